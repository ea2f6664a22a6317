"""The odometry motion model: the robot's pose at each scan given the previous pose and the measured odometry.

Source: Thrun, Burgard & Fox, *Probabilistic Robotics* (PR, 2005), sec. 5.4 (the odometry motion model), with the
Gaussian linearization PR uses for EKF localization (Table 7.2, ``R = V M V^T``).

* Odometry arrives as absolute odometry poses ``odometry (S, 3)`` (x m, y m, theta rad), as a raw log holds them.
  The control of step ``t`` (``t = 1..S-1``) is the increment from ``o_{t-1}`` to ``o_t``, decomposed as in PR
  Table 5.5 into ``(rot1, trans, rot2)`` (``rot1 = 0`` when ``trans < 1e-6`` m; angles wrapped to ``[-pi, pi)``).
* In the frame of the previous pose, the pose increment is ``(dx, dy, dtheta) = (trans cos rot1, trans sin rot1,
  rot1 + rot2)`` plus a zero-mean Normal error ``e_t ~ N(0, Sigma_t)`` with
  ``Sigma_t = V M V^T + diag(floor_xy^2, floor_xy^2, floor_theta^2)``, ``M = diag(std(rot1)^2, std(trans)^2,
  std(rot2)^2)`` and ``V = d(dx, dy, dtheta) / d(rot1, trans, rot2)`` at the odometry's values. The standard
  deviations are PR Table 5.6's with the noise given as standard deviations (as ``tools/noisy_odometry.py``):
  ``std(rot1) = a1 |rot1| + a2 trans``, ``std(trans) = a3 trans + a4 (|rot1| + |rot2|)``,
  ``std(rot2) = a1 |rot2| + a2 trans``. A step shorter than :data:`UNDIRECTED_RADIUS` floors measures no
  direction, so ``rot1`` and ``rot2`` are unknown there: its heading gets the variance of the two rotations' noise
  for a direction uniform on the circle, ``2 a1^2 pi^2 / 3``, as well. ``Sigma_t`` depends only on the odometry:
  :func:`odometry_controls` precomputes it per step.
* ``pose_t = pose_{t-1} (+) (increment_t + e_t)``, where :func:`compose` rotates ``(dx, dy)`` by ``theta_{t-1}``
  and adds ``dtheta`` to ``theta``. The heading is *not* wrapped in the state (it is a real number,
  ``theta_t = theta_{t-1} + dtheta + e_theta``), so the density of ``pose_t`` given ``pose_{t-1}`` is exactly the
  Normal density of ``e_t = (R(-theta_{t-1}) (p_t - p_{t-1}) - (dx, dy), theta_t - theta_{t-1} - dtheta)``: the
  map from ``e_t`` to ``pose_t`` is a rigid transform (unit Jacobian).

Zero noise: the known-pose model
--------------------------------
With all alphas and floors 0 (:func:`make_motion_params` with zeros), every ``Sigma_t`` is the zero matrix and the
model is the known-pose model: sampling returns the composed odometry path and the log-density is 0 on it and
``-inf`` elsewhere. The switch is the covariance itself, per step (a step is *deterministic* when its ``Sigma_t``
is exactly zero): the GenJAX distribution :data:`odometry_path` takes the covariances as arguments, so a flag can
only be read from them. "On the path" means within :func:`deterministic_tolerance` (the rounding of
:func:`compose`, about ``sqrt(eps)`` relative). :func:`make_motion_params` rejects floors of 0 with nonzero alphas
(a standing robot would then have a singular covariance), so every other ``Sigma_t`` is positive definite.
"""

from __future__ import annotations

import math

import genjax
import jax
import jax.numpy as jnp
import numpy as np
from genjax import Pytree

from bayesmap.errors import BayesmapError

MIN_TRANSLATION = 1.0e-6
"""Below this translation (meters) the first rotation of PR Table 5.5 is 0 (the heading of a standing robot)."""

UNDIRECTED_RADIUS = math.sqrt(-2.0 * math.log(0.01))
"""A step is *undirected* when its translation is at least :data:`MIN_TRANSLATION` but below this many
``floor_xy``: the radius inside which the floor noise alone puts a standing robot's odometry with 99 % probability
(a 2-D Normal's, ``sqrt(-2 ln 0.01)`` = 3.03; 3 cm at the default floor). The odometry then measures no direction of
motion, so PR's ``rot1`` and ``rot2``, on which its rotation noise scales, are unknown: the heading's variance gets
the variance of PR's rotation noise for a direction uniform on the circle, ``a1^2 pi^2 / 3`` for each of the two
rotations, on top of the step's own (:func:`odometry_controls`). Derived from the floor, not fitted; the
[validation](../validation/slam.md#steps-with-no-direction) has what it changed."""

_LOG_2PI = math.log(2.0 * math.pi)


@Pytree.dataclass
class MotionParams(Pytree):
    """Noise of the odometry motion model (a JAX pytree; every field is dynamic).

    The defaults are an *assumption about the robot's wheels*, not a fit to any data file: 10 % of each turn and
    0.05 rad of heading per meter travelled, 10 % of each distance and 0.05 m per radian turned, plus floors of
    1 cm and 0.005 rad (about 0.3 degrees) so that a standing robot keeps a positive definite covariance. Set them
    for your robot (``bayesmap slam --motion-alphas``). Checked by leave-one-log-out cross-validation over Intel,
    ACES and CSAIL (``benchmarks/motion_cv.py``): alphas fitted to the three logs' odometry did not make SLAM
    better, so these stay ([validation](../validation/defaults.md#motionparams)).

    Attributes:
        a1: rotation noise per radian of rotation (dimensionless; PR's alpha_1).
        a2: rotation noise per meter of translation (rad/m; PR's alpha_2).
        a3: translation noise per meter of translation (dimensionless; PR's alpha_3).
        a4: translation noise per radian of rotation (m/rad; PR's alpha_4).
        floor_xy: standard deviation added to x and y of every step, meters.
        floor_theta: standard deviation added to theta of every step, radians.
    """

    a1: float = 0.1
    a2: float = 0.05
    a3: float = 0.1
    a4: float = 0.05
    floor_xy: float = 0.01
    floor_theta: float = 0.005


def make_motion_params(alphas=None, floor_xy: float | None = None, floor_theta: float | None = None) -> MotionParams:
    """Build :class:`MotionParams` after checking every value.

    Args:
        alphas: ``(a1, a2, a3, a4)``, PR Table 5.6's noise parameters as standard deviations (see
            :class:`MotionParams` for units), each finite and >= 0; default :class:`MotionParams`'s.
        floor_xy: meters, finite and >= 0; default :class:`MotionParams`'s.
        floor_theta: radians, finite and >= 0; default :class:`MotionParams`'s.

    All zero is the known-pose model (see the module docstring).

    Raises:
        BayesmapError: if there are not four alphas, a value is negative or not finite, or a floor is 0 while
            another value is not (the covariance of a standing robot would be singular); the message names it.
    """
    default = MotionParams()
    alphas = (default.a1, default.a2, default.a3, default.a4) if alphas is None else tuple(alphas)
    floor_xy = default.floor_xy if floor_xy is None else floor_xy
    floor_theta = default.floor_theta if floor_theta is None else floor_theta
    if len(alphas) != 4:
        raise BayesmapError(f"alphas must be four numbers (a1, a2, a3, a4), got {alphas!r}")
    values = {"a1": alphas[0], "a2": alphas[1], "a3": alphas[2], "a4": alphas[3], "floor_xy": floor_xy,
              "floor_theta": floor_theta}
    checked = {}
    for name, value in values.items():
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise BayesmapError(f"{name} must be a number, got {value!r}") from None
        if not (math.isfinite(v) and v >= 0):
            raise BayesmapError(f"{name} must be a finite number >= 0, got {value!r}")
        checked[name] = v
    if any(checked.values()) and not (checked["floor_xy"] > 0 and checked["floor_theta"] > 0):
        raise BayesmapError(f"floor_xy and floor_theta must be > 0 unless every motion noise is 0 (known poses), "
                            f"got floor_xy={floor_xy!r}, floor_theta={floor_theta!r}")
    return MotionParams(**checked)


def wrap_angle(angle):
    """Angles wrapped to ``[-pi, pi)``, radians (as ``tools/noisy_odometry.py``): a Python float, a numpy array
    (float64 kept) or a JAX array (traceable), returned as the same kind, any shape."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def odometry_decomposition(odometry):
    """PR Table 5.5's ``(rot1, trans, rot2)`` of each odometry step.

    Args:
        odometry: ``(S, 3)`` absolute odometry poses (x m, y m, theta rad), ``S >= 1``.

    Returns:
        ``(S - 1, 3)`` float: ``rot1`` (rad, 0 when ``trans < MIN_TRANSLATION``), ``trans`` (m), ``rot2`` (rad),
        angles wrapped to ``[-pi, pi)``.
    """
    odometry = jnp.asarray(odometry)
    delta = odometry[1:, :2] - odometry[:-1, :2]
    trans = jnp.hypot(delta[:, 0], delta[:, 1])
    rot1 = jnp.where(trans < MIN_TRANSLATION, 0.0,
                     wrap_angle(jnp.arctan2(delta[:, 1], delta[:, 0]) - odometry[:-1, 2]))
    rot2 = wrap_angle(odometry[1:, 2] - odometry[:-1, 2] - rot1)
    return jnp.stack([rot1, trans, rot2], axis=-1)


def _step_covariance(control, params: MotionParams):
    """``Sigma_t`` ``(3, 3)`` of one control ``(rot1, trans, rot2)`` (see the module docstring)."""
    rot1, trans, rot2 = control[0], control[1], control[2]
    std = jnp.stack([params.a1 * jnp.abs(rot1) + params.a2 * trans,
                     params.a3 * trans + params.a4 * (jnp.abs(rot1) + jnp.abs(rot2)),
                     params.a1 * jnp.abs(rot2) + params.a2 * trans])
    zero, one = jnp.zeros_like(rot1), jnp.ones_like(rot1)
    jac = jnp.stack([jnp.stack([-trans * jnp.sin(rot1), jnp.cos(rot1), zero]),
                     jnp.stack([trans * jnp.cos(rot1), jnp.sin(rot1), zero]),
                     jnp.stack([one, zero, one])])
    floors = jnp.stack([params.floor_xy, params.floor_xy, params.floor_theta]) ** 2
    undirected = (trans >= MIN_TRANSLATION) & (trans < UNDIRECTED_RADIUS * params.floor_xy)
    unknown_direction = jnp.where(undirected, 2.0 * (params.a1 * math.pi) ** 2 / 3.0, 0.0)
    return (jac * std ** 2) @ jac.T + jnp.diag(floors + jnp.stack([zero, zero, unknown_direction]))


def odometry_controls(odometry, params: MotionParams | None = None):
    """The motion model's per-step increments and covariances from absolute odometry poses.

    Args:
        odometry: ``(S, 3)`` absolute odometry poses (x m, y m, theta rad), ``S >= 1``.
        params: the motion noise (default :class:`MotionParams`'s defaults).

    Returns:
        ``(increments (S - 1, 3), covariances (S - 1, 3, 3))``, float: ``(dx m, dy m, dtheta rad)`` in the frame of
        the previous pose and ``Sigma_t`` (see the module docstring).

    Raises:
        BayesmapError: if ``odometry`` is not ``(S, 3)`` with ``S >= 1`` or not finite.
    """
    odometry = np.asarray(odometry, dtype=np.float64)
    if odometry.ndim != 2 or odometry.shape[1] != 3 or odometry.shape[0] < 1:
        raise BayesmapError(f"odometry must have shape (S, 3) (x m, y m, theta rad), got {odometry.shape}")
    if not np.all(np.isfinite(odometry)):
        raise BayesmapError("odometry poses must be finite")
    params = MotionParams() if params is None else params
    controls = odometry_decomposition(jnp.asarray(odometry, dtype=jnp.result_type(float)))
    rot1, trans, rot2 = controls[:, 0], controls[:, 1], controls[:, 2]
    increments = jnp.stack([trans * jnp.cos(rot1), trans * jnp.sin(rot1), rot1 + rot2], axis=-1)
    covariances = jax.vmap(lambda c: _step_covariance(c, params))(controls)
    return increments, covariances.reshape(-1, 3, 3)


def composed_steps(odometry, starts, ends, params: MotionParams | None = None):
    """The motion model's step from scan ``starts[i]`` to scan ``ends[i]`` of an odometry path, through the scans
    between: the per-scan steps (:func:`odometry_controls`) composed, and their noise propagated to first order
    (:func:`compose_steps`). This is the odometry's step between two keyframes with the scans between them
    marginalized (linearized): a keyframe step of 0.5 m made of five steps of a bag-rate log carries their five
    heading errors, which one step of the same 0.5 m would not.

    Args:
        odometry: ``(S, 3)`` odometry poses (x m, y m, theta rad).
        starts: ``(M,)`` int scan indices, ``0 <= starts <= ends``.
        ends: ``(M,)`` int scan indices, ``ends < S``.
        params: the motion noise (default :class:`MotionParams`'s defaults).

    Returns:
        ``(increments (M, 3), covariances (M, 3, 3))`` float64, in the frame of each start pose (as
        :func:`motion_error` measures a step's error); zero where ``starts == ends``. For ``ends = starts + 1`` the
        step of :func:`odometry_controls`.

    Raises:
        BayesmapError: on a bad ``odometry`` (as :func:`odometry_controls`) or indices out of order or range.
    """
    return compose_steps(*odometry_controls(odometry, params), starts, ends)


def compose_steps(increments, covariances, starts, ends):
    """The steps ``starts[i] .. ends[i] - 1`` of a chain of uncertain relative poses composed into one, and their
    noise propagated to first order: each step's error, in the frame of the pose it starts from, turned into the
    frame of pose ``starts[i]``, the heading error's lever arm on the later steps included (the compounding of
    uncertain relative poses, Smith, Self & Cheeseman 1990, as a pose graph's odometry edges are summed).

    Args:
        increments: ``(S - 1, 3)`` step ``t`` from pose ``t`` to pose ``t + 1`` (dx m, dy m, dtheta rad) in the frame
            of pose ``t`` (:func:`odometry_controls`, or steps composed already).
        covariances: ``(S - 1, 3, 3)`` their error covariances.
        starts: ``(M,)`` int pose indices, ``0 <= starts <= ends``.
        ends: ``(M,)`` int pose indices, ``ends < S``.

    Returns:
        ``(increments (M, 3), covariances (M, 3, 3))`` float64, in the frame of each start pose; zero where
        ``starts == ends``; step ``t`` itself for ``ends = starts + 1``.

    Raises:
        BayesmapError: on indices out of order or range.
    """
    increments = np.asarray(increments, np.float64).reshape(-1, 3)
    covariances = np.asarray(covariances, np.float64).reshape(-1, 3, 3)
    starts, ends = np.asarray(starts, np.int64).reshape(-1), np.asarray(ends, np.int64).reshape(-1)
    if (starts.shape != ends.shape or np.any(starts < 0) or np.any(ends < starts)
            or np.any(ends > len(increments))):
        raise BayesmapError(f"composed steps need 0 <= starts <= ends < {len(increments) + 1} of equal length")
    pose, sigma = np.zeros((len(starts), 3)), np.zeros((len(starts), 3, 3))
    for j in range(int((ends - starts).max(initial=0))):
        live = starts + j < ends
        step = np.minimum(starts + j, max(len(increments) - 1, 0))
        u, q = increments[step], covariances[step]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        turn = np.zeros((len(starts), 3, 3))
        turn[:, 0, 0], turn[:, 0, 1], turn[:, 1, 0], turn[:, 1, 1], turn[:, 2, 2] = c, -s, s, c, 1.0
        lever = np.broadcast_to(np.eye(3), turn.shape).copy()
        lever[:, 0, 2] = -s * u[:, 0] - c * u[:, 1]
        lever[:, 1, 2] = c * u[:, 0] - s * u[:, 1]
        new_sigma = lever @ sigma @ np.swapaxes(lever, 1, 2) + turn @ q @ np.swapaxes(turn, 1, 2)
        new_pose = pose + np.stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1], u[:, 2]], axis=1)
        pose = np.where(live[:, None], new_pose, pose)
        sigma = np.where(live[:, None, None], new_sigma, sigma)
    return pose, (sigma + np.swapaxes(sigma, 1, 2)) / 2


def compose(pose, increment):
    """``pose (+) increment``: the increment ``(dx m, dy m, dtheta rad)``, given in the frame of ``pose``, applied to
    ``pose`` ``(x m, y m, theta rad)``; both ``(..., 3)``, broadcast. The heading is not wrapped.

    Returns:
        ``(..., 3)``: ``(x + cos(theta) dx - sin(theta) dy, y + sin(theta) dx + cos(theta) dy, theta + dtheta)``.
    """
    pose, increment = jnp.asarray(pose), jnp.asarray(increment)
    c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
    dx, dy = increment[..., 0], increment[..., 1]
    return jnp.stack([pose[..., 0] + c * dx - s * dy, pose[..., 1] + s * dx + c * dy,
                      pose[..., 2] + increment[..., 2]], axis=-1)


def motion_error(prev, pose, increment):
    """The motion error ``e`` ``(..., 3)`` that takes ``prev`` to ``pose`` (the inverse of :func:`compose` minus the
    increment): ``(R(-theta_prev) (p - p_prev) - (dx, dy), theta - theta_prev - dtheta)``, broadcast over leading
    axes of ``prev`` and ``pose`` ``(..., 3)``; ``increment`` ``(3,)``."""
    prev, pose, increment = jnp.asarray(prev), jnp.asarray(pose), jnp.asarray(increment)
    c, s = jnp.cos(prev[..., 2]), jnp.sin(prev[..., 2])
    ddx, ddy = pose[..., 0] - prev[..., 0], pose[..., 1] - prev[..., 1]
    return jnp.stack([c * ddx + s * ddy - increment[..., 0], -s * ddx + c * ddy - increment[..., 1],
                      pose[..., 2] - prev[..., 2] - increment[..., 2]], axis=-1)


def deterministic_tolerance(dtype, scale):
    """How far (meters, radians) a pose may be from the composed odometry path and still be *on* it in a
    deterministic (zero-covariance) step: ``sqrt(eps(dtype)) (1 + scale)``, ``scale`` the poses' magnitude (the
    rounding of :func:`compose` and :func:`motion_error` is a few ``eps`` relative, far below this)."""
    return math.sqrt(float(jnp.finfo(dtype).eps)) * (1.0 + scale)


def motion_logpdf(prev, pose, increment, cov):
    """``log p(pose_t = pose | pose_{t-1} = prev)`` of one step of the motion model.

    Args:
        prev: ``(..., 3)`` previous pose(s) (x m, y m, theta rad).
        pose: ``(..., 3)`` pose(s), broadcast with ``prev`` (e.g. many candidate poses at once).
        increment: ``(3,)`` the step's ``(dx m, dy m, dtheta rad)`` (:func:`odometry_controls`).
        cov: ``(3, 3)`` the step's ``Sigma_t``, positive definite, or exactly zero (a deterministic step).

    Returns:
        ``broadcast(prev, pose)[..., 0]`` float: the Normal log-density of :func:`motion_error` under
        ``N(0, cov)`` (density w.r.t. Lebesgue measure on ``(x, y, theta)``); for a zero ``cov``, 0 on the composed
        pose (within :func:`deterministic_tolerance`) and ``-inf`` elsewhere. Never raises.
    """
    err = motion_error(prev, pose, increment)
    cov = jnp.asarray(cov, dtype=err.dtype)
    deterministic = jnp.all(cov == 0)
    safe = jnp.where(deterministic, jnp.eye(3, dtype=err.dtype), cov)
    chol = jnp.linalg.cholesky(safe)
    flat = err.reshape(-1, 3)
    white = jax.scipy.linalg.solve_triangular(chol, flat.T, lower=True).T.reshape(err.shape)
    log_det = 2.0 * jnp.sum(jnp.log(jnp.diagonal(chol)))
    gauss = -0.5 * jnp.sum(white * white, axis=-1) - 0.5 * log_det - 1.5 * _LOG_2PI
    scale = jnp.maximum(jnp.max(jnp.abs(jnp.asarray(prev)), axis=-1), jnp.max(jnp.abs(jnp.asarray(pose)), axis=-1))
    tol = deterministic_tolerance(err.dtype, scale)
    on_path = jnp.all(jnp.abs(err) <= tol[..., None], axis=-1)
    return jnp.where(deterministic, jnp.where(on_path, 0.0, -jnp.inf), gauss)


def backward_step_covariance(params: MotionParams | None = None) -> np.ndarray:
    """The error covariance ``(3, 3)`` float64 (m^2, rad^2) that PR Table 5.6 gives a short step whose true motion
    backed up, beyond what the odometry it reports shows: the simulator (and PR's model) decomposes a step back as
    two half turns, ``rot1`` near ``pi`` and ``rot2`` near ``-pi``, so its heading carries the noise of both,
    variance ``2 (a1 pi)^2``, and its translation ``a4 (|rot1| + |rot2|)``, a standard deviation of ``2 pi a4``
    meters, while the reported step can look like a plain forward one to which :func:`odometry_controls` gives a few
    hundredths of a radian. The translation's direction is then unknown, so it is isotropic in x and y:
    ``diag((2 pi a4)^2, (2 pi a4)^2, 2 (a1 pi)^2)``; 0.31 m and 0.44 rad at :class:`MotionParams`' defaults. Derived
    from ``params`` (default :class:`MotionParams`), not fitted; the front end's search adds it as a tail
    (:func:`tailed_motion_logpdf`)."""
    params = MotionParams() if params is None else params
    xy = (2.0 * math.pi * float(params.a4)) ** 2
    return np.diag([xy, xy, 2.0 * (math.pi * float(params.a1)) ** 2])


def tailed_motion_logpdf(prev, pose, increment, cov, tail_weight, tail_cov):
    """``log((1 - w) N(e; 0, Sigma) + w N(e; 0, Sigma + T))``: :func:`motion_logpdf` with a broad component of weight
    ``w`` = ``tail_weight`` whose covariance adds ``T`` = ``tail_cov`` ``(3, 3)`` (e.g.
    :func:`backward_step_covariance`) to the step's ``Sigma`` = ``cov``; ``e`` the motion error
    (:func:`motion_error`). A heavy-tailed motion density for a search that must not refuse a pose far from an
    outlying odometry step (a max-mixture's role, Olson & Agarwal 2013, with a Gaussian broad component instead of
    a uniform one). ``w = 0``, or a step whose ``Sigma`` is exactly zero (deterministic), is :func:`motion_logpdf`
    exactly. Not the SLAM model's motion density, which stays
    :func:`motion_logpdf`. Shapes as :func:`motion_logpdf`; ``w`` in ``[0, 1)``. Never raises."""
    cov = jnp.asarray(cov)
    tail_weight = jnp.asarray(tail_weight, cov.dtype)
    normal = motion_logpdf(prev, pose, increment, cov)
    wide = motion_logpdf(prev, pose, increment, cov + jnp.asarray(tail_cov, cov.dtype)) + jnp.log(tail_weight)
    deterministic = jnp.all(cov == 0)  # a step the motion model fixes keeps no tail
    return jnp.where(deterministic, normal, jnp.logaddexp(normal + jnp.log1p(-tail_weight), wide))


def _step_sample(key, prev, increment, cov):
    """One draw of ``pose_t`` ``(3,)`` given ``prev`` ``(3,)`` (a zero ``cov``: the composed pose)."""
    deterministic = jnp.all(cov == 0)
    chol = jnp.linalg.cholesky(jnp.where(deterministic, jnp.eye(3, dtype=cov.dtype), cov))
    noise = chol @ jax.random.normal(key, (3,), dtype=cov.dtype)
    return compose(prev, increment + jnp.where(deterministic, 0.0, noise))


def _later_poses(key, first_pose, increments, covs):
    """Poses ``1..S-1`` ``(S - 1, 3)`` drawn step by step from ``first_pose`` (``jax.lax.scan``)."""
    first_pose = jnp.asarray(first_pose, dtype=jnp.result_type(float))
    increments = jnp.asarray(increments, dtype=first_pose.dtype).reshape(-1, 3)
    covs = jnp.asarray(covs, dtype=first_pose.dtype).reshape(-1, 3, 3)

    def body(prev, step):
        k, inc, cov = step
        pose = _step_sample(k, prev, inc, cov)
        return pose, pose

    keys = jax.random.split(key, increments.shape[0])
    return jax.lax.scan(body, first_pose, (keys, increments, covs))[1].reshape(-1, 3)


def _later_logpdf(poses, first_pose, increments, covs):
    """``log p(poses 1..S-1 | first_pose)``: the sum of the steps' :func:`motion_logpdf` (``poses`` ``(S - 1, 3)``)."""
    poses = jnp.asarray(poses).reshape(-1, 3)
    prev = jnp.concatenate([jnp.asarray(first_pose, dtype=poses.dtype)[None], poses[:-1]], axis=0)
    steps = jax.vmap(motion_logpdf)(prev, poses, jnp.asarray(increments).reshape(-1, 3),
                                    jnp.asarray(covs).reshape(-1, 3, 3))
    return jnp.sum(steps)


def sample_path(key, first_pose, increments, covs):
    """A path ``(S, 3)`` drawn from the motion model: ``first_pose`` ``(3,)`` then each step composed with its
    increment plus a ``N(0, Sigma_t)`` error (``increments`` ``(S - 1, 3)``, ``covs`` ``(S - 1, 3, 3)`` from
    :func:`odometry_controls`). Zero covariances give the composed odometry path."""
    later = _later_poses(key, first_pose, increments, covs)
    return jnp.concatenate([jnp.asarray(first_pose, dtype=later.dtype)[None], later], axis=0)


def path_logpdf(path, first_pose, increments, covs):
    """``log p(path)`` under the motion model: the sum over steps of :func:`motion_logpdf`.

    Args:
        path: ``(S, 3)`` poses (x m, y m, theta rad); ``path[0]`` must be ``first_pose`` (the fixed first pose).
        first_pose: ``(3,)`` the first pose.
        increments: ``(S - 1, 3)`` (:func:`odometry_controls`).
        covs: ``(S - 1, 3, 3)``.

    Returns:
        A scalar float; ``-inf`` if ``path[0] != first_pose`` (the first pose is not random). Never raises.
    """
    path = jnp.asarray(path)
    anchored = jnp.all(path[0] == jnp.asarray(first_pose, dtype=path.dtype))
    return jnp.where(anchored, _later_logpdf(path[1:], first_pose, increments, covs), -jnp.inf)


odometry_path = genjax.exact_density(_later_poses, _later_logpdf, name="odometry_path")
"""GenJAX distribution of the poses ``1..S-1`` ``(S - 1, 3)`` given ``(first_pose (3,), increments (S - 1, 3),
covs (S - 1, 3, 3))``: ``simulate`` draws with :func:`sample_path` (without the first pose), ``assess`` scores with
:func:`path_logpdf`'s sum of :func:`motion_logpdf`."""
