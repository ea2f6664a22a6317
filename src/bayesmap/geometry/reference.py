"""The reference builder of the ray-cell table: the original candidate-and-sort algorithm, slow and memory-hungry on
whole logs, kept because it is obviously right. :func:`bayesmap.geometry.raytable.build_ray_table` must reproduce
its tables (``tests/geometry/test_raytable.py`` compares the two).
"""

from __future__ import annotations

import numpy as np

from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import RayTable, broadcast_origins
from bayesmap.geometry.traversal import cell_frame, exact_pair_distances


def _candidate_cells(p, u, s_max, shape):
    """Cells that the rays ``p + s u``, ``0 <= s <= s_max`` (cell coordinates) may touch: a superset, found from
    the crossings with the grid lines (each crossing point and its neighbours) and the sensor cell's neighbours.
    Returns ``(ray_index, cell_i, cell_j)`` int arrays (with duplicates). Used by :func:`build_ray_table_reference`."""
    nx, ny = shape
    out_rays, out_i, out_j = [], [], []
    num = len(p)
    for axis in (0, 1):
        other = 1 - axis
        component = u[:, axis]
        moving = np.abs(component) > 1e-12
        # grid lines are at k + 0.5; walk from the sensor's line outwards in the direction of travel
        count = np.where(moving, np.ceil(s_max * np.abs(component)) + 2, 0).astype(np.int64)
        width = int(count.max()) if num else 0
        if width == 0:
            continue
        step = np.arange(width)
        direction = np.sign(component)
        start = np.floor(p[:, axis] - 0.5) + np.where(direction > 0, 0, 1)
        lines = start[:, None] + direction[:, None] * step[None, :] + 0.5
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (lines - p[:, axis, None]) / component[:, None]
        valid = moving[:, None] & (step[None, :] < count[:, None]) & (s >= -1e-6) & (s <= s_max[:, None] + 1e-6)
        rays, crossing = np.nonzero(valid)
        line = lines[rays, crossing]
        along = p[rays, other] + s[rays, crossing] * u[rays, other]  # the crossing point's other coordinate
        nearest = np.round(along).astype(np.int64)
        for side in (-0.5, 0.5):
            for offset in (-1, 0, 1):
                across = np.round(line + side).astype(np.int64)
                beside = nearest + offset
                out_rays.append(rays)
                out_i.append(across if axis == 0 else beside)
                out_j.append(beside if axis == 0 else across)
    sensor_cell = np.round(p).astype(np.int64)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            out_rays.append(np.arange(num))
            out_i.append(sensor_cell[:, 0] + di)
            out_j.append(sensor_cell[:, 1] + dj)
    rays = np.concatenate(out_rays)
    i = np.concatenate(out_i)
    j = np.concatenate(out_j)
    inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
    return rays[inside], i[inside], j[inside]


def build_ray_table_reference(grid: Grid, origins, beam_angles, max_distance: float | None = None,
                              chunk: int = 1 << 18) -> RayTable:
    """The reference builder (the original algorithm; slow and memory-hungry on whole logs): same arguments, result
    and errors as :func:`bayesmap.geometry.raytable.build_ray_table`, which must reproduce its tables (the tests
    compare the two).

    Candidate cells come from the ray's crossings with grid lines (a superset, with their neighbours), each
    candidate's exact distance is computed with the tutorial's edge arithmetic (:func:`cell_hit_distance`, in JAX's
    default float dtype, through :func:`exact_pair_distances`) and kept if it is below the max distance; the pairs
    are then sorted by (ray, distance, flat cell index). ``chunk`` is how many candidate (ray, cell) pairs are
    evaluated at once. Time and memory are a few hundred bytes and about a microsecond per candidate pair.

    Changes from the original: the grid's box is widened by more than the float rounding and an axis with ``u = 0``
    no longer gives a NaN exit distance (rays along or grazing the grid's border lost cells), and the pairs are
    evaluated in padded batches (see :func:`exact_pair_distances`).

    Raises:
        BayesmapError: if a sensor position is not finite or lies outside the grid, or ``origins`` has a shape
            other than ``(R, 2)`` or ``(2,)``.
    """
    beam_angles = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
    origins = broadcast_origins(origins, len(beam_angles))
    if max_distance is None:
        max_distance = grid.default_max_distance
    max_distance = float(max_distance)
    for xy in np.unique(origins, axis=0):
        grid.check_inside(xy)
    max_cells = max_distance / grid.resolution
    # in JAX's default float dtype, exactly as the model computes them
    p_table, u_table = cell_frame(grid, origins, beam_angles)
    p = p_table.astype(np.float64)
    u = u_table.astype(np.float64)
    # distance until the ray leaves the grid's box (slab method), capped by the max distance. The box is widened by
    # more than the edge test's float rounding (a ray grazing the border still touches the border cells), and an
    # axis the ray does not move along never ends it (0 / 0 gave NaN here, which dropped rays along the border).
    slack = 1e-3 + 1e-6 * min(max_cells, 1e12)
    lo = np.array([-0.5, -0.5]) - slack
    hi = np.array(grid.shape, dtype=np.float64) - 0.5 + slack
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - p) / u
        t2 = (hi - p) / u
    exit_s = np.min(np.where(u == 0, np.inf, np.maximum(t1, t2)), axis=1)
    s_max = np.minimum(exit_s, max_cells) + 1.0
    rays, cell_i, cell_j = _candidate_cells(p, u, s_max, grid.shape)
    ny = grid.shape[1]
    key = np.unique(rays * grid.num_cells + cell_i * ny + cell_j)
    rays = key // grid.num_cells
    flat = key % grid.num_cells
    cell_indices = np.stack([flat // ny, flat % ny], axis=-1).astype(p_table.dtype)
    dist = np.empty(len(key), dtype=p_table.dtype)
    for start in range(0, len(key), chunk):
        part = slice(start, start + chunk)
        dist[part] = exact_pair_distances(p_table[rays[part]], u_table[rays[part]], cell_indices[part])
    keep = dist < max_cells
    rays, flat, dist = rays[keep], flat[keep], dist[keep]
    order = np.lexsort((flat, dist, rays))
    rays, flat, dist = rays[order], flat[order], dist[order]
    num_rays = len(beam_angles)
    offsets = np.concatenate([[0], np.cumsum(np.bincount(rays, minlength=num_rays))]).astype(np.int64)
    return RayTable(
        grid=grid,
        offsets=offsets,
        pair_cells=flat.astype(np.int32),
        pair_dists=dist * dist.dtype.type(grid.resolution),
        origins=np.array(origins),
        beam_angles=beam_angles,
        max_distance=max_distance,
    )
