"""Hostile input at the command line, each case through ``bayesmap.cli.main`` and files on disk: Ctrl+C in the middle
of a run, devices and FIFOs given as files, a true trajectory of other scans, a folder that is not a bag given to
``--force``, the staging entries a killed write leaves, and output paths that cannot be written."""

import importlib
import io
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import bayesmap
from bayesmap.io.tum import write_tum
from helpers import run_cli

ROOM = "XXXXXXX\nX.....X\nX.....X\nX.....X\nXXXXXXX\n"
SRC = str(Path(bayesmap.__file__).resolve().parents[1])
"""The source tree under test, for the subprocesses (``PYTHONPATH``)."""


def _lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip()]


def _square_log(tmp_path: Path) -> Path:
    """A 4-scan CARMEN log (3 beams each) on a 2 m square, at stamps 100.0, 100.5, 101.0, 101.5 s."""
    corners = [(0.0, 0.0, 0.0), (2.0, 0.0, math.pi / 2), (2.0, 2.0, math.pi), (0.0, 2.0, -math.pi / 2)]
    lines = [f"FLASER 3 1.0 1.5 2.0 {x!r} {y!r} {t!r} {x!r} {y!r} {t!r} {100 + 0.5 * k!r} host {100 + 0.5 * k!r}\n"
             for k, (x, y, t) in enumerate(corners)]
    path = tmp_path / "square.log"
    path.write_text("".join(lines))
    return path


def _run_folder(tmp_path: Path, stamps) -> Path:
    """A ``bayesmap slam`` output folder: trajectory.tum at ``stamps`` and pose_cov.npy."""
    run = tmp_path / "run"
    run.mkdir()
    poses = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 1.5], [2.0, 2.0, 3.1], [0.0, 2.0, -1.5]])
    write_tum(run / "trajectory.tum", stamps, poses)
    buf = io.BytesIO()
    np.save(buf, np.broadcast_to(np.eye(3) * 0.01, (4, 3, 3)))
    (run / "pose_cov.npy").write_bytes(buf.getvalue())
    return run


# ------------------------------------------------------------------------------------------------------------------
# Ctrl+C: an interrupted run says so and exits 130, with nothing written
# ------------------------------------------------------------------------------------------------------------------


def _interrupt(monkeypatch, modules: str, name: str) -> None:
    """Make ``name`` of the first of ``modules`` (comma-separated) that imports raise KeyboardInterrupt (Ctrl+C in
    the middle of the work) in every bayesmap module that holds it, wherever the command imported it from (the
    modules' names as they are and as they were before the SLAM modules moved to bayesmap.slam)."""
    for module in modules.split(","):
        try:
            original = getattr(importlib.import_module(module), name)
            break
        except ModuleNotFoundError:
            continue

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    holders = [m for m in list(sys.modules.values())
               if getattr(m, "__name__", "").startswith("bayesmap") and getattr(m, name, None) is original]
    for holder in holders:
        monkeypatch.setattr(holder, name, interrupted)
    assert len(holders) >= 2  # the defining module and the command's


@pytest.mark.parametrize("args, module, name", [
    (["infer", "--map", "{t}/room.txt", "--sweeps", "5"], "bayesmap.inference.driver", "run_inference"),
    (["slam", "--num-poses", "3", "--sweeps", "2"], "bayesmap.slam.joint,bayesmap.inference.slam", "run_slam"),
])
def test_ctrl_c_says_so_and_exits_130(tmp_path, monkeypatch, capsys, args, module, name):
    (tmp_path / "room.txt").write_text(ROOM)
    _interrupt(monkeypatch, module, name)
    code, out, err = run_cli(monkeypatch, capsys, *[a.format(t=tmp_path) for a in args], "--out", tmp_path / "out")
    assert code == 130, (code, err)
    assert len(_lines(err)) == 1 and "interrupted" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.txt"]  # no output folder, no staging left


def test_ctrl_c_while_writing_keeps_the_old_outputs(tmp_path, monkeypatch, capsys):
    """Interrupted between two files of the new output folder: the old folder stays as it was, no staging left."""
    (tmp_path / "room.txt").write_text(ROOM)
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("old")
    real, written = Path.write_bytes, []

    def interrupted_write(self, data):
        if written:
            raise KeyboardInterrupt
        written.append(self.name)
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", interrupted_write)
    code, _, err = run_cli(monkeypatch, capsys, "infer", "--map", tmp_path / "room.txt", "--sweeps", 5, "--out", out,
                           "--force")
    assert code == 130 and "interrupted" in err, (code, err)
    assert written and [p.name for p in out.iterdir()] == ["summary.json"]
    assert (out / "summary.json").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "room.txt"]


# ------------------------------------------------------------------------------------------------------------------
# devices and FIFOs: refused at once, by name (not read without end, not waited on)
# ------------------------------------------------------------------------------------------------------------------

BATCH = """
import contextlib, io, json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))
from bayesmap.cli import main
results = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            main(argv)
        except SystemExit as exc:
            results.append([exc.code, err.getvalue()])
print(json.dumps(results))
"""
"""Run ``main`` on each argv of a JSON list in one process (one import of JAX), printing ``[[code, stderr], ...]``;
its address space limited to 4 GB, so that a reader that reads /dev/zero fails fast instead of filling the machine's
memory (JAX's import and these refusals need well under 1 GB)."""


def _run_batch(cases: list[list[str]], cwd: Path) -> list:
    env = {**os.environ, "PYTHONPATH": SRC}
    done = subprocess.run([sys.executable, "-c", BATCH, json.dumps(cases)], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_devices_and_fifos_are_refused_at_once(tmp_path):
    _square_log(tmp_path)
    write_tum(tmp_path / "truth.tum", [100.0, 100.5, 101.0, 101.5], np.zeros((4, 3)))
    for name in ("fifo.log", "fifo.txt", "fifo.bag", "fifo.tum", "fifo.yaml"):
        os.mkfifo(tmp_path / name)
    (tmp_path / "bag2").mkdir()  # a ROS 2 bag folder whose storage file is a FIFO
    (tmp_path / "bag2" / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 9\n")
    os.mkfifo(tmp_path / "bag2" / "bag2_0.db3")
    run = _run_folder(tmp_path, [100.0, 100.5, 101.0, 101.5])
    (run / "trajectory.tum").unlink()
    os.mkfifo(run / "trajectory.tum")
    cases = [
        (["slam", "--log", "/dev/zero", "--out", "o"], "'/dev/zero' is a character device"),
        (["infer", "--log", "/dev/urandom", "--out", "o"], "'/dev/urandom' is a character device"),
        (["convert", "/dev/zero", "out.bag"], "'/dev/zero' is a character device"),
        (["infer", "--log", "fifo.log", "--out", "o"], "'fifo.log' is a FIFO"),
        (["infer", "--map", "fifo.txt", "--out", "o"], "'fifo.txt' is a FIFO"),
        (["infer", "--bag", "fifo.bag", "--out", "o"], "'fifo.bag' is a FIFO"),
        (["slam", "--bag", "bag2", "--out", "o"], "bag2_0.db3' is a FIFO"),
        (["evaluate", "--log", "square.log", "--truth-trajectory", "fifo.tum"], "'fifo.tum' is a FIFO"),
        (["evaluate", "--log", "square.log", "--truth-trajectory", "truth.tum", "--run", "run"],
         "trajectory.tum' is a FIFO"),
        (["evaluate", "--truth", "fifo.yaml"], "'fifo.yaml' is a FIFO"),
    ]
    start = time.perf_counter()
    results = _run_batch([argv for argv, _ in cases], tmp_path)
    assert time.perf_counter() - start < 240
    for (argv, words), (code, err) in zip(cases, results):
        lines = _lines(err)
        assert code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], (argv, err)
    assert not (tmp_path / "o").exists() and not (tmp_path / "out.bag").exists()


# ------------------------------------------------------------------------------------------------------------------
# a true trajectory with a pose per scan but other scans' stamps is refused, not paired by order
# ------------------------------------------------------------------------------------------------------------------


def test_a_truth_of_other_scans_is_refused(tmp_path, monkeypatch, capsys):
    _square_log(tmp_path)
    run = _run_folder(tmp_path, [100.0, 100.5, 101.0, 101.5])
    write_tum(tmp_path / "other.tum", [200.0, 200.5, 201.0, 201.5], np.zeros((4, 3)))
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", tmp_path / "square.log", "--truth-trajectory",
                             tmp_path / "other.tum", "--run", run)
    lines = _lines(err)
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert "200.000 to 201.500" in lines[0] and "100.000 to 101.500" in lines[0], lines[0]
    # without --run, it is refused before SLAM runs (nothing printed)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", tmp_path / "square.log", "--truth-trajectory",
                             tmp_path / "other.tum", "--sweeps", 2)
    assert code == 2 and "200.000 to 201.500" in err and out == "", err


def test_a_truth_stamped_with_scan_indices_still_pairs_by_order(tmp_path, monkeypatch, capsys):
    _square_log(tmp_path)
    run = _run_folder(tmp_path, [100.0, 100.5, 101.0, 101.5])
    write_tum(tmp_path / "indexed.tum", [0, 1, 2, 3], np.zeros((4, 3)))
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", tmp_path / "square.log", "--truth-trajectory",
                             tmp_path / "indexed.tum", "--run", run)
    assert code == 0 and "paired by order" in out, err


# ------------------------------------------------------------------------------------------------------------------
# --force replaces only what bayesmap wrote: a folder that is not a ROS 2 bag is refused
# ------------------------------------------------------------------------------------------------------------------


def test_convert_force_keeps_a_folder_that_is_not_a_bag(tmp_path, monkeypatch, capsys):
    log = _square_log(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, _, err = run_cli(monkeypatch, capsys, "convert", log, out, "--ros2", "--force")
    assert code == 2 and len(_lines(err)) == 1 and str(out) in err and "not a ROS 2 bag" in err, err
    assert [p.name for p in out.iterdir()] == ["notes.txt"] and (out / "notes.txt").read_text() == "mine"
    # a bag is replaced; a bag with a user's file beside it is not
    bag = tmp_path / "bag"
    assert run_cli(monkeypatch, capsys, "convert", log, bag, "--ros2")[0] == 0
    assert run_cli(monkeypatch, capsys, "convert", log, bag, "--ros2", "--force", "--scans", "0:2")[0] == 0
    (bag / "notes.txt").write_text("mine")
    code, _, err = run_cli(monkeypatch, capsys, "convert", log, bag, "--ros2", "--force")
    assert code == 2 and "'notes.txt'" in err and (bag / "notes.txt").read_text() == "mine", err
    assert len(list(bag.iterdir())) == 3  # metadata.yaml, the .db3 and notes.txt


def test_out_bag_force_keeps_a_folder_that_is_not_a_bag(tmp_path, monkeypatch, capsys):
    (tmp_path / "room.txt").write_text(ROOM)
    folder = tmp_path / "maps"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("my: notes\n")
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--map", tmp_path / "room.txt", "--sweeps", 5,
                             "--out", tmp_path / "out", "--out-bag", folder, "--force")
    assert code == 2 and "not a ROS 2 bag" in err and out == "", err  # refused before any work
    assert (folder / "metadata.yaml").read_text() == "my: notes\n" and not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------------------------------
# a write killed in its last instant leaves a staging entry; the next write to the same place removes it
# ------------------------------------------------------------------------------------------------------------------

KILLED_WRITE = """
import os, signal, sys
from pathlib import Path
from bayesmap.io import files
real = Path.write_bytes
def dying(self, data):
    real(self, data)
    os.kill(os.getpid(), signal.SIGKILL)
def dying_replace(src, dst):
    os.kill(os.getpid(), signal.SIGKILL)
Path.write_bytes = dying
os.replace = dying_replace
if sys.argv[2] == "folder":
    files.replace_folder(Path(sys.argv[1]), {"summary.json": b"new", "posterior.npy": b"new"})
else:
    files.write_atomic(Path(sys.argv[1]), b"new", overwrite=True)
"""
"""Write ``argv[1]`` (a folder with ``replace_folder``, or a file with ``write_atomic``) and SIGKILL the process
in the middle: after the first file of the folder, or just before the file's rename."""


def _killed_write(path: Path, kind: str) -> list[str]:
    """Names of the hidden entries beside ``path`` after a write to it was killed (at least one)."""
    done = subprocess.run([sys.executable, "-c", KILLED_WRITE, str(path), kind], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": SRC}, timeout=120)
    assert done.returncode == -signal.SIGKILL, done.stderr
    left = [p.name for p in path.parent.iterdir() if p.name.startswith(f".{path.name}.")]
    assert left
    return left


def test_a_killed_writes_staging_is_removed_by_the_next_write(tmp_path, monkeypatch, capsys):
    (tmp_path / "room.txt").write_text(ROOM)
    out = tmp_path / "out"
    _killed_write(out, "folder")
    code, _, err = run_cli(monkeypatch, capsys, "infer", "--map", tmp_path / "room.txt", "--sweeps", 5, "--out", out)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "room.txt"]
    from bayesmap.io.files import write_atomic

    target = tmp_path / "scores.json"
    _killed_write(target, "file")
    write_atomic(target, b"{}", overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "room.txt", "scores.json"]


def test_the_staging_of_a_running_write_is_kept(tmp_path):
    """A staging entry whose process runs (the test's parent) is another write in progress: it stays, unless it is
    older than any write takes (bayesmap.io.files.STALE_AFTER_S)."""
    from bayesmap.io import files

    running = tmp_path / f".out.bayesmap-{os.getppid()}-abcdefgh"
    old = tmp_path / f".out.bayesmap-{os.getppid()}-oldoldol"
    mine = tmp_path / ".out.backup"  # a user's hidden file of another form
    for path in (running, old):
        path.mkdir()
    mine.write_text("mine")
    stale = time.time() - files.STALE_AFTER_S - 60
    os.utime(old, (stale, stale))
    os.utime(mine, (stale, stale))
    files.replace_folder(tmp_path / "out", {"a.npy": b"x"})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([running.name, mine.name, "out"])


# ------------------------------------------------------------------------------------------------------------------
# output paths are checked before the work
# ------------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("json_path, words", [("missing/x.json", "there is no folder"), ("sub", "is a folder")])
def test_evaluate_json_is_checked_before_the_work(tmp_path, monkeypatch, capsys, small_log, json_path, words):
    (tmp_path / "sub").mkdir()
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", small_log, "--every", 3, "--sweeps", 2,
                             "--json", tmp_path / json_path)
    lines = _lines(err)
    assert code == 2 and len(lines) == 1 and words in lines[0] and json_path in lines[0], err
    assert out == ""  # no evaluation ran (its table is printed before the JSON is written)
