"""The inference driver: run_inference (chains, chunks, progress, summary) and run_logodds, also through the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bayesmap import scenes
from bayesmap.errors import BayesmapError
from bayesmap.inference.driver import run_inference, run_logodds, scene_summary
from bayesmap.io.rosmap import read_rosmap
from bayesmap.progress import Progress
from helpers import room_scans, run_cli


def test_block_gibbs_on_three_scans():
    pb = room_scans("beam")
    result = run_inference(pb, "block", 60)
    assert result.summary["num_scans"] == 3 and result.summary["beam_model"] == "beam"
    assert result.summary["init"] == "logodds"
    # three viewpoints see the room's 99 visible cells; about 20% of the beam model's readings are outliers (short,
    # random, failures: 14 of 72 beams), each of which can leave at most one cell in doubt: measured 3-5 wrong over
    # seeds 0-2 (and 0-3 with the Normal model's readings, which have no outliers)
    assert result.summary["visible_cells"] == 99 and result.summary["wrong_visible_cells"] <= 8, result.summary
    with pytest.raises(BayesmapError, match="unknown chain start 'magic'"):
        run_inference(pb, "block", 10, init="magic")


@pytest.mark.parametrize("kwargs, match", [
    (dict(sweeps=0), "number of sweeps must be an integer >= 1, got 0"),
    (dict(sweeps=10, burn_in=10), r"burn-in must be an integer between 0 and 9 \(sweeps - 1\), got 10"),
    (dict(sweeps=10, chains=0), "number of chains must be an integer >= 1, got 0"),
    (dict(sweeps=10, burn_in=7, chains=2), "at least 4 sweeps after the burn-in, got 3"),
])
def test_run_inference_refuses_bad_settings(kwargs, match):
    with pytest.raises(BayesmapError, match=match):
        run_inference(room_scans("normal"), "block", **kwargs)


def test_both_drivers_share_the_scene_part_of_the_summary():
    """run_inference and run_logodds report the scene alike (scene_summary): same keys and values for the source,
    beams, scans, grid, max distance and truth; only the model's settings and the run's results differ."""
    pb = room_scans("normal")
    gibbs = run_inference(pb, "block", 6).summary
    logodds = run_logodds(pb).summary
    for key in ("source", "num_angles", "num_scans", "num_beams", "grid", "max_distance", "visible_cells"):
        assert gibbs[key] == logodds[key], key
    assert logodds["num_beams"] == 72 and logodds["grid"]["shape"] == [12, 9]
    assert "prior_wall_prob" in gibbs and "prior_wall_prob" not in logodds
    assert list(gibbs)[:9] == ["source", "sampler", "sampler_description", "sweeps", "burn_in", "seed", "chains",
                               "init", "prior_wall_prob"]
    alone = scene_summary(pb, {"method": "x"}, {"runtime_s": 1.0}, pb.truth, model=False)
    assert list(alone)[:2] == ["source", "method"] and alone["wrong_visible_cells"] == 0
    assert "max_range_readings" not in alone
    assert scene_summary(pb, {}, {}, pb.truth, model=True)["max_range_readings"] == int(pb.max_range_mask.sum())


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


def test_infer_whole_log_logodds_and_rosmap(small_log, tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--log", small_log, "--resolution", 0.2, "--sweeps", 6,
                             "--sampler", "chromatic", "--rosmap", "--report", "--out", tmp_path / "g")
    assert code in (0, None), err
    report = (tmp_path / "g" / "report.html").read_text()
    assert 'id="fig-posterior"' in report and 'id="fig-convergence"' in report and "axes in m" in report
    assert 'id="fig-importance"' not in report  # importance sampling is the single-scan tutorial's
    summary = json.loads((tmp_path / "g" / "summary.json").read_text())
    assert summary["num_scans"] == 12 and summary["num_beams"] == 12 * 180 and summary["beam_model"] == "beam"
    assert summary["prior_wall_prob"] == scenes.LOG_STRUCTURED_PRIOR and "12 scans" in out  # (the structured prior's)
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


def test_fast_samplers_refuse_problems_too_large_for_memory(monkeypatch):
    import bayesmap.inference.registry as registry

    pb = room_scans("normal")
    monkeypatch.setattr(registry, "MAX_FAST_PAIRS", pb.table.num_pairs - 1)
    with pytest.raises(BayesmapError, match=f"{pb.table.num_pairs:,} \\(beam, cell\\) pairs.*--sampler cellwise"):
        run_inference(pb, "chromatic", 4)
    assert run_inference(pb, "cellwise", 4).samples.shape == (4, 12, 9)  # no limit
    monkeypatch.setattr(registry, "MAX_FAST_PAIRS", pb.table.num_pairs)
    assert run_inference(pb, "chromatic", 4).samples.shape == (4, 12, 9)


def test_cellwise_chains_run_one_after_another_with_the_keys_of_chains_at_once(monkeypatch):
    """Several cellwise chains of one scan run one by one (vmap would turn their conditional writes into always-run
    selects); chain c gets the keys it would get at once, so the samples equal those of the vmap path, and progress
    reaches the total of all chains (one stage, reported at its start and after every chunk of 10 sweeps)."""
    import bayesmap.inference.driver as driver
    from bayesmap.scenes import tutorial_problem

    pb = tutorial_problem(num_angles=40)
    seen = []
    one_by_one = run_inference(pb, "cellwise", 20, chains=2, progress=seen.append)  # two chunks of 10 sweeps
    assert one_by_one.samples.shape == (2, 20, 21, 21)
    assert seen == [Progress("sweeps", done, 40, "sweep") for done in (0, 10, 20, 30, 40)]
    monkeypatch.setattr(driver, "SEQUENTIAL_CHAINS", ())
    seen.clear()
    at_once = run_inference(pb, "cellwise", 20, chains=2, progress=seen.append)
    assert [(p.done, p.total) for p in seen] == [(0, 20), (10, 20), (20, 20)]
    np.testing.assert_array_equal(one_by_one.samples, at_once.samples)
    assert not np.array_equal(one_by_one.samples[0], one_by_one.samples[1])


def test_progress_reports_do_not_change_the_chain():
    """The same seed with and without a progress callback: the same samples and posterior, bit for bit (reporting
    only reads the chunks' results); 25 sweeps are reported after chunks of 10, 10 and 5."""
    from bayesmap.scenes import tutorial_problem

    pb = tutorial_problem(num_angles=40)
    seen = []
    reported = run_inference(pb, "cellwise", 25, seed=3, progress=seen.append)
    silent = run_inference(pb, "cellwise", 25, seed=3)
    np.testing.assert_array_equal(reported.samples, silent.samples)
    np.testing.assert_array_equal(reported.posterior, silent.posterior)
    assert [p.done for p in seen] == [0, 10, 20, 25] and {(p.stage, p.total) for p in seen} == {("sweeps", 25)}


def test_cellwise_chains_of_a_log_are_tiled_map_chains_from_the_logodds_start():
    """On several scans the cellwise sampler runs :func:`tiled_map_chain` (whole table within the budget, tiles
    beyond), chain c with key c of the seed's key, from the log-odds start; progress counts the sweeps of every
    chain in one stage up to their total; the summary names the tiles. Without a callback the chains are the
    same, bit for bit."""
    import jax
    import jax.numpy as jnp

    from bayesmap.inference.tiled import tiled_map_chain

    pb = room_scans("beam")
    seen = []
    result = run_inference(pb, "cellwise", 12, seed=3, chains=2, progress=seen.append)
    assert result.samples.shape == (2, 12, 12, 9) and result.summary["tiles"] == 1
    dones = [p.done for p in seen]
    assert {(p.stage, p.total) for p in seen} == {("sweeps", 24)} and dones == sorted(dones) and dones[-1] == 24
    start = jnp.asarray(run_logodds(pb).posterior > 0.5, jnp.float32)
    for c, key in enumerate(jax.random.split(jax.random.key(3), 2)):
        chain = tiled_map_chain(key, pb.params, pb.ray_origins, pb.ray_angles, pb.model_ray_readings, start, 12,
                                pb.likelihood_power)
        np.testing.assert_array_equal(result.samples[c], chain.samples)
    silent = run_inference(pb, "cellwise", 12, seed=3, chains=2)
    np.testing.assert_array_equal(result.samples, silent.samples)
    np.testing.assert_array_equal(result.posterior, silent.posterior)
    tiled = run_inference(pb, "cellwise", 12, seed=3, tile_pairs=result.summary["ray_cell_pairs"] // 2)
    assert tiled.summary["tiles"] >= 2 and tiled.samples.shape == (12, 12, 9)
    with pytest.raises(BayesmapError, match="pairs per tile must be an integer >= 1, got 0"):
        run_inference(pb, "cellwise", 12, tile_pairs=0)


def test_beam_weights_reach_the_model_and_the_summary(tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--beam-model", "beam", "--beam-weights", "0.7,0.1,0.1,0.1",
                             "--lambda-short", "0.3", "--sweeps", 4, "--out", tmp_path / "o")
    assert code in (0, None), err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["beam_model"] == "beam"
    assert ([summary[k] for k in ("z_hit", "z_short", "z_max", "z_rand", "lambda_short")]
            == pytest.approx([0.7, 0.1, 0.1, 0.1, 0.3]))


def test_likelihood_power_in_the_summary_and_refused_by_reference_samplers(small_log):
    """The log's tempered target is recorded in the summary; the reference samplers (which sample the plain
    posterior through assess) refuse it with the value named."""
    from bayesmap.inference.registry import make_sampler
    from bayesmap.io.carmen import read_carmen
    from bayesmap.scenes import log_problem

    log = read_carmen(small_log)
    with pytest.raises(BayesmapError, match=r"likelihood power 0\.1\)"):
        make_sampler(log_problem(log, resolution=0.2, likelihood_power=0.1), "reference-raster")
    problem = log_problem(log, resolution=0.2)
    summary = run_inference(problem, "cellwise", 4).summary
    assert summary["likelihood_power"] == problem.likelihood_power < 1
    assert summary["posterior_estimate"] == "rao-blackwellized"
