"""The particle front end (sequential Monte Carlo over the front end's path) against the single track, the motion
model's exact distribution and the resampling's guarantees."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tests.slam.test_scanmatch import room_scans

from bayesmap.errors import BayesmapError
from bayesmap.model.motion import (
    backward_step_covariance,
    compose,
    make_motion_params,
    motion_error,
    odometry_controls,
    tailed_motion_logpdf,
)
from bayesmap.progress import Progress
from bayesmap.slam.particles import hypotheses, particle_path, systematic_resample
from bayesmap.slam.scanmatch import (
    FIELD_FLOOR,
    MOTION_TAIL_WEIGHT,
    ScanData,
    correlative_path,
    lattice_poses,
    step_lattice,
)

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)


def room_data():
    grid, truth, odometry, beams, readings = room_scans()
    inc, cov = odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05)))
    return grid, truth, odometry, ScanData(beams, readings, readings < 19.9, np.asarray(inc), np.asarray(cov))


def test_one_particle_that_takes_its_matches_is_the_single_track():
    """One particle that takes each match (``draw=False``) runs the single-track front end's computation: the same
    path to the bit, with and without progress reports (blocks of scans), and the same step covariances but for the
    last bits of float32 (the two loops are separate compiled programs, and XLA's CPU runtime that the matchers are
    built with, :data:`bayesmap.slam.scanmatch.MATCHER_COMPILER_OPTIONS`, may sum a step's lattice in another order:
    1.5e-11 m^2 apart on variances of about 1e-4 m^2)."""
    grid, _, odometry, data = room_data()
    single = correlative_path(odometry[0], data, grid.resolution, window=10.0)
    one = particle_path(odometry[0], data, grid.resolution, 1, draw=False, window=10.0)
    seen = []
    blocks = particle_path(odometry[0], data, grid.resolution, 1, draw=False, window=10.0, progress=seen.append)
    for got in (one, blocks):
        np.testing.assert_array_equal(got.matched.path, single.path)
        np.testing.assert_allclose(got.matched.step_cov, single.step_cov, rtol=1e-5, atol=1e-9)
        assert got.resamples == 0 and got.log_weights.tolist() == [0.0]
    assert seen[0] == Progress("front end", 0, len(odometry) - 1, "scan")
    assert seen[-1] == Progress("front end", len(odometry) - 1, len(odometry) - 1, "scan")


def test_particles_recover_the_true_path():
    """Eight particles, half of them searching from draws of the motion model, still find the room's true path: the
    heaviest particle within 4 cm and 0.03 rad (the single track's 3 cm and 0.02 rad, plus a cell's worth for a
    search that started elsewhere and stopped at another point of the same basin), where the odometry is off by
    decimeters; every particle's path starts at the first pose, the weights sum to 1, and one path carries them."""
    grid, truth, odometry, data = room_data()
    result = particle_path(odometry[0], data, grid.resolution, 8, seed=3, window=10.0)
    assert np.abs(odometry - truth)[:, :2].max() > 0.1
    assert np.abs(result.matched.path - truth)[:, :2].max() < 0.04
    assert np.abs(result.matched.path - truth)[:, 2].max() < 0.03
    assert result.paths.shape == (8, len(truth), 3)
    np.testing.assert_allclose(result.paths[:, 0], np.broadcast_to(odometry[0], (8, 3)), atol=1e-6)
    assert np.isclose(np.exp(result.log_weights).sum(), 1.0)
    assert hypotheses(result.paths, result.log_weights) == 1


def one_step_without_a_map(num, trusted_without_hits):
    """Two poses 0.5 m apart; beams whose endpoints lie off the fields' 1 m square (5 m readings), so the local map
    is empty; motion standard deviations 3 cm and 0.01 rad (inside the step lattice's +-0.3 m and +-0.05 rad)."""
    beams = np.tile(np.linspace(-np.pi, np.pi, 8, endpoint=False), (2, 1))
    cov = np.diag([0.03**2, 0.03**2, 0.01**2])
    increment = np.array([0.5, 0.1, 0.2])
    data = ScanData(beams, np.full((2, 8), 5.0), np.ones((2, 8), bool), increment[None], cov[None])
    first = np.array([0.2, -0.1, 0.7])
    result = particle_path(first, data, 0.05, num, seed=1, draw=True, half_width=0.5, likelihood_power=0.1,
                           min_hit_fraction=0.0 if trusted_without_hits else 0.2)
    return result, first, increment, cov


def motion_errors(poses, first, increment):
    """The motion errors ``(N, 3)`` that take ``first`` to ``poses`` (:func:`bayesmap.model.motion.motion_error`)."""
    return np.asarray(motion_error(jnp.asarray(first), jnp.asarray(poses), jnp.asarray(increment)))


@pytest.mark.parametrize("trusted_without_hits", [False, True])
def test_without_a_map_the_particles_are_the_motion_models_draws(trusted_without_hits):
    """With an empty local map every particle that draws its steps (``draw=True``) draws from the motion model: the
    untrusted branch directly; the trusted one (least hit fraction 0) from the step lattice's density, the motion
    model's Gaussian there. 2,000 particles: the motion errors' means within 4 standard errors (sd / sqrt(2000)),
    their standard deviations within 8 % (4 standard errors of a standard deviation, 6.3 %, plus the lattice's
    quadrature and its cells' uniform jitter, under 2 % measured), their correlations within 0.1 (4.5 standard
    errors). The weights stay equal, so nothing is resampled. The weight update is exact here: every endpoint
    scores ``log FIELD_FLOOR``, so an untrusted step's (the bootstrap filter's ``p S`` at the draw) is ``p K
    log(FIELD_FLOOR)``, and a trusted step's, the log of the step density's integral on the lattice, is that plus
    the log of the front end's motion density (the motion model with its tail, MOTION_TAIL_WEIGHT) summed over the
    lattice's nodes with their cells' volumes (computed here on its own). That quadrature of a density that
    integrates to 1 is itself within 0.2 of 0 (0.18 at these standard deviations: the cells' midpoint rule on
    sinh-spaced nodes overweights the center by 5-7 % a dimension); the error is common to particles whose steps are
    as wide, and a weight is only compared with others'."""
    num = 2000
    result, first, increment, cov = one_step_without_a_map(num, trusted_without_hits)
    errors = motion_errors(result.paths[:, 1], first, increment)
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(errors.mean(0)) < 4 * sd / np.sqrt(num))
    np.testing.assert_allclose(errors.std(0), sd, rtol=0.08)
    assert np.abs(np.corrcoef(errors.T) - np.eye(3)).max() < 0.1
    np.testing.assert_allclose(result.log_weights, -np.log(num), atol=1e-4)  # float32 logsumexps
    assert result.resamples == 0
    xy, theta, log_volume, _ = step_lattice()
    cands = lattice_poses(compose(jnp.asarray(first), jnp.asarray(increment)), xy, theta)
    density = tailed_motion_logpdf(jnp.asarray(first), cands, jnp.asarray(increment), jnp.asarray(cov),
                                   MOTION_TAIL_WEIGHT, backward_step_covariance())
    quadrature = float(jax.nn.logsumexp(density + log_volume))
    assert abs(quadrature) < 0.2
    want = 0.1 * 8 * np.log(FIELD_FLOOR) + (quadrature if trusted_without_hits else 0.0)
    assert result.log_evidence == pytest.approx(want, abs=1e-4)


def test_systematic_resampling_keeps_each_particle_about_its_weight_times_n():
    """Each particle gets floor(N w) or ceil(N w) copies (systematic resampling's guarantee), for many weights and
    keys."""
    rng = np.random.default_rng(0)
    for trial in range(50):
        weights = rng.dirichlet(np.full(16, 0.3))
        ancestors = np.asarray(systematic_resample(jax.random.key(trial), jnp.log(jnp.asarray(weights))))
        counts = np.bincount(ancestors, minlength=16)
        assert counts.sum() == 16
        assert np.all(counts >= np.floor(16 * weights - 1e-6)) and np.all(counts <= np.ceil(16 * weights + 1e-6))


def test_hypotheses_counts_the_distinct_heavy_paths():
    """Paths whose final positions lie within 0.5 m are one hypothesis; a group under 1 % of the weight is not
    counted; within 5 m the three heavy paths are one."""
    paths = np.zeros((4, 2, 3))
    paths[:, -1, 0] = [0.0, 0.2, 3.0, 9.0]
    weights = np.array([0.5, 0.3, 0.195, 0.005])
    assert hypotheses(paths, np.log(weights)) == 2
    assert hypotheses(paths, np.log(weights), min_weight=0.001) == 3
    assert hypotheses(paths, np.log(weights), distance=5.0) == 1


@pytest.mark.parametrize("particles", [0, 1.5, True])
def test_particle_path_checks_the_particle_count(particles):
    grid, _, odometry, data = room_data()
    with pytest.raises(BayesmapError, match="particles must be an integer"):
        particle_path(odometry[0], data, grid.resolution, particles)
