"""Sweep schedules: the order of Gibbs updates, the k x k blocks, and how updates can run in parallel.

Orders (of cells or of block anchors):

* ``"raster"``: ``i`` then ``j``, the tutorial's nested loops.
* ``"outward"``: the tutorial's sensor-outward order: cells by increasing ``floor|i - px| + floor|j - py|``
  (sensor position in cell coordinates), raster order among equals.

Blocks: a k x k block is anchored at every cell ``(i, j)`` with ``i <= nx - k`` and ``j <= ny - k``, so blocks
overlap and every cell belongs to at least one block ("blocks at every offset"); a 1 x 1 block is single-site
Gibbs. ``k`` is clipped to the grid's shape.

Parallel execution (used by the fast samplers only):

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
from bayesmap.grid import Grid

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


def _cell_rays(ray_cells: np.ndarray, num_cells: int) -> list[np.ndarray]:
    rays = np.repeat(np.arange(ray_cells.shape[0]), ray_cells.shape[1])
    flat = ray_cells.ravel()
    keep = flat < num_cells
    rays, flat = rays[keep], flat[keep]
    order = np.argsort(flat, kind="stable")
    rays, flat = rays[order], flat[order]
    bounds = np.searchsorted(flat, np.arange(num_cells + 1))
    return [rays[bounds[c] : bounds[c + 1]] for c in range(num_cells)]


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


def dependency_levels(blocks: np.ndarray, ray_cells: np.ndarray, num_cells: int) -> np.ndarray:
    """Group the sequential block updates ``blocks`` ``(NB, B)`` into levels of mutually non-conflicting blocks
    that preserve the order of every conflicting pair (see the module docstring).

    Args:
        blocks: ``(NB, B)`` flat cell indices, in sweep order.
        ray_cells: ``(R, L)`` the ray-cell table's cells (padding ``num_cells``).
        num_cells: number of cells in the grid.

    Returns:
        ``(num_levels, width)`` int32 block indices; padding ``NB`` (no block). Within a level, blocks keep their
        sweep order.
    """
    cell_rays = _cell_rays(ray_cells, num_cells)
    ray_last = np.full(ray_cells.shape[0], -1, dtype=np.int64)
    cell_last = np.full(num_cells, -1, dtype=np.int64)
    level = np.empty(len(blocks), dtype=np.int64)
    for b, cells in enumerate(blocks):
        rays = np.concatenate([cell_rays[c] for c in cells])
        lv = max(int(cell_last[cells].max()), int(ray_last[rays].max()) if len(rays) else -1) + 1
        level[b] = lv
        cell_last[cells] = lv
        ray_last[rays] = lv
    return _pad_levels(level, len(blocks))


def chromatic_levels(blocks: np.ndarray, ray_cells: np.ndarray, num_cells: int) -> np.ndarray:
    """Greedy colouring of the block conflict graph (visiting blocks in the given order); returns the colour
    classes as ``(num_colours, width)`` int32 block indices, padding ``NB``. See the module docstring."""
    cell_rays = _cell_rays(ray_cells, num_cells)
    ray_colours: list[set] = [set() for _ in range(ray_cells.shape[0])]
    cell_colours: list[set] = [set() for _ in range(num_cells)]
    colour = np.empty(len(blocks), dtype=np.int64)
    for b, cells in enumerate(blocks):
        rays = np.unique(np.concatenate([cell_rays[c] for c in cells]))
        used = set().union(*(cell_colours[c] for c in cells), *(ray_colours[r] for r in rays))
        c = 0
        while c in used:
            c += 1
        colour[b] = c
        for cell in cells:
            cell_colours[cell].add(c)
        for r in rays:
            ray_colours[r].add(c)
    return _pad_levels(colour, len(blocks))
