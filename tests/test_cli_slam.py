"""`bayesmap slam` on the tutorial SLAM scene: its outputs, their contents, and its refusals."""

import json

import numpy as np
import pytest

from bayesmap.io.tum import read_tum
from helpers import run_cli

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)


@pytest.mark.xdist_group("tutorial_slam")
def test_slam_writes_all_outputs(tmp_path, monkeypatch, capsys):
    """A short run (5 poses, 12 sweeps, 4 burn-in: the joint chain of tests/slam/test_joint.py's tutorial_slam,
    compiled once on their shared xdist worker) writes every output, consistent with each other, whole, and refuses
    to overwrite them without --force."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, stdout, err = run_cli(monkeypatch, capsys, "slam", "--num-poses", 5, "--sweeps", 12, "--burn-in", 4,
                                "--out", out, "--report")
    assert code == 0, err
    assert "ATE" in stdout and "odometry" in stdout
    names = {"trajectory.tum", "trajectory_samples.npy", "pose_cov.npy", "posterior.npy", "posterior.png",
             "summary.json", "report.html"}
    assert names | {"notes.txt"} == {p.name for p in out.iterdir()}
    stamps, poses = read_tum(out / "trajectory.tum")
    assert np.array_equal(stamps, np.arange(5)) and poses.shape == (5, 3)
    samples = np.load(out / "trajectory_samples.npy")
    cov = np.load(out / "pose_cov.npy")
    assert samples.shape == (8, 5, 3) and cov.shape == (5, 3, 3)
    assert np.allclose(poses[:, :2], samples[:, :, :2].mean(axis=0), atol=1e-5)
    posterior = np.load(out / "posterior.npy")
    assert posterior.shape == (21, 21) and posterior.min() >= 0 and posterior.max() <= 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["sweeps"] == 12 and summary["settings"]["num_poses"] == 5
    assert summary["posterior"]["ate_rmse_m"] < summary["odometry"]["ate_rmse_m"]
    assert 0 <= summary["posterior"]["coverage"] <= 1 and summary["odometry"]["coverage"] is None
    assert (out / "posterior.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "data:image/png;base64," in (out / "report.html").read_text()
    code, _, err = run_cli(monkeypatch, capsys, "slam", "--num-poses", 5, "--sweeps", 2, "--burn-in", 1,
                           "--out", out)
    assert code == 2 and "--force" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("args, match", [
    (["--log", "x.log"], "'x.log' does not exist"),
    (["--num-poses", "1"], "--num-poses"),
    (["--num-poses", "65"], "--num-poses"),
    (["--sweeps", "0"], "--sweeps"),
    (["--sweeps", "5", "--burn-in", "5"], "--burn-in"),
    (["--burn-in", "-1"], "--burn-in"),
    (["--seed", "-3"], "--seed"),
])
def test_slam_bad_values_are_one_line_exit_2(tmp_path, monkeypatch, capsys, args, match):
    code, out, err = run_cli(monkeypatch, capsys, "slam", *args, "--out", tmp_path / "o")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and match in lines[0], err
    assert not (tmp_path / "o").exists()
