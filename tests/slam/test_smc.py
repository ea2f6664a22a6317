"""Resample-move SMC over paths and maps (bayesmap.slam.smc) and the per-scan powers it moves with."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import logsumexp

from bayesmap.errors import BayesmapError
from bayesmap.model import motion
from bayesmap.model.generative import check_scan_powers
from bayesmap.slam.joint import slam_kernel
from bayesmap.slam.poses import discrete_pose_gibbs, slam_data
from bayesmap.slam.smc import TARGET_ESS, prior_particles, run_smc, scan_schedule, slam_smc
from helpers import exact_slam_log_joint, tiny_slam_problem

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)


def tiny_smc(substeps=1, num_moves=1):
    params, inc, cov, candidates, angles, y = tiny_slam_problem()
    data = slam_data(inc, cov, angles, y, params)
    algorithm = slam_smc(data, lambda powers: slam_kernel(data, discrete_pose_gibbs(data, candidates, powers), powers),
                         scan_schedule(3, 1.0, substeps), num_moves=num_moves)
    return params, inc, cov, candidates, angles, y, algorithm


def candidate_particles(key, algorithm, num, cands, params, inc, cov):
    """``num`` particles of the tiny problem for ``algorithm.init``: candidate paths drawn uniformly (9 paths), each
    weighted by the motion model's density over that uniform draw, and maps drawn from the prior (weight 1)."""
    k_pose, k_walls = jax.random.split(key)
    idx = jax.random.randint(k_pose, (num, 2), 0, 3)
    poses = jnp.stack([jnp.broadcast_to(cands[0, 0], (num, 3)), cands[1, idx[:, 0]], cands[2, idx[:, 1]]], 1)
    walls = jax.random.bernoulli(k_walls, params.prior_wall_prob, (num, *params.grid.shape))
    prior = jax.vmap(lambda p: motion.path_logpdf(p, cands[0, 0], inc, cov))(poses)
    return algorithm.init(poses, walls, prior + math.log(9.0))


def test_smc_is_unbiased_for_the_evidence_and_the_posterior_against_enumeration():
    """200 independent runs of 24 particles on the tiny problem of the joint chain's test (3 scans, poses 1 and 2 on
    3 candidates each, 64 maps). Each run starts from uniform candidate paths weighted by the motion model and maps
    drawn from the prior. Two exact properties of SMC (Del Moral 2004): ``E[Z_hat] = Z`` and ``E[Z_hat sum_i W_i
    f(x_i)] = Z E_pi[f]``, with ``Z`` and ``E_pi`` from the model's assess over the 576 joint states. Each is a mean of
    200 independent terms, checked to 5 standard errors (their standard deviation / sqrt(200)) plus the estimate's
    resolution, 1 / (200 * 24): no allowance for bias is needed, because there is none. A wrong incremental weight,
    a move at the wrong powers (one that does not leave the stage's target invariant) or a biased resampling would
    break them (moving at the last target's powers from the first stage on: mean Z_hat / Z 1.62, where 5 standard
    errors allow 1 +- 0.25)."""
    params, inc, cov, candidates, angles, y, algorithm = tiny_smc()
    logp, maps = exact_slam_log_joint(params, inc, cov, candidates, angles, y)
    log_z = logsumexp(logp)
    prob = np.exp(logp - log_z)
    exact = np.concatenate([prob.sum(axis=(1, 2)), prob.sum(axis=(0, 2)),
                            np.tensordot(prob.sum(axis=(0, 1)), maps, axes=1).reshape(-1)])
    assert 0.05 < exact[:6].min() and np.sum((exact[6:] > 0.1) & (exact[6:] < 0.9)) >= 2  # a sharp test
    cands = jnp.asarray(candidates, jnp.result_type(float))
    num, runs = 24, 200

    def one(key):
        k_init, k_run = jax.random.split(key)
        state, info = run_smc(k_run, algorithm, candidate_particles(k_init, algorithm, num, cands, params, inc, cov), 3)
        w = jnp.exp(state.log_weights)
        which = jnp.all(state.poses[:, 1:, None, :] == cands[None, 1:], axis=-1)  # (N, 2, 3) one-hot
        est = jnp.concatenate([w @ which[:, 0], w @ which[:, 1], w @ state.walls.reshape(num, -1)])
        return state.log_evidence, est, info.resampled

    log_ev, est, resampled = (np.asarray(a, np.float64) for a in
                              jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(0), runs)))
    assert resampled.mean() > 0.1  # the runs do resample: the test covers it
    ratio = np.exp(log_ev - log_z)
    assert abs(ratio.mean() - 1.0) < 5 * ratio.std() / math.sqrt(runs), (ratio.mean(), ratio.std())
    weighted = ratio[:, None] * est
    se = weighted.std(0) / math.sqrt(runs)
    resolution = 1.0 / (runs * num)  # a marginal below it may be held by no particle of any run (one cell: 6e-5)
    assert np.all(np.abs(weighted.mean(0) - exact) < 5 * se + resolution), (weighted.mean(0), exact, se)
    # and the self-normalized estimates are close too (bias O(1 / N)): within 0.05 of every exact marginal
    assert np.abs(est.mean(0) - exact).max() < 0.05


def test_the_adaptive_schedule_keeps_the_effective_sample_size_and_finds_the_posterior():
    """The adaptive schedule on the tiny problem: every stage's reweighting leaves at least TARGET_ESS of the 24
    particles' effective sample size (to the bisection's tolerance), every run reaches the posterior, and the
    self-normalized marginals of 100 runs are within 0.05 of enumeration (the fixed schedule's bound)."""
    params, inc, cov, candidates, angles, y = tiny_slam_problem()
    data = slam_data(inc, cov, angles, y, params)
    algorithm = slam_smc(data, lambda powers: slam_kernel(data, discrete_pose_gibbs(data, candidates, powers), powers))
    logp, maps = exact_slam_log_joint(params, inc, cov, candidates, angles, y)
    prob = np.exp(logp - logsumexp(logp))
    exact = np.concatenate([prob.sum(axis=(1, 2)), prob.sum(axis=(0, 2))])
    cands = jnp.asarray(candidates, jnp.result_type(float))
    num, runs, max_stages = 24, 100, 60

    def one(key):
        k_init, k_run = jax.random.split(key)
        initial = candidate_particles(k_init, algorithm, num, cands, params, inc, cov)
        state, info = run_smc(k_run, algorithm, initial, max_stages)
        which = jnp.all(state.poses[:, 1:, None, :] == cands[None, 1:], axis=-1)
        w = jnp.exp(state.log_weights)
        return state.done, state.stage, state.powers, info.ess, jnp.concatenate([w @ which[:, 0], w @ which[:, 1]])

    done, stages, powers, ess, est = (np.asarray(a) for a in
                                      jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(4), runs)))
    assert done.all() and np.all(powers == 1.0) and stages.max() < max_stages
    assert stages.min() > 3  # the scans are too informative for one stage each: the schedule did adapt
    ran = np.arange(max_stages)[None, :] < stages[:, None]
    assert np.all(ess[ran] >= TARGET_ESS * num * (1 - 1e-3))
    assert np.abs(est.mean(0) - exact).max() < 0.05, (est.mean(0), exact)


def test_prior_particles_draw_the_motion_model_and_the_prior_map():
    params, inc, cov, candidates, angles, y = tiny_slam_problem()
    data = slam_data(inc, cov, angles, y, params)
    poses, walls = prior_particles(jax.random.key(1), candidates[0, 0], data, 4000)
    assert poses.shape == (4000, 3, 3) and walls.shape == (4000, *params.grid.shape)
    np.testing.assert_array_equal(np.asarray(poses[:, 0]), np.broadcast_to(candidates[0, 0], (4000, 3)))
    # the walls are Bernoulli(prior) per cell: within 5 binomial standard errors
    p = params.prior_wall_prob
    assert abs(float(walls.mean()) - p) < 5 * math.sqrt(p * (1 - p) / walls.size)
    # the first step's error has the motion model's covariance: its empirical covariance within 10 % on the diagonal
    err = np.asarray(jax.vmap(motion.motion_error, in_axes=(None, 0, None))(jnp.asarray(candidates[0, 0]),
                                                                           poses[:, 1], jnp.asarray(inc[0])))
    np.testing.assert_allclose(np.diag(np.cov(err.T)), np.diag(cov[0]), rtol=0.1)


def test_per_scan_powers_equal_to_one_power_give_the_same_chain():
    """The pose kernel and the map sweep with every scan at eta draw the same states as with eta itself."""
    params, inc, cov, candidates, angles, y = tiny_slam_problem()
    data = slam_data(inc, cov, angles, y, params)
    start = jnp.asarray(candidates[:, 0]), jnp.zeros(params.grid.shape)
    runs = []
    for power in (0.3, np.full(3, 0.3)):
        kernel = slam_kernel(data, discrete_pose_gibbs(data, candidates, power), power)
        steps = jax.jit(lambda state: jax.lax.scan(lambda st, k: (kernel.step(k, st)[0], None), state,  # noqa: B023
                                                   jax.random.split(jax.random.key(2), 4))[0])
        runs.append(steps(kernel.init(*start)))
    np.testing.assert_array_equal(np.asarray(runs[0].poses), np.asarray(runs[1].poses))
    np.testing.assert_array_equal(np.asarray(runs[0].walls), np.asarray(runs[1].walls))
    assert not np.array_equal(np.asarray(runs[0].poses), np.asarray(candidates[:, 0]))  # the chain did move


def test_scan_schedule_adds_one_scan_at_a_time():
    np.testing.assert_allclose(scan_schedule(3, 0.5), [[0.5, 0, 0], [0.5, 0.5, 0], [0.5, 0.5, 0.5]])
    np.testing.assert_allclose(scan_schedule(2, 1.0, 2), [[0.5, 0], [1, 0], [1, 0.5], [1, 1]])


@pytest.mark.parametrize("powers", [np.array([0.5, 1.2, 0.0]), np.array([0.5, 0.5]), np.array([np.nan, 1, 1]), 0.0])
def test_bad_per_scan_powers_are_errors(powers):
    with pytest.raises(BayesmapError, match="power"):
        check_scan_powers(powers, 3)


def test_bad_schedules_and_counts_are_errors():
    params, inc, cov, candidates, angles, y, _ = tiny_smc()
    data = slam_data(inc, cov, angles, y, params)
    move = lambda powers: slam_kernel(data, discrete_pose_gibbs(data, candidates, powers), powers)  # noqa: E731
    for schedule in (np.ones((2, 4)), np.array([[1.0, 1, 1], [0.5, 1, 1]]), np.full((1, 3), 2.0)):
        with pytest.raises(BayesmapError, match="schedule"):
            slam_smc(data, move, schedule)
    with pytest.raises(BayesmapError, match="num_moves"):
        slam_smc(data, move, scan_schedule(3), num_moves=-1)
    with pytest.raises(BayesmapError, match="resample_ess"):
        slam_smc(data, move, scan_schedule(3), resample_ess=1.5)
    with pytest.raises(BayesmapError, match="target_ess"):
        slam_smc(data, move, None, target_ess=0.6, resample_ess=0.5)
    with pytest.raises(BayesmapError, match="target_ess"):
        slam_smc(data, move, None, target_ess=1.0)
    with pytest.raises(BayesmapError, match="substeps"):
        scan_schedule(3, 1.0, 0)
