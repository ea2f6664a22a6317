"""Exact ray casting (the tutorial's geometry): the distance along each beam to the first wall cell.

The tutorial's sensor model: a ray from the sensor position ``p`` in direction ``u = (cos a, sin a)`` stops at the
first wall cell it meets; the distance to a cell is the smallest ray parameter ``s >= 0`` at which the ray meets
one of the cell's four edges (a segment hit with the segment parameter in ``[0, 1]``, lines closer to parallel than
``|det| < 1e-10`` never hit). The distance is capped at a max distance. Everything here uses exactly that
arithmetic, so the ray-cell table and :func:`sensor_distances` give identical numbers.

All geometry runs in cell coordinates (center of cell ``(i, j)`` at ``(i, j)``) and is scaled by the grid's
resolution, so the tutorial's unit cells and maps in meters are the same code.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.geometry.grid import Grid

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


def scan_endpoints(poses, sensor_angles, readings, xp=jnp):
    """World endpoints of scans: each beam's reading along its world direction from its pose. Jittable.

    Args:
        poses: ``(..., 3)`` sensor poses (x, y in meters or cells, theta radians).
        sensor_angles: ``(..., K)`` beam angles relative to the heading, radians.
        readings: ``(..., K)`` readings, the units of ``poses``.
        xp: the array module, ``jax.numpy`` (float32 unless x64 is enabled) or ``numpy`` (float64 for float64
            inputs).

    Returns:
        ``(..., K, 2)`` endpoints.
    """
    theta = poses[..., 2:3] + sensor_angles
    return poses[..., None, :2] + readings[..., None] * xp.stack([xp.cos(theta), xp.sin(theta)], axis=-1)


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


def cell_exit_distance(p, u, cell, xp=jnp):
    """Ray parameter at which the ray ``p + s u`` leaves a cell it crosses (the chord geometry's exit distance),
    by the slab method (Kay & Kajiya 1986; Amanatides & Woo 1987): ``min`` over the axes the ray moves along
    (``|u_a| >= PARALLEL_TOL``, as the edge test) of ``(cell_a + sign(u_a) / 2 - p_a) / u_a``.

    Args:
        p: ``(..., 2)`` ray origin in cell coordinates.
        u: ``(..., 2)`` unit direction.
        cell: ``(..., 2)`` cell indices ``(i, j)``, the cell centered at ``(i, j)``.
        xp: the array module, ``jax.numpy`` (default, for the model) or ``numpy`` (for the ray-cell table).

    Returns:
        ``(...)`` distance in cells, in the dtype of ``p`` and ``u`` (``inf`` for a ray that moves along neither
        axis). For a cell the ray does not cross the number has no meaning. Never raises.
    """
    faces = _face_distances(p, u, cell, xp)
    return xp.minimum(faces[..., 0], faces[..., 1])  # (the same numbers as ``min`` over the axis, faster in numpy)


def _face_distances(p, u, cell, xp=jnp):
    """``(..., 2)`` the ray parameter at which the ray reaches the cell's far face along each axis (``inf`` for an
    axis it does not move along): :func:`cell_exit_distance` is their minimum, and the axis of the minimum is the
    one along which the ray leaves the cell."""
    moving = xp.abs(u) >= PARALLEL_TOL
    face = xp.asarray(cell, dtype=p.dtype) + xp.where(u > 0, 0.5, -0.5).astype(p.dtype)
    return xp.where(moving, (face - p) / xp.where(moving, u, 1.0), xp.inf)


def _ray_setup(walls, pos, grid: Grid):
    """The ray origin ``p`` (cell coordinates), every cell ``(nx ny, 2)`` and the wall mask ``(nx ny,)``, for
    :func:`first_hit_distances` and :func:`first_hit_chords`."""
    p = grid.to_cell_coords(jnp.asarray(pos))
    ii, jj = jnp.meshgrid(jnp.arange(grid.shape[0]), jnp.arange(grid.shape[1]), indexing="ij")
    cells = jnp.stack([ii.ravel(), jj.ravel()], axis=-1)
    is_wall = walls.reshape(-1) > 0
    return p, cells, is_wall


@partial(jax.jit, static_argnames=("grid", "max_distance"))
def first_hit_distances(walls, pos, beam_angles, grid: Grid, max_distance: float):
    """The jitted core of :func:`sensor_distances` (which fills in the defaults), for callers that already have a
    :class:`Grid` and a max distance: every ray against every cell (``K x nx ny`` edge tests).

    Args:
        walls: ``(nx, ny)`` JAX array, cells > 0 are walls.
        pos: ``(2,)`` sensor position, world meters.
        beam_angles: ``(K,)`` world-frame beam angles, radians.
        grid: the grid (static).
        max_distance: the max distance, meters (static).

    Returns:
        ``(K,)`` distances in meters, JAX's default float dtype, at most ``max_distance``.
    """
    p, cells, is_wall = _ray_setup(walls, pos, grid)
    max_cells = max_distance / grid.resolution

    def one_ray(angle):
        distances = cell_hit_distance(p, unit_dir(angle)[None, :], cells)
        return jnp.minimum(jnp.min(jnp.where(is_wall, distances, jnp.inf)), max_cells)

    return jax.vmap(one_ray)(beam_angles) * grid.resolution


@partial(jax.jit, static_argnames=("grid", "max_distance"))
def first_hit_chords(walls, pos, beam_angles, grid: Grid, max_distance: float):
    """The chord of each beam through its first wall cell: entry and exit distance (the chord geometry,
    :mod:`bayesmap.model.sensor`).

    The first wall cell is the wall with the smallest entry distance (:func:`cell_hit_distance`), ties broken by the
    smallest flat index ``i * ny + j`` (the ray-cell table's order); its exit distance is
    :func:`cell_exit_distance`. Both are capped at ``max_distance`` and the exit is at least the entry; a beam with
    no wall within ``max_distance`` has entry = exit = ``max_distance``.

    The arguments are those of :func:`first_hit_distances`.

    Returns:
        ``(K, 2)`` entry and exit distances in meters, JAX's default float dtype; column 0 equals
        :func:`first_hit_distances`. Never raises.
    """
    return wall_hit_chords(walls, pos, beam_angles, grid, max_distance, 1)[:, 0]


def wall_hit_chords(walls, pos, beam_angles, grid: Grid, max_distance: float, count: int):
    """The chords of each beam through its first ``count`` wall cells, in order along the beam (the first as in
    :func:`first_hit_chords`, the next the wall with the smallest entry distance among the rest, ties again by flat
    index: the ray-cell table's order). A wall that does not exist within ``max_distance`` gets entry = exit =
    ``max_distance``. The other arguments are those of :func:`first_hit_distances`; ``count`` >= 1 (static).

    Returns:
        ``(K, count, 2)`` entry and exit distances in meters, JAX's default float dtype. Never raises.
    """
    p, cells, is_wall = _ray_setup(walls, pos, grid)
    max_cells = max_distance / grid.resolution

    def one_ray(angle):
        u = unit_dir(angle)
        distances = jnp.where(is_wall, cell_hit_distance(p, u[None, :], cells), jnp.inf)
        out = []
        for _ in range(count):
            k = jnp.argmin(distances)  # the first of equal minima: the smallest flat index
            entry = jnp.minimum(distances[k], max_cells)
            exit_ = cell_exit_distance(p, u, cells[k].astype(p.dtype))
            out.append(jnp.stack([entry, jnp.clip(exit_, entry, max_cells)]))
            distances = distances.at[k].set(jnp.inf)
        return jnp.stack(out)

    return jax.vmap(one_ray)(beam_angles) * grid.resolution


def sensor_distances(walls, pos, beam_angles, grid: Grid | None = None, max_distance: float | None = None):
    """Exact distance from ``pos`` along each beam to the first wall cell, capped at ``max_distance``.

    Args:
        walls: ``(nx, ny)`` array, cells > 0 are walls.
        pos: ``(2,)`` sensor position in world coordinates (meters; the tutorial's unit cells by default).
        beam_angles: ``(K,)`` beam angles in radians, world frame.
        grid: the grid geometry; default: the tutorial convention for ``walls.shape`` (resolution 1, cell
            ``(i, j)`` centered at ``(i, j)``).
        max_distance: the max distance, meters; default :attr:`Grid.default_max_distance` (42 on the tutorial map).

    Returns:
        ``(K,)`` float array of distances in meters. Jit-able and vmap-able in ``walls``, ``pos`` and
        ``beam_angles`` (``grid`` and ``max_distance`` are static).
    """
    walls = jnp.asarray(walls)
    grid = grid or Grid(shape=walls.shape)
    if max_distance is None:
        max_distance = grid.default_max_distance
    return first_hit_distances(walls, pos, jnp.asarray(beam_angles), grid, float(max_distance))


def _march_start(p, u, shape):
    """A traversal's start along ``u`` from ``p`` (cell coordinates) in a grid of ``shape``: the first cell
    ``(2,)`` int32 (``-1`` for a ray that misses the grid), the ray parameters ``t_max`` ``(2,)`` of the next cell
    boundary per axis and ``t_delta`` ``(2,)`` between boundaries, and the step ``(2,)`` int32 per axis (Amanatides
    & Woo 1987)."""
    big = jnp.asarray(jnp.inf, p.dtype)
    n = jnp.asarray(shape, jnp.int32)
    with_u = jnp.abs(u) > PARALLEL_TOL
    safe_u = jnp.where(with_u, u, 1.0)
    # a sensor outside the grid: start where the ray enters the box of the cells (slab method)
    low, high = (-0.5 - p) / safe_u, (n.astype(p.dtype) - 0.5 - p) / safe_u
    inside_slab = (p >= -0.5) & (p <= n.astype(p.dtype) - 0.5)
    t_in = jnp.where(with_u, jnp.minimum(low, high), jnp.where(inside_slab, -big, big))
    t_out = jnp.where(with_u, jnp.maximum(low, high), jnp.where(inside_slab, big, -big))
    t_enter, t_exit = jnp.maximum(jnp.max(t_in), 0.0), jnp.min(t_out)
    start = p + jnp.where(t_enter > 0, t_enter, 0.0) * u
    cell = jnp.clip(jnp.floor(start + 0.5).astype(jnp.int32), 0, n - 1)
    cell = jnp.where(t_enter <= t_exit, cell, -1)  # a ray that misses the grid: nothing to visit
    step = jnp.where(u >= 0, 1, -1).astype(jnp.int32)
    boundary = cell.astype(p.dtype) + 0.5 * step.astype(p.dtype)
    t_max = jnp.where(with_u, (boundary - p) / safe_u, big)
    t_delta = jnp.where(with_u, 1.0 / jnp.abs(safe_u), big)
    return cell, t_max, t_delta, step


def _in_grid(c, n):
    """Whether cell indices ``(..., 2)`` lie in a grid of shape ``n`` ``(2,)``: ``(...)`` bool."""
    return jnp.all((c >= 0) & (c < n), axis=-1)


def _march_result(is_wall, p, u, c, hit, max_cells):
    """Entry and exit distance ``(2,)`` in cells of a traversal that ended in cell ``c``: its wall cell's if
    ``hit``, both ``max_cells`` if not.

    The first wall cell is the all-cells cast's (:func:`wall_hit_chords`): the wall cell of the smallest
    :func:`cell_hit_distance`, ties by flat index. For a sensor inside a wall cell, that cell's distance is where the
    ray leaves it, which is also where the next cell along the ray is entered: if that cell is a wall too, the two
    are compared as the all-cells cast compares them (for a wall reached from outside, the next cell is entered
    later, so nothing changes)."""
    n = jnp.asarray(is_wall.shape, jnp.int32)
    axis = jnp.argmin(_face_distances(p, u, c))
    nxt = c.at[axis].add(jnp.where(u[axis] > 0, 1, -1).astype(c.dtype))
    inside = _in_grid(nxt, n)
    safe = jnp.clip(nxt, 0, n - 1)
    d_here, d_next = cell_hit_distance(p, u, c), cell_hit_distance(p, u, nxt)
    flat_here, flat_next = c[0] * n[1] + c[1], nxt[0] * n[1] + nxt[1]
    earlier = (d_next < d_here) | ((d_next == d_here) & (flat_next < flat_here))
    c = jnp.where(hit & inside & is_wall[safe[0], safe[1]] & earlier, nxt, c)
    entry = jnp.where(hit, jnp.minimum(cell_hit_distance(p, u, c), max_cells), max_cells)
    exit_ = jnp.clip(cell_exit_distance(p, u, c.astype(p.dtype)), entry, max_cells)
    return jnp.stack([entry, jnp.where(hit, exit_, max_cells)])


def _march_one(is_wall, p, u, shape, max_cells, stop):
    """Entry and exit distance ``(2,)`` in cells from ``p`` along ``u`` of the first wall cell of ``is_wall``
    ``(nx, ny)`` bool, by grid traversal, capped at ``max_cells`` (both ``max_cells`` if no wall is reached, or if
    the first wall cell is entered at or beyond ``stop`` cells along the traversal); see :func:`march_first_hit` and
    :func:`march_first_chord`."""
    n = jnp.asarray(shape, jnp.int32)
    cell, t_max, t_delta, step = _march_start(p, u, shape)

    def cond(carry):
        c, t_max, entry, hit = carry
        return ~hit & _in_grid(c, n) & (entry < max_cells) & (entry < stop)

    def body(carry):
        c, t_max, entry, hit = carry
        wall = is_wall[c[0], c[1]]
        axis = jnp.argmin(t_max)
        nxt = c.at[axis].add(step[axis])
        return (jnp.where(wall, c, nxt), jnp.where(wall, t_max, t_max.at[axis].add(t_delta[axis])),
                jnp.where(wall, entry, t_max[axis]), wall)

    c, _, _, hit = jax.lax.while_loop(cond, body, (cell, t_max, jnp.zeros((), p.dtype), jnp.bool_(False)))
    return _march_result(is_wall, p, u, c, hit, max_cells)


def _march_lanes(is_wall, origins, directions, shape, max_cells, stops, lanes: int):
    """:func:`_march_one` for every ray ``(R, 2)`` in cells (origins ``(R, 2)`` or ``(2,)`` and stops ``(R,)`` in
    cells), the same numbers, by ``lanes`` traversals at a time that each take the next ray when theirs ends
    (longest stop first): the loop's steps follow the rays' total length instead of ``R`` times the longest ray's."""
    num_rays = directions.shape[0]
    n = jnp.asarray(shape, jnp.int32)
    origins = jnp.broadcast_to(origins, directions.shape)
    starts = jax.vmap(lambda p, u: _march_start(p, u, shape))(origins, directions) + (stops,)
    order = jnp.argsort(-stops).astype(jnp.int32)  # the queue: longest stop first

    def start_of(ray):
        """Each lane's ray's start ``(cell, t_max, t_delta, step, stop)`` (a lane past the queue: any ray's)."""
        return tuple(a[jnp.minimum(ray, num_rays - 1)] for a in starts)

    def cond(state):
        return jnp.any(state[0] < num_rays)

    def body(state):
        ray, (c, t_max, t_delta, step, stop), entry, hit_cells, hits, queued = state
        active = ray < num_rays
        go = active & _in_grid(c, n) & (entry < max_cells) & (entry < stop)
        cc = jnp.clip(c, 0, n - 1)
        wall = go & is_wall[cc[:, 0], cc[:, 1]]
        advance = go & ~wall
        axis = jnp.argmin(t_max, axis=-1)
        along = jax.nn.one_hot(axis, 2, dtype=jnp.int32) * advance[:, None]
        entry = jnp.where(advance, jnp.take_along_axis(t_max, axis[:, None], axis=-1)[:, 0], entry)
        c = c + along * step
        t_max = t_max + along.astype(t_max.dtype) * t_delta
        done = active & ~advance  # a wall (hit) or its end (no hit): record, then take the next ray
        slot = jnp.where(done, ray, num_rays)  # out of range: dropped
        hit_cells = hit_cells.at[slot].set(c, mode="drop")
        hits = hits.at[slot].set(wall, mode="drop")
        position = queued + jnp.cumsum(done, dtype=jnp.int32) - 1
        ray = jnp.where(done, jnp.where(position < num_rays, order[jnp.minimum(position, num_rays - 1)], num_rays),
                        ray)
        fresh = start_of(ray)
        lane = tuple(jnp.where(done.reshape((-1,) + (1,) * (a.ndim - 1)), b, a)
                     for a, b in zip((c, t_max, t_delta, step, stop), fresh, strict=True))
        entry = jnp.where(done, jnp.zeros((), entry.dtype), entry)
        return ray, lane, entry, hit_cells, hits, queued + jnp.sum(done, dtype=jnp.int32)

    first = jnp.arange(lanes, dtype=jnp.int32)
    ray = jnp.where(first < num_rays, order[jnp.minimum(first, num_rays - 1)], num_rays)
    state = (ray, start_of(ray), jnp.zeros((lanes,), directions.dtype), jnp.zeros((num_rays, 2), jnp.int32),
             jnp.zeros((num_rays,), bool), jnp.asarray(min(lanes, num_rays), jnp.int32))
    _, _, _, hit_cells, hits, _ = jax.lax.while_loop(cond, body, state)
    return jax.vmap(lambda p, u, c, h: _march_result(is_wall, p, u, c, h, max_cells))(origins, directions,
                                                                                      hit_cells, hits)


def _stop_cells(stops, count: int, max_cells: float, resolution: float, dtype):
    """``(count,)`` each ray's stop in cells: ``stops`` (meters) over the resolution, or ``max_cells`` for None."""
    if stops is None:
        return jnp.full((count,), max_cells, dtype)
    return jnp.asarray(stops, dtype).reshape(-1) / jnp.asarray(resolution, dtype)


@partial(jax.jit, static_argnames=("grid", "max_distance"))
def march_first_hit(walls, pos, beam_angles, grid: Grid, max_distance: float, stops=None):
    """:func:`first_hit_distances` by grid traversal (Amanatides & Woo 1987, "A Fast Voxel Traversal Algorithm for
    Ray Tracing"): each ray visits only the cells it crosses, in order, up to its first wall (work proportional to
    the distance, not to the grid's size), and the distance to that wall is :func:`cell_hit_distance`, the
    tutorial's arithmetic. The numbers equal :func:`first_hit_distances`' except for a ray that passes a grid vertex
    to within rounding, whose diagonal neighbour the edge test may count and the traversal does not (tests compare
    them on random maps).

    Args:
        walls: ``(nx, ny)`` array, cells > 0 are walls.
        pos: ``(2,)`` sensor position, world meters.
        beam_angles: ``(K,)`` world-frame beam angles, radians.
        grid: the grid (static).
        max_distance: the max distance, meters (static).
        stops: optional ``(K,)`` float, meters: how far along each beam to look for its first wall. A beam whose
            first wall cell is entered at or beyond its stop (the traversal's entry distance) reports no wall,
            ``max_distance``, without visiting the cells past it: a beam cut past its reading
            (:func:`bayesmap.model.generative.cut_chords`) needs no wall beyond the cut. None: every beam up to
            ``max_distance``.

    Returns:
        ``(K,)`` distances in meters, JAX's default float dtype, at most ``max_distance``. Never raises.
    """
    return _march(walls, pos, beam_angles, grid, max_distance, stops)[:, 0]


@partial(jax.jit, static_argnames=("grid", "max_distance"))
def march_first_chord(walls, pos, beam_angles, grid: Grid, max_distance: float, stops=None):
    """:func:`first_hit_chords` by the grid traversal of :func:`march_first_hit`: the entry and exit distance of each
    beam's first wall cell (the chord geometry, :mod:`bayesmap.model.sensor`), the exit by
    :func:`cell_exit_distance` as there. Equal to :func:`first_hit_chords` except for a ray that passes a grid vertex
    to within rounding (as :func:`march_first_hit`; tests compare them on random maps).

    The arguments are those of :func:`march_first_hit`.

    Returns:
        ``(K, 2)`` entry and exit distances in meters, JAX's default float dtype, ``entry <= exit <= max_distance``;
        column 0 equals :func:`march_first_hit`. Never raises.
    """
    return _march(walls, pos, beam_angles, grid, max_distance, stops)


def _march(walls, pos, beam_angles, grid: Grid, max_distance: float, stops=None):
    """``(K, 2)`` entry and exit distances, meters, of :func:`_march_one` for every beam (``stops``: ``(K,)``
    meters or None)."""
    p = grid.to_cell_coords(jnp.asarray(pos, jnp.result_type(float)))
    is_wall = jnp.asarray(walls) > 0
    max_cells = max_distance / grid.resolution
    directions = unit_dir(jnp.asarray(beam_angles, p.dtype))
    stop_cells = _stop_cells(stops, directions.shape[0], max_cells, grid.resolution, p.dtype)
    return jax.vmap(lambda u, stop: _march_one(is_wall, p, u, grid.shape, max_cells, stop))(
        directions, stop_cells) * grid.resolution


MARCH_LANES = 1024
"""How many traversals :func:`march_ray_chords` runs at once (a speed setting; no effect on the numbers). Each loop
step advances every lane by one cell and hands a finished lane the next ray. Measured on the 2-core machine, the
pose moves' batch of 220 ACES scans (39,600 rays at 0.1 m, cut 0.5 m past the readings): 1,024 lanes 69-72 ms, 512
95 ms, 2,048 110 ms, 4,096 106 ms, 128 102 ms; one scan at a time by :func:`march_first_chord`, 275 ms
([validation](../validation/scale.md#pose-moves-in-two-batches))."""


@partial(jax.jit, static_argnames=("grid", "max_distance", "lanes"))
def march_ray_chords(walls, origins, beam_angles, grid: Grid, max_distance: float, stops=None,
                     lanes: int = MARCH_LANES):
    """:func:`march_first_chord` for rays of many scans at once, each ray from its own origin: the entry and exit
    distance of each ray's first wall cell by grid traversal (the same numbers as :func:`march_first_chord` of each
    ray, tested), ``lanes`` traversals at a time, each taking the next ray when its own ends, longest stop first. The
    loop then runs about ``sum of the rays' lengths / lanes`` steps where a batch of whole scans would run as long
    as its longest ray, every ray stepping until it ends.

    Args:
        walls: ``(nx, ny)`` array, cells > 0 are walls.
        origins: ``(R, 2)`` each ray's sensor position, world meters.
        beam_angles: ``(R,)`` world-frame ray angles, radians.
        grid: the grid (static).
        max_distance: the max distance, meters (static).
        stops: optional ``(R,)`` float, meters: as :func:`march_first_hit`'s (a ray whose first wall cell is entered
            at or beyond its stop reports no wall); None: every ray up to ``max_distance``.
        lanes: traversals at once (static; :data:`MARCH_LANES`).

    Returns:
        ``(R, 2)`` entry and exit distances in meters, JAX's default float dtype, each row's entry at most its exit,
        both at most ``max_distance``. Never raises.
    """
    dtype = jnp.result_type(float)
    is_wall = jnp.asarray(walls) > 0
    origins = grid.to_cell_coords(jnp.asarray(origins, dtype).reshape(-1, 2))
    directions = unit_dir(jnp.asarray(beam_angles, dtype).reshape(-1))
    max_cells = max_distance / grid.resolution
    stop_cells = _stop_cells(stops, directions.shape[0], max_cells, grid.resolution, dtype)
    lanes = max(1, min(int(lanes), directions.shape[0]))
    return _march_lanes(is_wall, origins, directions, grid.shape, max_cells, stop_cells, lanes) * grid.resolution
