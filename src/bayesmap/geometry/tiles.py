"""Tiles of an occupancy grid, and the ray-cell table of one tile with the rest of the map held fixed.

A whole log's ray-cell table (:mod:`bayesmap.geometry.raytable`) grows with the total length of its beams; a tile's
grows with the beams that cross the tile. :func:`split_tiles` cuts the grid into rectangles of at most a given number
of (beam, cell) pairs, and :func:`tile_table` builds the table that the cellwise sampler
(:mod:`bayesmap.inference.cellwise`) needs to draw one tile's cells from their exact conditionals given every other
cell of the map (:mod:`bayesmap.inference.tiled` runs the tiles one after another).

Why a tile's table is small and exact. A reading depends on its beam's first wall cells only: the first with walls
that stop every beam, the first two with wall cells a beam can pass (``ModelParams.wall_pass_prob > 0``), and the
cellwise sampler keeps one more in its state to find the next when one is cleared (``kept`` below: 2, or 3). With
the cells outside the tile fixed, a beam's outside walls beyond its ``kept``-th outside wall can never be among its
first ``kept`` walls, whatever the tile's cells are, and its outside free cells never matter. So a tile's table keeps,
for each beam that crosses the tile, the beam's pairs inside the tile and its first ``kept`` outside wall cells (at
their true cells and distances), in order along the beam; a beam whose first ``kept - 1`` walls lie before it enters
the tile cannot be changed by the tile and is left out. The sampler keeps the outside cells frozen
(``CellwiseGibbs(..., frozen=...)``), so each tile cell is drawn from exactly the conditional it has in the whole
table (tested against the whole table's conditionals in ``tests/inference/test_tiled.py``).

Memory: a tile's table is built a chunk of beams at a time (:data:`TRACE_SLOTS` traced pairs, about 150 bytes each),
each chunk cut to the tile before the next is traced, so the peak is the tile's pairs plus one chunk.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import RayTable, build_ray_table

TRACE_SLOTS = 1 << 22
"""About how many (beam, cell) pairs are traced at once when counting a log's pairs or building a tile's table
(whole beams; about 150 bytes of temporaries each, so about 0.6 GB): bounds the memory these take, not what they
compute."""


@dataclass(frozen=True)
class Tile:
    """A rectangle of cells ``i0 <= i < i1``, ``j0 <= j < j1`` (``i`` along x, ``j`` along y) and its pairs.

    Attributes:
        i0, i1, j0, j1: the cell bounds (ints, half-open).
        pairs: how many (beam, cell) pairs of the log lie in the tile (its cells' counts; the table
            :func:`tile_table` builds also lists up to ``kept`` outside wall cells per beam).
    """

    i0: int
    i1: int
    j0: int
    j1: int
    pairs: int = 0

    @property
    def num_cells(self) -> int:
        return (self.i1 - self.i0) * (self.j1 - self.j0)

    def mask(self, shape: tuple[int, int]) -> np.ndarray:
        """``shape`` bool, True on the tile's cells."""
        out = np.zeros(shape, dtype=bool)
        out[self.i0:self.i1, self.j0:self.j1] = True
        return out


def ray_cells(grid, origins, beam_angles, max_distance) -> np.ndarray:
    """How many cells each beam crosses before it reaches ``max_distance`` or leaves ``grid``, estimated in closed
    form: ``L (|cos a| + |sin a|) / resolution + 2`` for the beam's length ``L`` inside the grid (one new cell per grid
    line crossed; Amanatides & Woo 1987, "A fast voxel traversal algorithm for ray tracing"). Within 1 % of the
    ray-cell table's pairs on the shared logs (an upper bound for a beam that starts inside the grid).

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid` (meters).
        origins: ``(R, 2)`` or ``(2,)`` float sensor positions, meters.
        beam_angles: ``(R,)`` float world-frame beam angles, radians.
        max_distance: meters, one for all beams or ``(R,)`` each beam's (a beam cut past its reading,
            :func:`bayesmap.model.generative.ray_limits`).

    Returns:
        ``(R,)`` float64 cells per beam.
    """
    angles = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64).reshape(-1, 2), (len(angles), 2))
    cos, sin = np.cos(angles), np.sin(angles)
    x0, x1, y0, y1 = grid.extent
    with np.errstate(divide="ignore", invalid="ignore"):  # a beam along an axis never meets the other axis' sides
        exit_x = np.where(cos > 0, (x1 - origins[:, 0]) / cos, np.where(cos < 0, (x0 - origins[:, 0]) / cos, np.inf))
        exit_y = np.where(sin > 0, (y1 - origins[:, 1]) / sin, np.where(sin < 0, (y0 - origins[:, 1]) / sin, np.inf))
    length = np.clip(np.minimum(np.minimum(exit_x, exit_y), max_distance), 0.0, None)
    return length * (np.abs(cos) + np.abs(sin)) / grid.resolution + 2.0



def _chunks(grid: Grid, origins: np.ndarray, angles: np.ndarray, lengths: np.ndarray, slots: int, step: int = 1):
    """Slices of consecutive rays of about ``slots`` traced cells each (:func:`ray_cells`), each starting at a
    multiple of ``step`` rays (at least ``step`` rays each, but for the last)."""
    ends = np.cumsum(ray_cells(grid, origins, angles, lengths))
    start = 0
    while start < len(angles):
        stop = int(np.searchsorted(ends, (ends[start - 1] if start else 0.0) + slots, side="right"))
        stop = max(stop - stop % step, start + step)
        yield slice(start, min(stop, len(angles)))
        start = stop


def _lengths(num_rays: int, max_distance: float, ray_limits) -> np.ndarray:
    return np.full(num_rays, float(max_distance)) if ray_limits is None else np.asarray(ray_limits, np.float64)


def _chunk_table(grid, origins, angles, max_distance, ray_limits, part) -> RayTable:
    limits = None if ray_limits is None else np.asarray(ray_limits)[part]
    return build_ray_table(grid, origins[part], angles[part], max_distance, ray_limits=limits)


def table_chunks(grid: Grid, origins, beam_angles, max_distance: float, ray_limits=None, slots: int = TRACE_SLOTS,
                 step: int = 1):
    """The ray-cell table :func:`~bayesmap.geometry.raytable.build_ray_table` would build for these rays (same
    arguments, meters and radians), a piece at a time: yields ``(rays, table)``, a slice of consecutive rays of about
    ``slots`` traced pairs (:func:`ray_cells`) and their table, so that a sum over the rays (a log-likelihood, a
    count per cell) needs the memory of one piece, not of the whole table. Each piece starts at a multiple of
    ``step`` rays (``step`` the beams of a scan: whole scans, as log-odds mapping's per-scan update needs).

    Raises:
        BayesmapError: as :func:`~bayesmap.geometry.raytable.build_ray_table`.
    """
    angles = np.asarray(beam_angles, np.float64).reshape(-1)
    origins = np.broadcast_to(np.asarray(origins, np.float64), (len(angles), 2))
    for part in _chunks(grid, origins, angles, _lengths(len(angles), max_distance, ray_limits), slots, step):
        yield part, _chunk_table(grid, origins, angles, max_distance, ray_limits, part)


def rays_per_cell(grid: Grid, origins, beam_angles, max_distance: float, ray_limits=None,
                  slots: int = TRACE_SLOTS) -> np.ndarray:
    """``(nx, ny)`` int64: how many rays cross each cell, the table :func:`~bayesmap.geometry.raytable.build_ray_table`
    would build for these rays (same arguments, meters and radians) counted a chunk of about ``slots`` traced pairs
    at a time, without holding it (its sum is the table's number of pairs).

    Raises:
        BayesmapError: as :func:`~bayesmap.geometry.raytable.build_ray_table`.
    """
    counts = np.zeros(grid.num_cells, dtype=np.int64)
    for _, table in table_chunks(grid, origins, beam_angles, max_distance, ray_limits, slots):
        counts += table.rays_per_cell()
    return counts.reshape(grid.shape)


def split_tiles(counts, max_pairs: int) -> list[Tile]:
    """The grid cut into rectangles of at most ``max_pairs`` pairs each: ``counts`` ``(nx, ny)`` (rays per cell,
    :func:`rays_per_cell`) is halved recursively along its longer side at the place that best balances the two
    halves' pairs (a k-d split), until every tile holds at most ``max_pairs`` or is one cell wide and long. Tiles
    come in the order of the recursion (the lower half first); together they cover the grid once.

    Raises:
        ValueError: if ``max_pairs`` is not positive.
    """
    if max_pairs <= 0:
        raise ValueError(f"max_pairs must be > 0, got {max_pairs!r}")
    counts = np.asarray(counts, np.int64)
    integral = np.zeros((counts.shape[0] + 1, counts.shape[1] + 1), dtype=np.int64)
    integral[1:, 1:] = counts.cumsum(0).cumsum(1)

    def total(i0, i1, j0, j1):
        return int(integral[i1, j1] - integral[i0, j1] - integral[i1, j0] + integral[i0, j0])

    out, stack = [], [(0, counts.shape[0], 0, counts.shape[1])]
    while stack:
        i0, i1, j0, j1 = stack.pop()
        pairs = total(i0, i1, j0, j1)
        if pairs <= max_pairs or (i1 - i0 == 1 and j1 - j0 == 1):
            out.append(Tile(i0, i1, j0, j1, pairs))
            continue
        along_i = (i1 - i0) >= (j1 - j0)
        lo, hi = (i0, i1) if along_i else (j0, j1)
        cuts = np.arange(lo + 1, hi)
        if along_i:
            below = integral[cuts, j1] - integral[cuts, j0] - integral[i0, j1] + integral[i0, j0]
        else:
            below = integral[i1, cuts] - integral[i0, cuts] - integral[i1, j0] + integral[i0, j0]
        cut = int(cuts[np.argmin(np.abs(2 * below - pairs))])
        halves = [(i0, cut, j0, j1), (cut, i1, j0, j1)] if along_i else [(i0, i1, j0, cut), (i0, i1, cut, j1)]
        stack.extend(reversed(halves))
    return out


def crossing_rays(grid: Grid, origins, beam_angles, lengths, tile: Tile) -> np.ndarray:
    """``(M,)`` int64 indices of the rays whose segment from the origin to ``lengths`` (meters) meets ``tile``'s
    rectangle, grown by a thousandth of a cell (a slab test, Kay & Kajiya 1986; a ray that only grazes the rectangle
    may be listed: its table rows are then empty and :func:`tile_table` leaves it out)."""
    origins = np.asarray(origins, np.float64).reshape(-1, 2)
    angles = np.asarray(beam_angles, np.float64).reshape(-1)
    lengths = np.asarray(lengths, np.float64).reshape(-1)
    res, (ox, oy) = grid.resolution, grid.origin
    pad = 1e-3 * res
    lows = np.array([ox + tile.i0 * res - pad, oy + tile.j0 * res - pad])
    highs = np.array([ox + tile.i1 * res + pad, oy + tile.j1 * res + pad])
    direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    enter, leave = np.zeros(len(angles)), lengths.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(2):
            d, o = direction[:, axis], origins[:, axis]
            flat = np.abs(d) < 1e-12
            t0, t1 = (lows[axis] - o) / d, (highs[axis] - o) / d
            near, far = np.minimum(t0, t1), np.maximum(t0, t1)
            inside = (o >= lows[axis]) & (o <= highs[axis])
            near = np.where(flat, np.where(inside, -np.inf, np.inf), near)
            far = np.where(flat, np.where(inside, np.inf, -np.inf), far)
            enter, leave = np.maximum(enter, near), np.minimum(leave, far)
    return np.flatnonzero(enter <= leave)


def _cut_to_tile(table: RayTable, tile: Tile, walls_flat: np.ndarray, kept: int):
    """The rows of ``table`` cut to ``tile`` (module docstring): ``(rays, counts, keep)``, the relevant rays of
    ``table`` (indices into it), their numbers of kept pairs, and the ``(P,)`` bool pairs kept."""
    ny = table.grid.shape[1]
    cells = table.pair_cells
    i, j = np.divmod(cells, ny)
    inside = (i >= tile.i0) & (i < tile.i1) & (j >= tile.j0) & (j < tile.j1)
    wall = (walls_flat[cells] > 0) & ~inside
    starts = table.per_pair(table.offsets[:-1])
    walls_before = np.concatenate([[0], np.cumsum(wall)])  # outside walls before each pair, in the whole table
    rank = walls_before[:-1] - walls_before[starts]  # ... and along its own ray
    seen_inside = np.concatenate([[0], np.cumsum(inside)])
    first_inside = inside & (seen_inside[:-1] == seen_inside[starts])  # the ray's first pair inside the tile
    relevant = np.zeros(table.num_rays, dtype=bool)
    rays_in = table.pair_rays[first_inside]
    relevant[rays_in] = rank[first_inside] < kept - 1  # fewer than kept - 1 walls before the tile
    keep = (inside | (wall & (rank < kept))) & table.per_pair(relevant)
    kept_before = np.concatenate([[0], np.cumsum(keep)])
    counts = kept_before[table.offsets[1:]] - kept_before[table.offsets[:-1]]
    rays = np.flatnonzero(relevant)
    return rays, counts[rays], keep


def tile_table(grid: Grid, origins, beam_angles, max_distance: float, ray_limits, walls, tile: Tile, kept: int,
               slots: int = TRACE_SLOTS) -> tuple[RayTable, np.ndarray]:
    """The ray-cell table of ``tile`` with the rest of ``walls`` fixed (module docstring).

    Args:
        grid: the grid.
        origins: ``(R, 2)`` sensor position of each ray, world meters.
        beam_angles: ``(R,)`` world-frame beam angles, radians.
        max_distance: the max distance, meters (as :func:`~bayesmap.geometry.raytable.build_ray_table`).
        ray_limits: ``(R,)`` each ray's own max distance, meters, or None.
        walls: ``(nx, ny)`` the map; its cells outside the tile are the ones held fixed.
        tile: the tile.
        kept: how many walls of a ray the sampler keeps: 2 (walls stop every beam) or 3 (a beam can pass a wall
            cell); see :class:`bayesmap.inference.cellwise.CellwiseState`.
        slots: about how many pairs to trace at once.

    Returns:
        ``(table, rays)``: a :class:`~bayesmap.geometry.raytable.RayTable` on ``grid`` whose rays are the rays
        ``rays`` ``(M,)`` int64 (ascending) of the input that the tile's cells can change, each with its pairs
        inside the tile and its first ``kept`` wall cells outside it, at their cells and distances, in order along
        the ray (positions along a ray count these pairs only).

    Raises:
        BayesmapError: as :func:`~bayesmap.geometry.raytable.build_ray_table`.
    """
    origins = np.broadcast_to(np.asarray(origins, np.float64), (len(np.ravel(beam_angles)), 2))
    angles = np.asarray(beam_angles, np.float64).reshape(-1)
    lengths = _lengths(len(angles), max_distance, ray_limits)
    crossing = crossing_rays(grid, origins, angles, lengths, tile)
    walls_flat = np.asarray(walls).reshape(-1)
    parts_rays, parts_counts, parts_cells, parts_dists = [], [], [], []
    limits = None if ray_limits is None else np.asarray(ray_limits)
    for part in _chunks(grid, origins[crossing], angles[crossing], lengths[crossing], slots):
        chosen = crossing[part]
        table = _chunk_table(grid, origins, angles, max_distance, limits, chosen)
        rays, counts, keep = _cut_to_tile(table, tile, walls_flat, kept)
        parts_rays.append(chosen[rays])
        parts_counts.append(counts)
        parts_cells.append(table.pair_cells[keep])
        parts_dists.append(table.pair_dists[keep])
        del table
    rays = np.concatenate(parts_rays) if parts_rays else np.zeros(0, np.int64)
    counts = np.concatenate(parts_counts) if parts_counts else np.zeros(0, np.int64)
    offsets = np.zeros(len(rays) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    dtype = parts_dists[0].dtype if parts_dists else np.dtype(np.float32)
    table = RayTable(
        grid=grid,
        offsets=offsets,
        pair_cells=np.concatenate(parts_cells) if parts_cells else np.zeros(0, np.int32),
        pair_dists=np.concatenate(parts_dists) if parts_dists else np.zeros(0, dtype),
        origins=np.array(origins[rays]),
        beam_angles=angles[rays],
        max_distance=float(max_distance),
        ray_limits=None if limits is None else limits[rays].astype(dtype),
    )
    return table, rays
