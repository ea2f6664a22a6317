"""Many chains and per-cell diagnostics (split R-hat, effective sample size)."""

import json

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.inference.chains import cell_diagnostics
from bayesmap.inference.driver import run_inference


def test_diagnostics_of_independent_draws():
    """4 chains x 400 iid Bernoulli(0.3) draws per cell: R-hat is 1 and the ESS the number of draws, within the
    estimators' sampling error (a few percent for 1,600 iid draws; we allow 2 % on R-hat and 25 % on ESS)."""
    rng = np.random.default_rng(0)
    draws = rng.random((4, 400, 2, 3)) < 0.3
    diag = cell_diagnostics(draws)
    assert diag["r_hat"].shape == diag["ess"].shape == (2, 3)
    assert np.all(np.abs(diag["r_hat"] - 1) < 0.02)
    assert np.all((diag["ess"] > 0.75 * 1600) & (diag["ess"] < 1.25 * 1600))


def test_diagnostics_flag_chains_that_disagree_and_constant_cells():
    rng = np.random.default_rng(1)
    p = np.array([0.05, 0.95, 0.05, 0.95])[:, None, None, None]
    draws = rng.random((4, 200, 1, 2)) < p  # chains stuck in different modes
    draws[:, :, 0, 1] = True  # a cell that never changes
    diag = cell_diagnostics(draws)
    assert diag["r_hat"][0, 0] > 1.5 and diag["ess"][0, 0] < 100
    assert np.isnan(diag["r_hat"][0, 1])


def test_diagnostics_need_two_chains():
    with pytest.raises(BayesmapError, match="chains >= 2"):
        cell_diagnostics(np.zeros((1, 50, 2, 2)))


def test_tutorial_chains_agree(tutorial):
    """4 chains of fast 2x2 block Gibbs (100 sweeps, 50 kept) on the tutorial scene: every cell that changes has
    split R-hat below 1.1 (the usual threshold; Vehtari et al. 2021 recommend 1.01 for final results, which
    needs longer chains), and the chains' joint posterior mean is as accurate as one chain's."""
    result = run_inference(tutorial, "block", sweeps=100, chains=4)
    assert result.samples.shape == (4, 100, 21, 21)
    assert result.summary["r_hat_max"] < 1.1
    assert result.summary["ess_min"] > 20
    assert result.summary["wrong_visible_cells"] <= 2


def test_cli_chains_write_diagnostics(tmp_path, monkeypatch, capsys):
    from helpers import run_cli

    code, out, err = run_cli(monkeypatch, capsys, "infer", "--sweeps", 10, "--chains", 3, "--sampler", "outward",
                             "--out", tmp_path / "out")
    assert code in (0, None), err
    with np.load(tmp_path / "out" / "diagnostics.npz") as diag:
        assert diag["r_hat"].shape == diag["ess"].shape == (21, 21)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["chains"] == 3 and summary["r_hat_max"] >= 1.0
    assert "R-hat" in out
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--sweeps", 5, "--chains", 2, "--out", tmp_path / "o2")
    assert code == 2 and "at least 4 sweeps" in err and not (tmp_path / "o2").exists()


def test_new_readings_prior_and_noise_reuse_the_compiled_sweep():
    """A sampler's arrays are arguments of the compiled chain: a problem with the same geometry but other readings,
    prior or noise runs without compiling again (what the app needs); another sensor position compiles anew."""
    import jax
    import jax.numpy as jnp

    from bayesmap.inference.chains import compiled_chain_count, run_chain_from
    from bayesmap.inference.registry import make_sampler
    from bayesmap.scenes import tutorial_problem

    def run(problem):
        algorithm = make_sampler(problem, "block")
        samples, _, _ = run_chain_from(jax.random.key(0), algorithm.init(jnp.zeros(problem.grid.shape)), algorithm, 7)
        return np.asarray(samples)

    first = run(tutorial_problem(seed=3))
    size = compiled_chain_count()
    second = run(tutorial_problem(seed=4, prior_wall_prob=0.2, sensor_noise=0.3))
    assert compiled_chain_count() == size  # no new compilation
    assert not np.array_equal(first, second)  # and the new data were used
    run(tutorial_problem(seed=3, pos=(6.0, 12.0)))
    assert compiled_chain_count() == size + 1


def test_every_sampler_steps_to_state_and_info():
    """The BlackJAX contract, for every kind of sampler (fast levels, cellwise, reference, reference-incremental):
    ``step(key, state) -> (state, GibbsInfo)``; the state's ``walls`` is a 0/1 map of the grid's shape, only the
    cellwise sampler reports conditional wall probabilities (in [0, 1], the prior 0.3 for cells no ray crosses), and
    a chain's ``wall_probs`` are those of ``info``: the same step run by hand gives the chain's first sweep."""
    import jax
    import jax.numpy as jnp

    from bayesmap.geometry.grid import Grid
    from bayesmap.geometry.raytable import build_ray_table
    from bayesmap.inference.base import GibbsInfo
    from bayesmap.inference.cellwise import cellwise_gibbs
    from bayesmap.inference.chains import run_chain
    from bayesmap.inference.fast import fast_gibbs
    from bayesmap.inference.reference import reference_gibbs, reference_incremental_gibbs
    from bayesmap.model.generative import make_params

    grid = Grid((4, 5))
    params = make_params(0.3, 0.4, 6, grid)
    pos = np.array([1.3, 2.2])
    angles = np.linspace(0.0, 2 * np.pi, 6, endpoint=False) + 0.1
    y = np.array([1.0, 2.0, 0.7, 3.5, 1.2, 2.5])
    table = build_ray_table(grid, np.repeat(pos[None], 6, axis=0), angles, params.max_range)
    samplers = {"fast": fast_gibbs(table, y, params, block_size=2), "cellwise": cellwise_gibbs(table, y, params),
                "reference": reference_gibbs(y, pos, params, angles),
                "reference-incremental": reference_incremental_gibbs(y, pos, params, angles)}
    free = np.asarray(table.rays_per_cell()).reshape(grid.shape) == 0
    assert free.any()
    for name, algorithm in samplers.items():
        key = jax.random.split(jax.random.key(2), 3)[0]  # the chain's first sweep's key
        state, info = jax.jit(algorithm.step)(key, algorithm.init(jnp.zeros(grid.shape)))
        assert isinstance(info, GibbsInfo), name
        walls = np.asarray(state.walls)
        assert walls.shape == grid.shape and set(np.unique(walls)) <= {0.0, 1.0}, name
        chain = run_chain(jax.random.key(2), algorithm, jnp.zeros(grid.shape), 3)
        np.testing.assert_array_equal(np.asarray(chain.samples[0]), walls > 0, err_msg=name)
        if name != "cellwise":
            assert info.wall_prob is None and chain.wall_probs is None, name
            continue
        prob = np.asarray(info.wall_prob)
        assert prob.shape == grid.shape and prob.dtype == np.float32 and ((prob >= 0) & (prob <= 1)).all()
        np.testing.assert_allclose(prob[free], 0.3, rtol=1e-6)
        assert np.abs(prob[~free] - 0.3).max() > 0.1  # the readings moved the crossed cells
        assert np.asarray(chain.wall_probs).shape == (3,) + grid.shape
        np.testing.assert_allclose(np.asarray(chain.wall_probs[0]), prob, rtol=1e-6, atol=1e-7)


def test_a_chain_run_with_progress_is_the_chain_run_in_one_scan(tutorial):
    """A progress callback runs a chain one sweep per compiled call over the keys the whole chain uses: the same
    samples, conditional probabilities and final state, bit for bit, as one ``lax.scan`` (one chain from walls, and
    several at once from one state); one report before the first sweep and one after each; and every number of
    sweeps runs on the one compiled sweep (no compilation after the first run)."""
    import jax
    import jax.numpy as jnp

    from bayesmap.inference.chains import compiled_chain_count, run_chain, run_recorded_chains
    from bayesmap.inference.registry import make_sampler
    from bayesmap.progress import Progress

    algorithm = make_sampler(tutorial, "cellwise")
    walls = jnp.zeros(tutorial.grid.shape)
    seen = []
    pieces = run_chain(jax.random.key(4), algorithm, walls, 9, progress=seen.append, stage="map")
    whole = run_chain(jax.random.key(4), algorithm, walls, 9)
    np.testing.assert_array_equal(pieces.samples, whole.samples)
    np.testing.assert_array_equal(pieces.wall_probs, whole.wall_probs)
    np.testing.assert_array_equal(pieces.final_state.walls, whole.final_state.walls)
    assert seen == [Progress("map", done, 9, "sweep") for done in range(10)]

    def record(state, info):  # what a caller of run_recorded_chains keeps: the map and the probabilities
        return state.walls, info.wall_prob

    state = algorithm.init(walls)
    seen.clear()
    several = run_recorded_chains(jax.random.key(5), state, algorithm, 4, record, num_chains=3, progress=seen.append)
    at_once = run_recorded_chains(jax.random.key(5), state, algorithm, 4, record, num_chains=3)
    assert several[0].shape == (3, 4) + tutorial.grid.shape
    for got, want in zip(several, at_once):
        np.testing.assert_array_equal(got, want)
    assert [p.done for p in seen] == [0, 1, 2, 3, 4]
    size = compiled_chain_count()
    run_chain(jax.random.key(6), algorithm, walls, 13, progress=seen.append)
    assert compiled_chain_count() == size


@pytest.mark.parametrize("reported", [False, True])
def test_a_chain_compiled_ahead_runs_without_compiling_again(reported, caplog):
    """``compile_recorded_chain`` compiles the program ``run_recorded_chains`` then runs (with a progress callback,
    one sweep per call; without, the whole chain): the run compiles nothing of its own (JAX's compile log) and
    records what a run compiled on the spot records, to the bit. A pose kernel, as ``run_log_slam`` compiles its
    pose block on another thread."""
    import logging

    import jax
    import jax.numpy as jnp

    from bayesmap.inference.chains import compile_recorded_chain, run_recorded_chains
    from bayesmap.slam.poses import random_walk_pose_mh, slam_data
    from bayesmap.slam.problem import slam_tutorial_problem

    def record(state, info):
        return state.poses, info.accepted

    problem = slam_tutorial_problem(seed=3, num_poses=5)
    increments, covs = problem.motion_steps()
    kernel = random_walk_pose_mh(slam_data(increments, covs, problem.sensor_angles, problem.readings,
                                           problem.params))
    state = kernel.init(jnp.asarray(problem.odometry), jnp.asarray(problem.truth, jnp.float32))
    progress = (lambda p: None) if reported else None
    jax.clear_caches()
    fresh = run_recorded_chains(jax.random.key(1), state, kernel, 6, record, progress=progress)
    jax.clear_caches()
    compile_recorded_chain(jax.random.key(0), state, kernel, 6, record, reported)
    caplog.set_level(logging.WARNING)
    with jax.log_compiles(True):
        ahead = run_recorded_chains(jax.random.key(1), state, kernel, 6, record, progress=progress)
    compiled = [r.getMessage() for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
    assert not any("_sweeps_jit" in m or "_run_jit" in m for m in compiled), compiled
    for a, b in zip(ahead, fresh, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
