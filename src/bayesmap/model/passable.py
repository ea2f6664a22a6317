"""Wall cells a beam can pass (``ModelParams.wall_pass_prob``): the reading of a ray given its first two wall cells.

With ``wall_pass_prob`` ``pi > 0`` a wall cell stops a beam with probability ``1 - pi`` and lets it through with
``pi``: the reading comes from the ray's first wall cell with probability ``1 - pi``, from its second with ``pi (1 -
pi)``, and is read as if there were no wall (the max distance) with ``pi^2`` (:func:`pass_mixture`,
:func:`pass_reading`), each part the sensor model of :mod:`bayesmap.model.sensor` in its geometry. ``pi = 0`` is that
model. The derivation, the sources (reflection and decay-rate maps) and why two walls suffice are in
``docs/sensor.md``, "Wall cells a beam can pass".
"""

from __future__ import annotations

import functools
import math

import genjax
import jax
import jax.numpy as jnp

from bayesmap.errors import BayesmapError
from bayesmap.model.sensor import (
    beam_sample,
    check_beam_model,
    check_geometry,
    chord_beam_sample,
    chord_normal_sample,
    reading_logpdf,
)

PASS_WALLS = 2
"""Wall cells of a ray that a reading can come from when walls can be passed (``wall_pass_prob > 0``): the first and
the second; a beam that passes both reads as if there were no wall (module docstring)."""


def check_wall_pass_prob(value) -> float:
    """Validate ``wall_pass_prob``, the probability that a beam passes through a wall cell it meets, and return it as
    a float.

    Raises:
        BayesmapError: unless it is a number in ``[0, 1)`` (the message names the value).
    """
    try:
        p = float(value)
    except (TypeError, ValueError):
        raise BayesmapError(f"wall_pass_prob must be a number, got {value!r}") from None
    if not (math.isfinite(p) and 0.0 <= p < 1.0):
        raise BayesmapError(f"wall_pass_prob must be in [0, 1) (0: every wall cell stops the beam), got {value!r}")
    return p


def pass_log_weights(pass_prob):
    """``(3,)`` log-probabilities that a beam is reflected by its first wall cell, by its second, or by neither:
    ``log(1 - pi)``, ``log(pi (1 - pi))``, ``log(pi^2)`` for ``pi = pass_prob`` (``-inf`` where ``pi = 0``)."""
    pi = jnp.asarray(pass_prob, jnp.result_type(float))
    log_pass, log_stop = jnp.log(pi), jnp.log1p(-pi)
    return jnp.stack([log_stop, log_pass + log_stop, 2.0 * log_pass])


def pass_mixture(log_first, log_second, log_none, pass_prob):
    """Log-density of a reading when wall cells can be passed: ``log((1 - pi) p1 + pi (1 - pi) p2 + pi^2 p0)`` from
    ``log p1``, ``log p2``, ``log p0``, the sensor model's log-density of the reading given the ray's first wall
    cell, its second, and no wall (broadcast; meters). With ``pi = 0`` it is ``log p1`` exactly. Never raises."""
    w = pass_log_weights(pass_prob)
    return jnp.logaddexp(jnp.logaddexp(w[0] + log_first, w[1] + log_second), w[2] + log_none)


def _wall_logpdf(beam_model: str, geometry: str, y, a, b, sensor_args):
    return reading_logpdf(beam_model, y, a, sensor_args, b if geometry == "chord" else None)


def _wall_sample(beam_model: str, geometry: str, key, a, b, sensor_args):
    if geometry == "chord":
        return (chord_normal_sample if beam_model == "normal" else chord_beam_sample)(key, a, b, *sensor_args)
    if beam_model == "normal":
        a = jnp.asarray(a)
        return a + sensor_args[0] * jax.random.normal(key, a.shape, jnp.result_type(a.dtype, float))
    return beam_sample(key, a, *sensor_args)


@functools.cache
def pass_reading(beam_model: str, geometry: str):
    """The GenJAX distribution of a reading when wall cells can be passed (``ModelParams.wall_pass_prob > 0``), for
    ``beam_model`` in ``geometry``; arguments ``(chords (3, 2), pass_prob, *sensor_args)``: the entry and exit
    distances (meters) of the ray's first wall cell, of its second, and ``(M, M)`` for no wall (``M`` the max
    distance; the entry geometry ignores the exits). ``simulate`` picks the first wall with probability
    ``1 - pi``, the second with ``pi (1 - pi)``, neither with ``pi^2``, then draws the reading from the sensor model
    at that wall; ``assess`` scores :func:`pass_mixture`.

    Raises:
        BayesmapError: on an unknown model or geometry name.
    """
    check_beam_model(beam_model)
    check_geometry(geometry)

    def logpdf(y, chords, pass_prob, *sensor_args):
        parts = [_wall_logpdf(beam_model, geometry, y, chords[k, 0], chords[k, 1], sensor_args) for k in range(3)]
        return pass_mixture(*parts, pass_prob)

    def sample(key, chords, pass_prob, *sensor_args):
        k_wall, k_reading = jax.random.split(key)
        wall = jax.random.categorical(k_wall, pass_log_weights(pass_prob))
        return _wall_sample(beam_model, geometry, k_reading, chords[wall, 0], chords[wall, 1], sensor_args)

    return genjax.exact_density(sample, logpdf, name=f"pass_{geometry}_{beam_model}_reading")
