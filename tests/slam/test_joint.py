"""The joint SLAM chain (bayesmap.slam.joint) and the tutorial SLAM scene (slam_tutorial_problem)."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.trajectory import absolute_trajectory_error
from bayesmap.inference.chains import compiled_chain_count
from bayesmap.slam.joint import pose_summary, run_slam, slam_kernel
from bayesmap.slam.poses import discrete_pose_gibbs, slam_data
from bayesmap.slam.problem import simulate_odometry, slam_tutorial_problem
from helpers import exact_slam_marginals, tiny_slam_problem

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)

def test_joint_kernel_matches_enumeration():
    """slam_kernel with discrete_pose_gibbs and the dense map sweep against the exact joint marginals of poses and
    walls. 2,000 independent chains of 50 sweeps from random starts (15 burn-in); each chain's average over its kept
    sweeps is one estimate, so the standard error is their standard deviation / sqrt(2000) (autocorrelation
    included). Tolerance: 5 standard errors plus 2e-3 for the burn-in's remaining (geometrically decaying) bias."""
    params, inc, cov, candidates, angles, y = tiny_slam_problem()
    p1, p2, pw = exact_slam_marginals(params, inc, cov, candidates, angles, y)
    assert 0.05 < p1.min() and 0.05 < p2.min()  # every candidate has mass: the test is sharp
    assert np.sum((pw > 0.1) & (pw < 0.9)) >= 2
    data = slam_data(inc, cov, angles, y, params)
    kernel = slam_kernel(data, discrete_pose_gibbs(data, candidates))
    cands = jnp.asarray(candidates, jnp.result_type(float))
    num_chains, num_sweeps, burn_in = 2000, 50, 15

    def chain(key):
        k_init, k_walls, k_run = jax.random.split(key, 3)
        idx = jax.random.randint(k_init, (3,), 0, 3)
        walls = jax.random.bernoulli(k_walls, 0.5, params.grid.shape)
        state = kernel.init(cands[jnp.arange(3), idx], walls)

        def body(state, k):
            state, info = kernel.step(k, state)
            which = jnp.all(state.poses[1:, None, :] == cands[1:], axis=-1)  # (2, 3) one-hot
            return state, (which.astype(jnp.float32), state.walls, info.wall_prob)

        _, (which, walls, prob) = jax.lax.scan(body, state, jax.random.split(k_run, num_sweeps))
        return which[burn_in:].mean(0), walls[burn_in:].mean(0), prob[burn_in:].mean(0)

    which, walls, prob = (np.asarray(a, np.float64) for a in
                          jax.jit(jax.vmap(chain))(jax.random.split(jax.random.key(1), num_chains)))
    assert np.allclose(which.sum(-1), 1.0)
    for est, exact in ((which[:, 0], p1), (which[:, 1], p2), (walls, pw), (prob, pw)):
        se = est.std(0) / np.sqrt(num_chains)
        assert np.all(np.abs(est.mean(0) - exact) < 5 * se + 2e-3), (est.mean(0), exact, se)


@pytest.fixture(scope="module")
def tutorial_slam():
    """5 poses, 12 sweeps (4 burn-in), seed 0: the run of tests/test_cli_slam.py::test_slam_writes_all_outputs, on
    the same xdist worker (group "tutorial_slam"), which then reuses this compiled chain."""
    problem = slam_tutorial_problem(seed=0, num_poses=5)
    return problem, run_slam(problem, sweeps=12, burn_in=4, seed=0)


@pytest.mark.xdist_group("tutorial_slam")
def test_posterior_path_beats_odometry_on_the_tutorial(tutorial_slam):
    """Seed 0, 5 poses around the room: the posterior mean path is closer to the true path than the odometry (ATE
    after rigid alignment), by a factor of 2, and the map is right where seen."""
    problem, result = tutorial_slam
    odometry_ate = absolute_trajectory_error(problem.odometry, problem.true_poses)["rmse_m"]
    posterior_ate = absolute_trajectory_error(result.mean_path, problem.true_poses)["rmse_m"]
    assert odometry_ate > 0.1  # the odometry is really off
    assert posterior_ate < 0.5 * odometry_ate, (posterior_ate, odometry_ate)
    assert result.pose_samples.shape == (8, 5, 3)
    assert result.pose_cov.shape == (5, 3, 3) and np.all(result.pose_cov[0] == 0)  # pose 0 is fixed
    assert np.all(np.linalg.eigvalsh(result.pose_cov[1:]) > -1e-12)
    assert result.posterior.shape == problem.truth.shape
    assert np.mean((result.posterior > 0.5) != (problem.truth > 0)) < 0.1
    assert 0 <= result.acceptance_rate <= 1 and result.runtime_s > 0


@pytest.mark.xdist_group("tutorial_slam")
def test_a_problem_of_the_same_shapes_reuses_the_compiled_joint_chain(tutorial_slam):
    """The joint kernel is a pytree of module functions and arrays, not closures: another scene of the same shapes
    (other odometry and readings) runs on the compiled chain of tutorial_slam's (none is compiled anew), and
    its own numbers come out (not the first problem's)."""
    problem, result = tutorial_slam
    before = compiled_chain_count()
    other = run_slam(slam_tutorial_problem(seed=1, num_poses=5), sweeps=12, burn_in=4, seed=1)
    assert compiled_chain_count() == before
    assert not np.allclose(other.mean_path, result.mean_path)


def test_pose_summary_uses_the_circular_mean():
    """Headings on both sides of pi average to pi (not 0); the theta variance is of the wrapped deviations."""
    samples = np.zeros((4, 2, 3))
    samples[:, 1] = [[1.0, 2.0, np.pi - 0.1], [3.0, 2.0, -np.pi + 0.1], [1.0, 4.0, np.pi - 0.1],
                     [3.0, 4.0, -np.pi + 0.1]]
    mean, cov = pose_summary(samples)
    assert np.allclose(mean[1, :2], [2.0, 3.0])
    assert np.isclose(abs(mean[1, 2]), np.pi)
    assert np.allclose(np.diag(cov[1]), [1.0, 1.0, 0.01])
    with pytest.raises(BayesmapError, match="pose samples"):
        pose_summary(np.zeros((0, 2, 3)))


def test_bad_counts_are_errors():
    problem = slam_tutorial_problem(num_poses=2, num_angles=8)
    for kwargs, name in (({"sweeps": 0}, "sweeps"), ({"burn_in": -1}, "burn_in"), ({"chains": 0}, "chains"),
                         ({"sweeps": 5, "burn_in": 5}, "burn_in"), ({"sweeps": 2.5}, "sweeps")):
        with pytest.raises(BayesmapError, match=name):
            run_slam(problem, **kwargs)


def test_slam_tutorial_scene():
    """The loop stays in the room's free space (no wall within 1 cell of any pose), the odometry starts at the
    first true pose and drifts, the readings are the tutorial's sensor model at the true poses."""
    problem = slam_tutorial_problem(seed=3, num_poses=8)
    walls = problem.truth
    for x, y, _ in problem.true_poses:
        i, j = int(round(x)), int(round(y))
        assert walls[i - 1:i + 2, j - 1:j + 2].sum() == 0, (x, y)
    assert np.array_equal(problem.odometry[0], problem.true_poses[0])
    drift = np.linalg.norm(problem.odometry[1:, :2] - problem.true_poses[1:, :2], axis=1)
    assert 0.01 < drift.max() < 2.0
    assert problem.readings.shape == problem.sensor_angles.shape == (8, 100)
    assert np.all(problem.readings >= 0) and np.all(problem.readings < problem.params.max_range + 1.0)
    assert np.median(problem.readings) < 10  # most beams hit the room's walls
    with pytest.raises(BayesmapError, match="num_poses"):
        slam_tutorial_problem(num_poses=1)


def test_simulate_odometry_without_noise_is_the_true_path():
    path = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.7], [0.5, 2.0, 3.0], [-1.0, 2.5, -2.9]])
    odometry = simulate_odometry(path, (0.0, 0.0, 0.0, 0.0))
    assert np.allclose(odometry, path, atol=1e-12)
    noisy = simulate_odometry(path, seed=1)
    assert not np.allclose(noisy, path) and np.array_equal(noisy, simulate_odometry(path, seed=1))
    with pytest.raises(BayesmapError, match="alphas"):
        simulate_odometry(path, (0.1, -0.1, 0.0, 0.0))
