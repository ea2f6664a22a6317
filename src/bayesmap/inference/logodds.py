"""Classic log-odds occupancy-grid mapping with an inverse sensor model: the non-Bayesian-posterior baseline.

The algorithm is ``occupancy_grid_mapping`` of Thrun, Burgard & Fox, *Probabilistic Robotics* (MIT Press 2005),
sec. 9.2, Table 9.1, with the inverse range sensor model of Table 9.2 reduced to the cells a beam crosses (as in
OctoMap): each cell ``m_i`` keeps the log-odds ``l_i = log(p(m_i) / (1 - p(m_i)))``, starting at the prior's
``l_0``; a scan adds ``logit(p_hit) - l_0`` to the cell containing a beam's endpoint ("hit") and
``logit(p_miss) - l_0`` to the cells the beam crosses before it ("miss"); a max-range reading (no return) is all
misses up to the max range and no hit. As in OctoMap (Hornung, Wurm, Bennewitz, Stachniss & Burgard, "OctoMap: an
efficient probabilistic 3D mapping framework based on octrees", Autonomous Robots 34(3), 2013, sec. 3.2 and the
``OccupancyOcTreeBase::computeUpdate`` rule): within one scan a cell is updated at most once, a hit winning over
misses, and after each update the log-odds is clamped to ``[logit(clamp_min), logit(clamp_max)]`` so the map can
change again later (the defaults are OctoMap's: ``p_hit`` 0.7, ``p_miss`` 0.4, clamping 0.12 / 0.97).

The ray geometry comes from a :class:`~bayesmap.geometry.raytable.RayTable`: its pairs list, along each ray, every
cell the ray crosses with the distance at which the ray enters it (for the cell containing the sensor, the table
holds the distance at which the ray leaves it; here that cell counts as entered at distance 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import RayTable, check_readings


def logit(p: float) -> float:
    """Log-odds ``log(p / (1 - p))`` of a probability ``p`` in ``(0, 1)``."""
    return math.log(p) - math.log1p(-p)


@dataclass(frozen=True)
class LogOddsParams:
    """Parameters of the inverse sensor model and the clamping (probabilities of occupied).

    Attributes:
        p_hit: probability of occupied of a cell containing a beam's endpoint (OctoMap's ``prob_hit``, 0.7).
        p_miss: probability of occupied of a cell a beam crosses (OctoMap's ``prob_miss``, 0.4).
        clamp_min: lower clamping bound (OctoMap's ``clamping_thres_min``, 0.12).
        clamp_max: upper clamping bound (OctoMap's ``clamping_thres_max``, 0.97).
        prior: prior probability of occupied of every cell, ``l_0 = logit(prior)`` (0.5, log-odds 0).

    Raises:
        BayesmapError: unless all are numbers with ``0 < p_miss < prior < p_hit < 1`` and
            ``0 < clamp_min <= prior <= clamp_max < 1``, ``clamp_min < clamp_max`` (names the offending value).
    """

    p_hit: float = 0.7
    p_miss: float = 0.4
    clamp_min: float = 0.12
    clamp_max: float = 0.97
    prior: float = 0.5

    def __post_init__(self) -> None:
        for name in ("p_hit", "p_miss", "clamp_min", "clamp_max", "prior"):
            val = getattr(self, name)
            if isinstance(val, (bool, np.bool_)) or not isinstance(val, (int, float, np.integer, np.floating)):
                raise BayesmapError(f"{name} must be a probability (a number in (0, 1)), got {val!r}")
            if not 0.0 < float(val) < 1.0:
                raise BayesmapError(f"{name} must be in (0, 1) (exclusive), got {val!r}")
            object.__setattr__(self, name, float(val))
        if not self.p_miss < self.prior < self.p_hit:
            raise BayesmapError(
                f"need p_miss < prior < p_hit (a hit must raise and a miss lower the occupancy), got p_miss "
                f"{self.p_miss!r}, prior {self.prior!r}, p_hit {self.p_hit!r}"
            )
        if not self.clamp_min <= self.prior <= self.clamp_max or not self.clamp_min < self.clamp_max:
            raise BayesmapError(
                f"need clamp_min <= prior <= clamp_max and clamp_min < clamp_max, got clamp_min {self.clamp_min!r}, "
                f"prior {self.prior!r}, clamp_max {self.clamp_max!r}"
            )

    @property
    def l_prior(self) -> float:
        """``l_0 = logit(prior)``, the log-odds of a cell never observed."""
        return logit(self.prior)

    @property
    def hit_update(self) -> float:
        """Log-odds added to a hit cell: ``logit(p_hit) - l_0`` (Table 9.1's ``inverse_sensor_model - l_0``)."""
        return logit(self.p_hit) - self.l_prior

    @property
    def miss_update(self) -> float:
        """Log-odds added to a miss cell: ``logit(p_miss) - l_0``."""
        return logit(self.p_miss) - self.l_prior

    @property
    def clamp_bounds(self) -> tuple[float, float]:
        """``(logit(clamp_min), logit(clamp_max))``."""
        return logit(self.clamp_min), logit(self.clamp_max)


def _grid_exit_distances(table: RayTable) -> np.ndarray:
    """``(R,)`` distance (meters) along each ray from its sensor to the border of the grid (slab method)."""
    xmin, xmax, ymin, ymax = table.grid.extent
    u = np.stack([np.cos(table.beam_angles), np.sin(table.beam_angles)], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (np.array([xmin, ymin]) - table.origins) / u
        t2 = (np.array([xmax, ymax]) - table.origins) / u
    far = np.where(u == 0.0, np.inf, np.maximum(t1, t2))
    return np.min(far, axis=1)


def beam_hits_and_misses(table: RayTable, readings, max_range_mask=None) -> tuple[np.ndarray, np.ndarray]:
    """Classify the (ray, cell) pairs of a ray-cell table by the inverse sensor model.

    For a beam with reading ``y`` (meters), a cell on the ray is entered at its table distance (the sensor's own
    cell at distance 0). The endpoint cell ("hit") is the last cell entered at or before ``y``; ties (a ray through
    a cell corner) go to the last such cell in the table's order, and a reading shorter than the way out of the
    sensor's cell makes that cell the hit. The cells entered strictly before the hit cell are "misses"; cells
    entered at the same distance as the hit cell (a corner it shares with the ray) or after ``y`` are untouched.

    A beam with no hit misses every cell entered at or before its reading: a max-range beam (no return), and a
    beam whose reading is at or beyond the table's ``max_distance`` or whose endpoint lies outside the grid (its
    endpoint is no cell of the table). Cells beyond the table's ``max_distance`` are not in the table and never
    touched.

    Args:
        table: the ray-cell table (R rays, P pairs).
        readings: ``(R,)`` range readings, meters, finite and ``>= 0``.
        max_range_mask: ``(R,)`` bool, True where the reading is max-range (no return); None: no such beams.

    Returns:
        ``(hit, miss)``: two ``(P,)`` bool arrays over the table's pairs, disjoint, at most one hit per ray.

    Raises:
        BayesmapError: if ``readings`` is not ``(R,)`` finite non-negative numbers, or ``max_range_mask`` is not a
            ``(R,)`` bool array.
    """
    num_rays = table.num_rays
    y = check_readings(readings, num_rays)
    if max_range_mask is None:
        is_max = np.zeros(num_rays, dtype=bool)
    else:
        is_max = np.asarray(max_range_mask)
        if is_max.dtype != bool or is_max.shape != (num_rays,):
            raise BayesmapError(
                f"max_range_mask must be a bool array of shape ({num_rays},), got {is_max.dtype} {is_max.shape}"
            )
    rays = table.pair_rays
    nx, ny = table.grid.shape
    ij = table.grid.cell_index(table.origins)  # (R, 2) cell containing each ray's sensor
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
    sensor_cell = np.where(inside, ij[:, 0] * ny + ij[:, 1], -1).astype(np.int32)
    is_sensor = table.pair_cells == table.per_pair(sensor_cell)
    # the sensor's cell is entered at distance 0; d <= y exactly when d <= the largest number of the distances'
    # dtype that is <= y (compared in that dtype: no float64 copy of every pair's reading)
    y_down = y.astype(table.pair_dists.dtype)
    y_down = np.where(y_down > y, np.nextafter(y_down, -np.inf), y_down)
    entered = (table.pair_dists <= table.per_pair(y_down)) | is_sensor
    # no hit where the endpoint is not a cell of the table: max-range beams, readings at or beyond the table's
    # max distance, and endpoints outside the grid
    no_hit = is_max | (y >= table.max_distance) | (y >= _grid_exit_distances(table))
    # hit: the last non-sensor cell entered by y (pair distances increase along each ray, so these cells are a
    # prefix of the ray's non-sensor cells); if there is none, the sensor's cell
    candidate = entered & ~is_sensor & ~table.per_pair(no_hit)
    idx = np.flatnonzero(candidate)
    ray_of = rays[idx]
    last = np.r_[ray_of[1:] != ray_of[:-1], True] if len(idx) else np.zeros(0, dtype=bool)
    hit = np.zeros(table.num_pairs, dtype=bool)
    hit[idx[last]] = True
    has_hit = np.zeros(num_rays, dtype=bool)
    has_hit[ray_of[last]] = True
    sensor_pairs = np.flatnonzero(is_sensor)
    sensor_rays = rays[sensor_pairs]
    fallback = ~has_hit[sensor_rays] & ~no_hit[sensor_rays]
    hit[sensor_pairs[fallback]] = True
    # misses: cells entered strictly before the hit cell (cells tied with it, e.g. touched at the same corner,
    # are left alone); a ray without a hit (max-range) misses every cell it entered
    entry = np.where(is_sensor, np.float32(0), table.pair_dists)
    hit_entry = np.full(num_rays, np.inf, dtype=entry.dtype)  # (entry's dtype holds its values exactly)
    hit_idx = np.flatnonzero(hit)
    hit_entry[rays[hit_idx]] = entry[hit_idx]
    miss = entered & (entry < table.per_pair(hit_entry))
    return hit, miss


def logodds_map(table: RayTable, readings, max_range_mask=None, scan_of_ray=None,
                params: LogOddsParams | None = None, initial=None) -> np.ndarray:
    """Occupancy-grid mapping in log-odds form (Thrun et al., *Probabilistic Robotics*, sec. 9.2, Table 9.1, with
    OctoMap's per-scan update rule and clamping; see the module docstring).

    Every cell starts at ``l_0 = logit(prior)``. Scans are applied in increasing order of their id; in a scan each
    cell some beam touches is updated once: by ``params.hit_update`` if it is the endpoint cell of some beam of the
    scan (a hit wins over misses), else by ``params.miss_update``; the touched cells are then clamped to
    ``params.clamp_bounds``. Which cells a beam hits and misses: :func:`beam_hits_and_misses`.

    Vectorized over the table's pairs (numpy); the only Python loop runs over the scans.

    Args:
        table: the ray-cell table of all beams (R rays, P pairs), e.g. from
            :func:`bayesmap.geometry.raytable.build_ray_table` with each ray's own sensor position and world-frame
            angle.
        readings: ``(R,)`` range readings, meters, finite and ``>= 0``.
        max_range_mask: ``(R,)`` bool, True for max-range readings (no return); None: none are.
        scan_of_ray: ``(R,)`` non-negative ints, the scan each ray belongs to; None: all rays form one scan (the
            single-scan problems of :mod:`bayesmap.scenes`). For a log, pass ``np.repeat(np.arange(S), K)``:
            grouping every beam as its own scan would update a cell many times per scan, grouping all scans as one
            only once in all.
        params: inverse sensor model and clamping; default :class:`LogOddsParams` ().
        initial: ``(nx, ny)`` log-odds the updates start from (those of the scans before, to map a log a piece of
            whole scans at a time, :meth:`bayesmap.problem.Problem.table_chunks`: the same result as in one
            piece); None: ``l_0`` everywhere.

    Returns:
        ``(nx, ny)`` float64 log-odds of occupied per cell (``l_0`` for cells no beam touched).

    Raises:
        BayesmapError: on bad ``readings`` / ``max_range_mask`` (see :func:`beam_hits_and_misses`), or a
            ``scan_of_ray`` that is not ``(R,)`` non-negative integers.
    """
    params = LogOddsParams() if params is None else params
    if not isinstance(params, LogOddsParams):
        raise BayesmapError(f"params must be a LogOddsParams, got {params!r}")
    num_rays = table.num_rays
    if scan_of_ray is None:
        scans = np.zeros(num_rays, dtype=np.int64)
    else:
        scans = np.asarray(scan_of_ray)
        if scans.shape != (num_rays,) or not (np.issubdtype(scans.dtype, np.integer) or scans.size == 0):
            raise BayesmapError(
                f"scan_of_ray must be an integer array of shape ({num_rays},), got {scans.dtype} {scans.shape}"
            )
        if scans.size and scans.min() < 0:
            raise BayesmapError(f"scan_of_ray must be >= 0, got {int(scans.min())} for ray {int(np.argmin(scans))}")
        scans = scans.astype(np.int64)
    hit, miss = beam_hits_and_misses(table, readings, max_range_mask)

    touched = hit | miss
    cells = table.pair_cells[touched]
    is_hit = hit[touched]
    pair_scan = scans[table.pair_rays[touched]]
    if len(pair_scan) > 1 and np.any(pair_scan[1:] < pair_scan[:-1]):
        order = np.argsort(pair_scan, kind="stable")
        cells, is_hit, pair_scan = cells[order], is_hit[order], pair_scan[order]
    # pairs of one scan are now contiguous: slice boundaries
    starts = np.flatnonzero(np.r_[True, pair_scan[1:] != pair_scan[:-1]]) if len(pair_scan) else np.zeros(0, int)
    bounds = np.r_[starts, len(pair_scan)]

    lo, hi = params.clamp_bounds
    if initial is None:
        logodds = np.full(table.num_cells, params.l_prior, dtype=np.float64)
    else:
        logodds = np.array(initial, dtype=np.float64).reshape(-1)
        if logodds.size != table.num_cells:
            raise BayesmapError(f"initial must have the grid's shape {tuple(table.grid.shape)}, got "
                                f"{np.shape(initial)}")
    update = np.zeros(table.num_cells, dtype=np.float64)  # scratch: this scan's update per cell
    hit_cells_all = np.where(is_hit, cells, -1)
    for a, b in zip(bounds[:-1], bounds[1:]):
        c = cells[a:b]
        h = hit_cells_all[a:b]
        update[c] = params.miss_update
        update[h[h >= 0]] = params.hit_update  # a hit wins over misses in the same scan
        # duplicates in c read the same old value and the same update: each cell changes once
        logodds[c] = np.clip(logodds[c] + update[c], lo, hi)
        update[c] = 0.0
    return logodds.reshape(table.grid.shape)


def occupancy(logodds) -> np.ndarray:
    """Probability of occupied from log-odds: ``1 / (1 + exp(-l))``, computed without overflow.

    Args:
        logodds: any shape, log-odds (``+-inf`` allowed).

    Returns:
        float64 array of the same shape, in ``[0, 1]``.

    Raises:
        BayesmapError: if a value is NaN.
    """
    arr = np.asarray(logodds, dtype=np.float64)
    if np.isnan(arr).any():
        raise BayesmapError("log-odds must not be NaN")
    return np.exp(-np.logaddexp(0.0, -arr))
