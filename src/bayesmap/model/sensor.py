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

The chord geometry (``ModelParams.geometry = "chord"``)
-----------------------------------------------------

The tutorial's geometry (``"entry"``) expects a wall cell's reading at ``d = a``, the distance at which the beam
enters the first wall cell. With ``"chord"`` the beam's first wall cell is entered at ``a`` and left at ``b >= a``
(meters, ``b`` capped at the max range) and the reflecting surface lies anywhere on that chord, uniformly: the
surface distance is ``x ~ Uniform[a, b]`` and the hit component is the sensor model's hit at ``x``, averaged over
``x``. With ``Phi`` the standard Normal CDF and ``G(t) = t Phi(t) + phi(t)`` (``G' = Phi``):

* ``"normal"``: ``f(y | a, b) = (Phi((y - a) / sigma) - Phi((y - b) / sigma)) / (b - a)``
  (:func:`chord_normal_logpdf`), which tends to ``Normal(y; a, sigma)`` as ``b -> a``;
* ``"beam"``: the hit is conditioned on ``y >= 0`` and censored at ``M`` *jointly* over ``(x, y)``: its density on
  ``[0, M)`` is ``(Phi((y - a) / sigma) - Phi((y - b) / sigma)) / (sigma (G(b / sigma) - G(a / sigma)))`` and its
  mass at ``M`` is ``(G((b - M) / sigma) - G((a - M) / sigma)) / (G(b / sigma) - G(a / sigma))``
  (:func:`chord_beam_logpdf`); with ``b -> a`` both tend to the entry geometry's ``eta N(y; a, sigma)`` and
  ``eta (1 - Phi((M - a) / sigma))``. The short component keeps ``d = a`` (objects in front of the wall).

A beam with no wall within range has ``a = b = M``. The mixture (PR sec. 6.3) is Thrun, Burgard & Fox's; averaging
its hit over the chord of the cell is bayesmap's own (derivation and stability in ``docs/sensor.md``). Everything
is in log space (``log_ndtr``, log-differences of CDFs), and a chord shorter than :data:`CHORD_MIN_WIDTH` sigmas is
scored at its midpoint, where the difference of CDFs would cancel (relative error below ``CHORD_MIN_WIDTH**2``).

Wall cells a beam can pass (``ModelParams.wall_pass_prob``): the reading then comes from the ray's first or second
wall cell or from no wall, each part the model above in its geometry (:mod:`bayesmap.model.passable`).

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

The beam model's and the chord geometry's densities and samplers are ``jax.jit`` functions, inlined where they are
called: a model traced again (``assess``, ``simulate``, a vmap over cells) reuses their traced programs for inputs of
the same shapes instead of tracing their few hundred operations again, and the compiled program is the one without
``jit`` (the same numbers, faster to compile: [speed](../validation/speed.md#test-by-test-ab83986-b26e4fd)).
"""

from __future__ import annotations

import functools
import math

import genjax
import jax
import jax.numpy as jnp
from jax.scipy.special import erf, log_ndtr, ndtr, ndtri

from bayesmap.errors import BayesmapError

SENSOR_MODELS = ("normal", "beam")
"""Names of the sensor models (``ModelParams.beam_model``)."""

GEOMETRIES = ("entry", "chord")
"""Names of the wall geometries (``ModelParams.geometry``): the reading expected at the face where the beam enters
the first wall cell (the tutorial's), or the hit averaged over the beam's chord through that cell (module
docstring)."""

CHORD_MIN_WIDTH = 1.0e-3
"""Chords shorter than this many ``sigma`` are scored at their midpoint (the Normal or hit at ``(a + b) / 2``): the
difference of CDFs would cancel, and the midpoint's relative error is below ``CHORD_MIN_WIDTH**2 (1 + z**2) / 24``."""

_ASYMPTOTIC_G = -10.0  # below this t, log G(t) from its asymptotic series (the direct formula cancels)

MIN_SHORT_DISTANCE = 1.0e-6
"""Shortest interval ``[0, d]`` of the short component, meters (its normalizer is infinite at ``d = 0``)."""

BEAM_DEFAULTS = {"z_hit": 0.8, "z_short": 0.05, "z_max": 0.05, "z_rand": 0.1, "lambda_short": 0.1}
"""Default mixture weights and ``lambda_short`` (1/m) of the beam model: a conservative starting point (PR gives no
weights; see the module docstring for why each; [validation](../validation/defaults.md#beam_defaults))."""

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


@functools.partial(jax.jit, inline=True)
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


@functools.partial(jax.jit, inline=True)
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


# --- The chord geometry: the hit averaged over the beam's chord through the first wall cell -----------------------


def _log_diff_exp(larger, smaller):
    """``log(exp(larger) - exp(smaller))`` for ``larger >= smaller`` (arrays), ``-inf`` where both are ``-inf``."""
    gap = jnp.minimum(smaller - larger, 0.0)
    return jnp.where(jnp.isneginf(larger), -jnp.inf, larger + jnp.log(-jnp.expm1(gap)))


def log_ndtr_difference(upper, lower):
    """``log(Phi(upper) - Phi(lower))`` for ``upper >= lower`` (arrays, broadcast), stable in both tails: the
    difference of upper-tail CDFs where both are above 0, of lower-tail CDFs where both are below 0 (each as a
    log-difference of ``log_ndtr``), and ``(erf(upper / sqrt 2) - erf(lower / sqrt 2)) / 2`` (two terms of one sign,
    no cancellation) where they straddle 0. ``-inf`` where ``upper == lower``. Never raises."""
    upper, lower = jnp.asarray(upper), jnp.asarray(lower)
    above = _log_diff_exp(log_ndtr(-lower), log_ndtr(-upper))
    below = _log_diff_exp(log_ndtr(upper), log_ndtr(lower))
    straddle = jnp.log(0.5 * (erf(upper / math.sqrt(2.0)) - erf(lower / math.sqrt(2.0))))
    return jnp.where(lower > 0, above, jnp.where(upper < 0, below, straddle))


def log_normal_partial_expectation(t):
    """``log G(t)`` with ``G(t) = t Phi(t) + phi(t) = int_{-inf}^t Phi(u) du = E[(t - Z)^+]`` (``Z`` standard
    Normal), for any ``t`` (array, float): directly for ``t >= -10`` (the cancellation of the two terms costs at most
    a factor ``t**2 = 100`` of rounding), else from the asymptotic series ``G(t) = phi(t) / t**2 (1 - 3 / t**2 +
    15 / t**4 - 105 / t**6 + ...)`` (Abramowitz & Stegun 7.1.23 for the Mills ratio; truncation below 1e-5).
    Never raises."""
    t = jnp.asarray(t)
    direct_t = jnp.maximum(t, _ASYMPTOTIC_G)
    direct = jnp.log(direct_t * ndtr(direct_t) + jnp.exp(-0.5 * direct_t * direct_t - _HALF_LOG_2PI))
    far = jnp.minimum(t, _ASYMPTOTIC_G)
    inv = 1.0 / (far * far)
    series = (-0.5 * far * far - _HALF_LOG_2PI + jnp.log(inv)
              + jnp.log1p(inv * (-3.0 + inv * (15.0 - 105.0 * inv))))
    return jnp.where(t >= _ASYMPTOTIC_G, direct, series)


def _chord_parts(a, b, sigma):
    """``(width in sigmas, wide, safe width, midpoint)`` of chords ``[a, b]``: ``wide`` where the chord is at least
    :data:`CHORD_MIN_WIDTH` sigmas long (scored by the closed form), else at the midpoint."""
    a, b = jnp.asarray(a), jnp.asarray(b)
    width = (b - a) / sigma
    wide = width >= CHORD_MIN_WIDTH
    return width, wide, jnp.where(wide, width, 1.0), 0.5 * (a + b)


@functools.partial(jax.jit, inline=True)
def chord_normal_logpdf(y, a, b, sigma):
    """The Normal averaged over the chord: ``log f(y | a, b)``, ``f = (Phi((y - a) / sigma) - Phi((y - b) / sigma))
    / (b - a)``, the density of ``x + sigma Z`` with ``x ~ Uniform[a, b]`` (see the module docstring).

    Args:
        y: reading(s), meters (any shape).
        a: entry distance(s) of the first wall cell, meters (broadcast).
        b: exit distance(s), meters, ``b >= a`` (broadcast); ``b == a`` gives :func:`normal_logpdf` at ``a``.
        sigma: standard deviation, meters, > 0.

    Returns:
        ``broadcast(y, a, b)`` float log-density (1/m); chords shorter than :data:`CHORD_MIN_WIDTH` sigmas are
        scored at the midpoint. Never raises.
    """
    y = jnp.asarray(y)
    _, wide, safe, mid = _chord_parts(a, b, sigma)
    upper = (y - a) / sigma
    lower = jnp.where(wide, upper - safe, upper - 1.0)
    averaged = log_ndtr_difference(upper, lower) - jnp.log(safe) - jnp.log(sigma)
    return jnp.where(wide, averaged, normal_logpdf(y, mid, sigma))


def _chord_log_mass_hit(a, b, sigma):
    """``log P(hit >= 0)`` over the chord: ``log((1 / w) int_{a/sigma}^{b/sigma} Phi(t) dt)`` (``w = (b - a) /
    sigma``), computed as ``log1p((G(-b / sigma) - G(-a / sigma)) / w)`` (``G(t) - G(-t) = t``; both ``G`` terms are
    at most ``phi(0)``, so nothing cancels for ``a >= 0``); ``log Phi(mid / sigma)`` for short chords."""
    _, wide, safe, mid = _chord_parts(a, b, sigma)
    def g(t):
        return t * ndtr(t) + jnp.exp(-0.5 * t * t - _HALF_LOG_2PI)

    averaged = jnp.log1p((g(-jnp.asarray(b) / sigma) - g(-jnp.asarray(a) / sigma)) / safe)
    return jnp.where(wide, averaged, log_ndtr(mid / sigma))


def chord_beam_log_density(y, a, b, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """The continuous part of the chord beam mixture (:func:`chord_beam_logpdf` for readings below the max range):
    the hit averaged over the chord ``[a, b]`` and conditioned on ``y >= 0`` jointly, the short component on
    ``[0, a]``, the uniform. Arguments as :func:`chord_beam_logpdf`.

    Returns:
        ``broadcast(y, a, b)`` float ``log f(y | a, b)`` (1/m), ``-inf`` for ``y < 0``. Never raises.
    """
    y = jnp.asarray(y)
    log_hit = jnp.log(z_hit) + chord_normal_logpdf(y, a, b, sigma) - _chord_log_mass_hit(a, b, sigma)
    d_short = jnp.maximum(jnp.asarray(a), MIN_SHORT_DISTANCE)
    log_short = (jnp.log(z_short) + jnp.log(lambda_short) - lambda_short * y
                 - jnp.log(-jnp.expm1(-lambda_short * d_short)))
    log_short = jnp.where(y <= d_short, log_short, -jnp.inf)
    log_rand = jnp.broadcast_to(jnp.log(z_rand) - jnp.log(max_range), log_hit.shape)
    return jnp.where(y < 0, -jnp.inf, _logsumexp(log_hit, jnp.broadcast_to(log_short, log_hit.shape), log_rand))


def chord_beam_log_max_mass(a, b, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """The point mass of the chord beam mixture at the max range: ``log(z_max + z_hit P(hit censored to M))`` with
    ``P = (G((b - M) / sigma) - G((a - M) / sigma)) / (G(b / sigma) - G(a / sigma))`` (module docstring), the
    numerator as a log-difference of :func:`log_normal_partial_expectation` (stable far below the max range).
    Arguments as :func:`chord_beam_logpdf` without ``y``.

    Returns:
        ``broadcast(a, b)`` float log-probability. Never raises.
    """
    a, b = jnp.asarray(a), jnp.asarray(b)
    _, wide, safe, mid = _chord_parts(a, b, sigma)
    hi = jnp.where(wide, (b - max_range) / sigma, 0.0)
    lo = jnp.where(wide, (a - max_range) / sigma, -1.0)
    averaged = _log_diff_exp(log_normal_partial_expectation(hi), log_normal_partial_expectation(lo)) - jnp.log(safe)
    log_censored = jnp.where(wide, averaged, log_ndtr((mid - max_range) / sigma))
    log_tail = jnp.log(z_hit) + log_censored - _chord_log_mass_hit(a, b, sigma)
    return jnp.logaddexp(jnp.log(z_max), log_tail)


@functools.partial(jax.jit, inline=True)
def chord_beam_logpdf(y, a, b, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """Log-density of the beam mixture with its hit averaged over the chord ``[a, b]`` of the first wall cell
    (module docstring; PR sec. 6.3 for the mixture, the chord averaging is bayesmap's).

    Args:
        y: reading(s), meters; ``y >= max_range`` is a max-range reading.
        a: entry distance of the first wall cell, meters, in ``[0, max_range]`` (``max_range``: no wall).
        b: exit distance, meters, ``a <= b <= max_range`` (``b == a``: :func:`beam_logpdf` at ``d = a``).
        sigma: hit standard deviation (``sensor_noise``), meters, > 0; the remaining arguments (``z_hit``,
            ``z_short``, ``z_max``, ``z_rand``, ``lambda_short``, ``max_range``) as :func:`beam_logpdf`.

    Returns:
        ``broadcast(y, a, b)`` float: ``log f(y | a, b)`` for ``0 <= y < M`` (1/m), ``log P(y = M | a, b)`` for
        ``y >= M``, ``-inf`` for ``y < 0``. Never raises.
    """
    args = (sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range)
    continuous = chord_beam_log_density(y, a, b, *args)
    return jnp.where(jnp.asarray(y) >= max_range, chord_beam_log_max_mass(a, b, *args), continuous)


CHORD_PROPOSALS = 32
"""Proposals of :func:`chord_beam_sample`'s rejection step (each accepted with probability >= 1/2)."""


def chord_normal_sample(key, a, b, sigma):
    """One draw of :func:`chord_normal_logpdf`: ``x ~ Uniform[a, b]``, then ``x + sigma Z`` (scalar, meters)."""
    k_x, k_z = jax.random.split(key)
    a = jnp.asarray(a)
    x = a + (jnp.asarray(b) - a) * jax.random.uniform(k_x, a.shape, a.dtype)
    return x + sigma * jax.random.normal(k_z, a.shape, a.dtype)


@functools.partial(jax.jit, inline=True)
def chord_beam_sample(key, a, b, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range):
    """One draw of :func:`chord_beam_logpdf` (scalar ``a``, ``b``; meters). The hit draws the surface ``x`` from
    its law given ``y >= 0`` (density proportional to ``Phi(x / sigma)`` on ``[a, b]``: uniform proposals accepted
    with probability ``Phi(x / sigma) >= 1/2``, the first of :data:`CHORD_PROPOSALS` accepted, so a draw is exact
    but for probability ``2**-32``), then ``y`` as :func:`beam_sample`'s hit at ``x``; the other components as
    :func:`beam_sample` with ``d = a``."""
    a = jnp.asarray(a)
    dtype = jnp.result_type(a.dtype, float)
    k_x, k_acc, k_rest = jax.random.split(key, 3)
    xs = a + (jnp.asarray(b) - a) * jax.random.uniform(k_x, (CHORD_PROPOSALS,), dtype)
    accept = jax.random.uniform(k_acc, (CHORD_PROPOSALS,), dtype) < ndtr(xs / sigma)
    x = xs[jnp.argmax(accept)]
    draw = beam_sample(k_rest, a, sigma, z_hit, z_short, z_max, z_rand, lambda_short, max_range)
    k_comp, k_u = jax.random.split(k_rest)  # beam_sample's own keys: the same component and uniform
    weights = jnp.stack([jnp.asarray(w, dtype) for w in (z_hit, z_short, z_max, z_rand)])
    comp = jax.random.categorical(k_comp, jnp.log(weights))
    u = jax.random.uniform(k_u, a.shape, dtype=dtype)
    hit = jnp.minimum(x - sigma * ndtri(u * ndtr(x / sigma)), max_range)
    return jnp.asarray(jnp.where(comp == 0, hit, draw), dtype)


chord_normal_reading = genjax.exact_density(chord_normal_sample, chord_normal_logpdf, name="chord_normal_reading")
"""GenJAX distribution of the ``"normal"`` model in the chord geometry, arguments ``(a, b, sigma)``."""

chord_beam_reading = genjax.exact_density(chord_beam_sample, chord_beam_logpdf, name="chord_beam_reading")
"""GenJAX distribution of the ``"beam"`` model in the chord geometry, arguments ``(a, b, sigma, z_hit, z_short,
z_max, z_rand, lambda_short, max_range)``."""


normal_reading = genjax.normal
"""GenJAX distribution of the ``"normal"`` model: ``genjax.normal``, arguments ``(d, sigma)``."""

beam_reading = genjax.exact_density(beam_sample, beam_logpdf, name="beam_reading")
"""GenJAX distribution of the ``"beam"`` model, arguments ``(d, sigma, z_hit, z_short, z_max, z_rand, lambda_short,
max_range)``: ``simulate`` draws with :func:`beam_sample`, ``assess`` scores with :func:`beam_logpdf`."""


def reading_distribution(beam_model: str, geometry: str = "entry"):
    """The GenJAX distribution of ``beam_model`` in ``geometry``: :data:`normal_reading` or :data:`beam_reading`
    (``"entry"``, arguments ``(d, *sensor_args)``), :data:`chord_normal_reading` or :data:`chord_beam_reading`
    (``"chord"``, arguments ``(a, b, *sensor_args)``); see :func:`reading_logpdf`.

    Raises:
        BayesmapError: on an unknown model or geometry name.
    """
    check_beam_model(beam_model)
    if check_geometry(geometry) == "chord":
        return chord_normal_reading if beam_model == "normal" else chord_beam_reading
    return normal_reading if beam_model == "normal" else beam_reading


def reading_logpdf(beam_model: str, y, d, sensor_args: tuple, exit_distance=None):
    """Log-density of readings ``y`` given the first wall's distances ``d`` (meters, broadcast) under ``beam_model``.

    Args:
        beam_model: ``"normal"`` or ``"beam"`` (static).
        y: readings, meters.
        d: entry distances of the first wall cell, meters (broadcast with ``y``).
        sensor_args: ``(sigma,)`` for ``"normal"``; ``(sigma, z_hit, z_short, z_max, z_rand, lambda_short,
            max_range)`` for ``"beam"`` (``ModelParams.sensor_args``).
        exit_distance: None for the tutorial's entry geometry; else the chord geometry's exit distances ``b >= d``
            (meters, broadcast).

    Returns:
        ``broadcast(y, d)`` float (:func:`normal_logpdf` or :func:`beam_logpdf`; with ``exit_distance``
        :func:`chord_normal_logpdf` or :func:`chord_beam_logpdf`).

    Raises:
        BayesmapError: on an unknown model name or the wrong number of arguments.
    """
    check_beam_model(beam_model)
    want = 1 if beam_model == "normal" else 7
    if len(sensor_args) != want:
        raise BayesmapError(f"sensor model {beam_model!r} takes {want} parameters, got {len(sensor_args)}")
    if exit_distance is not None:
        logpdf = chord_normal_logpdf if beam_model == "normal" else chord_beam_logpdf
        return logpdf(y, d, exit_distance, *sensor_args)
    return normal_logpdf(y, d, *sensor_args) if beam_model == "normal" else beam_logpdf(y, d, *sensor_args)


def check_geometry(geometry) -> str:
    """Return ``geometry`` if it names a wall geometry (:data:`GEOMETRIES`), else raise :class:`BayesmapError`
    naming it."""
    if geometry not in GEOMETRIES:
        raise BayesmapError(f"unknown geometry {geometry!r}; choose one of {', '.join(GEOMETRIES)}")
    return geometry


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
