"""The multi-scan model (one map, S scans from their own poses) and the fast kernel on it, for both sensor models.

The model's ``assess`` is the source of truth: the multi-scan score is checked against the single-scan model and an
independent sum of per-beam log-densities, then the fast kernel's conditionals against brute-force differences of
the multi-scan ``assess``."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import sensor_distances
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.fast import FastGibbs
from bayesmap.inference.schedules import block_configurations
from bayesmap.model.generative import (
    choices,
    full_model,
    log_joint_scans,
    make_params,
    model_args,
    multi_scan_model,
    prior_log_odds,
    reading_log_likelihood,
    scan_args,
)
from helpers import POSES, assess_block_log_joints, beam_enumeration_scene, scenes, sweeps_keep_ray_bits


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_one_scan_is_the_full_model(beam_model):
    """With S = 1 the multi-scan model scores exactly like the tutorial's full_model (float32, same computation:
    relative 1e-6)."""
    _, params, angles, truth, y, _ = scenes(beam_model, 0)
    one = multi_scan_model.assess(choices(truth, y[:1]), scan_args(POSES[0], params, angles[0]))[0]
    full = full_model.assess(choices(truth, y[0]), model_args(POSES[0], params, angles[0]))[0]
    assert float(one) == pytest.approx(float(full), rel=1e-6)
    assert float(log_joint_scans(truth, y[:1], POSES[:1], params, angles[:1])) == pytest.approx(float(full), rel=1e-6)


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
@pytest.mark.parametrize("seed", range(3))
def test_multi_scan_is_prior_plus_each_scan(beam_model, seed):
    """log_joint_scans == sum over scans of full_model.assess minus the (S - 1) repeated prior terms, and == prior +
    sum of per-beam log-densities at the exact distances (sensor_distances + sensor.py, not the model). Float64:
    absolute 1e-9 on totals of ~100 (sums of 30 terms in different orders)."""
    with enable_x64():
        _, params, angles, _, y, _ = scenes(beam_model, seed)
        rng = np.random.default_rng(100 + seed)
        walls = (rng.random(params.grid.shape) < 0.4).astype(np.float64)
        got = float(log_joint_scans(walls, y, POSES, params, angles))
        p = params.prior_wall_prob
        prior = float(np.sum(np.where(walls > 0, np.log(p), np.log1p(-p))))
        # jit: the parameters enter as float64 arrays (TFP would turn a concrete Python float into float32)
        assess = jax.jit(lambda w, ys, a: full_model.assess(choices(w, ys), a)[0])
        per_scan = [float(assess(walls, y[s], model_args(POSES[s], params, angles[s]))) for s in range(len(POSES))]
        assert got == pytest.approx(sum(per_scan) - (len(POSES) - 1) * prior, abs=1e-9)
        d = np.stack([np.asarray(sensor_distances(walls, POSES[s], angles[s], params.grid, params.max_range))
                      for s in range(len(POSES))])
        lik = float(np.sum(np.asarray(reading_log_likelihood(y, d, params))))
        assert got == pytest.approx(prior + lik, abs=1e-9)
        assert np.any(y == params.max_range) and np.any(d == params.max_range) and np.any(d < params.max_range)


def test_scan_args_check_shapes():
    params = make_params(grid=Grid((6, 7)))
    with pytest.raises(BayesmapError, match="poses"):
        scan_args(np.zeros((3, 3)), params, np.zeros((3, 5)))
    with pytest.raises(BayesmapError, match="beam_angles"):
        scan_args(POSES, params, np.zeros((2, 5)))
    with pytest.raises(BayesmapError, match="readings"):
        log_joint_scans(np.zeros((6, 7)), np.zeros((3, 4)), POSES, params, np.zeros((3, 5)))


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
@pytest.mark.parametrize("block_size", [1, 2])
def test_fast_conditionals_match_the_multi_scan_model(beam_model, block_size):
    """3 scans from different poses in one ray table, readings from the model with max-range readings set exactly
    to the max range (6 m: some walls lie beyond it, some rays have no wall within it): for random maps, every
    block's log-weights (single cells: log-odds) from the fast kernel equal the brute-force differences of the
    multi-scan model's assess over all the block's configurations.

    Tolerance 1e-4 (as tests/test_fast_exact.py): both sides run in float64 with the same geometry arithmetic,
    except that the model's prior is computed by TFP's Bernoulli in float32 even under x64 (the probability enters
    as a weakly typed float), so its sum over the 42 cells carries up to ~42 * 1.2 * 6e-8 = 3e-6 of rounding; a
    wrong sensor term (a missing normalizer, a point mass mistaken for a density) changes the differences by
    >= 1e-2."""
    with enable_x64():
        grid, params, angles, _, y, table = scenes(beam_model, 7)
        fast = FastGibbs(table, y.reshape(-1), params, block_size=block_size)
        configs = block_configurations(fast.blocks.shape[1])  # (C, B)

        brute = assess_block_log_joints(grid, params, angles, y, fast.blocks, configs)  # (NB, C)

        rng = np.random.default_rng(3)
        is_max = y.reshape(-1) == params.max_range
        max_hit_wall = max_no_wall = False
        for trial in range(3):
            walls = (rng.random(grid.shape) < [0.15, 0.35, 0.6][trial]).astype(np.float64)
            got = np.asarray(fast.block_log_weights(walls))
            want = np.asarray(brute(jnp.asarray(walls)))
            assert got.shape == want.shape == (len(fast.blocks), 2 ** block_size ** 2)
            np.testing.assert_allclose(got - got[:, :1], want - want[:, :1], atol=1e-4, rtol=0)
            if beam_model != "normal":  # the kernel looks the beam's log p(y | d) up; evaluated in the step instead,
                # the scores are the same up to float64 rounding (same function, same inputs)
                single = fast._single._replace(stop_ll=None, max_ll=None)
                bits = fast.ray_bits(walls)
                evaluated = np.asarray(
                    jax.vmap(lambda lv: fast.kernel._level_scores(bits[lv.src], lv)[0])(single))[:, 0]
                evaluated = np.stack([np.zeros_like(evaluated), evaluated], -1) if evaluated.ndim == 1 else evaluated
                np.testing.assert_allclose(evaluated - evaluated[:, :1], got - got[:, :1], atol=1e-9, rtol=0)
            d = table.first_wall_distances(walls)
            max_hit_wall |= bool(np.any(is_max & (d < params.max_range)))
            max_no_wall |= bool(np.any(is_max & (d == params.max_range)))
            assert np.ptp(want - want[:, :1]) > 1.0  # the data are informative: the comparison can fail
        # the max-range readings are exercised: some of their rays meet a wall within range, some do not
        assert max_hit_wall and max_no_wall


@pytest.mark.parametrize("block_size", [1, 2])
def test_fast_tempered_conditionals(block_size):
    """With a likelihood power eta the fast kernel's block log-weights are eta times the posterior's plus (1 - eta)
    times the prior's (relative to the empty configuration; the posterior's are checked against assess above).
    Float32, weights of size ~10: tolerance 1e-4."""
    grid, params, angles, _, y, table = scenes("beam", 7)
    plain = FastGibbs(table, y.reshape(-1), params, block_size=block_size)
    tempered = FastGibbs(table, y.reshape(-1), params, block_size=block_size, likelihood_power=0.25)
    configs = block_configurations(block_size ** 2)
    p = params.prior_wall_prob
    log_prior = configs.sum(axis=1) * prior_log_odds(p)  # relative to no wall in the block
    walls = (np.random.default_rng(5).random(grid.shape) < 0.3).astype(np.float32)
    base = np.asarray(plain.block_log_weights(walls), np.float64)
    got = np.asarray(tempered.block_log_weights(walls), np.float64)
    want = 0.25 * (base - base[:, :1]) + 0.75 * log_prior[None, :]
    np.testing.assert_allclose(got - got[:, :1], want, atol=1e-4, rtol=0)
    assert np.abs(want - (base - base[:, :1])).max() > 1.0


def test_beam_kernel_parameters_are_array_leaves_and_the_sweep_runs():
    """Other mixture weights give a kernel of the same tree structure (no recompilation); a few beam-model sweeps
    keep the state's ray bits equal to those recomputed from the map and move the chain."""
    grid, params, angles, _, y, table = scenes("beam", 1)
    other = make_params(0.2, 0.3, params.num_angles, grid, params.max_range, beam_model="beam", z_hit=0.7, z_short=0.1,
                        z_max=0.1, z_rand=0.1, lambda_short=0.3)
    a = FastGibbs(table, y.reshape(-1), params, block_size=2)
    b = FastGibbs(table, y.reshape(-1), other, block_size=2)
    assert jax.tree_util.tree_structure(a.kernel) == jax.tree_util.tree_structure(b.kernel)
    normal = FastGibbs(table, y.reshape(-1), make_params(0.3, 0.4, params.num_angles, grid, params.max_range),
                       block_size=2)
    assert jax.tree_util.tree_structure(normal.kernel) != jax.tree_util.tree_structure(a.kernel)  # static choice
    assert sweeps_keep_ray_bits(a, a.init(jnp.zeros(grid.shape, jnp.float32)), 3) > 0


def test_beam_kernel_needs_the_models_max_range():
    grid, params, angles, _, y, _ = scenes("beam", 2)
    table = build_ray_table(grid, np.repeat(POSES, angles.shape[1], axis=0), angles.reshape(-1), params.max_range + 1.0)
    with pytest.raises(BayesmapError, match="max range"):
        FastGibbs(table, y.reshape(-1), params)


@pytest.mark.parametrize("block_size, capacity", [(1, 1), (2, None)])
def test_beam_sampler_matches_exact_enumeration(block_size, capacity):
    """The whole sweep (not only its conditionals) with the beam model and two scans: 3 x 4 grid (4,096 maps
    enumerated with log_joint_scans), 2 poses x 6 beams, two readings at exactly the max range (4 m) and one short
    reading; 64 chains x 300 sweeps. Capacity 1 splits every level and draws blocks over several steps.

    Tolerance 0.06 as in tests/test_fast_exact.py::test_marginals_match_exact_enumeration (each marginal averages
    64 chains x 250 kept sweeps; its Monte Carlo standard error is <= 0.014)."""
    from bayesmap.inference.chains import run_chains

    table, y, params, exact = beam_enumeration_scene()
    fast = FastGibbs(table, y.reshape(-1), params, block_size=block_size, level_capacity=capacity)
    if capacity == 1:
        assert not np.all(np.asarray(fast._steps.commit))  # blocks drawn over several steps are exercised
    result = run_chains(jax.random.key(3), fast.algorithm, jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.samples[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.06, (est, exact)
    assert np.abs(exact - 0.3).max() > 0.3  # the data are informative: the test can fail
