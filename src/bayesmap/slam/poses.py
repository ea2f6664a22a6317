"""Exact pose conditionals given the map, and MCMC kernels over the robot's poses (the SLAM model's path).

The target is :data:`bayesmap.model.slam.slam_model`'s posterior over the poses given the walls: for a pose
``t >= 1`` (pose 0 is fixed), everything in the model's ``assess`` score that depends on ``pose_t`` is

    log p(pose_t | pose_{t-1})  +  log p(pose_{t+1} | pose_t)  (if t < S - 1)  +  eta log p(readings_t | walls, pose_t)

(motion model: :func:`bayesmap.model.motion.motion_logpdf`; scan likelihood: :func:`scan_log_likelihood`; ``eta``
the likelihood power, 1 for the posterior). :func:`pose_log_conditional` evaluates it at many candidate poses at
once (vmapped exact ray casts), and the kernels draw from it:

* :func:`discrete_pose_gibbs`: Gibbs over each pose restricted to a given finite candidate set (a model whose poses
  take a few discrete values; the enumeration test uses it);
* :func:`lattice_pose_mh`: for continuous poses, a multiple-try Metropolis move per pose (Liu, Liang & Wong 2000,
  "The multiple-try method and local optimization in Metropolis sampling", JASA 95): the candidates are the current
  pose plus a symmetric lattice of offsets (correlative scan matching's window, Olson 2009, "Real-time correlative
  scan matching", ICRA), one is picked with probability proportional to its conditional and accepted with
  ``min(1, Z(x) / Z(x'))``; see docs/slam.md for the derivation;
* :func:`random_walk_pose_mh`: random-walk Metropolis per pose, the odd poses at once and then the even ones (the
  kernel for real logs);
* :func:`segment_pose_mh`: Metropolis-Hastings moves of whole stretches of the path, each moved rigidly in the frame
  of its first pose (the two end steps and the stretch's scans decide), so that a stretch the scans leave free to
  slide moves as a whole; :func:`composed_pose_kernels` runs it after another kernel.

All are BlackJAX-style: pure ``init(poses, walls) -> PoseState`` and ``step(key, state) -> (PoseState,
PoseInfo)``, jittable, keys passed explicitly; they leave the walls unchanged, so they compose with the map kernels
of :mod:`bayesmap.inference` (Gibbs over the walls given the poses) into a chain on the joint posterior.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.tree_util import Partial

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raycast import march_first_chord, march_first_hit, march_ray_chords
from bayesmap.inference.base import SamplingAlgorithm
from bayesmap.model.generative import (
    ModelParams,
    check_likelihood_power,
    check_scan_powers,
    reading_log_likelihood,
    scan_power,
)
from bayesmap.model.motion import compose, motion_error, motion_logpdf


class SlamData(NamedTuple):
    """What the pose conditionals condition on besides the poses and the walls (a pytree).

    Attributes:
        increments: ``(S - 1, 3)`` odometry increments (dx m, dy m, dtheta rad) in the previous pose's frame.
        covs: ``(S - 1, 3, 3)`` their covariances (:func:`bayesmap.model.motion.odometry_controls`).
        sensor_angles: ``(S, K)`` beam angles relative to the heading, radians.
        readings: ``(S, K)`` range readings, meters.
        params: the map and sensor parameters (:class:`bayesmap.model.generative.ModelParams`).
    """

    increments: jax.Array
    covs: jax.Array
    sensor_angles: jax.Array
    readings: jax.Array
    params: ModelParams


def slam_data(odometry_increments, odometry_covs, sensor_angles, readings, params: ModelParams) -> SlamData:
    """Build :class:`SlamData` (JAX arrays of the default float dtype) after checking the shapes.

    Raises:
        BayesmapError: if ``sensor_angles`` is not ``(S, K)`` with ``S >= 2`` (there is no pose to infer with one
            scan), ``readings`` not ``(S, K)``, the increments not ``(S - 1, 3)``, the covariances not
            ``(S - 1, 3, 3)``, or a value is not finite. Either wall geometry (``params.geometry``) is supported by
            the pose moves; the dense map sweep of :mod:`bayesmap.slam.joint` supports only ``"entry"``.
    """
    dtype = jnp.result_type(float)
    arrays = [np.asarray(a, dtype=np.float64) for a in (odometry_increments, odometry_covs, sensor_angles, readings)]
    increments, covs, angles, y = arrays
    if angles.ndim != 2 or angles.shape[0] < 2 or angles.shape[1] < 1:
        raise BayesmapError(f"sensor_angles must have shape (S, K) with S >= 2, K >= 1, got {angles.shape}")
    s = angles.shape[0]
    for name, a, shape in (("readings", y, angles.shape), ("odometry_increments", increments, (s - 1, 3)),
                           ("odometry_covs", covs, (s - 1, 3, 3))):
        if a.shape != shape:
            raise BayesmapError(f"{name} must have shape {shape}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise BayesmapError(f"{name} must be finite")
    return SlamData(*(jnp.asarray(a, dtype=dtype) for a in arrays), params=params)


def scan_log_likelihood(walls, poses, sensor_angles, readings, params: ModelParams):
    """The sensor model's log-likelihood of one scan's readings at each candidate pose.

    Args:
        walls: ``(nx, ny)`` array, cells > 0 are walls.
        poses: ``(M, 3)`` candidate poses (x m, y m, theta rad).
        sensor_angles: ``(K,)`` beam angles relative to the heading, radians.
        readings: ``(K,)`` range readings, meters.
        params: the model parameters (grid, max range, sensor model).

    Returns:
        ``(M,)`` float: ``sum_k log p(readings_k | exact distance at the pose)``, the exact ray cast by grid
        traversal (:func:`bayesmap.geometry.raycast.march_first_hit`, the numbers of
        :func:`~bayesmap.geometry.raycast.first_hit_distances`; in the ``"chord"`` geometry the first wall cell's entry
        and exit, :func:`~bayesmap.geometry.raycast.march_first_chord`, the numbers of
        :func:`~bayesmap.geometry.raycast.first_hit_chords`) at world-frame angles ``theta + sensor_angles`` and
        :func:`bayesmap.model.generative.reading_log_likelihood`: the arithmetic of the model's ``assess``. With
        beams cut past their readings (``params.cut_past_reading`` finite) each beam's traversal stops one cell past
        its cut, where the cut likelihood no longer depends on the walls (the same numbers as a traversal to the max
        range, tested). Never raises.
    """
    walls = jnp.asarray(walls)
    stops = _cut_stops(readings, params)

    def one(pose):
        if params.geometry == "chord":
            chord = march_first_chord(walls, pose[:2], pose[2] + sensor_angles, params.grid, params.max_range, stops)
            return jnp.sum(reading_log_likelihood(readings, chord[:, 0], params, chord[:, 1]))
        d = march_first_hit(walls, pose[:2], pose[2] + sensor_angles, params.grid, params.max_range, stops)
        return jnp.sum(reading_log_likelihood(readings, d, params))

    return jax.vmap(one)(jnp.asarray(poses))


def scans_log_likelihood(walls, poses, sensor_angles, readings, params: ModelParams):
    """The sensor model's log-likelihood of each of ``M`` scans at its own pose, all their beams cast at once.

    Args:
        walls: ``(nx, ny)`` array, cells > 0 are walls.
        poses: ``(M, 3)`` one pose per scan (x m, y m, theta rad).
        sensor_angles: ``(M, K)`` beam angles relative to the heading, radians.
        readings: ``(M, K)`` range readings, meters.
        params: the model parameters (grid, max range, sensor model; opaque walls).

    Returns:
        ``(M,)`` float: row ``m`` is :func:`scan_log_likelihood` of scan ``m`` at ``poses[m]`` (the same numbers,
        tested), the rays traversed by :func:`bayesmap.geometry.raycast.march_ray_chords` (stopped one cell past the
        cut where beams are cut past their readings), whose loop follows the beams' total length rather than the
        longest beam. Never raises.
    """
    poses, readings = jnp.asarray(poses), jnp.asarray(readings)
    m, k = readings.shape
    stops = _cut_stops(readings, params)
    origins = jnp.broadcast_to(poses[:, None, :2], (m, k, 2))
    chords = march_ray_chords(walls, origins, poses[:, 2:3] + sensor_angles, params.grid, params.max_range,
                              stops).reshape(m, k, 2)
    exits = chords[..., 1] if params.geometry == "chord" else None
    return jnp.sum(reading_log_likelihood(readings, chords[..., 0], params, exits), axis=1)


def _cut_stops(readings, params: ModelParams):
    """Where each beam's traversal may stop, meters (``readings``' shape), or None: with beams cut past their
    readings a wall entered at or past ``y + cut`` counts as none, so a traversal looks one cell further, no more."""
    if not params.cut:
        return None
    return jnp.asarray(readings) + (params.cut_past_reading + params.grid.resolution)


def _motion_terms(t, candidates, poses, data: SlamData):
    """The motion model's part of :func:`pose_log_conditional` ``(M,)`` for a (possibly traced) ``t``: the steps
    ``t - 1 -> candidate`` and, if ``t < S - 1``, ``candidate -> t + 1``."""
    last = poses.shape[0] - 1
    before = motion_logpdf(poses[t - 1], candidates, data.increments[t - 1], data.covs[t - 1])
    nxt = jnp.minimum(t, last - 1)
    after = motion_logpdf(candidates, poses[jnp.minimum(t + 1, last)], data.increments[nxt], data.covs[nxt])
    return before + jnp.where(t < last, after, 0.0)


def _log_conditional(t, candidates, poses, walls, data: SlamData, eta):
    """:func:`pose_log_conditional` for a (possibly traced) ``t`` in ``1..S-1``, without checks; ``eta`` a float or
    per-scan powers (:func:`bayesmap.model.generative.check_scan_powers`)."""
    like = scan_log_likelihood(walls, candidates, data.sensor_angles[t], data.readings[t], data.params)
    return _motion_terms(t, candidates, poses, data) + scan_power(eta, t) * like


def pose_log_conditional(t: int, candidates, poses, walls, data: SlamData, likelihood_power: float = 1.0):
    """``log p(pose_t = candidate | other poses, walls, readings)`` up to a constant (the same for every candidate).

    Args:
        t: the pose's index, ``1 <= t <= S - 1`` (pose 0 is fixed).
        candidates: ``(M, 3)`` candidate poses (x m, y m, theta rad).
        poses: ``(S, 3)`` the current path (its row ``t`` is ignored).
        walls: ``(nx, ny)`` the map.
        data: the odometry, sensor angles, readings and parameters (:func:`slam_data`).
        likelihood_power: ``eta`` in (0, 1]: the scan's log-likelihood is multiplied by it.

    Returns:
        ``(M,)`` float: motion(``t - 1 -> candidate``) + motion(``candidate -> t + 1``, if ``t < S - 1``) + ``eta``
        times :func:`scan_log_likelihood`; ``-inf`` where the motion model rules a candidate out.

    Raises:
        BayesmapError: if ``t`` is not an integer in ``1..S-1`` (the message names it), or ``likelihood_power`` is
            not in (0, 1].
    """
    poses = jnp.asarray(poses)
    if int(t) != t or not 1 <= int(t) < poses.shape[0]:
        raise BayesmapError(f"t must be an integer in 1..{poses.shape[0] - 1} (pose 0 is fixed), got {t!r}")
    eta = check_likelihood_power(likelihood_power)
    return _log_conditional_jit(int(t), jnp.asarray(candidates, dtype=poses.dtype), poses, jnp.asarray(walls), data,
                                eta)


_log_conditional_jit = jax.jit(_log_conditional)


class PoseState(NamedTuple):
    """State of a pose kernel: ``poses`` ``(S, 3)`` (x m, y m, theta rad; row 0 fixed) and ``walls`` ``(nx, ny)``
    (the map the poses are conditioned on; the pose kernels leave it unchanged); ``scan_log_lik`` ``(S,)`` the
    untempered :func:`scan_log_likelihood` of each scan at its pose given ``walls`` (:func:`random_walk_pose_mh`'s
    ``init`` computes it, so that a move casts the proposal's rays only), or None (computed where needed; a state
    built from new walls must not carry an old one)."""

    poses: jax.Array
    walls: jax.Array
    scan_log_lik: jax.Array | None = None


class PoseInfo(NamedTuple):
    """What a pose sweep reports: ``accepted`` ``(S - 1,)`` bool, whether each pose ``1..S-1`` moved to the
    proposed candidate (always True for Gibbs draws), and ``log_conditional`` ``(S - 1,)`` float, the log
    conditional of each pose's new value (up to its constant)."""

    accepted: jax.Array
    log_conditional: jax.Array


def _init(poses, walls) -> PoseState:
    poses = jnp.asarray(poses, dtype=jnp.result_type(float))
    return PoseState(poses=poses, walls=jnp.asarray(walls, dtype=jnp.float32))


def _algorithm(update, init=Partial(_init)) -> SamplingAlgorithm:
    """A pose kernel from its per-pose ``update`` (a ``jax.tree_util.Partial`` of a module function and the kernel's
    arrays) and its ``init`` (a ``Partial`` too): ``init`` and ``step`` are pytrees of module functions and arrays, so
    a compiled chain takes the arrays as arguments and is reused by every kernel of the same shapes
    (:mod:`bayesmap.inference.chains`)."""
    return SamplingAlgorithm(init=init, step=Partial(_sweep, update))


def _sweep(update, key, state: PoseState):
    """Apply ``update(key, t, poses, walls, scan_log_lik) -> (pose, accepted, log_conditional, scan_log_lik)`` to
    ``t = 1..S-1`` in order (``scan_log_lik``: the state's, None where it has none)."""
    num_steps = state.poses.shape[0] - 1
    keys = jax.random.split(key, num_steps)

    def body(i, carry):
        poses, accepted, logc, cache = carry
        pose, acc, lc, cache = update(keys[i], i + 1, poses, state.walls, cache)
        return poses.at[i + 1].set(pose), accepted.at[i].set(acc), logc.at[i].set(lc), cache

    init = (state.poses, jnp.zeros(num_steps, bool), jnp.zeros(num_steps, state.poses.dtype), state.scan_log_lik)
    poses, accepted, logc, cache = jax.lax.fori_loop(0, num_steps, body, init)
    return PoseState(poses=poses, walls=state.walls, scan_log_lik=cache), PoseInfo(accepted=accepted,
                                                                                    log_conditional=logc)


def discrete_pose_gibbs(data: SlamData, candidates, likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """Gibbs over the poses restricted to finite candidate sets: for ``t = 1..S-1`` in order, draw ``pose_t`` from
    its exact conditional (:func:`pose_log_conditional`) over ``candidates[t]``.

    It is a Gibbs sampler of the model whose pose ``t`` takes the values ``candidates[t]`` (the SLAM model's density
    restricted to them): the chain stays on them if it starts on them (the current pose is one of the candidates;
    its own value is not used). Source: Geman & Geman 1984 (systematic-scan Gibbs).

    Args:
        data: :func:`slam_data`.
        candidates: ``(S, C, 3)`` candidate poses per scan (row 0 unused: pose 0 is fixed).
        likelihood_power: ``eta`` in (0, 1], or one power per scan ``(S,)`` in [0, 1]
            (:func:`bayesmap.model.generative.check_scan_powers`).

    Returns:
        A :class:`bayesmap.inference.base.SamplingAlgorithm`: ``init(poses (S, 3), walls (nx, ny)) -> PoseState``,
        ``step(key, PoseState) -> (PoseState, PoseInfo)``.

    Raises:
        BayesmapError: if ``candidates`` is not ``(S, C, 3)`` with ``C >= 1``, or ``likelihood_power`` is bad.
    """
    s = data.sensor_angles.shape[0]
    eta = check_scan_powers(likelihood_power, s)
    cands = jnp.asarray(candidates, dtype=data.increments.dtype)
    if cands.ndim != 3 or cands.shape[0] != s or cands.shape[1] < 1 or cands.shape[2] != 3:
        raise BayesmapError(f"candidates must have shape (S, C, 3) = ({s}, C, 3), got {tuple(cands.shape)}")

    return _algorithm(Partial(_discrete_update, cands, data, eta))


def _discrete_update(cands, data, eta, key, t, poses, walls, cache):
    """:func:`discrete_pose_gibbs`'s draw of pose ``t`` (``_sweep``'s ``update``; no cache)."""
    logw = _log_conditional(t, cands[t], poses, walls, data, eta)
    j = jax.random.categorical(key, logw)
    return cands[t, j], jnp.bool_(True), logw[j], cache


def lattice_offsets(h_xy: float, h_theta: float, half_width: int = 2):
    """The symmetric window of offsets ``(L, 3)``, ``L = (2 w + 1)^3``: ``(i h_xy, j h_xy, k h_theta)`` for ``i, j,
    k`` in ``-w..w`` (meters, meters, radians). Symmetric (``-o`` is in it with ``o``), as the MTM move needs.

    Raises:
        BayesmapError: if a step is not finite and > 0 or ``half_width`` is not an integer >= 1.
    """
    h_xy, h_theta = _positive("h_xy", h_xy), _positive("h_theta", h_theta)
    if not isinstance(half_width, (int, np.integer)) or half_width < 1:
        raise BayesmapError(f"half_width must be an integer >= 1, got {half_width!r}")
    r = np.arange(-half_width, half_width + 1, dtype=np.float64)
    grid = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    return jnp.asarray(grid * np.array([h_xy, h_xy, h_theta]), dtype=jnp.result_type(float))


def _positive(name: str, value) -> float:
    """``value`` as a float, checked finite and > 0 (else a BayesmapError naming ``name`` and the value)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BayesmapError(f"{name} must be a finite number > 0, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise BayesmapError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def lattice_pose_mh(data: SlamData, h_xy: float, h_theta: float, half_width: int = 2, jitter: float = 0.5,
                    likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """Multiple-try Metropolis over each pose with a lattice window of candidates (exact for the pose posterior).

    For ``t = 1..S-1`` in order, with ``x`` the current pose and ``pi`` its conditional
    (:func:`pose_log_conditional`): draw the step sizes ``h = (h_xy u_x, h_xy u_y, h_theta u_theta)`` with ``u ~
    Uniform(1 - jitter, 1 + jitter)`` each (independent of ``x``); score the window ``x + O_h``
    (:func:`lattice_offsets` with those steps); pick ``x'`` with probability ``pi(x') / Z(x)``, ``Z(x)`` the sum of
    ``pi`` over ``x + O_h``; score ``x' + O_h`` for ``Z(x')``; accept ``x'`` with probability
    ``min(1, Z(x) / Z(x'))``. Because ``O_h`` is symmetric, this is Metropolis-Hastings with the proposal
    ``q(x -> x') = pi(x') / Z(x)``, whose ratio is ``Z(x) / Z(x')`` (derivation in docs/slam.md; Liu, Liang & Wong
    2000, with the whole window as the tries). Each fixed ``h`` leaves the conditional invariant, so the mixture over
    random ``h`` does too; the random steps make the chain irreducible on the continuous poses (with ``jitter = 0``
    it only visits ``x_0`` plus the lattice). The window is correlative scan matching's search (Olson 2009).

    Args:
        data: :func:`slam_data`.
        h_xy: lattice step in x and y, meters, > 0.
        h_theta: lattice step in theta, radians, > 0.
        half_width: ``w``, the window has ``(2 w + 1)^3`` candidates.
        jitter: in ``[0, 1)``; the steps' relative spread (0: a fixed lattice).
        likelihood_power: ``eta`` in (0, 1], or one power per scan ``(S,)`` in [0, 1]
            (:func:`bayesmap.model.generative.check_scan_powers`).

    Returns:
        A :class:`bayesmap.inference.base.SamplingAlgorithm`: ``init(poses (S, 3), walls (nx, ny)) -> PoseState``,
        ``step(key, PoseState) -> (PoseState, PoseInfo)`` (``accepted``: the move was accepted).

    Raises:
        BayesmapError: on a bad step, half width, jitter or likelihood power (the message names it).
    """
    eta = check_scan_powers(likelihood_power, data.sensor_angles.shape[0])
    unit = lattice_offsets(1.0, 1.0, half_width)
    try:
        jitter_value = float(jitter)
    except (TypeError, ValueError):
        jitter_value = math.nan
    if not 0 <= jitter_value < 1:
        raise BayesmapError(f"jitter must be a number in [0, 1), got {jitter!r}")
    h_xy, h_theta = _positive("h_xy", h_xy), _positive("h_theta", h_theta)
    steps = jnp.asarray([h_xy, h_xy, h_theta], dtype=unit.dtype)

    return _algorithm(Partial(_lattice_update, unit, steps, jitter_value, data, eta))


def _lattice_update(unit, steps, jitter, data, eta, key, t, poses, walls, cache):
    """:func:`lattice_pose_mh`'s move of pose ``t`` (``_sweep``'s ``update``; no cache)."""
    center = unit.shape[0] // 2  # the zero offset: the current pose
    k_h, k_pick, k_acc = jax.random.split(key, 3)
    offsets = unit * steps * jax.random.uniform(k_h, (3,), steps.dtype, 1 - jitter, 1 + jitter)
    x = poses[t]
    logw = _log_conditional(t, x + offsets, poses, walls, data, eta)
    j = jax.random.categorical(k_pick, logw)
    proposal = x + offsets[j]
    logw_back = _log_conditional(t, proposal + offsets, poses, walls, data, eta)
    log_ratio = jax.nn.logsumexp(logw) - jax.nn.logsumexp(logw_back)
    accept = jnp.log(jax.random.uniform(k_acc, (), steps.dtype)) < log_ratio
    return jnp.where(accept, proposal, x), accept, jnp.where(accept, logw[j], logw[center]), cache


RANDOM_WALK_STD = (0.01, 0.01, 0.003)
"""Default proposal standard deviations of :func:`random_walk_pose_mh` (x m, y m, theta rad): about the spread of a
pose given the map and a laser scan of a hundred or more beams (a centimeter, a sixth of a degree)."""


def random_walk_pose_mh(data: SlamData, step_std=RANDOM_WALK_STD, likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """Random-walk Metropolis over each pose (Metropolis et al. 1953): for a pose ``t``, propose ``x' = x + step_std *
    N(0, I_3)`` and accept with probability ``min(1, pi(x') / pi(x))``, ``pi`` the pose's exact conditional
    (:func:`pose_log_conditional`). One ray cast of the scan per proposal, against the ``(2 w + 1)^3`` of
    :func:`lattice_pose_mh`'s windows: the kernel for real logs, where every scan casts hundreds of beams over a large
    grid. Its ``init`` casts every scan once at its pose (``PoseState.scan_log_lik``); a move then scores the current
    pose from that cache and the motion model (the walls do not change during a pose sweep), and a state without
    the cache (a joint kernel's, whose walls change between its pose sweeps) casts the current pose again.

    A sweep moves the odd poses ``1, 3, 5, ...`` together, then the even ones ``2, 4, ...``: given the walls, pose
    ``t``'s conditional involves only poses ``t - 1`` and ``t + 1`` (the motion model is a Markov chain and each scan
    depends on its own pose), so the poses of one parity are conditionally independent and moving them at once is
    the same kernel as moving them one after another in that order (tested: the same moves as single-pose moves in
    that order, with the same keys; pose ``t``'s key is the ``t - 1``-th of the sweep key's ``S - 1`` splits). A
    systematic-scan Gibbs order over two blocks (Geman & Geman 1984's coloring of a chain graph); the two blocks'
    beams are cast in two batches (:func:`scans_log_likelihood`).

    Args:
        data: :func:`slam_data`.
        step_std: ``(3,)`` proposal standard deviations (x m, y m, theta rad), each finite and > 0.
        likelihood_power: ``eta`` in (0, 1].

    Returns:
        A :class:`bayesmap.inference.base.SamplingAlgorithm` over :class:`PoseState` (``accepted``: the proposal was
        accepted).

    Raises:
        BayesmapError: on a bad step or likelihood power (the message names it).
    """
    eta = check_likelihood_power(likelihood_power)
    values = np.asarray(step_std, dtype=object).reshape(-1)
    if len(values) != 3:
        raise BayesmapError(f"step_std must be three finite numbers > 0 (x m, y m, theta rad), got {step_std!r}")
    scale = jnp.asarray([_positive("step_std", v) for v in values], dtype=data.increments.dtype)

    return SamplingAlgorithm(init=Partial(_cached_init, data), step=Partial(_random_walk_sweep, scale, data, eta))


def _cached_init(data, poses, walls) -> PoseState:
    """:func:`_init` with every scan's log-likelihood at its pose."""
    state = _init(poses, walls)
    return state._replace(scan_log_lik=_scan_log_likelihoods(data, state.poses, state.walls))


@jax.jit
def _scan_log_likelihoods(data, poses, walls):
    """``(S,)`` each scan's log-likelihood at its pose, in ``poses``' dtype (compiled once per shapes)."""
    like = scans_log_likelihood(walls, poses, data.sensor_angles, data.readings, data.params)
    return like.astype(poses.dtype)


def _random_walk_sweep(scale, data, eta, key, state: PoseState):
    """:func:`random_walk_pose_mh`'s sweep: the odd poses' moves at once, then the even poses' (each block padded to
    ``S // 2`` poses, the padding's moves dropped; one compiled block, run twice), the current poses' scan
    log-likelihoods from the state's cache where it has one."""
    s = state.poses.shape[0]
    keys = jax.random.split(key, s - 1)
    size = s // 2
    cached = state.scan_log_lik is not None

    def block(b, carry):
        poses, cache, accepted, log_conditional = carry
        index = 1 + b + 2 * jnp.arange(size)
        valid = index < s
        t = jnp.minimum(index, s - 1)
        k_prop, k_acc = jnp.moveaxis(jax.vmap(jax.random.split)(keys[t - 1]), 1, 0)
        x = poses[t]
        proposal = x + scale * jax.vmap(lambda k: jax.random.normal(k, (3,), scale.dtype))(k_prop)
        angles, readings = data.sensor_angles[t], data.readings[t]
        both = jnp.concatenate([proposal, x]) if not cached else proposal
        cast = scans_log_likelihood(state.walls, both, jnp.concatenate([angles] * (1 + (not cached))),
                                    jnp.concatenate([readings] * (1 + (not cached))), data.params).astype(poses.dtype)
        new_like = cast[:size]
        like = cache[t] if cached else cast[size:]
        motion = jax.vmap(lambda tt, a, c: _motion_terms(tt, jnp.stack([a, c]), poses, data))(t, x, proposal)
        logc = motion + eta * jnp.stack([like, new_like], axis=-1)
        u = jax.vmap(lambda k: jax.random.uniform(k, (), scale.dtype))(k_acc)
        accept = valid & (jnp.log(u) < logc[:, 1] - logc[:, 0])
        slot = jnp.where(valid, index, s)  # out of range: dropped
        poses = poses.at[slot].set(jnp.where(accept[:, None], proposal, x), mode="drop")
        if cached:
            cache = cache.at[slot].set(jnp.where(accept, new_like, like), mode="drop")
        accepted = accepted.at[slot - 1].set(accept, mode="drop")
        log_conditional = log_conditional.at[slot - 1].set(jnp.where(accept, logc[:, 1], logc[:, 0]), mode="drop")
        return poses, cache, accepted, log_conditional

    init = (state.poses, state.scan_log_lik, jnp.zeros(s - 1, bool), jnp.zeros(s - 1, state.poses.dtype))
    poses, cache, accepted, log_conditional = jax.lax.fori_loop(0, 2, block, init)
    return (PoseState(poses=poses, walls=state.walls, scan_log_lik=cache),
            PoseInfo(accepted=accepted, log_conditional=log_conditional))


SEGMENT_LENGTH = 10
"""Default poses per segment of :func:`segment_pose_mh`: ten consecutive scans moved together. A sampler setting, not
a model one: it changes how fast the chain mixes, not the posterior it targets. Chosen with
:data:`SEGMENT_STEP_STD` on one run (Intel, odometry seed 0, every other scan: 10 and 30 poses tried) and checked on
fifteen others ([validation](../validation/slam.md#segment-moves-in-the-chain))."""

SEGMENT_STEP_STD = (0.03, 0.03, 0.005)
"""Default proposal standard deviations of :func:`segment_pose_mh`'s rigid move (x m, y m, theta rad), in the frame
of the segment's first pose: three times the single-pose random walk's position step (:data:`RANDOM_WALK_STD`), for
the directions in which all of a segment's scans leave it free to slide (along a corridor). A sampler setting,
chosen with :data:`SEGMENT_LENGTH` (0.01, 0.03 and 0.05 m tried;
[validation](../validation/slam.md#segment-moves-in-the-chain))."""


def moved_segment(poses, a, b, delta):
    """``poses`` ``(S, 3)`` with rows ``a..b`` (``1 <= a <= b <= S - 1``, possibly traced) moved rigidly by
    ``delta`` ``(3,)`` (dx m, dy m, dtheta rad) given in the frame of pose ``a``: ``x_t' = x_a (+) delta (+) (x_a^-1
    (+) x_t)``, so every step inside the segment is kept and pose ``a`` goes to ``x_a (+) delta``. The inverse move is
    ``delta^-1`` from the moved pose ``a``. Jittable."""
    poses = jnp.asarray(poses)
    idx = jnp.arange(poses.shape[0])
    inside = (idx >= a) & (idx <= b)
    anchor = poses[a]
    moved = _moved_rigidly(anchor, compose(anchor, jnp.asarray(delta, poses.dtype)), poses)
    return jnp.where(inside[:, None], moved, poses)


def _moved_rigidly(anchor, target, poses):
    """``target (+) (anchor^-1 (+) poses)``: ``poses`` ``(..., 3)`` moved with ``anchor`` (broadcast) as one rigid
    body that takes ``anchor`` to ``target`` (:func:`moved_segment`'s rows, ``target = anchor (+) delta``)."""
    within = motion_error(anchor, poses, jnp.zeros(3, poses.dtype))  # each pose in the frame of the anchor
    return compose(target, within)


def segment_log_ratio(a: int, b: int, delta, poses, walls, data: SlamData, likelihood_power: float = 1.0):
    """``log pi(x') - log pi(x)`` of the path posterior given the walls (the model's log joint at fixed walls and
    readings) for the segment move ``x' =`` :func:`moved_segment` ``(x, a, b, delta)``: the motion terms at the
    segment's two ends (the steps inside it are unchanged) and the segment's scans' log-likelihoods at power
    ``likelihood_power`` (a float, or one power per scan).

    Args:
        a: the segment's first pose, ``1 <= a`` (pose 0 is fixed).
        b: its last pose, ``a <= b <= S - 1``.
        delta: ``(3,)`` the move (dx m, dy m, dtheta rad) in the frame of pose ``a``.
        poses: ``(S, 3)`` the current path.
        walls: ``(nx, ny)`` the map.
        data: :func:`slam_data`.
        likelihood_power: ``eta`` in (0, 1], or one power per scan ``(S,)`` in [0, 1].

    Returns:
        The log ratio, a float scalar.

    Raises:
        BayesmapError: if ``a``, ``b`` are not integers with ``1 <= a <= b <= S - 1``, or the power is bad.
    """
    poses = jnp.asarray(poses)
    s = poses.shape[0]
    if int(a) != a or int(b) != b or not 1 <= int(a) <= int(b) <= s - 1:
        raise BayesmapError(f"the segment must have integers 1 <= a <= b <= {s - 1} (pose 0 is fixed), got a={a!r}, "
                            f"b={b!r}")
    eta = check_scan_powers(likelihood_power, s)
    like = _scan_log_likelihoods(data, poses, jnp.asarray(walls, jnp.float32))
    one = jnp.asarray([int(a)]), jnp.asarray([int(b)]), jnp.asarray([True])
    return _segment_log_ratios_jit(*one, jnp.asarray(delta, poses.dtype)[None], poses, jnp.asarray(walls), data, eta,
                                   like, int(b) - int(a) + 1)[0][0]


def _segment_log_ratios(a, b, valid, delta, poses, walls, data: SlamData, eta, like, length: int):
    """The segment moves ``a[i]..b[i]`` by ``delta[i]`` (``(n,)``, ``(n,)``, ``(n, 3)``; ``valid`` ``(n,)`` bool: a
    move that is not is all padding), each scored against ``poses`` ``(S, 3)`` as it is, casting only the segments'
    scans (``length`` rows each, at least ``b - a + 1``): ``(log ratios (n,), the rows' indices (n, length) and
    whether each is in its segment, the moved rows (n, length, 3), their scans' untempered log-likelihoods (n,
    length))``; ``like`` ``(S,)`` the current scans' untempered log-likelihoods."""
    s = poses.shape[0]
    rows = jnp.arange(length)
    idx = jnp.minimum(a[:, None] + rows, s - 1)
    inside = valid[:, None] & (a[:, None] + rows <= b[:, None])
    anchor = poses[a]
    moved = _moved_rigidly(anchor[:, None], compose(anchor, delta)[:, None], poses[idx])  # (n, length, 3)
    n = a.shape[0]
    cast = scans_log_likelihood(walls, moved.reshape(-1, 3), data.sensor_angles[idx].reshape(n * length, -1),
                                data.readings[idx].reshape(n * length, -1),
                                data.params).astype(poses.dtype).reshape(n, length)
    power = eta if jnp.ndim(eta) == 0 else eta[idx]
    scans = jnp.sum(jnp.where(inside, power * (cast - like[idx]), 0.0), axis=1)
    step_logpdf = jax.vmap(motion_logpdf)
    before = (step_logpdf(poses[a - 1], moved[:, 0], data.increments[a - 1], data.covs[a - 1])
              - step_logpdf(poses[a - 1], poses[a], data.increments[a - 1], data.covs[a - 1]))
    last = jnp.take_along_axis(moved, (b - a)[:, None, None], axis=1)[:, 0]  # the moved pose b
    nxt, step = jnp.minimum(b + 1, s - 1), jnp.minimum(b, s - 2)
    after = (step_logpdf(last, poses[nxt], data.increments[step], data.covs[step])
             - step_logpdf(poses[b], poses[nxt], data.increments[step], data.covs[step]))
    return before + jnp.where(b < s - 1, after, 0.0) + scans, idx, inside, moved, cast


_segment_log_ratios_jit = jax.jit(_segment_log_ratios, static_argnames=("length",))


def segment_pose_mh(data: SlamData, length: int = SEGMENT_LENGTH, step_std=SEGMENT_STEP_STD,
                    likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """Metropolis-Hastings moves of whole stretches of the path, each moved rigidly (exact for the path posterior
    given the walls).

    A single-pose kernel moves a pose against both of its neighbours' motion terms, so a stretch of path that the
    scans leave free to slide as a whole (along a corridor, where every scan fits the side walls equally well) moves
    by the odometry's few centimeters at a time. This kernel moves ``length`` consecutive poses together. A sweep
    draws an offset ``o`` uniformly in ``0..length - 1`` (independently of the state) and cuts poses ``1..S-1`` into
    the segments ``1..o``, ``o+1..o+length``, ...; for each segment ``a..b`` it proposes ``delta ~ N(0,
    diag(step_std)^2)`` in the frame of pose ``a`` and the path :func:`moved_segment` ``(x, a, b, delta)``, and
    accepts with probability ``min(1, pi(x') / pi(x))`` (:func:`segment_log_ratio`: only the two end steps and the
    segment's scans change). The first, third, ... segments move at once, then the second, fourth, ...: given the
    walls, two segments that are not neighbours share no pose and no motion term, so their moves are independent and
    a block of them is the same kernel as the same moves one after another (tested against such a replay), with
    every block's scans cast in one call.

    Why the ratio has no proposal term: the move ``(x, delta) -> (x', delta^-1)`` is an involution (from ``x'`` the
    move ``delta^-1`` in the frame of the moved pose ``a`` returns ``x``), it moves each pose of the segment by a rigid
    motion (unit Jacobian), and ``delta^-1 = (-R(-dtheta) (dx, dy), -dtheta)`` has the same density as ``delta``
    under ``N(0, diag(s_xy, s_xy, s_theta)^2)`` with equal x and y deviations (a rotation of an isotropic Gaussian;
    unit Jacobian). So the Metropolis-Hastings ratio (Green 1995's form for deterministic involutions; Tierney 1998)
    is ``pi(x') / pi(x)``. Each offset gives a kernel that leaves the posterior invariant, so their mixture does. With
    ``length = 1`` it is a random-walk Metropolis move per pose, in the pose's own frame.

    Args:
        data: :func:`slam_data`.
        length: poses per segment, an integer >= 1.
        step_std: ``(2,)`` or ``(3,)`` proposal standard deviations ``(xy m, theta rad)`` or ``(x m, y m, theta
            rad)`` with equal x and y (the symmetry above needs an isotropic position step), each finite and > 0.
        likelihood_power: ``eta`` in (0, 1], or one power per scan ``(S,)`` in [0, 1]
            (:func:`bayesmap.model.generative.check_scan_powers`).

    Returns:
        A :class:`bayesmap.inference.base.SamplingAlgorithm` over :class:`PoseState` (``init`` casts every scan
        once; ``accepted`` ``(S - 1,)``: whether each pose's segment move was accepted).

    Raises:
        BayesmapError: on a bad length, step or likelihood power (the message names it).
    """
    eta = check_scan_powers(likelihood_power, data.sensor_angles.shape[0])
    if isinstance(length, bool) or not isinstance(length, (int, np.integer)) or length < 1:
        raise BayesmapError(f"length must be an integer >= 1, got {length!r}")
    values = np.asarray(step_std, dtype=object).reshape(-1)
    if len(values) == 2:
        values = values[[0, 0, 1]]
    if len(values) != 3:
        raise BayesmapError(f"step_std must be (xy m, theta rad) or (x m, y m, theta rad), got {step_std!r}")
    scale = [_positive("step_std", v) for v in values]
    if scale[0] != scale[1]:
        raise BayesmapError(f"step_std must have equal x and y deviations (an isotropic step), got {step_std!r}")
    scale = jnp.asarray(scale, dtype=data.increments.dtype)
    return SamplingAlgorithm(init=Partial(_cached_init, data),
                             step=Partial(_segment_sweep, int(length), scale, data, eta))


def _segment_sweep(length, scale, data, eta, key, state: PoseState):
    """:func:`segment_pose_mh`'s sweep: the even segments' moves at once, then the odd segments' (two segments that
    are not neighbours share no pose and no motion term, so given the walls their moves are independent; each block
    padded to the same number of segments, the padding's moves dropped; one compiled block, run twice), the current
    poses' scan log-likelihoods from the state's cache where it has one."""
    s = state.poses.shape[0]
    k_offset, k_moves = jax.random.split(key)
    offset = jax.random.randint(k_offset, (), 0, length)
    count = (s - 2) // length + 2  # segments enough for any offset (the extra ones empty)
    keys = jax.random.split(k_moves, count)
    size = (count + 1) // 2  # segments per block
    cached = state.scan_log_lik is not None
    like = state.scan_log_lik if cached else _scan_log_likelihoods(data, state.poses, state.walls)

    def block(parity, carry):
        poses, like, accepted = carry
        k = parity + 2 * jnp.arange(size)  # (size,) this block's segments
        first = 1 + offset + (k - 1) * length
        a, b = jnp.maximum(first, 1), jnp.minimum(first + length - 1, s - 1)
        valid = (k < count) & (a <= b)
        a = jnp.minimum(a, s - 1)
        b = jnp.maximum(b, a)
        k_delta, k_acc = jnp.moveaxis(jax.vmap(jax.random.split)(keys[jnp.minimum(k, count - 1)]), 1, 0)
        delta = scale * jax.vmap(lambda kk: jax.random.normal(kk, (3,), scale.dtype))(k_delta)  # (size, 3)
        log_ratio, idx, inside, moved, cast = _segment_log_ratios(a, b, valid, delta, poses, state.walls, data,
                                                                  eta, like, length)
        u = jax.vmap(lambda kk: jax.random.uniform(kk, (), scale.dtype))(k_acc)
        accept = valid & (jnp.log(u) < log_ratio)
        slot = jnp.where(inside & accept[:, None], idx, s).reshape(-1)  # out of range: dropped
        poses = poses.at[slot].set(moved.reshape(-1, 3), mode="drop")
        like = like.at[slot].set(cast.reshape(-1), mode="drop")
        member = jnp.where(inside, idx, s).reshape(-1)
        accepted = accepted.at[member - 1].set(jnp.repeat(accept, length), mode="drop")
        return poses, like, accepted

    poses, like, accepted = jax.lax.fori_loop(0, 2, block, (state.poses, like, jnp.zeros(s - 1, bool)))
    t = jnp.arange(1, s)
    motion = jax.vmap(lambda tt: _motion_terms(tt, poses[tt][None], poses, data)[0])(t)
    power = eta if jnp.ndim(eta) == 0 else eta[t]
    return (PoseState(poses=poses, walls=state.walls, scan_log_lik=like if cached else None),
            PoseInfo(accepted=accepted, log_conditional=motion + power * like[t]))


def composed_pose_kernels(first: SamplingAlgorithm, second: SamplingAlgorithm) -> SamplingAlgorithm:
    """One sweep of ``first`` then one of ``second``, two pose kernels over :class:`PoseState` on the same data (a
    cycle of kernels, each leaving the path posterior invariant, leaves it invariant: Tierney 1994). ``init`` is
    ``first``'s; ``accepted`` reports, per pose, whether either sweep moved it, and ``log_conditional`` is
    ``second``'s."""
    return SamplingAlgorithm(init=first.init, step=Partial(_composed_sweep, first.step, second.step))


def _composed_sweep(first, second, key, state: PoseState):
    k_first, k_second = jax.random.split(key)
    state, a = first(k_first, state)
    state, b = second(k_second, state)
    return state, PoseInfo(accepted=a.accepted | b.accepted, log_conditional=b.log_conditional)
