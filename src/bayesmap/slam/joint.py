"""Joint SLAM at the tutorial's scale: a Gibbs chain over the path and the map together.

The target is the SLAM model's posterior ``p(poses, walls | readings, odometry)``
(:data:`bayesmap.model.slam.slam_model`; the readings' likelihood tempered by ``eta``, 1 for the posterior).
One step of :func:`slam_kernel` updates two blocks in turn (Gibbs over blocks, e.g. Robert & Casella, *Monte Carlo
Statistical Methods*, 2nd ed., sec. 10.1):

1. the poses given the walls: one pass of a pose kernel of :mod:`bayesmap.slam.poses`
   (:func:`~bayesmap.slam.poses.lattice_pose_mh`, multiple-try Metropolis, or
   :func:`~bayesmap.slam.poses.discrete_pose_gibbs` on finite candidate sets), each of which leaves
   ``p(poses | walls, readings, odometry)`` invariant;
2. the walls given the new poses: one raster sweep of the dense single-site Gibbs kernel
   (:func:`bayesmap.inference.dense.dense_sweep`), its ray-cell distances recomputed in JAX from the new poses
   (:func:`bayesmap.inference.dense.dense_state`), which leaves ``p(walls | poses, readings)`` invariant.

Each block's kernel leaves the joint posterior invariant, so their composition does too (docs/slam.md). The shapes
never depend on the poses' values: the whole chain is one compiled ``lax.scan`` (chains by ``vmap``).

:func:`run_slam` runs it on a :class:`bayesmap.slam.problem.SlamProblem` and summarizes the kept sweeps
(:class:`SlamResult`): pose samples, the posterior mean path (circular mean of the heading), per-pose covariances,
the posterior map (the mean of the conditional wall probabilities, Rao-Blackwellized) and the pose kernel's
acceptance rate.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.tree_util import Partial

from bayesmap.errors import BayesmapError
from bayesmap.inference.base import SamplingAlgorithm
from bayesmap.inference.chains import run_recorded_chains
from bayesmap.inference.dense import dense_readings, dense_state, dense_sweep
from bayesmap.model.generative import check_likelihood_power, check_scan_powers, make_params, prior_log_odds
from bayesmap.model.motion import compose, motion_logpdf, wrap_angle
from bayesmap.progress import ProgressCallback
from bayesmap.slam.poses import (
    PoseState,
    SlamData,
    lattice_offsets,
    lattice_pose_mh,
    scan_log_likelihood,
    slam_data,
)

LATTICE_STEP_CELLS = 0.1
"""Default lattice step of the pose kernel in x and y, in cells (0.1 m on the tutorial's 1 m cells)."""

LATTICE_STEP_THETA = 0.02
"""Default lattice step of the pose kernel in theta, radians (about 1.1 degrees)."""

LATTICE_HALF_WIDTH = 1
"""Default half width of the pose kernel's window: ``(2 w + 1)^3 = 27`` candidate poses per move."""

MATCH_LEVELS = ((0.3, 0.06, 4), (0.1, 0.02, 2), (0.03, 0.006, 2))
"""The coarse-to-fine search of :func:`scan_matching_path`: per level the lattice step in x and y (cells), in theta
(radians) and the half width (``(2 w + 1)^3`` candidates), each level centered on the previous level's best pose:
the first covers +-1.2 cells and +-0.24 rad around the odometry's prediction."""

MAP_INIT_SWEEPS = 3
"""Map-only sweeps at the initial (odometry) path before the joint chain: a start for the map (an initial point does
not change the target)."""


class SlamState(NamedTuple):
    """State of the joint chain: ``poses`` ``(S, 3)`` (x m, y m, theta rad; row 0 fixed) and ``walls`` ``(nx, ny)``
    float32 of 0.0 / 1.0."""

    poses: jax.Array
    walls: jax.Array


class SlamInfo(NamedTuple):
    """What a joint step reports: ``accepted`` ``(S - 1,)`` bool (the pose kernel's moves; always True for Gibbs
    draws) and ``wall_prob`` ``(nx, ny)`` float32, the conditional wall probability each cell was drawn with."""

    accepted: jax.Array
    wall_prob: jax.Array


def slam_kernel(data: SlamData, pose_kernel: SamplingAlgorithm, likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """The joint kernel: one pose-kernel pass given the walls, then one dense map sweep given the new poses.

    Args:
        data: the odometry, sensor angles ``(S, K)``, readings ``(S, K)`` and parameters
            (:func:`bayesmap.slam.poses.slam_data`).
        pose_kernel: a pose kernel over :class:`~bayesmap.slam.poses.PoseState` built on the same ``data``
            and likelihood power (:func:`~bayesmap.slam.poses.lattice_pose_mh` or
            :func:`~bayesmap.slam.poses.discrete_pose_gibbs`).
        likelihood_power: ``eta`` in (0, 1] of the map sweep (use the pose kernel's), or one power per scan
            ``(S,)`` in [0, 1] (:func:`bayesmap.model.generative.check_scan_powers`; each of the scan's beams counts
            at its scan's power).

    Returns:
        A :class:`~bayesmap.inference.base.SamplingAlgorithm`: ``init(poses (S, 3), walls (nx, ny)) -> SlamState``,
        ``step(key, SlamState) -> (SlamState, SlamInfo)``; pure and jittable.

    Raises:
        BayesmapError: on a bad likelihood power, readings that are negative or not finite, or a dense table too
            large (:func:`bayesmap.inference.dense.dense_readings`).
    """
    num_scans, beams = data.sensor_angles.shape
    eta = check_scan_powers(likelihood_power, num_scans)
    params = data.params
    prior_lo = prior_log_odds(params.prior_wall_prob)
    angles, y = dense_readings(data.sensor_angles, data.readings, params)
    if jnp.ndim(eta):  # the dense table's rays are the scans' beams in order
        eta = jnp.repeat(eta, beams)

    # pytrees of module functions and arrays (not closures): a compiled chain takes the arrays as arguments, so runs
    # of the same shapes share it (run_slam_chains)
    return SamplingAlgorithm(init=Partial(_joint_init),
                             step=Partial(_joint_step, pose_kernel.step, angles, y, params, eta, prior_lo))


def _joint_init(poses, walls) -> SlamState:
    return SlamState(poses=jnp.asarray(poses, dtype=jnp.result_type(float)),
                     walls=(jnp.asarray(walls) > 0).astype(jnp.float32))


def _joint_step(pose_step, angles, y, params, eta, prior_lo, key, state: SlamState):
    """:func:`slam_kernel`'s step: the poses given the walls, then a dense map sweep given the new poses."""
    k_pose, k_map = jax.random.split(key)
    pose_state, pose_info = pose_step(k_pose, PoseState(poses=state.poses, walls=state.walls))
    map_state = dense_state(state.walls, pose_state.poses, angles, params)
    map_state, map_info = dense_sweep(k_map, map_state, y, params, eta, prior_lo)
    return (SlamState(poses=pose_state.poses, walls=map_state.walls),
            SlamInfo(accepted=pose_info.accepted, wall_prob=map_info.wall_prob))


def _joint_record(state: SlamState, info: SlamInfo):
    """What a joint chain keeps per sweep: the poses, walls, acceptances and wall probabilities."""
    return state.poses, state.walls, info.accepted, info.wall_prob


def run_slam_chains(key, algorithm: SamplingAlgorithm, initial: SlamState, num_sweeps: int, num_chains: int = 1,
                    progress: ProgressCallback | None = None):
    """Run ``num_chains`` independent joint chains (``vmap`` of a ``lax.scan``) from the same initial state;
    ``progress`` (:mod:`bayesmap.progress`) is told of each sweep (stage ``"joint chain"``), the same chains either way.

    Returns:
        ``(poses (C, T, S, 3), walls (C, T, nx, ny), accepted (C, T, S - 1), wall_prob (C, T, nx, ny))`` as JAX
        arrays, ``C = num_chains``, ``T = num_sweeps``.
    """
    return run_recorded_chains(key, initial, algorithm, num_sweeps, _joint_record, num_chains, progress,
                               "joint chain")


def circular_mean(theta, axis=0):
    """The circular mean of angles (radians) along ``axis``: ``atan2(mean sin, mean cos)`` (Mardia & Jupp,
    *Directional Statistics*, sec. 2.2.1); numpy."""
    theta = np.asarray(theta, dtype=np.float64)
    return np.arctan2(np.sin(theta).mean(axis=axis), np.cos(theta).mean(axis=axis))


def pose_summary(samples) -> tuple[np.ndarray, np.ndarray]:
    """The posterior mean path and pose covariances of pose samples ``(N, S, 3)`` (x m, y m, theta rad).

    Returns:
        ``(mean (S, 3), cov (S, 3, 3))`` float64: x and y averaged, theta the :func:`circular_mean` (kept within
        ``pi`` of the first sample's heading, so an unwrapped path stays unwrapped); the covariance of ``(x, y,
        theta - mean theta wrapped to [-pi, pi))`` with divisor ``N`` (zeros for a pose that never moved).

    Raises:
        BayesmapError: if ``samples`` is not ``(N, S, 3)`` with ``N >= 1``.
    """
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 3 or samples.shape[0] < 1 or samples.shape[2] != 3:
        raise BayesmapError(f"pose samples must have shape (N, S, 3) with N >= 1, got {samples.shape}")
    ref = samples[0, :, 2]
    theta = ref + np.angle(np.exp(1j * circular_mean(samples[:, :, 2] - ref, axis=0)))
    mean = np.concatenate([samples[:, :, :2].mean(axis=0), theta[:, None]], axis=1)
    dev = samples - mean
    dev[:, :, 2] = wrap_angle(dev[:, :, 2])
    cov = np.einsum("nsi,nsj->sij", dev, dev) / samples.shape[0]
    return mean, cov


class SlamResult(NamedTuple):
    """The summary of a joint SLAM run (kept sweeps of every chain).

    Attributes:
        pose_samples: ``(N, S, 3)`` float64 sampled paths (x m, y m, theta rad), ``N = chains * (sweeps - burn_in)``.
        mean_path: ``(S, 3)`` float64 posterior mean path (:func:`pose_summary`).
        pose_cov: ``(S, 3, 3)`` float64 posterior pose covariances (m^2, m rad, rad^2).
        posterior: ``(nx, ny)`` float64 posterior wall probabilities: the mean over kept sweeps and chains of the
            conditional wall probabilities.
        acceptance_rate: the fraction of accepted pose moves over kept sweeps (1.0 for Gibbs draws); a
            multiple-try move that picks the current pose counts as accepted, so this overstates how often a pose
            moves; where a sweep is two kernels' (:func:`bayesmap.slam.poses.composed_pose_kernels`), a pose counts
            as moved when either moved it.
        runtime_s: wall-clock seconds of the run, compilation included.
        last_walls: ``(nx, ny)`` float32, the last chain's last map sample.
        grid: the grid of ``posterior`` (a real log's is fitted to the inferred path), or None: the problem's.
        loop_edges: loop edges of the start path's pose graph (real logs), or None.
        graph_cov: ``(S, 3, 3)`` float64 the pose graph's Laplace covariances at unit scale (real logs;
            :func:`bayesmap.slam.pipeline.graph_uncertainty`), or None.
        chain_posterior: ``(nx, ny)`` float64 the joint chain's own posterior wall probabilities where
            ``posterior`` is another map's (real logs: the final map at the mean path,
            :func:`bayesmap.slam.pipeline.run_log_slam`), or None (``posterior`` is the chain's).
        final_map_power: the likelihood power of that other map (real logs), or None.
        final_map_noise: its sensor noise, meters (real logs: :data:`bayesmap.slam.pipeline.FINAL_MAP_NOISE`), or
            None.
        loop_hypotheses: the last loop-closure round's hypotheses about which loop edges are true (real logs,
            :class:`bayesmap.slam.posegraph.LoopHypotheses`), or None (no loop edge found, or no loop closure).
        front_end_hypotheses: how many distinct front-end paths carried at least 1 % of the weight (real logs: 1
            for the single track; :func:`bayesmap.slam.particles.hypotheses`), or None.
        path_hypotheses: the start paths weighed where the front end's match and the odometry disagreed
            (:class:`bayesmap.slam.branches.PathHypotheses`), or None (no such step, or no branches).
    """

    pose_samples: np.ndarray
    mean_path: np.ndarray
    pose_cov: np.ndarray
    posterior: np.ndarray
    acceptance_rate: float
    runtime_s: float
    last_walls: np.ndarray
    grid: object = None
    loop_edges: int | None = None
    graph_cov: np.ndarray | None = None
    chain_posterior: np.ndarray | None = None
    final_map_power: float | None = None
    final_map_noise: float | None = None
    loop_hypotheses: object = None
    front_end_hypotheses: int | None = None
    path_hypotheses: object = None


def check_counts(sweeps, burn_in, chains) -> tuple[int, int, int]:
    """Validate the run's counts (BayesmapError naming the bad one)."""
    for name, value, low in (("sweeps", sweeps, 1), ("burn_in", burn_in, 0), ("chains", chains, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise BayesmapError(f"{name} must be an integer >= {low}, got {value!r}")
    if burn_in >= sweeps:
        raise BayesmapError(f"burn_in must be smaller than sweeps ({sweeps}), got {burn_in!r}")
    return int(sweeps), int(burn_in), int(chains)


def run_slam(problem, sweeps: int = 100, burn_in: int = 20, seed: int = 0, chains: int = 1,
             pose_kernel: SamplingAlgorithm | None = None, progress: ProgressCallback | None = None) -> SlamResult:
    """Infer the path and the map of a SLAM problem with the joint chain (:func:`slam_kernel`).

    The chains start at the path found by scan matching (:func:`scan_matching_path`) with the map after
    :data:`MAP_INIT_SWEEPS` dense sweeps at that path from an empty map; then ``sweeps`` joint steps, the first
    ``burn_in`` dropped. The start does not change the target, only how soon the chain reaches it: started at the
    odometry, the map fits the scans at the wrong poses and holds them there.

    Args:
        problem: a :class:`bayesmap.slam.problem.SlamProblem` (params, motion, odometry ``(S, 3)``, sensor angles and
            readings ``(S, K)``, likelihood power).
        sweeps: joint steps per chain, >= 1.
        burn_in: steps dropped, ``0 <= burn_in < sweeps``.
        seed: the random seed (``jax.random.key(seed)``).
        chains: independent chains (``vmap``), >= 1.
        pose_kernel: the pose kernel; default :func:`~bayesmap.slam.poses.lattice_pose_mh` with steps
            :data:`LATTICE_STEP_CELLS` cells and :data:`LATTICE_STEP_THETA` rad, half width
            :data:`LATTICE_HALF_WIDTH`.
        progress: a :data:`bayesmap.progress.ProgressCallback`, told of each joint sweep (stage ``"joint chain"``,
            unit sweep); None reports nothing. The chain is the same either way.

    Returns:
        A :class:`SlamResult`.

    Raises:
        BayesmapError: on bad counts (the message names the value) or bad problem data (as :func:`slam_kernel`).
    """
    sweeps, burn_in, chains = check_counts(sweeps, burn_in, chains)
    start = time.perf_counter()
    increments, covs = problem.motion_steps()
    data = slam_data(increments, covs, problem.sensor_angles, problem.readings, problem.params)
    eta = problem.likelihood_power
    if pose_kernel is None:
        step = LATTICE_STEP_CELLS * problem.params.grid.resolution
        pose_kernel = lattice_pose_mh(data, step, LATTICE_STEP_THETA, LATTICE_HALF_WIDTH, likelihood_power=eta)
    kernel = slam_kernel(data, pose_kernel, eta)
    key_init, key_run = jax.random.split(jax.random.key(seed))
    path = scan_matching_path(problem.odometry[0], data, eta)
    walls = initial_map(key_init, path, data, eta)
    poses, walls_run, accepted, wall_prob = run_slam_chains(key_run, kernel, kernel.init(path, walls), sweeps, chains,
                                                         progress)
    samples = np.asarray(poses[:, burn_in:], np.float64).reshape(-1, *poses.shape[2:])
    mean, cov = pose_summary(samples)
    posterior = np.asarray(wall_prob[:, burn_in:], np.float64).mean(axis=(0, 1))
    acceptance = float(np.asarray(accepted[:, burn_in:]).mean()) if accepted.shape[-1] else 1.0
    return SlamResult(pose_samples=samples, mean_path=mean, pose_cov=cov, posterior=posterior,
                      acceptance_rate=acceptance, runtime_s=time.perf_counter() - start,
                      last_walls=np.asarray(walls_run[-1, -1], np.float32))


def initial_map(key, poses, data: SlamData, likelihood_power: float = 1.0) -> jax.Array:
    """A starting map for the joint chain: :data:`MAP_INIT_SWEEPS` dense sweeps at ``poses`` ``(S, 3)`` from an
    empty map (``(nx, ny)`` float32). Any start leaves the target unchanged; this one spares the pose kernel an
    empty map, on which every reading looks like a max-range reading.

    Raises:
        BayesmapError: as :func:`slam_kernel`.
    """
    eta = check_likelihood_power(likelihood_power)
    params = data.params
    angles, y = dense_readings(data.sensor_angles, data.readings, params)
    return _initial_map(key, jnp.asarray(poses), angles, y, params, eta, prior_log_odds(params.prior_wall_prob))


@jax.jit
def _initial_map(key, poses, angles, y, params, eta, prior_lo):
    state = dense_state(jnp.zeros(params.grid.shape), poses, angles, params)

    def body(st, k):
        return dense_sweep(k, st, y, params, eta, prior_lo)[0], None

    return jax.lax.scan(body, state, jax.random.split(key, MAP_INIT_SWEEPS))[0].walls


def endpoint_map(poses, data: SlamData, used) -> jax.Array:
    """A rough map for scan matching: the cells just behind the endpoints of the returned (not max-range) readings of
    the scans ``used`` (``(S,)`` bool) at ``poses`` ``(S, 3)``, ``(nx, ny)`` float32 of 0/1. A reading stops at the
    face of its wall cell; half a cell further lies inside it. Jittable."""
    params = data.params
    grid = params.grid
    y = data.readings
    theta = poses[:, 2:3] + data.sensor_angles
    reach = y + 0.5 * grid.resolution
    ends = poses[:, None, :2] + reach[..., None] * jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)
    cells = jnp.floor(grid.to_cell_coords(ends) + 0.5).astype(jnp.int32).reshape(-1, 2)
    inside = jnp.all((cells >= 0) & (cells < jnp.asarray(grid.shape)), axis=-1) & (y.reshape(-1) < params.max_range)
    inside = inside & jnp.repeat(jnp.asarray(used), y.shape[1])
    flat = jnp.where(inside, cells[:, 0] * grid.shape[1] + cells[:, 1], grid.shape[0] * grid.shape[1])
    walls = jnp.zeros(grid.shape[0] * grid.shape[1] + 1, jnp.float32).at[flat].set(1.0)
    return walls[:-1].reshape(grid.shape)


def scan_matching_path(first_pose, data: SlamData, likelihood_power: float = 1.0) -> np.ndarray:
    """A starting path for the joint chain by sequential scan matching (the front end of a SLAM system; Olson 2009,
    "Real-time correlative scan matching", ICRA): for ``t = 1..S-1``, predict pose ``t`` by composing the previous
    estimate with the odometry increment, then search a coarse-to-fine lattice around it (:data:`MATCH_LEVELS`)
    for the candidate that maximizes ``motion log-density + eta * scan log-likelihood`` against the
    :func:`endpoint_map` of scans ``0..t-1`` at their estimates, the scan's likelihood under the robust beam mixture
    (*Probabilistic Robotics* sec. 6.3, :mod:`bayesmap.model.sensor` defaults, ``sigma_hit`` the model's sensor noise):
    the endpoint map has holes, and a beam through a hole must cost a random reading, not the Normal's tail. Only a
    starting point: it does not change the chain's target. ``first_pose`` ``(3,)`` is the fixed first pose.

    Returns:
        ``(S, 3)`` float64 path (x m, y m, theta rad), row 0 the fixed first pose.

    Raises:
        BayesmapError: on a bad likelihood power.
    """
    eta = check_likelihood_power(likelihood_power)
    params = data.params
    robust = make_params(params.prior_wall_prob, params.sensor_noise, params.num_angles, params.grid,
                         params.max_distance, beam_model="beam")
    res = params.grid.resolution
    levels = [lattice_offsets(h * res, ht, w) for h, ht, w in MATCH_LEVELS]
    s = data.readings.shape[0]
    path = jnp.zeros((s, 3), data.increments.dtype).at[0].set(jnp.asarray(first_pose, data.increments.dtype))
    scans = jnp.arange(s)
    for t in range(1, s):
        path = _match(path, t, scans < t, compose(path[t - 1], data.increments[t - 1]), data, levels, eta, robust)
    return np.asarray(path, np.float64)


@jax.jit
def _match(path, t, used, center, data, levels, eta, robust):
    """One step of :func:`scan_matching_path`: pose ``t`` by the coarse-to-fine search around ``center``."""
    prev = path[t - 1]
    walls = endpoint_map(path, data, used)
    best = center
    for offsets in levels:
        cands = best + offsets
        score = motion_logpdf(prev, cands, data.increments[t - 1], data.covs[t - 1]) + eta * scan_log_likelihood(
            walls, cands, data.sensor_angles[t], data.readings[t], robust)
        best = cands[jnp.argmax(score)]
    return path.at[t].set(best)
