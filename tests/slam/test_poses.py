"""Pose conditionals and pose kernels (bayesmap.slam.poses) against the SLAM model's assess and enumeration."""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.model import motion
from bayesmap.model.generative import make_params, simulate_scan_readings
from bayesmap.model.slam import slam_args, slam_choices, slam_model
from bayesmap.slam.poses import (
    composed_pose_kernels,
    discrete_pose_gibbs,
    lattice_offsets,
    lattice_pose_mh,
    moved_segment,
    pose_log_conditional,
    random_walk_pose_mh,
    scan_log_likelihood,
    segment_log_ratio,
    segment_pose_mh,
    slam_data,
)
from helpers import exact_slam_marginals

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)


# --- enumeration: joint marginals of poses and walls on a tiny problem ----------------------------------------------

TINY_GRID = Grid((3, 2))  # 6 unit cells: 2^6 maps
MAX_RANGE = 1.5  # meters: short, so that walls beyond a beam's reach stay uncertain
TINY_ODOMETRY = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, 0.3], [2.0, 0.0, 0.9]])
TINY_OFFSETS = np.array([[0.0, 0.0, 0.0], [0.15, -0.1, 0.15], [-0.1, 0.15, -0.15]])  # 3 candidates per pose


def tiny_problem():
    params = make_params(0.3, 0.5, 1, TINY_GRID, MAX_RANGE)
    inc, cov = motion.odometry_controls(TINY_ODOMETRY, motion.make_motion_params((0.2, 0.1, 0.2, 0.1), 0.25, 0.2))
    candidates = TINY_ODOMETRY[:, None, :] + TINY_OFFSETS[None]  # (3, 3, 3); row 0: pose 0 (fixed) repeated
    candidates[0] = TINY_ODOMETRY[0]
    angles = np.tile(np.array([-2.5, -0.9, 0.4, 1.9]), (3, 1))  # 4 beams, sensor frame
    truth_path = np.stack([candidates[0, 0], candidates[1, 1], candidates[2, 2]])
    truth = np.array([[0, 0], [0, 1], [0, 0]], np.float32)
    y = np.asarray(simulate_scan_readings(jax.random.key(7), truth, truth_path[:, :2], params,
                                          truth_path[:, 2:3] + angles), np.float64)
    return params, inc, cov, candidates, angles, y


def wall_sweep(params, inc, cov, angles, y):
    """A single-site Gibbs sweep over the walls given the poses, each cell's conditional from assess differences
    (the reference map kernel of this test: Gibbs over the walls given the poses)."""

    def log_joint(poses, walls):
        return slam_model.assess(slam_choices(poses, walls, y), slam_args(TINY_ODOMETRY[0], inc, cov, params,
                                                                          angles))[0]

    def sweep(key, poses, walls):
        keys = jax.random.split(key, walls.size)

        def update(c, w):
            flat = w.reshape(-1)
            lw = jnp.stack([log_joint(poses, flat.at[c].set(v).reshape(w.shape)) for v in (0.0, 1.0)])
            return flat.at[c].set(jax.random.categorical(keys[c], lw).astype(w.dtype)).reshape(w.shape)

        return jax.lax.fori_loop(0, walls.size, update, walls)

    return sweep


def test_gibbs_over_poses_and_walls_matches_enumeration():
    """Chains alternating discrete_pose_gibbs with a Gibbs sweep over the walls, against the exact joint marginals.

    2,000 independent chains of 60 sweeps from random starts (20 burn-in: the state space has 576 states and a
    sweep updates everything, so the chains forget their start in a few sweeps). Each chain's average over its last
    40 sweeps is one estimate; the chains are independent, so the standard error of the mean of the 2,000 estimates
    is their standard deviation / sqrt(2000) (this accounts for the autocorrelation within a chain). The tolerance
    is 5 standard errors plus 2e-3 (the burn-in's remaining bias, which decays geometrically): a wrong
    conditional (a missing motion factor, a wrong frame) moves these marginals by several percent."""
    params, inc, cov, candidates, angles, y = tiny_problem()
    p1, p2, pw = exact_slam_marginals(params, inc, cov, candidates, angles, y)
    # the test is only sharp if every candidate has real mass, the readings move the poses away from the motion
    # model's preference (the odometry's own candidate, 0) and some walls are uncertain
    assert 0.1 < p1.min() and 0.1 < p2.min() and p1.argmax() == 1
    assert np.sum((pw > 0.1) & (pw < 0.9)) >= 2
    data = slam_data(inc, cov, angles, y, params)
    poses_kernel = discrete_pose_gibbs(data, candidates)
    sweep = wall_sweep(params, inc, cov, angles, y)
    cands = jnp.asarray(candidates, jnp.result_type(float))
    num_chains, num_sweeps, burn_in = 2000, 60, 20

    def chain(key):
        k_init, k_walls, k_run = jax.random.split(key, 3)
        idx = jax.random.randint(k_init, (3,), 0, 3)
        walls = jax.random.bernoulli(k_walls, 0.5, TINY_GRID.shape).astype(jnp.float32)
        state = poses_kernel.init(cands[jnp.arange(3), idx], walls)

        def body(state, k):
            k_p, k_w = jax.random.split(k)
            state, _ = poses_kernel.step(k_p, state)
            state = state._replace(walls=sweep(k_w, state.poses, state.walls))
            which = jnp.all(state.poses[1:, None, :] == cands[1:], axis=-1)  # (2, 3) one-hot
            return state, (which.astype(jnp.float32), state.walls)

        _, (which, walls) = jax.lax.scan(body, state, jax.random.split(k_run, num_sweeps))
        return which[burn_in:].mean(0), walls[burn_in:].mean(0)

    which, walls = jax.jit(jax.vmap(chain))(jax.random.split(jax.random.key(0), num_chains))
    which, walls = np.asarray(which), np.asarray(walls)
    assert np.allclose(which.sum(-1), 1.0)  # every pose is always exactly one of its candidates
    for est, exact in ((which[:, 0], p1), (which[:, 1], p2), (walls, pw)):
        se = est.std(0) / np.sqrt(num_chains)
        assert np.all(np.abs(est.mean(0) - exact) < 5 * se + 2e-3), (est.mean(0), exact, se)


# --- lattice_pose_mh: the chain's pose marginal against the exact conditional ---------------------------------------


def lattice_problem():
    """Two scans on a 4 x 4 grid with a few walls: pose 0 fixed, pose 1 random (no t + 1 factor), 8 beams."""
    grid = Grid((4, 4))
    params = make_params(0.3, 0.3, 1, grid, 4.0)
    walls = np.zeros(grid.shape, np.float32)
    walls[3, :] = 1
    walls[:, 3] = 1
    walls[0, 1] = 1
    odometry = np.array([[0.5, 0.5, 0.0], [1.5, 1.5, 0.5]])
    inc, cov = motion.odometry_controls(odometry, motion.make_motion_params((0, 0, 0, 0), 0.15, 0.1))
    angles = np.tile(np.linspace(-np.pi, np.pi, 8, endpoint=False), (2, 1))
    truth = np.array([odometry[0], [1.62, 1.42, 0.58]])
    y = np.asarray(simulate_scan_readings(jax.random.key(1), walls, truth[:, :2], params, truth[:, 2:3] + angles))
    return slam_data(inc, cov, angles, y, params), odometry, walls


def run_pose_chains(kernel, start, walls, num_chains, num_sweeps, burn_in):
    """Pose 1 of ``num_chains`` independent chains, sweeps after ``burn_in``: ``(num_chains, kept, 3)``."""

    def chain(key):
        def body(state, k):
            state, info = kernel.step(k, state)
            return state, state.poses[1]

        return jax.lax.scan(body, kernel.init(start, walls), jax.random.split(key, num_sweeps))[1][burn_in:]

    return np.asarray(jax.jit(jax.vmap(chain))(jax.random.split(jax.random.key(3), num_chains)), np.float64)


def test_lattice_mh_fixed_lattice_matches_the_exact_conditional():
    """jitter = 0: the chain lives on x0 + the lattice (steps 0.1 m, 0.1 m, 0.1 rad), where its target is the
    conditional restricted to the lattice points. Exact: the conditional on the 13^3 lattice points within 6 steps of
    x0 (4 motion standard deviations; the test checks that the box's faces hold < 1e-3 of the mass), normalized.
    Compared: the 1-D marginals of the lattice index in x, y and theta. 400 independent chains x 30 sweeps after 10
    of burn-in (the conditional's standard deviation is about one lattice step and each sweep can move a step, so
    the chains forget their start in a few sweeps); the standard error of a probability is the standard deviation of
    the per-chain frequencies / sqrt(400) (independent chains, autocorrelation included; up to 0.009 here);
    tolerance 5 standard errors + 3e-3 (burn-in bias). Measured with keys 3 to 6, the largest error is under 0.45 of
    the tolerance, while accepting always (plain resampling in the window) moves the x marginal by 0.10, 3.6 to 4
    tolerances."""
    with enable_x64():
        data, odometry, walls = lattice_problem()
        h, half = 0.1, 6
        x0 = odometry[1]
        r = np.arange(-half, half + 1)
        idx = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
        logp = np.asarray(pose_log_conditional(1, x0 + h * idx, odometry, walls, data))
        prob = np.exp(logp - logp.max()).reshape(len(r), len(r), len(r))
        prob /= prob.sum()
        exact = [prob.sum(axis=(1, 2)), prob.sum(axis=(0, 2)), prob.sum(axis=(0, 1))]
        assert all(m[0] + m[-1] < 1e-3 for m in exact)
        assert lattice_offsets(h, h, 1).shape == (27, 3)
        kernel = lattice_pose_mh(data, h, h, half_width=1, jitter=0.0)
        poses = run_pose_chains(kernel, odometry, walls, 400, 40, 10)
        steps = (poses - x0) / h
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)  # on the lattice
        steps = np.round(steps).astype(int)
        for d in range(3):
            freq = (steps[..., d, None] == r).mean(axis=1)  # (chains, 13)
            se = freq.std(0) / np.sqrt(len(freq))
            assert np.all(np.abs(freq.mean(0) - exact[d]) < 5 * se + 3e-3), (d, freq.mean(0), exact[d], se)


@functools.cache
def lattice_moments():
    """:func:`conditional_moments` of :func:`lattice_problem` (in float64), computed once per process: the two
    continuous tests below share it (one xdist group)."""
    with enable_x64():
        return conditional_moments(*lattice_problem())


def conditional_moments(data, odometry, walls):
    """Mean and standard deviation ``(3,)`` of pose 1's exact conditional by quadrature on a 49^3 grid of step 0.025
    (m, m, rad) over +-0.6 around the odometry."""
    g = np.arange(-24, 25) * 0.025
    pts = odometry[1] + np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    logp = np.concatenate([np.asarray(pose_log_conditional(1, c, odometry, walls, data))
                           for c in np.array_split(pts, 8)])
    w = np.exp(logp - logp.max())
    w /= w.sum()
    mean = w @ pts
    return mean, np.sqrt(w @ (pts - mean) ** 2)


@pytest.mark.xdist_group("continuous_pose")
def test_lattice_mh_jittered_matches_the_continuous_conditional():
    """jitter = 0.5 (continuous poses): the chain's mean and standard deviation of pose 1 in x, y and theta against
    the exact conditional's, by quadrature on a 49^3 grid of step 0.025 (m, m, rad) over +-0.6 around the odometry
    (4 motion standard deviations). Quadrature error: the grid is 6 times finer than the smallest standard
    deviation; allowed 2e-3. Monte Carlo: 400 independent chains x 30 kept sweeps after 10 of burn-in (as the fixed
    lattice test), standard error of the mean of per-chain averages (about 0.002 m, 0.001 rad); tolerance 5 standard
    errors + 2e-3 (quadrature) for means, 20 % for standard deviations (their sampling error and the burn-in;
    measured within 3 % with keys 3 to 6)."""
    with enable_x64():
        data, odometry, walls = lattice_problem()
        mean, sd = lattice_moments()
        kernel = lattice_pose_mh(data, 0.1, 0.1, half_width=1, jitter=0.5)
        poses = run_pose_chains(kernel, odometry, walls, 400, 40, 10)
        per_chain = poses.mean(axis=1)
        se = per_chain.std(0) / np.sqrt(len(per_chain))
        assert np.all(np.abs(per_chain.mean(0) - mean) < 5 * se + 2e-3), (per_chain.mean(0), mean, se)
        np.testing.assert_allclose(poses.reshape(-1, 3).std(0), sd, rtol=0.2)
        assert len(np.unique(poses[:, -1, 0])) > 300  # continuous: the chains do not share a lattice


@pytest.mark.xdist_group("continuous_pose")
def test_random_walk_mh_matches_the_continuous_conditional():
    """Random-walk Metropolis (steps 0.1 m, 0.1 m, 0.1 rad) on the same problem and with the same quadrature and
    tolerances as the jittered lattice test above: 400 independent chains x 75 kept sweeps after 25 of burn-in (a
    random walk mixes more slowly than the 27-point window, so more sweeps), mean within 5 standard errors of the
    per-chain averages (about 0.002 m, 0.001 rad) + 2e-3, standard deviations within 20 % (measured within 4 % with
    keys 3 to 6). An acceptance ratio with a sign error or a missing motion factor moves the mean by several
    standard deviations of the conditional (0.06 to 0.1 each), many times the tolerance (about 0.012 m, 0.007
    rad)."""
    with enable_x64():
        data, odometry, walls = lattice_problem()
        mean, sd = lattice_moments()
        kernel = random_walk_pose_mh(data, (0.1, 0.1, 0.1))
        poses = run_pose_chains(kernel, odometry, walls, 400, 100, 25)
        per_chain = poses.mean(axis=1)
        se = per_chain.std(0) / np.sqrt(len(per_chain))
        assert np.all(np.abs(per_chain.mean(0) - mean) < 5 * se + 2e-3), (per_chain.mean(0), mean, se)
        np.testing.assert_allclose(poses.reshape(-1, 3).std(0), sd, rtol=0.2)


@pytest.mark.parametrize("step_std", [(0.1, 0.1), (0.1, 0.0, 0.1), (0.1, np.nan, 0.1), "x"])
def test_random_walk_bad_steps_are_errors(step_std):
    data, _, _ = lattice_problem()
    with pytest.raises(BayesmapError, match="step_std"):
        random_walk_pose_mh(data, step_std)


# --- segment_pose_mh: rigid moves of whole stretches of the path ----------------------------------------------------


def inverse_step(delta):
    """``delta^-1`` of a step ``(dx, dy, dtheta)``: ``(-R(-dtheta) (dx, dy), -dtheta)``."""
    c, s = np.cos(delta[2]), np.sin(delta[2])
    return np.array([-(c * delta[0] + s * delta[1]), -(-s * delta[0] + c * delta[1]), -delta[2]])


def test_segment_log_ratio_is_the_difference_of_assess():
    """The segment move's log ratio against differences of slam_model's assess, on the tiny problem (3 scans, 2 free
    poses) for every segment, and the move's inverse returns the path (the involution the kernel's ratio needs). The
    ratio keeps only the segment's scans and its two end steps; a missing end step or a scan left out moves it by
    0.1-1 nats here, against a rounding tolerance of 1e-9."""
    with enable_x64():
        params, inc, cov, candidates, angles, y = tiny_problem()
        data = slam_data(inc, cov, angles, y, params)
        walls = np.array([[0, 1], [1, 0], [0, 0]], np.float32)
        poses = jnp.asarray(candidates[:, 1])
        args = slam_args(TINY_ODOMETRY[0], inc, cov, params, angles)

        def assess(p):
            return float(slam_model.assess(slam_choices(p, walls, y), args)[0])

        for (a, b), delta in itertools.product(((1, 1), (1, 2), (2, 2)), ([0.05, -0.03, 0.1], [-0.2, 0.1, -0.3])):
            moved = moved_segment(poses, a, b, jnp.asarray(delta))
            np.testing.assert_allclose(float(segment_log_ratio(a, b, delta, poses, walls, data)),
                                       assess(moved) - assess(poses), atol=1e-9)
            np.testing.assert_allclose(moved_segment(moved, a, b, jnp.asarray(inverse_step(np.array(delta)))), poses,
                                       atol=1e-12)
            assert np.all(moved[:a] == poses[:a]) and np.all(moved[b + 1:] == poses[b + 1:])
        with pytest.raises(BayesmapError, match="segment"):
            segment_log_ratio(0, 1, [0, 0, 0], poses, walls, data)


@pytest.mark.xdist_group("continuous_pose")
def test_segment_mh_of_one_pose_matches_the_continuous_conditional():
    """length = 1 on the two-scan problem (one free pose, so every segment is pose 1 and the move is a random walk
    in the pose's own frame): the chain's mean and standard deviation against the exact conditional by quadrature,
    with the random-walk test's chains, sweeps and tolerances (5 standard errors of the per-chain averages + 2e-3,
    20 % on the standard deviations)."""
    with enable_x64():
        data, odometry, walls = lattice_problem()
        mean, sd = lattice_moments()
        kernel = segment_pose_mh(data, 1, (0.1, 0.1))
        poses = run_pose_chains(kernel, odometry, walls, 400, 100, 25)
        per_chain = poses.mean(axis=1)
        se = per_chain.std(0) / np.sqrt(len(per_chain))
        assert np.all(np.abs(per_chain.mean(0) - mean) < 5 * se + 2e-3), (per_chain.mean(0), mean, se)
        np.testing.assert_allclose(poses.reshape(-1, 3).std(0), sd, rtol=0.2)


@pytest.mark.xdist_group("continuous_pose")
def test_random_walk_then_segment_moves_match_the_continuous_conditional():
    """composed_pose_kernels(random walk, segment moves) on the two-scan problem, with the random-walk test's chains,
    sweeps and tolerances: a cycle of two kernels that each leave the conditional invariant leaves it invariant, and
    the composed sweep passes the state (and its cached scan log-likelihoods) from one to the other correctly."""
    with enable_x64():
        data, odometry, walls = lattice_problem()
        mean, sd = lattice_moments()
        kernel = composed_pose_kernels(random_walk_pose_mh(data, (0.1, 0.1, 0.1)), segment_pose_mh(data, 1, (0.1, 0.1)))
        poses = run_pose_chains(kernel, odometry, walls, 400, 100, 25)
        per_chain = poses.mean(axis=1)
        se = per_chain.std(0) / np.sqrt(len(per_chain))
        assert np.all(np.abs(per_chain.mean(0) - mean) < 5 * se + 2e-3), (per_chain.mean(0), mean, se)
        np.testing.assert_allclose(poses.reshape(-1, 3).std(0), sd, rtol=0.2)


def segment_problem():
    """Three scans on the lattice problem's 4 x 4 grid: poses 1 and 2 free, the second scan's readings simulated
    away from the odometry, so that the posterior pulls the two poses off it together."""
    data, odometry, walls = lattice_problem()
    params = data.params
    odometry = np.array([[0.5, 0.5, 0.0], [1.5, 1.5, 0.5], [2.0, 1.0, 0.2]])
    inc, cov = motion.odometry_controls(odometry, motion.make_motion_params((0, 0, 0, 0), 0.15, 0.1))
    angles = np.tile(np.linspace(-np.pi, np.pi, 8, endpoint=False), (3, 1))
    truth = np.array([odometry[0], [1.62, 1.42, 0.58], [2.1, 0.95, 0.3]])
    y = np.asarray(simulate_scan_readings(jax.random.key(1), walls, truth[:, :2], params, truth[:, 2:3] + angles))
    return slam_data(inc, cov, angles, y, params), odometry, walls


def importance_moments(data, odometry, walls, num=400_000):
    """The posterior means ``(2, 3)`` of poses 1 and 2 given the walls and their standard errors, by self-normalized
    importance sampling with the motion model as the proposal (the weights are the scans' likelihoods; the standard
    error by the delta method)."""
    key = jax.random.key(11)
    e1, e2 = jax.random.normal(key, (2, num, 3), jnp.float64)
    chol = np.linalg.cholesky(np.asarray(data.covs))
    x1 = motion.compose(odometry[0], np.asarray(data.increments[0]) + e1 @ chol[0].T)
    x2 = motion.compose(x1, np.asarray(data.increments[1]) + e2 @ chol[1].T)
    logw = sum(np.asarray(jax.vmap(lambda p, t=t: scan_log_likelihood(walls, p[None], data.sensor_angles[t],
                                                                        data.readings[t], data.params)[0])(x))
               for t, x in ((1, x1), (2, x2)))
    w = np.exp(logw - logw.max())
    w /= w.sum()
    x = np.stack([np.asarray(x1), np.asarray(x2)], axis=1)  # (num, 2, 3)
    mean = np.einsum("n,nij->ij", w, x)
    se = np.sqrt(np.einsum("n,nij->ij", w**2, (x - mean) ** 2))
    return mean, se


def test_segment_mh_matches_the_posterior_of_two_poses():
    """length = 2 on three scans (poses 1 and 2 free): a sweep moves both poses together (offset 0) or each alone
    (offset 1). The chains' means of both poses against the posterior means by importance sampling from the motion
    model (400,000 draws; its standard error is 1e-4 to 1e-3 here). 400 independent chains x 150 kept sweeps after 50;
    tolerance 5 times the two standard errors combined + 2e-3 (burn-in bias), about 0.016 m / rad, while the readings
    move the posterior means 0.14 m from the odometry. Leaving the step after a segment out of the ratio (the step
    from pose 1 to pose 2 when pose 1 moves alone) fails it: pose 1's x mean moves from 1.511 to 1.496."""
    with enable_x64():
        data, odometry, walls = segment_problem()
        exact, exact_se = importance_moments(data, odometry, walls)
        kernel = segment_pose_mh(data, 2, (0.1, 0.1))

        def chain(key):
            def body(state, k):
                state, _ = kernel.step(k, state)
                return state, state.poses[1:]

            return jax.lax.scan(body, kernel.init(odometry, walls), jax.random.split(key, 200))[1][50:]

        poses = np.asarray(jax.jit(jax.vmap(chain))(jax.random.split(jax.random.key(5), 400)), np.float64)
        per_chain = poses.mean(axis=1)  # (400, 2, 3)
        se = per_chain.std(0) / np.sqrt(len(per_chain))
        tol = 5 * np.sqrt(se**2 + exact_se**2) + 2e-3
        assert np.all(np.abs(per_chain.mean(0) - exact) < tol), (per_chain.mean(0), exact, tol)
        assert np.abs(exact - odometry[1:]).max() > 5 * tol.max()  # the readings move the poses: the test is sharp


@pytest.mark.parametrize(("length", "step_std", "match"), [(0, (0.1, 0.1), "length"), (2.5, (0.1, 0.1), "length"),
                                                          (2, (0.1, 0.2, 0.1), "equal"), (2, (0.1,), "step_std"),
                                                          (2, (0.1, -1.0), "step_std")])
def test_segment_mh_bad_arguments_are_errors(length, step_std, match):
    data, _, _ = lattice_problem()
    with pytest.raises(BayesmapError, match=match):
        segment_pose_mh(data, length, step_std)
