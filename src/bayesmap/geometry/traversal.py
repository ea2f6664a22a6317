"""The ray-cell table's tracer: grid traversal in closed form, vectorized over many rays, in exactly the arithmetic
of the tutorial's edge test (:func:`bayesmap.geometry.raycast.cell_hit_distance`).

Algorithm: grid traversal in closed form (Amanatides & Woo 1987, "A Fast Voxel Traversal Algorithm for Ray
Tracing"), vectorized over all rays of a chunk, without a sort. In cell coordinates a ray ``p + s u`` crosses the grid
lines of one axis at ``s0 + k / |u_a|``, ``k = 0, 1, ...``; the cells it visits are the cell it starts in and then one
new cell per crossing, in the merged order of the two sequences. The slot of x-crossing ``k`` in that order is
``1 + k + ceil((s_x(k) - s0_y) |u_y|)`` (that many y-crossings come earlier), the y-crossings fill the remaining slots
in order, and a slot's cell follows from the numbers of crossings of each axis before it: all of it ``np.repeat`` /
``np.arange`` / index arithmetic over the chunk's crossings. A cell's distance is the crossing where the ray enters
it (for the start cell, where it leaves it), computed as ``(line - p) / u`` in the table dtype: the tutorial's edge
arithmetic rounds exactly the same way for an edge it hits inside the segment. A sensor on a grid line starts in the
cell behind it (the edge test counts the contact at ``s = 0``); lines with ``|u_a| < PARALLEL_TOL`` are never crossed.

Corners: where a crossing passes a grid vertex closer than the edge test's rounding error (which is below
``2 eps (s + 1)`` cells along the line, ``eps`` the dtype's machine epsilon; the threshold is 32 eps (s + 2)), the
tutorial's inclusive test may or may not count the diagonal cells, and may even miss the entry edge. The four cells
around every such vertex are therefore evaluated with the exact edge arithmetic itself (the jitted
:func:`~bayesmap.geometry.raycast.cell_hit_distance`, through :func:`exact_pair_distances`, as the reference builder
:func:`bayesmap.geometry.reference.build_ray_table_reference` does), replace the fast pairs of those cells and are
inserted in order. This covers rays through vertices, rays along grid lines, sensors on cell corners and edges, and
the rare generic near-misses (about 0.1 % of crossings on a real log at 0.1 m). Equal distances (the start cell and
the first cell entered always share one; cells around a vertex may) are ordered by flat cell index, as the reference
builder's sort does.

:func:`trace_rays` is the entry point; :func:`bayesmap.geometry.raytable.build_ray_table` wraps its result as a
:class:`~bayesmap.geometry.raytable.RayTable`.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import PARALLEL_TOL, cell_hit_distance, unit_dir

TRACE_THREADS = 4  # most threads tracing chunks of rays in trace_rays (at most one per core)


def cell_frame(grid: Grid, origins: np.ndarray, beam_angles: np.ndarray):
    """Ray origins ``(R, 2)`` and unit directions ``(R, 2)`` in cell coordinates, in JAX's default float dtype and
    computed by JAX exactly as the model computes them (both builders start from these very numbers). Each ray's
    numbers depend only on its own origin and angle, not on the other rays of the batch (``replace_rays`` relies on
    it; ``test_replace_rays_equals_a_rebuild`` checks it)."""
    dtype = jnp.result_type(float)
    origins, beam_angles = np.asarray(origins), np.asarray(beam_angles)
    num_rays = len(beam_angles)
    pad = power_of_two_length(num_rays, 64) - num_rays  # (JAX compiles each operation once per length)
    origins = np.pad(origins, ((0, pad), (0, 0)))
    beam_angles = np.pad(beam_angles, (0, pad))
    p_table = np.asarray(grid.to_cell_coords(jnp.asarray(origins, dtype=dtype)))[:num_rays]
    u_table = np.asarray(unit_dir(jnp.asarray(beam_angles, dtype=dtype)))[:num_rays]
    return p_table, u_table


def power_of_two_length(n: int, at_least: int) -> int:
    """The length ``n`` rays or pairs are padded to before JAX runs on them: the next power of two, at least
    ``at_least`` (a power of two). Each operation or jitted function compiles once per length of its arrays, and JAX
    keeps every program it compiled until :func:`bayesmap.memory.drop_compiled_programs`: the tables of a whole
    log's tiles and chunks, of many lengths, then share a few programs (:func:`cell_frame`, 64;
    :func:`exact_pair_distances`, 1024). A power of two also keeps every entry in the vectorized body of XLA's CPU
    loop (:func:`exact_pair_distances`). :func:`bayesmap.model.likelihood.padded_length` pads by at most 25 % instead,
    for functions whose work the padding adds to."""
    return max(int(at_least), 1 << (int(n) - 1).bit_length())


@jax.jit
def _pair_distances(p, u, cells):
    return cell_hit_distance(p, u, cells)


def exact_pair_distances(p, u, cells) -> np.ndarray:
    """:func:`cell_hit_distance` of ``n`` (ray, cell) pairs, with one jitted function for both builders.

    Args:
        p: ``(n, 2)`` ray origins, cell coordinates, the table's dtype.
        u: ``(n, 2)`` unit directions, the table's dtype.
        cells: ``(n, 2)`` cell indices as floats of the table's dtype.

    Returns:
        ``(n,)`` distances in cells (``inf`` where the ray misses the cell).

    The inputs are padded to a power of two (at least 1024). Besides compiling only a few sizes, this keeps every
    pair in the vectorized body of XLA's CPU loop: its scalar remainder loop rounds the edge test's segment
    parameter differently (the products are fused differently), so a ray that passes a grid vertex within an ulp
    could count the diagonal cell or not depending on the pair's position in the batch.
    """
    n = len(p)
    if n == 0:
        return np.zeros(0, dtype=p.dtype)
    size = power_of_two_length(n, 1024)
    if size > n:
        fill = np.zeros((size - n, 2), dtype=p.dtype)
        p, u, cells = (np.concatenate([a, fill + a[:1]]) for a in (p, u, cells))
    return np.asarray(_pair_distances(p, u, cells))[:n]


# A crossing of a grid line that passes a grid vertex closer than this many float ulps of the distance (along the
# line) is handed to the exact edge arithmetic: there the tutorial's edge test (segment parameter in [0, 1]) can go
# either way in float32 (its rounding error is below 2 * eps * (s + 1) cells, see the module docstring).
_VERTEX_TOL_ULPS = 32.0


def _vertex_tol(s, magnitude, dtype):
    """How close (cells, along a grid line) a crossing at ray parameter ``s`` may pass a grid vertex before it is
    handed to the exact edge arithmetic: ``_VERTEX_TOL_ULPS * eps * (s + 2)`` (``eps`` of the table's dtype; the
    edge test's own rounding error is below ``2 eps (s + 1)``) plus a margin for the float64 rounding of the
    crossing point (``magnitude``: a bound on the coordinates involved). Arrays broadcast."""
    eps = float(np.finfo(dtype).eps)
    eps64 = float(np.finfo(np.float64).eps)
    return _VERTEX_TOL_ULPS * eps * (s + 2.0) + 16.0 * eps64 * (magnitude + 2.0)


class _Traversal(NamedTuple):
    """Per-ray, per-axis parameters of the grid traversal, each ``(R, 2)`` (see :func:`_traversal`)."""

    step: np.ndarray  # int64 sign(u_a), 0 if the ray does not move along axis a
    start: np.ndarray  # int64 index of the cell the ray is in just before s = 0
    line: np.ndarray  # float64 first grid line crossed at s >= 0
    s0: np.ndarray  # float64 ray parameter of that crossing
    slope: np.ndarray  # float64 |u_a| (0 if not moving): crossing k is at s0 + k / slope
    count: np.ndarray  # int64 number of crossings generated

    def rows(self, rays) -> "_Traversal":
        """The parameters of the rays ``rays`` (an index or slice)."""
        return _Traversal(*(values[rays] for values in self))


class _NearVertex(NamedTuple):
    """Crossings that pass a grid vertex within the edge test's float rounding, each ``(n,)``."""

    slots: np.ndarray  # int64 slot of the crossing in its chunk
    rays: np.ndarray  # int64 ray (in the chunk)
    vertex_x: np.ndarray  # float64 the vertex, cell coordinates (half-integers)
    vertex_y: np.ndarray


def _traversal(p: np.ndarray, u: np.ndarray, shape: tuple[int, int], max_cells, dtype) -> _Traversal:
    """Per-ray, per-axis parameters of the grid traversal (Amanatides & Woo 1987), float64 cell coordinates.

    Grid lines along axis ``a`` sit at half-integers. For each ray ``p + s u`` (``(R, 2)`` each) and axis:

    * ``moving``: ``|u_a| >= PARALLEL_TOL`` (otherwise the tutorial's edge test calls these edges parallel and the
      ray never crosses them);
    * ``step``: ``sign(u_a)`` as int64 (0 if not moving);
    * ``start``: int64 index of the cell the ray is in just *before* ``s = 0`` (for a sensor on a grid line, the
      cell behind it: the edge test counts the contact at ``s = 0``);
    * ``line``: the first grid line crossed at ``s >= 0``, ``start + step / 2``;
    * ``s0``: its ray parameter (``>= 0``; 0 if not moving); ``slope``: ``|u_a|`` (0 if not moving), so crossing
      ``k`` is at ``s0 + k / slope``;
    * ``count``: int64 number of crossings generated: up to and including the grid's border line on that axis,
      and only while ``s <= min(max_cells (1 + 1e-6), exit (1 + 1e-9))``, ``exit`` where the ray leaves the grid's
      box widened by the vertex tolerance: every crossing whose distance in ``dtype`` can be below the max distance
      (``max_cells``, in cells) or that can pass a vertex of a border cell within the tolerance, never one far
      outside the grid.
    """
    size = np.asarray(shape, dtype=np.float64)
    moving = np.abs(u) >= PARALLEL_TOL
    forward = u > 0
    step = np.where(moving, np.where(forward, 1, -1), 0).astype(np.int64)
    start = np.where(moving & forward, np.ceil(p + 0.5) - 1.0, np.floor(p + 0.5))
    line = start + 0.5 * step
    safe_u = np.where(moving, u, 1.0)
    s0 = np.where(moving, (line - p) / safe_u, 0.0)
    slope = np.where(moving, np.abs(u), 0.0)
    border = np.where(forward, size - start, start + 1.0)
    # where the ray leaves the grid's box, widened on each axis by the vertex tolerance of the other axis'
    # crossings (a ray grazing the border keeps touching border cells in the edge test)
    s_limit = max_cells * (1.0 + 1e-6) + 1e-6
    s_reference = np.minimum(s_limit, 2.0 * math.hypot(*shape) + 4.0)
    tolerance = _vertex_tol(np.float64(s_reference), np.abs(p).max(axis=1) + s_reference, dtype) * np.abs(u).max(axis=1)
    with np.errstate(divide="ignore"):
        slack = 2.0 * tolerance[:, None] / np.where(moving, np.abs(u), 0.0)[:, ::-1]
    exit_s = np.min(np.where(moving, (np.where(forward, size - 0.5 + slack, -0.5 - slack) - p) / safe_u, np.inf),
                    axis=1)
    s_end = np.minimum(s_limit, exit_s * (1.0 + 1e-9) + 1e-9)[:, None]
    reach = np.floor((s_end - s0) * slope) + 1.0
    count = np.where(moving & (s0 <= s_end), np.minimum(border, reach), 0.0).astype(np.int64)
    return _Traversal(step=step, start=start.astype(np.int64), line=line, s0=s0, slope=slope, count=count)


def _flat_index(cell_i, cell_j, shape):
    """Flat index ``i * ny + j`` of cells ``(i, j)`` (int arrays), -1 for cells outside the grid."""
    nx, ny = shape
    return np.where((cell_i >= 0) & (cell_i < nx) & (cell_j >= 0) & (cell_j < ny), cell_i * ny + cell_j, -1)


def _slot_limits(max_cells, first, dtype):
    """The max distance in cells that each slot's distance is compared with: ``max_cells`` itself when it is one
    number for all rays (a scalar: numpy compares it in the table's dtype), else each ray's ``(n,)`` limit in the
    table's ``dtype``, repeated for the ray's slots (``first``: each ray's first slot, then the total)."""
    if np.ndim(max_cells) == 0:
        return max_cells
    return np.repeat(np.asarray(max_cells, dtype), np.diff(first))


def _trace_chunk(p, u, p_table, u_table, traversal: _Traversal, shape, max_cells):
    """The sorted (ray, cell) pairs of a chunk of rays: see the module docstring for the algorithm.

    Args:
        p, u: ``(n, 2)`` float64 ray origins / unit directions in cell coordinates (the table dtype's values).
        p_table, u_table: the same in the table's dtype.
        traversal: :func:`_traversal` of these rays.
        shape: the grid's ``(nx, ny)``.
        max_cells: the max distance in cells, a number or ``(n,)`` one per ray.

    Returns:
        ``(counts, cells, dists)``: ``(n,)`` int64 pairs per ray; ``(P,)`` int32 flat cell indices and ``(P,)``
        distances in cells (table dtype), sorted by (ray, distance, flat index).

    Steps: lay out one slot per cell visited (the start cell, then one per grid-line crossing) and fill in each
    slot's cell and distance (:func:`_trace_slots`); keep the slots inside the grid and below the max distance;
    hand the cells around grid vertices passed within the float rounding to the exact edge arithmetic
    (:func:`_near_vertex_keys`, :func:`_drop_fast_pairs_near_vertices`, :func:`_insert_exact_pairs`); compact
    (:func:`_compact_slots`); re-sort any ray out of order (:func:`_resort_unordered_rays`, a safety net).
    """
    num_rays = len(p)
    # slot 0 of a ray is the cell it starts in, slot m >= 1 the cell entered at its m-th grid-line crossing
    first = np.zeros(num_rays + 1, dtype=np.int64)
    np.cumsum(1 + traversal.count[:, 0] + traversal.count[:, 1], out=first[1:])
    flat, dist, near = _trace_slots(p, u, p_table, u_table, traversal, shape, first)
    keep = (flat >= 0) & (dist < _slot_limits(max_cells, first, dist.dtype))
    exact_keys = _near_vertex_keys(near, shape)
    if len(exact_keys):
        _drop_fast_pairs_near_vertices(keep, flat, near, first, exact_keys, shape[0] * shape[1])
    counts, cells, dists = _compact_slots(flat, dist, keep, first)
    del flat, dist, keep
    if len(exact_keys):
        counts, cells, dists = _insert_exact_pairs(counts, cells, dists, exact_keys, p_table, u_table, shape, max_cells)
    _resort_unordered_rays(counts, cells, dists)
    return counts, cells, dists


def _trace_slots(p, u, p_table, u_table, traversal: _Traversal, shape, first):
    """Cell and distance of every slot of a chunk of rays, and the crossings near grid vertices.

    Args:
        p, u, p_table, u_table, traversal, shape: as in :func:`_trace_chunk`.
        first: ``(n + 1,)`` int64 first slot of each ray (``first[-1]`` slots in all).

    Returns:
        ``(flat, dist, near)``: ``(slots,)`` int64 flat cell index of each slot (-1 outside the grid), ``(slots,)``
        distance in cells (table dtype; ``inf`` for a start cell the ray never leaves), and the crossings near a
        grid vertex (a :class:`_NearVertex`, or None if the rays cross no grid line).
    """
    total = int(first[-1])
    head = first[:-1]
    count, s0, slope = traversal.count, traversal.s0, traversal.slope
    largest_component = np.abs(u).max(axis=1)
    s_top = np.max(np.where(count > 0, s0 + (count - 1) / np.where(slope > 0, slope, 1.0), 0.0), axis=1)
    screen_tol = (_vertex_tol(s_top, np.abs(p).max(axis=1) + 2.0 * s_top + 1.0, p_table.dtype) * largest_component
                  * (1.0 + 1e-6))
    flat = np.empty(total, dtype=np.int64)  # -1: outside the grid
    dist = np.empty(total, dtype=p_table.dtype)
    is_x = np.zeros(total, dtype=bool)
    near = []
    for axis in (0, 1):
        if count[:, axis].any():
            near.append(_axis_crossings(axis, p, u, p_table, u_table, traversal, head, screen_tol, largest_component,
                                        shape, flat, dist, is_x))
    del is_x
    # the start cell is left at the first crossing (or never, within the max distance)
    flat[head] = _flat_index(traversal.start[:, 0], traversal.start[:, 1], shape)
    second = np.minimum(head + 1, total - 1)
    dist[head] = np.where(np.diff(first) > 1, dist[second], np.inf)
    return flat, dist, (_NearVertex(*(np.concatenate(parts) for parts in zip(*near))) if near else None)


def _axis_crossings(axis, p, u, p_table, u_table, traversal: _Traversal, head, screen_tol, largest_component, shape,
                    flat, dist, is_x) -> _NearVertex:
    """Fill in the slots of the rays' crossings of the grid lines of ``axis`` (0 first, then 1), in place.

    Writes the cell entered (``flat``) and its distance (``dist``) at each crossing's slot; axis 0 marks its slots
    in ``is_x``, axis 1 takes the remaining slots (all but the heads) in order. ``head`` is each ray's first slot,
    ``screen_tol`` ``(n,)`` each ray's largest vertex tolerance (a cheap first screen), ``largest_component``
    ``(n,)`` ``max |u_a|``. Returns the crossings that pass a grid vertex within :func:`_vertex_tol`.
    """
    counts = traversal.count[:, axis]
    start, step = traversal.start, traversal.step
    dtype = p_table.dtype

    def per_crossing(values):
        return np.repeat(values, counts)

    other = 1 - axis
    ray = per_crossing(np.arange(len(p)))
    k = np.arange(len(ray)) - per_crossing(np.cumsum(counts) - counts)  # crossing index along its axis
    line = per_crossing(traversal.line[:, axis]) + k * per_crossing(step[:, axis])
    u_axis = per_crossing(u[:, axis])
    s = (line - per_crossing(p[:, axis])) / u_axis
    # the distance in the table's dtype with the same two roundings as the tutorial's edge arithmetic
    d = (line.astype(dtype) - per_crossing(p_table[:, axis])) / per_crossing(u_table[:, axis])
    if axis == 0:
        # merge the two arithmetic sequences without sorting: x-crossing k comes after k x-crossings and
        # after the ceil((s_x(k) - s0_y) |u_y|) y-crossings with a smaller parameter
        y_before = np.clip(np.ceil((s - per_crossing(traversal.s0[:, 1])) * per_crossing(traversal.slope[:, 1])),
                           0, per_crossing(traversal.count[:, 1])).astype(np.int64)
        slots = per_crossing(head) + 1 + k + y_before
        is_x[slots] = True
        flat[slots] = _flat_index(per_crossing(start[:, 0]) + per_crossing(step[:, 0]) * (k + 1),
                                  per_crossing(start[:, 1]) + per_crossing(step[:, 1]) * y_before, shape)
    else:
        # the y-crossings take the remaining slots, in order
        is_y = ~is_x
        is_y[head] = False
        slots = np.flatnonzero(is_y)
        del is_y
        x_before = slots - per_crossing(head) - 1 - k
        flat[slots] = _flat_index(per_crossing(start[:, 0]) + per_crossing(step[:, 0]) * x_before,
                                  per_crossing(start[:, 1]) + per_crossing(step[:, 1]) * (k + 1), shape)
    dist[slots] = d
    del d
    # crossings that pass a grid vertex within the float rounding of the edge test
    along = per_crossing(p[:, other]) + s * per_crossing(u[:, other])  # the crossing point's other coordinate
    vertex = np.floor(along) + 0.5
    off_vertex = np.abs(along - vertex) * np.abs(u_axis)
    near = np.flatnonzero(off_vertex < per_crossing(screen_tol))  # cheap screen, then the exact tolerance
    near = near[off_vertex[near] < _vertex_tol(s[near], np.abs(along[near]) + s[near], dtype)
                * largest_component[ray[near]]]
    return _NearVertex(slots=slots[near], rays=ray[near], vertex_x=line[near] if axis == 0 else vertex[near],
                       vertex_y=vertex[near] if axis == 0 else line[near])


def _near_vertex_keys(near: _NearVertex | None, shape) -> np.ndarray:
    """Sorted unique int64 keys ``ray * num_cells + flat`` of the four cells around each near-vertex crossing
    (inside the grid): these pairs get the exact edge arithmetic instead of the fast one."""
    if near is None or not len(near.slots):
        return np.zeros(0, dtype=np.int64)
    nx, ny = shape
    cell_i = (np.rint(near.vertex_x - 0.5).astype(np.int64)[:, None] + np.array([0, 1, 0, 1])).ravel()
    cell_j = (np.rint(near.vertex_y - 0.5).astype(np.int64)[:, None] + np.array([0, 0, 1, 1])).ravel()
    rays = np.repeat(near.rays, 4)
    inside = (cell_i >= 0) & (cell_i < nx) & (cell_j >= 0) & (cell_j < ny)
    return np.unique(rays[inside] * (nx * ny) + cell_i[inside] * ny + cell_j[inside])


def _drop_fast_pairs_near_vertices(keep, flat, near: _NearVertex, first, exact_keys, num_cells: int) -> None:
    """Clear ``keep`` for the fast slots whose (ray, cell) is in ``exact_keys`` (in place). Within the 2 x 2 cells
    around a vertex a ray crosses only the vertex's two lines, so the cells it visits there are in slots
    ``g - 2 .. g + 1`` of any such crossing ``g``."""
    for offset in (-2, -1, 0, 1):
        slots = near.slots + offset
        ok = (slots >= first[near.rays]) & (slots < first[near.rays + 1])
        slots, rays = slots[ok], near.rays[ok]
        cells = flat[slots]
        keys = rays * num_cells + cells
        found = np.minimum(np.searchsorted(exact_keys, keys), len(exact_keys) - 1)
        keep[slots[(exact_keys[found] == keys) & (cells >= 0)]] = False


def _compact_slots(flat, dist, keep, first):
    """The kept slots, ray by ray: ``(counts (n,) int64, cells int32, dists)``. The start cell and the first cell
    entered share a distance: they are ordered by flat index, as the reference builder's sort does (``flat`` is
    modified in place)."""
    head = first[:-1]
    second = np.minimum(head + 1, len(flat) - 1)
    swap = (np.diff(first) > 1) & keep[head] & keep[second] & (flat[head] > flat[second])
    start_slots, second_slots = head[swap], second[swap]
    flat[start_slots], flat[second_slots] = flat[second_slots], flat[start_slots]
    counts = np.add.reduceat(keep, head, dtype=np.int64) if len(head) else np.zeros(0, dtype=np.int64)
    return counts, flat[keep].astype(np.int32), dist[keep]


def _insert_exact_pairs(counts, fast_cells, fast_dists, exact_keys, p_table, u_table, shape, max_cells):
    """Evaluate the pairs ``exact_keys`` (``ray * num_cells + flat``) with the exact edge arithmetic
    (:func:`exact_pair_distances`) and insert those below ``max_cells`` in their rays by (distance, flat index),
    with a vectorized bisection within each ray's fast pairs. Returns the new ``(counts, cells, dists)``."""
    num_rays = len(counts)
    ny = shape[1]
    num_cells = shape[0] * ny
    rays = exact_keys // num_cells
    cells = exact_keys % num_cells
    cell_indices = np.stack([cells // ny, cells % ny], axis=-1).astype(p_table.dtype)
    dists = exact_pair_distances(p_table[rays], u_table[rays], cell_indices)
    ok = dists < (max_cells if np.ndim(max_cells) == 0 else np.asarray(max_cells, dists.dtype)[rays])
    rays, cells, dists = rays[ok], cells[ok].astype(np.int32), dists[ok]
    order = np.lexsort((cells, dists, rays))
    rays, cells, dists = rays[order], cells[order], dists[order]
    ends = np.zeros(num_rays + 1, dtype=np.int64)
    np.cumsum(counts, out=ends[1:])
    lo, hi = ends[rays], ends[rays + 1]
    while np.any(lo < hi):
        mid = (lo + hi) // 2
        m = np.minimum(mid, len(fast_cells) - 1)
        after = (fast_dists[m] < dists) | ((fast_dists[m] == dists) & (fast_cells[m] < cells))
        active = lo < hi
        lo = np.where(active & after, mid + 1, lo)
        hi = np.where(active & ~after, mid, hi)
    return (counts + np.bincount(rays, minlength=num_rays), np.insert(fast_cells, lo, cells),
            np.insert(fast_dists, lo, dists))


def _resort_unordered_rays(counts, cells, dists) -> None:
    """Safety net (never triggered in the tests): re-sort, in place, any ray whose pairs are not in (distance, flat
    index) order."""
    ends = np.cumsum(counts)
    same = np.ones(max(len(cells) - 1, 0), dtype=bool)
    same[ends[(ends > 0) & (ends < len(cells))] - 1] = False
    bad = same & ((dists[1:] < dists[:-1]) | ((dists[1:] == dists[:-1]) & (cells[1:] <= cells[:-1])))
    for ray in np.unique(np.searchsorted(ends, np.flatnonzero(bad), side="right")):
        rows = slice(int(ends[ray] - counts[ray]), int(ends[ray]))
        order = np.lexsort((cells[rows], dists[rows]))
        cells[rows], dists[rows] = cells[rows][order], dists[rows][order]


def _ray_chunks(slot_ends: np.ndarray, chunk: int) -> list[slice]:
    """Slices of whole rays of about ``chunk`` slots each (at least one ray), from each ray's cumulative slot
    count ``slot_ends`` ``(R,)``."""
    chunks = []
    start = 0
    while start < len(slot_ends):
        done = int(slot_ends[start - 1]) if start else 0
        stop = max(start + 1, int(np.searchsorted(slot_ends, done + max(int(chunk), 1), side="right")))
        chunks.append(slice(start, stop))
        start = stop
    return chunks


def trace_rays(p_table, u_table, shape, max_cells, chunk: int):
    """The (ray, cell) pairs of all rays in closed form (module docstring), traced by chunks of ``chunk`` slots of
    whole rays on up to :data:`TRACE_THREADS` threads (numpy releases the GIL), gathered in order.

    Args:
        p_table: ``(R, 2)`` ray origins in cell coordinates, in the table's dtype (:func:`cell_frame`).
        u_table: ``(R, 2)`` unit directions, in the table's dtype.
        shape: the grid's ``(nx, ny)``.
        max_cells: the max distance in cells, a number or ``(R,)`` float64 one per ray; pairs at this distance or
            beyond are not listed (compared in the table's dtype).
        chunk: about how many (ray, cell) slots to trace at once (bounds the temporaries, about 150 bytes a slot).

    Returns:
        ``(counts, cells, dists)``: ``(R,)`` int64 pairs per ray, ``(P,)`` int32 flat cell indices ``i * ny + j``
        and ``(P,)`` distances in cells (the table's dtype), ray by ray, each ray's pairs sorted by (distance, flat
        index). Never raises for valid inputs (:func:`bayesmap.geometry.raytable.build_ray_table` checks them).
    """
    p = p_table.astype(np.float64)
    u = u_table.astype(np.float64)
    traversal = _traversal(p, u, shape, max_cells, p_table.dtype)
    num_rays = len(p)
    slot_ends = np.cumsum(1 + traversal.count.sum(axis=1))
    counts = np.zeros(num_rays, dtype=np.int64)
    capacity = int(slot_ends[-1]) + 1024 if num_rays else 0
    cells = np.empty(capacity, dtype=np.int32)
    dists = np.empty(capacity, dtype=p_table.dtype)

    def trace(rays):
        limit = max_cells if np.ndim(max_cells) == 0 else max_cells[rays]
        return _trace_chunk(p[rays], u[rays], p_table[rays], u_table[rays], traversal.rows(rays), shape, limit)

    used = 0
    chunks = _ray_chunks(slot_ends, chunk)
    with ThreadPoolExecutor(max_workers=max(1, min(TRACE_THREADS, os.cpu_count() or 1))) as pool:
        for rays, (ray_counts, chunk_cells, chunk_dists) in zip(chunks, pool.map(trace, chunks)):
            counts[rays] = ray_counts
            if used + len(chunk_cells) > len(cells):  # more exact corner cells than fast slots: grow (rare)
                grow = max(len(cells) // 2, len(chunk_cells), 1024)
                cells = np.concatenate([cells[:used], np.empty(len(cells) - used + grow, dtype=cells.dtype)])
                dists = np.concatenate([dists[:used], np.empty(len(dists) - used + grow, dtype=dists.dtype)])
            cells[used:used + len(chunk_cells)] = chunk_cells
            dists[used:used + len(chunk_dists)] = chunk_dists
            used += len(chunk_cells)
    cells.resize(used, refcheck=False)
    dists.resize(used, refcheck=False)
    return counts, cells, dists
