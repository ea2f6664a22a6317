"""Scenes: the tutorial's scene and real scans as a :class:`~bayesmap.problem.Problem`, and every default of a scene.

Layout of this module: first every default of a scene (one documented block; the CLI and
:mod:`bayesmap.evaluation.heldout` read them from here), then the functions that derive a log's defaults from its
data (:func:`endpoints_per_cell`, :func:`log_likelihood_power`, :func:`log_coupling`, :func:`log_prior_wall_prob`,
:func:`log_wall_pass_prob`), then the scene constructors :func:`tutorial_problem`, :func:`scan_problem` and
:func:`log_problem`. The problem they build (observations, poses, parameters) is :mod:`bayesmap.problem`; a log
whose poses are odometry is a SLAM scene (:mod:`bayesmap.slam.problem`).

How each default of a log was chosen, with its history and the command that reproduces it, is on the validation
page [Defaults and how they were chosen](../validation/defaults.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles
from bayesmap.io.ascii import tutorial_map
from bayesmap.model.generative import check_likelihood_power, make_params, simulate_readings
from bayesmap.model.prior import DEFAULT_COUPLING, coupling_for_run_length
from bayesmap.problem import Observations, Problem

# ---------------------------------------------------------------------------------------------------------------
# Scene defaults: every default of a scene, in one place
# ---------------------------------------------------------------------------------------------------------------

TUTORIAL_POS = (10.0, 10.0)
"""Sensor position of the tutorial's scene, meters: the center cell of its 21 x 21 map of 1 m cells."""

TUTORIAL_PRIOR = 0.5
"""The tutorial's ``prior_wall_prob`` (also the default of maps and of a single scan of a log)."""

TUTORIAL_SENSOR_NOISE = 0.2
"""The tutorial's ``sensor_noise``: standard deviation of a reading, meters (also the default of maps)."""

TUTORIAL_NUM_ANGLES = 100
"""The tutorial's ``num_angles``: beams equally spaced over 360 degrees."""

TUTORIAL_SEED = 0
"""Seed of the tutorial's simulated readings (``jax.random.key(0)`` gives the tutorial's readings)."""

TUTORIAL_BEAM_MODEL = "normal"
"""Sensor model of the tutorial and of maps: the tutorial's Normal reading around the first wall's distance."""

LOG_BEAM_MODEL = "beam"
"""Sensor model of real scans of a log: the robust beam mixture (Thrun, Burgard and Fox, Probabilistic Robotics,
section 6.3)."""

RESOLUTION = 0.1
"""Grid resolution for real data, meters per cell."""

MARGIN = 1.0
"""Meters added around the sensor positions and the returned beams' endpoints when a grid is fitted to real data."""

MAX_RANGE_MARGIN = 1.0
"""When a log has no max-range readings (``CarmenLog.max_range`` is infinite), the model's max distance is the
longest selected reading plus this many meters."""

LOG_PRIOR = 0.1
"""Default prior wall probability for maps from many scans with independent cells (logs with no coupling, floor
plans): indoor floor plans have about a tenth of their cells occupied, and with 0.5 the robust beam model explains a
long beam's reading as a sensor failure rather than as free space (the prior odds of "no wall in 100 cells" are
2^-100 against a likelihood ratio of at most 9) ([validation](../validation/defaults.md#log_prior))."""

# The map defaults of a log: every one a property of the sensor or the world, none a count of cells, chosen together
# by leave-one-log-out cross-validation over Intel, ACES and CSAIL at 0.1 and 0.2 m (benchmarks/map_cv.py; the
# protocol, the stages of the search and the history are on docs/validation/defaults.md).

LOG_GEOMETRY = "chord"
"""Wall geometry of real scans of a log (``ModelParams.geometry``): ``"chord"``, the surface anywhere on the beam's
chord through the first wall cell, the sensor's hit averaged over it (:mod:`bayesmap.model.sensor`). It needs no
range offset at any resolution: a log's default offset is 0. The tutorial's ``"entry"`` geometry (the reading
expected where the beam enters the cell) stays the tutorial's; ``bayesmap slam --log`` uses the chord geometry too
(:data:`bayesmap.slam.problem.SLAM_GEOMETRY`). Chosen by leave-one-log-out cross-validation of the held-out AUC and
predictive NLL over Intel, ACES and CSAIL at 0.1 and 0.2 m, with the other map defaults of a log
([validation](../validation/defaults.md#log_geometry))."""

LOG_SENSOR_NOISE = 0.05
"""Default ``sensor_noise`` of a log's map, meters: the hit component's standard deviation (a property of the laser
and of the poses' residual error, not of the cells). Chosen by leave-one-log-out cross-validation over 0.05 and
0.1 m, with the other map defaults of a log ([validation](../validation/defaults.md#log_sensor_noise))."""

SCAN_SENSOR_NOISE = 0.05
"""Default ``sensor_noise`` of the map of one real scan (``infer --log FILE --scan N``, the tutorial's single-scan
model), meters: half a cell at the default 0.1 m; one scan has no held-out beams to cross-validate it on
([validation](../validation/defaults.md#scan_sensor_noise))."""

LOG_READINGS_PER_CELL = 0.7
"""How many independent readings the returned beams that end in one cell are worth together, on average: the default
likelihood power ``eta`` of a log's map (:attr:`bayesmap.problem.Problem.likelihood_power`) is this over the mean
number of returned readings per cell that holds an endpoint (:func:`log_likelihood_power`). The model treats every
beam as independent evidence given the map; the beams of a log are not (a scan's beams share its pose error,
neighbouring beams and consecutive scans see the same surface through the same errors), and raising the likelihood
to ``eta < 1`` counts each beam as a fraction of one (a power posterior;
:func:`bayesmap.model.generative.check_likelihood_power`). A cell's evidence does not grow with the number of scans
that see it through the same errors: a power that does not follow the density over-counts a log with twice the scans,
or cells of twice the size. Chosen by leave-one-log-out
cross-validation among 0.5, 0.7, 1, 1.4 and 2, with the other map defaults of a log
([validation](../validation/defaults.md#log_readings_per_cell))."""

LOG_RUN_LENGTH = 1.0
"""Default mean run length of the structured prior of a log's map, meters (:func:`log_coupling`;
:func:`bayesmap.model.prior.coupling_for_run_length`): the coupling whose runs of equal cells along a row are this
long on average, at any resolution; 0 would be the independent prior. Chosen by leave-one-log-out
cross-validation over 0, 1, 2 and 4 m, with the other map defaults of a log
([validation](../validation/defaults.md#log_run_length))."""

LOG_CUT_PAST_READING = 0.5
"""Meters past its reading beyond which a returned beam of a log does not look at the map
(``ModelParams.cut_past_reading``; :func:`bayesmap.model.generative.cut_chords`), the default of ``bayesmap infer``,
``evaluate`` and ``slam`` on logs: the ray-cell table stops there, a fifth of the whole beams' pairs on Intel. Chosen
by leave-one-log-out cross-validation over 0.25, 0.5, 1 and 2 m and the whole beam, as the shortest cut whose held-out
NLL and AUC on the other logs at 0.1 and 0.2 m are no worse than the whole beam's
([validation](../validation/defaults.md#log_cut_past_reading)). :func:`log_problem`'s own default stays the whole
beam (held-out beams are scored whole)."""

LOG_KEYFRAME_DISTANCE = 0.2
"""Meters the poses must move from the last keyframe for a scan of a log to be mapped by ``bayesmap infer`` and
``evaluate`` (:func:`bayesmap.slam.keyframes.select_keyframes`; with :data:`LOG_KEYFRAME_TURN`): Karto's default
``MinimumTravelDistance``. At the corrected poses it keeps 905 of Intel's 910 scans, 439 of ACES' 440 and all of
CSAIL's 406, whose maps were validated with every scan, and 1,846 of Freiburg 079's 4,791 (a bag's rate, a scan every
0.1 m), whose every scan would not fit in memory ([validation](../validation/scale.md#keyframes)). ``bayesmap slam``
keeps fewer (:data:`bayesmap.slam.keyframes.KEYFRAME_DISTANCE`)."""

LOG_KEYFRAME_TURN = 0.2
"""Radians the heading must turn from the last keyframe for a scan to be mapped (with
:data:`LOG_KEYFRAME_DISTANCE`), about Karto's default ``MinimumTravelHeading`` (10 degrees, 0.17 rad)."""

LOG_WALL_PASS_PROB = 0.5
"""Default probability that a beam passes through a wall cell of a log's map (``ModelParams.wall_pass_prob``; a
probability of the world, the same at every resolution). 0.5 is the largest value the model is meant for: a reading
comes from the ray's first two wall cells or from no wall, and at 0.5 the no-wall reading already carries a quarter
of the mass (``pi^2``), a third wall's share that the two-wall model cannot place (docs/sensor.md). Chosen by
leave-one-log-out cross-validation over 0.1, 0.3 and 0.5, with the other map defaults of a log
([validation](../validation/defaults.md#log_wall_pass_prob))."""

LOG_STRUCTURED_PRIOR = 0.1
"""Default ``prior_wall_prob`` of a log's map with the structured prior (coupling ``J > 0``, the default): the
probability that a cell is a wall *given as many wall as free 4-neighbours* (:mod:`bayesmap.model.prior`), not the
fraction of wall cells. Equal to :data:`LOG_PRIOR`, the independent prior's (:func:`log_prior_wall_prob`), by the
cross-validation, not by construction: the two mean different things. Chosen by leave-one-log-out
cross-validation over 0.1, 0.3 and 0.5, with the other map defaults of a log
([validation](../validation/defaults.md#log_structured_prior))."""

SIMULATED_NUM_POSES = 30
"""Simulated scans of a floor plan (:func:`bayesmap.evaluation.heldout.evaluate_truth`): number of poses."""

SIMULATED_NUM_ANGLES = 360
"""Simulated scans of a floor plan: beams per scan, equally spaced over 360 degrees."""

SIMULATED_MAX_RANGE = 20.0
"""Simulated scans of a floor plan: the sensor's max range, meters."""

SIMULATED_CLEARANCE = 0.5
"""Simulated scans of a floor plan: meters of known free space around every pose."""

SIMULATED_SENSOR_NOISE = 0.05
"""Simulated scans of a floor plan: the sensor's noise (the hit's standard deviation), meters; the model's too."""


# ---------------------------------------------------------------------------------------------------------------
# A log's defaults from its data
# ---------------------------------------------------------------------------------------------------------------


def endpoints_per_cell(endpoints, grid: Grid) -> float:
    """The mean number of returned readings whose endpoint falls in a cell, over the cells of ``grid`` that hold at
    least one endpoint.

    Args:
        endpoints: ``(N, 2)`` world-frame endpoints of the returned (not max-range) readings, meters.
        grid: the cells; endpoints outside it are not counted.

    Returns:
        The mean count (a float >= 1), or 0.0 when no endpoint lies inside the grid.
    """
    cells = grid.cell_index(np.asarray(endpoints, np.float64).reshape(-1, 2))
    inside = np.all((cells >= 0) & (cells < np.asarray(grid.shape)), axis=1)
    if not inside.any():
        return 0.0
    flat = cells[inside, 0] * grid.shape[1] + cells[inside, 1]
    return float(inside.sum() / len(np.unique(flat)))


def log_likelihood_power(per_cell: float, readings_per_cell: float = LOG_READINGS_PER_CELL) -> float:
    """The default likelihood power of a log's map whose cells hold ``per_cell`` returned endpoints on average
    (:func:`endpoints_per_cell`): ``min(1, readings_per_cell / per_cell)``, so that a typical wall cell's readings
    together count as ``readings_per_cell`` independent ones (:data:`LOG_READINGS_PER_CELL`); 1 when nothing
    returned. This is the power of Miller & Dunson's coarsened posterior (2019, JASA 114(527), in its power-posterior
    form ``alpha / (alpha + n)`` for ``n`` observations, about ``alpha / n`` for large ``n``) with ``n`` the
    observations of one cell, the unit whose posterior the map reports.

    Raises:
        BayesmapError: if ``readings_per_cell`` is not a finite number > 0.
    """
    if (isinstance(readings_per_cell, bool) or not isinstance(readings_per_cell, (int, float))
            or not math.isfinite(readings_per_cell) or readings_per_cell <= 0):
        raise BayesmapError(f"readings_per_cell must be a finite number > 0, got {readings_per_cell!r}")
    return 1.0 if per_cell <= 0 else min(1.0, float(readings_per_cell) / float(per_cell))


def log_coupling(resolution: float, run_length: float = LOG_RUN_LENGTH) -> float:
    """The default coupling ``J`` (nats) of a log's map on cells of ``resolution`` meters: the structured prior whose
    mean run length is ``run_length`` meters (:func:`bayesmap.model.prior.coupling_for_run_length`); 0 (the
    independent prior, runs of two cells) where ``run_length`` is 0 or shorter than two cells.

    Raises:
        BayesmapError: if ``resolution`` is not finite and > 0.
    """
    if not (math.isfinite(resolution) and resolution > 0):
        raise BayesmapError(f"resolution must be a finite number > 0 (meters), got {resolution!r}")
    if not run_length or run_length < 2 * resolution:
        return 0.0
    return coupling_for_run_length(run_length, resolution)


def log_prior_wall_prob(coupling: float) -> float:
    """The default ``prior_wall_prob`` of a log's map with the structured prior's coupling ``coupling`` (nats):
    :data:`LOG_STRUCTURED_PRIOR` when ``coupling > 0``, :data:`LOG_PRIOR` for independent cells."""
    return LOG_STRUCTURED_PRIOR if coupling > 0 else LOG_PRIOR


def log_wall_pass_prob(sampler: str | None = None) -> float:
    """The default ``wall_pass_prob`` of a log's map when it is mapped with ``sampler``: :data:`LOG_WALL_PASS_PROB`
    for the cellwise sampler (``None``: the default sampler of several scans, cellwise), 0 (opaque walls) for every
    other sampler, since only the cellwise sampler keeps the ray's second wall that a passing beam reaches."""
    return LOG_WALL_PASS_PROB if sampler in (None, "cellwise") else 0.0


# ---------------------------------------------------------------------------------------------------------------
# Scene constructors
# ---------------------------------------------------------------------------------------------------------------


def tutorial_problem(walls=None, pos=TUTORIAL_POS, seed: int = TUTORIAL_SEED, prior_wall_prob: float = TUTORIAL_PRIOR,
                     sensor_noise: float = TUTORIAL_SENSOR_NOISE, num_angles: int = TUTORIAL_NUM_ANGLES,
                     source: str = "tutorial map", beam_model: str = TUTORIAL_BEAM_MODEL,
                     sensor_params: dict | None = None, coupling: float = DEFAULT_COUPLING) -> Problem:
    """The tutorial's scene: a map (default the built-in 21 x 21), the sensor at ``pos`` (meters, default the
    center) with heading 0, ``num_angles`` equally spaced beams, readings simulated from the sensor model with
    ``jax.random.key(seed)`` (seed 0 gives the tutorial's readings). ``coupling``: the structured prior's ``J``
    (:mod:`bayesmap.model.prior`; 0, the tutorial's independent prior); the readings do not depend on it.

    Raises:
        BayesmapError: on bad parameters or a sensor position outside the grid.
    """
    walls = tutorial_map() if walls is None else (np.asarray(walls) > 0.5).astype(np.float32)
    grid = Grid(shape=walls.shape)
    params = make_params(prior_wall_prob, sensor_noise, num_angles, grid, beam_model=beam_model,
                         **(sensor_params or {}), coupling=coupling)
    grid.check_inside(pos)
    pos = np.asarray(pos, dtype=np.float64)
    beam_angles = np.asarray(angles(num_angles), dtype=np.float64)
    readings = simulate_readings(jax.random.key(seed), walls, pos, params)
    # the Normal sensor model can go below 0 next to a wall; a real sensor cannot: clip to 0
    readings = np.maximum(np.asarray(readings, dtype=np.float64), 0.0)
    return Problem.from_world_frame(params, pos, beam_angles, readings, truth=walls, source=source)


@dataclass(frozen=True)
class _LogScans:
    """Scans of a log as a scene sees them (:func:`_log_scans`)."""

    observations: Observations
    poses: np.ndarray  # (S, 3)
    world_angles: np.ndarray  # (S, K), as the log computed them
    grid: Grid
    endpoints: np.ndarray  # (N, 2) world endpoints of the returned beams, meters


def _log_scans(log, scans: np.ndarray, resolution: float, margin: float, grid: Grid | None) -> _LogScans:
    """The observations and poses of the scans ``scans`` of ``log`` and a grid covering them.

    Max-range handling: the sensor's max range is the log's (or, if the log has none, the longest selected reading
    plus :data:`MAX_RANGE_MARGIN`), and every max-range reading is set to exactly that value. The grid
    (``resolution`` meters per cell, unless ``grid`` is given) covers the sensor positions and the endpoints of all
    beams that returned (not max-range), plus ``margin`` meters.

    Raises:
        BayesmapError: on no scan or a scan index out of range.
    """
    if len(scans) == 0:
        raise BayesmapError("no scan selected")
    for index in (scans.min(), scans.max()):
        log.check_index(int(index))
    ranges = np.asarray(log.ranges[scans], dtype=np.float64)
    max_range = float(log.max_range) if math.isfinite(log.max_range) else float(ranges.max()) + MAX_RANGE_MARGIN
    is_max = ranges >= max_range
    poses = np.asarray(log.poses[scans], dtype=np.float64)
    world = np.asarray(log.angles[scans], dtype=np.float64)
    ends = (poses[:, None, :2] + ranges[..., None] * np.stack([np.cos(world), np.sin(world)], axis=-1))[~is_max]
    if grid is None:
        grid = Grid.covering(np.vstack([ends, poses[:, :2]]), resolution=resolution, margin=margin)
    observations = Observations(beam_angles=world - poses[:, 2:3], readings=np.where(is_max, max_range, ranges),
                                max_range_mask=is_max, max_range=max_range)
    return _LogScans(observations, poses, world, grid, ends)


def scan_problem(log, index: int, resolution: float = RESOLUTION, prior_wall_prob: float = TUTORIAL_PRIOR,
                 sensor_noise: float = TUTORIAL_SENSOR_NOISE, margin: float = MARGIN,
                 beam_model: str = TUTORIAL_BEAM_MODEL, sensor_params: dict | None = None,
                 coupling: float = DEFAULT_COUPLING) -> Problem:
    """The area around one real scan at its pose (a single-scan problem).

    ``sensor_noise`` should be a few centimeters for a laser: with the tutorial's 0.2 m on 0.1 m cells the
    evidence of one beam spreads over four cells (the CLI's default for one scan is :data:`SCAN_SENSOR_NOISE`).

    The grid (``resolution`` meters per cell) covers the sensor and the endpoints of all beams that returned
    (not max-range), plus ``margin`` meters. Max-range handling: the model's max distance is the log's max range
    and every max-range reading is set to exactly that value, so a beam with no return says "no wall within max
    range along this beam" (with no wall on the beam the model's expected reading is the max distance). Beams
    leave the grid as free space.

    Args:
        log: a :class:`bayesmap.io.carmen.CarmenLog`.
        index: the scan's index, ``0 <= index < len(log)``.

    Raises:
        BayesmapError: on an index out of range or bad parameters.
    """
    log.check_index(index)
    scans = _log_scans(log, np.array([index]), resolution, margin, None)
    obs = scans.observations
    params = make_params(prior_wall_prob, sensor_noise, obs.num_beams, scans.grid, max_distance=obs.max_range,
                         beam_model=beam_model, **(sensor_params or {}), coupling=coupling)
    return Problem(params=params, observations=obs, poses=scans.poses, world_angles=scans.world_angles,
                   multi_scan=False, source=f"{log.path} scan {index}",
                   extra={"pose": [float(v) for v in scans.poses[0]], "max_range": obs.max_range})


def log_problem(log, scans=None, resolution: float = RESOLUTION, prior_wall_prob: float | None = None,
                sensor_noise: float | None = None, beam_model: str = LOG_BEAM_MODEL, margin: float = MARGIN,
                grid: Grid | None = None, range_offset: float | None = None,
                sensor_params: dict | None = None, likelihood_power: float | None = None,
                geometry: str = LOG_GEOMETRY, coupling: float | None = None,
                wall_pass_prob: float | None = None, readings_per_cell: float | None = None,
                cut_past_reading: float = math.inf) -> Problem:
    """Many scans of a real log at their poses: one map from all of them.

    The grid (``resolution`` meters per cell) covers the sensor positions and the endpoints of all beams that
    returned, plus ``margin`` meters. The model's max distance is the log's max range and max-range readings are set
    to exactly that value: with the beam model they are scored by its point mass at the max range (a beam with no
    wall within range makes them likely), not dropped.

    Args:
        log: a :class:`bayesmap.io.carmen.CarmenLog`.
        scans: scan indices (``(S,)`` ints); default all.
        resolution: meters per cell.
        prior_wall_prob: prior probability of a wall (with the structured prior: given as many wall as free
            neighbours); default :func:`log_prior_wall_prob` of the coupling (0.1 with the structured prior and
            for independent cells).
        sensor_noise: the hit component's standard deviation, meters; default :data:`LOG_SENSOR_NOISE`.
        beam_model: ``"beam"`` (the robust mixture, default for real data) or ``"normal"``.
        margin: meters added around the data.
        grid: use this grid instead (e.g. one covering held-out scans too); its resolution wins.
        range_offset: meters the model subtracts from each returned reading (:attr:`Problem.range_offset`);
            default 0.
        sensor_params: the beam mixture's ``z_hit``, ``z_short``, ``z_max``, ``z_rand``, ``lambda_short`` (keywords of
            :func:`bayesmap.model.generative.make_params`); default :data:`bayesmap.model.sensor.BEAM_DEFAULTS`.
        likelihood_power: :attr:`Problem.likelihood_power`; default :func:`log_likelihood_power` of the chosen
            scans' :func:`endpoints_per_cell` on the grid and ``readings_per_cell``.
        geometry: the wall geometry, ``"chord"`` (default, :data:`LOG_GEOMETRY`) or ``"entry"`` (the tutorial's).
        coupling: the structured prior's ``J`` (nats per agreeing pair of 4-neighbours,
            :mod:`bayesmap.model.prior`); default :func:`log_coupling` at the grid's resolution (mean runs of
            :data:`LOG_RUN_LENGTH` meters); 0 is the independent prior.
        wall_pass_prob: the probability that a beam passes through a wall cell
            (:class:`bayesmap.model.generative.ModelParams`); default :data:`LOG_WALL_PASS_PROB`.
        readings_per_cell: what the default likelihood power makes a cell's endpoints worth; default
            :data:`LOG_READINGS_PER_CELL`; unused when ``likelihood_power`` is given.
        cut_past_reading: meters past its reading beyond which a beam does not look at the map
            (:class:`bayesmap.model.generative.ModelParams`); default ``inf``, the whole beam.

    Raises:
        BayesmapError: on bad parameters or scan indices, or a sensor position outside ``grid``.
    """
    scans = np.arange(len(log)) if scans is None else np.asarray(scans, dtype=np.int64).reshape(-1)
    chosen = _log_scans(log, scans, resolution, margin, grid)
    obs, grid = chosen.observations, chosen.grid
    resolution = grid.resolution
    noise = LOG_SENSOR_NOISE if sensor_noise is None else sensor_noise
    coupling = log_coupling(resolution) if coupling is None else coupling
    prior_wall_prob = log_prior_wall_prob(coupling) if prior_wall_prob is None else prior_wall_prob
    params = make_params(prior_wall_prob, noise, obs.num_beams, grid, max_distance=obs.max_range,
                         beam_model=beam_model, geometry=geometry, **(sensor_params or {}), coupling=coupling,
                         wall_pass_prob=LOG_WALL_PASS_PROB if wall_pass_prob is None else wall_pass_prob,
                         cut_past_reading=cut_past_reading)
    label = (f"{log.path} scans {scans[0]}..{scans[-1]} ({len(scans)})" if len(scans) > 1
             else f"{log.path} scan {scans[0]}")
    offset = 0.0 if range_offset is None else float(range_offset)
    if not (math.isfinite(offset) and 0 <= offset < obs.max_range):
        raise BayesmapError(f"range_offset must be between 0 and the max range {obs.max_range:g} m, "
                            f"got {range_offset!r}")
    if likelihood_power is None:
        per_cell = endpoints_per_cell(chosen.endpoints, grid)
        likelihood_power = log_likelihood_power(
            per_cell, LOG_READINGS_PER_CELL if readings_per_cell is None else readings_per_cell)
    eta = check_likelihood_power(likelihood_power)
    return Problem(params=params, observations=obs, poses=chosen.poses, world_angles=chosen.world_angles,
                   source=label, extra={"max_range": obs.max_range, "scans": len(scans), "range_offset": offset,
                                         "geometry": geometry, "coupling": float(coupling),
                                         "wall_pass_prob": params.wall_pass_prob,
                                         "cut_past_reading": params.cut_past_reading if params.cut else None},
                   range_offset=offset, likelihood_power=eta)
