"""SLAM scenes: scans taken along a path known only through odometry, and the SLAM pipeline's map model.

:class:`SlamProblem` is what the SLAM samplers take: the map model, the motion model, the odometry and the scans.
It is built from the tutorial's room (:func:`slam_tutorial_problem`), from any known map and path
(:func:`simulated_slam_problem`), or from a raw log whose pose fields hold odometry (:func:`log_slam_problem`).
The mapping problem of known poses is :class:`bayesmap.problem.Problem`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles
from bayesmap.io.ascii import tutorial_map
from bayesmap.model.generative import ModelParams, make_params, replace_params, simulate_scan_readings
from bayesmap.model.motion import MotionParams, composed_steps, odometry_controls, wrap_angle
from bayesmap.scenes import (
    LOG_BEAM_MODEL,
    LOG_CUT_PAST_READING,
    LOG_GEOMETRY,
    LOG_PRIOR,
    LOG_SENSOR_NOISE,
    LOG_WALL_PASS_PROB,
    RESOLUTION,
    TUTORIAL_NUM_ANGLES,
    TUTORIAL_PRIOR,
    TUTORIAL_SENSOR_NOISE,
    log_coupling,
    log_prior_wall_prob,
    log_problem,
)

# ---------------------------------------------------------------------------------------------------------------
# The SLAM pipeline's map model: the settings its defaults were cross-validated with (chord geometry, no range
# offset, since its pose moves cast chords)
# ---------------------------------------------------------------------------------------------------------------

SLAM_GEOMETRY = "chord"
"""Wall geometry of ``bayesmap slam --log`` (:func:`log_slam_problem`), maps and pose moves alike (the pose moves cast
each beam's first wall cell and its chord by grid traversal, :func:`bayesmap.geometry.raycast.march_first_chord`):
the chord geometry with no range offset. Chosen as a log's map geometry (:data:`bayesmap.scenes.LOG_GEOMETRY`); it
replaced the entry geometry with a range offset at equal ATE on Intel, ACES and CSAIL
([validation](../validation/defaults.md#slam_geometry))."""

SLAM_SENSOR_NOISE = 0.05
"""``sensor_noise`` of ``bayesmap slam --log``, meters (:func:`slam_map_settings`): a log's map noise when the SLAM
pipeline's other defaults were cross-validated with it
([validation](../validation/defaults.md#slam_likelihood_power))."""

SLAM_LIKELIHOOD_POWER = 0.1
"""Likelihood power of ``bayesmap slam --log``'s chain (maps and poses; :func:`slam_map_settings`) and front end: the
value its front end, motion noise, loop edges and path uncertainty were cross-validated with, and the front end's
power chosen by leave-one-log-out cross-validation of the start path's ATE over Intel, ACES and CSAIL
([validation](../validation/defaults.md#slam_likelihood_power)). The final map at the mean path follows the log
default (:func:`log_map_params`)."""


def slam_map_settings() -> dict:
    """The map model of ``bayesmap slam --log``, as keywords of :func:`log_problem`: :data:`SLAM_GEOMETRY` with no
    range offset, :data:`SLAM_SENSOR_NOISE`, :data:`SLAM_LIKELIHOOD_POWER`, the independent prior and wall cells
    that stop every beam (its pose moves cast to the first wall only), each returned beam cut
    :data:`bayesmap.scenes.LOG_CUT_PAST_READING` meters past its reading (maps and pose moves alike; the final map
    keeps the cut, :func:`log_map_params`)."""
    return {"geometry": SLAM_GEOMETRY, "range_offset": 0.0, "sensor_noise": SLAM_SENSOR_NOISE,
            "likelihood_power": SLAM_LIKELIHOOD_POWER, "coupling": 0.0, "wall_pass_prob": 0.0,
            "cut_past_reading": LOG_CUT_PAST_READING}


# ---------------------------------------------------------------------------------------------------------------
# SLAM at the tutorial's scale: a robot with noisy odometry on a loop around the tutorial's room
# ---------------------------------------------------------------------------------------------------------------

SLAM_ODOMETRY_ALPHAS = (0.05, 0.02, 0.05, 0.01)
"""PR Table 5.6's ``(a1, a2, a3, a4)`` (standard deviations) of the simulated odometry of
:func:`slam_tutorial_problem`: the defaults of ``tools/noisy_odometry.py`` (5 % of each turn, 0.02 rad of heading
per meter, 5 % of each distance, 0.01 m per radian). The model's motion noise is separate (``motion``)."""

SLAM_LOOP_CENTER = (6.0, 8.5)
"""Center of the built-in loop path, meters: the middle of the tutorial room's free space."""

SLAM_LOOP_RADII = (4.5, 4.0)
"""Half axes of the built-in loop (an ellipse), meters: every point of it keeps at least 1.1 m from the walls."""


@dataclass(frozen=True, eq=False)
class SlamProblem:
    """A SLAM problem: scans taken along a path that is known only through odometry.

    Attributes:
        params: the map and sensor parameters (grid, sensor model, prior).
        motion: the model's odometry motion noise (:class:`bayesmap.model.motion.MotionParams`).
        odometry: ``(S, 3)`` float64 odometry poses (x m, y m, theta rad), ``odometry[0]`` the fixed first pose.
        sensor_angles: ``(S, K)`` float64 beam angles relative to the heading, radians.
        readings: ``(S, K)`` float64 range readings, meters.
        true_poses: ``(S, 3)`` float64 true path, or None for real data.
        truth: ``(nx, ny)`` float32 true map, or None.
        likelihood_power: ``eta`` in (0, 1] (1: the posterior).
        source: a description for summaries.
        max_range_mask: ``(S, K)`` bool, True for max-range readings (no return), or None (none are).
        timestamps: ``(S,)`` float64 scan timestamps, seconds, or None (simulated scenes).
        range_offset: meters the model's ``readings`` are short of what the sensor read (returned beams only; the
            range offset of :func:`log_problem`, 0 for simulated scenes): the geometry of the scans themselves,
            used by scan matching, is ``readings + range_offset``.
        final_map_params: the map model of the final map drawn at the posterior mean path
            (:func:`bayesmap.slam.pipeline.run_log_slam`, stage 6), or None (no final map: the chain's own).
            :func:`log_slam_problem` sets the map model of a log at known poses (:func:`log_map_params`).
        final_map_power: the likelihood power of that final map, in (0, 1], or None: the log default at the mean
            path (:func:`log_likelihood_power` of its :func:`endpoints_per_cell`), which :func:`log_slam_problem`
            sets.
        steps: ``(increments (S - 1, 3), covariances (S - 1, 3, 3))`` the motion model's steps between consecutive
            scans where they are not one odometry step each (keyframes, or a selection of a log's scans that skips
            some: the steps of the scans between composed, :func:`bayesmap.model.motion.composed_steps`), or None:
            :func:`bayesmap.model.motion.odometry_controls` of ``odometry`` (:meth:`motion_steps`).
    """

    params: ModelParams
    motion: object
    odometry: np.ndarray
    sensor_angles: np.ndarray
    readings: np.ndarray
    true_poses: np.ndarray | None = None
    truth: np.ndarray | None = None
    likelihood_power: float = 1.0
    source: str = ""
    max_range_mask: np.ndarray | None = None
    timestamps: np.ndarray | None = None
    range_offset: float = 0.0
    final_map_params: ModelParams | None = None
    final_map_power: float | None = 1.0
    steps: tuple | None = None

    @property
    def num_scans(self) -> int:
        """``S``."""
        return self.odometry.shape[0]

    def motion_steps(self) -> tuple:
        """``(increments (S - 1, 3), covariances (S - 1, 3, 3))``: the motion model's step from each scan to the next,
        ``steps`` where given, else :func:`bayesmap.model.motion.odometry_controls` of the odometry under
        ``motion``."""
        return self.steps if self.steps is not None else odometry_controls(self.odometry, self.motion)


def simulate_odometry(true_poses, alphas=SLAM_ODOMETRY_ALPHAS, seed: int = 0) -> np.ndarray:
    """Noisy odometry of a true path: PR Table 5.6 (``sample_motion_model_odometry``) with the noise as standard
    deviations, exactly as ``tools/noisy_odometry.py``: each true motion split into ``(rot1, trans, rot2)``, each
    perturbed by a zero-mean Normal (``std(rot1) = a1 |rot1| + a2 trans``, ``std(trans) = a3 trans + a4 (|rot1| +
    |rot2|)``, ``std(rot2) = a1 |rot2| + a2 trans``; radians, meters), chained from the first true pose.

    Args:
        true_poses: ``(S, 3)`` true path (x m, y m, theta rad).
        alphas: ``(a1, a2, a3, a4)``, each >= 0.
        seed: ``numpy.random.default_rng`` seed.

    Returns:
        ``(S, 3)`` float64 odometry poses (headings wrapped to ``[-pi, pi)``), row 0 the true first pose.

    Raises:
        BayesmapError: if ``true_poses`` is not ``(S, 3)`` finite or there are not four alphas >= 0.
    """
    poses = np.asarray(true_poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3 or len(poses) < 1 or not np.all(np.isfinite(poses)):
        raise BayesmapError(f"true_poses must be finite with shape (S, 3), got {poses.shape}")
    a = np.asarray(alphas, dtype=np.float64)
    if a.shape != (4,) or not np.all(np.isfinite(a) & (a >= 0)):
        raise BayesmapError(f"alphas must be four finite numbers >= 0, got {alphas!r}")
    rng = np.random.default_rng(seed)
    out = [poses[0]]
    for (x0, y0, t0), (x1, y1, t1) in zip(poses[:-1], poses[1:]):
        trans = math.hypot(x1 - x0, y1 - y0)
        rot1 = wrap_angle(math.atan2(y1 - y0, x1 - x0) - t0) if trans > 1e-6 else 0.0
        rot2 = wrap_angle(t1 - t0 - rot1)
        r1 = rot1 + rng.normal(0, a[0] * abs(rot1) + a[1] * trans)
        tr = trans + rng.normal(0, a[2] * trans + a[3] * (abs(rot1) + abs(rot2)))
        r2 = rot2 + rng.normal(0, a[0] * abs(rot2) + a[1] * trans)
        ox, oy, ot = out[-1]
        out.append(np.array([ox + tr * math.cos(ot + r1), oy + tr * math.sin(ot + r1), wrap_angle(ot + r1 + r2)]))
    return np.stack(out)


def slam_tutorial_problem(seed: int = 0, num_poses: int = 8, motion=None, num_angles: int = TUTORIAL_NUM_ANGLES,
                          prior_wall_prob: float = TUTORIAL_PRIOR,
                          sensor_noise: float = TUTORIAL_SENSOR_NOISE) -> SlamProblem:
    """The tutorial's map scanned by a robot driving once around the room, known only through its odometry.

    The true path: ``num_poses`` poses equally spaced (counter-clockwise) on the ellipse :data:`SLAM_LOOP_CENTER`,
    :data:`SLAM_LOOP_RADII`, each heading along the loop; the odometry: :func:`simulate_odometry` of it with
    :data:`SLAM_ODOMETRY_ALPHAS` and ``seed``; the readings: the tutorial's sensor model (``num_angles`` equally
    spaced beams, relative to the heading) simulated at the true poses with ``jax.random.key(seed)``, clipped at 0
    as :func:`tutorial_problem`'s.

    Args:
        seed: seed of the odometry noise and of the readings.
        num_poses: ``S``, 2 to 64.
        motion: the model's motion noise (:class:`bayesmap.model.motion.MotionParams`); default its defaults.
        num_angles: beams per scan (the tutorial's ``num_angles``).
        prior_wall_prob: the prior probability of a wall (the tutorial's).
        sensor_noise: the standard deviation of a reading, meters (the tutorial's).

    Raises:
        BayesmapError: if ``num_poses`` is not an integer in 2..64, or on bad parameters (the message names them).
    """
    if isinstance(num_poses, bool) or not isinstance(num_poses, (int, np.integer)) or not 2 <= num_poses <= 64:
        raise BayesmapError(f"num_poses must be an integer from 2 to 64, got {num_poses!r}")
    walls = tutorial_map()
    params = make_params(prior_wall_prob, sensor_noise, num_angles, Grid(shape=walls.shape))
    phase = 2 * np.pi * np.arange(num_poses) / num_poses - np.pi / 2
    (cx, cy), (rx, ry) = SLAM_LOOP_CENTER, SLAM_LOOP_RADII
    heading = np.arctan2(ry * np.cos(phase), -rx * np.sin(phase))
    true_poses = np.column_stack([cx + rx * np.cos(phase), cy + ry * np.sin(phase), heading])
    return simulated_slam_problem(walls, true_poses, params, seed, motion,
                                  source=f"tutorial map, loop of {num_poses} poses, odometry seed {seed}")


def simulated_slam_problem(walls, true_poses, params: ModelParams, seed: int, motion=None,
                           source: str = "") -> SlamProblem:
    """A SLAM scene simulated on a known map: a robot at ``true_poses`` known only through its odometry.

    The odometry: :func:`simulate_odometry` of the true path with :data:`SLAM_ODOMETRY_ALPHAS` and ``seed``; the
    readings: ``params``' sensor model (``params.num_angles`` equally spaced beams, relative to the heading) simulated
    at the true poses with ``jax.random.key(seed)``, clipped at 0 as :func:`tutorial_problem`'s.

    Args:
        walls: ``(nx, ny)`` true map (cells > 0.5 are walls).
        true_poses: ``(S, 3)`` the robot's path (x m, y m, theta rad), ``S >= 2``.
        params: the model parameters (grid, sensor model, prior).
        seed: seed of the odometry noise and of the readings.
        motion: the model's motion noise (:class:`bayesmap.model.motion.MotionParams`); default its defaults.
        source: a description for summaries.
    """

    walls = (np.asarray(walls) > 0.5).astype(np.float32)
    true_poses = np.asarray(true_poses, dtype=np.float64)
    odometry = simulate_odometry(true_poses, SLAM_ODOMETRY_ALPHAS, seed)
    sensor_angles = np.tile(np.asarray(angles(params.num_angles), dtype=np.float64), (len(true_poses), 1))
    readings = simulate_scan_readings(jax.random.key(seed), walls, true_poses[:, :2], params,
                                      true_poses[:, 2:3] + sensor_angles)
    readings = np.maximum(np.asarray(readings, dtype=np.float64), 0.0)
    return SlamProblem(params=params, motion=MotionParams() if motion is None else motion, odometry=odometry,
                       sensor_angles=sensor_angles, readings=readings, true_poses=true_poses, truth=walls,
                       source=source)


# ---------------------------------------------------------------------------------------------------------------
# SLAM on a real log: scans whose pose fields hold odometry
# ---------------------------------------------------------------------------------------------------------------

SLAM_LOG_MARGIN = 5.0
"""Meters added around the odometry's endpoints for the grid of :func:`log_slam_problem`. The odometry's map is
distorted by its drift, so the inferred map's extent is only known after the front end; the runner
(:func:`bayesmap.slam.pipeline.run_log_slam`) fits the final grid to the matched path."""


def log_map_params(params: ModelParams) -> ModelParams:
    """``params`` (a log's model) with the map model of a log at known poses, :func:`log_problem`'s defaults: the
    geometry :data:`LOG_GEOMETRY`, the sensor noise :data:`LOG_SENSOR_NOISE`, the structured prior of
    :func:`log_coupling`, its prior wall probability :func:`log_prior_wall_prob` and the pass probability
    :data:`LOG_WALL_PASS_PROB`; the grid, the beam model and its weights and the max range kept. (Its likelihood
    power follows the density of the readings at the path, :func:`log_likelihood_power`.)"""
    coupling = log_coupling(params.grid.resolution)
    return replace_params(params, sensor_noise=LOG_SENSOR_NOISE, geometry=LOG_GEOMETRY,
                          prior_wall_prob=log_prior_wall_prob(coupling), coupling=coupling, neighbourhood=None,
                          wall_pass_prob=LOG_WALL_PASS_PROB, max_distance=params.max_range)


def log_slam_problem(log, scans=None, resolution: float = RESOLUTION, prior_wall_prob: float = LOG_PRIOR,
                     sensor_noise: float | None = None, beam_model: str = LOG_BEAM_MODEL,
                     range_offset: float | None = None, sensor_params: dict | None = None,
                     likelihood_power: float | None = None, motion=None) -> SlamProblem:
    """A SLAM problem from a log whose pose fields hold odometry (a raw log, or a bag read with its odometry).

    The sensor model is :func:`log_problem`'s beam mixture with the SLAM pipeline's map settings
    (:func:`slam_map_settings`: chord geometry, no range offset, sensor noise :data:`SLAM_SENSOR_NOISE`, power
    :data:`SLAM_LIKELIHOOD_POWER`, the independent prior); the readings
    are the model's readings (max-range readings at exactly the max range, returned readings minus the range
    offset). The grid covers the odometry's beam endpoints plus
    :data:`SLAM_LOG_MARGIN` meters; the runner refits it to the inferred path. The arguments not listed below are
    :func:`log_problem`'s.

    Where ``scans`` skips scans of the log (every other scan, say), the motion model's step from one chosen scan to
    the next is the odometry's steps through the skipped scans composed, their noise propagated
    (:func:`bayesmap.model.motion.composed_steps`, as between keyframes: the skipped poses marginalized), not one
    step of the odometry's net motion. A log holds the odometry of every scan; taken as one step, two steps that
    back up and turn back look like a plain step forward, and the motion model would claim a heading standard
    deviation of 0.05 rad where the simulated odometry of ACES erred by 0.4 rad
    ([validation](../validation/slam.md#the-odometry-through-the-scans-left-out)).

    Args:
        log: a :class:`bayesmap.io.carmen.CarmenLog`; its poses are the odometry.
        scans: scan indices (``(S,)`` ints, ``S >= 2``); default all. Not in increasing order: each step the
            odometry's net motion between the two scans, as one step of the motion model.
        motion: the motion noise (:class:`bayesmap.model.motion.MotionParams`); default its defaults.

    Raises:
        BayesmapError: on fewer than two scans, bad indices or bad parameters (the message names the value).
    """
    scans = np.arange(len(log)) if scans is None else np.asarray(scans, dtype=np.int64).reshape(-1)
    if len(scans) < 2:
        raise BayesmapError(f"SLAM needs at least two scans, got {len(scans)}")
    settings = slam_map_settings()
    given = {"sensor_noise": sensor_noise, "range_offset": range_offset, "likelihood_power": likelihood_power}
    settings.update({k: v for k, v in given.items() if v is not None})
    problem = log_problem(log, scans, resolution=resolution, prior_wall_prob=prior_wall_prob,
                          beam_model=beam_model, margin=SLAM_LOG_MARGIN, sensor_params=sensor_params, **settings)
    obs = problem.observations
    mask = obs.max_range_mask if obs.max_range_mask is not None else np.zeros(obs.readings.shape, bool)
    motion = MotionParams() if motion is None else motion
    gaps = np.diff(scans)
    steps = None
    if np.all(gaps >= 1) and np.any(gaps > 1):
        steps = composed_steps(np.asarray(log.poses, np.float64), scans[:-1], scans[1:], motion)
    return SlamProblem(params=problem.params, motion=motion,
                       odometry=np.asarray(problem.poses, np.float64), sensor_angles=obs.beam_angles,
                       readings=problem.model_readings, likelihood_power=problem.likelihood_power,
                       source=problem.source, max_range_mask=mask,
                       timestamps=np.asarray(log.timestamps, np.float64)[scans], range_offset=problem.range_offset,
                       final_map_params=log_map_params(problem.params), final_map_power=None, steps=steps)
