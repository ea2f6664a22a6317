"""Sensor models: the log-density of a range reading ``y`` given the exact distance ``d`` to the first wall.

Two models, chosen by name (``ModelParams.beam_model``, static):

* ``"normal"``, the tutorial's: ``y ~ Normal(d, sensor_noise)`` on the whole real line
  (:func:`normal_logpdf`; GenJAX distribution :data:`normal_reading`, which *is* ``genjax.normal``, so the
  tutorial's model, its readings and its scores are unchanged).
* ``"beam"``, the robust beam range-finder mixture of Thrun, Burgard & Fox, *Probabilistic Robotics* (PR), sec.
  6.3.1, eqs. 6.4-6.12 (:func:`beam_logpdf`; GenJAX distribution :data:`beam_reading`).

The beam mixture as implemented
-------------------------------

A reading lives on ``[0, M]`` with ``M = max_range`` (meters; the model's max distance ``ModelParams.max_range``).
Its law is a *mixed* measure: a density on ``[0, M)`` plus a point mass at ``y = M`` (a "max-range reading", no
return). :func:`beam_logpdf` returns the log of the density for ``0 <= y < M`` and the log of the point mass for
``y >= M`` (every ``y >= M`` is read as a max-range reading; a real sensor reports nothing beyond ``M``), i.e. the
density with respect to Lebesgue measure on ``[0, M)`` plus a unit atom at ``M``; ``-inf`` for ``y < 0``. With
weights ``z_hit + z_short + z_max + z_rand = 1`` (PR eq. 6.12) and ``sigma = sensor_noise``:

* **hit** (PR eqs. 6.4-6.6): ``Normal(d, sigma)`` conditioned on ``y >= 0`` (PR's normalizer ``eta`` for the
  lower end: the mass below 0 is renormalized away, ``eta = 1 / Phi(d / sigma)``), and *censored* at the upper
  end: a hit that would land at or beyond ``M`` is reported as the max-range reading. Density
  ``eta N(y; d, sigma)`` on ``[0, M)``, mass ``eta (1 - Phi((M - d) / sigma))`` at ``M``.

  Deviation from PR, on purpose: PR truncates the hit to ``[0, M]`` and renormalizes over it, so its point mass at
  ``M`` is ``z_max`` whatever ``d`` is: a max-range reading then says nothing about the map. Censoring keeps the
  information the tutorial's model and the CARMEN pipeline rely on: a ray with no wall within range has
  ``d = M`` and puts ``z_hit / 2 + z_max`` on the max-range reading (0.45 with the defaults), a ray that meets a
  wall well within range only ``z_max`` (0.05); a max-range reading is evidence of free space, bounded to
  ``log 9`` per beam. For ``y < M`` the density differs from PR's only by the normalizer ``Phi((M - d) / sigma)``,
  which is 1 unless the wall is within a few ``sigma`` of the max range.
* **short** (PR eqs. 6.7-6.8): ``lambda_short exp(-lambda_short y) / (1 - exp(-lambda_short d))`` on ``[0, d]``
  (unexpected objects in front of the wall). For ``d`` below ``MIN_SHORT_DISTANCE`` (a sensor on a cell edge;
  PR's normalizer is infinite at ``d = 0``) the interval is ``[0, MIN_SHORT_DISTANCE]``, so the component is a
  proper density for every ``d >= 0``.
* **max** (PR eq. 6.9): a point mass at ``M`` (sensor failures: specular or black surfaces).
* **rand** (PR eq. 6.10): uniform ``1 / M`` on ``[0, M)``.

The mixture (PR eq. 6.11) is therefore a probability measure on ``[0, M]`` for every ``d`` in ``[0, M]``:
``z_hit + z_short + z_rand`` of continuous mass plus ``z_max + z_hit eta (1 - Phi((M - d) / sigma))`` at ``M``,
hit's parts adding up to ``z_hit`` (tested by quadrature in ``tests/test_sensor.py``). Everything is computed in
log space (``log_ndtr``, ``logsumexp``), so far tails do not underflow to ``-inf``.

Default parameters (:data:`BEAM_DEFAULTS`)
------------------------------------------

PR learns the weights from data (PR sec. 6.3.2, Table 6.2) and gives none; these defaults are a conservative
starting point:

* ``z_hit = 0.8``: most returns come from the first wall (the model's job); hits keep the dominant weight.
* ``z_short = 0.05``: few unexpected objects in a static map (people walking by in CARMEN logs).
* ``z_max = 0.05``: max-range failures are rare for a laser; ROS ``amcl``'s default ``laser_z_max`` is also 0.05.
* ``z_rand = 0.1``: the floor that makes the model robust: one reading can move the log-odds of a cell by at most
  about ``log(peak hit density / (z_rand / M))``, e.g. ``log((0.8 / (0.2 sqrt(2 pi))) / (0.1 / 42)) = 6.5`` on the
  tutorial scene, instead of ``(y - d)^2 / (2 sigma^2)`` without bound for the Normal.
* ``lambda_short = 0.1`` per meter: ROS ``amcl``'s / Nav2's default ``lambda_short``; over room-sized distances the
  short component is close to uniform on ``[0, d]``.
"""

from __future__ import annotations

import functools
import math

import genjax
import jax
import jax.numpy as jnp
from jax.scipy.special import log_ndtr, ndtr, ndtri

from bayesmap.errors import BayesmapError

SENSOR_MODELS = ("normal", "beam")
"""Names of the sensor models (``ModelParams.beam_model``)."""

MIN_SHORT_DISTANCE = 1.0e-6
"""Shortest interval ``[0, d]`` of the short component, meters (its normalizer is infinite at ``d = 0``)."""

BEAM_DEFAULTS = {"z_hit": 0.8, "z_short": 0.05, "z_max": 0.05, "z_rand": 0.1, "lambda_short": 0.1}
"""Default mixture weights and ``lambda_short`` (1/m) of the beam model; see the module docstring for why."""

WEIGHT_SUM_TOL = 1.0e-6
"""How far ``z_hit + z_short + z_max + z_rand`` may be from 1 (rounding of decimal inputs)."""

_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


def normal_logpdf(y, d, sigma):
    """The tutorial's sensor model: ``log Normal(y; d, sigma)``.

    Args:
        y: reading(s), meters (any shape).
        d: exact distance(s) to the first wall, meters (broadcast with ``y``).
        sigma: standard deviation, meters, > 0 (scalar or broadcast).

    Returns:
        The log-density, shape ``broadcast(y, d, sigma)``, float. Equal to ``genjax.normal``'s ``assess`` up to
        floating-point rounding (TFP orders the same operations differently); the fast samplers have always used
        exactly this arithmetic. Never raises.
    """
    z = (y - d) / sigma
    return -0.5 * z * z - jnp.log(sigma) - 0.5 * jnp.log(2 * jnp.pi)


def _logsumexp(*terms):
    """``jax.nn.logsumexp`` of ``terms`` (arrays of one shape) stacked on a new first axis, written out: the same
    operations in the same order (so the same bits), without the stack and the reduction over a short axis, which
    XLA's CPU backend runs several times slower (measured 4x for three terms on 42 million elements)."""
    top = functools.reduce(jnp.maximum, terms)
    top = jax.lax.stop_gradient(jnp.where(jnp.isfinite(top), top, 0.0))
    total = functools.reduce(jnp.add, [jnp.exp(t - top) for t in terms])
    return jnp.log(total) + top


def beam_log_density(y, d, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """The continuous part of the beam mixture: what :func:`beam_logpdf` returns for readings below the max range.

    The arguments are those of :func:`beam_logpdf` (``z_max`` is not used).

    Returns:
        ``broadcast(y, d)`` float: ``log f(y | d)`` (1/m) of the hit, short and rand components, whatever ``y`` is
        (:func:`beam_logpdf` uses it for ``0 <= y < M``), ``-inf`` for ``y < 0``. Never raises.
    """
    y = jnp.asarray(y)
    d = jnp.asarray(d)
    log_mass_hit = log_ndtr(d / sigma)  # log P(Normal(d, sigma) >= 0), PR eq. 6.5's normalizer for the lower end
    z = (y - d) / sigma
    log_hit = jnp.log(z_hit) - 0.5 * z * z - jnp.log(sigma) - _HALF_LOG_2PI - log_mass_hit
    d_short = jnp.maximum(d, MIN_SHORT_DISTANCE)
    log_short = (jnp.log(z_short) + jnp.log(lambda_short) - lambda_short * y
                 - jnp.log(-jnp.expm1(-lambda_short * d_short)))
    log_short = jnp.where(y <= d_short, log_short, -jnp.inf)
    log_rand = jnp.broadcast_to(jnp.log(z_rand) - jnp.log(max_range), log_hit.shape)
    return jnp.where(y < 0, -jnp.inf, _logsumexp(log_hit, log_short, log_rand))


def beam_log_max_mass(d, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """The point mass of the beam mixture at the max range: what :func:`beam_logpdf` returns for ``y >= M``.

    The arguments are those of :func:`beam_logpdf` without ``y`` (``z_short``, ``z_rand`` and ``lambda_short`` are
    not used).

    Returns:
        ``d.shape`` float: ``log P(y = M | d) = log(z_max + z_hit P(hit censored to M))`` (a probability). Never
        raises.
    """
    d = jnp.asarray(d)
    log_mass_hit = log_ndtr(d / sigma)
    log_tail = jnp.log(z_hit) + log_ndtr((d - max_range) / sigma) - log_mass_hit  # hits censored to the max range
    return jnp.logaddexp(jnp.log(z_max), log_tail)


def beam_logpdf(y, d, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """Log-density of the robust beam mixture (PR eqs. 6.4-6.12, with the hit censored at ``max_range``; see the
    module docstring for the exact convention).

    Args:
        y: reading(s), meters (any shape); ``y >= max_range`` is a max-range reading.
        d: exact distance(s) to the first wall, meters, in ``[0, max_range]`` (``max_range`` when no wall is within
            range); broadcast with ``y``.
        sigma: hit standard deviation (``sensor_noise``), meters, > 0.
        z_hit: weight of the hit component (> 0); the four weights are >= 0 and sum to 1.
        z_short: weight of the short component (unexpected objects).
        z_max: weight of the max-range point mass (failures).
        z_rand: weight of the uniform component (random readings).
        lambda_short: rate of the short component, 1/m, > 0.
        max_range: the sensor's max range ``M``, meters, > 0.

    Returns:
        ``broadcast(y, d)`` float: ``log f(y | d)`` for ``0 <= y < M`` (density, 1/m; :func:`beam_log_density`),
        ``log P(y = M | d)`` for ``y >= M`` (probability; :func:`beam_log_max_mass`), ``-inf`` for ``y < 0``.
        Parameters are not checked here (this runs inside jit); :func:`check_sensor_params` does. Never raises.
    """
    args = (sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range)
    continuous = beam_log_density(y, d, *args)
    return jnp.where(jnp.asarray(y) >= max_range, beam_log_max_mass(d, *args), continuous)


def beam_sample(key, d, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """One draw from the beam mixture (see :func:`beam_logpdf` for the arguments; scalar ``d``).

    A component is drawn with probabilities ``(z_hit, z_short, z_max, z_rand)``, then the reading by inverse CDF:
    hit ``d - sigma Phi^-1(u Phi(d / sigma))`` (Normal conditioned on ``>= 0``) capped at ``max_range``; short
    ``-log(1 - u (1 - exp(-lambda d))) / lambda``; max ``max_range``; rand ``u max_range``.

    Returns:
        A scalar float reading in ``[0, max_range]``, meters. Never raises.
    """
    d = jnp.asarray(d)
    dtype = jnp.result_type(d.dtype, float)
    k_comp, k_u = jax.random.split(key)
    weights = jnp.stack([jnp.asarray(w, dtype) for w in (z_hit, z_short, z_max, z_rand)])
    comp = jax.random.categorical(k_comp, jnp.log(weights))
    u = jax.random.uniform(k_u, d.shape, dtype=dtype)
    hit = jnp.minimum(d - sigma * ndtri(u * ndtr(d / sigma)), max_range)
    d_short = jnp.maximum(d, MIN_SHORT_DISTANCE)
    short = -jnp.log1p(u * jnp.expm1(-lambda_short * d_short)) / lambda_short
    candidates = jnp.stack([hit, short, jnp.full_like(hit, max_range), u * max_range])
    return jnp.asarray(candidates[comp], dtype)


normal_reading = genjax.normal
"""GenJAX distribution of the ``"normal"`` model: ``genjax.normal``, arguments ``(d, sigma)``."""

beam_reading = genjax.exact_density(beam_sample, beam_logpdf, name="beam_reading")
"""GenJAX distribution of the ``"beam"`` model, arguments ``(d, sigma, z_hit, z_short, z_max, z_rand, lambda_short,
max_range)``: ``simulate`` draws with :func:`beam_sample`, ``assess`` scores with :func:`beam_logpdf`."""


def reading_distribution(beam_model: str):
    """The GenJAX distribution of ``beam_model`` (:data:`normal_reading` or :data:`beam_reading`); it takes
    ``(d, *sensor_args)``, see :func:`reading_logpdf`.

    Raises:
        BayesmapError: on an unknown name.
    """
    check_beam_model(beam_model)
    return normal_reading if beam_model == "normal" else beam_reading


def reading_logpdf(beam_model: str, y, d, sensor_args: tuple):
    """Log-density of readings ``y`` given exact distances ``d`` (meters, broadcast) under ``beam_model``.

    Args:
        beam_model: ``"normal"`` or ``"beam"`` (static).
        y: readings, meters.
        d: exact distances to the first wall, meters (broadcast with ``y``).
        sensor_args: ``(sigma,)`` for ``"normal"``; ``(sigma, z_hit, z_short, z_max, z_rand, lambda_short,
            max_range)`` for ``"beam"`` (``ModelParams.sensor_args``).

    Returns:
        ``broadcast(y, d)`` float (:func:`normal_logpdf` or :func:`beam_logpdf`).

    Raises:
        BayesmapError: on an unknown model name or the wrong number of arguments.
    """
    check_beam_model(beam_model)
    want = 1 if beam_model == "normal" else 7
    if len(sensor_args) != want:
        raise BayesmapError(f"sensor model {beam_model!r} takes {want} parameters, got {len(sensor_args)}")
    return normal_logpdf(y, d, *sensor_args) if beam_model == "normal" else beam_logpdf(y, d, *sensor_args)


def check_beam_model(beam_model) -> str:
    """Return ``beam_model`` if it names a sensor model, else raise :class:`BayesmapError` naming it."""
    if beam_model not in SENSOR_MODELS:
        raise BayesmapError(f"unknown beam_model {beam_model!r}; choose one of {', '.join(SENSOR_MODELS)}")
    return beam_model


def check_sensor_params(beam_model, z_hit, z_short, z_max, z_rand, lambda_short) -> tuple[float, ...]:
    """Validate the beam mixture's parameters (checked whatever ``beam_model`` is, so that switching the model on
    never meets bad defaults).

    Returns:
        ``(z_hit, z_short, z_max, z_rand, lambda_short)`` as floats.

    Raises:
        BayesmapError: on an unknown ``beam_model``; a weight that is not finite and >= 0 (``z_hit`` must be > 0:
            the hit is the only component with support everywhere on ``[0, max_range)`` and at ``max_range``);
            weights whose sum is not 1 within :data:`WEIGHT_SUM_TOL`; ``lambda_short`` not finite and > 0. The
            message names the offending parameter and value.
    """
    check_beam_model(beam_model)
    weights = {"z_hit": z_hit, "z_short": z_short, "z_max": z_max, "z_rand": z_rand}
    out = {}
    for name, value in weights.items():
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise BayesmapError(f"{name} must be a number, got {value!r}") from None
        if not (math.isfinite(v) and v >= 0):
            raise BayesmapError(f"{name} must be a finite weight >= 0, got {value!r}")
        out[name] = v
    if not out["z_hit"] > 0:
        raise BayesmapError(f"z_hit must be > 0 (the hit component is the only one that covers every reading), "
                            f"got {z_hit!r}")
    total = sum(out.values())
    if abs(total - 1.0) > WEIGHT_SUM_TOL:
        listed = ", ".join(f"{k}={v!r}" for k, v in weights.items())
        raise BayesmapError(f"beam weights must sum to 1, got {listed} (sum {total!r})")
    try:
        lam = float(lambda_short)
    except (TypeError, ValueError):
        raise BayesmapError(f"lambda_short must be a number, got {lambda_short!r}") from None
    if not (math.isfinite(lam) and lam > 0):
        raise BayesmapError(f"lambda_short must be a finite rate > 0 (1/m), got {lambda_short!r}")
    return out["z_hit"], out["z_short"], out["z_max"], out["z_rand"], lam
