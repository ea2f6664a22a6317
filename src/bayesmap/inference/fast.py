"""Fast exact Gibbs: block conditionals from the ray-cell table instead of re-running the model.

For a block of cells (one cell for single-site Gibbs), only the rays through the block depend on its values.
For such a ray, let ``m_out`` be the distance of its first wall *outside* the block (or the max distance). With the
block in configuration ``c``, the ray's expected distance is ``min(m_out, min over block walls of t)``, where ``t``
is the table's stopping distance of each block cell on that ray. The block's conditional log-weights are then

    log w(c) = sum over block cells of log prior(c_cell) + sum over rays through the block of log N(y_r; d_r(c), s)

up to a constant that does not depend on ``c`` (``shared/DESIGN.md``, "The fast conditional"; for one cell it is
the prior log-odds plus, per ray, ``log N(y | d1) - log N(y | d0)``).

The state keeps, next to the map, the walls *along each ray* as a bit string (bit ``p`` of ray ``r`` is the wall
value of the ``p``-th cell on the ray, 32 cells per ``uint32`` word). The first wall outside a block is then the
lowest set bit of ``ray bits & ~block bits``: a handful of word operations per ray, whatever the ray's length.

A sweep runs the levels of a schedule (:mod:`bayesmap.inference.schedules`): all blocks of a level share no cell
and no ray, so their conditionals are computed and sampled at once, each exactly as if sampled alone. With
``schedule="sequential"`` the levels come from :func:`dependency_levels`, which makes one sweep the *same
transition kernel* as the reference sweep in the same order; ``"chromatic"`` runs colour classes instead. Levels
are split (:func:`split_levels`) so that each holds at most ``level_capacity`` (block, ray) entries: a level is a
fixed-size piece of work in a ``lax.fori_loop``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.chains import SamplingAlgorithm
from bayesmap.inference.schedules import (
    block_configurations,
    chromatic_levels,
    dependency_levels,
    make_blocks,
    split_levels,
)
from bayesmap.model import ModelParams
from bayesmap.raycast import RayTable, check_readings

SCHEDULES = ("sequential", "chromatic")
WORD_BITS = 32


def _normal_logpdf(y, mean, scale):
    z = (y - mean) / scale
    return -0.5 * z * z - jnp.log(scale) - 0.5 * jnp.log(2 * jnp.pi)


def sample_categorical(log_weights, u):
    """Index ``(...,)`` int32 drawn from the unnormalized log-weights ``(..., C)`` by inverse CDF with uniforms
    ``u`` ``(...,)`` in ``[0, 1)``; ``-inf`` weights are never drawn (rows must have a finite maximum)."""
    p = jnp.exp(log_weights - jnp.max(log_weights, axis=-1, keepdims=True))
    num = p.shape[-1]
    below = np.arange(num)[None, :] <= np.arange(num)[:, None]  # (C, C): j <= k
    cdf = jnp.sum(jnp.where(below, p[..., None, :], 0.0), axis=-1)  # a cumsum without reduce_window
    return jnp.sum(cdf < (u * cdf[..., -1])[..., None], axis=-1, dtype=jnp.int32)


class FastGibbsState(NamedTuple):
    """State of a fast Gibbs chain.

    Attributes:
        walls: ``(nx, ny)`` float32 map of 0.0 / 1.0.
        ray_bits: ``(num_words + 1,)`` uint32, the walls along every ray, one bit per (ray, cell) pair; the last
            word is scratch space (always 0).
    """

    walls: jax.Array
    ray_bits: jax.Array


class Levels(NamedTuple):
    """A schedule as fixed-size device arrays, one row per level: level ``l`` updates ``A`` blocks from ``E``
    (block, ray) entries, each ray's bit string read from ``W`` words of the sweep's buffer (see
    :meth:`FastGibbs.step`). The entry axis is the last (contiguous) one, so that the CPU vectorizes along it.

    Attributes:
        src: ``(NL, W, E)`` int32 buffer index of each entry's ray words (a zero word for padding).
        block_bits: ``(NL, W, E)`` uint32 the bits of the block's cells on the ray.
        pair0: ``(NL, E)`` int32 index of the ray's first pair in the table (``P`` for padding).
        y: ``(NL, E)`` float the ray's reading (meters).
        slot: ``(NL, E)`` int32 which block of the level the entry belongs to (``A`` for padding).
        pos: ``(NL, B, E)`` int32 position of each block cell along the ray, ``-1`` if the ray misses it.
        stop: ``(NL, C, E)`` float the ray's distance if only the block's walls in configuration ``c`` existed
            (``inf`` if none of them is on the ray), meters.
        log_prior: ``(NL, A, C)`` float prior log-probability of each configuration (``-inf`` for configurations
            that set cells a padding block does not have).
    """

    src: jax.Array
    block_bits: jax.Array
    pair0: jax.Array
    y: jax.Array
    slot: jax.Array
    pos: jax.Array
    stop: jax.Array
    log_prior: jax.Array


class FastGibbs:
    """The fast Gibbs sampler for one problem (table, readings, parameters) and one schedule.

    Args:
        table: the ray-cell table of the scene (its rays are in the order of ``readings``).
        readings: ``(R,)`` observed ranges, meters.
        params: model parameters (``prior_wall_prob`` and ``sensor_noise`` are used; geometry comes from the table).
        order: ``"raster"`` or ``"outward"`` (block anchors' order).
        block_size: 1 for single-site, k for k x k blocks.
        schedule: ``"sequential"`` (same kernel as the reference sweep) or ``"chromatic"``.
        pos: ``(2,)`` sensor position, meters (for the outward order; default: the first ray's origin).
        level_capacity: most (block, ray) entries per level; levels with more are split (a block crossed by more
            rays gets a level of its own, and sets the level size). Default: no splitting below 4096.

    Attributes:
        blocks: ``(NB, B)`` int flat cell indices, sweep order.
        levels: ``(num_levels, width)`` int32 block indices after splitting (padding ``NB``).
        algorithm: the :class:`SamplingAlgorithm` (``init``, ``step``).

    Raises:
        BayesmapError: on readings that do not match the table's rays, an unknown schedule or order, or a bad
            block size.

    Memory: the table's pairs, one bit per pair for the state, and per (block, ray) entry ``B`` positions and
    ``2**B`` distances (``B`` cells per block); a sweep's buffer holds one copy of each entry's ray words.
    """

    def __init__(self, table: RayTable, readings, params: ModelParams, order: str = "raster", block_size: int = 1,
                 schedule: str = "sequential", pos=None, level_capacity: int | None = None):
        if schedule not in SCHEDULES:
            raise BayesmapError(f"unknown schedule {schedule!r}; choose one of {', '.join(SCHEDULES)}")
        self.table = table
        self.grid = table.grid
        self._y = check_readings(readings, table.num_rays)
        if pos is None:
            pos = table.origins[0] if table.num_rays else np.zeros(2)
        self.blocks = make_blocks(self.grid, block_size, order, pos)
        make_levels = dependency_levels if schedule == "sequential" else chromatic_levels
        base_levels = make_levels(self.blocks, table)
        self._dtype = jnp.result_type(float)
        self._num_cells = table.num_cells
        # per-ray word layout of the state's bit strings, then one zero word
        num_words = (-(-table.lengths // WORD_BITS)).astype(np.int64)
        self._num_words = num_words
        self._max_words = max(int(num_words.max(initial=0)), 1)
        self._word_offsets = np.concatenate([[0], np.cumsum(num_words)[:-1]]).astype(np.int64)
        self._zero_word = int(num_words.sum())
        self._pair_dists = jnp.asarray(np.append(table.pair_dists, table.max_distance), dtype=self._dtype)
        self._pair_cells = jnp.asarray(table.pair_cells)
        self._pair_words = jnp.asarray(self._word_offsets[table.pair_rays] + table.pair_positions // WORD_BITS,
                                       dtype=jnp.int32)
        self._pair_shift = jnp.asarray(table.pair_positions % WORD_BITS, dtype=jnp.uint32)
        self._config_bits = block_configurations(self.blocks.shape[1]) > 0  # (C, B) numpy
        self._bits = jnp.asarray(self._config_bits)
        p = float(params.prior_wall_prob)
        self._log_prior = np.log(np.array([1.0 - p, p])) if 0.0 < p < 1.0 else np.log(np.array([1.0 - p, p]) + 0.0)
        self._noise = jnp.asarray(params.sensor_noise, dtype=self._dtype)

        self._entries = self._block_entries()
        entry_count = np.bincount(self._entries[0], minlength=len(self.blocks))
        self.level_capacity = max(int(level_capacity or 4096), int(entry_count.max(initial=0)), 1)
        self.levels = split_levels(base_levels, entry_count, self.level_capacity)
        level_entries = np.array([entry_count[row[row < len(self.blocks)]].sum() for row in self.levels])
        self._capacity = max(int(level_entries.max(initial=1)), 1)
        self._levels, self._final_words, self._final_walls = self._pack_levels(self.levels, chained=True)
        self.algorithm = SamplingAlgorithm(init=self.init, step=self.step)

    # -- static preparation (numpy) ------------------------------------------------------------------------------

    def _block_entries(self):
        """All (block, ray) entries: ``(block, ray, pos (M, B), stop (M, B))`` sorted by block then ray."""
        table, blocks = self.table, self.blocks
        nb, size = blocks.shape
        num_rays = max(table.num_rays, 1)
        by_cell = np.argsort(table.pair_cells, kind="stable")
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

    def _pack_levels(self, levels: np.ndarray, chained: bool):
        """Device arrays for the levels ``levels`` ``(NL, A)`` (block indices, padding ``NB``).

        With ``chained``, an entry reads its ray's words from the buffer slot where the ray's previous entry in
        the sweep wrote them (or from the state if it is the ray's first entry), and the final state is gathered
        from the last writers; otherwise every entry reads the state (independent levels, for
        :meth:`block_log_weights`). Returns ``(Levels, final_words, final_walls)``."""
        nb, size = self.blocks.shape
        num_levels, width = levels.shape
        cap, num_w = self._capacity, self._max_words
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
        block, ray, pos, stop, lv, sl = block[order], ray[order], pos[order], stop[order], lv[order], sl[order]
        counts = np.bincount(lv, minlength=num_levels)
        index = np.arange(len(lv)) - np.repeat(np.cumsum(counts) - counts, counts)
        flat = lv * cap + index  # entry's row in the (NL * E) layout
        w = np.arange(num_w)
        valid_w = w[None, :] < self._num_words[ray][:, None]  # (M, W)
        state_word = self._word_offsets[ray][:, None] + w[None, :]
        base = self._zero_word + 1  # the buffer: state words, one zero word, then the levels' writes

        def written_at(entry, word):  # where level l wrote word w of its entry e: a (W, E) block per level
            return base + (entry // cap) * cap * num_w + word * cap + entry % cap

        src_words = state_word
        if chained:
            # previous entry of the same ray in sweep order (entries are sorted by level)
            by_ray = np.lexsort((flat, ray))
            prev = np.full(len(ray), -1, dtype=np.int64)
            same = ray[by_ray][1:] == ray[by_ray][:-1]
            prev[by_ray[1:][same]] = flat[by_ray[:-1][same]]
            src_words = np.where(prev[:, None] >= 0, written_at(prev[:, None], w[None, :]), state_word)
        src = np.full((num_levels * cap, num_w), self._zero_word, dtype=np.int64)
        src[flat] = np.where(valid_w, src_words, self._zero_word)
        bits = np.zeros((num_levels * cap, num_w), dtype=np.uint32)
        on = pos >= 0
        for j in range(size):
            word = np.where(on[:, j], pos[:, j] // WORD_BITS, 0)
            np.bitwise_or.at(bits, (flat[on[:, j]], word[on[:, j]]),
                             (np.uint32(1) << (pos[on[:, j], j] % WORD_BITS).astype(np.uint32)))
        pair0 = np.full(num_levels * cap, self.table.num_pairs, dtype=np.int64)
        pair0[flat] = self.table.offsets[ray]
        y = np.zeros(num_levels * cap)
        y[flat] = self._y[ray]
        slot = np.full(num_levels * cap, width, dtype=np.int64)
        slot[flat] = sl
        pos_out = np.full((num_levels * cap, size), -1, dtype=np.int64)
        pos_out[flat] = pos
        stop_c = np.full((num_levels * cap, len(self._config_bits)), np.inf)
        stop_c[flat] = np.min(np.where(self._config_bits[None], stop[:, None, :], np.inf), axis=-1)
        exists = np.vstack([self.blocks, np.full((1, size), -1)])[levels] >= 0  # (NL, A, B)
        bits_c = self._config_bits[None, None]  # (1, 1, C, B)
        prior = np.where(exists[:, :, None, :], np.where(bits_c, self._log_prior[1], self._log_prior[0]), 0.0).sum(-1)
        prior = np.where(np.any(bits_c & ~exists[:, :, None, :], axis=-1), -np.inf, prior)
        dt, i32 = self._dtype, jnp.int32

        def entries_last(a, dtype):
            a = a.reshape((num_levels, cap) + a.shape[1:])
            return jnp.asarray(np.moveaxis(a, 1, -1) if a.ndim == 3 else a, dtype=dtype)

        packed = Levels(
            src=entries_last(src, i32),
            block_bits=entries_last(bits, jnp.uint32),
            pair0=entries_last(pair0, i32),
            y=entries_last(y, dt),
            slot=entries_last(slot, i32),
            pos=entries_last(pos_out, i32),
            stop=entries_last(stop_c, dt),
            log_prior=jnp.asarray(prior, dtype=dt),
        )
        if not chained:
            return packed, None, None
        # final state: each ray word from the ray's last entry (or unchanged), each cell from its last block
        final_words = np.arange(self._zero_word + 1)
        last = np.full(self.table.num_rays, -1, dtype=np.int64)
        last[ray] = flat  # entries are in sweep order, so the last assignment wins
        has = last >= 0
        words_of = self._word_offsets[:, None] + w[None, :]
        mask = has[:, None] & (w[None, :] < self._num_words[:, None])
        final_words[words_of[mask]] = written_at(last[:, None], w[None, :])[mask]
        cell_last = np.full(self._num_cells, -1, dtype=np.int64)
        ls = np.nonzero(levels < nb)
        cells = self.blocks[levels[ls]]  # (n, B), in level order
        flat_on = (ls[0] * width + ls[1])[:, None] * size + np.arange(size)[None, :]
        cell_last[cells.reshape(-1)] = flat_on.reshape(-1)
        return packed, jnp.asarray(final_words, dtype=i32), jnp.asarray(cell_last, dtype=i32)

    # -- the kernel (pure JAX) -----------------------------------------------------------------------------------

    @property
    def num_configurations(self) -> int:
        return int(self._bits.shape[0])

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
        return self._pair_dists[pair]

    def _level_log_weights(self, words, lv: Levels):
        """Conditional log-weights ``(A, C)`` of the blocks of one level from their rays' words ``(W, E)``, and the
        words with the blocks' bits cleared."""
        outside = words & ~lv.block_bits
        m_out = self._first_outside(lv.pair0, outside)  # (E,)
        d = jnp.minimum(lv.stop, m_out[None, :])  # (C, E)
        ll = _normal_logpdf(lv.y[None, :], d, self._noise)
        num_blocks = lv.log_prior.shape[0]
        # sum over each block's rays with a dense (A, E) mask: scatters are slow loops on the CPU
        mine = lv.slot[None, :] == jnp.arange(num_blocks, dtype=lv.slot.dtype)[:, None]
        if ll.shape[0] > 2:  # many configurations: accumulate (A, C) rows over the entries (vectorized over A, C)
            w = jnp.sum(jnp.where(mine.T[:, :, None], ll.T[:, None, :], 0.0), axis=0)
        else:
            w = jnp.sum(jnp.where(mine[:, None, :], ll[None], 0.0), axis=-1)
        return w + lv.log_prior, outside

    def block_log_weights(self, walls) -> jax.Array:
        """Conditional log-weights of every block given the rest of ``walls`` ``(nx, ny)``: ``(NB, 2**B)``, each
        row up to an additive constant, configurations of :func:`block_configurations`. Uses the sweep's kernel
        (each block as a level of its own)."""
        if not hasattr(self, "_single"):
            self._single = self._pack_levels(np.arange(len(self.blocks), dtype=np.int32)[:, None], chained=False)[0]
        ray_bits = self.ray_bits(walls)
        return jax.vmap(lambda lv: self._level_log_weights(ray_bits[lv.src], lv)[0])(self._single)[:, 0]

    def step(self, key, state: FastGibbsState) -> FastGibbsState:
        """One sweep: every level in order, all its blocks sampled at once.

        No scatter runs inside the loop (on the CPU a scatter is a loop of its own): each level reads its rays'
        words from the buffer slot where they were last written, at indices fixed in advance, and appends its new
        words with one ``dynamic_update_slice``; the final map and ray bits are gathered from the last writers."""
        num_levels, num_w, cap = self._levels.src.shape
        width = self._levels.log_prior.shape[1]
        # one uniform per block and level: inverse-CDF sampling of the 2**B configurations (cheaper on the CPU
        # than a Gumbel per configuration, whose double log dominates a sweep)
        uniforms = jax.random.uniform(key, (num_levels, width), dtype=self._dtype)
        buffer = jnp.concatenate([state.ray_bits, jnp.zeros(num_levels * cap * num_w, jnp.uint32)])
        base = self._zero_word + 1
        no_block = jnp.zeros((1, self._bits.shape[1]), dtype=bool)

        def level(buffer, xs):
            l, lv, u = xs
            log_w, outside = self._level_log_weights(buffer[lv.src], lv)
            on = self._bits[sample_categorical(log_w, u)]  # (A, B)
            new = outside | self._bits_at(lv.pos, jnp.concatenate([on, no_block])[lv.slot].T)
            buffer = jax.lax.dynamic_update_slice(buffer, new.reshape(-1), (base + l * cap * num_w,))
            return buffer, on

        buffer, on = jax.lax.scan(level, buffer, (jnp.arange(num_levels), self._levels, uniforms))
        walls = on.reshape(-1)[self._final_walls].astype(state.walls.dtype).reshape(state.walls.shape)
        return FastGibbsState(walls=walls, ray_bits=buffer[self._final_words])


def fast_gibbs(table: RayTable, readings, params: ModelParams, order: str = "raster", block_size: int = 1,
               schedule: str = "sequential", pos=None) -> SamplingAlgorithm:
    """The fast exact Gibbs sampler as a :class:`SamplingAlgorithm`; see :class:`FastGibbs` for the arguments."""
    return FastGibbs(table, readings, params, order, block_size, schedule, pos).algorithm
