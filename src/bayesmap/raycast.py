"""Exact ray-cell geometry (the tutorial's) and the sparse ray-cell table used by the fast samplers.

The tutorial's sensor model: a ray from the sensor position ``p`` in direction ``u = (cos a, sin a)`` stops at the
first wall cell it meets; the distance to a cell is the smallest ray parameter ``s >= 0`` at which the ray meets
one of the cell's four edges (a segment hit with the segment parameter in ``[0, 1]``, lines closer to parallel than
``|det| < 1e-10`` never hit). The distance is capped at a max distance. Everything here uses exactly that
arithmetic, so the ray-cell table and :func:`sensor_distances` give identical numbers.

All geometry runs in cell coordinates (center of cell ``(i, j)`` at ``(i, j)``) and is scaled by the grid's
resolution, so the tutorial's unit cells and maps in meters are the same code.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, partial

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.grid import Grid

PARALLEL_TOL = 1.0e-10

# The four corners of a cell relative to its center, in the tutorial's order; edge k runs from corner k to
# corner k - 1 (the tutorial's ``jnp.roll(vertices, 1)``).
_CORNERS = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]], dtype=np.float32)
_EDGE_START = _CORNERS
_EDGE_VEC = np.roll(_CORNERS, 1, axis=0) - _CORNERS


def angles(num_angles: int) -> jnp.ndarray:
    """The tutorial's beam angles: ``num_angles`` equally spaced angles in ``[0, 2 pi)``, radians, shape
    ``(num_angles,)``."""
    return jnp.arange(0, 1, 1 / num_angles) * 2 * jnp.pi


def unit_dir(angle):
    """Unit vector ``(cos a, sin a)`` of an angle in radians; shape ``angle.shape + (2,)``."""
    return jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)


def cell_hit_distance(p, u, cell):
    """Ray parameter at which the ray ``p + s u`` first meets the boundary of a cell, or ``inf`` if it never does.

    Args:
        p: ``(..., 2)`` ray origin in cell coordinates.
        u: ``(..., 2)`` unit direction.
        cell: ``(..., 2)`` cell indices ``(i, j)`` (ints or floats), the cell centered at ``(i, j)``.

    Returns:
        ``(...)`` distance in cells (``inf`` if the ray misses the cell). Broadcasts over leading axes.

    The arithmetic is the tutorial's ``solve_lines`` / ``distance`` for each of the four edges, minimum taken.
    """
    p = jnp.asarray(p)[..., None, :]
    u = jnp.asarray(u)[..., None, :]
    dtype = jnp.result_type(p.dtype, u.dtype, jnp.float32)
    q = jnp.asarray(cell, dtype=dtype)[..., None, :] + jnp.asarray(_EDGE_START, dtype=dtype)
    v = jnp.asarray(_EDGE_VEC, dtype=dtype)
    det = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    s = (v[..., 0] * (p[..., 1] - q[..., 1]) - v[..., 1] * (p[..., 0] - q[..., 0])) / det
    t = (u[..., 1] * (q[..., 0] - p[..., 0]) - u[..., 0] * (q[..., 1] - p[..., 1])) / det
    parallel = jnp.abs(det) < PARALLEL_TOL
    hit = ~parallel & (s >= 0.0) & (t >= 0.0) & (t <= 1.0)
    return jnp.min(jnp.where(hit, s, jnp.inf), axis=-1)


@partial(jax.jit, static_argnames=("grid", "max_distance"))
def _sensor_distances(walls, pos, beam_angles, grid: Grid, max_distance: float):
    p = grid.to_cell_coords(jnp.asarray(pos))
    ii, jj = jnp.meshgrid(jnp.arange(grid.shape[0]), jnp.arange(grid.shape[1]), indexing="ij")
    cells = jnp.stack([ii.ravel(), jj.ravel()], axis=-1)
    is_wall = walls.reshape(-1) > 0
    cap = max_distance / grid.resolution

    def one_ray(angle):
        t = cell_hit_distance(p, unit_dir(angle)[None, :], cells)
        return jnp.minimum(jnp.min(jnp.where(is_wall, t, jnp.inf)), cap)

    return jax.vmap(one_ray)(beam_angles) * grid.resolution


def sensor_distances(walls, pos, beam_angles, grid: Grid | None = None, max_distance: float | None = None):
    """Exact distance from ``pos`` along each beam to the first wall cell, capped at ``max_distance``.

    Args:
        walls: ``(nx, ny)`` array, cells > 0 are walls.
        pos: ``(2,)`` sensor position in world coordinates (meters; the tutorial's unit cells by default).
        beam_angles: ``(K,)`` beam angles in radians, world frame.
        grid: the grid geometry; default: the tutorial convention for ``walls.shape`` (resolution 1, cell
            ``(i, j)`` centered at ``(i, j)``).
        max_distance: cap in meters; default :attr:`Grid.default_max_distance` (42 on the tutorial map).

    Returns:
        ``(K,)`` float array of distances in meters. Jit-able and vmap-able in ``walls``, ``pos`` and
        ``beam_angles`` (``grid`` and ``max_distance`` are static).
    """
    walls = jnp.asarray(walls)
    grid = grid or Grid(shape=walls.shape)
    if max_distance is None:
        max_distance = grid.default_max_distance
    return _sensor_distances(walls, pos, jnp.asarray(beam_angles), grid, float(max_distance))


# ---------------------------------------------------------------------------------------------------------------
# The ray-cell table
# ---------------------------------------------------------------------------------------------------------------


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

    @cached_property
    def pair_rays(self) -> np.ndarray:
        """``(P,)`` int64 ray of each pair."""
        return np.repeat(np.arange(self.num_rays), self.lengths)

    @cached_property
    def pair_positions(self) -> np.ndarray:
        """``(P,)`` int64 position of each pair along its ray (0 = closest to the sensor)."""
        return np.arange(self.num_pairs) - np.repeat(self.offsets[:-1], self.lengths)

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
        np.minimum.at(out, self.pair_rays, d)
        return out

    def rays_per_cell(self) -> np.ndarray:
        """``(num_cells,)`` int: how many rays cross each cell."""
        return np.bincount(self.pair_cells, minlength=self.num_cells)


def _candidate_cells(p, u, s_max, shape):
    """Cells that the rays ``p + s u``, ``0 <= s <= s_max`` (cell coordinates) may touch: a superset, found from
    the crossings with the grid lines (each crossing point and its neighbours) and the sensor cell's neighbours.
    Returns ``(ray_index, cell_i, cell_j)`` int arrays (with duplicates)."""
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


def build_ray_table(grid: Grid, origins, beam_angles, max_distance: float | None = None, chunk: int = 1 << 18) -> RayTable:
    """Build the :class:`RayTable` for rays from ``origins`` at ``beam_angles``.

    Args:
        grid: the grid.
        origins: ``(R, 2)`` sensor position of each ray, world meters (or ``(2,)`` for one position, broadcast).
        beam_angles: ``(R,)`` world-frame beam angles, radians.
        max_distance: cap in meters; default :attr:`Grid.default_max_distance`.
        chunk: how many candidate (ray, cell) pairs to evaluate at once.

    Returns:
        The table. Memory and time grow with the number of (ray, cell) pairs, not rays x cells: candidate cells
        come from the ray's crossings with grid lines, then each candidate's exact distance is computed with the
        tutorial's edge arithmetic and kept if it is below the max distance.

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
    dtype = jnp.result_type(float)
    p32 = np.asarray(grid.to_cell_coords(jnp.asarray(origins, dtype=dtype)))
    u32 = np.asarray(unit_dir(jnp.asarray(beam_angles, dtype=dtype)))
    p = p32.astype(np.float64)
    u = u32.astype(np.float64)
    # distance until the ray leaves the grid's box (slab method), capped by the max distance
    lo = np.array([-0.5, -0.5])
    hi = np.array(grid.shape, dtype=np.float64) - 0.5
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - p) / u
        t2 = (hi - p) / u
    exit_s = np.min(np.where(np.isnan(t1), np.inf, np.maximum(t1, t2)), axis=1)
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
        dist[sl] = np.asarray(_pair_distances(p32[rr[sl]], u32[rr[sl]], cell_ij[sl]))
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
