"""The SLAM model in GenJAX: the robot's poses as random choices, beside the map (the source of truth of every SLAM
sampler).

:data:`slam_model` draws poses ``1..S-1`` at ``"poses"`` from the odometry motion model (:mod:`bayesmap.model.motion`,
*Probabilistic Robotics* sec. 5.4; pose 0 is fixed: it anchors the frame), then the walls prior of
:data:`bayesmap.model.generative.multi_scan_model` and the readings of each scan at its pose, with beam angles
relative to the heading. With zero motion noise it is :data:`~bayesmap.model.generative.multi_scan_model` at the
odometry path. :func:`slam_args`, :func:`slam_choices`, :func:`log_joint_slam` and :func:`simulate_slam` go with it;
docs/slam.md derives the pose conditionals that :mod:`bayesmap.slam.poses` samples.
"""

from __future__ import annotations

import genjax
import jax
import jax.numpy as jnp
import numpy as np
from genjax import ChoiceMapBuilder as C

from bayesmap.errors import BayesmapError
from bayesmap.model import motion, prior
from bayesmap.model.generative import ModelParams, choices, scan_sensor_model, walls_prior


@genjax.gen
def slam_model(first_pose, odometry_increments, odometry_covs, params: ModelParams, sensor_angles):
    """Path and map together: poses from the odometry motion model, walls from the prior, readings at the poses.

    Poses ``1..S-1`` at ``"poses"`` ``(S - 1, 3)`` from :data:`bayesmap.model.motion.odometry_path` (PR sec. 5.4;
    the first pose is fixed: it anchors the frame), walls at ``"walls"`` (the prior of
    :data:`bayesmap.model.generative.multi_scan_model`), readings ``(S, K)`` at ``"readings"`` from
    :data:`~bayesmap.model.generative.scan_sensor_model` at the positions ``poses[:, :2]`` with world-frame angles
    ``poses[:, 2:3] + sensor_angles``. With zero motion noise (zero covariances) it is the known-pose
    :data:`~bayesmap.model.generative.multi_scan_model` at the composed odometry path.

    Args (see :func:`slam_args`):
        first_pose: ``(3,)`` the first pose (x m, y m, theta rad).
        odometry_increments: ``(S - 1, 3)`` the motion model's steps
            (:func:`bayesmap.model.motion.odometry_controls`).
        odometry_covs: ``(S - 1, 3, 3)`` their covariances.
        params: the map and sensor parameters.
        sensor_angles: ``(S, K)`` beam angles relative to the robot's heading, radians.

    Returns ``(poses (S, 3)`` with the first pose prepended, ``walls (nx, ny)`` bool, ``readings (S, K))``.
    """
    later = motion.odometry_path(first_pose, odometry_increments, odometry_covs) @ "poses"
    poses = jnp.concatenate([first_pose[None], later], axis=0)
    walls = walls_prior(params.grid.shape)(params.prior_wall_prob) @ "walls"
    readings = scan_sensor_model(poses[:, :2], walls, params, poses[:, 2:3] + sensor_angles) @ "readings"
    if params.structured:  # as in bayesmap.model.generative.full_model
        prior.connections(walls, params.coupling) @ "connections"
    return poses, walls, readings


def slam_args(first_pose, odometry_increments, odometry_covs, params: ModelParams, sensor_angles) -> tuple:
    """The argument tuple of :data:`slam_model` as JAX arrays of the default float dtype (shapes as there).

    Raises:
        BayesmapError: if ``first_pose`` is not ``(3,)``, the increments not ``(S - 1, 3)``, the covariances not
            ``(S - 1, 3, 3)``, ``sensor_angles`` not ``(S, K)`` with ``K >= 1``, or a value is not finite.
    """
    dtype = jnp.result_type(float)
    first_pose = np.asarray(first_pose, dtype=np.float64)
    sensor_angles = np.asarray(sensor_angles, dtype=np.float64)
    increments = np.asarray(odometry_increments, dtype=np.float64)
    covs = np.asarray(odometry_covs, dtype=np.float64)
    if first_pose.shape != (3,):
        raise BayesmapError(f"first_pose must have shape (3,) (x m, y m, theta rad), got {first_pose.shape}")
    if sensor_angles.ndim != 2 or sensor_angles.shape[0] < 1 or sensor_angles.shape[1] < 1:
        raise BayesmapError(f"sensor_angles must have shape (S, K) with S, K >= 1, got {sensor_angles.shape}")
    steps = sensor_angles.shape[0] - 1
    if increments.shape != (steps, 3):
        raise BayesmapError(f"odometry_increments must have shape (S - 1, 3) = ({steps}, 3), got {increments.shape}")
    if covs.shape != (steps, 3, 3):
        raise BayesmapError(f"odometry_covs must have shape (S - 1, 3, 3) = ({steps}, 3, 3), got {covs.shape}")
    if not all(np.all(np.isfinite(a)) for a in (first_pose, sensor_angles, increments, covs)):
        raise BayesmapError("first_pose, odometry and sensor angles must be finite")
    return (jnp.asarray(first_pose, dtype=dtype), jnp.asarray(increments, dtype=dtype),
            jnp.asarray(covs, dtype=dtype), params, jnp.asarray(sensor_angles, dtype=dtype))


def slam_choices(poses, walls, readings, params: ModelParams | None = None):
    """The choice map of :data:`slam_model`: ``{"poses": poses[1:], "walls": walls, "readings": readings}`` from the
    whole path ``poses`` ``(S, 3)`` (its first pose is the model's argument, not a choice); with ``params`` of a
    structured prior also the observed ``"connections"`` (:func:`choices`)."""
    return C["poses"].set(jnp.asarray(poses)[1:]) | choices(walls, readings, params)


@jax.jit
def _assess_slam(poses, walls, readings, args):
    return slam_model.assess(slam_choices(poses, walls, readings, args[3]), args)[0]


def log_joint_slam(poses, walls, readings, odometry_increments, odometry_covs, params: ModelParams, sensor_angles):
    """``log p(poses, walls, readings)`` under :data:`slam_model`: exactly its ``assess`` score.

    Args:
        poses: ``(S, 3)`` the path (x m, y m, theta rad); ``poses[0]`` is the fixed first pose (the model's
            argument).
        walls: ``(nx, ny)`` array of 0/1 (float or bool).
        readings: ``(S, K)`` range readings, meters.
        odometry_increments: ``(S - 1, 3)`` (:func:`bayesmap.model.motion.odometry_controls`).
        odometry_covs: ``(S - 1, 3, 3)``.
        params: the model parameters.
        sensor_angles: ``(S, K)`` beam angles relative to the heading, radians.

    Returns:
        A scalar JAX float.

    Raises:
        BayesmapError: on shapes that do not match (:func:`slam_args`), ``poses`` not ``(S, 3)`` or readings not
            ``(S, K)``.
    """
    poses = jnp.asarray(poses, dtype=jnp.result_type(float))
    if poses.ndim != 2 or poses.shape[0] < 1 or poses.shape[1] != 3:
        raise BayesmapError(f"poses must have shape (S, 3) (x m, y m, theta rad), got {tuple(poses.shape)}")
    args = slam_args(poses[0], odometry_increments, odometry_covs, params, sensor_angles)
    if poses.shape != (args[4].shape[0], 3):
        raise BayesmapError(f"poses must have shape (S, 3) = ({args[4].shape[0]}, 3), got {tuple(poses.shape)}")
    readings = jnp.asarray(readings)
    if readings.shape != args[4].shape:
        raise BayesmapError(f"readings must have shape {tuple(args[4].shape)} (S, K), got {tuple(readings.shape)}")
    return _assess_slam(poses, jnp.asarray(walls, dtype=jnp.float32), readings, args)


def simulate_slam(key, first_pose, odometry_increments, odometry_covs, params: ModelParams, sensor_angles):
    """Sample ``(poses (S, 3), walls (nx, ny) bool, readings (S, K))`` from :data:`slam_model` with ``key``
    (arguments as :func:`slam_args`).

    Raises:
        BayesmapError: on shapes that do not match.
    """
    trace = slam_model.simulate(key, slam_args(first_pose, odometry_increments, odometry_covs, params, sensor_angles))
    return trace.get_retval()
