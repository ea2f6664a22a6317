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

The state keeps, next to the map, the walls *along each ray* as a bit string (bit ``p`` of ray ``r`` is the wall
value of the ``p``-th cell on the ray, 32 cells per ``uint32`` word). The first wall outside a block is then the
lowest set bit of ``ray bits & ~block bits``: a handful of word operations per ray, whatever the ray's length.

A sweep runs the levels of a schedule (:mod:`bayesmap.inference.schedules`): all blocks of a level share no cell
and no ray, so their conditionals are computed and sampled at once, each exactly as if sampled alone. With
``schedule="sequential"`` the levels come from :func:`dependency_levels`, which makes one sweep the *same
transition kernel* as the reference sweep in the same order; ``"chromatic"`` runs colour classes instead. Levels
are split (:func:`split_levels`) into fixed-size steps of a ``lax.scan`` of at most ``level_capacity`` (block,
ray) entries; a block crossed by more rays is drawn over several steps (:class:`Levels`).

The structured prior (:mod:`bayesmap.model.prior`, ``params.coupling > 0``) adds to a block's log-weights ``J`` times
the agreements of its configuration with the block's 4-neighbours outside it, and ``J`` times the agreements of the
pairs inside the block (enumerated with the configuration: :func:`bayesmap.model.prior.internal_agreements`); for one
cell, ``J (n_wall - n_free)``. The blocks of a level must then not be neighbours either (two neighbouring cells drawn
at once would each be drawn given the other's old value): the schedules count a shared edge between two blocks'
cells as a conflict (:func:`dependency_levels` keeps their order). The neighbours' current values are read from the
sweep's buffer, where every draw is written (:attr:`Levels.nbr_src`), and from the map at the start of the sweep
(a copy of it sits after the ray words). With ``J = 0`` nothing changes.

Each block is drawn by inverse CDF from one uniform (for single cells: wall with probability
``1 / (1 + exp(-log odds))``), which on the CPU is much cheaper than a Gumbel per configuration.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import RayTable
from bayesmap.inference.base import GibbsInfo, KernelFields, KernelSampler, SamplingAlgorithm
from bayesmap.inference.schedules import (
    block_configurations,
    chromatic_levels,
    dependency_levels,
    make_blocks,
    split_levels,
)
from bayesmap.model.generative import ModelParams, prior_log_odds
from bayesmap.model.likelihood import likelihood_inputs, log_likelihood_table, pair_log_likelihoods, tempered
from bayesmap.model.prior import internal_agreements, neighbour_indices
from bayesmap.model.sensor import normal_logpdf, reading_logpdf

SCHEDULES = ("sequential", "chromatic")  # the ``schedule`` choices of :class:`FastGibbs`
WORD_BITS = 32  # cells per word of a ray's bit string (``uint32``)


def sample_categorical(log_weights, u):
    """Index ``(...,)`` int32 drawn from the unnormalized log-weights ``(..., C)`` by inverse CDF with uniforms
    ``u`` ``(...,)`` in ``[0, 1)``; ``-inf`` weights are never drawn (rows must have a finite maximum)."""
    num = log_weights.shape[-1]
    p = jnp.exp(log_weights - jnp.max(log_weights, axis=-1, keepdims=True))
    below = np.arange(num)[None, :] <= np.arange(num)[:, None]  # (C, C): j <= k
    cdf = jnp.sum(jnp.where(below, p[..., None, :], 0.0), axis=-1)  # a cumsum without reduce_window
    return jnp.sum(cdf < (u * cdf[..., -1])[..., None], axis=-1, dtype=jnp.int32)


class FastGibbsState(NamedTuple):
    """State of a fast Gibbs chain.

    Attributes:
        walls: ``(nx, ny)`` float32 map of 0.0 / 1.0.
        ray_bits: ``(num_words + 1,)`` uint32, the walls along every ray, one bit per (ray, cell) pair (ray ``r``'s
            ``ceil(length / 32)`` words in a row, cell ``p`` of the ray at bit ``p % 32`` of word ``p // 32``); the
            last word is always 0 (read for padding).
    """

    walls: jax.Array
    ray_bits: jax.Array


class Levels(NamedTuple):
    """A schedule as fixed-size device arrays, one row per step of the sweep: step ``s`` updates up to ``A``
    blocks from ``E`` (block, ray) entries, each ray's bit string read from ``W`` words of the sweep's buffer (see
    :meth:`FastGibbs.step`). The entry axis is the last (contiguous) one, so that the CPU vectorizes along it.

    A block crossed by more than ``E`` rays (the sensor's cell, say) takes several consecutive steps, one chunk
    of its rays each: the first steps only add up its log-weights (``carry_in``), the last one draws it
    (``commit``). Rays of the unfinished chunks are written without the block's bits; whoever reads them next adds
    those bits back from the block's drawn configuration (``fix_src``, ``fix_pos``).

    Attributes:
        src: ``(NL, W, E)`` int32 buffer index of each entry's ray words (a zero word for padding).
        block_bits: ``(NL, W, E)`` uint32 the bits of the block's cells on the ray.
        pair0: ``(NL, E)`` int32 index of the ray's first pair in the table (``P`` for padding).
        y: ``(NL, E)`` float the ray's reading (meters).
        slot: ``(NL, E)`` int32 which block of the level the entry belongs to (``A`` for padding).
        pos: ``(NL, B, E)`` int32 position of each block cell along the ray, ``-1`` if the ray misses it.
        stop: ``(NL, C, E)`` float the ray's distance if only the block's walls in configuration ``c`` existed
            (``inf`` if none of them is on the ray), meters.
        log_prior: ``(NL, A, C)`` float prior log-probability of each configuration relative to the all-free one
            (its number of walls times the prior log-odds; so column 0 is 0 and, for single cells, column 1 the
            prior log-odds), ``-inf`` for configurations that set cells a padding block does not have, 0 in the
            first steps of a chunked block.
        carry_in: ``(NL,)`` bool, the step continues the previous step's block (add its log-weights).
        commit: ``(NL,)`` bool, the step draws its blocks.
        fix_src: ``(NL, E)`` int32 buffer index of the drawn configuration of a chunked block whose bits the
            entry's words lack (the zero word, configuration 0, if none).
        fix_pos: ``(NL, B, E)`` int32 positions of that block's cells on the ray, ``-1`` if none.
        stop_ll: ``(NL, C, E)`` float ``log p(y | stop)`` of the sensor model at each configuration's own stopping
            distance (0 where ``stop`` is ``inf``), and
        max_ll: ``(NL, E)`` float ``log p(y | max distance)`` (the ray has no wall): both precomputed for sensor
            models other than ``"normal"``, which are costly to evaluate (see :class:`FastKernel`); None for
            ``"normal"`` (evaluated in the step, as always); a test sets them to None to check the lookups against
            evaluating in the step.
        stop_pos: ``(NL, C, E)`` int32 position on the ray of each configuration's first wall (``2**31 - 1`` if
            none), in the chord geometry only (else None): a block wall and the first wall outside the block can
            enter at the same distance (the sensor's cell and the next one always do) but have different chords, and
            the first wall is then the earlier in the table's order, as in the model.
        nbr_src: ``(NL, A, B, 4)`` int32, structured prior only (else None): buffer index where the current value of
            each 4-neighbour of each block cell is (a block's draw, or the sweep's copy of the starting map), and
        nbr_bit: ``(NL, A, B, 4)`` int32 which cell of that draw's configuration it is; and
        nbr_on: ``(NL, A, B, 4)`` bool whether the neighbour counts: inside the grid, outside the block, and the step
            draws the block.
    """

    src: jax.Array
    block_bits: jax.Array
    pair0: jax.Array
    y: jax.Array
    slot: jax.Array
    pos: jax.Array
    stop: jax.Array
    log_prior: jax.Array
    carry_in: jax.Array
    commit: jax.Array
    fix_src: jax.Array
    fix_pos: jax.Array
    stop_ll: jax.Array | None = None
    max_ll: jax.Array | None = None
    stop_pos: jax.Array | None = None
    nbr_src: jax.Array | None = None
    nbr_bit: jax.Array | None = None
    nbr_on: jax.Array | None = None


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
        """See :meth:`FastKernel.ray_bits`."""
        return self.kernel.ray_bits(walls)

    def block_log_weights(self, walls) -> jax.Array:
        """Conditional log-weights of every block given the rest of ``walls`` ``(nx, ny)``: ``(NB, 2**B)``, each
        row up to an additive constant, configurations of :func:`block_configurations`. Uses the sweep's kernel
        (each block as a level of its own)."""
        if not hasattr(self, "_single"):
            singles = np.arange(len(self.blocks), dtype=np.int32)[:, None]
            most = int(np.bincount(self._entries[0], minlength=len(self.blocks)).max(initial=1))
            self._single = self._pack(singles, max(most, 1), chained=False)[0]
        return _block_log_weights(self.kernel, self._single, self.ray_bits(walls), jnp.asarray(walls))


@jax.jit
def _block_log_weights(kernel, single, ray_bits, walls):
    """:meth:`FastGibbs.block_log_weights`, compiled (kernels of the same static metadata share it)."""
    buffer = kernel.start_buffer(ray_bits, walls, 0)
    scores = jax.vmap(lambda lv: kernel._level_scores(buffer[lv.src], lv, kernel._neighbour_field(buffer, lv))[0])(
        single)[:, 0]
    if scores.ndim == 1:
        scores = jnp.stack([jnp.zeros_like(scores), scores], axis=-1)
    return scores


@jax.tree_util.register_pytree_node_class
class FastKernel(KernelFields):
    """The fast sweep's data and code: arrays as pytree leaves, sizes and flags as static metadata, so that two
    problems with the same geometry, schedule and sensor model (other readings, prior, noise or mixture weights)
    share one compiled sweep. Built by :class:`FastGibbs`.

    The sensor model: ``_beam_model`` (static name) and ``_sensor``, a tuple of scalar arrays (kernel dtype), the
    model's ``params.sensor_args``: ``(sensor_noise,)`` for ``"normal"``, ``(sensor_noise, z_hit, z_short, z_max,
    z_rand, lambda_short, max_range)`` for ``"beam"``. The Normal is evaluated in the step (a few multiplies). The
    beam mixture costs tens of transcendental operations, but a ray's candidate distances are all known in
    advance (its pairs' stopping distances, or the max distance), so ``log p(y | d)`` is looked up instead:
    ``_pair_ll`` ``(P + 1,)`` for the first wall outside the block (the pair found in the ray's bits),
    ``Levels.max_ll`` for no wall, ``Levels.stop_ll`` for a wall of the block (None for ``"normal"``). The step
    then costs no more than the Normal's; the tables are recomputed with the readings, never compiled in."""

    _ARRAYS = ("_steps", "_final_words", "_final_walls", "_final_fix", "_pair_dists", "_pair_cells", "_pair_words",
               "_pair_shift", "_bits", "_sensor", "_pair_ll", "_power", "_coupling")
    _STATIC = ("_max_words", "_zero_word", "_chunked", "_dtype", "_beam_model", "_geometry", "_walls_words")

    @property
    def num_configurations(self) -> int:
        return int(self._bits.shape[0])

    @property
    def _lookup(self) -> bool:
        """Whether ``log p(y | d)`` is looked up (:attr:`FastGibbs._lookup`): the beam model, or the chord geometry."""
        return self._beam_model != "normal" or self._geometry == "chord"

    def ray_bits(self, walls) -> jax.Array:
        """The walls along every ray as bit strings, ``(num_words + 1,)`` uint32 (see :class:`FastGibbsState`)."""
        on = jnp.asarray(walls).reshape(-1)[self._pair_cells] > 0
        bits = jnp.where(on, jnp.left_shift(jnp.uint32(1), self._pair_shift), jnp.uint32(0))
        return jax.ops.segment_sum(bits, self._pair_words, num_segments=self._zero_word + 1)

    def init(self, walls) -> FastGibbsState:
        """State for the map ``walls`` ``(nx, ny)``."""
        walls = jnp.asarray(walls, dtype=jnp.float32)
        return FastGibbsState(walls=walls, ray_bits=self.ray_bits(walls))

    def _bits_at(self, pos, on):
        """Bit strings ``(W, E)`` uint32 with the bits at positions ``pos`` ``(B, E)`` set where ``on`` ``(B, E)``."""
        bit = jnp.where(on & (pos >= 0), jnp.left_shift(jnp.uint32(1), (pos % WORD_BITS).astype(jnp.uint32)),
                        jnp.uint32(0))
        if self._max_words == 1:
            return jnp.sum(bit, axis=0, dtype=jnp.uint32)[None]
        w = jnp.arange(self._max_words, dtype=jnp.int32)[:, None, None]
        mine = (pos // WORD_BITS)[None] == w  # (W, B, E)
        return jnp.sum(jnp.where(mine, bit[None], jnp.uint32(0)), axis=1, dtype=jnp.uint32)

    def _first_outside(self, pair0, words):
        """Distance (meters, ``(E,)``) of the first set bit of ``words`` ``(W, E)`` on each ray, or the max
        distance if none is set."""
        if words.shape[0] == 1:
            word, w = words[0], 0
            found = word != 0
        else:
            nonzero = words != 0
            w = jnp.argmax(nonzero, axis=0)
            word = jnp.take_along_axis(words, w[None, :], axis=0)[0]
            found = jnp.any(nonzero, axis=0)
        lowest = word & (~word + jnp.uint32(1))
        bit = (WORD_BITS - 1) - jax.lax.clz(lowest).astype(jnp.int32)
        pair = jnp.where(found, pair0 + WORD_BITS * w + bit, self._pair_dists.shape[0] - 1)
        if self._lookup:
            return self._pair_dists[pair], pair, found
        return self._pair_dists[pair]

    def start_buffer(self, ray_bits, walls, extra: int) -> jax.Array:
        """A sweep's buffer: the ray words ``ray_bits`` (``(num_words + 1,)`` uint32), with the structured prior the
        map ``walls`` ``(nx, ny)`` as uint32 0/1 (one word per cell), then ``extra`` zero words for the steps."""
        parts = [ray_bits]
        if self._walls_words:
            parts.append((jnp.asarray(walls).reshape(-1) > 0).astype(jnp.uint32))
        parts.append(jnp.zeros(extra, jnp.uint32))
        return jnp.concatenate(parts)

    def _neighbour_field(self, buffer, lv: Levels):
        """``(A, B)`` ``n_wall - n_free`` over each block cell's counted 4-neighbours (:attr:`Levels.nbr_on`), their
        values read from ``buffer``; None without the structured prior."""
        if lv.nbr_src is None:
            return None
        values = self._bits[buffer[lv.nbr_src], lv.nbr_bit]  # (A, B, 4) bool
        return jnp.sum(jnp.where(lv.nbr_on, jnp.where(values, 1.0, -1.0), 0.0), axis=-1).astype(self._dtype)

    def _level_scores(self, words, lv: Levels, field=None):
        """Conditional scores of the blocks of one level from their rays' words ``(W, E)``: log-odds ``(A,)`` for
        single cells, else log-weights ``(A, C)`` up to a constant; and the words with the blocks' bits cleared.
        ``field`` ``(A, B)``: the structured prior's :meth:`_neighbour_field` (times ``J``, added), or None."""
        outside = words & ~lv.block_bits
        if not self._lookup:
            m_out = self._first_outside(lv.pair0, outside)  # (E,)
            d = jnp.minimum(lv.stop, m_out[None, :])  # (C, E)
            ll = normal_logpdf(lv.y[None, :], d, *self._sensor)  # the tutorial's Normal, evaluated in the step
        else:  # d = stop if stop < m_out else m_out, each log p(y | d) looked up (see the class docstring)
            m_out, pair, found = self._first_outside(lv.pair0, outside)
            if lv.stop_ll is None or lv.max_ll is None:  # not looked up: evaluated (tests compare the two)
                if self._geometry == "chord":
                    raise BayesmapError("the chord geometry's log-likelihoods are looked up: Levels.stop_ll and "
                                        "Levels.max_ll are needed")
                stop_ll = reading_logpdf(self._beam_model, lv.y[None, :], lv.stop, self._sensor)
                m_ll = reading_logpdf(self._beam_model, lv.y, m_out, self._sensor)
            else:
                stop_ll, m_ll = lv.stop_ll, jnp.where(found, self._pair_ll[pair], lv.max_ll)
            if lv.stop_pos is None:
                ll = jnp.where(lv.stop < m_out[None, :], stop_ll, m_ll[None, :])
            else:  # the chord geometry: the first wall in the table's order (ties in distance have other chords)
                out_pos = jnp.where(found, pair - lv.pair0, jnp.iinfo(jnp.int32).max)
                ll = jnp.where(lv.stop_pos < out_pos[None, :], stop_ll, m_ll[None, :])
        ll = tempered(ll, self._power)  # each log p(y | d) times eta (1: the posterior; exact)
        num_blocks = lv.log_prior.shape[0]
        # sum over each block's rays with a dense (A, E) mask: scatters are slow loops on the CPU
        mine = lv.slot[None, :] == jnp.arange(num_blocks, dtype=lv.slot.dtype)[:, None]
        if ll.shape[0] == 2:  # single cells: one log-likelihood ratio per ray, summed into log-odds (a dot: XLA
            # turns a long masked sum into a slow reduce-window)
            log_odds = jnp.dot(mine.astype(ll.dtype), ll[1] - ll[0], precision=jax.lax.Precision.HIGHEST)
            log_odds = log_odds + lv.log_prior[:, 1]  # the prior log-odds (configuration 0 has prior 0)
            if field is not None:  # the structured prior: J (n_wall - n_free)
                log_odds = log_odds + self._coupling * field[:, 0]
            return log_odds, outside
        # many configurations: accumulate (A, C) rows over the entries (vectorized over A and C)
        scores = jnp.sum(jnp.where(mine.T[:, :, None], ll.T[:, None, :], 0.0), axis=0) + lv.log_prior
        if field is not None:  # J times each configuration's walls' n_wall - n_free (up to a constant per block)
            scores = scores + self._coupling * jnp.dot(field, self._bits.T.astype(field.dtype),
                                                       precision=jax.lax.Precision.HIGHEST)
        return scores, outside

    @staticmethod
    def _draw(scores, u):
        """Configuration index ``(A,)`` int32 from log-odds ``(A,)`` or log-weights ``(A, C)``, one uniform each."""
        if scores.ndim == 1:  # 1 with probability 1 / (1 + exp(-log odds)); a padding block has log-odds -inf
            return (u * (1.0 + jnp.exp(-scores)) < 1.0).astype(jnp.int32)
        return sample_categorical(scores, u)

    def _bits_of_draws(self, buffer, fix_src, fix_pos):
        """Bits ``(W, E)`` of chunked blocks' drawn configurations (read from ``buffer[fix_src]``) at ``fix_pos``."""
        config = buffer[fix_src]  # (E,) uint32 configuration index, 0 when there is nothing to add
        return self._bits_at(fix_pos, self._bits[config].T)

    def step(self, key, state: FastGibbsState) -> tuple[FastGibbsState, GibbsInfo]:
        """One sweep: every level in order, all its blocks sampled at once; returns ``(state, GibbsInfo())`` (the
        fast samplers record no conditional probabilities).

        No scatter runs inside the loop (on the CPU a scatter is a loop of its own): each step reads its rays'
        words from the buffer slot where they were last written, at indices fixed in advance, and appends its new
        words with one ``dynamic_update_slice``; the final map and ray bits are gathered from the last writers.
        Blocks are drawn by inverse CDF from one uniform each."""
        steps = self._steps
        num_steps, num_w, entries_per_step = steps.src.shape
        width = steps.log_prior.shape[1]
        chunked = self._chunked
        uniforms = jax.random.uniform(key, (num_steps, width), dtype=self._dtype)
        base, stride = self._zero_word + 1 + self._walls_words, num_w * entries_per_step + width
        buffer = self.start_buffer(state.ray_bits, state.walls, num_steps * stride)
        no_block = jnp.zeros((1, self._bits.shape[1]), dtype=bool)

        def one_step(carry, xs):
            buffer, acc = carry
            s, lv, u = xs
            words = buffer[lv.src]
            if chunked:
                words = words | self._bits_of_draws(buffer, lv.fix_src, lv.fix_pos)
            scores, outside = self._level_scores(words, lv, self._neighbour_field(buffer, lv))
            if chunked:
                scores = scores + jnp.where(lv.carry_in, acc, 0.0)
            choice = self._draw(scores, u)
            entry_on = jnp.concatenate([self._bits[choice], no_block])[lv.slot].T  # (B, E)
            if chunked:
                entry_on = entry_on & lv.commit
            new = outside | self._bits_at(lv.pos, entry_on)
            written = jnp.concatenate([new.reshape(-1), choice.astype(jnp.uint32)])
            return (jax.lax.dynamic_update_slice(buffer, written, (base + s * stride,)), scores), None

        acc = jnp.zeros(steps.log_prior.shape[1:] if self.num_configurations > 2 else (width,), self._dtype)
        (buffer, _), _ = jax.lax.scan(one_step, (buffer, acc), (jnp.arange(num_steps), steps, uniforms))
        draw_at, cell_j = self._final_walls
        walls = self._bits[buffer[draw_at], cell_j].astype(state.walls.dtype).reshape(state.walls.shape)
        ray_bits = buffer[self._final_words]
        if self._final_fix is not None:
            fsrc, fpos, words_ray, words_w = self._final_fix
            fixed = self._bits_of_draws(buffer, fsrc, fpos)  # (W, R)
            ray_bits = jnp.concatenate([ray_bits[:-1] | fixed[words_w, words_ray], ray_bits[-1:]])
        return FastGibbsState(walls=walls, ray_bits=ray_bits), GibbsInfo()


def fast_gibbs(table: RayTable, readings, params: ModelParams, order: str = "raster", block_size: int = 1,
               schedule: str = "sequential", pos=None, likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """The fast exact Gibbs sampler as a :class:`SamplingAlgorithm`; see :class:`FastGibbs` for the arguments."""
    return FastGibbs(table, readings, params, order, block_size, schedule, pos,
                     likelihood_power=likelihood_power).algorithm
