"""The sparse ray-cell table: for every ray (beam), the cells it crosses in order and the distance at which it
would stop in each, built in closed form (Amanatides & Woo crossings, :mod:`bayesmap.geometry.traversal`) with exactly
the arithmetic of :func:`bayesmap.geometry.raycast.sensor_distances`, so the table and the exact ray cast give
identical numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import cell_exit_distance
from bayesmap.geometry.traversal import cell_frame, trace_rays

_CHUNK_PAIRS = 1 << 18  # pairs per chunk of numpy passes over all pairs (temporaries of <= 2 MB: malloc reuses them)


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
        max_distance: the max distance (meters): pairs at this distance or beyond are not listed.
        ray_limits: ``(R,)`` float (the dtype of ``pair_dists``) each ray's own max distance, meters, at most
            ``max_distance``: pairs at it or beyond are not listed (a beam cut past its reading,
            :func:`bayesmap.model.generative.ray_limits`); None: ``max_distance`` for every ray. A ray with no wall
            among its pairs still has the "no wall" distance ``max_distance``.
    """

    grid: Grid
    offsets: np.ndarray
    pair_cells: np.ndarray
    pair_dists: np.ndarray
    origins: np.ndarray
    beam_angles: np.ndarray
    max_distance: float
    ray_limits: np.ndarray | None = None

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
        """``(P,)`` int64 ray of each pair (computed once and kept: 8 bytes per pair; :meth:`rays_of_pairs` for a
        few pairs)."""
        return self.per_pair(np.arange(self.num_rays))

    def rays_of_pairs(self, pairs) -> np.ndarray:
        """``pairs.shape`` int64, the ray of each of ``pairs`` (pair indices, any order): ``pair_rays[pairs]``
        without building :attr:`pair_rays` (a binary search in :attr:`offsets`)."""
        return np.searchsorted(self.offsets, pairs, side="right") - 1

    def rays_of_range(self, start: int, stop: int) -> np.ndarray:
        """``(stop - start,)`` int64, the ray of each pair ``start .. stop - 1`` (``0 <= start < stop <= P``):
        ``pair_rays[start:stop]``, each ray's index repeated over its pairs in the range (two binary searches, where
        :meth:`rays_of_pairs` does one a pair)."""
        first, last = np.searchsorted(self.offsets, [start, stop - 1], side="right") - 1
        bounds = np.clip(self.offsets[first:last + 2], start, stop)
        return np.repeat(np.arange(first, last + 1, dtype=np.int64), np.diff(bounds))

    @cached_property
    def pair_positions(self) -> np.ndarray:
        """``(P,)`` int64 position of each pair along its ray (0 = closest to the sensor)."""
        return np.arange(self.num_pairs) - self.per_pair(self.offsets[:-1])

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

    @cached_property
    def pair_exits(self) -> np.ndarray:
        """``(P,)`` exit distance of each pair (meters, the dtype of :attr:`pair_dists`): where the ray leaves the
        cell (:func:`~bayesmap.geometry.raycast.cell_exit_distance` in float64 cell coordinates from the numbers
        the table was traced from), at least the pair's entry distance and at most the max distance. The chord
        geometry's ``b`` (:mod:`bayesmap.model.sensor`); computed on first use, a chunk of pairs at a time (4 bytes
        per pair in float32)."""
        out = np.empty(self.num_pairs, dtype=self.pair_dists.dtype)
        if not self.num_pairs:
            return out
        frame = self._frame()
        for start in range(0, self.num_pairs, _CHUNK_PAIRS):
            stop = min(start + _CHUNK_PAIRS, self.num_pairs)
            out[start:stop] = self._exits(np.arange(start, stop), frame, self.rays_of_range(start, stop))
        return out

    def _frame(self) -> tuple[np.ndarray, np.ndarray]:
        """The rays' origins and unit directions ``(R, 2)`` in cell coordinates (:func:`cell_frame`), in float64."""
        p_table, u_table = cell_frame(self.grid, self.origins, self.beam_angles)
        return p_table.astype(np.float64), u_table.astype(np.float64)

    def exits_of_pairs(self, pairs) -> np.ndarray:
        """``pairs.shape`` exit distances (meters, the dtype of :attr:`pair_dists`) of the pairs ``pairs`` (pair
        indices, any order): ``pair_exits[pairs]``, to the bit, without computing every pair's."""
        return self._exits(pairs, self._frame())

    def _exits(self, pairs, frame, rays=None) -> np.ndarray:
        """:meth:`exits_of_pairs` given the rays' :meth:`_frame` (computed once by callers that need many) and,
        where the caller has them, the pairs' rays."""
        pairs = np.asarray(pairs, dtype=np.int64)
        dtype = self.pair_dists.dtype
        if not pairs.size:
            return np.empty(pairs.shape, dtype=dtype)
        rays = self.rays_of_pairs(pairs) if rays is None else rays
        p, u = frame[0][rays], frame[1][rays]
        flat = self.pair_cells[pairs].astype(np.int64)
        cells = np.stack([flat // self.grid.shape[1], flat % self.grid.shape[1]], axis=-1).astype(np.float64)
        exits = cell_exit_distance(p, u, cells, xp=np).astype(dtype) * dtype.type(self.grid.resolution)
        return np.clip(exits, self.pair_dists[pairs], dtype.type(self.max_distance))

    def first_wall_chords(self, walls) -> np.ndarray:
        """``(R, 2)`` entry and exit distance (meters) of each ray's first wall cell, both the max distance for a ray
        with no wall: :func:`~bayesmap.geometry.raycast.first_hit_chords` from the table (column 0 is
        :meth:`first_wall_distances`; the exit is :attr:`pair_exits` of the first wall pair)."""
        return self.wall_chords(walls, 1)[:, 0]

    def wall_chords(self, walls, count: int) -> np.ndarray:
        """``(R, count, 2)`` entry and exit distances (meters) of each ray's first ``count`` wall cells in order
        along it, both the max distance for a wall the ray does not have:
        :func:`~bayesmap.geometry.raycast.wall_hit_chords` from the table."""
        is_wall = np.asarray(walls).reshape(-1)[self.pair_cells] > 0
        out = np.full((self.num_rays, count, 2), self.max_distance, dtype=self.pair_dists.dtype)
        frame = self._frame() if self.num_pairs else None
        for k in range(count):
            first = np.full(self.num_rays, self.num_pairs, dtype=np.int64)
            wall_pairs = np.flatnonzero(is_wall)
            np.minimum.at(first, self.pair_rays[wall_pairs], wall_pairs)
            hit = first < self.num_pairs
            out[hit, k, 0] = self.pair_dists[first[hit]]
            out[hit, k, 1] = self._exits(first[hit], frame)
            is_wall[first[hit]] = False
        return out

    def ray(self, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Cells ``(n,)`` int32 and stopping distances ``(n,)`` (meters) of ray ``r``, in order along the ray."""
        pairs = slice(int(self.offsets[r]), int(self.offsets[r + 1]))
        return self.pair_cells[pairs], self.pair_dists[pairs]

    def first_wall_distances(self, walls) -> np.ndarray:
        """Distance of each ray to its first wall (meters, ``(R,)``), capped at ``max_distance``; equals
        :func:`sensor_distances` for every ray."""
        is_wall = np.asarray(walls).reshape(-1)[self.pair_cells] > 0
        wall_dists = np.where(is_wall, self.pair_dists, self.max_distance)
        out = np.full(self.num_rays, self.max_distance, dtype=self.pair_dists.dtype)
        crossed = self.lengths > 0  # (reduceat reads one value of an empty segment: rays without pairs are left out)
        out[crossed] = np.minimum(out[crossed], np.minimum.reduceat(wall_dists, self.offsets[:-1][crossed]))
        return out

    def rays_per_cell(self) -> np.ndarray:
        """``(num_cells,)`` int64: how many rays cross each cell (counted a chunk of pairs at a time: ``np.bincount``
        copies its input to int64 first)."""
        counts = np.zeros(self.num_cells, dtype=np.int64)
        for start in range(0, self.num_pairs, _CHUNK_PAIRS):
            counts += np.bincount(self.pair_cells[start:start + _CHUNK_PAIRS], minlength=self.num_cells)
        return counts

    def replace_rays(self, rays, origins, beam_angles, chunk: int = 1 << 18) -> RayTable:
        """This table with rays ``rays`` moved to new ``origins`` and ``beam_angles``: only those rays are traced
        (by :func:`build_ray_table`) and their rows spliced into copies of the compressed-row arrays.

        For latent poses: when the pose of one scan (or a few) changes, replace the rays of those scans. In a table
        built scan after scan (as :mod:`bayesmap.scenes` builds it), scan ``s`` of ``K`` beams is the rays
        ``s K .. (s + 1) K - 1``.

        Args:
            rays: ``(M,)`` distinct ints in ``[0, num_rays)``, the rays to replace, in any order.
            origins: ``(M, 2)`` new sensor position of each of them, world meters (or ``(2,)`` for all of them).
            beam_angles: ``(M,)`` their new world-frame beam angles, radians.
            chunk: as in :func:`build_ray_table`.

        Returns:
            A new :class:`RayTable` (this one is not modified) equal, array for array (``offsets``,
            ``pair_cells``, ``pair_dists``, ``origins``, ``beam_angles``), to :func:`build_ray_table` of all rays
            at their new origins and angles: a ray's row depends only on its own origin and angle. The cached
            per-pair views this table has already computed (:attr:`lengths`, :attr:`pair_rays`,
            :attr:`pair_positions`) are spliced too, equal to recomputing them; the table has no cached per-cell
            views (:meth:`pairs_by_cell` and :meth:`rays_per_cell` compute theirs on each call).

        Cost: the tracing is proportional to the replaced rays (their grid-line crossings, the same work as a table
        of those rays alone), not to the table. Assembling the result copies each per-pair array once, in one
        contiguous block per run of consecutive replaced or kept rays (a memory copy, no per-pair Python loop, no
        sort), and the per-ray arrays once (``O(num_rays)``). Measured on the Intel table (every third scan at 0.1 m:
        54,720 rays, 13.4 M pairs), moving two scans takes about 50 ms (half of it the copy) against 2.7 s for a
        rebuild, once JAX has compiled the cell-frame arithmetic for that number of rays (about a second on the
        first call with a new ``M``).

        Raises:
            BayesmapError: if a ray index is not an integer, outside ``[0, num_rays)`` or repeated; if the numbers
                of rays and beam angles differ; if the table's distances are not in JAX's current default float
                dtype (x64 switched since it was built); and as :func:`build_ray_table` for bad origins or angles.
        """
        rays = np.asarray(rays)
        if rays.size and not np.issubdtype(rays.dtype, np.integer):
            raise BayesmapError(f"ray indices must be integers, got {rays.dtype} values")
        rays = rays.astype(np.int64).reshape(-1)
        bad = np.flatnonzero((rays < 0) | (rays >= self.num_rays))
        if len(bad):
            raise BayesmapError(f"ray index {rays[bad[0]]} is outside [0, {self.num_rays})")
        beam_angles = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
        if len(beam_angles) != len(rays):
            raise BayesmapError(f"{len(rays)} rays to replace but {len(beam_angles)} beam angles")
        origins = broadcast_origins(origins, len(rays))
        order = np.argsort(rays, kind="stable")
        rays = rays[order]
        repeated = np.flatnonzero(np.diff(rays) == 0)
        if len(repeated):
            raise BayesmapError(f"ray {rays[repeated[0]]} is listed twice")
        limits = None if self.ray_limits is None else self.ray_limits[rays]
        new_rows = build_ray_table(self.grid, origins[order], beam_angles[order], self.max_distance, chunk, limits)
        if new_rows.pair_dists.dtype != self.pair_dists.dtype:
            raise BayesmapError(f"the table's distances are {self.pair_dists.dtype} but JAX's default float is now "
                                f"{new_rows.pair_dists.dtype}: rebuild the table")
        return _splice_rows(self, rays, new_rows)


def broadcast_origins(origins, num_rays: int) -> np.ndarray:
    """``(num_rays, 2)`` float64 view of ``origins`` (``(num_rays, 2)``, or ``(2,)`` for all rays), meters.

    Raises:
        BayesmapError: if ``origins`` has another shape.
    """
    values = np.asarray(origins, dtype=np.float64)
    try:
        return np.broadcast_to(values, (num_rays, 2))
    except ValueError:
        raise BayesmapError(f"sensor origins must have shape ({num_rays}, 2) or (2,) (meters), "
                            f"got shape {values.shape}") from None


def _checked_rays(grid: Grid, origins, beam_angles, max_distance: float | None):
    """Validated ``(origins (R, 2) float64, beam_angles (R,) float64, max_distance float)`` (meters, radians),
    the max distance defaulting to :attr:`Grid.default_max_distance`; raises as :func:`build_ray_table` says."""
    beam_angles = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
    origins = broadcast_origins(origins, len(beam_angles))
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
    for ray in np.flatnonzero(outside):
        grid.check_inside(origins[ray])
    return origins, beam_angles, max_distance


def build_ray_table(grid: Grid, origins, beam_angles, max_distance: float | None = None,
                    chunk: int = 1 << 18, ray_limits=None) -> RayTable:
    """Build the :class:`RayTable` for rays from ``origins`` at ``beam_angles``.

    Args:
        grid: the grid.
        origins: ``(R, 2)`` sensor position of each ray, world meters (or ``(2,)`` for one position, broadcast).
        beam_angles: ``(R,)`` world-frame beam angles, radians.
        max_distance: the max distance, meters (finite, ``>= 0``); default :attr:`Grid.default_max_distance`.
        chunk: about how many (ray, cell) slots to trace at once (whole rays; bounds the temporaries, about 150
            bytes per slot); up to :data:`bayesmap.geometry.traversal.TRACE_THREADS` chunks are traced at a time,
            one per core.
        ray_limits: ``(R,)`` each ray's own max distance, meters (``<= max_distance``; a ray's pairs at it or
            beyond are left out, compared in the table's dtype: :attr:`RayTable.ray_limits`); None: none.

    Returns:
        The table: for each ray every cell whose tutorial distance (:func:`cell_hit_distance`, in JAX's default
        float dtype, meters after scaling by the resolution) is below the max distance, sorted by distance, ties
        by flat cell index. It is the same table as the reference builder's
        (:func:`bayesmap.geometry.reference.build_ray_table_reference`):
        same offsets, cells and order, and distances equal to the last bit (they come from the same two float
        roundings, or from the same jitted function); the tests check cells and offsets exactly and distances to
        1e-5 relative + 1e-5 cells. (Whether a ray that passes a grid vertex within an ulp touches the diagonal
        cell is decided by the edge test's float rounding, which in XLA can depend on the batch layout; both
        builders evaluate such pairs the same way, see
        :func:`bayesmap.geometry.traversal.exact_pair_distances`.)

    Algorithm: grid traversal in closed form (Amanatides & Woo 1987, "A Fast Voxel Traversal Algorithm for Ray
    Tracing"), vectorized over all rays of a chunk, without a sort; the cells around a grid vertex that a ray passes
    within the edge test's float rounding get the exact edge arithmetic (:mod:`bayesmap.geometry.traversal`, which
    also says how the slots, distances and corners are computed).

    Time and memory are O(pairs): about 8 bytes per pair for the result plus the temporaries of the chunks being
    traced.

    Raises:
        BayesmapError: if a sensor position is not finite or lies outside the grid, a beam angle is not finite,
            or the max distance is not a finite number >= 0.
    """
    origins, beam_angles, max_distance = _checked_rays(grid, origins, beam_angles, max_distance)
    max_cells = max_distance / grid.resolution
    p_table, u_table = cell_frame(grid, origins, beam_angles)
    limits = _checked_limits(ray_limits, len(beam_angles), max_distance, p_table.dtype)
    if limits is not None:  # traced a little past each limit, then cut exactly in meters below
        max_cells = np.minimum(limits.astype(np.float64) * (1.0 + 1e-6) / grid.resolution, max_cells)
    counts, cells, dists = trace_rays(p_table, u_table, grid.shape, max_cells, chunk)
    dists *= dists.dtype.type(grid.resolution)
    if limits is not None:
        counts, cells, dists = _cut_rows(counts, cells, dists, limits)
    offsets = np.zeros(len(beam_angles) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return RayTable(
        grid=grid,
        offsets=offsets,
        pair_cells=cells,
        pair_dists=dists,
        origins=np.array(origins),
        beam_angles=beam_angles,
        max_distance=max_distance,
        ray_limits=limits,
    )


def _checked_limits(ray_limits, num_rays: int, max_distance: float, dtype) -> np.ndarray | None:
    """``ray_limits`` as ``(R,)`` of the table's ``dtype`` (None stays None).

    Raises:
        BayesmapError: on the wrong length, or a limit that is NaN, below 0 or above the max distance (named).
    """
    if ray_limits is None:
        return None
    limits = np.asarray(ray_limits).reshape(-1).astype(dtype)
    if limits.shape != (num_rays,):
        raise BayesmapError(f"expected {num_rays} ray limits (meters), got {limits.size}")
    bad = np.flatnonzero(~((limits >= 0) & (limits <= dtype.type(max_distance))))  # (compared in the table's dtype)
    if len(bad):
        raise BayesmapError(f"ray limit {bad[0]} is {float(limits[bad[0]])!r}: ray limits must lie in "
                            f"[0, {max_distance!r}] (meters, the max distance)")
    return limits


def _cut_rows(counts, cells, dists, limits):
    """Each ray's pairs below its limit (meters, the table's dtype): ``(counts, cells, dists)`` as
    :func:`bayesmap.geometry.traversal.trace_rays` returns them."""
    keep = dists < np.repeat(limits, counts)
    total = np.concatenate([[0], np.cumsum(keep, dtype=np.int64)])
    ends = np.cumsum(counts)
    return total[ends] - total[ends - counts], cells[keep], dists[keep]


def _splice_plan(old_offsets, new_offsets, spliced_offsets, rays) -> list[tuple[bool, int, int, int]]:
    """How to assemble the pair arrays of a table whose sorted, distinct rays ``rays`` ``(M,)`` were replaced:
    blocks ``(from_new, source_start, destination_start, size)`` of pairs, one block per run of consecutive
    replaced rays (``from_new``: taken from the table of the replacement rays, offsets ``new_offsets``) and one per
    run of kept rays in between (taken from the old table, offsets ``old_offsets``); ``spliced_offsets`` are the
    offsets of the result."""
    breaks = np.flatnonzero(np.diff(rays) != 1) + 1
    run_begins = np.concatenate([[0], breaks]) if len(rays) else np.zeros(0, dtype=np.int64)
    run_ends = np.concatenate([breaks, [len(rays)]]) if len(rays) else np.zeros(0, dtype=np.int64)
    plan = []
    kept_from = 0  # first ray of the current run of kept rays
    for begin, end in zip(run_begins.tolist(), run_ends.tolist()):
        run_first, run_stop = int(rays[begin]), int(rays[end - 1]) + 1
        plan.append((False, int(old_offsets[kept_from]), int(spliced_offsets[kept_from]),
                     int(spliced_offsets[run_first] - spliced_offsets[kept_from])))
        plan.append((True, int(new_offsets[begin]), int(spliced_offsets[run_first]),
                     int(new_offsets[end] - new_offsets[begin])))
        kept_from = run_stop
    plan.append((False, int(old_offsets[kept_from]), int(spliced_offsets[kept_from]),
                 int(spliced_offsets[-1] - spliced_offsets[kept_from])))
    return [block for block in plan if block[3] > 0]


def _splice_values(old_values: np.ndarray, new_values: np.ndarray, plan, num_pairs: int) -> np.ndarray:
    """``(num_pairs,)`` per-pair values assembled block by block from ``old_values`` and ``new_values`` (same
    dtype) following :func:`_splice_plan`: one contiguous copy per block."""
    out = np.empty(num_pairs, dtype=old_values.dtype)
    for from_new, source, destination, size in plan:
        out[destination:destination + size] = (new_values if from_new else old_values)[source:source + size]
    return out


def _splice_rows(table: RayTable, rays: np.ndarray, new_rows: RayTable) -> RayTable:
    """``table`` with the rows of the sorted, distinct rays ``rays`` ``(M,)`` replaced by the rows of ``new_rows``
    (a table of ``M`` rays, in the same order); also splices the cached per-pair views ``table`` has computed."""
    lengths = table.lengths.copy()
    lengths[rays] = new_rows.lengths
    offsets = np.zeros(table.num_rays + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    num_pairs = int(offsets[-1])
    plan = _splice_plan(table.offsets, new_rows.offsets, offsets, rays)
    origins = np.array(table.origins)
    origins[rays] = new_rows.origins
    beam_angles = np.array(table.beam_angles)
    beam_angles[rays] = new_rows.beam_angles
    spliced = RayTable(
        grid=table.grid,
        offsets=offsets,
        pair_cells=_splice_values(table.pair_cells, new_rows.pair_cells, plan, num_pairs),
        pair_dists=_splice_values(table.pair_dists, new_rows.pair_dists, plan, num_pairs),
        origins=origins,
        beam_angles=beam_angles,
        max_distance=table.max_distance,
        ray_limits=None if table.ray_limits is None else _spliced_limits(table.ray_limits, rays, new_rows),
    )
    cached = vars(table)
    spliced_cache = vars(spliced)  # where functools.cached_property keeps its values
    spliced_cache["lengths"] = lengths
    if "pair_rays" in cached:
        spliced_cache["pair_rays"] = _splice_values(cached["pair_rays"], np.repeat(rays, new_rows.lengths), plan,
                                                    num_pairs)
    if "pair_positions" in cached:
        spliced_cache["pair_positions"] = _splice_values(cached["pair_positions"], new_rows.pair_positions, plan,
                                                         num_pairs)
    return spliced


def _spliced_limits(limits: np.ndarray, rays: np.ndarray, new_rows: RayTable) -> np.ndarray:
    out = np.array(limits)
    out[rays] = new_rows.ray_limits
    return out


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
    values = np.asarray(readings, dtype=np.float64).reshape(-1)
    if values.shape != (num_rays,):
        raise BayesmapError(f"expected {num_rays} readings, got {values.size}")
    bad = np.flatnonzero(~np.isfinite(values) | (values < 0))
    if len(bad):
        raise BayesmapError(f"reading {bad[0]} is {values[bad[0]]!r}: readings must be finite and >= 0 (meters)")
    return values
