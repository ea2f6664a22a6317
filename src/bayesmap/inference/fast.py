"""Fast exact Gibbs: block conditionals from the ray-cell table instead of re-running the model.

For a block of cells (one cell for single-site Gibbs), only the rays through the block depend on its values.
For such a ray, let ``m_out`` be the distance of its first wall *outside* the block (or the max distance). With the
block in configuration ``c``, the ray's expected distance is ``min(m_out, min over block walls of t)``, where ``t``
is the table's stopping distance of each block cell on that ray. The block's conditional log-weights are then

    log w(c) = sum over block cells of log prior(c_cell) + sum over rays through the block of log p(y_r | d_r(c))

up to a constant that does not depend on ``c`` (derived in ``docs/fast-conditional.md``; for one cell it is
the prior log-odds plus, per ray, ``log p(y | d1) - log p(y | d0)``). ``log p(y | d)`` is the model's sensor model
(:mod:`bayesmap.model.sensor`, ``params.beam_model``): the tutorial's ``log N(y; d, sensor_noise)`` or the robust beam
mixture; a ray with no wall within the max distance has ``d = table.max_distance``, exactly as in the model.
Rays may come from several scans (poses): the table holds each ray's own origin.

A sweep runs the levels of a schedule (:mod:`bayesmap.inference.schedules`): all blocks of a level share no cell
and no ray, so their conditionals are computed and sampled at once, each exactly as if sampled alone. With
``schedule="sequential"`` the levels come from :func:`dependency_levels`, which makes one sweep the *same
transition kernel* as the reference sweep in the same order; ``"chromatic"`` runs colour classes instead. Levels
are split (:func:`split_levels`) into fixed-size steps of a ``lax.scan`` of at most ``level_capacity`` (block,
ray) entries; a block crossed by more rays is drawn over several steps
(:class:`~bayesmap.inference.fastkernel.Levels`).

The structured prior (:mod:`bayesmap.model.prior`, ``params.coupling > 0``) adds to a block's log-weights ``J`` times
the agreements of its configuration with the block's 4-neighbours outside it, and ``J`` times the agreements of the
pairs inside the block (enumerated with the configuration: :func:`bayesmap.model.prior.internal_agreements`); for one
cell, ``J (n_wall - n_free)``. The blocks of a level must then not be neighbours either (two neighbouring cells drawn
at once would each be drawn given the other's old value): the schedules count a shared edge between two blocks'
cells as a conflict (:func:`dependency_levels` keeps their order). The neighbours' current values are read from the
sweep's buffer, where every draw is written (``Levels.nbr_src``), and from the map at the start of the sweep
(a copy of it sits after the ray words). With ``J = 0`` nothing changes.

This module builds the sampler for one problem and schedule: :class:`FastGibbs` packs the schedule's levels, on the
host, into the fixed-size device arrays of the sweep's steps; the sweep itself, compiled once for every problem of
the same shapes, is :class:`bayesmap.inference.fastkernel.FastKernel`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import RayTable
from bayesmap.inference.base import KernelSampler, SamplingAlgorithm
from bayesmap.inference.fastkernel import WORD_BITS, FastKernel, Levels, block_log_weights
from bayesmap.inference.schedules import (
    block_configurations,
    chromatic_levels,
    dependency_levels,
    make_blocks,
    split_levels,
)
from bayesmap.model.generative import ModelParams, prior_log_odds
from bayesmap.model.likelihood import likelihood_inputs, log_likelihood_table, pair_log_likelihoods
from bayesmap.model.prior import internal_agreements, neighbour_indices

SCHEDULES = ("sequential", "chromatic")  # the ``schedule`` choices of :class:`FastGibbs`


class _StepLayout(NamedTuple):
    """Where the ``M`` (block, ray) entries of a sweep's levels go (built by ``FastGibbs._step_layout``), entries in
    sweep order (level, block slot, ray).

    Attributes:
        ray, pos, stop, slot: ``(M,)`` the entry's ray, ``(M, B)`` its block's cells' positions on the ray (-1: off
            the ray) and stopping distances (meters, ``inf`` off the ray), ``(M,)`` its block's slot in the level.
        step, index: ``(M,)`` the step that reads the entry and its index among the step's entries.
        num_steps, entries_per_step: the sweep's ``NS`` steps of ``E`` entries.
        step_level: ``(NS,)`` the level of each step.
        commit_step: ``(NL,)`` the last step of each level (where its blocks are drawn).
        commit, carry_in: ``(NS,)`` bool, the step draws its blocks / continues the previous step's block.
        base, stride: the sweep buffer's first step word (after the state's words and the zero word) and the words
            per step (``W x E`` entry words, then ``A`` draws).
        written: ``(M, W)`` buffer index of each word the entry writes.
        config_at: ``(M,)`` buffer index of the draw of the entry's block.
        unfinished: ``(M,)`` bool, the entry is written before its block is drawn (a chunked block).
        rows, cols: the (level, slot) of every real block of the levels, in sweep order.
    """

    ray: np.ndarray
    pos: np.ndarray
    stop: np.ndarray
    slot: np.ndarray
    step: np.ndarray
    index: np.ndarray
    num_steps: int
    entries_per_step: int
    step_level: np.ndarray
    commit_step: np.ndarray
    commit: np.ndarray
    carry_in: np.ndarray
    base: int
    stride: int
    written: np.ndarray
    config_at: np.ndarray
    unfinished: np.ndarray
    rows: np.ndarray
    cols: np.ndarray


class FastGibbs(KernelSampler):
    """The fast Gibbs sampler for one problem (table, readings, parameters) and one schedule.

    Args:
        table: the ray-cell table of the scene (its rays are in the order of ``readings``).
        readings: ``(R,)`` observed ranges, meters (for several scans, ``(S, K)`` readings flattened scan by scan,
            in the order of the table's rays); max-range readings equal to the max distance.
        params: model parameters: ``prior_wall_prob``, the structured prior's ``coupling`` and the sensor model
            (``beam_model``, ``sensor_noise`` and, for ``"beam"``, the mixture's weights and ``lambda_short``, whose
            max range is the table's max distance);
            geometry comes from the table. The dynamic parameters are kernel arrays (changing them reuses the
            compiled sweep); ``beam_model`` is static.
        order: ``"raster"`` or ``"outward"`` (block anchors' order).
        block_size: 1 for single-site, k for k x k blocks.
        schedule: ``"sequential"`` (same kernel as the reference sweep) or ``"chromatic"``.
        pos: ``(2,)`` sensor position, meters (for the outward order; default: the first ray's origin).
        level_capacity: most (block, ray) entries per step; larger levels are split (:func:`split_levels`), and a
            block crossed by more rays is drawn over several steps. Default: no splitting unless padding every
            level to the largest would cost more than 4 times the real work; then 32 (or the mean entries per
            level if larger).
        likelihood_power: ``eta`` in (0, 1]: sample ``p(walls) p(readings | walls) ** eta`` (every log-likelihood
            of a conditional times ``eta``: :func:`bayesmap.model.likelihood.tempered`); 1, the posterior.

    Attributes:
        blocks: ``(NB, B)`` int flat cell indices, sweep order.
        levels: ``(num_levels, width)`` int32 block indices after splitting (padding ``NB``).
        kernel: the :class:`FastKernel` (arrays and code of the sweep).
        algorithm: the :class:`SamplingAlgorithm`: ``init`` and ``step`` are ``jax.tree_util.Partial`` of the
            kernel, so a compiled chain takes the kernel's arrays as arguments and is reused by any problem of
            the same geometry and schedule.

    Raises:
        BayesmapError: on readings that do not match the table's rays, an unknown schedule or order, a bad block
            size, a likelihood power outside (0, 1], or (beam model) a table whose max distance is not
            ``params.max_range`` (the sensor's max range; :func:`~bayesmap.model.likelihood.check_max_range`).

    Memory: the table's pairs, one bit per pair for the state, and per (block, ray) entry ``B`` positions and
    ``2**B`` distances (``B`` cells per block); a sweep's buffer holds one copy of each entry's ray words. The beam
    model adds its looked-up log-likelihoods: one float per pair and ``2**B + 1`` per entry (:class:`FastKernel`).
    """

    def __init__(self, table: RayTable, readings, params: ModelParams, order: str = "raster", block_size: int = 1,
                 schedule: str = "sequential", pos=None, level_capacity: int | None = None,
                 likelihood_power: float = 1.0):
        if schedule not in SCHEDULES:
            raise BayesmapError(f"unknown schedule {schedule!r}; choose one of {', '.join(SCHEDULES)}")
        inputs = likelihood_inputs(table, readings, params, likelihood_power)
        self.table = table
        self.grid = table.grid
        self._y, self.beam_model, self._sensor_args = inputs.readings, inputs.beam_model, inputs.sensor_args
        self.geometry = inputs.geometry
        # log p(y | d) looked up from tables (the beam mixture, and any model in the chord geometry) or evaluated
        self._lookup = self.beam_model != "normal" or self.geometry == "chord"
        self._dtype = inputs.dtype
        if pos is None:
            pos = table.origins[0] if table.num_rays else np.zeros(2)
        self.blocks = make_blocks(self.grid, block_size, order, pos)
        self._block_shape = (min(int(block_size), self.grid.shape[0]), min(int(block_size), self.grid.shape[1]))
        self._structured = params.structured
        self._coupling = float(params.coupling)
        neighbours = neighbour_indices(self.grid.shape) if self._structured else None
        make_levels = dependency_levels if schedule == "sequential" else chromatic_levels
        base_levels = make_levels(self.blocks, table, neighbours)
        self._num_cells = table.num_cells
        # the structured prior: a copy of the map at the sweep's start after the ray words and the zero word
        self._walls_words = table.num_cells if self._structured else 0
        # per-ray word layout of the state's bit strings, then one zero word
        num_words = (-(-table.lengths // WORD_BITS)).astype(np.int64)
        self._num_words = num_words
        self._max_words = max(int(num_words.max(initial=0)), 1)
        self._word_offsets = np.concatenate([[0], np.cumsum(num_words)[:-1]]).astype(np.int64)
        self._zero_word = int(num_words.sum())
        self._config_bits = block_configurations(self.blocks.shape[1]) > 0  # (C, B) numpy
        self._prior_log_odds = prior_log_odds(params.prior_wall_prob)

        self._entries = self._block_entries()
        entry_count = np.bincount(self._entries[0], minlength=len(self.blocks))
        if level_capacity is None:
            # Measured on the tutorial scene (2-core CPU): a step costs about 0.5 us plus its work. Padding every
            # level to the largest (the sensor's cell: all 100 rays) costs the raster sweep 2x; steps of 32 entries,
            # with the few large blocks drawn over several steps, halve it. Schedules with few, wide levels (sensor-
            # outward, chromatic) are faster unsplit.
            per_level = [int(entry_count[row[row < len(self.blocks)]].sum()) for row in base_levels]
            largest = max(per_level, default=1)
            mean = len(self._entries[0]) / max(len(base_levels), 1)
            split = largest * len(base_levels) > 4 * max(len(self._entries[0]), 1)
            level_capacity = max(32, 8 * math.ceil(mean / 8)) if split else max(largest, 1)
        self.level_capacity = max(int(level_capacity), 1)
        self.levels = split_levels(base_levels, entry_count, self.level_capacity)
        packed = self._pack(self.levels, self.level_capacity, chained=True)
        self._steps, final_words, final_walls, final_fix = packed
        self.kernel = FastKernel(
            _steps=self._steps, _final_words=final_words, _final_walls=final_walls, _final_fix=final_fix,
            _pair_dists=jnp.asarray(np.append(table.pair_dists, table.max_distance), dtype=self._dtype),
            _pair_cells=jnp.asarray(table.pair_cells),
            _pair_words=jnp.asarray(self._word_offsets[table.pair_rays] + table.pair_positions // WORD_BITS,
                                    dtype=jnp.int32),
            _pair_shift=jnp.asarray(table.pair_positions % WORD_BITS, dtype=jnp.uint32),
            _bits=jnp.asarray(self._config_bits),
            _sensor=self._sensor_args, _pair_ll=self._pair_log_likelihoods(),
            _power=jnp.asarray(inputs.likelihood_power, dtype=self._dtype),
            _coupling=jnp.asarray(self._coupling, dtype=self._dtype) if self._structured else None,
            _walls_words=self._walls_words,
            _beam_model=params.beam_model, _geometry=self.geometry, _max_words=self._max_words,
            _zero_word=self._zero_word,
            _chunked=not bool(np.all(np.asarray(self._steps.commit))), _dtype=jnp.dtype(self._dtype).name)

    # -- static preparation (numpy) ------------------------------------------------------------------------------

    def _pair_log_likelihoods(self):
        """``(P + 1,)`` ``log p(y_r | t)`` for each (ray r, cell) pair's stopping distance ``t`` (in the chord
        geometry its chord, up to the pair's exit distance), then a 0 for the "no wall" index, whose value comes from
        ``Levels.max_ll``; None for ``"normal"`` in the entry geometry (evaluated in the step)."""
        if not self._lookup:
            return None
        return pair_log_likelihoods(self.table, self._y, self.beam_model, self._sensor_args, self.geometry)

    def _block_entries(self):
        """All (block, ray) entries: ``(block, ray, pos (M, B), stop (M, B))`` sorted by block then ray."""
        table, blocks = self.table, self.blocks
        nb, size = blocks.shape
        num_rays = max(table.num_rays, 1)
        by_cell = table.pairs_by_cell()
        cell_start = np.searchsorted(table.pair_cells[by_cell], np.arange(table.num_cells + 1))
        member_cell = blocks.reshape(-1)
        counts = cell_start[member_cell + 1] - cell_start[member_cell]
        member = np.repeat(np.arange(nb * size), counts)
        within = np.arange(len(member)) - np.repeat(np.cumsum(counts) - counts, counts)
        pair = by_cell[cell_start[member_cell[member]] + within]
        block, j = member // size, member % size
        key = block.astype(np.int64) * num_rays + table.pair_rays[pair]
        unique, entry = np.unique(key, return_inverse=True)
        pos = np.full((len(unique), size), -1, dtype=np.int64)
        stop = np.full((len(unique), size), np.inf, dtype=np.float64)
        pos[entry, j] = table.pair_positions[pair]
        stop[entry, j] = table.pair_dists[pair]
        return (unique // num_rays).astype(np.int64), (unique % num_rays).astype(np.int64), pos, stop

    def _pack(self, levels: np.ndarray, entries_per_step: int, chained: bool):
        """Device arrays for the levels ``levels`` ``(NL, A)`` (block indices, padding ``NB``), ``entries_per_step``
        (block, ray) entries per step; a level with more entries (one block, see :func:`split_levels`) takes several
        steps.

        With ``chained``, an entry reads its ray's words from the buffer slot where the ray's previous entry in the
        sweep wrote them (or from the state if it is the ray's first entry), and the final state is gathered from
        the last writers; otherwise every entry reads the state (independent levels, for
        :meth:`block_log_weights`; no level may then exceed ``entries_per_step``).

        Returns:
            ``(Levels, final_words, final_walls, final_fix)``; the last three are None unless ``chained``.
        """
        layout = self._step_layout(levels, entries_per_step)
        src_words, fix_src, fix_pos = self._entry_sources(layout, chained)
        packed = self._levels_arrays(layout, levels, src_words, fix_src, fix_pos)
        if self._structured:
            packed = packed._replace(**self._neighbour_sources(layout, levels, chained))
        if not chained:
            return packed, None, None, None
        return (packed,) + self._final_gathers(layout, levels)

    def _step_layout(self, levels: np.ndarray, entries_per_step: int) -> _StepLayout:
        """The entries of ``levels`` in sweep order and where each lands: its step, its index in the step, and its
        words' and its block's draw's places in the sweep's buffer (see :class:`_StepLayout`)."""
        nb = len(self.blocks)
        num_levels, width = levels.shape
        num_w = self._max_words
        level_of = np.full(nb, -1, dtype=np.int64)
        slot_of = np.zeros(nb, dtype=np.int64)
        rows, cols = np.nonzero(levels < nb)
        level_of[levels[rows, cols]] = rows
        slot_of[levels[rows, cols]] = cols
        block, ray, pos, stop = self._entries
        keep = level_of[block] >= 0
        block, ray, pos, stop = block[keep], ray[keep], pos[keep], stop[keep]
        lv, sl = level_of[block], slot_of[block]
        order = np.lexsort((ray, sl, lv))
        ray, pos, stop, lv, sl = (a[order] for a in (ray, pos, stop, lv, sl))
        # steps: a level takes ceil(entries / entries_per_step) consecutive steps (more than one only for one block)
        per_level = np.bincount(lv, minlength=num_levels)
        level_steps = np.maximum(1, -(-per_level // entries_per_step))
        first_step = np.concatenate([[0], np.cumsum(level_steps)[:-1]])
        num_steps = int(level_steps.sum())
        rank = np.arange(len(lv)) - np.repeat(np.cumsum(per_level) - per_level, per_level)
        step, index = first_step[lv] + rank // entries_per_step, rank % entries_per_step
        commit_step = first_step + level_steps - 1  # per level
        commit = np.zeros(num_steps, dtype=bool)
        commit[commit_step] = True
        carry_in = np.ones(num_steps, dtype=bool)
        carry_in[first_step] = False
        # the buffer: state words, one zero word, then per step its entries' words (W x E) and its draws (A)
        base, stride = self._zero_word + 1 + self._walls_words, num_w * entries_per_step + width
        written = (base + step * stride)[:, None] + np.arange(num_w)[None, :] * entries_per_step + index[:, None]
        return _StepLayout(
            ray=ray, pos=pos, stop=stop, slot=sl, step=step, index=index, num_steps=num_steps,
            entries_per_step=entries_per_step, step_level=np.repeat(np.arange(num_levels), level_steps),
            commit_step=commit_step, commit=commit, carry_in=carry_in, base=base, stride=stride, written=written,
            config_at=base + commit_step[lv] * stride + num_w * entries_per_step + sl,
            unfinished=~commit[step], rows=rows, cols=cols)

    def _entry_sources(self, layout: _StepLayout, chained: bool):
        """Where each entry reads its ray's words: ``src_words`` ``(M, W)`` buffer indices (the state's words, or
        with ``chained`` those the ray's previous entry wrote; the zero word past the ray's words), and for an entry
        whose previous entry was written before its block was drawn, the buffer index of that draw ``fix_src``
        ``(M,)`` and the block's positions on the ray ``fix_pos`` ``(M, B)`` (else the zero word and -1)."""
        ray, num_w = layout.ray, self._max_words
        w = np.arange(num_w)
        src_words = self._word_offsets[ray][:, None] + w[None, :]
        fix_src = np.full(len(ray), self._zero_word, dtype=np.int64)
        fix_pos = np.full((len(ray), self.blocks.shape[1]), -1, dtype=np.int64)
        if chained:  # the previous entry of the same ray in sweep order
            by_ray = np.lexsort((layout.step, ray))
            prev = np.full(len(ray), -1, dtype=np.int64)
            same = ray[by_ray][1:] == ray[by_ray][:-1]
            prev[by_ray[1:][same]] = by_ray[:-1][same]
            has = prev >= 0
            src_words = np.where(has[:, None], layout.written[np.maximum(prev, 0)], src_words)
            fix = has & layout.unfinished[np.maximum(prev, 0)]
            fix_src[fix] = layout.config_at[prev[fix]]
            fix_pos[fix] = layout.pos[prev[fix]]
        valid_w = w[None, :] < self._num_words[ray][:, None]
        return np.where(valid_w, src_words, self._zero_word), fix_src, fix_pos

    def _configuration_log_prior(self, levels: np.ndarray, layout: _StepLayout) -> np.ndarray:
        """``(NS, A, C)`` float64 prior log-weight of each configuration of each step's blocks, relative to the
        all-free configuration: the number of walls times :func:`~bayesmap.model.generative.prior_log_odds`;
        ``-inf`` for configurations that set cells a padding block does not have, and 0 in the steps of a chunked
        block before its last (its prior counts once)."""
        size = self.blocks.shape[1]
        exists = np.vstack([self.blocks, np.full((1, size), -1)])[levels] >= 0  # (NL, A, B)
        bits_c = self._config_bits[None, None]  # (1, 1, C, B)
        prior = np.where(exists[:, :, None, :] & bits_c, self._prior_log_odds, 0.0).sum(-1)
        if self._structured:  # the pairs of neighbours inside the block, enumerated with the configuration
            prior = prior + self._coupling * internal_agreements(self._block_shape, self._config_bits)
        prior = np.where(np.any(bits_c & ~exists[:, :, None, :], axis=-1), -np.inf, prior)[layout.step_level]
        return np.where(layout.commit[:, None, None] | np.isinf(prior), prior, 0.0)

    def _neighbour_sources(self, layout: _StepLayout, levels: np.ndarray, chained: bool) -> dict:
        """The structured prior's :attr:`Levels.nbr_src`, ``nbr_bit`` and ``nbr_on`` of ``layout``: for each block
        cell's 4-neighbour outside the block, the buffer index and configuration cell of its latest value before
        the block's commit step (its last draw earlier in the sweep with ``chained``, else the sweep's copy of the
        starting map, read as configuration index 0 or 1 at cell ``B - 1``)."""
        size, nb = self.blocks.shape[1], len(self.blocks)
        num_levels, width = levels.shape
        first = self._zero_word + 1
        latest_src = first + np.arange(self._num_cells, dtype=np.int64)
        latest_bit = np.full(self._num_cells, size - 1, dtype=np.int64)
        neighbours = neighbour_indices(self.grid.shape)
        src = np.full((layout.num_steps, width, size, 4), self._zero_word, dtype=np.int64)
        bit = np.zeros((layout.num_steps, width, size, 4), dtype=np.int64)
        on = np.zeros((layout.num_steps, width, size, 4), dtype=bool)
        draws = layout.base + self._max_words * layout.entries_per_step
        for lv in range(num_levels):
            step = layout.commit_step[lv]
            slots = np.flatnonzero(levels[lv] < nb)
            cells = self.blocks[levels[lv, slots]]  # (n, B)
            near = neighbours[cells]  # (n, B, 4)
            valid = (near >= 0) & ~np.any(near[..., None] == cells[:, None, None, :], axis=-1)
            src[step, slots] = np.where(valid, latest_src[near], self._zero_word)
            bit[step, slots] = np.where(valid, latest_bit[near], 0)
            on[step, slots] = valid
            if chained:  # the level's draws: no block of the level neighbours another, so after the level is right
                latest_src[cells] = (draws + step * layout.stride + slots)[:, None]
                latest_bit[cells] = np.arange(size)[None, :]
        i32 = jnp.int32
        return dict(nbr_src=jnp.asarray(src, i32), nbr_bit=jnp.asarray(bit, i32), nbr_on=jnp.asarray(on))

    def _levels_arrays(self, layout: _StepLayout, levels: np.ndarray, src_words, fix_src, fix_pos) -> Levels:
        """The :class:`Levels` of ``layout``: each entry's data at its (step, index), padding elsewhere; with the
        beam model, its looked-up log-likelihoods (:func:`~bayesmap.model.likelihood.log_likelihood_table`)."""
        ray, pos, size = layout.ray, layout.pos, self.blocks.shape[1]
        num_w, width = self._max_words, levels.shape[1]
        bits = np.zeros((len(ray), num_w), dtype=np.uint32)
        for j in range(size):
            on = pos[:, j] >= 0
            np.bitwise_or.at(bits, (np.nonzero(on)[0], pos[on, j] // WORD_BITS),
                             np.left_shift(np.uint32(1), (pos[on, j] % WORD_BITS).astype(np.uint32)))
        stop_c = np.min(np.where(self._config_bits[None], layout.stop[:, None, :], np.inf), axis=-1)  # (M, C)
        at = (layout.step, layout.index)
        dt, i32 = self._dtype, jnp.int32

        def fill(shape, value, data, dtype):
            out = np.full((layout.num_steps, layout.entries_per_step) + shape, value,
                          dtype=np.float64 if dtype == dt else np.int64)
            out[at] = data
            out = np.moveaxis(out, 1, -1) if out.ndim == 3 else out  # entries last: the CPU vectorizes along it
            return jnp.asarray(out, dtype=dtype)

        packed = Levels(
            src=fill((num_w,), self._zero_word, src_words, i32),
            block_bits=fill((num_w,), 0, bits, jnp.uint32),
            pair0=fill((), self.table.num_pairs, self.table.offsets[ray], i32),
            y=fill((), 0.0, self._y[ray], dt),
            slot=fill((), width, layout.slot, i32),
            pos=fill((size,), -1, pos, i32),
            stop=fill((len(self._config_bits),), np.inf, stop_c, dt),
            log_prior=jnp.asarray(self._configuration_log_prior(levels, layout), dtype=dt),
            carry_in=jnp.asarray(layout.carry_in),
            commit=jnp.asarray(layout.commit),
            fix_src=fill((), self._zero_word, fix_src, i32),
            fix_pos=fill((size,), -1, fix_pos, i32),
        )
        if not self._lookup:
            return packed
        no_wall = jnp.asarray(self.table.max_distance, dtype=dt)
        stop_exit, no_wall_exit = None, None
        if self.geometry == "chord":  # the exit of each configuration's first wall: its block cell first on the ray
            on_ray = self._config_bits[None] & (pos[:, None, :] >= 0)  # (M, C, B)
            first = np.argmin(np.where(on_ray, pos[:, None, :], np.iinfo(np.int64).max), axis=-1)  # (M, C)
            pair = self.table.offsets[ray][:, None] + np.take_along_axis(pos, first, axis=1)
            exits = self.table.pair_exits[np.minimum(pair, self.table.num_pairs - 1)]
            exit_c = np.where(np.any(on_ray, axis=-1), exits, np.inf)
            stop_exit, no_wall_exit = fill((len(self._config_bits),), np.inf, exit_c, dt), no_wall
            none = np.iinfo(np.int32).max
            first_pos = np.where(np.any(on_ray, axis=-1), np.take_along_axis(pos, first, axis=1), none)
            packed = packed._replace(stop_pos=fill((len(self._config_bits),), none, first_pos, i32))
        return packed._replace(
            stop_ll=log_likelihood_table(self.beam_model, self._sensor_args, packed.y[:, None, :], packed.stop,
                                         None if stop_exit is None else stop_exit),
            max_ll=log_likelihood_table(self.beam_model, self._sensor_args, packed.y, no_wall, no_wall_exit))

    def _final_gathers(self, layout: _StepLayout, levels: np.ndarray):
        """Where a sweep's final state is in its buffer: ``(final_words, final_walls, final_fix)``. Each ray word
        comes from the ray's last entry (or is unchanged), each cell from its block's last draw; rays last written
        by an unfinished chunk get their block's bits back at the end (``final_fix``, None if there are none)."""
        ray, i32 = layout.ray, jnp.int32
        size, num_rays = self.blocks.shape[1], self.table.num_rays
        last = np.full(num_rays, -1, dtype=np.int64)
        np.maximum.at(last, ray, np.arange(len(ray)))  # entries are sorted by step: the largest index is the last
        words_ray = np.repeat(np.arange(num_rays), self._num_words)
        words_w = np.arange(self._zero_word) - np.repeat(self._word_offsets, self._num_words)
        final_words = np.arange(self._zero_word + 1)
        last_w = last[words_ray]
        final_words[:-1] = np.where(last_w >= 0, layout.written[np.maximum(last_w, 0), words_w], final_words[:-1])
        final_fix = None
        late = (last >= 0) & layout.unfinished[np.maximum(last, 0)]
        if late.any():
            fsrc = np.full(num_rays, self._zero_word, dtype=np.int64)
            fpos = np.full((size, num_rays), -1, dtype=np.int64)
            fsrc[late] = layout.config_at[last[late]]
            fpos[:, late] = layout.pos[last[late]].T
            final_fix = (jnp.asarray(fsrc, dtype=i32), jnp.asarray(fpos, dtype=i32),
                         jnp.asarray(words_ray, dtype=i32), jnp.asarray(words_w, dtype=i32))
        rows, cols = layout.rows, layout.cols
        cells = self.blocks[levels[rows, cols]].reshape(-1)  # rows in sweep order
        draw_at = np.repeat(layout.base + layout.commit_step[rows] * layout.stride
                            + self._max_words * layout.entries_per_step + cols, size)
        latest = np.full(self._num_cells, -1, dtype=np.int64)
        np.maximum.at(latest, cells, np.arange(len(cells)))  # a cell is in one block per level: the last level wins
        final_walls = (jnp.asarray(draw_at[latest], dtype=i32), jnp.asarray(latest % size, dtype=i32))
        return jnp.asarray(final_words, dtype=i32), final_walls, final_fix

    # -- the kernel lives in FastKernel (a pytree: a new problem of the same shapes reuses the compiled sweep) ----

    @property
    def num_configurations(self) -> int:
        """``2**B``, the configurations of a block of ``B`` cells."""
        return self.kernel.num_configurations

    def ray_bits(self, walls) -> jax.Array:
        """See :meth:`bayesmap.inference.fastkernel.FastKernel.ray_bits`."""
        return self.kernel.ray_bits(walls)

    def block_log_weights(self, walls) -> jax.Array:
        """Conditional log-weights of every block given the rest of ``walls`` ``(nx, ny)``: ``(NB, 2**B)``, each
        row up to an additive constant, configurations of :func:`block_configurations`. Uses the sweep's kernel
        (each block as a level of its own)."""
        if not hasattr(self, "_single"):
            singles = np.arange(len(self.blocks), dtype=np.int32)[:, None]
            most = int(np.bincount(self._entries[0], minlength=len(self.blocks)).max(initial=1))
            self._single = self._pack(singles, max(most, 1), chained=False)[0]
        return block_log_weights(self.kernel, self._single, self.ray_bits(walls), jnp.asarray(walls))


def fast_gibbs(table: RayTable, readings, params: ModelParams, order: str = "raster", block_size: int = 1,
               schedule: str = "sequential", pos=None, likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """The fast exact Gibbs sampler as a :class:`SamplingAlgorithm`; see :class:`FastGibbs` for the arguments."""
    return FastGibbs(table, readings, params, order, block_size, schedule, pos,
                     likelihood_power=likelihood_power).algorithm
