"""Every command-line user error is ONE line on stderr and exit code 2: usage errors of every command and
option, enumerated from the typer app (a new option is covered without editing this file), and the refusals of
bad values, sizes that cannot fit, and a sensor in a wall."""

import gzip
import os
import stat
from pathlib import Path

import numpy as np
import pytest
import typer

from bayesmap.cli import app
from bayesmap.errors import BayesmapError
from helpers import SHARED_DATA, run_cli

INTEL = SHARED_DATA / "carmen" / "intel-corrected.log.gz"


def _commands():
    group = typer.main.get_command(app)
    return sorted(group.commands.items())


def _numeric(annotation) -> bool:
    """True for int, float, Optional[int | float] and tuples of them (typer's option annotations)."""
    import typing

    if annotation in (int, float):
        return True
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    return bool(args) and all(_numeric(a) for a in args)


def _usage_cases():
    """(argv, what) for every command: an unknown flag; for every option a missing value (or, for a flag, a value
    it does not take) and, for a number, a wrong type."""
    cases = [(["nosuchcmd"], "unknown command"), (["--no-such-flag"], "unknown top-level flag")]
    for name, command in _commands():
        cases.append(([name, "--no-such-flag"], f"{name}: unknown flag"))
        for param in command.params:
            if param.param_type_name != "option" or param.name == "help":
                continue
            flag = max(param.opts, key=len)
            if param.is_flag:
                cases.append(([name, f"{flag}=yes"], f"{name} {flag}: a value given to a flag"))
                continue
            cases.append(([name, flag], f"{name} {flag}: missing value"))
            if _numeric(param.type_descriptor.annotation):
                cases.append(([name, flag, *["abc"] * param.nargs], f"{name} {flag}: wrong type"))
    return cases


USAGE_CASES = _usage_cases()


def test_the_enumeration_covers_every_command_and_numeric_option():
    names = {name for name, _ in _commands()}
    assert {"demo", "infer", "bench", "evaluate", "app"} <= names
    whats = " | ".join(what for _, what in USAGE_CASES)
    for expected in ("infer --sweeps: wrong type", "infer --pos: wrong type", "evaluate --num-poses: wrong type",
                     "app --port: wrong type", "bench --repeats: wrong type", "infer --out: missing value",
                     "infer --force: a value given"):
        assert expected in whats


@pytest.mark.parametrize("argv, what", USAGE_CASES, ids=[what for _, what in USAGE_CASES])
def test_usage_errors_are_one_line_exit_2(monkeypatch, capsys, argv, what):
    code, out, err = run_cli(monkeypatch, capsys, *argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, (what, code, err)
    assert len(lines) == 1 and lines[0].startswith("error: "), (what, err)
    assert "Traceback" not in err and out == ""
    if what.endswith("wrong type"):  # the offending value is named, as typed
        assert "'abc" in err, (what, err)


def test_help_is_exit_0_and_has_no_emoji(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--help")
    assert code == 0 and "--scans" in out
    assert "\U0001f171" not in out  # rich read ':b:' of 'a:b:step' as the emoji code of a blood-type B
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--help")
    assert code == 0 and "\U0001f171" not in out


@pytest.fixture
def small_log(tmp_path, intel_log):
    """The first 5 scans of the Intel log."""
    lines = []
    with gzip.open(intel_log, "rt") as handle:
        for line in handle:
            if line.startswith("FLASER"):
                lines.append(line)
                if len(lines) == 5:
                    break
    path = tmp_path / "five.log"
    path.write_text("".join(lines))
    return path


def _far_pose_log(small_log: Path) -> Path:
    lines = small_log.read_text().splitlines()
    toks = lines[2].split()
    toks[2 + 180] = "1e6"  # x of the third pose, 1000 km away
    lines[2] = " ".join(toks)
    path = small_log.with_name("far.log")
    path.write_text("\n".join(lines) + "\n")
    return path


def _rosmap_yaml(tmp_path: Path, resolution: str) -> Path:
    import numpy as np

    from bayesmap.io.rosmap import write_pgm

    image = np.full((40, 50), 254, np.uint8)
    image[0, :] = image[-1, :] = image[:, 0] = image[:, -1] = 0
    write_pgm(tmp_path / "room.pgm", image)
    path = tmp_path / f"room-{resolution}.yaml"
    path.write_text(f"image: room.pgm\nresolution: {resolution}\norigin: [0, 0, 0]\nnegate: 0\n"
                    "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return path


@pytest.mark.parametrize("make_args, match", [
    # values are validated before computing (no numpy warnings first)
    (lambda t, log: ["infer", "--resolution", "0"], r"--resolution.*> ?0|\(0, 100\]"),
    (lambda t, log: ["infer", "--resolution", "nan"], "got nan"),
    (lambda t, log: ["infer", "--pos", "1e308", "2"], "got 1e\\+308"),
    # sizes that cannot fit are refused up front, naming the figure and the way out
    (lambda t, log: ["infer", "--sweeps", "9223372036854775808"], "--sweeps"),
    (lambda t, log: ["infer", "--log", log, "--resolution", "1e-6"], "cells of 1e-06 m .*coarser --resolution"),
    (lambda t, log: ["infer", "--log", _far_pose_log(log), "--method", "logodds"], "far-away pose"),
    (lambda t, log: ["infer", "--log", INTEL, "--resolution", "0.01", "--cut-past-reading", "inf"],
     r"ray-cell table would take about \d+ GB.*--keyframe-distance.*--cut-past-reading"),
    (lambda t, log: ["evaluate", "--truth", _rosmap_yaml(t, "1e-9")], "finer than 0.01 m"),
    (lambda t, log: ["evaluate", "--log", log, "--resolution", "1e-5"], "cells of 1e-05 m .*coarser --resolution"),
    # a scene that cannot be simulated
    (lambda t, log: ["evaluate", "--truth", _rosmap_yaml(t, "0.05"), "--num-poses", "0"], "--num-poses"),
    (lambda t, log: ["evaluate", "--truth", _rosmap_yaml(t, "1e9")], "shorter than one cell"),
    # the app refuses a sensor in a wall; so does the CLI, naming the cell
    (lambda t, log: ["infer", "--map", t / "room.txt", "--pos", "1", "1"], r"in wall cell \(1, 1\)"),
    # an implausible reading names the file, the line and the value
    (lambda t, log: ["infer", "--log", t / "outlier.log"], r"outlier.log:2: range 9 of 180 is 1e\+26"),
    (lambda t, log: ["infer", "--log", log, "--max-range", "-3"], "--max-range"),
    (lambda t, log: ["infer", "--max-range", "50"], "need --log"),
    # walls a beam can pass: a probability below 1, several scans of a log, a sampler that keeps two walls
    (lambda t, log: ["infer", "--log", log, "--wall-pass-prob", "1"], "wall_pass_prob must be in \\[0, 1\\)"),
    (lambda t, log: ["infer", "--wall-pass-prob", "0.2"],
     "--cut-past-reading, --tile-pairs and the keyframe options apply"),
    (lambda t, log: ["infer", "--cut-past-reading", "1"],
     "--cut-past-reading, --tile-pairs and the keyframe options apply"),
    (lambda t, log: ["infer", "--keyframe-distance", "1"],
     "--cut-past-reading, --tile-pairs and the keyframe options apply"),
    (lambda t, log: ["slam", "--keyframe-turn", "1"], "the keyframe options need --log"),
    (lambda t, log: ["slam", "--log", log, "--keyframe-distance", "-1", "--out", t / "kf"],
     "keyframe distance must be"),
    (lambda t, log: ["infer", "--log", log, "--wall-pass-prob", "0.2", "--sampler", "raster"],
     "wall_pass_prob = 0.2; the cellwise sampler supports it"),
    # --scan and --scans agree on negative indexes; out of range is refused by both alike
    (lambda t, log: ["infer", "--log", log, "--scan", "-6"], "scan -6 is out of range"),
    # a folder with folders of its own is not swapped as a whole
    (lambda t, log: ["infer", "--out", t, "--force"], "holds a folder of its own"),
])
def test_bad_values_are_refused_in_one_line(tmp_path, monkeypatch, capsys, small_log, make_args, match):
    import re

    (tmp_path / "room.txt").write_text(".....\n.XXX.\n.X...\n.....\n")
    lines = small_log.read_text().splitlines()
    toks = lines[1].split()
    toks[10] = "1e26"
    (tmp_path / "outlier.log").write_text("\n".join([lines[0], " ".join(toks), *lines[2:]]) + "\n")
    (tmp_path / "sub").mkdir()
    args = make_args(tmp_path, small_log)
    if args[0] == "infer" and "--out" not in args:
        args += ["--out", tmp_path / "o"]
    code, out, err = run_cli(monkeypatch, capsys, *args)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert re.search(match, lines[0]), lines[0]
    assert not (tmp_path / "o").exists()


def test_scan_minus_one_is_the_last_scan(tmp_path, monkeypatch, capsys, small_log):
    """--scan -1 and --scans -1 both mean the last scan (a negative index counts from the end in both)."""
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--log", small_log, "--scan", "-1", "--method", "logodds",
                             "--out", tmp_path / "o")
    assert code == 0, err
    assert "scan 4," in out


def test_max_range_option_reaches_the_reader(tmp_path, monkeypatch, capsys, small_log):
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--log", small_log, "--max-range", "10",
                             "--method", "logodds", "--resolution", "0.2", "--out", tmp_path / "o")
    assert code == 0, err
    import json

    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert json.dumps(summary).count("NaN") == 0
    import numpy as np

    assert np.load(tmp_path / "o" / "readings.npy").max() == pytest.approx(10.0)


# ------------------------------------------------------------------------------------------------------------------
# the output folder is replaced as a whole
# ------------------------------------------------------------------------------------------------------------------


def test_replace_folder_keeps_the_old_output_when_writing_fails(tmp_path, monkeypatch):
    from bayesmap.io import files

    out = tmp_path / "out"
    files.replace_folder(out, {"a.npy": b"old a", "summary.json": b"old summary"})
    (out / "mine.txt").write_text("the user's")
    written = []
    real = Path.write_bytes

    def failing(self, data):
        if len(written) == 2:
            raise OSError(28, "No space left on device")
        written.append(self.name)
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", failing)
    with pytest.raises(BayesmapError, match="No space left"):
        files.replace_folder(out, {"a.npy": b"new a", "b.png": b"new b", "summary.json": b"new summary"})
    assert written == ["a.npy", "b.png"]
    assert sorted(p.name for p in out.iterdir()) == ["a.npy", "mine.txt", "summary.json"]
    assert (out / "summary.json").read_bytes() == b"old summary" and (out / "a.npy").read_bytes() == b"old a"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no staging folder left behind


def test_replace_folder_swaps_in_the_new_output_whole(tmp_path):
    from bayesmap.io import files

    out = tmp_path / "out"
    files.replace_folder(out, {"a.npy": b"old", "diagnostics.npz": b"old chains"})
    (out / "mine.txt").write_text("the user's")
    files.replace_folder(out, {"a.npy": b"new", "summary.json": b"new"}, owned=["diagnostics.npz"])
    # the old run's diagnostics do not linger beside the new outputs; the user's file stays
    assert sorted(p.name for p in out.iterdir()) == ["a.npy", "mine.txt", "summary.json"]
    assert (out / "a.npy").read_bytes() == b"new" and (out / "mine.txt").read_text() == "the user's"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_output_folder_mode_follows_the_umask(tmp_path, umask):
    from bayesmap.io import files

    old = os.umask(umask)
    try:
        files.replace_folder(tmp_path / "out", {"a.npy": b"x"})
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out").stat().st_mode) == 0o777 & ~umask
    assert stat.S_IMODE((tmp_path / "out" / "a.npy").stat().st_mode) == 0o666 & ~umask


def test_the_pair_estimate_bounds_every_ray_within_three_cells(small_log):
    """runs.inputs.ray_cells, what the size check counts: every ray of a real table has at most that many pairs and
    fewer than 3 less (a beam inside the grid enters one new cell per grid line it crosses, and the estimate adds 2
    for its first cell and the lines' fractional parts), so over a whole log it is within 1 % (0.1 % at 5 cm)."""
    from bayesmap.io.carmen import read_carmen
    from bayesmap.runs.inputs import ray_cells
    from bayesmap.scenes import log_problem

    for resolution in (0.1, 0.25):
        problem = log_problem(read_carmen(small_log), resolution=resolution)
        table = problem.table
        estimate = ray_cells(problem.grid, problem.ray_origins, problem.ray_angles, float(problem.params.max_range))
        assert estimate.shape == (table.num_rays,)
        excess = estimate - table.lengths
        assert np.all((excess >= 0) & (excess < 3)), (excess.min(), excess.max())


def test_the_whole_intel_log_at_10_cm_fits(intel_log):
    """The size limits leave room for the README's whole-log run (42.4 million pairs, 2.9 GB peak) and refuse the
    same log at 1 cm (about 4 billion pairs)."""
    from bayesmap.io.carmen import read_carmen
    from bayesmap.runs.inputs import check_problem_size
    from bayesmap.scenes import log_problem

    log = read_carmen(intel_log)
    check_problem_size(log_problem(log, resolution=0.1))
    check_problem_size(log_problem(log, resolution=0.05))
    with pytest.raises(BayesmapError, match="ray-cell table"):
        check_problem_size(log_problem(log, resolution=0.01))
