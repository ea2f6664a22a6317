"""Correlative scan matching: a starting path for SLAM on real logs (the front end of a SLAM system).

Each scan is matched, in order, against a likelihood field built from the endpoints of the scans before it at their
matched poses, those taken within the last :data:`LOCAL_MAP_DISTANCE` meters of travel (Olson 2009, "Real-time
correlative scan matching", ICRA; the likelihood field of Thrun, Burgard & Fox, *Probabilistic Robotics*, sec. 6.4):

* the field value of a cell is ``max over endpoint cells c' of exp(-|c - c'|^2 / (2 sigma^2))`` over the endpoints
  within a radius (``sigma`` and the radius: :data:`FIELDS`, meters), updated by a scatter-max after each
  scan;
* a candidate pose's score is the odometry motion model's log-density from the previous estimate plus
  ``p sum_k log(z_hit field(endpoint_k) + z_floor)`` over the scan's returned beams (``z_floor`` =
  :data:`FIELD_FLOOR`: an endpoint in unmapped space costs a bounded amount, so unexplored areas and people do
  not pull the match; ``p`` the likelihood power, 1 in Olson's score: below 1 the scan's hundreds of correlated
  beams count as fewer, and the odometry decides along directions where the field is nearly flat, a corridor's
  axis);
* the candidates form a coarse-to-fine lattice around the odometry's prediction (:data:`MATCH_LEVELS`), each level
  centered on the previous level's best;
* a match that puts fewer than :data:`MIN_HIT_FRACTION` of the scan's returned endpoints on the local map is not
  trusted: the scan then takes the odometry's prediction (a scan that sees mostly new space, where a few chance
  coincidences with the local map can outscore the motion model; the loop closure's
  :data:`bayesmap.slam.posegraph.LOOP_MIN_HIT_FRACTION` is the same test, as Karto's minimum responses are for
  the matches that link chains and close loops, though Karto keeps every sequential match).

Every cell also keeps the path length of the last scan that reached it, and a match sees only the cells reached
within the window: the local map of a running buffer of scans (Karto's design). The fields cover a square of
:data:`MATCH_GRID_HALF_WIDTH` around the robot and follow it: when the robot nears their edge they move to center on
it, by whole cells, and hold what a grid covering everything would hold there (the cells both squares cover are
moved; the others are filled from the earlier scans that reach them, at their matched poses), so the grid never
depends on where the odometry says the robot went. Every cell coordinate is computed in one frame, at the first
pose, and shifted by whole cells, so the path does not depend on where the square is or on its size (while the
beams stay inside it), to the bit. The path drifts
slowly; :mod:`bayesmap.slam.posegraph` closes the loops, and :func:`correlative_path` is only a start for the joint
chain, which does not depend on it for its target.

Everything is one jitted ``lax.fori_loop`` over the scans (shapes fixed by the grid and the scan size), whose bounds
are arguments: given a progress callback (:mod:`bayesmap.progress`), :func:`correlative_path` runs it a block of
scans per call, the same path, and reports after each.

A search scores every candidate of a level's lattice; each beam's direction is computed once per heading of the
lattice, not once per candidate. The front end's local map is one pass over the grid per scan (:func:`local_map`:
the cells reached outside the window set to unmapped) before the search, the hit fraction and the step posterior
read it: since each scan's step posterior looks up 1,521 candidates' endpoints at four cells each, that pass costs
less than a stamp lookup per endpoint (the front end on 300 ACES scans: 12.4 -> 5.8 s, the same path to the bit).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
import scipy.sparse
import scipy.spatial

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import scan_endpoints
from bayesmap.model.generative import check_likelihood_power
from bayesmap.model.motion import MotionParams, backward_step_covariance, compose, motion_logpdf, tailed_motion_logpdf
from bayesmap.progress import ProgressCallback, report

FIELDS = ((0.05, 0.15), (0.2, 0.5))
"""The two likelihood fields, as (standard deviation, radius) in meters: the fine one (a laser's range noise is 1-3
cm; the field adds the cell's own width; radius three sigma) scores the fine levels of the search, the broad one
the first, coarse level, whose lattice steps the fine field would fall between (Olson 2009's multi-resolution
search)."""

FIELD_FLOOR = 0.05
"""The field's floor inside the score's logarithm: an endpoint in unmapped space costs ``log 0.05`` instead of
``-inf`` (the beam model's random-reading floor, *Probabilistic Robotics* sec. 6.4)."""

MIN_HIT_FRACTION = 0.2
"""The least fraction of a scan's returned endpoints that its match must put on the local map (:func:`hit_fraction`
at the matched pose: within about 6 cm of a mapped endpoint); below it the scan takes the odometry's prediction
(0 trusts every match). A scan that sees mostly space its local map has not seen is matched by chance
coincidences, which put fewer of its endpoints on the map than a true match does. Chosen by leave-one-log-out
cross-validation of the start path's ATE among 0, 0.2 and 0.35 over Intel, ACES and CSAIL
(``benchmarks/front_end_cv.py``; [validation](../validation/defaults.md#min_hit_fraction))."""

MATCH_LEVELS = ((0.1, 0.04, 4, 20, 1), (0.03, 0.007, 3, 6, 0), (0.01, 0.0025, 2, 2, 0), (0.003, 0.0008, 2, 2, 0))
"""The coarse-to-fine search: per level the lattice step in x and y (meters) and in theta (radians), the half widths
``w_xy`` and ``w_theta`` (``(2 w_xy + 1)^2 (2 w_theta + 1)`` candidates) and the field it scores against (index into
:data:`FIELDS`): the first level covers +-0.4 m and +-0.8 rad (46 degrees) around the odometry's prediction, the
second +-0.09 m and +-0.042 rad around the first's best, a whole heading step of the first level either side (so a
first level that picks the heading next to the right one is corrected), the last resolves 3 mm and 0.05 degrees.
The first level's heading window is 3.5 standard deviations of the odometry's heading error on a step that backs up
(a turn of about pi under *Probabilistic Robotics* Table 5.5's decomposition); the motion model's log-density is part
of every candidate's score, so the wide window costs only time. The second level's heading reach was chosen by
leave-one-log-out cross-validation ([validation](../validation/defaults.md#match_levels))."""

MOTION_TAIL_WEIGHT = 0.01
"""The weight of the broad component of the front end's motion density (:func:`bayesmap.model.motion.
tailed_motion_logpdf`, its covariance :func:`bayesmap.model.motion.backward_step_covariance` of the problem's motion
noise): the search and each step's posterior score a candidate by ``log((1 - w) N(Sigma) + w N(Sigma + T))``
instead of the motion model's Normal alone. An odometry step that backed up can err by tenths of a radian where the
motion model claims hundredths; with the Normal alone a scan that fits there costs the search tens of nats, its
match falls short and the scan takes the wrong prediction (Intel with odometry noise twice the shared logs': the
track lost, 3.7-4.0 m). The target's motion density is not changed: the front end only finds the chain's start.
Chosen by leave-one-log-out cross-validation of the start path's ATE among 0 (off) and 0.01 with the broad component
over x, y and heading or over the heading alone, on Intel, ACES and CSAIL at the shared logs' odometry noise and
twice it ([validation](../validation/defaults.md#motion_tail_weight))."""


FIELD_SEED = False
"""Whether the front end's search (:func:`search`'s ``field_seed``) also descends from the first level's best
candidate by the scan's broad-field score alone, besides the best by that score plus the motion term, taking that
descent where it scores higher at the last level and ends in another basin (beyond the second level's reach). The
broad field (0.2 m) compresses a scan's fit where the fine one tells poses apart by far more, while the motion term
weighs the same at every level, so at the first level a step whose odometry erred by more than the motion model
allows can lose to the odometry's prediction by the motion term alone, and the fine levels, +-0.09 m and +-0.042 rad
around it, cannot come back. On, it matched such a step of Freiburg 079 right, but on every other scan of CSAIL, whose
steps see too little of their local map for the score to tell basins apart, the other basin was the wrong one and
`slam --log` lost the track on 4 of 5 odometry seeds; so it is off (leave-one-log-out cross-validation of the start
path's ATE over Intel, ACES and CSAIL chose it on two of three folds;
[validation](../validation/defaults.md#field_seed))."""


LOCAL_MAP_DISTANCE = 10.0
"""Meters of path length: :func:`correlative_path` matches each scan against the scans taken within this distance
travelled before it (slam_toolbox's, i.e. Karto's, default running buffer, ``scan_buffer_maximum_scan_distance``),
not against the whole map. A map of every earlier scan snaps a scan taken after a drift onto the old, displaced
walls, a jump that the loop closure then treats as a measured step; the local map leaves the loops to
:mod:`bayesmap.slam.posegraph`. Karto's default; 20 m was tried against it by leave-one-log-out cross-validation
and not adopted (``benchmarks/front_end_cv.py --parameter window``;
[validation](../validation/defaults.md#local_map_distance))."""


MATCH_GRID_HALF_WIDTH = 40.0
"""Meters: the front end's likelihood fields live on a square grid of +-40 m that follows the robot (recentred on the
predicted pose, by whole cells, whenever that pose is more than a quarter of the half width from the grid's center), so
the robot always has at least 30 m of grid on every side, more than the local map's 10 m of travel and the beams of an
indoor laser (CSAIL's longest return is 35 m, its 99th percentile 14 m). The fields and stamps of a 0.05 m grid of
this size take 41 MB. When the grid moves, its fields and stamps are those of a grid covering everything, restricted
to the window: the cells both windows cover are moved, the others filled from every earlier scan that reaches them
at its matched pose ([validation](../validation/defaults.md#match_grid_half_width))."""


STEP_POSTERIOR_NODES = ((0.012, 0.3, 6), (0.005, 0.05, 4))
"""The lattice on which :func:`step_posterior` integrates a step's posterior: for x and y (meters, 13 nodes each) and
for the heading (radians, 9 nodes), the offset of the first node from the match, of the last, and the nodes per
side, spaced as ``a sinh(b k)``: dense near the match, sparse in the tails. It spans +-0.3 m and +-0.05 rad, the
widest steps measured on ACES (99th percentiles 0.09 m and 0.016 rad). On ACES (odometry seed 0, every 7th step)
the standard deviations it gives are within 0.7 % of a uniform lattice of 41 x 41 x 41 candidates (+-0.4 m in
0.02 m steps, +-0.12 rad in 0.006 rad steps) at the median and within 5 % at the 5th and 95th percentiles, with
1,521 candidates instead of 68,921 ([validation](../validation/defaults.md#step_posterior_nodes))."""


class ScanData(NamedTuple):
    """The scans a matcher needs (a pytree of arrays).

    Attributes:
        sensor_angles: ``(S, K)`` beam angles relative to the heading, radians.
        readings: ``(S, K)`` range readings, meters.
        returned: ``(S, K)`` bool, True for beams that returned (not max-range).
        increments: ``(S - 1, 3)`` odometry increments in the previous pose's frame (m, m, rad).
        covs: ``(S - 1, 3, 3)`` their covariances (:func:`bayesmap.model.motion.odometry_controls`).
    """

    sensor_angles: jax.Array
    readings: jax.Array
    returned: jax.Array
    increments: jax.Array
    covs: jax.Array


def _stencil_reach(resolution: float, radius: float) -> int:
    """The half width in cells of :func:`_field_stencil`'s square: how far (in cells, per axis) an endpoint's
    stencil reaches."""
    return int(math.ceil(radius / resolution + 0.75))


def _field_stencil(resolution: float, radius: float):
    """Cell offsets ``(F, 2)`` int32 within ``radius`` meters (plus half a cell diagonal) of a cell."""
    r = _stencil_reach(resolution, radius)
    ii, jj = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
    keep = (ii**2 + jj**2) * resolution**2 <= (radius + 0.75 * resolution) ** 2
    return jnp.asarray(np.stack([ii[keep], jj[keep]], axis=-1).astype(np.int32))


def _cells(grid: Grid, xy, shift=None):
    """Nearest cell indices ``(..., 2)`` int32 of world points, and whether they lie inside the grid; ``shift`` as in
    :func:`search`."""
    cells = jnp.floor(grid.to_cell_coords(xy) + 0.5).astype(jnp.int32)
    if shift is not None:
        cells = cells - shift
    inside = jnp.all((cells >= 0) & (cells < jnp.asarray(grid.shape)), axis=-1)
    return jnp.clip(cells, 0, jnp.asarray(grid.shape) - 1), inside


def _stencil_cells(grid: Grid, pose, sensor_angles, readings, returned, sigma: float, radius: float, size: int,
                   shift=None):
    """The flat indices ``(E, F)`` of the cells whose centers lie within ``radius`` meters of the returned endpoints
    of scans ``(..., K)`` at poses ``(..., 3)`` (``size``, out of range, where none), and ``exp(-d^2 / (2
    sigma^2))`` of their distance ``d`` from the endpoint; ``shift`` as in :func:`search`."""
    offsets = _field_stencil(grid.resolution, radius)
    ends = scan_endpoints(pose, sensor_angles, readings)
    coords = grid.to_cell_coords(ends).reshape(-1, 2)
    cells = jnp.floor(coords + 0.5).astype(jnp.int32)
    target = cells[:, None, :] + offsets[None, :, :]
    d2 = jnp.sum((target - coords[:, None, :]) ** 2, axis=-1) * grid.resolution**2  # from the endpoint itself
    if shift is not None:
        cells, target = cells - shift, target - shift
    n = jnp.asarray(grid.shape)
    ok = returned.reshape(-1) & jnp.all((cells >= 0) & (cells < n), axis=-1)
    ok = ok[:, None] & jnp.all((target >= 0) & (target < n), axis=-1) & (d2 <= radius**2)
    return jnp.where(ok, target[..., 0] * grid.shape[1] + target[..., 1], size), jnp.exp(-d2 / (2 * sigma**2))


def add_scan(field, grid: Grid, pose, sensor_angles, readings, returned, sigma: float, radius: float, shift=None):
    """The likelihood field ``(nx, ny)`` float32 with more endpoints: the returned beams of scans ``(..., K)`` at
    poses ``(..., 3)`` (one scan or several), a scatter-max of ``exp(-d^2 / (2 sigma^2))`` over the cells whose
    centers lie within ``radius`` meters of each endpoint, ``d`` the distance from the endpoint itself (not its
    cell: no half-cell bias). Endpoints outside the grid are skipped. ``shift`` as in :func:`search`. Jittable."""
    flat, vals = _stencil_cells(grid, pose, sensor_angles, readings, returned, sigma, radius, field.size, shift)
    return field.reshape(-1).at[flat.reshape(-1)].max(vals.astype(field.dtype).reshape(-1),
                                                     mode="drop").reshape(field.shape)


def _lookup(field, cells, window):
    """``field`` at integer cells ``(..., 2)`` (inside the grid), 0 where the window's stamps (``(stamps, since)``:
    the path length of the last scan that reached a cell, and the least one a match sees) leave a cell out; None:
    every cell."""
    value = field[cells[..., 0], cells[..., 1]]
    if window is None:
        return value
    stamps, since = window
    return jnp.where(stamps[cells[..., 0], cells[..., 1]] >= since, value, 0.0)


def _endpoint_values(field, grid: Grid, ends, interpolate: bool, window=None, shift=None):
    """The field at world endpoints ``(..., 2)``: bilinearly interpolated between cell centers (``interpolate``; else
    the nearest cell's value, four times cheaper); 0 outside the grid and at cells ``window`` leaves out
    (:func:`_lookup`); ``shift`` as in :func:`search`."""
    if not interpolate:
        cells, inside = _cells(grid, ends, shift)
        return jnp.where(inside, _lookup(field, cells, window), 0.0)
    c = grid.to_cell_coords(ends)
    base = jnp.floor(c)
    frac = c - base
    base = base.astype(jnp.int32)
    if shift is not None:
        base = base - shift
    n = jnp.asarray(grid.shape)
    value = jnp.zeros(c.shape[:-1], field.dtype)
    for di, dj in ((0, 0), (1, 0), (0, 1), (1, 1)):
        cell = base + jnp.asarray([di, dj])
        ok = jnp.all((cell >= 0) & (cell < n), axis=-1)
        cell = jnp.clip(cell, 0, n - 1)
        weight = (frac[..., 0] if di else 1 - frac[..., 0]) * (frac[..., 1] if dj else 1 - frac[..., 1])
        value = value + jnp.where(ok, weight * _lookup(field, cell, window), 0.0)
    return value


def _log_score(value, returned):
    return jnp.sum(jnp.where(returned, jnp.log(value + FIELD_FLOOR), 0.0), axis=-1)


def field_scores(field, grid: Grid, candidates, sensor_angles, readings, returned, interpolate: bool = True):
    """``(M,)`` float32: ``sum_k log(field(endpoint_k) + FIELD_FLOOR)`` over the returned beams of one scan at each
    candidate pose ``(M, 3)``; the field bilinearly interpolated between cell centers (``interpolate``; else the
    nearest cell's value, four times cheaper), endpoints outside the grid count as unmapped."""
    ends = scan_endpoints(candidates, sensor_angles, readings)
    return _log_score(_endpoint_values(field, grid, ends, interpolate), returned)


def _beam_reach(center, theta, sensor_angles, readings):
    """``(B, K, 2)``: each beam's endpoint less the sensor's position at the headings ``center[2] + theta``."""
    angle = (center[2] + theta)[:, None] + sensor_angles
    return readings[..., None] * jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)


def _unmapped(dtype):
    """The log score of an endpoint off the map (:func:`log_field` of an empty cell)."""
    return log_field(jnp.zeros((), dtype))


def lattice_scores(field, grid: Grid, center, xy, theta, sensor_angles, readings, returned, interpolate: bool,
                    window=None, log_field=None, shift=None):
    """:func:`field_scores` of the candidates ``center + (xy[a], theta[b])`` in the order ``a * len(theta) + b``
    (``xy`` ``(A, 2)``, ``theta`` ``(B,)``), each beam's direction computed once per heading instead of once per
    candidate, the field masked by ``window`` (:func:`_lookup`). ``log_field``: :func:`log_field` of ``field``, read
    instead of taking a logarithm per endpoint where the nearest cell's value is looked up (the same values);
    ``shift`` as in :func:`search`."""
    reach = _beam_reach(center, theta, sensor_angles, readings)  # (B, K, 2)
    ends = ((center[:2] + xy)[:, None, None, :] + reach[None]).reshape(-1, *reach.shape[1:])  # (A B, K, 2)
    if interpolate or log_field is None:
        return _log_score(_endpoint_values(field, grid, ends, interpolate, window, shift), returned)
    floor = _unmapped(field.dtype)
    cells, inside = _cells(grid, ends, shift)
    if window is not None:  # a cell off the window counts as unmapped
        inside = inside & (window[0][cells[..., 0], cells[..., 1]] >= window[1])
    value = jnp.where(inside, log_field[cells[..., 0], cells[..., 1]], floor)
    return jnp.sum(jnp.where(returned, value, 0.0), axis=-1)


def lattice_poses(center, xy, theta):
    """``(A B, 3)`` the candidate poses ``center + (xy[a], theta[b])`` in the order of :func:`lattice_scores`
    (``a * len(theta) + b``). Jittable."""
    return jnp.concatenate([jnp.repeat(center[:2] + xy, len(theta), axis=0),
                            jnp.tile(center[2] + theta, len(xy))[:, None]], axis=1)


BOUND_BLOCK = 4
"""Translations per side of the squares :func:`bounded_lattice_argmax` bounds together: a speed setting (any value
gives the same match). With 4, the first level of CSAIL seed 0's +-6 m loop searches takes 14.7 ms against 80.8 ms
scoring every candidate ([validation](../validation/slam.md#time-against-the-pipeline-at-685e56c))."""

BOUND_CHUNK = 64
"""Squares :func:`bounded_lattice_argmax` scores at once (a speed setting: any value gives the same match)."""


MATCHER_COMPILER_OPTIONS = {"xla_cpu_use_thunk_runtime": False} if jax.__version_info__ < (0, 7) else None
"""XLA options the scan matchers' compiled loops are built with (the front end's, the particle front end's and the
loop closure's local maps and searches): a speed setting. On a CPU, XLA's runtime of before its thunk runtime, which
JAX 0.4.32 made the default and which is slower for loops of many small steps (jax-ml/jax#26145); JAX 0.7 removed the
older one, so from there None, the default. With it the front end of CSAIL (406 scans, the 2-core machine) takes
5.3 s warm against 10.9 s and the loop closure 2.1 s against 2.6 s. The front end's path is the same to the bit and
its steps' covariances within 3e-9 of each other; of the 40 paths of the Karto table, 39 are the same to the
millimeter and one 1 mm off. The chain's pose sweeps run slower on it (5.2-5.8 s a round against 2.2 s) and the
placing of scans no faster, so they keep the default
([validation](../validation/scale.md#the-scan-matchers-on-xlas-earlier-cpu-runtime)). An option of XLA's CPU
compiler: other backends do not read it."""


def bound_span(step: float, resolution: float, block: int = BOUND_BLOCK) -> int:
    """The side, in cells, of the box every endpoint of a ``block x block`` square of translations ``step`` meters
    apart can land in on cells of ``resolution`` meters, one cell of margin each side
    (:func:`bounded_lattice_argmax`)."""
    return int(math.ceil((block - 1) * step / resolution - 1e-9)) + 4


def bounded_lattice_argmax(log_field, grid: Grid, center, xy, theta, sensor_angles, readings, returned,
                           span: int, block: int = BOUND_BLOCK, chunk: int = BOUND_CHUNK):
    """The index ``a * len(theta) + b`` of the best of :func:`lattice_scores` at the nearest cell of ``log_field``
    (:func:`log_field`, ``(nx, ny)`` on ``grid``; no window, no shift) over the lattice ``center + (xy[a], theta[b])``
    (``center`` ``(3,)`` x m, y m, theta rad; ``xy`` ``(n^2, 2)`` meters, a square lattice in the order of
    :func:`lattices`' offsets; ``theta`` ``(B,)`` rad) of one scan (``sensor_angles``, ``readings``, ``returned``
    ``(K,)``), and its score: the same as ``argmax`` of the scores of every candidate
    (the first of equal ones), found by branch and bound (Olson 2009, "Real-time correlative scan matching"). Each
    ``block x block`` square of translations at one heading is bounded by the sum over the scan's returned beams of
    the largest value of ``log_field`` in the box of cells any of its candidates' endpoints can land in (one cell of
    margin each side), outside the grid the unmapped score; the squares are scored exactly, ``chunk`` at a time in
    decreasing order of their bounds, until no bound left reaches the best score found less 0.05 (float32 sums of a
    scan's beams in another order differ by far less). ``span``: :func:`bound_span` of the lattice's step. Jittable.

    Returns:
        ``(index, score)``: int32 and float, as ``argmax`` and ``max`` of the whole lattice's scores.
    """
    n = math.isqrt(xy.shape[0])
    heads = theta.shape[0]
    side = -(-n // block)
    pairs = side * side * heads
    padded = jnp.pad(log_field, span, constant_values=_unmapped(log_field.dtype))
    strips = jax.lax.reduce_window(padded, -jnp.inf, jax.lax.max, (span, 1), (1, 1), "VALID")  # (the max separates)
    boxes = jax.lax.reduce_window(strips, -jnp.inf, jax.lax.max, (1, span), (1, 1), "VALID")  # at each box's low corner
    reach = _beam_reach(center, theta, sensor_angles, readings)  # (B, K, 2)
    first = jnp.arange(side) * block  # each square's first row (and column) of the lattice
    low = jnp.stack(jnp.meshgrid(xy[first * n, 0], xy[first, 1], indexing="ij"), axis=-1).reshape(-1, 2)  # (side^2, 2)
    ends = (center[:2] + low)[:, None, None, :] + reach[None]  # (side^2, B, K, 2)
    corner = jnp.floor(grid.to_cell_coords(ends) + 0.5).astype(jnp.int32) - 1 + span
    corner = jnp.clip(corner, 0, jnp.asarray(boxes.shape) - 1)
    bounds = jnp.sum(jnp.where(returned, boxes[corner[..., 0], corner[..., 1]], 0.0), axis=-1).reshape(-1)
    order = jnp.argsort(-bounds)
    sorted_bounds = jnp.concatenate([bounds[order], jnp.full(chunk, -jnp.inf, bounds.dtype)])
    order = jnp.concatenate([order, jnp.zeros(chunk, order.dtype)])
    offsets = jnp.stack(jnp.meshgrid(jnp.arange(block), jnp.arange(block), indexing="ij"), axis=-1).reshape(-1, 2)

    def squares(i):
        picked = jax.lax.dynamic_slice(order, (i * chunk,), (chunk,))
        real = i * chunk + jnp.arange(chunk) < pairs
        square, b = picked // heads, picked % heads
        rows = first[square // side][:, None] + offsets[:, 0]  # (chunk, block^2)
        cols = first[square % side][:, None] + offsets[:, 1]
        valid = real[:, None] & (rows < n) & (cols < n)
        a = jnp.minimum(rows, n - 1) * n + jnp.minimum(cols, n - 1)

        def one(a_s, b_s):
            return lattice_scores(log_field, grid, center, xy[a_s], theta[b_s][None], sensor_angles, readings,
                                  returned, interpolate=False, log_field=log_field)

        scores = jnp.where(valid, jax.vmap(one)(a, b), -jnp.inf)
        return scores.reshape(-1), (a * heads + b[:, None]).reshape(-1)

    def better(score, index, best):
        return (score > best[1]) | ((score == best[1]) & (index < best[0]))

    def body(carry):
        i, best = carry
        scores, index = squares(i)
        top = jnp.max(scores)
        j = jnp.argmin(jnp.where(scores == top, index, jnp.iinfo(jnp.int32).max))
        cand = (index[j].astype(jnp.int32), top)
        best = jax.tree_util.tree_map(lambda c, o: jnp.where(better(cand[1], cand[0], best), c, o), cand, best)
        return i + 1, best

    def more(carry):
        i, best = carry
        return (i * chunk < pairs) & (sorted_bounds[i * chunk] >= best[1] - 0.05)

    start = (jnp.asarray(0), (jnp.asarray(jnp.iinfo(jnp.int32).max, jnp.int32), jnp.asarray(-jnp.inf, bounds.dtype)))
    _, best = jax.lax.while_loop(more, body, start)
    return best


def log_field(field):
    """``log(field + FIELD_FLOOR)`` per cell, what :func:`search` reads for a level that looks up the nearest cell
    when given it: worth it when a search looks up more endpoints than the grid has cells (the loop closure's wide
    window), and only as an argument of the jitted search (inside one computation, XLA computes it again at every
    lookup). Jittable."""
    return jnp.log(field + FIELD_FLOOR)


def _lattice(h_xy: float, h_theta: float, w_xy: int, w_theta: int):
    """A level's lattice as ``(xy offsets (A, 2), heading offsets (B,))``: the candidates are every pair, ``A = (2
    w_xy + 1)^2``, ``B = 2 w_theta + 1``."""
    r = np.arange(-w_xy, w_xy + 1, dtype=np.float64) * h_xy
    xy = np.stack(np.meshgrid(r, r, indexing="ij"), axis=-1).reshape(-1, 2)
    return jnp.asarray(xy), jnp.asarray(np.arange(-w_theta, w_theta + 1, dtype=np.float64) * h_theta)


def empty_fields(grid: Grid) -> tuple:
    """One zero field ``(nx, ny)`` float32 per entry of :data:`FIELDS`."""
    return tuple(jnp.zeros(grid.shape, jnp.float32) for _ in FIELDS)


def add_to_fields(fields: tuple, grid: Grid, pose, sensor_angles, readings, returned, shift=None) -> tuple:
    """:func:`add_scan` of scans ``(..., K)`` at poses ``(..., 3)`` to every field of :data:`FIELDS` (``shift`` as
    there). Jittable."""
    return tuple(add_scan(field, grid, pose, sensor_angles, readings, returned, sigma, radius, shift)
                 for field, (sigma, radius) in zip(fields, FIELDS))


@jax.tree_util.register_pytree_node_class
class Lattices:
    """The search levels of :func:`search`: per level the candidate offsets as ``(xy (A, 2), heading (B,))`` (pytree
    leaves; the candidates are every pair) and the index of the field it scores against (static), so a jitted
    function takes them as one argument and compiles once per set of field indices and lattice shapes. Iterating
    gives ``((xy, heading), field index)`` per level."""

    def __init__(self, offsets: tuple, fields: tuple):
        self.offsets, self.fields = tuple(offsets), tuple(fields)

    def __iter__(self):
        return iter(zip(self.offsets, self.fields))

    def tree_flatten(self):
        return self.offsets, self.fields

    @classmethod
    def tree_unflatten(cls, fields, offsets):
        return cls(offsets, fields)


def lattices(levels) -> Lattices:
    """The candidate offsets ``(xy (A, 2), heading (B,))`` and field index of every search level (see
    :data:`MATCH_LEVELS`)."""
    return Lattices([_lattice(h, ht, w, wt) for h, ht, w, wt, _ in levels], [f for *_, f in levels])


def search(fields: tuple, grid: Grid, center, sensor_angles, readings, returned, levels: Lattices,
           log_prior=None, window=None, log_fields=None, shift=None, field_seed: bool = False,
           bound_span: int | None = None):
    """The coarse-to-fine search: at each level score ``center + offsets`` (:func:`field_scores` plus
    ``log_prior(candidates)`` if given) and recenter on the best (the first of equal scores, in the order of the
    offsets ``(x, y, heading)``, heading fastest); the fine field (index 0) is interpolated, the broad one looked up at
    the nearest cell. Jittable.

    Args:
        levels: the output of :func:`lattices`.
        window: None, or ``(stamps (nx, ny), since)``: the fields count as 0 at the cells whose stamp is below
            ``since`` (the front end's local map, :func:`correlative_path`), as if masked, without a pass over the
            grid.
        log_fields: None, or per field its :func:`log_field` (or None), read by the levels that look up the nearest
            cell (the same scores, faster when there are more lookups than cells).
        shift: None, or ``(2,)`` int32 cells: the poses are given in the frame of a grid ``shift`` cells before
            this one (cell ``c`` there is cell ``c - shift`` here): every cell coordinate is computed in that frame
            and the cells shifted in integers, so that nothing depends on ``shift`` to the bit (the front end's
            fields, which follow the robot).
        field_seed: with ``log_prior`` and more than one level, also descend the later levels from the first
            level's best candidate by the field score alone, and return that descent where it scores higher at the
            last level and ends beyond the second level's reach (in x or y, or in heading) from the other descent's
            end: two ends within it are one basin, where a lattice step's difference would only perturb the path
            (:data:`FIELD_SEED`). The result never scores lower than without it. The cost: the later levels twice.
        bound_span: None, or :func:`bound_span` of the first level's step: find the first level's best by branch
            and bound (:func:`bounded_lattice_argmax`), the same candidate and score as scoring every one. Only for
            a search without ``log_prior``, ``window`` and ``shift`` whose first level looks up the nearest cell of
            its ``log_fields`` entry (the loop closure's).

    Returns:
        ``(best (3,), score)``: the best pose and its score at the last level.
    """
    levels = list(levels)

    def level_scores(best, level):
        (xy, theta), f = level
        scores = lattice_scores(fields[f], grid, best, xy, theta, sensor_angles, readings, returned,
                                interpolate=f == 0, window=window,
                                log_field=None if log_fields is None else log_fields[f], shift=shift)
        return lattice_poses(best, xy, theta), scores

    def with_prior(cands, scores):
        return scores if log_prior is None else scores + log_prior(cands)

    def descend(best, score, rest):
        for level in rest:
            cands, scores = level_scores(best, level)
            scores = with_prior(cands, scores)
            j = jnp.argmax(scores)
            best, score = cands[j], scores[j]
        return best, score

    if not levels:
        return center, jnp.asarray(0.0)
    if bound_span is not None:
        (xy, theta), f = levels[0]
        if log_prior is not None or window is not None or shift is not None or f == 0 or log_fields is None \
                or log_fields[f] is None:
            raise BayesmapError("a bounded search needs no prior, window or shift and a first level at the nearest "
                                "cell of its log field")
        j, score = bounded_lattice_argmax(log_fields[f], grid, center, xy, theta, sensor_angles, readings, returned,
                                          bound_span)
        a, b = j // theta.shape[0], j % theta.shape[0]
        return descend(lattice_poses(center, xy[a][None], theta[b][None])[0], score, levels[1:])
    cands, field = level_scores(center, levels[0])
    scores = with_prior(cands, field)
    j = jnp.argmax(scores)
    best, score = descend(cands[j], scores[j], levels[1:])
    if field_seed and log_prior is not None and len(levels) > 1:
        k = jnp.argmax(field)
        other, other_score = descend(cands[k], scores[k], levels[1:])
        (xy, theta), _ = levels[1]  # the second level's reach: two ends within it are one basin
        gap = jnp.abs(other - best)
        apart = (jnp.max(gap[:2]) > jnp.max(jnp.abs(xy))) | (gap[2] > jnp.max(jnp.abs(theta)))
        better = apart & (other_score > score)
        best, score = jnp.where(better, other, best), jnp.where(better, other_score, score)
    return best, score


def _sinh_nodes(first: float, last: float, per_side: int) -> tuple[np.ndarray, np.ndarray]:
    """``2 per_side + 1`` nodes ``a sinh(b k)``, ``k = -per_side .. per_side``, the first at ``first`` and the last
    at ``last``, with each node's width (half the distance between its neighbours; half a gap at the ends)."""
    # sinh(n b) / sinh(b) grows from n (b -> 0) past any ratio used (b = 10): its root by Brent's method
    b = scipy.optimize.brentq(lambda b: math.sinh(per_side * b) / math.sinh(b) - last / first, 1e-9, 10.0,
                              xtol=1e-15)
    nodes = first / math.sinh(b) * np.sinh(b * np.arange(-per_side, per_side + 1))
    width = np.empty_like(nodes)
    width[1:-1] = (nodes[2:] - nodes[:-2]) / 2
    width[0], width[-1] = (nodes[1] - nodes[0]) / 2, (nodes[-1] - nodes[-2]) / 2
    return nodes, width


def step_lattice(nodes=STEP_POSTERIOR_NODES) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The lattice of :func:`step_posterior` (:data:`STEP_POSTERIOR_NODES`): ``(xy (A, 2), theta (B,), log_volume
    (A B,), floor (3, 3))``, the candidates every pair in the order of :func:`lattice_scores`, ``log_volume`` each
    candidate's log cell volume (the quadrature weight of a non-uniform lattice), ``floor`` the variance of a
    uniform cell as wide as the innermost gaps, ``diag(h_xy^2, h_xy^2, h_theta^2) / 12`` (a posterior narrower than
    the lattice resolves reads as that cell).

    Raises:
        BayesmapError: unless every entry of ``nodes`` has ``0 < first < last`` and ``per_side >= 2``.
    """
    parts = []
    for first, last, per_side in nodes:
        if not (0 < first < last and isinstance(per_side, int) and per_side >= 2):
            raise BayesmapError(f"step lattice nodes must be (first, last, per_side) with 0 < first < last and "
                                f"per_side >= 2, got {(first, last, per_side)!r}")
        parts.append(_sinh_nodes(first, last, per_side))
    (x, wx), (t, wt) = parts
    xy = np.stack(np.meshgrid(x, x, indexing="ij"), axis=-1).reshape(-1, 2)
    volume = np.outer(wx, wx).reshape(-1)[:, None] * wt[None, :]
    floor = np.diag([nodes[0][0] ** 2, nodes[0][0] ** 2, nodes[1][0] ** 2]) / 12
    return jnp.asarray(xy), jnp.asarray(t), jnp.asarray(np.log(volume).reshape(-1)), jnp.asarray(floor)


def step_cell_widths(nodes=STEP_POSTERIOR_NODES) -> jax.Array:
    """``(A B, 3)`` the widths (m, m, rad) of each candidate's cell of :func:`step_lattice`, in its order: a draw
    from the lattice density uniform within the drawn node's cell (:mod:`bayesmap.slam.particles`)."""
    (_, wx), (_, wt) = (_sinh_nodes(*node) for node in nodes)
    wxy = np.stack(np.meshgrid(wx, wx, indexing="ij"), axis=-1).reshape(-1, 2)
    return jnp.asarray(np.concatenate([np.repeat(wxy, len(wt), axis=0), np.tile(wt, len(wxy))[:, None]], axis=1))


def _lattice_candidates(fields: tuple, grid: Grid, center, sensor_angles, readings, returned, lattice, window, shift):
    """The step ``lattice``'s candidates around ``center``, their field scores and log cell volumes."""
    xy, theta, log_volume, _ = lattice
    scores = lattice_scores(fields[0], grid, center, xy, theta, sensor_angles, readings, returned, interpolate=True,
                            window=window, shift=shift)
    return lattice_poses(center, xy, theta), scores, log_volume


def scan_logits(fields: tuple, grid: Grid, center, sensor_angles, readings, returned, power, lattice, window=None,
                shift=None):
    """The candidates ``(A B, 3)`` of the step ``lattice`` (:func:`step_lattice`) around ``center`` ``(3,)`` and the
    scan's part of their log densities ``(A B,)``: ``power S(x) + log_volume``, ``S`` the scan's field score against
    the local map (:func:`lattice_scores`, fine field, interpolated), each candidate's cell volume the quadrature
    weight. :func:`step_logits` adds the motion model; a loop edge's match has none
    (:func:`bayesmap.slam.posegraph.loop_posteriors`). ``window``, ``shift`` as :func:`search`. Jittable."""
    cands, scores, log_volume = _lattice_candidates(fields, grid, center, sensor_angles, readings, returned, lattice,
                                                    window, shift)
    return cands, power * scores + log_volume


def step_logits(fields: tuple, grid: Grid, center, prev, increment, cov, sensor_angles, readings, returned, power,
                lattice, window=None, shift=None, tail=None):
    """The candidates ``(A B, 3)`` of the step ``lattice`` (:func:`step_lattice`) around ``center`` and their log
    densities ``(A B,)``: ``power S(x) + log p(x | prev, increment, cov) + log_volume`` (:func:`scan_logits` with
    ``p`` the motion model, :func:`bayesmap.model.motion.motion_logpdf`): a softmax gives
    the step's posterior on the lattice, a logsumexp the log of its integral (the evidence of the step: the weight
    update of Grisetti et al. 2007's improved proposal). ``prev``, ``center`` ``(3,)`` in the frame of ``shift``
    (:func:`search`); ``tail``: None, or ``(weight, covariance (3, 3))``, the motion model with a broad component
    (:func:`bayesmap.model.motion.tailed_motion_logpdf`, as the front end searches). Jittable."""
    cands, scores, log_volume = _lattice_candidates(fields, grid, center, sensor_angles, readings, returned, lattice,
                                                    window, shift)
    motion = (motion_logpdf(prev, cands, increment, cov) if tail is None
              else tailed_motion_logpdf(prev, cands, increment, cov, *tail))
    return cands, power * scores + motion + log_volume


def lattice_covariance(cands, logits, frame, floor):
    """The covariance ``(3, 3)`` in the frame of ``frame`` ``(3,)`` (its heading) of the lattice density
    ``softmax(logits)`` over ``cands`` ``(M, 3)`` (:func:`scan_logits`, :func:`step_logits`), plus ``floor``
    ``(3, 3)``. Jittable."""
    weights = jax.nn.softmax(logits)
    mean = weights @ cands
    world = jnp.einsum("n,ni,nj->ij", weights, cands - mean, cands - mean)
    c, s = jnp.cos(frame[2]), jnp.sin(frame[2])
    turn = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], world.dtype)
    return turn.T @ world @ turn + floor


def step_covariance(cands, logits, prev, cov, floor):
    """:func:`lattice_covariance` of a step's lattice density in the frame of ``prev`` ``(3,)``; a step whose motion
    covariance ``cov`` is exactly zero gets ``floor`` alone. Jittable."""
    deterministic = jnp.all(jnp.asarray(cov) == 0)  # a step the motion model fixes: the lattice cell alone
    return jnp.where(deterministic, floor, lattice_covariance(cands, logits, prev, floor))


def step_posterior(fields: tuple, grid: Grid, center, prev, increment, cov, sensor_angles, readings, returned,
                   power, lattice, window=None, shift=None, tail=None):
    """The covariance ``(3, 3)`` of one step's posterior in the frame of the previous pose (the sequential edge's
    frame; m^2, m rad, rad^2): the density ``exp(power S(x) + log p(x | prev, increment, cov))`` of
    :func:`step_logits` integrated on the non-uniform ``lattice`` (:func:`step_lattice`, its ``floor`` added) around
    ``center``, the match (:func:`step_covariance`). The covariance of a correlative match's response (Olson 2009,
    sec. IV-B) with the likelihood tempered as the front end's score is. A step whose motion covariance is exactly
    zero gets ``floor``. ``tail`` as :func:`step_logits`. Jittable.
    """
    cands, logits = step_logits(fields, grid, center, prev, increment, cov, sensor_angles, readings, returned, power,
                                lattice, window, shift, tail)
    return step_covariance(cands, logits, prev, cov, lattice[-1])


def local_map(fields: tuple, stamps, since) -> tuple:
    """The fields ``(n, n)`` with every cell whose stamp (the path length of the last scan that reached it) is below
    ``since`` set to 0, unmapped: the local map a match reads, the same values as reading the fields through the
    window ``(stamps, since)`` (:func:`search`), with one pass over the grid instead of a stamp lookup per endpoint.
    Jittable."""
    return tuple(jnp.where(stamps >= since, field, jnp.zeros((), field.dtype)) for field in fields)


def hit_fraction(fields: tuple, grid: Grid, pose, sensor_angles, readings, returned, window=None, shift=None):
    """The fraction of returned beams whose endpoint at ``pose`` lands where the fine field exceeds one half (within
    about 1.2 sigma of a mapped endpoint): a match quality in [0, 1]; ``window`` and ``shift`` as in :func:`search`.
    Jittable."""
    value = _endpoint_values(fields[0], grid, scan_endpoints(pose, sensor_angles, readings), False, window, shift)
    return jnp.sum(returned & (value > 0.5)) / jnp.maximum(jnp.sum(returned), 1)


class MatchedPath(NamedTuple):
    """The front end's result (:func:`correlative_path`).

    Attributes:
        path: ``(S, 3)`` float64 poses (x m, y m, theta rad), row 0 the first pose.
        step_cov: ``(S - 1, 3, 3)`` float64: each step's posterior covariance in the frame of the pose before it
            (:func:`step_posterior`; a step whose match was not trusted: the motion model's covariance, plus the
            lattice's ``floor``).
        hypotheses: how many distinct paths carry at least 1 % of the weight (1 for the single track;
            :func:`bayesmap.slam.particles.hypotheses` for the particle front end).
    """

    path: np.ndarray
    step_cov: np.ndarray
    hypotheses: int = 1


def correlative_path(first_pose, data: ScanData, resolution: float, levels=MATCH_LEVELS,
                     window: float | None = LOCAL_MAP_DISTANCE,
                     half_width: float = MATCH_GRID_HALF_WIDTH,
                     likelihood_power: float = 1.0, min_hit_fraction: float = MIN_HIT_FRACTION,
                     progress: ProgressCallback | None = None, motion_tail: float = MOTION_TAIL_WEIGHT,
                     motion: MotionParams | None = None, field_seed: bool = FIELD_SEED,
                     odometry_steps=None, prefix: MatchedPath | None = None, until=None) -> MatchedPath:
    """Sequential correlative scan matching of every scan against the field of the scans before it, with each step's
    posterior covariance (:func:`step_posterior`).

    Args:
        first_pose: ``(3,)`` the fixed first pose (x m, y m, theta rad).
        data: the scans and odometry (:class:`ScanData`).
        resolution: the fields' cell size, meters.
        levels: the coarse-to-fine search (:data:`MATCH_LEVELS`).
        window: meters of path length (:data:`LOCAL_MAP_DISTANCE`): match each scan only against the scans
            within this distance travelled before it (by the odometry); None: against every scan before it.
        half_width: meters (:data:`MATCH_GRID_HALF_WIDTH`): the fields cover +-``half_width`` around a center that
            follows the robot; endpoints outside are ignored.
        likelihood_power: ``p`` in (0, 1]: each candidate's score is ``p`` times the field score plus the motion
            model's log-density (1: every beam counts fully, Olson 2009's score; :func:`bayesmap.slam.pipeline.
            front_end` passes the target's power, as the SLAM model tempers its readings).
        min_hit_fraction: a match that puts fewer of the scan's returned endpoints on the local map is replaced by
            the odometry's prediction (:data:`MIN_HIT_FRACTION`).
        progress: called with ``Progress("front end", done, S - 1, "scan")`` before the first match and after each
            block of about ``S / 100`` scans (the loop then runs a block per compiled call: the same path); None:
            one call, no reports.
        motion_tail: the weight in [0, 1) of the motion density's broad component in the search and the steps'
            posteriors (:data:`MOTION_TAIL_WEIGHT`; 0: the motion model's Normal alone).
        motion: the motion noise whose :func:`bayesmap.model.motion.backward_step_covariance` is the broad
            component's extra covariance (default :class:`bayesmap.model.motion.MotionParams`' defaults); the steps'
            own covariances are ``data``'s.
        field_seed: also descend from the first level's best by the field alone (:data:`FIELD_SEED`).
        odometry_steps: indices ``t`` in ``1 .. S - 1`` of the scans whose pose is the odometry's prediction from
            the pose before, whatever their match (as an untrusted match's: covariance the motion model's plus the
            lattice's floor); the other hypothesis at a step where scan and odometry disagree
            (:mod:`bayesmap.slam.branches`). None: none.
        prefix: a :class:`MatchedPath` of the same scans by this function with the same settings and none of
            ``odometry_steps`` before the first of them: its poses and steps before that scan are kept and matching
            resumes there (:func:`resumed_window`), the same path as matching from the first scan.
        until: None, or a function of the path matched so far, ``path (n, 3)`` and ``step_cov (n - 1, 3, 3)``
            float64 (poses ``0 .. n - 1``), that returns a scan index ``j < n`` to stop at, or None to go on: it is
            called after each block of ``ceil((S - 1) / 100)`` scans (:func:`run_in_blocks`), and the path returned
            ends at ``j`` (a branch that rejoins the single track, :func:`bayesmap.slam.branches.rejoin_scan`). The
            path up to ``j`` is the same as without it.

    Returns:
        A :class:`MatchedPath`: the path, row 0 ``first_pose``, and the steps' covariances (``S`` poses; ``j + 1``
        where ``until`` stopped it at ``j``).

    Raises:
        BayesmapError: if the shapes disagree, ``resolution`` or ``half_width`` is not a finite number > 0 or the
            grid would have fewer than 8 cells a side, ``likelihood_power`` is not in (0, 1], or
            ``min_hit_fraction`` or ``motion_tail`` is not in [0, 1), or an index of ``odometry_steps`` is outside
            ``1 .. S - 1`` (named).
    """
    forced = odometry_mask(odometry_steps, data.readings.shape[0])
    setup = front_end_setup(first_pose, data, resolution, window, half_width, likelihood_power, min_hit_fraction,
                            motion_tail, motion)
    run = functools.partial(_correlative_steps, d=setup.scans, frame=setup.frame, span=setup.span,
                            prior_weight=setup.prior_weight, min_hit=setup.min_hit, steps=lattices(levels),
                            grid=setup.grid, half_width=float(half_width), power=setup.power,
                            posterior=step_lattice(), tail=(setup.tail_weight, setup.tail_cov),
                            field_seed=bool(field_seed), forced=jnp.asarray(forced))
    first = 1
    if prefix is not None and forced.any():
        first = int(np.argmax(forced))
        start = functools.partial(resumed_window, jnp.asarray(prefix.path, setup.frame.dtype),
                                  jnp.asarray(prefix.step_cov, setup.frame.dtype), first, setup.scans, setup.frame,
                                  setup.grid, float(half_width))
    else:
        start = functools.partial(start_window, setup.first_pose, setup.scans, setup.frame, setup.grid)
    stops = []

    def stopped(carry, hi) -> bool:  # (the path so far to the host before the next block's call donates it)
        j = until(np.asarray(carry[0][:hi], np.float64), np.asarray(carry[-1][1:hi], np.float64))
        stops.extend([] if j is None else [int(j)])
        return j is not None

    carry = run_in_blocks(run, start, data.readings.shape[0], progress, first, None if until is None else stopped)
    path, step_cov = np.asarray(carry[0], np.float64), np.asarray(carry[-1], np.float64)[1:]
    return MatchedPath(path, step_cov) if not stops else MatchedPath(path[:stops[0] + 1], step_cov[:stops[0]])


def odometry_mask(steps, count: int) -> np.ndarray:
    """``(count,)`` bool, True at the scan indices ``steps`` (an iterable of ints in ``1 .. count - 1``; None: none).

    Raises:
        BayesmapError: naming an index that is not an integer in ``1 .. count - 1``.
    """
    mask = np.zeros(count, bool)
    for t in () if steps is None else steps:
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not 1 <= t < count:
            raise BayesmapError(f"odometry step {t!r} is not a scan index in 1..{count - 1}")
        mask[int(t)] = True
    return mask


class FrontEndSetup(NamedTuple):
    """What the front end's jitted loops take (:func:`front_end_setup`).

    Attributes:
        scans: the scans as :class:`FrontEndScans` (arrays of JAX's default float; bool ``returned``).
        first_pose: ``(3,)`` the first pose, world coordinates.
        frame: ``(3,)`` the world position of the first pose with a heading of 0: every match is computed in this
            frame (the poses less ``frame``).
        grid: the fields' square grid (origin 0; its cell ``(i, j)`` is the frame's cell ``offset + (i, j)``).
        span: meters of travel of the local map (``inf``: every scan).
        power: the likelihood power ``p``.
        prior_weight: ``1 / p``, the motion term's weight in the search's score (scaling it instead of the field
            score leaves the argmax the same).
        min_hit: the least hit fraction of a trusted match.
        tail_weight: the weight of the motion density's broad component (:data:`MOTION_TAIL_WEIGHT`).
        tail_cov: ``(3, 3)`` its extra covariance (:func:`bayesmap.model.motion.backward_step_covariance`).
    """

    scans: "FrontEndScans"
    first_pose: jax.Array
    frame: jax.Array
    grid: Grid
    span: jax.Array
    power: jax.Array
    prior_weight: jax.Array
    min_hit: jax.Array
    tail_weight: jax.Array
    tail_cov: jax.Array


def front_end_setup(first_pose, data: ScanData, resolution: float, window: float | None = LOCAL_MAP_DISTANCE,
                    half_width: float = MATCH_GRID_HALF_WIDTH, likelihood_power: float = 1.0,
                    min_hit_fraction: float = MIN_HIT_FRACTION, motion_tail: float = MOTION_TAIL_WEIGHT,
                    motion: MotionParams | None = None) -> FrontEndSetup:
    """Check the front end's arguments (:func:`correlative_path`'s) and build what its loops take.

    Raises:
        BayesmapError: if the shapes disagree, ``resolution`` or ``half_width`` is not a finite number > 0 or the
            grid would have fewer than 8 cells a side, ``likelihood_power`` is not in (0, 1], or
            ``min_hit_fraction`` or ``motion_tail`` is not in [0, 1).
    """
    s, k = data.readings.shape
    if data.sensor_angles.shape != (s, k) or data.returned.shape != (s, k) or data.increments.shape != (s - 1, 3):
        raise BayesmapError(f"scan data shapes disagree: readings {data.readings.shape}, angles "
                            f"{data.sensor_angles.shape}, returned {data.returned.shape}, increments "
                            f"{data.increments.shape}")
    for name, value in (("resolution", resolution), ("half_width", half_width)):
        if not (math.isfinite(float(value)) and value > 0):
            raise BayesmapError(f"{name} must be a finite number of meters > 0, got {value!r}")
    power = check_likelihood_power(likelihood_power)
    for name, value in (("min_hit_fraction", min_hit_fraction), ("motion_tail", motion_tail)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1:
            raise BayesmapError(f"{name} must be a number in [0, 1), got {value!r}")
    n = int(math.ceil(2 * half_width / resolution))
    if n < 8:
        raise BayesmapError(f"half_width {half_width!r} m is under 4 cells of {resolution!r} m")
    dtype = jnp.result_type(float)
    first_pose = np.asarray(first_pose, np.float64)
    travelled = path_length(data.increments)
    arrays = ScanData(*(jnp.asarray(a, dtype=bool if a.dtype == bool else dtype) for a in map(np.asarray, data)))
    return FrontEndSetup(scans=FrontEndScans(*arrays, travelled=jnp.asarray(travelled, dtype)),
                         first_pose=jnp.asarray(first_pose, dtype),
                         frame=jnp.asarray(np.append(first_pose[:2], 0.0), dtype),
                         grid=Grid(shape=(n, n), resolution=resolution, origin=(0.0, 0.0)),
                         span=jnp.asarray(np.inf if window is None else float(window), dtype),
                         power=jnp.asarray(power, dtype),
                         prior_weight=jnp.asarray(1.0 / power, dtype), min_hit=jnp.asarray(min_hit_fraction, dtype),
                         tail_weight=jnp.asarray(motion_tail, dtype),
                         tail_cov=jnp.asarray(backward_step_covariance(motion), dtype))


def recentred(predicted, offset, grid: Grid, half_width: float):
    """Whether the fields' window must move before matching at ``predicted`` ``(3,)`` (in the front end's frame) and
    its offset ``(2,)`` int32 after: it moves, by whole cells, to center on ``predicted`` when that lies more than a
    quarter of ``half_width`` from its center (:data:`MATCH_GRID_HALF_WIDTH`). Jittable."""
    n = grid.shape[0]
    cells = jnp.round(predicted[:2] / grid.resolution - offset - n / 2).astype(jnp.int32)  # from the center
    far = jnp.max(jnp.abs(cells)) * grid.resolution > half_width / 4
    return far, jnp.where(far, offset + cells, offset)


PROGRESS_REPORTS = 100
"""With a progress callback, the front end reports about this many times, a compiled call per block of scans: a call
costs about 3.5 ms on the 2-core machine, a third of a scan's matching, so a call per scan would slow the front end
by a third."""


def run_in_blocks(run, start, count: int, progress: ProgressCallback | None, first: int = 1, until=None):
    """``run(start(), first, count)``, a front end's loop over the scans ``first .. count - 1`` from the carry
    ``start()`` makes (the single track's and the particles', :mod:`bayesmap.slam.particles`); with ``progress`` or
    ``until``, in blocks of ``ceil((count - 1) / PROGRESS_REPORTS)`` scans (:data:`PROGRESS_REPORTS`), one call each
    (the same carry: the loop's bounds are arguments, one compilation), reporting the scans matched after each;
    ``until(carry, hi) -> bool``, called after the block that ends before scan ``hi``, stops the loop there when
    True."""
    if (progress is None and until is None) or count - first < 1:
        return run(start(), first, count)
    report(progress, "front end", first - 1, count - 1, "scan")
    carry = start()
    block = max(1, -(-(count - 1) // PROGRESS_REPORTS))
    for lo in range(first, count, block):
        hi = min(lo + block, count)
        carry = jax.block_until_ready(run(carry, lo, hi))
        report(progress, "front end", hi - 1, count - 1, "scan")
        if until is not None and until(carry, hi):
            break
    return carry


def path_length(increments) -> np.ndarray:
    """``(S,)`` float64: the odometry's path length at each scan, meters, from its increments ``(S - 1, 3)`` (0 at the
    first scan): what the front end's local map is measured in (:data:`LOCAL_MAP_DISTANCE`)."""
    increments = np.asarray(increments, np.float64)
    return np.concatenate([[0.0], np.cumsum(np.hypot(increments[:, 0], increments[:, 1]))])


def local_map_shares(path, data: ScanData, window: float | None = LOCAL_MAP_DISTANCE,
                     radius: float = FIELDS[0][1]) -> scipy.sparse.csr_matrix:
    """Which scans each front-end step was matched against: row ``t - 1`` holds, for each scan ``s`` of step ``t``'s
    local map (the scans ``s < t`` within ``window`` meters of travel before it by the odometry, as
    :func:`correlative_path` windows its fields), the share of scan ``t``'s returned endpoints at ``path[t]`` whose
    nearest local-map endpoint within ``radius`` meters (the fine field's reach, :data:`FIELDS`) is one of scan
    ``s``'s, at ``path[s]``. The field is a scatter-max over the endpoints, so the nearest endpoint is the one that
    sets an endpoint's field value, and moving scan ``s`` moves what it sets. A step with no endpoint within reach of
    its local map puts its whole share on scan ``t - 1``. What :class:`bayesmap.slam.posegraph.LocalMaps` ties each
    step's scan information to.

    Args:
        path: ``(S, 3)`` float the poses the local maps were built at (x m, y m, theta rad): the front end's path.
        data: the scans and odometry (:class:`ScanData`), ``S`` scans.
        window: meters of travel (:data:`LOCAL_MAP_DISTANCE`); None: every scan before.
        radius: meters, > 0.

    Returns:
        ``(S - 1, S)`` float64 sparse rows, each summing to 1, nonzero only in columns ``< t`` of row ``t - 1``.

    Raises:
        BayesmapError: if ``path`` is not ``(S, 3)`` for the ``S`` scans of ``data``, or ``radius`` or ``window`` is
            not a finite number > 0.
    """
    readings = np.asarray(data.readings, np.float64)
    count = readings.shape[0]
    path = np.asarray(path, np.float64)
    if path.shape != (count, 3):
        raise BayesmapError(f"path must be ({count}, 3), one pose per scan, got shape {path.shape}")
    for name, value in (("radius", radius), ("window", 1.0 if window is None else window)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise BayesmapError(f"{name} must be a finite number of meters > 0, got {value!r}")
    ends = scan_endpoints(path, np.asarray(data.sensor_angles, np.float64), readings, xp=np)
    returned = np.asarray(data.returned, bool)
    travelled = path_length(data.increments)
    first = np.zeros(count, np.int64) if window is None else np.searchsorted(travelled, travelled - window)
    rows, cols, vals = [], [], []
    for t in range(1, count):
        members = np.arange(first[t], t)
        points = ends[members][returned[members]]
        share = None
        if len(points) and returned[t].any():
            owner = np.repeat(members, returned[members].sum(axis=1))
            distance, nearest = scipy.spatial.cKDTree(points).query(ends[t][returned[t]], distance_upper_bound=radius)
            hit = np.isfinite(distance)
            if hit.any():
                scans, counts = np.unique(owner[nearest[hit]], return_counts=True)
                share = (scans, counts / counts.sum())
        scans, weights = share if share is not None else (np.array([t - 1]), np.array([1.0]))
        rows.append(np.full(len(scans), t - 1))
        cols.append(scans)
        vals.append(weights)
    if count < 2:
        return scipy.sparse.csr_matrix((0, count))
    return scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                   shape=(count - 1, count))


def add_matched(d, grid: Grid, frame, world, u, offset, carry):
    """The fields and stamps ``carry`` of the window at ``offset`` with scan ``u`` of ``d`` added at its matched
    pose ``world`` ``(3,)``: its endpoints' fields (:func:`add_to_fields`), and its path length scatter-maxed into
    the cells its broad field reaches (the stamps). Computed in the front end's frame (world coordinates less
    ``frame`` ``(3,)``) and shifted by whole cells, so the values do not depend on where the window is or on its
    size."""
    fields, stamps = carry
    pose = world - frame
    angles, readings, returned = d.sensor_angles[u], d.readings[u], d.returned[u]
    fields = add_to_fields(fields, grid, pose, angles, readings, returned, offset)
    flat, _ = _stencil_cells(grid, pose, angles, readings, returned, *FIELDS[-1], stamps.size, offset)
    stamps = stamps.reshape(-1).at[flat.reshape(-1)].max(d.travelled[u], mode="drop").reshape(stamps.shape)
    return fields, stamps


def _rebuild(d, grid: Grid, frame, path, t, offset):
    """The fields and stamps of the window at ``offset`` from every scan ``< t`` of ``d`` at its matched pose in
    ``path``: those of a grid covering everything, restricted to the window (the stamps mask all but the local
    map)."""
    empty = (empty_fields(grid), jnp.full(grid.shape, -jnp.inf, frame.dtype))
    return jax.lax.fori_loop(0, t, lambda u, carry: add_matched(d, grid, frame, path[u], u, offset, carry), empty)


def moved_window(d, grid: Grid, frame, path, t, fields, stamps, old, new):
    """The fields and stamps of the window at offset ``new`` (``(2,)`` int32; those of a grid covering every scan
    ``< t`` of ``d`` at its pose in ``path`` ``(S, 3)``, restricted to the window), from those at offset ``old``,
    the same to the bit as a rebuild from every scan. Jittable. A cell that lies at least a stencil's reach (the
    broad field's radius in cells, plus one) inside both windows has the same value in either (every endpoint
    that reaches it lies inside both), so it is moved; every other cell is cleared and filled again from the
    scans ``< t`` whose endpoints reach it (by their bounding box plus the reach; adding a scan twice changes
    nothing). Scans far from the windows' edges, most of them, are skipped."""
    n = grid.shape[0]
    delta = new - old
    margin = _stencil_reach(grid.resolution, FIELDS[-1][1]) + 1
    lo = jnp.maximum(margin, margin - delta)  # the moved square, in the new window's cells
    hi = jnp.minimum(n - margin, n - margin - delta)
    cell = jnp.arange(n)
    keep = ((cell[:, None] >= lo[0]) & (cell[:, None] < hi[0]) & (cell[None, :] >= lo[1]) & (cell[None, :] < hi[1]))

    def shifted(array, fill):
        return jnp.where(keep, jnp.roll(array, (-delta[0], -delta[1]), axis=(0, 1)), fill)

    poses = path - frame
    coords = grid.to_cell_coords(scan_endpoints(poses, d.sensor_angles, d.readings)) - new  # (S, K, 2)
    returned = d.returned[..., None]
    first = jnp.clip(jnp.min(jnp.where(returned, coords, jnp.inf), axis=1) - margin, 0, n - 1)
    last = jnp.clip(jnp.max(jnp.where(returned, coords, -jnp.inf), axis=1) + margin, 0, n - 1)
    moved_only = jnp.all(first >= lo, axis=-1) & jnp.all(last < hi, axis=-1)  # (or nothing: no returned beam)
    again = (jnp.arange(len(path)) < t) & ~moved_only
    scans = jnp.nonzero(again, size=len(path), fill_value=0)[0]

    def add(i, carry):
        return add_matched(d, grid, frame, path[scans[i]], scans[i], new, carry)

    moved = (tuple(shifted(field, 0.0) for field in fields), shifted(stamps, -jnp.inf))
    return jax.lax.fori_loop(0, jnp.sum(again), add, moved)


@functools.partial(jax.jit, static_argnames=("grid",))
def start_window(first, d, frame, grid: Grid):
    """The carry of the front end's loop before scan 1: ``(path (S, 3)`` with row 0 ``first``, the fields and stamps
    of scan 0 at it, the window's offset: the frame's cell of its first cell, so that ``first`` is at its center;
    the steps' covariances ``(S, 3, 3)``, row ``t`` the step to scan ``t``, zeros)."""
    path = jnp.zeros((d.readings.shape[0], 3), first.dtype).at[0].set(first)
    offset = jnp.full(2, -(grid.shape[0] // 2), jnp.int32)
    fields, stamps = _rebuild(d, grid, frame, path, 1, offset)
    return path, fields, stamps, offset, jnp.zeros((d.readings.shape[0], 3, 3), first.dtype)


@functools.partial(jax.jit, static_argnames=("grid", "half_width"))
def resumed_window(path, step_cov, t, d, frame, grid: Grid, half_width: float):
    """The carry of :func:`correlative_path`'s loop before scan ``t`` of a path whose poses before ``t`` are those
    of ``path`` ``(S, 3)`` (world coordinates) and steps those of ``step_cov`` ``(S - 1, 3, 3)``: the window's offset
    as the loop moved it over the scans ``1 .. t - 1`` (:func:`recentred` replayed) and the fields and stamps of the
    scans ``< t`` in it (a rebuild, the same to the bit as the loop's own, :func:`moved_window`)."""
    def moved(u, offset):
        return recentred(compose(path[u - 1] - frame, d.increments[u - 1]), offset, grid, half_width)[1]

    offset = jax.lax.fori_loop(1, t, moved, jnp.full(2, -(grid.shape[0] // 2), jnp.int32))
    fields, stamps = _rebuild(d, grid, frame, path, t, offset)
    return path, fields, stamps, offset, jnp.concatenate([jnp.zeros((1, 3, 3), step_cov.dtype), step_cov])


@functools.partial(jax.jit, static_argnames=("grid", "half_width", "field_seed"), donate_argnames=("carry",),
                   compiler_options=MATCHER_COMPILER_OPTIONS)
def _correlative_steps(carry, lo, hi, d, frame, span, prior_weight, min_hit, steps: Lattices, grid: Grid,
                       half_width: float, power, posterior, tail, forced, field_seed: bool = FIELD_SEED):
    """The jitted loop of :func:`correlative_path` over the scans ``lo <= t < hi`` from ``carry`` (module level, so
    that another run with the same shapes and settings reuses the compiled code; the bounds are arguments, so runs in
    pieces share it): the carry ``(path (S, 3)`` in world coordinates, fields, stamps, window offset) after scan
    ``hi - 1``. ``steps`` are the search levels (:func:`lattices`); ``frame`` ``(3,)`` the world position (and a
    heading of 0) of the frame every match is computed in (the first pose's: the poses less ``frame``, their cells
    in that frame's grid of ``grid.resolution``, the window's cell ``(i, j)`` the frame's cell ``offset + (i, j)``);
    ``prior_weight`` the inverse of the likelihood power (scaling the motion term instead of the field score leaves
    the argmax the same); ``min_hit`` the least hit fraction of a trusted match; ``power`` the likelihood power and
    ``posterior`` the lattice (:func:`step_lattice`) of each step's covariance (:func:`step_posterior`), the last
    entry of the carry; ``tail`` ``(weight, covariance)`` the motion density's broad component in both;
    ``forced`` ``(S,)`` bool: the scans that take the odometry's prediction (:func:`odometry_mask`); ``field_seed``
    :func:`search`'s."""
    def body(t, carry):
        path, fields, stamps, offset, step_cov = carry
        prev = path[t - 1] - frame
        predicted = compose(prev, d.increments[t - 1])
        far, moved = recentred(predicted, offset, grid, half_width)
        fields, stamps = jax.lax.cond(far, lambda: moved_window(d, grid, frame, path, t, fields, stamps, offset, moved),
                                      lambda: (fields, stamps))

        def log_prior(cands):
            return prior_weight * tailed_motion_logpdf(prev, cands, d.increments[t - 1], d.covs[t - 1], *tail)

        seen = local_map(fields, stamps, d.travelled[t] - span)  # the cells reached within the window
        scan = (d.sensor_angles[t], d.readings[t], d.returned[t])
        best, _ = search(seen, grid, predicted, *scan, steps, log_prior, shift=moved, field_seed=field_seed)
        hits = hit_fraction(seen, grid, best, *scan, shift=moved)
        odometry = (hits < min_hit) | forced[t]
        world = jnp.where(odometry, predicted, best) + frame
        cov = step_posterior(seen, grid, best, prev, d.increments[t - 1], d.covs[t - 1], *scan, power, posterior,
                             shift=moved, tail=tail)
        cov = jnp.where(odometry, d.covs[t - 1] + posterior[-1], cov)
        fields, stamps = add_matched(d, grid, frame, world, t, moved, (fields, stamps))
        return path.at[t].set(world), fields, stamps, moved, step_cov.at[t].set(cov)

    return jax.lax.fori_loop(lo, hi, body, carry)


class FrontEndScans(NamedTuple):
    """The scans as the front end's jitted loops read them: :class:`ScanData`'s arrays (JAX's default float; bool
    ``returned``) and ``travelled`` ``(S,)``, the odometry's path length at each scan, meters (the stamps of the local
    map, :func:`add_matched`)."""

    sensor_angles: jax.Array
    readings: jax.Array
    returned: jax.Array
    increments: jax.Array
    covs: jax.Array
    travelled: jax.Array
