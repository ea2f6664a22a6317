"""Many scans: the multi-scan Problem, scan selections, whole logs through the CLI, log-odds, ROS export, evaluate."""

from __future__ import annotations

import gzip
import json

import jax
import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.rosmap import read_rosmap, write_pgm
from bayesmap.model.generative import log_joint_scans, make_params, simulate_scan_readings
from bayesmap.scenes import Problem, log_problem
from bayesmap.cli import parse_scans
from bayesmap.inference.driver import run_inference, run_logodds
from helpers import run_cli


def room_scans(beam_model: str, seed: int = 0) -> Problem:
    """A 12 x 9 unit-cell room with an inner wall, seen by 3 scans of 24 beams from different positions."""
    walls = np.zeros((12, 9), np.float32)
    walls[0, :] = walls[-1, :] = walls[:, 0] = walls[:, -1] = 1
    walls[6, 3:7] = 1
    grid = Grid((12, 9))
    poses = np.array([[2.3, 2.1], [9.2, 6.4], [3.7, 6.6]])
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)[None] + np.array([[0.0], [0.1], [0.2]])
    params = make_params(0.3, 0.25, 24, grid, max_distance=15.0, beam_model=beam_model)
    readings = np.asarray(simulate_scan_readings(jax.random.key(seed), walls, poses, params, angles), np.float64)
    readings = np.clip(readings, 0.0, 15.0)
    return Problem(params=params, pos=poses, beam_angles=angles, readings=readings, truth=walls,
                   max_range_mask=readings >= 15.0)


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_table_log_joint_equals_assess_of_the_multi_scan_model(beam_model):
    pb = room_scans(beam_model)
    rng = np.random.default_rng(1)
    for walls in [pb.truth, np.zeros_like(pb.truth), (rng.random(pb.truth.shape) < 0.3).astype(np.float32)]:
        dense = float(log_joint_scans(walls, pb.readings, pb.pos, pb.params, pb.beam_angles))
        # the model's prior term is float32 (TFP); the table's is float64: agree to float32 rounding of ~1e2 terms
        assert pb.table_log_joint(walls) == pytest.approx(dense, rel=1e-5, abs=1e-3)
        assert pb.log_joint(walls) == pytest.approx(dense, rel=1e-6)  # small problem: assess itself


def test_multi_scan_problem_layout_and_gibbs():
    pb = room_scans("beam")
    assert pb.multi_scan and pb.num_scans == 3 and pb.table.num_rays == 72
    assert np.array_equal(pb.scan_of_ray, np.repeat([0, 1, 2], 24))
    assert np.array_equal(pb.ray_origins[24], pb.pos[1]) and pb.ray_angles[25] == pb.beam_angles[1, 1]
    with pytest.raises(BayesmapError, match="take one scan; this problem has 3"):
        pb.single_scan()
    result = run_inference(pb, "block", 60, progress=False)
    assert result.summary["num_scans"] == 3 and result.summary["beam_model"] == "beam"
    assert result.summary["init"] == "logodds"
    # three viewpoints see the room's 99 visible cells; about 20% of the beam model's readings are outliers (short,
    # random, failures: 14 of 72 beams), each of which can leave at most one cell in doubt: measured 3-5 wrong over
    # seeds 0-2 (and 0-3 with the Normal model's readings, which have no outliers)
    assert result.summary["visible_cells"] == 99 and result.summary["wrong_visible_cells"] <= 8, result.summary
    with pytest.raises(BayesmapError, match="unknown chain start 'magic'"):
        run_inference(pb, "block", 10, init="magic", progress=False)


def test_logodds_marks_the_walls_the_beams_hit():
    pb = room_scans("normal")
    result = run_logodds(pb)
    assert result.samples.shape == (0, 12, 9) and result.summary["method"] == "logodds"
    occupied = result.posterior > 0.5
    # log-odds puts walls where the beams end: mostly on true walls or next to them (0.25 m noise on 1 m cells)
    near_wall = np.zeros_like(occupied)
    t = pb.truth > 0
    near_wall[:-1] |= t[1:]
    near_wall[1:] |= t[:-1]
    near_wall[:, :-1] |= t[:, 1:]
    near_wall[:, 1:] |= t[:, :-1]
    assert occupied.sum() >= 10 and np.mean((t | near_wall)[occupied]) > 0.95


@pytest.mark.parametrize("spec, expected", [
    (None, list(range(10))), ("all", list(range(10))), ("3", [3]), ("-1", [9]), ("2:5", [2, 3, 4]),
    ("::4", [0, 4, 8]), ("1:8:3, 9", [1, 4, 7, 9]), ("8:", [8, 9]),
])
def test_parse_scans(spec, expected):
    assert list(parse_scans(spec, 10)) == expected


@pytest.mark.parametrize("spec, match", [("10", "scan 10 is out of range"), ("a", "bad scan selection 'a'"),
                                         ("1:2:0", "bad scan selection"), ("5:2", "selects no scan"),
                                         ("1:2:3:4", "bad scan selection")])
def test_parse_scans_errors(spec, match):
    with pytest.raises(BayesmapError, match=match):
        parse_scans(spec, 10)


@pytest.fixture(scope="module")
def small_log(tmp_path_factory, intel_log):
    """The first 12 scans of the Intel log, as a plain CARMEN file."""
    path = tmp_path_factory.mktemp("log") / "intel12.log"
    with gzip.open(intel_log, "rt") as handle:
        lines = [line for line in handle if line.startswith("FLASER")][:12]
    path.write_text("".join(lines))
    return path


def test_infer_whole_log_logodds_and_rosmap(small_log, tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--log", small_log, "--resolution", 0.2, "--sweeps", 6,
                             "--sampler", "chromatic", "--rosmap", "--report", "--out", tmp_path / "g")
    assert code in (0, None), err
    report = (tmp_path / "g" / "report.html").read_text()
    assert 'id="fig-posterior"' in report and 'id="fig-convergence"' in report and "axes in m" in report
    assert 'id="fig-importance"' not in report  # importance sampling is the single-scan tutorial's
    summary = json.loads((tmp_path / "g" / "summary.json").read_text())
    assert summary["num_scans"] == 12 and summary["num_beams"] == 12 * 180 and summary["beam_model"] == "beam"
    assert summary["prior_wall_prob"] == 0.1 and "12 scans" in out
    plan = read_rosmap(tmp_path / "g" / "map.yaml")
    posterior = np.load(tmp_path / "g" / "posterior.npy")
    assert plan.grid.shape == posterior.shape and plan.grid.resolution == 0.2
    np.testing.assert_allclose(plan.occupancy, posterior, atol=0.5 / 255 + 1e-6)
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--log", small_log, "--scans", "0:12:2", "--resolution", 0.2,
                             "--method", "logodds", "--out", tmp_path / "lo")
    assert code in (0, None), err
    summary = json.loads((tmp_path / "lo" / "summary.json").read_text())
    assert summary["method"] == "logodds" and summary["num_scans"] == 6 and "sweeps" not in summary
    lo = np.load(tmp_path / "lo" / "posterior.npy")
    assert 0.12 - 1e-6 <= lo.min() and lo.max() <= 0.97 + 1e-6  # OctoMap's clamping bounds


def test_evaluate_log_writes_the_table(small_log, tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", small_log, "--every", 4, "--resolution", 0.2,
                             "--sweeps", 6, "--json", tmp_path / "scores.json")
    assert code in (0, None), err
    scores = json.loads((tmp_path / "scores.json").read_text())
    for method in ("bayesmap", "logodds"):
        assert 0.5 < scores[method]["auc"] <= 1.0 and np.isfinite(scores[method]["nll"])
    assert scores["setup"]["test_scans"] == 3 and scores["setup"]["train_scans"] == 9
    assert "bayesmap" in out and "logodds" in out and "auc" in out
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", small_log, "--json", tmp_path / "scores.json")
    assert code == 2 and "already exists" in err


def test_evaluate_truth_on_a_floor_plan(tmp_path, monkeypatch, capsys):
    # a 6 m x 4 m room with a pillar, as a bare PGM of 0.1 m pixels: 0 wall, 255 free, 205 unknown outside
    image = np.full((44, 64), 205, np.uint8)
    image[2:42, 2:62] = 0
    image[3:41, 3:61] = 255
    image[18:24, 30:34] = 0
    write_pgm(tmp_path / "room.pgm", image)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--truth", tmp_path / "room.pgm", "--num-poses", 4,
                             "--num-angles", 90, "--max-range", 8, "--sweeps", 10, "--json", tmp_path / "s.json")
    assert code in (0, None), err
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["setup"]["cells_scored"] > 500
    for method in ("bayesmap", "logodds"):
        assert set(scores[method]) >= {"accuracy", "auc", "brier", "cells"}
    # four viewpoints in a small room: the posterior gets nearly every seen cell right
    assert scores["bayesmap"]["accuracy"] > 0.9 and scores["bayesmap"]["brier"] < 0.1


def test_range_offset_shifts_only_returned_readings_the_model_scores(small_log):
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(small_log)
    pb = log_problem(log, resolution=0.2)
    assert pb.range_offset == 0.2 and pb.extra["range_offset"] == 0.2  # one cell by default
    raw, model, is_max = pb.ray_readings, pb.model_ray_readings, pb.ray_max_range
    assert is_max.any() and (~is_max).any()
    np.testing.assert_array_equal(model[is_max], raw[is_max])  # max-range readings keep the max range
    np.testing.assert_allclose(model[~is_max], np.maximum(raw[~is_max] - 0.2, 0.0))
    # the model's log joint scores the shifted readings; the figures and log-odds keep the measured ones
    walls = np.zeros(pb.grid.shape)
    unshifted = log_problem(log, resolution=0.2, range_offset=0.0)
    assert unshifted.range_offset == 0.0 and np.array_equal(unshifted.model_ray_readings, raw)
    assert pb.table_log_joint(walls) != unshifted.table_log_joint(walls)
    np.testing.assert_array_equal(run_logodds(pb).posterior, run_logodds(unshifted).posterior)
    for bad in (-0.1, float("nan"), 1e6):
        with pytest.raises(BayesmapError, match="range_offset"):
            log_problem(log, resolution=0.2, range_offset=bad)


def test_fast_samplers_refuse_problems_too_large_for_memory(monkeypatch):
    import bayesmap.inference.registry as registry

    pb = room_scans("normal")
    monkeypatch.setattr(registry, "MAX_FAST_PAIRS", pb.table.num_pairs - 1)
    with pytest.raises(BayesmapError, match=f"{pb.table.num_pairs:,} \\(beam, cell\\) pairs.*--sampler cellwise"):
        run_inference(pb, "chromatic", 4, progress=False)
    assert run_inference(pb, "cellwise", 4, progress=False).samples.shape == (4, 12, 9)  # no limit
    monkeypatch.setattr(registry, "MAX_FAST_PAIRS", pb.table.num_pairs)
    assert run_inference(pb, "chromatic", 4, progress=False).samples.shape == (4, 12, 9)


def test_cellwise_chains_run_one_after_another_with_the_keys_of_chains_at_once(monkeypatch):
    """Several cellwise chains run one by one (vmap would turn their conditional writes into always-run selects);
    chain c gets the keys it would get at once, so the samples equal those of the vmap path, and progress reaches
    the total of all chains."""
    import bayesmap.inference.driver as driver

    pb = room_scans("beam")
    seen = []
    one_by_one = run_inference(pb, "cellwise", 12, chains=2, progress=False, on_progress=lambda d, t: seen.append((d, t)))
    assert one_by_one.samples.shape == (2, 12, 12, 9)
    assert seen[-1] == (24, 24)
    monkeypatch.setattr(driver, "SEQUENTIAL_CHAINS", ())
    at_once = run_inference(pb, "cellwise", 12, chains=2, progress=False)
    np.testing.assert_array_equal(one_by_one.samples, at_once.samples)
    assert not np.array_equal(one_by_one.samples[0], one_by_one.samples[1])


def test_beam_weights_reach_the_model_and_the_summary(tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--beam-model", "beam", "--beam-weights", "0.7,0.1,0.1,0.1",
                             "--lambda-short", "0.3", "--sweeps", 4, "--out", tmp_path / "o")
    assert code in (0, None), err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["beam_model"] == "beam"
    assert [summary[k] for k in ("z_hit", "z_short", "z_max", "z_rand", "lambda_short")] == pytest.approx([0.7, 0.1, 0.1, 0.1, 0.3])


def test_likelihood_power_default_for_logs_and_refusals(small_log):
    """Logs default to the tempered target (LOG_LIKELIHOOD_POWER), recorded in the summary; bad powers and the
    reference samplers (which sample the plain posterior through assess) are refused with the value named."""
    from bayesmap.io.carmen import read_carmen
    from bayesmap.scenes import LOG_LIKELIHOOD_POWER
    from bayesmap.inference.registry import make_sampler
    from bayesmap.inference.driver import run_inference

    log = read_carmen(small_log)
    pb = log_problem(log, resolution=0.2)
    assert pb.likelihood_power == LOG_LIKELIHOOD_POWER < 1
    assert log_problem(log, resolution=0.2, likelihood_power=1).likelihood_power == 1.0
    for bad in (0, -0.5, 2, "x"):
        with pytest.raises(BayesmapError, match="likelihood_power"):
            log_problem(log, resolution=0.2, likelihood_power=bad)
    with pytest.raises(BayesmapError, match="likelihood power 0.1"):
        make_sampler(pb, "reference-raster")
    summary = run_inference(pb, "cellwise", 4, progress=False).summary
    assert summary["likelihood_power"] == LOG_LIKELIHOOD_POWER
    assert summary["posterior_estimate"] == "rao-blackwellized"
