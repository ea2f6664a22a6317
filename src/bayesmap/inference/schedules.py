"""Sweep schedules: the order of Gibbs updates, the k x k blocks, and how updates can run in parallel.

Orders (of cells or of block anchors):

* ``"raster"``: ``i`` then ``j``, the tutorial's nested loops.
* ``"outward"``: the tutorial's sensor-outward order: cells by increasing ``floor|i - px| + floor|j - py|``
  (sensor position in cell coordinates), raster order among equals.

Blocks: a k x k block is anchored at every cell ``(i, j)`` with ``i <= nx - k`` and ``j <= ny - k``, so blocks
overlap and every cell belongs to at least one block ("blocks at every offset"); a 1 x 1 block is single-site
Gibbs. ``k`` is clipped to the grid's shape.

Parallel execution (used by the fast samplers only; with the structured prior of :mod:`bayesmap.model.prior`,
blocks with cells that share an edge conflict too, ``neighbours`` below):

* :func:`dependency_levels` groups a sequence of block updates into levels. Two blocks *conflict* if they share
  a cell or a ray passes through both; the conditional of a block depends only on the cells of the rays through
  it, so non-conflicting updates commute. Each block goes one level above the last earlier block it conflicts
  with. Running the levels in order, all blocks of a level at once, is therefore the *same transition kernel*
  as the sequential sweep (same order for every conflicting pair).
* :func:`chromatic_levels` colours the conflict graph greedily (a block takes the smallest colour not used by a
  conflicting block); a sweep runs the colour classes in turn. This is a different systematic scan with the same
  conditionals: chromatic Gibbs (Gonzalez, Low, Gretton, Guestrin, "Parallel Gibbs Sampling: From Colored
  Fields to Thin Junction Trees", AISTATS 2011).
"""

from __future__ import annotations

import itertools

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid

ORDERS = ("raster", "outward")


def cell_order(grid: Grid, order: str = "raster", pos=None) -> np.ndarray:
    """Flat indices ``i * ny + j`` of all cells in the given order, ``(nx * ny,)`` int64.

    Args:
        grid: the grid.
        order: ``"raster"`` or ``"outward"``.
        pos: ``(2,)`` sensor position, world meters (needed for ``"outward"``).

    Raises:
        BayesmapError: on an unknown order, or ``"outward"`` without a position.
    """
    nx, ny = grid.shape
    if order == "raster":
        return np.arange(nx * ny)
    if order == "outward":
        if pos is None:
            raise BayesmapError("the sensor-outward order needs the sensor position")
        p = np.asarray(grid.to_cell_coords(np.asarray(pos, dtype=np.float64)), dtype=np.float64)
        i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        ring = np.floor(np.abs(i - p[0])) + np.floor(np.abs(j - p[1]))
        return np.argsort(ring.ravel(), kind="stable")
    raise BayesmapError(f"unknown order {order!r}; choose one of {', '.join(ORDERS)}")


def make_blocks(grid: Grid, block_size: int = 1, order: str = "raster", pos=None) -> np.ndarray:
    """The blocks of one sweep, in update order: ``(num_blocks, k*k)`` int64 flat cell indices.

    Block ``b`` is anchored at a cell ``(i, j)`` and holds cells ``(i + a, j + c)`` for ``a, c < k`` (row-major).
    Anchors are all ``(i, j)`` with ``i <= nx - k``, ``j <= ny - k``, visited in ``order`` (see
    :func:`cell_order`).

    Raises:
        BayesmapError: if ``block_size`` is not an integer >= 1, or on a bad order.
    """
    if int(block_size) != block_size or block_size < 1:
        raise BayesmapError(f"block size must be an integer >= 1, got {block_size!r}")
    nx, ny = grid.shape
    kx, ky = min(int(block_size), nx), min(int(block_size), ny)
    anchors = cell_order(grid, order, pos)
    ai, aj = anchors // ny, anchors % ny
    keep = (ai <= nx - kx) & (aj <= ny - ky)
    ai, aj = ai[keep], aj[keep]
    offsets = np.array(list(itertools.product(range(kx), range(ky))))
    return (ai[:, None] + offsets[None, :, 0]) * ny + (aj[:, None] + offsets[None, :, 1])


def block_configurations(block_cells: int) -> np.ndarray:
    """All ``2**block_cells`` 0/1 configurations of a block, ``(2**B, B)`` float32; row ``c`` is the binary
    expansion of ``c`` with cell 0 as the most significant bit (row 0 all free, last row all walls)."""
    return np.array(list(itertools.product([0.0, 1.0], repeat=block_cells)), dtype=np.float32)


def cell_rays(table) -> list[np.ndarray]:
    """For each cell, the sorted distinct rays of ``table`` (a :class:`~bayesmap.geometry.raytable.RayTable`) that
    cross it: a list of ``num_cells`` int64 arrays."""
    stride = max(table.num_rays, 1)
    key = np.unique(table.pair_cells.astype(np.int64) * stride + table.pair_rays)
    cells, rays = key // stride, key % stride
    bounds = np.searchsorted(cells, np.arange(table.num_cells + 1))
    return [rays[bounds[c] : bounds[c + 1]] for c in range(table.num_cells)]


def _pad_levels(level_of_block: np.ndarray, num_blocks: int) -> np.ndarray:
    num_levels = int(level_of_block.max()) + 1 if len(level_of_block) else 0
    order = np.argsort(level_of_block, kind="stable")
    counts = np.bincount(level_of_block, minlength=num_levels)
    width = max(int(counts.max()) if num_levels else 0, 1)
    out = np.full((num_levels, width), num_blocks, dtype=np.int32)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    sorted_levels = level_of_block[order]
    out[sorted_levels, np.arange(len(order)) - first[sorted_levels]] = order
    return out


def _near(cells: np.ndarray, neighbours) -> np.ndarray:
    """``cells`` and, with ``neighbours`` ``(N, 4)`` (the structured prior's), their 4-neighbours inside the grid."""
    if neighbours is None:
        return cells
    near = neighbours[cells].reshape(-1)
    return np.concatenate([cells, near[near >= 0]])


def dependency_levels(blocks: np.ndarray, table, neighbours=None) -> np.ndarray:
    """Group the sequential block updates ``blocks`` ``(NB, B)`` into levels of mutually non-conflicting blocks
    that preserve the order of every conflicting pair (see the module docstring).

    Args:
        blocks: ``(NB, B)`` flat cell indices, in sweep order.
        table: the scene's :class:`~bayesmap.geometry.raytable.RayTable`.
        neighbours: ``(N, 4)`` flat indices of each cell's 4-neighbours (``-1`` outside the grid,
            :func:`bayesmap.model.prior.neighbour_indices`) for the structured prior: blocks with neighbouring
            cells conflict too (each one's conditional reads the other's cells); None (the independent prior): not.

    Returns:
        ``(num_levels, width)`` int32 block indices; padding ``NB`` (no block). Within a level, blocks keep their
        sweep order.
    """
    rays_of = cell_rays(table)
    ray_last = np.full(table.num_rays, -1, dtype=np.int64)
    cell_last = np.full(table.num_cells, -1, dtype=np.int64)
    level = np.empty(len(blocks), dtype=np.int64)
    for b, cells in enumerate(blocks):
        rays = np.concatenate([rays_of[c] for c in cells])
        lv = max(int(cell_last[_near(cells, neighbours)].max()), int(ray_last[rays].max()) if len(rays) else -1) + 1
        level[b] = lv
        cell_last[cells] = lv
        ray_last[rays] = lv
    return _pad_levels(level, len(blocks))


def chromatic_levels(blocks: np.ndarray, table, neighbours=None) -> np.ndarray:
    """Greedy colouring of the block conflict graph (visiting blocks in the given order); returns the colour
    classes as ``(num_colours, width)`` int32 block indices, padding ``NB``. See the module docstring;
    ``neighbours`` as in :func:`dependency_levels`."""
    rays_of = cell_rays(table)
    ray_colours: list[set] = [set() for _ in range(table.num_rays)]
    cell_colours: list[set] = [set() for _ in range(table.num_cells)]
    colour = np.empty(len(blocks), dtype=np.int64)
    for b, cells in enumerate(blocks):
        rays = np.unique(np.concatenate([rays_of[c] for c in cells]))
        used = set().union(*(cell_colours[c] for c in _near(cells, neighbours)), *(ray_colours[r] for r in rays))
        c = 0
        while c in used:
            c += 1
        colour[b] = c
        for cell in cells:
            cell_colours[cell].add(c)
        for r in rays:
            ray_colours[r].add(c)
    return _pad_levels(colour, len(blocks))


def split_levels(levels: np.ndarray, cost: np.ndarray, capacity: int) -> np.ndarray:
    """Split levels so that none holds more than ``capacity`` blocks or more than ``capacity`` units of ``cost``
    (a block whose own cost exceeds ``capacity`` gets a level of its own).

    The blocks of a level are pairwise non-conflicting, so running a level's parts one after the other is the same
    transition as running the level at once; splitting changes neither a sequential sweep's kernel nor a colour
    class's conditionals. It bounds the padding of the fast sampler's fixed-size levels.

    Args:
        levels: ``(num_levels, width)`` block indices, padding ``NB = len(cost)``.
        cost: ``(NB,)`` non-negative work of each block (the fast sampler uses the number of rays through it).
        capacity: the largest total cost (and block count) of a level, >= 1.

    Returns:
        ``(num_levels', width')`` int32 block indices, padding ``NB``, blocks in their original order.
    """
    nb = len(cost)
    level_of: list[int] = []
    order: list[int] = []
    current = -1
    for row in levels:
        load = count = capacity + 1  # force a new level at the start of each original level
        for b in row[row < nb]:
            c = int(cost[b])
            if count + 1 > capacity or (load + c > capacity and count > 0):
                current += 1
                load = count = 0
            load += c
            count += 1
            level_of.append(current)
            order.append(int(b))
    num_levels = current + 1
    counts = np.bincount(np.asarray(level_of, dtype=np.int64), minlength=num_levels)
    width = max(int(counts.max()) if num_levels else 0, 1)
    out = np.full((max(num_levels, 0), width), nb, dtype=np.int32)
    fill = np.zeros(num_levels, dtype=np.int64)
    for lv, b in zip(level_of, order):
        out[lv, fill[lv]] = b
        fill[lv] += 1
    return out
