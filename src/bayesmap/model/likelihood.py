"""The likelihood side of the fast samplers' conditionals, in one place: their inputs (checked readings, the sensor
model's arguments in the kernel dtype, the max-range rule), the tables of ``log p(y | d)`` they look up, and
tempering.

A cell's (or block's) Gibbs conditional under the model of :mod:`bayesmap.model.generative` is

    log w(c) = log prior(c) + eta * sum over the rays r through the cell of log p(y_r | d_r(c))

up to a constant (derived in ``docs/fast-conditional.md``): ``log p(y | d)`` is the sensor model
(:func:`bayesmap.model.sensor.reading_logpdf`) at the ray's expected distance ``d`` (meters), and ``eta`` the
likelihood power (:func:`tempered`). The prior part is :func:`bayesmap.model.generative.prior_log_odds` per wall.
Used by :mod:`bayesmap.inference.fast` and :mod:`bayesmap.inference.cellwise`.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import RayTable, check_readings
from bayesmap.model.generative import ModelParams, check_likelihood_power, check_opaque_walls, ray_limits
from bayesmap.model.sensor import reading_logpdf


class LikelihoodInputs(NamedTuple):
    """The checked inputs of a sampler's likelihood terms (:func:`likelihood_inputs`).

    Attributes:
        readings: ``(R,)`` float64 range readings, meters, one per ray of the table.
        beam_model: the sensor model's name (``"normal"`` or ``"beam"``).
        sensor_args: ``params.sensor_args`` as scalar arrays of ``dtype``.
        dtype: the kernel's float dtype (``jnp.result_type(float)``: float32 unless x64 is enabled).
        likelihood_power: ``eta`` in (0, 1] (:func:`tempered`).
        geometry: ``params.geometry`` (``"entry"`` or ``"chord"``): with ``"chord"`` the tables score each pair's
            chord, from its entry distance to its exit distance
            (:attr:`~bayesmap.geometry.raytable.RayTable.pair_exits`).
    """

    readings: np.ndarray
    beam_model: str
    sensor_args: tuple
    dtype: jnp.dtype
    likelihood_power: float
    geometry: str = "entry"


def check_max_range(table: RayTable, params: ModelParams) -> None:
    """The max-range rule: with a sensor model that has a max range (``"beam"``: a point mass at the max range,
    Thrun, Burgard & Fox, *Probabilistic Robotics*, sec. 6.3), the table's max distance (meters) must be that max
    range, ``params.max_range``, so that a ray with no wall in the table has exactly the model's "no wall" distance.
    The Normal sensor has no max range: any table fits.

    Raises:
        BayesmapError: if the beam model's max range differs from the table's max distance (both named).
    """
    if params.beam_model != "normal" and not math.isclose(float(table.max_distance), params.max_range, rel_tol=1e-12):
        raise BayesmapError(f"the table's max distance {table.max_distance!r} m is not the model's max range "
                            f"params.max_range = {params.max_range!r} m")


def check_ray_limits(table: RayTable, readings, params: ModelParams) -> None:
    """The cut rule: a table for a model whose beams are cut past their readings (``params.cut``) lists exactly the
    cells the model looks at, its :attr:`~bayesmap.geometry.raytable.RayTable.ray_limits` those of
    :func:`bayesmap.model.generative.ray_limits` for ``readings`` ``(R,)`` (meters); a table for an uncut model has
    none.

    Raises:
        BayesmapError: when the table's ray limits do not match the model's (both named).
    """
    want = ray_limits(readings, params, table.pair_dists.dtype)
    if want is None and table.ray_limits is not None:
        raise BayesmapError("the table is cut past the readings but the model is not (params.cut_past_reading = "
                            f"{params.cut_past_reading!r}): build the table without ray_limits")
    if want is not None and (table.ray_limits is None or not np.array_equal(table.ray_limits, want)):
        raise BayesmapError(f"the model cuts each beam {params.cut_past_reading!r} m past its reading but the table's "
                            "ray limits differ: build it with ray_limits=bayesmap.model.generative.ray_limits("
                            "readings, params)")


def likelihood_inputs(table: RayTable, readings, params: ModelParams,
                      likelihood_power: float = 1.0, passable: bool = False) -> LikelihoodInputs:
    """Check a sampler's arguments and cast them for its kernel (see :class:`LikelihoodInputs`).

    Args:
        table: the ray-cell table (its rays in the order of ``readings``).
        readings: ``(R,)`` ranges, meters (max-range readings equal to the max distance).
        params: model parameters (the sensor model).
        likelihood_power: ``eta`` (:func:`bayesmap.model.generative.check_likelihood_power`).
        passable: whether the sampler handles wall cells a beam can pass (``params.wall_pass_prob > 0``: each ray's
            first two walls); the level-based samplers keep one.

    Raises:
        BayesmapError: on readings that do not match the table's rays (:func:`check_readings`), a bad likelihood
            power, a table that breaks the max-range rule (:func:`check_max_range`) or the cut rule
            (:func:`check_ray_limits`), or ``params.wall_pass_prob > 0``
            for a sampler that is not ``passable``.
    """
    if not passable:
        check_opaque_walls(params, "this sampler")
    y = check_readings(readings, table.num_rays)
    eta = check_likelihood_power(likelihood_power)
    check_max_range(table, params)
    check_ray_limits(table, y, params)
    dtype = jnp.result_type(float)
    sensor_args = tuple(jnp.asarray(a, dtype=dtype) for a in params.sensor_args)
    return LikelihoodInputs(readings=y, beam_model=params.beam_model, sensor_args=sensor_args, dtype=dtype,
                            likelihood_power=eta, geometry=params.geometry)


def tempered(log_likelihood, likelihood_power):
    """Tempering, the one rule of every sampler: each ``log p(y | d)`` term of a conditional (any shape) times the
    likelihood power ``eta`` (a float or scalar array), before terms are summed or differenced; the prior part is
    never tempered. A chain then targets ``p(walls) p(readings | walls) ** eta``
    (:func:`bayesmap.model.generative.check_likelihood_power` for the sources); ``eta = 1`` leaves every term as
    it is (bit for bit)."""
    return likelihood_power * log_likelihood


def padded_length(n: int) -> int:
    """The length an array of ``n`` entries is padded to before a jitted function whose compilation depends on its
    length: the smallest ``m * 2 ** e >= n`` with ``m`` in 4..7 (``n`` itself below 8), so lengths within 25 % of
    each other mostly share one compilation, and padding adds at most 25 % to the work.

    Raises:
        ValueError: on a negative ``n``.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if n < 8:
        return n
    e = max(int(n).bit_length() - 3, 0)
    return -(-n // 2 ** e) * 2 ** e


def padded(values: np.ndarray, length: int, fill: float) -> np.ndarray:
    """``values`` ``(n, ...)`` followed by rows of ``fill`` up to ``(length, ...)`` (``length >= n``), in their
    dtype: the padding that lets arrays of many lengths share one compilation (:func:`chunked_length`)."""
    out = np.full((length, *values.shape[1:]), fill, dtype=values.dtype)
    out[:len(values)] = values
    return out


@partial(jax.jit, static_argnames=("beam_model",))
def log_likelihood_table(beam_model: str, sensor_args, y, d, exit_distance=None):
    """``log p(y | d)`` of the sensor model ``beam_model`` (``sensor_args`` as :attr:`LikelihoodInputs.sensor_args`)
    for readings ``y`` and distances ``d`` (meters, broadcast shapes; result of their shape and dtype), 0 where ``d``
    is ``inf`` (a block configuration that does not stop the ray: never selected). With ``exit_distance`` (meters,
    broadcast with ``d``) the chord geometry's ``log p(y | d, exit_distance)``."""
    finite = jnp.isfinite(d)
    if exit_distance is None:
        ll = reading_logpdf(beam_model, y, d, sensor_args)
    else:  # the chord's closed form is evaluated at a finite chord where d is inf (and then not selected)
        ll = reading_logpdf(beam_model, y, jnp.where(finite, d, 0.0), sensor_args,
                            jnp.where(finite, exit_distance, 0.0))
    return jnp.where(jnp.isfinite(d), ll, 0.0)


PAIR_CHUNK = 1 << 16
"""Entries of ``log p(y | d)`` computed by one call of the compiled table (:func:`chunked_log_likelihoods`): every
table of any size then runs one compilation. 65,536 float entries: 256 KB of each input, a call's overhead (tens of
microseconds) small beside its work."""


def chunked_length(n: int) -> int:
    """The length ``L`` of :func:`chunked_log_likelihoods`' result for ``n`` entries: ``PAIR_CHUNK *
    padded_length(n // PAIR_CHUNK + 1)``, ``L > n``; arrays padded to it run the same compiled operations for
    every ``n`` of one ``L``.

    Raises:
        ValueError: on a negative ``n``.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    return PAIR_CHUNK * padded_length(n // PAIR_CHUNK + 1)


def chunked_log_likelihoods(beam_model: str, sensor_args, y: np.ndarray, d: np.ndarray,
                            exits: np.ndarray | None = None) -> jax.Array:
    """``(L,)`` :func:`log_likelihood_table` of the readings ``y`` and distances ``d`` (``(N,)`` float, meters; with
    ``exits`` ``(N,)`` the chord geometry's exit distances), computed :data:`PAIR_CHUNK` entries at a time, so that
    arrays of any length share one compilation; then zeros up to ``L = PAIR_CHUNK * padded_length(n) > N`` for
    ``n = N // PAIR_CHUNK + 1`` chunks (:func:`padded_length`: the concatenation's compilations). Dispatched
    asynchronously (the caller can work on while it is computed)."""
    dtype = sensor_args[0].dtype
    size = len(y)
    num = size // PAIR_CHUNK + 1
    length = num * PAIR_CHUNK
    y, d = padded(np.asarray(y, dtype), length, 0.0), padded(np.asarray(d, dtype), length, np.inf)
    exits = None if exits is None else padded(np.asarray(exits, dtype), length, 0.0)
    parts = []
    for k in range(num):
        chunk = slice(k * PAIR_CHUNK, (k + 1) * PAIR_CHUNK)
        parts.append(log_likelihood_table(beam_model, sensor_args, y[chunk], d[chunk],
                                          None if exits is None else exits[chunk]))
    if num == 1:
        return parts[0]
    return jnp.concatenate(parts + [jnp.zeros(PAIR_CHUNK, dtype)] * (padded_length(num) - num))


def pair_log_likelihoods(table: RayTable, readings: np.ndarray, beam_model: str, sensor_args,
                         geometry: str = "entry") -> jax.Array:
    """``(L,)`` ``log p(y_r | t)`` of the sensor model ``beam_model`` (with ``sensor_args``, scalar arrays of the
    kernel dtype, as ``params.sensor_args``) for every (ray r, cell) pair of ``table``, then zeros (the index ``P``
    pads lookups; ``L > P`` as :func:`chunked_log_likelihoods`, which computes it): ``y_r`` from ``readings``
    ``(R,)`` (meters), ``t`` the pair's stopping distance (meters); in the ``"chord"`` ``geometry``
    ``log p(y_r | t, e)`` with ``e`` the pair's exit distance (:attr:`RayTable.pair_exits`).

    Equal to ``reading_logpdf(beam_model, y, t, sensor_args)`` element by element (the same operations). The
    result is dispatched asynchronously (the caller can work on while it is computed)."""
    dtype = sensor_args[0].dtype
    y = table.per_pair(np.asarray(readings, dtype=dtype))
    exits = table.pair_exits if geometry == "chord" else None
    return chunked_log_likelihoods(beam_model, sensor_args, y, table.pair_dists, exits)


def no_wall_log_likelihoods(inputs: LikelihoodInputs, max_distance: float) -> jax.Array:
    """``(L,)`` ``log p(y_r | no wall)``: the first ``R`` entries those of the rays (the sensor model at the max
    distance, meters; in the chord geometry the chord ``[max_distance, max_distance]``), in the kernel dtype; the
    rest padding (``L > R`` as :func:`chunked_log_likelihoods`)."""
    y = np.asarray(inputs.readings, inputs.dtype)
    no_wall = np.full(len(y), max_distance, inputs.dtype)
    return chunked_log_likelihoods(inputs.beam_model, inputs.sensor_args, y, no_wall,
                                   no_wall if inputs.geometry == "chord" else None)
