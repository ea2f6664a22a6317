"""SLAM on a real log: the path and the map of hundreds of scans of a real building.

The pipeline (each stage a start for the next; only the last defines the answer's target):

1. front end: sequential correlative scan matching (:func:`bayesmap.inference.scanmatch.correlative_path`);
2. the final grid: fitted to the beam endpoints at the matched path, plus :data:`bayesmap.scenes.MARGIN`;
3. the joint chain on ``p(poses, walls | readings, odometry)``.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.cellwise import cellwise_gibbs
from bayesmap.inference.chains import run_chain
from bayesmap.inference.scanmatch import ScanData, correlative_path, scan_endpoints
from bayesmap.inference.slam import SlamResult, pose_summary
from bayesmap.model.generative import make_params
from bayesmap.model.motion import odometry_controls

FRONT_END_RESOLUTION = 0.05
"""Cell size of the front end's likelihood fields, meters (finer than the map: the fields resolve sub-cell
shifts)."""

MAP_MARGIN = 1.0
"""Meters around the matched path's endpoints for the final grid."""


def scan_data(problem) -> ScanData:
    """The :class:`~bayesmap.inference.scanmatch.ScanData` of a :class:`bayesmap.scenes.SlamProblem` (odometry
    controls under the problem's motion model; max-range beams marked as not returned)."""
    increments, covs = odometry_controls(problem.odometry, problem.motion)
    mask = problem.max_range_mask if problem.max_range_mask is not None else np.zeros(problem.readings.shape, bool)
    returned = ~np.asarray(mask, bool)
    readings = np.where(returned, problem.readings, 0.0)
    return ScanData(np.asarray(problem.sensor_angles), readings, returned, np.asarray(increments),
                    np.asarray(covs))


def fitted_grid(problem, path, resolution: float) -> Grid:
    """The grid covering the returned beams' endpoints and the sensor positions at ``path`` ``(S, 3)`` plus
    :data:`MAP_MARGIN` meters."""
    data = scan_data(problem)
    ends = np.asarray(scan_endpoints(jnp.asarray(path), data.sensor_angles, data.readings))
    return Grid.covering(np.vstack([ends[data.returned], path[:, :2]]), resolution=resolution, margin=MAP_MARGIN)


def front_end(problem) -> np.ndarray:
    """The front end's path ``(S, 3)`` float64 (x m, y m, theta rad): correlative scan matching on a grid of
    :data:`FRONT_END_RESOLUTION` meters covering the odometry's endpoints plus the problem's margin."""
    data = scan_data(problem)
    odometry = np.asarray(problem.odometry, np.float64)
    grid = fitted_grid(problem, odometry, FRONT_END_RESOLUTION)
    grid = Grid.covering(np.asarray(grid.cell_centers()).reshape(-1, 2)[[0, -1]], resolution=FRONT_END_RESOLUTION,
                         margin=5.0)
    return correlative_path(odometry[0], data, grid)


def with_grid(params, grid: Grid):
    """``params`` (:class:`bayesmap.model.generative.ModelParams`) on another grid, every other value kept."""
    beam = {name: getattr(params, name) for name in ("z_hit", "z_short", "z_max", "z_rand", "lambda_short")}
    return make_params(params.prior_wall_prob, params.sensor_noise, params.num_angles, grid,
                       max_distance=params.max_range, beam_model=params.beam_model, **beam)


def run_log_slam(problem, sweeps: int = 20, burn_in: int = 5, seed: int = 0, progress: bool = False) -> SlamResult:
    """Infer the path and the map of a real log (:func:`bayesmap.scenes.log_slam_problem`).

    STUB (interface only): front end, then a cellwise map chain at the front end's path; one pose sample.

    Args:
        problem: a :class:`bayesmap.scenes.SlamProblem` from a log.
        sweeps: map sweeps; burn_in: sweeps dropped; seed: the random seed; progress: show a tqdm bar.

    Returns:
        A :class:`bayesmap.inference.slam.SlamResult` whose ``grid`` is the fitted grid.
    """
    start = time.perf_counter()
    path = front_end(problem)
    grid = fitted_grid(problem, path, problem.params.grid.resolution)
    p = problem.params
    params = with_grid(p, grid)
    theta = path[:, 2:3] + problem.sensor_angles
    origins = np.repeat(path[:, :2], problem.sensor_angles.shape[1], axis=0)
    table = build_ray_table(grid, origins, theta.reshape(-1), p.max_range)
    sampler = cellwise_gibbs(table, problem.readings.reshape(-1), params, problem.likelihood_power)
    chain = run_chain(jax.random.key(seed), sampler, jnp.zeros(grid.shape, jnp.float32), sweeps)
    posterior = np.asarray(chain.wall_probs[burn_in:] if chain.wall_probs is not None else chain.samples[burn_in:],
                           np.float64).mean(axis=0)
    samples = path[None]
    mean, cov = pose_summary(samples)
    return SlamResult(pose_samples=samples, mean_path=mean, pose_cov=cov, posterior=posterior, acceptance_rate=1.0,
                      runtime_s=time.perf_counter() - start, last_walls=np.asarray(chain.samples[-1], np.float32),
                      grid=grid)
