"""The sparse ray-cell table: for every ray (beam), the cells it crosses in order and the distance at which it
would stop in each, built in closed form (Amanatides & Woo crossings) with exactly the arithmetic of
:func:`bayesmap.geometry.raycast.sensor_distances`, so the table and the exact ray cast give identical numbers.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import PARALLEL_TOL, cell_hit_distance, unit_dir

_CHUNK_PAIRS = 1 << 18  # pairs per chunk of numpy passes over all pairs (temporaries of <= 2 MB: malloc reuses them)
TRACE_THREADS = 4  # most threads tracing chunks of rays in build_ray_table (at most one per core)



@dataclass(frozen=True)
class RayTable:
    """Which cells each ray crosses and at which distance it would stop there, for fixed sensor poses and beams.

    Stored sparse, in compressed-row form: the (ray, cell) pairs of ray ``r`` are ``offsets[r]:offsets[r + 1]`` of
    ``pair_cells`` / ``pair_dists``, in order of increasing stopping distance (meters, exactly the numbers
    :func:`sensor_distances` would use). Only cells at a distance below the max distance are listed: a wall beyond
    it does not change the reading. Memory is proportional to the number of pairs, not rays x cells. Rays from
    several poses (scans) live in one table: ray ``r`` has its own origin and angle.

    Attributes:
        grid: the grid geometry.
        offsets: ``(R + 1,)`` int64 start of each ray's pairs (``offsets[-1] == num_pairs``).
        pair_cells: ``(P,)`` int32 flat cell index ``i * ny + j`` of each pair.
        pair_dists: ``(P,)`` float (JAX's default dtype, float32 unless x64 is on) stopping distance of each
            pair, meters.
        origins: ``(R, 2)`` float64 world position of each ray's sensor (meters).
        beam_angles: ``(R,)`` float64 world-frame angle of each ray (radians).
        max_distance: the cap on distances (meters).
    """

    grid: Grid
    offsets: np.ndarray
    pair_cells: np.ndarray
    pair_dists: np.ndarray
    origins: np.ndarray
    beam_angles: np.ndarray
    max_distance: float

    @property
    def num_rays(self) -> int:
        return len(self.offsets) - 1

    @property
    def num_cells(self) -> int:
        return self.grid.num_cells

    @property
    def num_pairs(self) -> int:
        return int(self.offsets[-1])

    @cached_property
    def lengths(self) -> np.ndarray:
        """``(R,)`` int64 number of cells on each ray (computed once; do not modify)."""
        return np.diff(self.offsets)

    def per_pair(self, values) -> np.ndarray:
        """``(P,)`` each ray's value of ``values`` ``(R,)`` (any dtype), repeated for its pairs: ``values[pair_rays]``
        without building or reading :attr:`pair_rays` (faster)."""
        return np.repeat(np.asarray(values), self.lengths)

    @cached_property
    def pair_rays(self) -> np.ndarray:
        """``(P,)`` int64 ray of each pair."""
        return self.per_pair(np.arange(self.num_rays))

    @cached_property
    def pair_positions(self) -> np.ndarray:
        """``(P,)`` int64 position of each pair along its ray (0 = closest to the sensor)."""
        return np.arange(self.num_pairs) - self.per_pair(self.offsets[:-1])

    def ray_pairs(self, rays) -> np.ndarray:
        """``(n,)`` int64 indices of the pairs of ``rays`` (ints, ascending for ascending pairs), ray by ray."""
        rays = np.asarray(rays, dtype=np.int64).reshape(-1)
        lengths = self.lengths[rays]
        ends = np.cumsum(lengths)
        return np.arange(int(ends[-1]) if len(ends) else 0) + np.repeat(self.offsets[rays] - (ends - lengths), lengths)

    def pairs_by_cell(self, cell_rank=None) -> np.ndarray:
        """``(P,)`` int64 pair indices sorted by ``cell_rank[cell]`` (``(num_cells,)`` ints below ``2**32``; default
        the flat cell index), the pairs of equal rank in pair order (ray by ray): ``np.argsort(cell_rank[pair_cells],
        kind="stable")``, computed as one sort of 64-bit keys ``rank << 32 | pair`` (numpy sorts those with a SIMD
        quicksort, several times faster than its stable sort of 32-bit keys), in the one buffer it returns."""
        num = self.num_pairs
        if num >= 1 << 32:
            raise BayesmapError(f"{num:,} pairs: at most 2**32 are supported")
        rank = np.arange(self.num_cells) if cell_rank is None else np.asarray(cell_rank)
        if len(rank) and (rank.min() < 0 or rank.max() >= 1 << 32):
            raise BayesmapError("cell ranks must lie in [0, 2**32)")
        rank = rank.astype(np.uint64) << np.uint64(32)
        keys = np.empty(num, dtype=np.uint64)
        for start in range(0, num, _CHUNK_PAIRS):
            part = keys[start:start + _CHUNK_PAIRS]
            np.take(rank, self.pair_cells[start:start + _CHUNK_PAIRS], out=part)
            part |= np.arange(start, start + len(part), dtype=np.uint64)
        keys.sort()
        keys &= np.uint64(0xFFFFFFFF)
        return keys.view(np.int64)

    def ray(self, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Cells ``(n,)`` int32 and stopping distances ``(n,)`` (meters) of ray ``r``, in order along the ray."""
        sl = slice(int(self.offsets[r]), int(self.offsets[r + 1]))
        return self.pair_cells[sl], self.pair_dists[sl]

    def first_wall_distances(self, walls) -> np.ndarray:
        """Distance of each ray to its first wall (meters, ``(R,)``), capped at ``max_distance``; equals
        :func:`sensor_distances` for every ray."""
        is_wall = np.asarray(walls).reshape(-1)[self.pair_cells] > 0
        d = np.where(is_wall, self.pair_dists, self.max_distance)
        out = np.full(self.num_rays, self.max_distance, dtype=self.pair_dists.dtype)
        crossed = self.lengths > 0  # (reduceat reads one value of an empty segment: rays without pairs are left out)
        out[crossed] = np.minimum(out[crossed], np.minimum.reduceat(d, self.offsets[:-1][crossed]))
        return out

    def rays_per_cell(self) -> np.ndarray:
        """``(num_cells,)`` int64: how many rays cross each cell (counted a chunk of pairs at a time: ``np.bincount``
        copies its input to int64 first)."""
        counts = np.zeros(self.num_cells, dtype=np.int64)
        for start in range(0, self.num_pairs, _CHUNK_PAIRS):
            counts += np.bincount(self.pair_cells[start:start + _CHUNK_PAIRS], minlength=self.num_cells)
        return counts


def _candidate_cells(p, u, s_max, shape):
    """Cells that the rays ``p + s u``, ``0 <= s <= s_max`` (cell coordinates) may touch: a superset, found from
    the crossings with the grid lines (each crossing point and its neighbours) and the sensor cell's neighbours.
    Returns ``(ray_index, cell_i, cell_j)`` int arrays (with duplicates). Used by :func:`_build_ray_table_exact`."""
    nx, ny = shape
    out_r, out_i, out_j = [], [], []
    num = len(p)
    for axis in (0, 1):
        other = 1 - axis
        comp = u[:, axis]
        moving = np.abs(comp) > 1e-12
        # grid lines are at k + 0.5; walk from the sensor's line outwards in the direction of travel
        count = np.where(moving, np.ceil(s_max * np.abs(comp)) + 2, 0).astype(np.int64)
        width = int(count.max()) if num else 0
        if width == 0:
            continue
        step = np.arange(width)
        direction = np.sign(comp)
        start = np.floor(p[:, axis] - 0.5) + np.where(direction > 0, 0, 1)
        lines = start[:, None] + direction[:, None] * step[None, :] + 0.5
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (lines - p[:, axis, None]) / comp[:, None]
        valid = moving[:, None] & (step[None, :] < count[:, None]) & (s >= -1e-6) & (s <= s_max[:, None] + 1e-6)
        rr, kk = np.nonzero(valid)
        line = lines[rr, kk]
        cross = p[rr, other] + s[rr, kk] * u[rr, other]
        base = np.round(cross).astype(np.int64)
        for side in (-0.5, 0.5):
            for off in (-1, 0, 1):
                a = np.round(line + side).astype(np.int64)
                b = base + off
                out_r.append(rr)
                out_i.append(a if axis == 0 else b)
                out_j.append(b if axis == 0 else a)
    base = np.round(p).astype(np.int64)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            out_r.append(np.arange(num))
            out_i.append(base[:, 0] + di)
            out_j.append(base[:, 1] + dj)
    r = np.concatenate(out_r)
    i = np.concatenate(out_i)
    j = np.concatenate(out_j)
    inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
    return r[inside], i[inside], j[inside]


@jax.jit
def _pair_distances(p, u, cells):
    return cell_hit_distance(p, u, cells)


def _exact_pair_distances(p, u, cells) -> np.ndarray:
    """:func:`cell_hit_distance` of ``n`` (ray, cell) pairs, with one jitted function for both builders.

    Args:
        p, u: ``(n, 2)`` ray origins and unit directions, cell coordinates, the table's dtype.
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
    size = max(1024, 1 << (n - 1).bit_length())
    if size > n:
        fill = np.zeros((size - n, 2), dtype=p.dtype)
        p, u, cells = (np.concatenate([a, fill + a[:1]]) for a in (p, u, cells))
    return np.asarray(_pair_distances(p, u, cells))[:n]


def _cell_frame(grid: Grid, origins: np.ndarray, beam_angles: np.ndarray):
    """Ray origins ``(R, 2)`` and unit directions ``(R, 2)`` in cell coordinates, in JAX's default float dtype and
    computed by JAX exactly as the model computes them (both builders start from these very numbers)."""
    dtype = jnp.result_type(float)
    p_t = np.asarray(grid.to_cell_coords(jnp.asarray(origins, dtype=dtype)))
    u_t = np.asarray(unit_dir(jnp.asarray(beam_angles, dtype=dtype)))
    return p_t, u_t


def _build_ray_table_exact(grid: Grid, origins, beam_angles, max_distance: float | None = None,
                           chunk: int = 1 << 18) -> RayTable:
    """The reference builder (the original algorithm; slow and memory-hungry on whole logs): same arguments, result
    and errors as :func:`build_ray_table`, which must reproduce its tables.

    Candidate cells come from the ray's crossings with grid lines (a superset, with their neighbours), each
    candidate's exact distance is computed with the tutorial's edge arithmetic (:func:`cell_hit_distance`, in JAX's
    default float dtype, through :func:`_exact_pair_distances`) and kept if it is below the max distance; the pairs
    are then sorted by (ray, distance, flat cell index). ``chunk`` is how many candidate (ray, cell) pairs are
    evaluated at once. Time and memory are a few hundred bytes and about a microsecond per candidate pair.

    Changes from the original: the grid's box is widened by more than the float rounding and an axis with ``u = 0``
    no longer gives a NaN exit distance (rays along or grazing the grid's border lost cells), and the pairs are
    evaluated in padded batches (see :func:`_exact_pair_distances`).

    Raises:
        BayesmapError: if a sensor position is not finite or lies outside the grid.
    """
    beam_angles = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), (len(beam_angles), 2))
    if max_distance is None:
        max_distance = grid.default_max_distance
    max_distance = float(max_distance)
    for xy in np.unique(origins, axis=0):
        grid.check_inside(xy)
    cap = max_distance / grid.resolution
    # in JAX's default float dtype, exactly as the model computes them
    p32, u32 = _cell_frame(grid, origins, beam_angles)
    p = p32.astype(np.float64)
    u = u32.astype(np.float64)
    # distance until the ray leaves the grid's box (slab method), capped by the max distance. The box is widened by
    # more than the edge test's float rounding (a ray grazing the border still touches the border cells), and an
    # axis the ray does not move along never ends it (0 / 0 gave NaN here, which dropped rays along the border).
    slack = 1e-3 + 1e-6 * min(cap, 1e12)
    lo = np.array([-0.5, -0.5]) - slack
    hi = np.array(grid.shape, dtype=np.float64) - 0.5 + slack
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - p) / u
        t2 = (hi - p) / u
    exit_s = np.min(np.where(u == 0, np.inf, np.maximum(t1, t2)), axis=1)
    s_max = np.minimum(exit_s, cap) + 1.0
    rr, ii, jj = _candidate_cells(p, u, s_max, grid.shape)
    ny = grid.shape[1]
    key = np.unique(rr * grid.num_cells + ii * ny + jj)
    rr = key // grid.num_cells
    flat = key % grid.num_cells
    cell_ij = np.stack([flat // ny, flat % ny], axis=-1).astype(p32.dtype)
    dist = np.empty(len(key), dtype=p32.dtype)
    for start in range(0, len(key), chunk):
        sl = slice(start, start + chunk)
        dist[sl] = _exact_pair_distances(p32[rr[sl]], u32[rr[sl]], cell_ij[sl])
    keep = dist < cap
    rr, flat, dist = rr[keep], flat[keep], dist[keep]
    order = np.lexsort((flat, dist, rr))
    rr, flat, dist = rr[order], flat[order], dist[order]
    num_rays = len(beam_angles)
    offsets = np.concatenate([[0], np.cumsum(np.bincount(rr, minlength=num_rays))]).astype(np.int64)
    return RayTable(
        grid=grid,
        offsets=offsets,
        pair_cells=flat.astype(np.int32),
        pair_dists=dist * dist.dtype.type(grid.resolution),
        origins=np.array(origins),
        beam_angles=beam_angles,
        max_distance=max_distance,
    )


# A crossing of a grid line that passes a grid vertex closer than this many float ulps of the distance (along the
# line) is handed to the exact edge arithmetic: there the tutorial's edge test (segment parameter in [0, 1]) can go
# either way in float32 (its rounding error is below 2 * eps * (s + 1) cells, see build_ray_table).
_VERTEX_TOL_ULPS = 32.0


def _vertex_tol(s, magnitude, dtype):
    """How close (cells, along a grid line) a crossing at ray parameter ``s`` may pass a grid vertex before it is
    handed to the exact edge arithmetic: ``_VERTEX_TOL_ULPS * eps * (s + 2)`` (``eps`` of the table's dtype; the
    edge test's own rounding error is below ``2 eps (s + 1)``) plus a margin for the float64 rounding of the
    crossing point (``magnitude``: a bound on the coordinates involved). Arrays broadcast."""
    eps = float(np.finfo(dtype).eps)
    eps64 = float(np.finfo(np.float64).eps)
    return _VERTEX_TOL_ULPS * eps * (s + 2.0) + 16.0 * eps64 * (magnitude + 2.0)


def _traversal(p: np.ndarray, u: np.ndarray, shape: tuple[int, int], cap: float, dtype) -> dict[str, np.ndarray]:
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
      and only while ``s <= min(cap (1 + 1e-6), exit (1 + 1e-9))``, ``exit`` where the ray leaves the grid's box
      widened by the vertex tolerance: every crossing whose distance in ``dtype`` can be below the cap or that
      can pass a vertex of a border cell within the tolerance, never one far outside the grid.
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
    s_cap = cap * (1.0 + 1e-6) + 1e-6
    s_ref = min(s_cap, 2.0 * math.hypot(*shape) + 4.0)
    tol = _vertex_tol(np.float64(s_ref), np.abs(p).max(axis=1) + s_ref, dtype) * np.abs(u).max(axis=1)
    with np.errstate(divide="ignore"):
        slack = 2.0 * tol[:, None] / np.where(moving, np.abs(u), 0.0)[:, ::-1]
    exit_s = np.min(np.where(moving, (np.where(forward, size - 0.5 + slack, -0.5 - slack) - p) / safe_u, np.inf),
                    axis=1)
    s_end = np.minimum(s_cap, exit_s * (1.0 + 1e-9) + 1e-9)[:, None]
    reach = np.floor((s_end - s0) * slope) + 1.0
    count = np.where(moving & (s0 <= s_end), np.minimum(border, reach), 0.0).astype(np.int64)
    return {"step": step, "start": start.astype(np.int64), "line": line, "s0": s0, "slope": slope, "count": count}


def _trace_chunk(p, u, p_t, u_t, trav, shape, cap: float):
    """The sorted (ray, cell) pairs of a chunk of rays: see :func:`build_ray_table` for the algorithm.

    Args:
        p, u: ``(n, 2)`` float64 ray origins / unit directions in cell coordinates (the table dtype's values).
        p_t, u_t: the same in the table's dtype.
        trav: :func:`_traversal` of these rays.
        shape: the grid's ``(nx, ny)``.
        cap: the max distance in cells.

    Returns:
        ``(counts, cells, dists)``: ``(n,)`` int64 pairs per ray; ``(P,)`` int32 flat cell indices and ``(P,)``
        distances in cells (table dtype), sorted by (ray, distance, flat index).
    """
    num = len(p)
    nx, ny = shape
    num_cells = nx * ny
    dtype = p_t.dtype
    count = trav["count"]
    start, step, s0, slope = trav["start"], trav["step"], trav["s0"], trav["slope"]
    # slot 0 of a ray is the cell it starts in, slot m >= 1 the cell entered at its m-th grid-line crossing
    nslot = 1 + count[:, 0] + count[:, 1]
    first = np.zeros(num + 1, dtype=np.int64)
    np.cumsum(nslot, out=first[1:])
    total = int(first[-1])
    head = first[:-1]
    umax = np.abs(u).max(axis=1)
    s_top = np.max(np.where(count > 0, s0 + (count - 1) / np.where(slope > 0, slope, 1.0), 0.0), axis=1)
    screen = _vertex_tol(s_top, np.abs(p).max(axis=1) + 2.0 * s_top + 1.0, dtype) * umax * (1.0 + 1e-6)
    flat = np.empty(total, dtype=np.int64)  # -1: outside the grid
    dist = np.empty(total, dtype=dtype)
    is_x = np.zeros(total, dtype=bool)
    near_slot, near_ray, near_vx, near_vy = [], [], [], []

    def flat_index(ci, cj):
        return np.where((ci >= 0) & (ci < nx) & (cj >= 0) & (cj < ny), ci * ny + cj, -1)

    for a in (0, 1):
        n_a = count[:, a]
        if not n_a.any():
            continue

        def rep(v):
            return np.repeat(v, n_a)

        b = 1 - a
        r = rep(np.arange(num))
        k = np.arange(len(r)) - rep(np.cumsum(n_a) - n_a)  # crossing index along its axis
        line = rep(trav["line"][:, a]) + k * rep(step[:, a])
        ua = rep(u[:, a])
        s = (line - rep(p[:, a])) / ua
        # the distance in the table's dtype with the same two roundings as the tutorial's edge arithmetic
        d = (line.astype(dtype) - rep(p_t[:, a])) / rep(u_t[:, a])
        if a == 0:
            # merge the two arithmetic sequences without sorting: x-crossing k comes after k x-crossings and
            # after the ceil((s_x(k) - s0_y) |u_y|) y-crossings with a smaller parameter
            before = np.clip(np.ceil((s - rep(s0[:, 1])) * rep(slope[:, 1])), 0, rep(count[:, 1])).astype(np.int64)
            pos = rep(head) + 1 + k + before
            is_x[pos] = True
            flat[pos] = flat_index(rep(start[:, 0]) + rep(step[:, 0]) * (k + 1),
                                   rep(start[:, 1]) + rep(step[:, 1]) * before)
        else:
            # the y-crossings take the remaining slots, in order
            is_y = ~is_x
            is_y[head] = False
            pos = np.flatnonzero(is_y)
            del is_y
            kx = pos - rep(head) - 1 - k  # x-crossings before
            flat[pos] = flat_index(rep(start[:, 0]) + rep(step[:, 0]) * kx,
                                   rep(start[:, 1]) + rep(step[:, 1]) * (k + 1))
        dist[pos] = d
        # crossings that pass a grid vertex within the float rounding of the edge test
        along = rep(p[:, b]) + s * rep(u[:, b])  # the crossing point's other coordinate
        vertex = np.floor(along) + 0.5
        off_vertex = np.abs(along - vertex) * np.abs(ua)
        g = np.flatnonzero(off_vertex < rep(screen))  # cheap screen with the ray's largest tolerance, then exact
        g = g[off_vertex[g] < _vertex_tol(s[g], np.abs(along[g]) + s[g], dtype) * umax[r[g]]]
        near_slot.append(pos[g])
        near_ray.append(r[g])
        near_vx.append(line[g] if a == 0 else vertex[g])
        near_vy.append(vertex[g] if a == 0 else line[g])
        del r, k, line, ua, s, d, pos, along, vertex, off_vertex
    # the start cell is left at the first crossing (or never, within the cap)
    flat[head] = flat_index(start[:, 0], start[:, 1])
    nxt = np.minimum(head + 1, total - 1)
    dist[head] = np.where(nslot > 1, dist[nxt], np.inf)
    del is_x
    keep = (flat >= 0) & (dist < cap)

    exact_keys = np.zeros(0, dtype=np.int64)
    if near_slot:
        g = np.concatenate(near_slot)
        gr = np.concatenate(near_ray)
        vx = np.concatenate(near_vx)
        vy = np.concatenate(near_vy)
    if near_slot and len(g):
        # the four cells around each such vertex get the exact edge arithmetic instead
        ei = (np.rint(vx - 0.5).astype(np.int64)[:, None] + np.array([0, 1, 0, 1])).ravel()
        ej = (np.rint(vy - 0.5).astype(np.int64)[:, None] + np.array([0, 0, 1, 1])).ravel()
        er = np.repeat(gr, 4)
        ok = (ei >= 0) & (ei < nx) & (ej >= 0) & (ej < ny)
        exact_keys = np.unique(er[ok] * num_cells + ei[ok] * ny + ej[ok])
        del ei, ej, er, ok
    if len(exact_keys):
        # ... and leave the fast pairs: within the 2 x 2 cells around a vertex a ray crosses only the vertex's two
        # lines, so the cells it visits there are in slots g - 2 .. g + 1 of any such crossing g
        for off in (-2, -1, 0, 1):
            h = g + off
            ok = (h >= head[gr]) & (h < first[gr + 1])
            h, hr = h[ok], gr[ok]
            fh = flat[h]
            key = hr * num_cells + fh
            pos = np.minimum(np.searchsorted(exact_keys, key), len(exact_keys) - 1)
            keep[h[(exact_keys[pos] == key) & (fh >= 0)]] = False

    # the start cell and the first cell entered share a distance: order them by flat index, as the sort does
    swap = (nslot > 1) & keep[head] & keep[nxt] & (flat[head] > flat[nxt])
    sa, sb = head[swap], nxt[swap]
    flat[sa], flat[sb] = flat[sb], flat[sa]
    counts = np.add.reduceat(keep, head, dtype=np.int64) if num else np.zeros(0, dtype=np.int64)
    f_cell = flat[keep].astype(np.int32)
    f_dist = dist[keep]
    del flat, dist, keep

    if len(exact_keys):
        e_ray = exact_keys // num_cells
        e_cell = exact_keys % num_cells
        cells = np.stack([e_cell // ny, e_cell % ny], axis=-1).astype(dtype)
        e_dist = _exact_pair_distances(p_t[e_ray], u_t[e_ray], cells)
        ok = e_dist < cap
        e_ray, e_cell, e_dist = e_ray[ok], e_cell[ok].astype(np.int32), e_dist[ok]
        order = np.lexsort((e_cell, e_dist, e_ray))
        e_ray, e_cell, e_dist = e_ray[order], e_cell[order], e_dist[order]
        # insert them in their rays by (distance, flat index): vectorized bisection within each ray's fast pairs
        ends = np.zeros(num + 1, dtype=np.int64)
        np.cumsum(counts, out=ends[1:])
        lo, hi = ends[e_ray], ends[e_ray + 1]
        while np.any(lo < hi):
            mid = (lo + hi) // 2
            m = np.minimum(mid, len(f_cell) - 1)
            after = (f_dist[m] < e_dist) | ((f_dist[m] == e_dist) & (f_cell[m] < e_cell))
            active = lo < hi
            lo = np.where(active & after, mid + 1, lo)
            hi = np.where(active & ~after, mid, hi)
        f_cell = np.insert(f_cell, lo, e_cell)
        f_dist = np.insert(f_dist, lo, e_dist)
        counts += np.bincount(e_ray, minlength=num)

    # safety net (never triggered in the tests): re-sort any ray that is not in (distance, flat index) order
    ends = np.cumsum(counts)
    same = np.ones(max(len(f_cell) - 1, 0), dtype=bool)
    same[ends[(ends > 0) & (ends < len(f_cell))] - 1] = False
    bad = same & ((f_dist[1:] < f_dist[:-1]) | ((f_dist[1:] == f_dist[:-1]) & (f_cell[1:] <= f_cell[:-1])))
    for r in np.unique(np.searchsorted(ends, np.flatnonzero(bad), side="right")):
        sl = slice(int(ends[r] - counts[r]), int(ends[r]))
        order = np.lexsort((f_cell[sl], f_dist[sl]))
        f_cell[sl], f_dist[sl] = f_cell[sl][order], f_dist[sl][order]
    return counts, f_cell, f_dist


def build_ray_table(grid: Grid, origins, beam_angles, max_distance: float | None = None, chunk: int = 1 << 18) -> RayTable:
    """Build the :class:`RayTable` for rays from ``origins`` at ``beam_angles``.

    Args:
        grid: the grid.
        origins: ``(R, 2)`` sensor position of each ray, world meters (or ``(2,)`` for one position, broadcast).
        beam_angles: ``(R,)`` world-frame beam angles, radians.
        max_distance: cap in meters (finite, ``>= 0``); default :attr:`Grid.default_max_distance`.
        chunk: about how many (ray, cell) slots to trace at once (whole rays; bounds the temporaries, about 150
            bytes per slot); up to :data:`TRACE_THREADS` chunks are traced at a time, one per core.

    Returns:
        The table: for each ray every cell whose tutorial distance (:func:`cell_hit_distance`, in JAX's default
        float dtype, meters after scaling by the resolution) is below the max distance, sorted by distance, ties
        by flat cell index. It is the same table as the reference builder's (:func:`_build_ray_table_exact`):
        same offsets, cells and order, and distances equal to the last bit (they come from the same two float
        roundings, or from the same jitted function); the tests check cells and offsets exactly and distances to
        1e-5 relative + 1e-5 cells. (Whether a ray that passes a grid vertex within an ulp touches the diagonal
        cell is decided by the edge test's float rounding, which in XLA can depend on the batch layout; both
        builders evaluate such pairs the same way, see :func:`_exact_pair_distances`.)

    Algorithm: grid traversal in closed form (Amanatides & Woo 1987, "A Fast Voxel Traversal Algorithm for Ray
    Tracing"), vectorized over all rays of a chunk, without a sort. In cell coordinates a ray ``p + s u`` crosses
    the grid lines of one axis at ``s0 + k / |u_a|``, ``k = 0, 1, ...``; the cells it visits are the cell it starts
    in and then one new cell per crossing, in the merged order of the two sequences. The slot of x-crossing ``k`` in
    that order is ``1 + k + ceil((s_x(k) - s0_y) |u_y|)`` (that many y-crossings come earlier), the y-crossings
    fill the remaining slots in order, and a slot's cell follows from the numbers of crossings of each axis before
    it: all of it ``np.repeat`` / ``np.arange`` / index arithmetic over the chunk's crossings. A cell's distance is
    the crossing where the ray enters it (for the start cell, where it leaves it), computed as ``(line - p) / u``
    in the table dtype: the tutorial's edge arithmetic rounds exactly the same way for an edge it hits inside the
    segment. A sensor on a grid line starts in the cell behind it (the edge test counts the contact at ``s = 0``);
    lines with ``|u_a| < PARALLEL_TOL`` are never crossed.

    Corners: where a crossing passes a grid vertex closer than the edge test's rounding error (which is below
    ``2 eps (s + 1)`` cells along the line, ``eps`` the dtype's machine epsilon; the threshold is 32 eps (s + 2)),
    the tutorial's inclusive test may or may not count the diagonal cells, and may even miss the entry edge. The
    four cells around every such vertex are therefore evaluated with the exact edge arithmetic itself (the jitted
    :func:`cell_hit_distance`, as the reference builder does), replace the fast pairs of those cells and are
    inserted in order. This covers rays through vertices, rays along grid lines, sensors on cell corners and
    edges, and the rare generic near-misses (about 0.1 % of crossings on a real log at 0.1 m). Equal distances
    (the start cell and the first cell entered always share one; cells around a vertex may) are ordered by flat
    cell index, as the reference builder's sort does.

    Time and memory are O(pairs): about 8 bytes per pair for the result plus the temporaries of the chunks being
    traced.

    Raises:
        BayesmapError: if a sensor position is not finite or lies outside the grid, a beam angle is not finite,
            or the max distance is not a finite number >= 0.
    """
    beam_angles = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), (len(beam_angles), 2))
    if max_distance is None:
        max_distance = grid.default_max_distance
    max_distance = float(max_distance)
    if not (math.isfinite(max_distance) and max_distance >= 0):
        raise BayesmapError(f"max distance must be a finite number >= 0 (meters), got {max_distance!r}")
    bad = np.flatnonzero(~np.isfinite(beam_angles))
    if len(bad):
        raise BayesmapError(f"beam angle {bad[0]} is {beam_angles[bad[0]]!r}: beam angles must be finite (radians)")
    xmin, xmax, ymin, ymax = grid.extent
    with np.errstate(invalid="ignore"):
        outside = ~((origins[:, 0] >= xmin) & (origins[:, 0] <= xmax) & (origins[:, 1] >= ymin)
                    & (origins[:, 1] <= ymax))
    for r in np.flatnonzero(outside):
        grid.check_inside(origins[r])
    cap = max_distance / grid.resolution
    p_t, u_t = _cell_frame(grid, origins, beam_angles)
    p = p_t.astype(np.float64)
    u = u_t.astype(np.float64)
    trav = _traversal(p, u, grid.shape, cap, p_t.dtype)
    num_rays = len(beam_angles)
    ends = np.cumsum(1 + trav["count"].sum(axis=1))
    counts = np.zeros(num_rays, dtype=np.int64)
    capacity = int(ends[-1]) + 1024 if num_rays else 0
    cells = np.empty(capacity, dtype=np.int32)
    dists = np.empty(capacity, dtype=p_t.dtype)
    chunks = []  # slices of whole rays, about `chunk` slots each
    start = 0
    while start < num_rays:
        done = int(ends[start - 1]) if start else 0
        stop = max(start + 1, int(np.searchsorted(ends, done + max(int(chunk), 1), side="right")))
        chunks.append(slice(start, stop))
        start = stop

    def trace(sl):
        return _trace_chunk(p[sl], u[sl], p_t[sl], u_t[sl], {k: v[sl] for k, v in trav.items()}, grid.shape, cap)

    used = 0
    # chunks are independent: traced on up to TRACE_THREADS threads (numpy releases the GIL), gathered in order
    with ThreadPoolExecutor(max_workers=max(1, min(TRACE_THREADS, os.cpu_count() or 1))) as pool:
        for sl, (n, c, d) in zip(chunks, pool.map(trace, chunks)):
            counts[sl] = n
            if used + len(c) > len(cells):  # more exact corner cells than fast slots: grow (rare)
                grow = max(len(cells) // 2, len(c), 1024)
                cells = np.concatenate([cells[:used], np.empty(len(cells) - used + grow, dtype=cells.dtype)])
                dists = np.concatenate([dists[:used], np.empty(len(dists) - used + grow, dtype=dists.dtype)])
            cells[used:used + len(c)] = c
            dists[used:used + len(d)] = d
            used += len(c)
    cells.resize(used, refcheck=False)
    dists.resize(used, refcheck=False)
    dists *= dists.dtype.type(grid.resolution)
    offsets = np.zeros(num_rays + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return RayTable(
        grid=grid,
        offsets=offsets,
        pair_cells=cells,
        pair_dists=dists,
        origins=np.array(origins),
        beam_angles=beam_angles,
        max_distance=max_distance,
    )


def visible_cells(table: RayTable, walls) -> np.ndarray:
    """Cells a ray crosses before its first wall, or that are that first wall: ``(nx, ny)`` bool.

    A cell tied in distance with the first wall (a ray through a corner) counts only if it is itself a wall.
    """
    is_wall = np.asarray(walls).reshape(-1)[table.pair_cells] > 0
    first = table.first_wall_distances(walls)[table.pair_rays]
    seen = (table.pair_dists < first) | (is_wall & (table.pair_dists <= first))
    out = np.zeros(table.num_cells, dtype=bool)
    out[table.pair_cells[seen]] = True
    return out.reshape(table.grid.shape)


def check_readings(readings, num_rays: int) -> np.ndarray:
    """Validate range readings: ``(num_rays,)`` finite, non-negative meters. Returns them as float64.

    Raises:
        BayesmapError: on the wrong length or a NaN, infinite or negative value (names the first offender).
    """
    arr = np.asarray(readings, dtype=np.float64).reshape(-1)
    if arr.shape != (num_rays,):
        raise BayesmapError(f"expected {num_rays} readings, got {arr.size}")
    bad = np.flatnonzero(~np.isfinite(arr) | (arr < 0))
    if len(bad):
        raise BayesmapError(f"reading {bad[0]} is {arr[bad[0]]!r}: readings must be finite and >= 0 (meters)")
    return arr
