"""Self-normalized importance sampling with the prior as proposal (the tutorial's first, failing method).

Each particle is a map drawn from the prior by ``full_model.importance`` with the readings constrained; its log
weight is ``log p(readings | walls)``. With a structured prior (:mod:`bayesmap.model.prior`) the observed
``"connections"`` are constrained too: the particles come from the independent prior and the weight adds the
Markov random field's ``-J`` per differing pair of neighbours, so the weighted particles target the same posterior.
Normalized weights ``w_i / sum_j w_j`` estimate posterior expectations;
resampling draws unweighted maps. On the tutorial scene the weights collapse onto one particle (effective sample
size about 1).

Source: self-normalized importance sampling and the effective sample size ``1 / sum_i w_i^2`` (Kong 1992; Owen,
*Monte Carlo theory, methods and examples*, ch. 9).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from genjax import ChoiceMapBuilder as C

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import check_readings
from bayesmap.model.generative import ModelParams, full_model, model_args
from bayesmap.model.prior import observed_connections


class ImportanceResult(NamedTuple):
    """Weighted particles.

    Attributes:
        walls: ``(N, nx, ny)`` bool maps drawn from the prior.
        log_weights: ``(N,)`` normalized log weights (``logsumexp`` = 0).
        log_marginal: estimate of ``log p(readings)`` (log of the mean unnormalized weight).
        ess: effective sample size ``1 / sum w_i^2``, between 1 and N.
    """

    walls: jax.Array
    log_weights: jax.Array
    log_marginal: jax.Array
    ess: jax.Array


def effective_sample_size(log_weights) -> jax.Array:
    """``1 / sum_i w_i^2`` of the normalized weights ``exp(log_weights - logsumexp(log_weights))``; ``(N,)`` ->
    scalar."""
    lw = log_weights - jax.scipy.special.logsumexp(log_weights)
    return 1.0 / jnp.sum(jnp.exp(2.0 * lw))


@partial(jax.jit, static_argnames=("num_batches", "batch_size"))
def _weighted_particles(key, readings, args, num_batches: int, batch_size: int):
    constraints = C["readings"].set(readings)
    if args[1].structured:
        constraints = constraints | C["connections"].set(observed_connections(args[1].grid.shape))

    def one(k):
        trace, log_w = full_model.importance(k, constraints, args)
        return trace.get_choices()["walls"] > 0, log_w

    keys = jax.random.split(key, num_batches * batch_size).reshape(num_batches, batch_size)
    walls, log_w = jax.lax.map(jax.vmap(one), keys)
    return walls.reshape((-1,) + walls.shape[2:]), log_w.reshape(-1)


def importance_sampling(key, readings, pos, params: ModelParams, num_particles: int, beam_angles=None,
                        batch_size: int = 1000) -> ImportanceResult:
    """Self-normalized importance sampling with ``num_particles`` prior samples.

    Args:
        key: PRNG key.
        readings: ``(K,)`` observed ranges, meters.
        pos: ``(2,)`` sensor position, world meters.
        params: model parameters.
        num_particles: number of particles N (>= 1); memory is about ``N * nx * ny`` bytes.
        beam_angles: ``(K,)`` radians; default the tutorial's angles.
        batch_size: particles evaluated at once (bounds peak memory).

    Raises:
        BayesmapError: on a bad particle count, bad readings or a sensor position outside the grid.
    """
    if int(num_particles) != num_particles or num_particles < 1:
        raise BayesmapError(f"number of particles must be an integer >= 1, got {num_particles!r}")
    args = model_args(pos, params, beam_angles)
    params.grid.check_inside(np.asarray(args[0]))
    readings = jnp.asarray(check_readings(readings, int(args[2].shape[0])), dtype=args[0].dtype)
    batch = int(min(batch_size, num_particles))
    num_batches = -(-int(num_particles) // batch)
    walls, log_w = _weighted_particles(key, readings, args, num_batches, batch)
    walls, log_w = walls[:num_particles], log_w[:num_particles]
    total = jax.scipy.special.logsumexp(log_w)
    return ImportanceResult(
        walls=walls,
        log_weights=log_w - total,
        log_marginal=total - jnp.log(num_particles),
        ess=effective_sample_size(log_w),
    )


def resample(key, log_weights, num_samples: int) -> jax.Array:
    """Indices ``(num_samples,)`` drawn independently from the categorical distribution of the weights."""
    return jax.random.categorical(key, log_weights, shape=(int(num_samples),))
