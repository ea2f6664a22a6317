"""Keyframes: SLAM on the scans where the robot moved, every other scan placed on the keyframes' map afterwards.

A log recorded the way bags are (a scan every few centimeters, Freiburg 079: 4,791 scans over 434 m) holds many
nearly identical scans. As Karto and slam_toolbox do (``MinimumTravelDistance``, ``minimum_travel_heading``),
bayesmap's SLAM keeps a scan as a keyframe when the odometry has moved :data:`KEYFRAME_DISTANCE` meters or turned
:data:`KEYFRAME_TURN` radians since the last keyframe (:func:`select_keyframes`; given the motion model's steps, it
also cuts where the steps since would compose to a heading the front end's search may not cover,
:data:`KEYFRAME_HEADING_SD`, which ``slam --log`` does not use); the SLAM model is the same model on
the keyframes' scans (:func:`keyframe_problem`), its step from one keyframe to the next the odometry's steps of the
scans between composed, their noise propagated to first order (:func:`bayesmap.model.motion.composed_steps`: the
intermediate poses marginalized). Taken as one step of the motion model instead, a 0.5 m step of Freiburg 079 would
claim a heading standard deviation of 0.06 rad where the five 0.1 m steps it is made of carry 0.6-1.1 rad, and the
odometry's real heading errors of 0.7 rad there would pin the front end (on some of its steps).

Every other scan is then placed (:func:`place_scans`):

* its prediction is its keyframe's (the last keyframe before it) posterior mean pose composed with the odometry's
  motion from the keyframe to the scan (the scans' steps between composed, their noise propagated:
  :func:`bayesmap.model.motion.composed_steps`);
* it is matched, by the front end's coarse-to-fine correlative search (:func:`bayesmap.slam.scanmatch.search`, the
  levels of :data:`PLACE_LEVELS`), against the likelihood fields of the keyframes' returned endpoints at the mean path
  (the keyframes' map), its score the fields' at the problem's likelihood power plus the motion model's
  log-density of that one step; a match that puts fewer than
  :data:`bayesmap.slam.scanmatch.MIN_HIT_FRACTION` of its endpoints on the map keeps the prediction, as the front end
  does;
* its covariance is its keyframe's plus the motion model's covariance of the step, rotated into the world frame
  (the keyframe's uncertainty carried along the odometry, *Probabilistic Robotics* sec. 5.4; the match's own
  spread, a few millimeters, is left out), and its samples are the keyframe's samples composed with the matched
  offset from the keyframe's mean pose, so that a scan moves with its keyframe in every sample.

The scans are placed independently of each other, in batches split over the devices JAX sees (``shard_map`` over
``jax.devices()``: one CPU, several CPU devices, a GPU or several), with the same poses on any number of devices
(``tests/slam/test_keyframes.py`` runs it on four CPU devices).

The keyframes cut the work of a bag-rate log by the ratio of its scans to its keyframes (about 3.5 on Freiburg 079);
on logs with a scan every 0.7-1 m (Intel, ACES, CSAIL) nearly every scan is a keyframe
([validation](../validation/scale.md#keyframes)).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental.shard_map import shard_map
from jax.sharding import Mesh, PartitionSpec

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import scan_endpoints
from bayesmap.model.motion import compose, compose_steps, motion_logpdf
from bayesmap.slam.posegraph import relative, rotation3
from bayesmap.slam.scanmatch import (
    MATCH_LEVELS,
    MIN_HIT_FRACTION,
    ScanData,
    add_to_fields,
    empty_fields,
    hit_fraction,
    lattices,
    search,
)

KEYFRAME_DISTANCE = 0.3
"""Meters of odometry travel since the last keyframe that make a scan a keyframe of ``bayesmap slam`` (with
:data:`KEYFRAME_TURN`). Chosen among 0.2, 0.3 and 0.5 m (Karto's ``MinimumTravelDistance`` default, between, and
slam_toolbox's ``minimum_travel_distance``) by leave-one-log-out cross-validation of the path's ATE over Intel, ACES
and CSAIL: the largest (cheapest) value whose ATE on each other log is at most 0.03 m (about the chain's own spread)
above its ATE with every scan a keyframe; it keeps 883 of Intel's 910 scans, 433 of ACES' 440, all of CSAIL's 406
and 1,373 of Freiburg 079's 4,791 ([validation](../validation/defaults.md#keyframe_distance-and-keyframe_turn))."""

KEYFRAME_TURN = 0.3
"""Radians of odometry turn since the last keyframe that make a scan a keyframe (about 17 degrees; with
:data:`KEYFRAME_DISTANCE`, chosen with it)."""

KEYFRAME_HEADING_SD = MATCH_LEVELS[0][1] * MATCH_LEVELS[0][3] / 3.5
"""Radians: with the motion model's steps, :func:`select_keyframes` also makes the scan before a step a keyframe where
the heading standard deviation of the odometry composed since the last keyframe would pass this (0.229 rad: the front
end's first search level reaches +-0.8 rad around each step's prediction, :data:`bayesmap.slam.scanmatch.
MATCH_LEVELS`, 3.5 of these). A keyframe's step composed of steps that jittered or backed up, each with an undirected
heading (:data:`bayesmap.model.motion.UNDIRECTED_RADIUS`), can carry a heading error beyond the search. Derived from
the search, not fitted. ``slam --log`` does not pass the steps, so it keyframes by distance and turn alone: the rule
kept ACES with odometry twice as noisy as the shared logs' (seed 1: 20.7 -> 0.12 m) but lost Freiburg 079's odometry
seed 2 at the shared noise (0.073 -> 3.618 m), by changing which local map one outlying step met
([validation](../validation/defaults.md#keyframe_heading_sd))."""

PLACE_LEVELS = ((0.05, 0.03, 2, 4, 1), *MATCH_LEVELS[1:])
"""The search that places a scan between keyframes: a coarse level on the broad field, +-0.1 m and +-0.12 rad around
the prediction in steps of 0.05 m and 0.03 rad, then the front end's fine levels (:data:`bayesmap.slam.scanmatch.
MATCH_LEVELS` without its first: +-0.09 m and +-0.042 rad more, down to 3 mm and 0.05 degrees). The odometry's error
over the at most :data:`KEYFRAME_DISTANCE` meters from a keyframe is centimeters; the front end's first level, +-0.4
m and +-0.8 rad, is for the front end's steps between keyframes, and would cost 15 times the candidates."""

FIELD_RESOLUTION = 0.05
"""Cell size of the keyframes' likelihood fields, meters (the front end's, :data:`bayesmap.slam.pipeline.
FRONT_END_RESOLUTION`)."""

PLACE_BATCH = 32
"""Scans matched at once (the search's candidates of this many scans are scored together)."""


def _check_threshold(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise BayesmapError(f"{name} must be a finite number >= 0, got {value!r}")
    return float(value)


def select_keyframes(odometry, distance: float = KEYFRAME_DISTANCE, turn: float = KEYFRAME_TURN, step_covs=None,
                     heading_sd: float = KEYFRAME_HEADING_SD) -> np.ndarray:
    """The keyframes of a path: the first scan, then every scan whose odometry pose lies ``distance`` meters or more
    from the last keyframe's or has turned ``turn`` radians or more from it (Karto's and slam_toolbox's rule). With
    the motion model's steps ``step_covs``, also every scan past which the heading's standard deviation of the
    steps composed since the last keyframe (the square root of the sum of their heading variances: the heading of
    composed steps is their sum) would exceed ``heading_sd``, so that no keyframe's step leaves the front end's
    search (:data:`KEYFRAME_HEADING_SD`); a single step that exceeds it alone stays one step.

    Args:
        odometry: ``(S, 3)`` odometry poses (x m, y m, theta rad), ``S >= 1``.
        distance: meters, >= 0 (:data:`KEYFRAME_DISTANCE`); 0 (or ``turn`` 0) keeps every scan.
        turn: radians, >= 0 (:data:`KEYFRAME_TURN`).
        step_covs: None (distance and turn alone), or ``(S - 1, 3, 3)`` the motion model's covariance of each step
            (m^2, m rad, rad^2; :meth:`bayesmap.slam.problem.SlamProblem.motion_steps`).
        heading_sd: radians, > 0 (``inf``: distance and turn alone).

    Returns:
        ``(K,)`` int64 ascending scan indices, ``K >= 1``, starting with 0.

    Raises:
        BayesmapError: on a bad ``odometry`` or ``step_covs`` shape, a negative or non-finite threshold, or a
            ``heading_sd`` that is not a number > 0 (named).
    """
    distance, turn = _check_threshold("keyframe distance", distance), _check_threshold("keyframe turn", turn)
    odometry = np.asarray(odometry, np.float64)
    if odometry.ndim != 2 or odometry.shape[1] != 3 or len(odometry) == 0:
        raise BayesmapError(f"odometry must have shape (S, 3) with S >= 1, got {odometry.shape}")
    if isinstance(heading_sd, bool) or not isinstance(heading_sd, (int, float)) or not heading_sd > 0:
        raise BayesmapError(f"keyframe heading_sd must be a number of radians > 0, got {heading_sd!r}")
    if distance == 0 or turn == 0:
        return np.arange(len(odometry), dtype=np.int64)
    variances = np.zeros(len(odometry) - 1)
    if step_covs is not None:
        step_covs = np.asarray(step_covs, np.float64)
        if step_covs.shape != (len(odometry) - 1, 3, 3):
            raise BayesmapError(f"step_covs must have shape {(len(odometry) - 1, 3, 3)}, got {step_covs.shape}")
        variances = np.clip(step_covs[:, 2, 2], 0.0, None)
    limit = float(heading_sd) ** 2
    keep, last, composed = [0], odometry[0].tolist(), 0.0
    for s, (x, y, theta) in enumerate(odometry.tolist()):
        if s == 0:
            continue
        if composed + variances[s - 1] > limit and keep[-1] < s - 1:  # the step to s would leave the search
            keep.append(s - 1)
            last, composed = odometry[s - 1].tolist(), 0.0
        composed += variances[s - 1]
        turned = abs((theta - last[2] + math.pi) % (2 * math.pi) - math.pi)  # wrapped to [-pi, pi)
        if math.hypot(x - last[0], y - last[1]) >= distance or turned >= turn:
            keep.append(s)
            last, composed = (x, y, theta), 0.0
    return np.asarray(keep, np.int64)


def keyframe_problem(problem, keyframes):
    """``problem`` (a :class:`bayesmap.slam.problem.SlamProblem`) on the scans ``keyframes`` ``(K,)`` only: its
    odometry, beams, readings, max-range mask, timestamps and true path (where known) taken at those scans, and its
    motion model's steps from keyframe to keyframe composed from the problem's steps between them
    (:meth:`~bayesmap.slam.problem.SlamProblem.motion_steps`, :func:`bayesmap.model.motion.compose_steps`: the
    intermediate poses marginalized, their odometry noise kept); the rest kept.
    """
    k = np.asarray(keyframes, np.int64)

    def take(a):
        return None if a is None else np.asarray(a)[k]

    steps = compose_steps(*problem.motion_steps(), k[:-1], k[1:])
    return dataclasses.replace(problem, odometry=take(problem.odometry), sensor_angles=take(problem.sensor_angles),
                               readings=take(problem.readings), true_poses=take(problem.true_poses),
                               max_range_mask=take(problem.max_range_mask), timestamps=take(problem.timestamps),
                               steps=steps)


def owners(num_scans: int, keyframes) -> np.ndarray:
    """``(S,)`` int64: for each scan, the index into ``keyframes`` of the last keyframe at or before it."""
    return np.searchsorted(np.asarray(keyframes), np.arange(num_scans), side="right") - 1


def step_moves(steps, keyframes) -> tuple[np.ndarray, np.ndarray]:
    """The odometry's motion from each scan's keyframe to the scan (:func:`owners`): the motion model's steps
    ``steps`` (``(increments (S - 1, 3), covariances (S - 1, 3, 3))``, a problem's
    :meth:`~bayesmap.slam.problem.SlamProblem.motion_steps`) between them composed
    (:func:`bayesmap.model.motion.compose_steps`): ``(increments (S, 3), covariances (S, 3, 3))`` float64; zero for
    the keyframes themselves."""
    num_scans = len(np.asarray(steps[0])) + 1
    start = np.asarray(keyframes, np.int64)[owners(num_scans, keyframes)]
    return compose_steps(*steps, start, np.arange(num_scans))


def keyframe_fields(grid: Grid, poses, sensor_angles, readings, returned, batch: int = PLACE_BATCH) -> tuple:
    """The likelihood fields (:func:`bayesmap.slam.scanmatch.add_to_fields`) on ``grid`` of the returned beams of
    scans ``(K, B)`` at ``poses`` ``(K, 3)``, added ``batch`` scans at a time (bounded temporaries)."""
    fields = empty_fields(grid)
    add = jax.jit(add_to_fields, static_argnums=1)
    for lo in range(0, len(poses), batch):
        part = slice(lo, lo + batch)
        fields = add(fields, grid, jnp.asarray(poses[part]), jnp.asarray(sensor_angles[part]),
                     jnp.asarray(readings[part]), jnp.asarray(returned[part]))
    return fields


def _place_one(fields, grid, steps, power, min_hit, keyframe, increment, cov, angles, readings, returned):
    prediction = compose(keyframe, increment)

    def log_prior(cands):
        return motion_logpdf(keyframe, cands, increment, cov) / power

    best, _ = search(fields, grid, prediction, angles, readings, returned, steps, log_prior)
    hits = hit_fraction(fields, grid, best, angles, readings, returned)
    return jnp.where(hits >= min_hit, best, prediction)


@functools.lru_cache(maxsize=8)
def _place_batch(grid: Grid, devices: tuple):
    """The compiled placement of a batch of scans on ``grid``'s fields, the batch split over ``devices`` (one
    ``shard_map`` block of the batch per device; the fields, lattices and scalars replicated)."""
    def place(fields, steps, power, min_hit, *batch):
        return jax.vmap(functools.partial(_place_one, fields, grid, steps, power, min_hit))(*batch)

    mesh = Mesh(np.asarray(devices), ("scans",))
    split = PartitionSpec("scans")
    return jax.jit(shard_map(place, mesh, in_specs=(PartitionSpec(),) * 4 + (split,) * 6, out_specs=split,
                             check_rep=False))


def place_scans(mean_path, keyframes, data: ScanData, likelihood_power: float,
                min_hit_fraction: float = MIN_HIT_FRACTION, batch: int = PLACE_BATCH) -> np.ndarray:
    """Every scan's pose, the keyframes' given: each other scan matched against the keyframes' map (module
    docstring).

    Args:
        mean_path: ``(K, 3)`` the keyframes' poses (x m, y m, theta rad).
        keyframes: ``(K,)`` their scan indices (:func:`select_keyframes`).
        data: every scan's beams and the motion model's steps from scan to scan
            (:class:`bayesmap.slam.scanmatch.ScanData`, ``S`` scans).
        likelihood_power: the fields' score is multiplied by it, in (0, 1] (the problem's).
        min_hit_fraction: a match with fewer endpoints on the map keeps the prediction.
        batch: scans matched per compiled call (rounded up to a multiple of the devices).

    Returns:
        ``(S, 3)`` float64 poses; the keyframes' rows are ``mean_path``.
    """
    mean_path, keyframes = np.asarray(mean_path, np.float64), np.asarray(keyframes, np.int64)
    num_scans = len(data.readings)
    poses = np.zeros((num_scans, 3))
    poses[keyframes] = mean_path
    others = np.setdiff1d(np.arange(num_scans), keyframes)
    if len(others) == 0:
        return poses
    angles, readings, returned = (np.asarray(a) for a in (data.sensor_angles, data.readings, data.returned))
    ends = scan_endpoints(mean_path, angles[keyframes], readings[keyframes], xp=np)[returned[keyframes]]
    grid = Grid.covering(np.vstack([ends, mean_path[:, :2]]), FIELD_RESOLUTION, margin=2.0)
    fields = keyframe_fields(grid, mean_path, angles[keyframes], readings[keyframes], returned[keyframes])
    increments, covs = step_moves((data.increments, data.covs), keyframes)
    start = mean_path[owners(num_scans, keyframes)]
    steps = lattices(PLACE_LEVELS)
    dtype = jnp.result_type(float)
    scalars = (jnp.asarray(likelihood_power, dtype), jnp.asarray(min_hit_fraction, dtype))
    devices = tuple(jax.devices())
    batch = -(-batch // len(devices)) * len(devices)  # a whole number of scans per device
    run = _place_batch(grid, devices)
    for lo in range(0, len(others), batch):
        part = others[lo:lo + batch]
        size = len(part)
        part = np.concatenate([part, np.full(batch - size, part[-1])])  # one compiled shape
        args = (start[part], increments[part], covs[part], angles[part], readings[part])
        out = run(fields, steps, *scalars, *(jnp.asarray(a, dtype) for a in args), jnp.asarray(returned[part]))
        poses[part[:size]] = np.asarray(out, np.float64)[:size]
    return poses


def placed_uncertainty(poses, keyframes, steps, keyframe_cov, keyframe_samples) -> tuple[np.ndarray, np.ndarray]:
    """Every scan's covariance and samples from its keyframe's (module docstring).

    Args:
        poses: ``(S, 3)`` every scan's pose (:func:`place_scans`).
        keyframes: ``(K,)`` scan indices of the keyframes.
        steps: ``(increments (S - 1, 3), covariances (S - 1, 3, 3))`` the motion model's steps from scan to scan
            (the problem's :meth:`~bayesmap.slam.problem.SlamProblem.motion_steps`).
        keyframe_cov: ``(K, 3, 3)`` the keyframes' covariances.
        keyframe_samples: ``(N, K, 3)`` the keyframes' pose samples.

    Returns:
        ``(cov (S, 3, 3), samples (N, S, 3))`` float64: a scan's covariance is its keyframe's plus the motion model's
        covariance of the step from it, rotated by the keyframe's heading; its samples are its keyframe's composed
        with its offset from the keyframe's pose. The keyframes' rows are theirs unchanged.
    """
    poses, keyframe_cov = np.asarray(poses, np.float64), np.asarray(keyframe_cov, np.float64)
    own = owners(len(poses), keyframes)
    _, step_covs = step_moves(steps, keyframes)
    heading = poses[np.asarray(keyframes)][own, 2]
    rot = rotation3(heading)
    cov = keyframe_cov[own] + rot @ step_covs @ np.swapaxes(rot, 1, 2)
    cov = (cov + np.swapaxes(cov, 1, 2)) / 2  # exactly symmetric (the steps' covariances are float32)
    kf_mean = poses[np.asarray(keyframes)][own]
    offsets = relative(kf_mean, poses)[None]
    base = np.asarray(keyframe_samples, np.float64)[:, own]
    c, s = np.cos(base[..., 2]), np.sin(base[..., 2])
    samples = np.stack([base[..., 0] + c * offsets[..., 0] - s * offsets[..., 1],
                        base[..., 1] + s * offsets[..., 0] + c * offsets[..., 1],
                        base[..., 2] + offsets[..., 2]], axis=-1)
    return cov, samples
