"""The SLAM target at a path with the walls integrated out (bayesmap.slam.evidence)."""

import dataclasses
import math

import jax
import numpy as np
import pytest
from scipy.special import logsumexp

from bayesmap.errors import BayesmapError
from bayesmap.model.generative import replace_params
from bayesmap.model.motion import path_logpdf
from bayesmap.model.slam import log_joint_slam
from bayesmap.slam.evidence import drawn_map, map_entropy_bound, path_evidence, target_log_density
from bayesmap.slam.problem import SlamProblem, slam_tutorial_problem
from helpers import TINY_SLAM_ODOMETRY, exact_slam_log_joint, tiny_slam_problem

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)


def test_the_target_is_the_slam_models_assess_and_tempers_only_the_readings():
    """At power 1 the target's density is the SLAM model's assess (float32 sums of a few hundred terms: 1e-5
    relative); at power 0.25 only the readings' part is scaled. The bound with certain probabilities (the draw
    itself) is the target; a cell at one half adds its entropy, log 2, and the prior's expectation in place of the
    draw's value (2e-3: without x64 JAX sums the prior's 441 terms in float32, whose rounding at a sum near 300
    reaches 1e-3)."""
    problem = slam_tutorial_problem(seed=3, num_poses=4)
    params = problem.params
    rng = np.random.default_rng(0)
    path = problem.true_poses + np.concatenate([[[0.0, 0.0, 0.0]], rng.normal(0, 0.05, (3, 3))])
    path[:, 2] = np.unwrap(path[:, 2])  # as the target reads it (the tutorial's axis-aligned rays graze cell
    # corners, where a heading 2 pi apart rounds a few beams across a wall)
    walls = np.asarray(problem.truth, np.float32)
    increments, covs = problem.motion_steps()
    assess = float(log_joint_slam(path, walls, problem.readings, increments, covs, params, problem.sensor_angles))
    target, motion, readings = target_log_density(problem, params, path, walls)
    assert target == pytest.approx(assess, rel=1e-5, abs=1e-2)
    assert motion == pytest.approx(float(path_logpdf(path, path[0], increments, covs)), abs=1e-3)
    tempered = dataclasses.replace(problem, likelihood_power=0.25)
    target_t, _, readings_t = target_log_density(tempered, params, path, walls)
    assert readings_t == pytest.approx(0.25 * readings, rel=1e-6)
    assert target_t == pytest.approx(target - 0.75 * readings, rel=1e-5, abs=1e-2)
    assert map_entropy_bound(params, walls, target, walls) == pytest.approx(target, abs=2e-3)
    half = walls.astype(np.float64).copy()
    half[0, 0] = 0.5
    q = params.prior_wall_prob
    drawn = np.log(q) if walls[0, 0] > 0.5 else np.log1p(-q)
    expected_change = 0.5 * np.log(q) + 0.5 * np.log1p(-q) - drawn + np.log(2.0)
    assert map_entropy_bound(params, half, target, walls) == pytest.approx(target + expected_change, abs=2e-3)


@pytest.mark.parametrize("power, pass_prob", [(1.0, 0.0), (0.25, 0.0), (0.25, 0.05)])
def test_a_draws_readings_term_is_the_targets(power, pass_prob):
    """The readings' term a draw's sweep leaves (``TiledChain.readings_log_lik``, from its own table, float32 rows)
    is the target's (:func:`target_log_density`, a table of its own in float64) at the drawn walls, tempered or not,
    also where a beam can pass a wall cell: to float32 precision (1e-5 relative; the sum of some 300 rays)."""
    problem = dataclasses.replace(slam_tutorial_problem(seed=3, num_poses=4), likelihood_power=power)
    params = replace_params(problem.params, wall_pass_prob=pass_prob)
    path = problem.true_poses + np.concatenate([[[0.0, 0.0, 0.0]], np.full((3, 3), 0.02)])
    for key in range(3):
        chain = drawn_map(problem, params, path, jax.random.key(key), 3)
        _, _, readings = target_log_density(problem, params, path, chain.walls)
        assert chain.readings_log_lik == pytest.approx(readings, rel=1e-5, abs=1e-3)


def test_a_tiled_draw_is_scored_by_the_targets_own_table():
    """A draw swept a tile at a time has no one table to read its readings' term from
    (``readings_log_lik`` None): its bound then takes the target's (:func:`target_log_density` at its last walls)."""
    from bayesmap.slam.evidence import draw_evidence

    problem = slam_tutorial_problem(seed=3, num_poses=4)
    params = problem.params
    path = problem.true_poses + np.concatenate([[[0.0, 0.0, 0.0]], np.full((3, 3), 0.02)])
    whole = drawn_map(problem, params, path, jax.random.key(0), 3)
    tiled = drawn_map(problem, params, path, jax.random.key(0), 3, tile_pairs=4000)
    assert whole.readings_log_lik is not None and len(whole.tiles) == 1
    assert tiled.readings_log_lik is None and len(tiled.tiles) > 1
    walls = np.asarray(tiled.walls)
    probabilities = np.asarray(tiled.wall_probs, np.float64)[1:].mean(axis=0)
    target, _, _ = target_log_density(problem, params, path, walls)
    assert draw_evidence(problem, params, path, tiled) == pytest.approx(
        map_entropy_bound(params, probabilities, target, walls), rel=1e-12)


def tiny_problem():
    params, inc, cov, candidates, angles, y = tiny_slam_problem()
    problem = SlamProblem(params=params, motion=None, odometry=TINY_SLAM_ODOMETRY, sensor_angles=angles, readings=y,
                          steps=(inc, cov))
    return problem, params, inc, cov, candidates, angles, y


def test_the_bound_averaged_over_its_factorized_maps_is_below_the_exact_marginal():
    """On the tiny SLAM problem (3 scans, 6 cells: 64 maps), for a path and any factorized ``q``: the bound's
    expectation over maps drawn from ``q`` (every map weighed by ``q``) is ``E_q[log p(x, w, y)] + H(q)``, computed
    apart from the model's assess, and lies below the exact ``log sum_w p(x, w, y)`` (Jensen), equal where ``q`` is
    the exact posterior's marginals and the posterior factorizes, which it nearly does here (within 0.1 nats:
    0.01-0.08 at the nine paths)."""
    problem, params, inc, cov, candidates, angles, y = tiny_problem()
    logp, maps = exact_slam_log_joint(params, inc, cov, candidates, angles, y)
    flat = maps.reshape(len(maps), -1)
    for i, j in ((0, 0), (1, 2), (2, 1)):
        path = np.stack([candidates[0, 0], candidates[1, i], candidates[2, j]])
        exact = logsumexp(logp[i, j])
        posterior = np.exp(logp[i, j] - exact)
        marginals = (posterior @ flat).reshape(params.grid.shape)
        for q in (marginals, np.full(params.grid.shape, 0.3)):
            qf = q.reshape(-1)
            weight = np.prod(np.where(flat > 0.5, qf, 1 - qf), axis=1)
            bounds = np.array([map_entropy_bound(params, q, target_log_density(problem, params, path, w)[0], w)
                               for w in maps])
            entropy = -np.sum(qf * np.log(qf) + (1 - qf) * np.log1p(-qf))
            elbo = weight @ logp[i, j] + entropy
            assert weight @ bounds == pytest.approx(elbo, abs=1e-4)
            assert elbo <= exact + 1e-6
        qf = marginals.reshape(-1)
        weight = np.prod(np.where(flat > 0.5, qf, 1 - qf), axis=1)
        entropy = -np.sum(qf * np.log(qf) + (1 - qf) * np.log1p(-qf))
        assert weight @ logp[i, j] + entropy > exact - 0.1


def test_path_evidence_estimates_the_exact_marginal_of_the_tiny_problem():
    """``path_evidence`` at three paths of the tiny problem, 80 keys each (20 sweeps): its mean is the exact
    ``log sum_w p(x, w, y)`` (64 maps, the model's assess) within 4 standard errors of the mean plus 0.1 nats, the
    bound's gap at the exact marginals (previous test); the readings' term is one draw's, from the chain at the
    path, so the estimate scatters about it (a standard deviation near 1 nat)."""
    problem, params, inc, cov, candidates, angles, y = tiny_problem()
    logp, _ = exact_slam_log_joint(params, inc, cov, candidates, angles, y)
    keys = 80
    for i, j in ((0, 0), (1, 2), (2, 1)):
        path = np.stack([candidates[0, 0], candidates[1, i], candidates[2, j]])
        exact = logsumexp(logp[i, j])
        draws = np.array([path_evidence(jax.random.key(k), problem, params, path, 20)[0] for k in range(keys)])
        se = draws.std() / math.sqrt(keys)
        assert abs(draws.mean() - exact) < 4 * se + 0.1, (i, j, draws.mean(), exact, se)


def test_path_evidence_names_what_it_cannot_bound():
    problem, params, *_ = tiny_problem()
    path = np.asarray(TINY_SLAM_ODOMETRY)
    with pytest.raises(BayesmapError, match="sweeps >= 2, got 1"):
        path_evidence(jax.random.key(0), problem, params, path, 1)
    coupled = replace_params(params, coupling=0.5, neighbourhood=None)
    with pytest.raises(BayesmapError, match="independent prior, got coupling 0.5"):
        path_evidence(jax.random.key(0), problem, coupled, path, 4)
