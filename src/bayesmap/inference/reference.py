"""The tutorial's Gibbs samplers, built directly on the GenJAX model (``assess`` and ``edit``).

These are the reference algorithms: slow (each cell update runs the whole model once per candidate value) but
obviously right. The fast samplers in :mod:`bayesmap.inference.fast` are tested against them.

* :func:`reference_gibbs` with ``block_size=1``: single-site Gibbs; each cell's two values are enumerated and
  scored with ``full_model.assess`` (raster or sensor-outward order).
* :func:`reference_gibbs` with ``block_size=k``: k x k block Gibbs; all ``2**(k*k)`` configurations of a block
  are scored with ``assess`` and one is drawn from their normalized weights.
* :func:`reference_incremental_gibbs`: the tutorial's incremental-trace variant: propose flipping a cell with
  ``trace.edit`` and keep the flip with probability ``sigmoid(incremental weight)``, which is exactly the Gibbs
  conditional of the flipped value.

With a structured prior (``params.coupling > 0``, :mod:`bayesmap.model.prior`) the scored choice maps hold the
observed ``"connections"``, so ``assess`` (and the incremental weight of ``edit``) includes the Markov random field's
neighbour terms: the reference samplers need no change of their own.

Source: Gibbs sampling by enumeration of full conditionals (Geman & Geman 1984; e.g. Bishop, *Pattern
Recognition and Machine Learning*, sec. 11.3).
"""

from __future__ import annotations

from typing import NamedTuple

import genjax
import jax
import jax.numpy as jnp
import numpy as np
from genjax import ChoiceMapBuilder as C

from bayesmap.geometry.raytable import check_readings
from bayesmap.inference.base import GibbsInfo, GibbsState, SamplingAlgorithm
from bayesmap.inference.schedules import block_configurations, make_blocks
from bayesmap.model.generative import ModelParams, choices, full_model, model_args


def _prepare(readings, pos, params: ModelParams, beam_angles):
    args = model_args(pos, params, beam_angles)
    params.grid.check_inside(np.asarray(args[0]))
    readings = jnp.asarray(check_readings(readings, int(args[2].shape[0])))
    return readings, args


def block_log_weights(walls, block_cells, readings, args):
    """``log p(walls with the block set to each configuration, readings)`` by ``full_model.assess``.

    Args:
        walls: ``(nx, ny)`` current map.
        block_cells: ``(B,)`` flat cell indices of the block.
        readings: ``(K,)`` meters.
        args: the model's arguments (:func:`bayesmap.model.generative.model_args`).

    Returns:
        ``(2**B,)`` log joint of each configuration of :func:`block_configurations` (B is static).
    """
    shape = walls.shape
    configs = jnp.asarray(block_configurations(block_cells.shape[0]), dtype=walls.dtype)

    def score(config):
        candidate = walls.reshape(-1).at[block_cells].set(config).reshape(shape)
        return full_model.assess(choices(candidate, readings, args[1]), args)[0]

    return jax.vmap(score)(configs)


def reference_gibbs(readings, pos, params: ModelParams, beam_angles=None, order: str = "raster",
                    block_size: int = 1) -> SamplingAlgorithm:
    """The tutorial's Gibbs sweep by enumeration with ``assess``.

    Args:
        readings: ``(K,)`` observed ranges, meters.
        pos: ``(2,)`` sensor position, world meters.
        params: model parameters (its grid sets the map's shape).
        beam_angles: ``(K,)`` radians; default the tutorial's ``angles(params.num_angles)``.
        order: ``"raster"`` or ``"outward"`` (see :mod:`bayesmap.inference.schedules`).
        block_size: 1 for single-site Gibbs, k for k x k blocks anchored at every cell.

    Returns:
        A :class:`SamplingAlgorithm` over :class:`GibbsState`; one ``step`` is one sweep and returns ``(state,
        GibbsInfo())`` (no conditional probabilities recorded).

    Raises:
        BayesmapError: on readings of the wrong length or non-finite/negative values, a sensor position outside
            the grid, an unknown order or a bad block size.
    """
    readings, args = _prepare(readings, pos, params, beam_angles)
    blocks = jnp.asarray(make_blocks(params.grid, block_size, order, args[0]))
    configs = jnp.asarray(block_configurations(blocks.shape[1]))

    def init(walls):
        return GibbsState(walls=jnp.asarray(walls, dtype=jnp.float32))

    def step(key, state: GibbsState) -> tuple[GibbsState, GibbsInfo]:
        keys = jax.random.split(key, blocks.shape[0])

        def update(b, walls):
            cells = blocks[b]
            log_w = block_log_weights(walls, cells, readings, args)
            choice = jax.random.categorical(keys[b], log_w)
            return walls.reshape(-1).at[cells].set(configs[choice]).reshape(walls.shape)

        return GibbsState(walls=jax.lax.fori_loop(0, blocks.shape[0], update, state.walls)), GibbsInfo()

    return SamplingAlgorithm(init=init, step=step)


class TraceState(NamedTuple):
    """The incremental sampler's state: a trace of ``full_model`` with the readings constrained."""

    trace: genjax.Trace

    @property
    def walls(self):
        """``(nx, ny)`` float32 current map."""
        return self.trace.get_choices()["walls"]


def reference_incremental_gibbs(readings, pos, params: ModelParams, beam_angles=None,
                                order: str = "raster") -> SamplingAlgorithm:
    """The tutorial's single-site Gibbs with incremental trace updates (``trace.edit``).

    For each cell, the edit request flips it; the returned incremental weight ``w = log p(flipped) - log p(current)``
    gives the flip probability ``sigmoid(w) = p(flipped) / (p(flipped) + p(current))``, the Gibbs conditional.

    Arguments and errors as :func:`reference_gibbs` (no blocks). The state is a :class:`TraceState`; ``step``
    returns ``(state, GibbsInfo())``.
    """
    readings, args = _prepare(readings, pos, params, beam_angles)
    cells = jnp.asarray(make_blocks(params.grid, 1, order, args[0])[:, 0])
    ny = params.grid.shape[1]

    def init(walls):
        constraints = choices(jnp.asarray(walls, dtype=jnp.float32), readings, args[1])
        trace, _ = full_model.importance(jax.random.key(0), constraints, args)
        return TraceState(trace=trace)

    def step(key, state: TraceState) -> tuple[TraceState, GibbsInfo]:
        keys = jax.random.split(key, cells.shape[0])

        def update(n, trace):
            i, j = cells[n] // ny, cells[n] % ny
            walls = trace.get_choices()["walls"]
            flipped = walls.at[i, j].set(1.0 - walls[i, j])
            request = genjax.StaticRequest({"walls": genjax.Update(C.v(flipped))})
            edit_key, accept_key = jax.random.split(keys[n])
            new_trace, weight, _, _ = trace.edit(edit_key, request, None)
            accept = jax.random.bernoulli(accept_key, jax.nn.sigmoid(weight))
            return jax.lax.cond(accept, lambda: new_trace, lambda: trace)

        return TraceState(trace=jax.lax.fori_loop(0, cells.shape[0], update, state.trace)), GibbsInfo()

    return SamplingAlgorithm(init=init, step=step)
