"""The fast Gibbs sweep (:mod:`bayesmap.inference.fast`) as a compiled kernel: its state, its steps' data and its code.

The state keeps, next to the map, the walls *along each ray* as a bit string (:class:`FastGibbsState`: bit ``p`` of
ray ``r`` is the wall value of the ``p``-th cell on the ray, 32 cells per ``uint32`` word). The first wall outside a
block is then the lowest set bit of ``ray bits & ~block bits``: a handful of word operations per ray, whatever the
ray's length.

A sweep is a ``lax.scan`` over fixed-size steps (:class:`Levels`, packed on the host by
:class:`bayesmap.inference.fast.FastGibbs`): each step scores the blocks of one level from their rays' words
(:meth:`FastKernel.step`), draws them, and appends its new words to the sweep's buffer. The kernel is a pytree
(:class:`FastKernel`): its arrays are arguments of the compiled sweep, so another problem of the same shapes reuses
the compilation.

Each block is drawn by inverse CDF from one uniform (for single cells: wall with probability
``1 / (1 + exp(-log odds))``; :func:`sample_categorical` for blocks), which on the CPU is much cheaper than a Gumbel
per configuration.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.base import GibbsInfo, KernelFields
from bayesmap.model.likelihood import tempered
from bayesmap.model.sensor import normal_logpdf, reading_logpdf

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
    :meth:`FastKernel.step`). The entry axis is the last (contiguous) one, so that the CPU vectorizes along it.

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


@jax.jit
def block_log_weights(kernel, single, ray_bits, walls):
    """Conditional log-weights ``(NB, 2**B)`` of every block given the rest of ``walls`` ``(nx, ny)``, each block a
    level of its own (``single``: the :class:`Levels` of one block per step, unchained), from the state's
    ``ray_bits``; compiled, shared by kernels of the same static metadata
    (:meth:`bayesmap.inference.fast.FastGibbs.block_log_weights`)."""
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
    share one compiled sweep. Built by :class:`bayesmap.inference.fast.FastGibbs`.

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
        """Whether ``log p(y | d)`` is looked up: the beam model, or the chord geometry."""
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
