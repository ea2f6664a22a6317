"""Whole-log single-site Gibbs: one cell at a time, with each ray's first and second wall kept in the state.

The samplers of :mod:`bayesmap.inference.fast` update many cells at once and keep, per (block, ray) entry of a
sweep, the ray's words and distances (about 1.9 KB per pair): right for one scan, impossible for a whole log
(42 million pairs for the Intel log at 0.1 m), whose "shares a ray" graph is nearly complete anyway, so colour
classes would bring little parallelism. This sampler is the plain systematic-scan single-site Gibbs sampler
(Geman & Geman 1984) done cheaply:

* A cell's conditional log-odds is the prior log-odds plus, over the rays through it, ``log p(y | d1) - log p(y |
  d0)`` (derived in ``docs/fast-conditional.md``). Only three cases exist: the ray's first wall lies before
  the cell (the term cancels), after it (``d1`` is the cell's stopping distance, ``d0`` the first wall's), or the
  cell *is* the first wall (``d0`` is the second wall's). So the state keeps, per ray, the position along the ray of
  its first and second wall and ``log p(y | .)`` at each (:class:`CellwiseState`), and a cell's update reads one
  row per ray through it: O(pairs) per sweep, with ``log p(y | t)`` of every (ray, cell) pair looked up from a
  table computed once per set of readings (any sensor model costs the same).
* When the drawn value differs from the current one, the rows of the rays whose first or second wall changes are
  rewritten, ``SEARCH_BATCH`` rays at a time; removing a ray's first or second wall needs the next wall along it,
  found by walking the ray's cells in the map (``SEARCH_CHUNK`` at a time). A cell that keeps its value writes
  nothing, nor does one that changes behind the second wall of every ray through it (no row changes).
* Cells are visited in a fixed order: grouped by how many rays cross them (so that each group's lanes have a fixed
  width, padding at most 2x), then in raster order within a group. Any fixed order gives a valid Gibbs sweep. The
  whole sweep is one loop: a group's scoring is one branch of a switch on the group, and the rewrite of the rows,
  the largest part of the loop, is traced once for all groups (:meth:`CellwiseKernel._sweep`): compiling a sweep
  of Intel's scans with the log defaults took 2.7-4.1 s instead of 4.7-9.0 s with a loop per group
  (docs/validation/speed.md, "One loop for every width group").
  Cells that no ray crosses are independent of everything given the rest: they are drawn from the prior at once.
* The loop scores consecutive cells of the order at once (``SPECULATIVE_CELLS``, or ``SPECULATIVE_LANES`` lanes'
  worth in a narrow group: 256 cells of 8 lanes), from the same rows, and draws each from its score. Cell ``j`` of
  the block sees exactly the rows it would see one cell at a time as long as no earlier cell of the block changed a
  row: the cells up to and including the first draw that changes rows are kept, the rest of the block is scored
  again from the rewritten rows. So the draws are those of the one-cell-at-a-time sweep in the same order (same
  uniforms, same conditionals), with one pass over memory for many cells instead of one per cell (each step of a
  loop costs several microseconds on CPU; ~4% of cells change rows per sweep on the Intel log). How many is a speed
  setting, not a model one (any number makes the same draws): at 16 cells or 2,048 lanes a sweep at known poses took
  0.12 / 0.09 / 0.15 s on Intel / ACES / CSAIL against 0.17-0.18 / 0.15 / 0.34 s at 8 cells (docs/validation/
  speed.md, "Cells scored at once"). Within the sweep the map is kept in the visiting order, so that a block's cells
  are one contiguous slice.

A sweep visits the first ``count`` rows of each width group (:class:`Lanes`): every crossed cell, or, for the kernel
:meth:`CellwiseKernel.focus` returns, only the cells it is given (those in doubt: :mod:`bayesmap.inference.focus`),
which it puts first in each group; the others keep their values, a Gibbs update of the visited cells given the rest.

The structured prior (:mod:`bayesmap.model.prior`, ``params.coupling > 0``): a cell's log-odds gain ``J (n_wall -
n_free)`` over its 4-neighbours, read from the map in visiting order (which then holds every cell: those no ray
crosses after the others). Within each group the cells of one colour of the grid's checkerboard (``i + j`` even) come
before the other's, so that the cells scored at once are rarely neighbours; the speculative rule also stops at the
first draw that changes a cell with a neighbour later among the cells scored at once (whose score would otherwise be
stale). The cells no ray crosses now depend on their neighbours: after the crossed cells, those of colour even are
drawn all at once, then those of colour odd (two cells of one colour are never neighbours, and such a cell's
conditional involves only its neighbours: each is drawn from its exact conditional, chromatic Gibbs). The draws
are those of the one-cell-at-a-time sweep in this order. With ``J = 0`` nothing changes: the same order, lanes and
draws as without the structured prior.

Wall cells a beam can pass (``params.wall_pass_prob`` ``pi > 0``; :mod:`bayesmap.model.generative`): a reading
depends on its ray's first two walls, ``log p(y) = log((1 - pi) p(y | w1) + pi (1 - pi) p(y | w2) + pi^2 p(y | none))``
(:func:`bayesmap.model.passable.pass_mixture`). A cell's term for a ray compares this mixture with the cell a wall and
free: with the cell before the ray's first wall, ``(cell, w1)`` against ``(w1, w2)``; the cell the first wall,
``(w1, w2)`` against ``(w2, w3)``; between the first and second, ``(w1, cell)`` against ``(w1, w2)``; the second
wall, ``(w1, w2)`` against ``(w1, w3)``; behind the second wall, nothing. So the rows keep each ray's first *three*
walls; setting a cell changes a row if it lies before the ray's third wall, clearing it if it is one of the three.
The mixture is tempered as a whole: the rows hold untempered log-likelihoods and each term is multiplied by the
likelihood power (a mixture's log is not the sum of its components' logs).

Posterior marginals: each update draws its cell from ``p(cell | rest)``; each sweep reports these probabilities in
its ``info`` (:attr:`bayesmap.inference.base.GibbsInfo.wall_prob`: the prior for cells no ray crosses), and the
mean of these conditional probabilities over kept sweeps estimates the marginal ``P(cell is a wall | readings)``
with less variance than the mean of the 0/1 draws (Rao-Blackwellization; Gelfand & Smith 1990, sec. 2.3;
Liu, Wong & Kong 1994). Unlike the 0/1 mean it also ranks cells that were walls in none or all of the kept sweeps,
which matters for scores such as the held-out AUC.

Memory: per pair, 12 bytes in the sweep's lanes (ray, position, looked-up log-likelihood; at most twice that with
the padding, 1.16x on the Intel log) plus 8 bytes of tables (cell and log-likelihood, for the lookups and
:meth:`CellwiseKernel.init`); per ray, one row of 4 numbers; per cell, its place in the visiting order.

The kernel is exact: each update draws the cell from its full conditional, the same transition as the reference
sweep (:mod:`bayesmap.inference.reference`) in this sampler's order; tests check the conditionals against the
GenJAX model's ``assess``, the state's rows against those recomputed from the map, and marginals against exact
enumeration. It is written for one chain: under ``vmap`` (several chains at once) JAX turns the conditional
writes into selects that always run, which is correct but slow; run chains of large problems one after another.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import RayTable
from bayesmap.inference.base import GibbsInfo, KernelFields, KernelSampler, SamplingAlgorithm
from bayesmap.memory import release_freed_memory
from bayesmap.model.generative import ModelParams, prior_log_odds
from bayesmap.model.likelihood import (
    likelihood_inputs,
    no_wall_log_likelihoods,
    pair_log_likelihoods,
    tempered,
)
from bayesmap.model.passable import pass_log_weights
from bayesmap.model.prior import neighbour_field, neighbour_indices

NO_WALL = float(1 << 22)  # "no such wall": a position beyond every ray (exact in float32)
SEARCH_CHUNK = 32  # cells read per step of the walk along a ray to its next wall
SEARCH_BATCH = 16  # rays whose rows a changed cell rewrites (and walks) at once
SPECULATIVE_CELLS = 16  # the fewest consecutive cells scored at once from the same rows, kept up to the first that
# changes a row (see the module docstring); not a block of a joint update (``block_size`` of the fast samplers)
SPECULATIVE_LANES = 2048  # narrow groups score SPECULATIVE_LANES // width cells at once, if more
MAX_WIDTH = 1 << 16
MAX_PADDED_LANES = 1.5
"""The most lanes (each width group's cells times its width) a sweep padded to an earlier kernel's sizes may have, as a
multiple of the lanes of the sizes its own table would get (:func:`fitted_shapes`): padding cells are swept like cells,
so a small tile padded to a dense one's sizes would do the dense one's work. Beyond it the sweep is sized for its own
table and compiles anew (about 2 s on two cores). A speed knob, not a model setting (padding changes no draw), and
not tuned: Freiburg 079's tiles and a SLAM run's map blocks stay well within it
([validation](../validation/slam.md#tiles-that-share-one-compiled-sweep))."""


class CellwiseState(NamedTuple):
    """State of a :class:`CellwiseGibbs` chain.

    Attributes:
        walls: ``(nx, ny)`` float32 map of 0.0 / 1.0.
        ray_walls: ``(R + 1, 4)`` float (kernel dtype): per ray, the position along the ray (0 = the cell closest to
            the sensor) of its first and of its second wall (:data:`NO_WALL` if there is none), then ``log p(y_r | d)``
            at each (at the max distance for :data:`NO_WALL`). The last row belongs to no ray (read by padding lanes).
            When a beam can pass a wall cell (``params.wall_pass_prob > 0``), ``(R + 1, 12)``: the positions of the
            first, second and third wall, ``log p(y_r | d)`` (untempered) at each, ``log p(y_r | no wall)``, and five
            mixtures of these that do not depend on the cell scored (:meth:`CellwiseKernel._ray_mixtures`).
    """

    walls: jax.Array
    ray_walls: jax.Array


def width_groups(counts: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """Cells grouped by how many rays cross them: ``[(width, cells), ...]`` with widths 8, 16, 32, ... (powers of 2)
    and each cell (flat index, ascending) in the group of the smallest width >= its count; cells with count 0 are
    left out.

    Raises:
        BayesmapError: if a cell is crossed by more than 65,536 rays.
    """
    counts = np.asarray(counts)
    if counts.max(initial=0) > MAX_WIDTH:
        raise BayesmapError(f"a cell is crossed by {int(counts.max()):,} rays; at most {MAX_WIDTH:,} are supported")
    groups, low, width = [], 0, 8
    while low < counts.max(initial=0):
        cells = np.nonzero((counts > low) & (counts <= width))[0]
        if len(cells):
            groups.append((width, cells))
        low, width = width, 2 * width
    return groups


class Lanes(NamedTuple):
    """One group of cells of equal padded width ``W``: ``(n,)`` int32 ``cells``; per cell and lane, ``(n, W)``
    int32 ``rays`` (``R`` for padding), int32 ``positions`` along the ray, and ``log_lik`` ``log p(y_ray | stopping
    distance of the cell)`` (0 for padding); with the structured prior, ``neighbours`` ``(n, 4)`` int32 the places
    of the cell's 4-neighbours in the visiting order (the number of visited cells, a slot that holds 0.5, for a
    neighbour outside the grid), else None. A sweep visits the first ``count`` rows (a scalar int32 array): every
    real cell (the padding rows come last), or fewer (:meth:`CellwiseKernel.focus`)."""

    cells: jax.Array
    rays: jax.Array
    positions: jax.Array
    log_lik: jax.Array
    neighbours: jax.Array | None = None
    count: jax.Array | None = None


class SweepShapes(NamedTuple):
    """The sizes of a cellwise sweep's arrays, which decide its compilation: kernels of equal sizes (and equal model
    flags) share one compiled sweep.

    Attributes:
        groups: ``((width, cells), ...)`` ascending by width: each width group's lanes are ``(cells, width)``.
        rest: entries of the visiting order after the groups (the cells no ray crosses, with the structured prior,
            and the frozen cells).
        rays: rays of the per-ray rows (``ray_walls`` has ``rays + 1``).
        pairs: (ray, cell) pairs of the table (the pair arrays have ``pairs + 1``).
    """

    groups: tuple[tuple[int, int], ...]
    rest: int
    rays: int
    pairs: int


def fitted_shapes(needed: SweepShapes, at_least: SweepShapes | None = None, headroom: float = 0.0) -> SweepShapes:
    """The sizes to pad a sweep's arrays to: each size of ``needed`` that fits the one of ``at_least`` takes that one
    (so that a kernel built with a previous kernel's :attr:`CellwiseKernel.shapes` reuses its compilation); one that
    does not fit, or has none, is ``needed`` times ``1 + headroom`` rounded up to a multiple of 8 (exactly ``needed``
    with no headroom). A width group of ``at_least`` that ``needed`` lacks is kept (cells that are all padding). With
    a headroom, sizes that do not all fit ``at_least`` also get a group of twice the widest width (up to
    :data:`MAX_WIDTH`), of as many padding cells as the widest group's size, where no group is wider than ``needed``'s
    widest: a table at moved poses may have a cell crossed by more rays than any before (on CSAIL's hypotheses, a
    group of 2,048 lanes the first table lacked), and would compile anew for it. Where the sizes from ``at_least``
    would hold more than :data:`MAX_PADDED_LANES` times the lanes of ``needed``'s own sizes (without ``at_least``;
    with a headroom, its reserved group of twice the widest width counted in them, so the limit is that much more
    lenient than the lanes ``needed`` fills), the own sizes are returned.

    Raises:
        BayesmapError: on a negative or non-finite ``headroom``.
    """
    if isinstance(headroom, bool) or not isinstance(headroom, (int, float)) or not np.isfinite(headroom) \
            or headroom < 0:
        raise BayesmapError(f"headroom must be a finite number >= 0, got {headroom!r}")

    def fit(n: int, have: int | None) -> int:
        if have is not None and n <= have:
            return have
        return n if headroom == 0 else int(np.ceil(n * (1 + headroom) / 8)) * 8

    had, need = ({} if at_least is None else dict(at_least.groups)), dict(needed.groups)
    groups = tuple((w, fit(need.get(w, 0), had.get(w))) for w in sorted(set(had) | set(need)))
    if had:
        own = fitted_shapes(needed, None, headroom)
        if _lanes_of(groups) > MAX_PADDED_LANES * _lanes_of(own.groups):  # a small table padded to a large one's work
            return own
    sizes = SweepShapes(groups, *(fit(getattr(needed, f), None if at_least is None else getattr(at_least, f))
                                  for f in ("rest", "rays", "pairs")))
    if headroom and sizes != at_least and need and max(need) == groups[-1][0] and 2 * max(need) <= MAX_WIDTH:
        sizes = sizes._replace(groups=groups + ((2 * max(need), groups[-1][1]),))
    return sizes


def _lanes_of(groups) -> int:
    """The lanes of width groups ``((width, cells), ...)``: each group's cells times its width."""
    return sum(width * cells for width, cells in groups)


def checkerboard_groups(groups, shape: tuple[int, int]):
    """``groups`` (from :func:`width_groups`) with each group's cells reordered: those with ``i + j`` even first,
    then the odd ones, each part ascending. Two cells of one part are never 4-neighbours."""
    ny = shape[1]
    out = []
    for width, cells in groups:
        odd = (cells // ny + cells % ny) % 2
        out.append((width, cells[np.argsort(odd, kind="stable")]))
    return out


def _visiting_order(parts, sizes, num_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """``(order, rank)``: the sweep's visiting order, ``(sum(sizes),)`` int32, the cells of ``parts`` (int arrays)
    one part after another, part ``k`` padded with cell 0 to ``sizes[k]`` entries (the padding entries are read and
    drawn like cells but belong to none), and ``(num_cells,)`` int32 each cell's place in it (0 for cells in no
    part)."""
    order = np.zeros(int(sum(sizes)), dtype=np.int32)
    rank = np.zeros(num_cells, dtype=np.int32)
    start = 0
    for cells, size in zip(parts, sizes):
        order[start:start + len(cells)] = cells
        rank[cells] = np.arange(start, start + len(cells), dtype=np.int32)
        start += size
    return order, rank


def _lanes(table: RayTable, counts: np.ndarray, groups, rank: np.ndarray, pair_ll: jax.Array,
           dtype, shapes: SweepShapes) -> tuple[Lanes, ...]:
    """The sweep's :class:`Lanes`, one per width group (``groups``, ``[(width, cells), ...]`` of
    :func:`width_groups` of ``counts``, the table's rays per cell, with a group for each width of ``shapes.groups``,
    in its order, maybe of no cells; ``rank`` the cells' visiting order, :func:`_visiting_order`); ``pair_ll``
    ``(L > P,)`` of ``dtype`` from :func:`~bayesmap.model.likelihood.pair_log_likelihoods`, read last (it may still
    be computing). Each group is padded to its size in ``shapes`` with cells (cell 0) whose lanes are all padding
    (ray ``shapes.rays``).

    The pairs are sorted once into the order of the lanes (group by group, cells ascending, a cell's pairs in ray
    order), so that each group's pairs are one contiguous slice, written row by row into its padded ``(n, W)``
    arrays, a block of rows at a time. Memory besides the lanes: the sorted pair indices (8 bytes per pair), each
    pair's ray while the rays and positions are written (4 bytes per pair) and one block's temporaries (fresh pages
    cost more than the work on them).
    """
    if not groups:
        return ()
    size = dict(shapes.groups)
    order = table.pairs_by_cell(rank)
    firsts = np.cumsum([0] + [int(counts[cells].sum()) for _, cells in groups])  # each group's first sorted pair
    pair_rays = table.per_pair(np.arange(table.num_rays, dtype=np.int32))  # (a gather below, not a search)
    parts = []
    for (width, cells), first in zip(groups, firsts):
        rays = np.full((size[width], width), shapes.rays, dtype=np.int32)
        positions = np.zeros((size[width], width), dtype=np.int32)
        for rows, valid, pair in _row_blocks(counts[cells], width, order, first):
            ray = pair_rays[pair]
            rays[rows][valid] = ray
            positions[rows][valid] = pair - table.offsets[ray]
        parts.append((rays, positions))
    del pair_rays
    pair_ll = np.asarray(pair_ll)
    lanes = []
    for (width, cells), first, (rays, positions) in zip(groups, firsts, parts):
        log_lik = np.zeros((size[width], width), dtype=dtype)
        for rows, valid, pair in _row_blocks(counts[cells], width, order, first):
            log_lik[rows][valid] = pair_ll[pair]
        padded = np.zeros(size[width], np.int32)
        padded[:len(cells)] = cells
        lanes.append(Lanes(cells=jnp.asarray(padded), rays=jnp.asarray(rays),
                           positions=jnp.asarray(positions), log_lik=jnp.asarray(log_lik),
                           count=jnp.asarray(len(cells), jnp.int32)))
    return tuple(lanes)


def _row_blocks(num: np.ndarray, width: int, order: np.ndarray, first: int):
    """Blocks of about 2**18 lanes of a width group whose cells have ``num`` ``(n,)`` pairs each, the group's pairs
    being ``order[first:first + num.sum()]``: yields ``(rows, valid, pairs)``, a slice of the rows, their
    ``(rows, width)`` bool lanes that hold a pair, and those pairs (row by row) from ``order``."""
    bounds = first + np.concatenate([[0], np.cumsum(num)])
    step = max(1, (1 << 18) // width)
    for start in range(0, len(num), step):
        rows = slice(start, min(start + step, len(num)))
        yield rows, np.arange(width) < num[rows, None], order[bounds[rows.start]:bounds[rows.stop]]


@jax.tree_util.register_pytree_node_class
class CellwiseKernel(KernelFields):
    """The sweep's data (pytree leaves) and code; built by :class:`CellwiseGibbs`. Problems with the same geometry
    and sensor model (other readings, prior, noise, mixture weights, coupling) share one compiled sweep, and so do
    kernels built to the same :attr:`shapes`. ``_order`` is the visiting order (int32 flat cells, with padding
    entries: :func:`_visiting_order`), ``_rank`` each cell's place in it; ``_coupling`` is the structured prior's
    ``J`` (a scalar array), None for the independent prior; ``_frozen`` ``(nx * ny,)`` bool the cells a sweep keeps
    as they are (None: none), last in the visiting order. With wall cells a beam can pass
    (``_penetrable``), ``_eta`` is the likelihood power and ``_pass_weights`` the ``(3,)`` log-weights of
    :func:`bayesmap.model.passable.pass_log_weights` (both None otherwise: the tables are tempered already)."""

    _ARRAYS = ("_lanes", "_free", "_rank", "_order", "_pair_cells", "_pair_ll", "_ray_start", "_ray_length",
               "_max_ll", "_prior_log_odds", "_coupling", "_frozen", "_eta", "_pass_weights")
    _STATIC = ("_shape", "_num_rays", "_num_pairs", "_penetrable")

    @property
    def shapes(self) -> SweepShapes:
        """The sizes of this kernel's arrays (:class:`SweepShapes`), padding included."""
        groups = tuple((int(lanes.rays.shape[1]), int(lanes.rays.shape[0])) for lanes in self._lanes)
        rest = int(self._order.shape[0]) - sum(n for _, n in groups)
        return SweepShapes(groups=groups, rest=rest, rays=self._num_rays, pairs=self._num_pairs)

    # -- the per-ray rows ---------------------------------------------------------------------------------------

    def _pair_log_lik(self, rays, positions):
        """``log p(y_ray | d)`` at a position along each ray (the max distance's for :data:`NO_WALL`)."""
        none = positions >= NO_WALL
        pair = jnp.where(none, self._num_pairs, self._ray_start[rays] + positions.astype(jnp.int32))
        return jnp.where(none, self._max_ll[rays], self._pair_ll[pair])

    def ray_walls(self, walls) -> jax.Array:
        """The state's rows ``(R + 1, 4)`` for the map ``walls`` ``(nx, ny)`` (see :class:`CellwiseState`).

        The pairs of a ray are contiguous in the table and in order along it, so one reverse cumulative minimum over
        all pairs of ``pair index if wall else P`` gives, at each pair, the first wall at or after it; a ray's first
        wall is that value at its first pair, its second wall the value just after the first (walls beyond the ray's
        last pair belong to other rays: none). On the CPU this is several times faster than segment minima by ray
        (scatters).
        """
        dtype = self._pair_ll.dtype
        num_pairs = self._num_pairs
        pair = jnp.arange(num_pairs + 1, dtype=jnp.int32)
        on = (jnp.asarray(walls).reshape(-1)[self._pair_cells] > 0) & (pair < num_pairs)
        next_wall = jax.lax.cummin(jnp.where(on, pair, num_pairs), reverse=True)  # (P + 1,) pair indices
        start = self._ray_start
        end = start + self._ray_length

        def position(wall):  # a ray's wall (pair index) as its position along the ray, NO_WALL if not on the ray
            return jnp.where(wall < end, (wall - start).astype(dtype), NO_WALL)

        walls_at = [next_wall[start]]
        for _ in range(2 if self._penetrable else 1):  # the second (and third) wall: the next after the one before
            walls_at.append(next_wall[jnp.minimum(walls_at[-1] + 1, num_pairs)])
        positions = [position(w) for w in walls_at]
        rays = jnp.arange(self._num_rays + 1, dtype=jnp.int32)
        columns = positions + [self._pair_log_lik(rays, p) for p in positions]
        padding = [-1.0] * len(positions) + [0.0] * len(positions)
        if self._penetrable:  # log p(y | no wall) and the mixtures that do not depend on the cell scored
            none = self._max_ll[rays]
            columns += [none] + self._ray_mixtures(*columns[3:6], none)
            padding += [0.0] * 6
        rows = jnp.stack(columns, axis=1)
        return rows.at[self._num_rays].set(jnp.array(padding, dtype))  # the padding lanes' row

    def readings_log_likelihood(self, state: CellwiseState) -> float:
        """The readings' tempered log-likelihood (nats) at the state's walls, ``eta log p(readings | walls)``, from its
        per-ray rows (:class:`CellwiseState`), summed in float64: each ray's ``log p(y | first wall)``, tempered in
        the tables, or with wall cells a beam can pass its mixture of the first two walls and none, times ``eta``.
        The padding rays' rows add 0. The readings' term of the target the sweep samples, which
        :meth:`bayesmap.problem.Problem.table_log_joint` computes in float64 from a table of its own (they agree to
        the kernel's float precision, tested)."""
        rows = np.asarray(state.ray_walls, np.float64)[:self._num_rays]
        if self._penetrable:
            return float(np.asarray(self._eta, np.float64) * rows[:, 7].sum())
        return float(rows[:, 2].sum())

    def init(self, walls) -> CellwiseState:
        """State for the map ``walls`` ``(nx, ny)``."""
        walls = jnp.asarray(walls, dtype=jnp.float32).reshape(self._shape)
        return CellwiseState(walls=walls, ray_walls=_ray_walls(self, walls))

    # -- the sweep ---------------------------------------------------------------------------------------------

    def _score(self, rows, positions, log_lik):
        """Over the last axis (a cell's lanes): the sum of ``log p(y | d1) - log p(y | d0)`` (see the module
        docstring), and whether setting the cell to 1 / to 0 would change a row (a ray's first or second wall):
        some lane lies before the ray's second wall / the cell is a ray's first or second wall (with wall cells a
        beam can pass, the first three walls: :meth:`_pass_terms`). Padding lanes (row ``(-1, ..., 0, ...)``,
        position 0) add nothing. One pass (a variadic reduction) over the lanes and their rows."""
        q = positions.astype(rows.dtype)
        if self._penetrable:
            term, can_add, can_remove = self._pass_terms(rows, q, log_lik)
        else:
            first, second, ll_first, ll_second = rows[..., 0], rows[..., 1], rows[..., 2], rows[..., 3]
            term = jnp.where(q < first, log_lik - ll_first, jnp.where(q == first, log_lik - ll_second, 0.0))
            can_add, can_remove = q < second, (q == first) | (q == second)
        zero = jnp.zeros((), term.dtype)
        return jax.lax.reduce((term, can_add, can_remove), (zero, False, False),
                              lambda x, y: (x[0] + y[0], x[1] | y[1], x[2] | y[2]), (term.ndim - 1,))

    def _ray_mixtures(self, ll_first, ll_second, ll_third, ll_none):
        """The per-ray columns 7-11 of a row with passable walls: ``log p(y)`` with first and second walls (1, 2),
        (2, 3) and (1, 3), and ``log(w1 p(y | 1) + w2 p(y | none))``, ``log(w0 p(y | 1) + w2 p(y | none))`` (``w``
        the weights of :func:`bayesmap.model.passable.pass_log_weights`): with them a lane's term needs one
        ``logaddexp`` (:meth:`_pass_terms`). A list of arrays shaped like the arguments."""
        w = self._pass_weights

        def mix(a, b):  # log p(y) with first wall a and second wall b (log-likelihoods)
            return jnp.logaddexp(jnp.logaddexp(w[0] + a, w[1] + b), w[2] + ll_none)

        return [mix(ll_first, ll_second), mix(ll_second, ll_third), mix(ll_first, ll_third),
                jnp.logaddexp(w[1] + ll_first, w[2] + ll_none), jnp.logaddexp(w[0] + ll_first, w[2] + ll_none)]

    def _pass_terms(self, rows, q, log_lik):
        """Per lane, with wall cells a beam can pass: the tempered term of the module docstring (the mixture with
        the cell a wall minus with it free) and whether setting / clearing the cell changes the row (it lies before
        the third wall / it is one of the first three). The mixtures that do not involve the cell are the row's
        (:meth:`_ray_mixtures`); one ``logaddexp`` per lane adds the cell as the first or the second wall."""
        first, second, third = rows[..., 0], rows[..., 1], rows[..., 2]
        m12, m23, m13, rest_second, rest_first = (rows[..., c] for c in range(7, 12))
        w = self._pass_weights
        before, at_first, at_second = q < first, q == first, q == second
        # the cell a wall: the first (before the first wall) or the second (between the first and second)
        a, b = jnp.where(before, w[0], w[1]) + log_lik, jnp.where(before, rest_second, rest_first)
        wall = jnp.logaddexp(a, b)
        term = jnp.where(before | (q < second) & ~at_first, wall - m12,
                         jnp.where(at_first, m12 - m23, jnp.where(at_second, m12 - m13, 0.0)))
        return self._eta * term, q < third, at_first | at_second | (q == third)

    def _walk(self, rays, after, need, cur):
        """Position of the first wall of each ray beyond position ``after`` (:data:`NO_WALL` if none), for the lanes
        ``need`` (others: :data:`NO_WALL`), in the map ``cur`` (in visiting order); walks the rays' cells
        ``SEARCH_CHUNK`` at a time until every needed lane is done."""
        length, start = self._ray_length[rays], self._ray_start[rays]
        offsets = jnp.arange(SEARCH_CHUNK, dtype=jnp.int32)

        def more(carry):
            at, found = carry
            return jnp.any(need & (found >= NO_WALL) & (at < length))

        def walk(carry):
            at, found = carry
            ts = at[:, None] + offsets[None, :]
            inside = ts < length[:, None]
            cell = self._pair_cells[jnp.where(inside, start[:, None] + ts, self._num_pairs)]
            hit = inside & (cur[self._rank[cell]] > 0)
            first = jnp.min(jnp.where(hit, ts, int(NO_WALL)), axis=1).astype(found.dtype)
            return at + SEARCH_CHUNK, jnp.where(need & (found >= NO_WALL), first, found)

        begin = jnp.where(after >= NO_WALL, length, after.astype(jnp.int32) + 1)
        _, found = jax.lax.while_loop(more, walk, (begin, jnp.full(rays.shape, NO_WALL, after.dtype)))
        return found

    def _changed_lanes(self, lanes, k, new, done, rows_all):
        """The next ``SEARCH_BATCH`` lanes of cell ``k`` of ``lanes`` after lane ``done`` (-1: from the first) whose
        ray's row changes now that the cell is ``new``: the rays whose first or second wall (with passable walls:
        or third) changes, none for a cell behind every ray's last kept wall. Returns ``(rays, data, ok, last,
        more)``: ``(SEARCH_BATCH,)`` int32 their rays, ``(SEARCH_BATCH, C + 2)`` their rows (``C`` columns) with the
        cell's position along the ray and ``log p(y | d)`` there, ``(SEARCH_BATCH,)`` bool which entries hold a lane
        (the first ones, in lane order), the last lane taken and whether changed lanes remain after it. The lanes'
        rows are those before the rewrite (the rows of later lanes are not rewritten yet: a ray crosses a cell once).
        The only part of a rewrite whose shapes depend on the group's width (:meth:`_sweep`)."""
        rays, positions, log_lik = lanes.rays[k], lanes.positions[k], lanes.log_lik[k]
        rows = rows_all[rays]
        width = rays.shape[0]
        batch = min(width, SEARCH_BATCH)
        q = positions.astype(rows.dtype)
        walls_at = [rows[:, c] for c in range(3 if self._penetrable else 2)]  # the kept walls
        is_kept = jnp.any(jnp.stack([q == w for w in walls_at]), axis=0)
        lane_ids = jnp.arange(width, dtype=jnp.int32)
        changed = (rays < self._num_rays) & (lane_ids > done) & jnp.where(new, (q < walls_at[-1]) & ~is_kept, is_kept)
        rank = jnp.where(changed, (width - lane_ids).astype(jnp.float32), 0.0)  # largest for the first changed lane
        got, lane = jax.lax.top_k(rank, batch)
        ok = got > 0
        num = jnp.sum(ok, dtype=jnp.int32)
        lane = jnp.where(ok, lane, 0)
        data = jnp.concatenate([rows[lane], q[lane, None], log_lik[lane, None]], axis=1)
        pad = SEARCH_BATCH - batch
        return (jnp.pad(rays[lane], (0, pad)), jnp.pad(data, ((0, pad), (0, 0))), jnp.pad(ok, (0, pad)),
                lane[jnp.maximum(num - 1, 0)], jnp.sum(changed, dtype=jnp.int32) > num)

    def _no_changed_lanes(self, rows_all):
        """What :meth:`_changed_lanes` returns when no lane changes."""
        return (jnp.zeros(SEARCH_BATCH, jnp.int32), jnp.zeros((SEARCH_BATCH, rows_all.shape[1] + 2), rows_all.dtype),
                jnp.zeros(SEARCH_BATCH, bool), jnp.int32(-1), jnp.bool_(False))

    def _write_rows(self, rays, data, ok, new, cur, rows_all):
        """``rows_all`` with the rows of ``rays`` (the entries with ``ok``, from :meth:`_changed_lanes`) rewritten
        for their cell now ``new`` (``cur``, the map in visiting order, already has it): the cell joins the kept walls
        or leaves them, and a ray that loses one gets the next wall after its last kept one by a walk (:meth:`_walk`).
        One write per row: XLA's CPU scatter runs as a loop over all its indices."""
        kept = 3 if self._penetrable else 2  # walls a row keeps
        at, ll_at = data[:, :kept], data[:, kept:2 * kept]  # the kept walls' positions and log-likelihoods
        p, ll = data[:, -2], data[:, -1]

        def row(pos, lls):  # a row from its walls' positions and log-likelihoods (and the no-wall one, kept)
            if not self._penetrable:
                return jnp.stack(pos + lls, axis=1)
            none = data[:, 2 * kept]
            return jnp.stack(pos + lls + [none] + self._ray_mixtures(*lls, none), axis=1)

        def added():  # the cell joins the kept walls in order; the last one drops out
            pos, lls = [], []
            for c in range(kept):
                before = p < at[:, c]
                prev = p < at[:, c - 1] if c else jnp.zeros_like(before)
                pos.append(jnp.where(prev, at[:, c - 1] if c else p, jnp.where(before, p, at[:, c])))
                lls.append(jnp.where(prev, ll_at[:, c - 1] if c else ll, jnp.where(before, ll, ll_at[:, c])))
            return row(pos, lls)

        def removed():  # the walls after the cell move up one; the new last is the next wall after the old last
            nxt = self._walk(rays, at[:, -1], ok, cur)
            nxt_ll = self._pair_log_lik(rays, nxt)
            pos, lls = [], []
            for c in range(kept):
                gone = p <= at[:, c]  # the cell is this wall or one before it: shift up
                up, up_ll = (at[:, c + 1], ll_at[:, c + 1]) if c + 1 < kept else (nxt, nxt_ll)
                pos.append(jnp.where(gone, up, at[:, c]))
                lls.append(jnp.where(gone, up_ll, ll_at[:, c]))
            return row(pos, lls)

        rows_new = jax.lax.cond(new, added, removed)

        def put(t, rows_all):
            return jax.lax.dynamic_update_slice(rows_all, jax.lax.dynamic_slice_in_dim(rows_new, t, 1), (rays[t], 0))

        return jax.lax.fori_loop(0, jnp.sum(ok, dtype=jnp.int32), put, rows_all)

    def _block_size(self, lanes) -> int:
        """Cells of a width group scored at once: ``SPECULATIVE_CELLS`` or ``SPECULATIVE_LANES // width``, if more,
        and at most the group's rows."""
        n, width = lanes.rays.shape
        return min(max(SPECULATIVE_CELLS, SPECULATIVE_LANES // width), n)

    def _score_block(self, lanes, base, i, cur, rows_all, probs_size: int, u):
        """One block of a group's sweep: from row ``i`` of ``lanes``, :meth:`_block_size` cells scored at once from
        the same rows, drawn, and kept up to the first draw that changes a row (see the module docstring). ``cur``
        and ``u``: the map and the uniforms in visiting order, the group's cells at ``base, base + 1, ...``.
        Returns ``(i, start, keep, value, prob, rewrite, k, new)``: the next row to visit; from the place ``start``
        in visiting order on, ``(probs_size,)`` which places take their draw (the block's cells up to the stop;
        the entries after the block's: none), the draws and their conditional probabilities (float32); and whether
        cell ``k`` (a row), drawn ``new``, changes rows (:meth:`_changed_lanes`). Small arrays only: the caller
        writes the map, so that the loop updates it in place."""
        size = self._block_size(lanes)
        j = jnp.arange(size, dtype=jnp.int32)
        count = lanes.count
        # the block: cells s .. s + size - 1 of the group, those before i done, those from count on not visited
        s = jnp.maximum(jnp.minimum(i, count - size), 0)
        end = jnp.minimum(s + size, count)
        rays, positions, log_lik = (jax.lax.dynamic_slice_in_dim(a, s, size)
                                    for a in (lanes.rays, lanes.positions, lanes.log_lik))
        score, can_add, can_remove = self._score(rows_all[rays], positions, log_lik)
        log_odds = self._prior_log_odds + score
        if lanes.neighbours is not None:  # the structured prior: J (n_wall - n_free), from the current map
            neighbours = jax.lax.dynamic_slice_in_dim(lanes.neighbours, s, size)  # (size, 4) visiting places
            log_odds = log_odds + self._coupling * jnp.sum(2.0 * cur[neighbours] - 1.0, axis=-1)
            # a cell with a neighbour later among these: its change makes the later score stale
            later = jnp.any((neighbours > base + s + j[:, None]) & (neighbours < base + end), axis=-1)
        prob = jax.nn.sigmoid(log_odds)
        old = jax.lax.dynamic_slice_in_dim(cur, base + s, size) > 0
        new = jax.lax.dynamic_slice_in_dim(u, base + s, size) < prob
        changes = jnp.where(new, can_add, can_remove)
        if lanes.neighbours is not None:
            changes = changes | later
        live = (j >= i - s) & (s + j < end)
        rewrites = live & (new != old) & changes
        stop = jnp.where(jnp.any(rewrites), jnp.argmax(rewrites), size)  # the first cell that changes rows
        keep = live & (j <= stop)
        rewrite = stop < size
        if lanes.neighbours is not None:  # a stop for a neighbour only: rows change only if the cell's rows do
            rewrite = rewrite & jnp.any((j == stop) & jnp.where(new, can_add, can_remove))
        pad = probs_size - size
        return (s + jnp.minimum(stop + 1, size), base + s, jnp.pad(keep, (0, pad)), jnp.pad(new, (0, pad)),
                jnp.pad(prob.astype(jnp.float32), (0, pad)), rewrite, s + jnp.minimum(stop, size - 1),
                jnp.any(new & (j == stop)))

    def _sweep(self, cur, rows_all, probs, u):
        """Every width group's cells (the rows ``0 .. lanes.count - 1`` of each) once, in order, in one loop: each
        step scores a block of the current group (:meth:`_score_block`) or goes on rewriting the rows of the cell that
        stopped the last block, ``SEARCH_BATCH`` rays at a time (:meth:`_changed_lanes`, :meth:`_write_rows`). The
        width-dependent parts are the branches of one ``lax.switch`` on the group, which return small arrays only;
        the rewrite, the largest part of the loop, is traced once for all groups, so that the compile time grows
        with the number of groups only by their scoring. ``cur``, ``probs`` and ``u`` are in visiting order
        (:meth:`step`)."""
        groups, bases, base = [], [], 0
        for lanes in self._lanes:
            if lanes.rays.shape[0]:
                groups.append(lanes)
                bases.append(base)
            base += lanes.cells.shape[0]
        if not groups:
            return cur, rows_all, probs
        counts = jnp.stack([lanes.count for lanes in groups])
        size = max(self._block_size(lanes) for lanes in groups)
        length = cur.shape[0]  # a block's writes start at most ``size`` before the groups' end: pad, never clamp
        cur, probs, u = (jnp.pad(a, (0, size)) for a in (cur, probs, u))

        def branch(lanes, base):
            def run(operand):
                i, k, new, done, pending, cur, rows_all = operand

                def resume():
                    return (i, jnp.int32(0), jnp.zeros(size, bool), jnp.zeros(size, bool), jnp.zeros(size, jnp.float32),
                            jnp.bool_(True), k, new)

                i, start, keep, value, prob, active, k, new = jax.lax.cond(
                    pending, resume, lambda: self._score_block(lanes, base, i, cur, rows_all, size, u))
                done = jnp.where(pending, done, -1)
                batch = jax.lax.cond(active, lambda: self._changed_lanes(lanes, k, new, done, rows_all),
                                     lambda: self._no_changed_lanes(rows_all))
                return (i, k, new, start, keep, value, prob) + batch

            return run

        branches = [branch(lanes, base) for lanes, base in zip(groups, bases)]

        def body(carry):
            g, i, cur, rows_all, probs, k, new, done, pending = carry
            i, k, new, start, keep, value, prob, rays, data, ok, done, more = jax.lax.switch(
                g, branches, (i, k, new, done, pending, cur, rows_all))
            old = jax.lax.dynamic_slice_in_dim(cur, start, size)
            cur = jax.lax.dynamic_update_slice_in_dim(cur, jnp.where(keep, value.astype(cur.dtype), old), start, 0)
            old = jax.lax.dynamic_slice_in_dim(probs, start, size)
            probs = jax.lax.dynamic_update_slice_in_dim(probs, jnp.where(keep, prob, old), start, 0)
            rows_all = jax.lax.cond(jnp.any(ok), lambda r: self._write_rows(rays, data, ok, new, cur, r),
                                    lambda r: r, rows_all)  # after writing cur: the walk reads the new map
            next_group = (i >= counts[g]) & ~more
            return (jnp.where(next_group, g + 1, g), jnp.where(next_group, 0, i), cur, rows_all, probs, k, new,
                    done, more)

        start = (jnp.int32(0), jnp.int32(0), cur, rows_all, probs, jnp.int32(0), jnp.bool_(False), jnp.int32(-1),
                 jnp.bool_(False))
        _, _, cur, rows_all, probs, *_ = jax.lax.while_loop(lambda c: c[0] < len(groups), body, start)
        return cur[:length], rows_all, probs[:length]

    def step(self, key, state: CellwiseState) -> tuple[CellwiseState, GibbsInfo]:
        """One sweep: every cell once, in the order of the module docstring. Returns the new state and
        ``GibbsInfo(wall_prob)``, ``(nx, ny)`` float32, the conditional wall probability each cell was drawn with
        (the prior for cells no ray crosses)."""
        walls = state.walls.reshape(-1)
        u = jax.random.uniform(key, walls.shape)
        prior = jax.nn.sigmoid(self._prior_log_odds)
        # the visiting order: the groups' cells, then (with the structured prior) those no ray crosses and the frozen
        # ones (kept, read by the walks along the rays and as neighbours)
        cur, u_order = walls[self._order], u[self._order]
        if self._coupling is not None:  # the slot outside-the-grid neighbours read: 2 * 0.5 - 1 = 0
            cur = jnp.append(cur, jnp.asarray(0.5, cur.dtype))
        probs = jnp.zeros(self._order.shape, jnp.float32)
        cur, rows, probs = self._sweep(cur, state.ray_walls, probs, u_order)
        if self._coupling is None:
            walls = jnp.where(self._free, (u < prior).astype(walls.dtype), cur[self._rank])
            wall_prob = jnp.where(self._free, prior.astype(jnp.float32), probs[self._rank])
        else:  # the cells no ray crosses: one checkerboard colour at a time, each given its neighbours
            walls, wall_prob = cur[self._rank], probs[self._rank]
            nx, ny = self._shape
            even = jnp.asarray((np.add.outer(np.arange(nx), np.arange(ny)) % 2 == 0).reshape(-1))
            for colour in (even, ~even):
                mask = self._free & colour
                field = neighbour_field(walls.reshape(self._shape)).reshape(-1).astype(self._coupling.dtype)
                p = jax.nn.sigmoid(self._prior_log_odds + self._coupling * field)
                walls = jnp.where(mask, (u < p).astype(walls.dtype), walls)
                wall_prob = jnp.where(mask, p.astype(jnp.float32), wall_prob)
        if self._frozen is not None:  # a frozen cell reports the value it keeps
            wall_prob = jnp.where(self._frozen, walls.astype(jnp.float32), wall_prob)
        state = CellwiseState(walls=walls.reshape(self._shape), ray_walls=rows)
        return state, GibbsInfo(wall_prob=wall_prob.reshape(self._shape))

    def focus(self, cells) -> CellwiseKernel:
        """Reorder this kernel's cells, in place, so that within each width group those in ``cells`` (``(nx, ny)``
        bool) come first, in their order, then the others, in theirs; return the kernel that visits only those of
        ``cells`` (the others keep their values: a Gibbs update of those cells given the rest). Both hold the same
        arrays and shapes, so that they share one compiled sweep (:func:`bayesmap.inference.focus.focused_chain`
        alternates them). In place, a group at a time, so that the lanes are never held twice: this kernel's sweep
        then visits the cells in the new order, which is as valid a sweep as any fixed order, with the same
        conditionals (:meth:`cell_log_odds`) and per-ray rows (a state of the kernel stays one of both)."""
        cells = np.asarray(cells, bool).reshape(-1)
        order = np.asarray(self._order).copy()
        rank = np.asarray(self._rank).copy()
        place_map = np.arange(len(order) + 1, dtype=np.int32)  # old place -> new place (the last: outside the grid)
        moved, counts, base = [], [], 0
        for lanes in self._lanes:
            n, count = lanes.rays.shape[0], int(lanes.count)
            first = cells[order[base:base + count]]
            perm = np.concatenate([np.flatnonzero(first), np.flatnonzero(~first), np.arange(count, n)])
            place_map[base + perm] = base + np.arange(n, dtype=np.int32)
            order[base:base + n] = order[base + perm]
            rank[order[base:base + count]] = np.arange(base, base + count, dtype=rank.dtype)
            moved.append(perm)
            counts.append(int(first.sum()))
            base += n
        for g, perm in enumerate(moved):  # in numpy, one array at a time (its old copy freed before the next)
            for name in ("cells", "rays", "positions", "log_lik", "neighbours"):
                if getattr(self._lanes[g], name) is not None:
                    new = np.asarray(getattr(self._lanes[g], name))[perm]
                    new = jnp.asarray(place_map[new] if name == "neighbours" else new)
                    self._lanes = self._lanes[:g] + (self._lanes[g]._replace(**{name: new}),) + self._lanes[g + 1:]
                    del new
        release_freed_memory()
        self._order, self._rank = jnp.asarray(order), jnp.asarray(rank)
        fields = {name: getattr(self, name) for name in self._ARRAYS + self._STATIC}
        fields["_lanes"] = tuple(lanes._replace(count=jnp.asarray(count, jnp.int32))
                                 for lanes, count in zip(self._lanes, counts))
        return CellwiseKernel(**fields)

    def cell_log_odds(self, walls) -> jax.Array:
        """Every cell's conditional log-odds given the rest of ``walls`` ``(nx, ny)``: ``(nx, ny)``, computed with
        the sweep's own scoring (each cell alone, from the rows of ``walls``)."""
        rows_all = self.ray_walls(walls)
        out = jnp.full(self._shape[0] * self._shape[1], self._prior_log_odds, rows_all.dtype)
        if self._coupling is not None:
            out = out + self._coupling * neighbour_field(jnp.asarray(walls)).reshape(-1).astype(rows_all.dtype)
        for lanes in self._lanes:
            scores = self._score(rows_all[lanes.rays], lanes.positions, lanes.log_lik)[0]
            out = out.at[lanes.cells].add(scores)
        return out.reshape(self._shape)


@jax.jit
def _ray_walls(kernel: CellwiseKernel, walls):
    return kernel.ray_walls(walls)


@jax.jit
def _cell_log_odds(kernel: CellwiseKernel, walls):
    return kernel.cell_log_odds(walls)


class CellwiseGibbs(KernelSampler):
    """Single-site Gibbs for large problems (whole logs): see the module docstring.

    Args:
        table: the ray-cell table (its rays in the order of ``readings``; any number of scans).
        readings: ``(R,)`` ranges, meters, max-range readings equal to the max distance.
        params: model parameters (``prior_wall_prob``, the structured prior's ``coupling`` and the sensor model; for
            ``"beam"`` the table's max distance must be the model's max range ``params.max_range``).
        likelihood_power: ``eta`` in (0, 1]: sample ``p(walls) p(readings | walls) ** eta``
            (every log-likelihood the sweep looks up times ``eta``: :func:`bayesmap.model.likelihood.tempered`; with
            ``params.wall_pass_prob > 0`` every beam's mixture times ``eta``); 1, the posterior, by default.
        frozen: ``(nx, ny)`` bool, cells a sweep keeps as they are (the rest of the map, fixed, while a tile of it
            is sampled: :mod:`bayesmap.inference.tiled`); their rays' rows still read them. The sweep is then the
            Gibbs sweep of the other cells given these; ``info.wall_prob`` reports a frozen cell's value. None: none.
        shapes: pad the sweep's arrays at least to these sizes (:class:`SweepShapes`; :func:`fitted_shapes`), for
            example a previous kernel's ``kernel.shapes``: a table that fits them reuses that kernel's compiled
            sweep. Padding changes no draw: the padding cells' lanes add nothing and no cell reads them. None: none.
        headroom: a size that is not given by ``shapes`` or does not fit it is padded by this fraction (rounded up
            to a multiple of 8), so that the next, similar table fits (:func:`fitted_shapes`), >= 0; 0: exactly.

    Attributes:
        kernel: the :class:`CellwiseKernel`.
        algorithm: the :class:`SamplingAlgorithm` (``init``, ``step``), partials of the kernel
            (:attr:`bayesmap.inference.base.KernelSampler.algorithm`).

    Raises:
        BayesmapError: on readings that do not match the table's rays, a table whose max distance is not the beam
            model's max range, a bad ``likelihood_power``, a cell crossed by more than 65,536 rays, ``frozen`` of
            another shape than the grid's, or a bad ``headroom``.
    """

    def __init__(self, table: RayTable, readings, params: ModelParams, likelihood_power: float = 1.0,
                 frozen=None, shapes: SweepShapes | None = None, headroom: float = 0.0):
        inputs = likelihood_inputs(table, readings, params, likelihood_power, passable=True)
        y, beam_model, sensor, dtype, eta = inputs[:5]
        num_rays, num_pairs = table.num_rays, table.num_pairs
        # dispatched first: XLA computes the log-likelihoods while numpy sorts the pairs into the lanes
        max_ll = no_wall_log_likelihoods(inputs, table.max_distance)
        pair_ll = pair_log_likelihoods(table, y, beam_model, sensor, inputs.geometry)
        penetrable = params.penetrable
        if eta != 1.0 and not penetrable:  # every log-likelihood the sweep looks up, tempered (eta = 1 leaves them)
            pair_ll, max_ll = tempered(pair_ll, eta), tempered(max_ll, eta)
        counts = table.rays_per_cell()
        frozen_cells = None
        if frozen is not None:
            frozen = np.asarray(frozen, dtype=bool)
            if frozen.shape != tuple(table.grid.shape):
                raise BayesmapError(f"frozen must have the grid's shape {tuple(table.grid.shape)}, got {frozen.shape}")
            frozen = frozen.reshape(-1)
            frozen_cells = np.flatnonzero(frozen)
            counts = np.where(frozen, 0, counts)  # visited: the cells that are not frozen
        structured = params.structured
        groups = width_groups(counts)
        free = counts == 0 if frozen is None else (counts == 0) & ~frozen
        if structured:  # checkerboard colours one after the other in each group, every cell ranked (docstring)
            groups = checkerboard_groups(groups, table.grid.shape)
        # after the groups: the cells no ray crosses (structured prior), then the frozen cells
        rest = [np.flatnonzero(free)] if structured else []
        rest += [] if frozen_cells is None else [frozen_cells]
        rest = np.concatenate(rest) if rest else np.zeros(0, np.int64)
        needed = SweepShapes(groups=tuple((width, len(cells)) for width, cells in groups), rest=len(rest),
                             rays=num_rays, pairs=num_pairs)
        sizes = fitted_shapes(needed, shapes, headroom)
        real = dict(groups)  # and a group of no cells for each width only ``shapes`` has
        groups = [(width, real.get(width, np.zeros(0, np.int64))) for width, _ in sizes.groups]
        parts = [cells for _, cells in groups] + [rest]
        order, rank = _visiting_order(parts, [n for _, n in sizes.groups] + [sizes.rest], table.num_cells)
        lanes = _lanes(table, counts, groups, rank, pair_ll, dtype, sizes)
        if structured:
            places = np.append(rank, len(order)).astype(np.int32)  # -1 (outside) -> the 0.5 slot
            lanes = tuple(part._replace(neighbours=jnp.asarray(places[neighbour_indices(table.grid.shape)[
                np.asarray(part.cells)]])) for part in lanes)
            lanes = tuple(part._replace(neighbours=part.neighbours.at[len(cells):].set(len(order)))
                          for part, cells in zip(lanes, parts))  # padding cells: only the 0.5 slot
        padded_rays, padded_pairs = sizes.rays - num_rays, sizes.pairs - num_pairs
        self.kernel = CellwiseKernel(
            _lanes=lanes, _free=jnp.asarray(free), _rank=jnp.asarray(rank), _order=jnp.asarray(order),
            _frozen=None if frozen is None else jnp.asarray(frozen),
            _pair_cells=jnp.asarray(np.append(table.pair_cells, np.zeros(padded_pairs + 1, table.pair_cells.dtype)),
                                    jnp.int32),
            _pair_ll=jnp.asarray(np.append(np.asarray(pair_ll)[:num_pairs], np.zeros(padded_pairs + 1, dtype))),
            _ray_start=jnp.asarray(np.append(table.offsets[:-1], np.full(padded_rays + 1, sizes.pairs)), jnp.int32),
            _ray_length=jnp.asarray(np.append(table.lengths, np.zeros(padded_rays + 1)), jnp.int32),
            _max_ll=jnp.asarray(np.append(np.asarray(max_ll)[:num_rays], np.zeros(padded_rays + 1)), dtype),
            _prior_log_odds=jnp.asarray(prior_log_odds(params.prior_wall_prob), dtype),
            _coupling=jnp.asarray(params.coupling, dtype) if structured else None,
            _eta=jnp.asarray(eta, dtype) if penetrable else None,
            _pass_weights=pass_log_weights(params.wall_pass_prob).astype(dtype) if penetrable else None,
            _shape=tuple(table.grid.shape), _num_rays=sizes.rays, _num_pairs=sizes.pairs, _penetrable=penetrable)

    def ray_walls(self, walls) -> jax.Array:
        """See :meth:`CellwiseKernel.ray_walls`."""
        return self.kernel.ray_walls(walls)

    def cell_log_odds(self, walls) -> jax.Array:
        """See :meth:`CellwiseKernel.cell_log_odds` (compiled: kernels of the same static metadata share it)."""
        return _cell_log_odds(self.kernel, jnp.asarray(walls))


def cellwise_gibbs(table: RayTable, readings, params: ModelParams, likelihood_power: float = 1.0,
                   frozen=None, shapes: SweepShapes | None = None, headroom: float = 0.0) -> SamplingAlgorithm:
    """The :class:`CellwiseGibbs` sampler's :class:`SamplingAlgorithm`."""
    return CellwiseGibbs(table, readings, params, likelihood_power, frozen, shapes, headroom).algorithm
