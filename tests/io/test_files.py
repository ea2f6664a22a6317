"""bayesmap.io.files: only regular files are read, writes go through a staging entry that a later write sweeps when
its writer is gone, and a folder is replaced only when it holds what the writer recognises as its own."""

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bayesmap.errors import BayesmapError
from bayesmap.io import files


def test_read_bytes_refuses_devices_and_fifos_at_once(tmp_path):
    fifo = tmp_path / "pipe.log"
    os.mkfifo(fifo)
    start = time.perf_counter()
    with pytest.raises(BayesmapError, match=r"CARMEN log '.*pipe\.log' is a FIFO \(named pipe\), not a regular file"):
        files.read_bytes(fifo, "CARMEN log")  # no writer: opening it blocking would wait for ever
    with pytest.raises(BayesmapError, match=r"map file '/dev/zero' is a character device"):
        files.read_bytes("/dev/zero", "map file")  # reading it would never end
    assert time.perf_counter() - start < 5
    link = tmp_path / "link.txt"
    (tmp_path / "real.txt").write_bytes(b"abc")
    link.symlink_to(tmp_path / "real.txt")
    assert files.read_bytes(link, "map file") == (str(link), b"abc")  # a link to a regular file is read


def test_check_regular_checks_every_file_of_a_folder(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("x")
    (bag / "sub").mkdir()  # folders inside are not checked (a reader does not open them as files)
    assert files.check_regular(bag, "ROS bag", folder=True) == bag
    with pytest.raises(BayesmapError, match="is a directory"):
        files.check_regular(bag, "ROS bag")
    os.mkfifo(bag / "bag_0.db3")
    with pytest.raises(BayesmapError, match=r"ROS bag '.*bag': file '.*bag_0\.db3' is a FIFO"):
        files.check_regular(bag, "ROS bag", folder=True)
    with pytest.raises(BayesmapError, match="does not exist"):
        files.check_regular(tmp_path / "nothing", "ROS bag")


def test_check_own_folder(tmp_path):
    folder = tmp_path / "bag"
    folder.mkdir()
    files.check_own_folder(folder, "metadata.yaml", (".db3",), "a ROS 2 bag")  # empty: nothing of a user's in it
    (folder / "bag_0.db3").write_bytes(b"")
    with pytest.raises(BayesmapError, match=r"not a ROS 2 bag \(no metadata.yaml\)"):
        files.check_own_folder(folder, "metadata.yaml", (".db3",), "a ROS 2 bag")
    (folder / "metadata.yaml").write_text("")
    files.check_own_folder(folder, "metadata.yaml", (".db3",), "a ROS 2 bag")
    (folder / "notes.db3.txt").write_text("mine")
    with pytest.raises(BayesmapError, match=r"it holds 'notes.db3.txt'"):
        files.check_own_folder(folder, "metadata.yaml", (".db3",), "a ROS 2 bag")


def _dead_pid() -> int:
    """The id of a process that has ended (a child, waited for)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_sweep_stale_removes_only_abandoned_staging(tmp_path):
    target = tmp_path / "out"
    dead = tmp_path / f".out.bayesmap-{_dead_pid()}-abcd_123"
    dead_file = tmp_path / f".out.bayesmap-{_dead_pid()}-abcd_124.tmp"
    alive = tmp_path / f".out.bayesmap-{os.getppid()}-abcd_125"
    mine = tmp_path / f".out.bayesmap-{os.getpid()}-abcd_126"  # this process's own write in progress
    aged = tmp_path / f".out.bayesmap-{os.getppid()}-abcd_127"
    users = [tmp_path / ".out.backup", tmp_path / ".out.abcd_128", tmp_path / ".other.bayesmap-1-abcd_129"]
    for path in (dead, alive, mine, aged):
        path.mkdir()
    (dead / "summary.json").write_text("half")
    dead_file.write_text("half")
    for path in users:
        path.write_text("the user's")
    old = time.time() - files.STALE_AFTER_S - 1
    for path in (aged, *users):
        os.utime(path, (old, old))
    removed = files.sweep_stale(target)
    assert sorted(p.name for p in removed) == sorted([dead.name, dead_file.name, aged.name])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, mine.name] + [p.name for p in users])


def test_make_staging_names_its_process(tmp_path):
    folder = files.make_staging(tmp_path / "out", folder=True)
    file = files.make_staging(tmp_path / "x.json")
    assert folder.is_dir() and folder.name.startswith(f".out.bayesmap-{os.getpid()}-")
    assert file.is_file() and file.name.startswith(f".x.json.bayesmap-{os.getpid()}-") and file.name.endswith(".tmp")
    assert files.sweep_stale(tmp_path / "out") == [] and files.sweep_stale(tmp_path / "x.json") == []


def test_write_atomic_leaves_nothing_when_interrupted(tmp_path, monkeypatch):
    target = tmp_path / "scores.json"
    target.write_text("old")

    def interrupted(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        files.write_atomic(target, "new", overwrite=True)
    assert [p.name for p in tmp_path.iterdir()] == ["scores.json"] and target.read_text() == "old"


def test_write_atomic_sweeps_a_killed_writes_file(tmp_path):
    target = tmp_path / "scores.json"
    left = tmp_path / f".scores.json.bayesmap-{_dead_pid()}-abcdefgh.tmp"
    left.write_text("half")
    files.write_atomic(target, "new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scores.json"] and Path(target).read_text() == "new"
