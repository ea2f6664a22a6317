"""Scenes: what a sensor observed, where it was, and the model parameters; the tutorial's scene and real scans.

Layout of this module: first every default of a scene (one documented block; the CLI and
:mod:`bayesmap.evaluation.heldout` read them from here), then :class:`Observations` and :class:`Problem`, then the
scene constructors :func:`tutorial_problem`, :func:`scan_problem` and :func:`log_problem`.

Observed versus conditioned on
------------------------------
A :class:`Problem` keeps apart what the sensor observed and what the map samplers condition on:

* :class:`Observations` are fixed data: per scan the beam angles relative to the robot's heading (sensor frame,
  ``(S, K)`` radians), the range readings (``(S, K)`` meters), which readings were max-range and the max range
  (odometry joins them when poses become random).
* ``Problem.poses`` ``(S, 3)`` (x m, y m, theta rad) are the robot's poses the map is conditioned on: the log's
  corrected poses today, a latent variable tomorrow. Everything the samplers use is derived from them: the
  world-frame beam angles ``theta + relative angle`` (:attr:`Problem.ray_angles`), the ray origins and the ray-cell
  table (:attr:`Problem.table`, built lazily).

:meth:`Problem.with_poses` returns the same scene at other poses (same observations, parameters and truth); its
table is built again on first use. A pose kernel (the next step, poses as random variables) composes with the map
kernels of :mod:`bayesmap.inference` as a Gibbs sweep over two blocks: (1) propose or draw new poses given the
current map, targeting ``p(poses | walls, readings, odometry)``, proportional to ``p(readings | walls, poses)`` (only
the moved scans' beams change it) times the odometry's motion model; (2) find the scans whose pose changed
(:meth:`Problem.moved_scans`); (3) rebuild only those scans' rows of the ray-cell table (:meth:`Problem.rays_of_scans`
gives their ray indices, ``RayTable`` rebuilds rows for chosen scans) and recompute the map sampler's per-ray state
(first walls) on those rays; (4) run map sweeps on the updated table. Map samplers never read the sensor-frame
angles, only the table and the readings, so they need no change when poses move.

The world-frame angles of a log are kept exactly as :mod:`bayesmap.io.carmen` computed them
(``Problem.world_angles``, dropped by :meth:`Problem.with_poses`): ``theta + (angle - theta)`` can differ from
``angle`` in the last bit, and the ray table and every number downstream must stay the same.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles
from bayesmap.geometry.raytable import RayTable, build_ray_table, visible_cells
from bayesmap.io.ascii import tutorial_map
from bayesmap.model.generative import (
    ModelParams,
    check_likelihood_power,
    log_joint,
    log_joint_scans,
    make_params,
    simulate_readings,
    walls_log_likelihood,
)
from bayesmap.model.prior import DEFAULT_COUPLING, coupling_for_run_length, disagreeing_pairs
from bayesmap.model.sensor import PASS_WALLS

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
"""Default prior wall probability for maps from many scans (logs, floor plans): indoor floor plans have about a tenth
of their cells occupied, and with 0.5 the robust beam model explains a long beam's reading as a sensor failure rather
than as free space (the prior odds of "no wall in 100 cells" are 2^-100 against a likelihood ratio of at most 9)."""

# The map defaults of a log (issue 16): every one a property of the sensor or the world, none a count of cells,
# chosen by leave-one-log-out cross-validation over Intel, ACES and CSAIL at 0.1 and 0.2 m (benchmarks/map_cv.py;
# the protocol and the table are in the README, "Map defaults of logs, by cross-validation").

LOG_GEOMETRY = "chord"
"""Wall geometry of real scans of a log (``ModelParams.geometry``): ``"chord"``, the surface anywhere on the beam's
chord through the first wall cell, the sensor's hit averaged over it (:mod:`bayesmap.model.sensor`). It needs no
range offset at any resolution: a log's default offset is 0. The tutorial's ``"entry"`` geometry (the reading
expected where the beam enters the cell) ranks cells worse without an offset (README, geometry table) and stays the
tutorial's. ``bayesmap slam --log`` uses the chord geometry too (:data:`SLAM_GEOMETRY`).

The cross-validation (``benchmarks/map_cv.py``): every other scan of each log, every 10th of those held out, maps at
0.1 and 0.2 m; for each log held out, the setting with the largest mean held-out AUC margin over log-odds mapping on
the other two logs, among those whose predictive NLL is below log-odds' on both logs at both resolutions.
Searched: power 0.01-0.3, run length 0-4 m, noise 0.05 and 0.1 m, ``z_rand`` 0.1 and 0.3 (2026-11-22), then the
probability that a beam passes a wall cell, 0.1, 0.3 and 0.5, with run lengths 0, 1 and 2 m at power 0.1 and noise
0.1 m (2026-11-23), then the prior wall probability of the structured prior, 0.3 and 0.5 (2026-11-24), then a power
that follows the data's density, 0.5, 0.7, 1, 1.4 and 2 readings per cell (:data:`LOG_READINGS_PER_CELL`), with runs
of 1 and 2 m (2026-11-24), then noise 0.05 and 0.1 m, pass probability 0.3 and 0.5 and prior wall probability 0.1
and 0.3 at 0.7 readings per cell (2026-11-24). Chosen on all three logs and in every fold, by both of
``map_cv.py``'s rules: 0.7 readings per cell, run length 1 m, noise 0.05 m, ``z_rand`` 0.1, pass probability 0.5,
prior wall probability 0.1 (:data:`LOG_STRUCTURED_PRIOR`; mean AUC margin +0.0347, at least +0.023 and an NLL below
log-odds' on every log and resolution; README, "A check of the other settings at c 0.7"; with noise 0.1 m and prior
0.3, the defaults until 2026-11-25: +0.0337; with the fixed power 0.1 before that: mean +0.030, at least +0.016;
before passable walls: power 0.1, 2 m, mean margin +0.020, 0.003 below log-odds on CSAIL at 0.2 m). With walls that
stop every beam (pass probability 0) and the other defaults, the margin at 0.2 m falls to +0.006 (Intel), +0.010
(ACES) and -0.003 (CSAIL)."""

LOG_SENSOR_NOISE = 0.05
"""Default ``sensor_noise`` of a log's map, meters: the hit component's standard deviation (a property of the laser
and of the poses' residual error, not of the cells). Cross-validated (:data:`LOG_GEOMETRY`'s note) over 0.05 and
0.1 m; 0.1 m until 2026-11-25."""

SCAN_SENSOR_NOISE = 0.05
"""Default ``sensor_noise`` of the map of one real scan (``infer --log FILE --scan N``, the tutorial's single-scan
model), meters: what half a cell gave at the default 0.1 m before every default became a length in meters. One scan
has no held-out beams to cross-validate it on."""

LOG_READINGS_PER_CELL = 0.7
"""How many independent readings the returned beams that end in one cell are worth together, on average: the default
likelihood power ``eta`` of a log's map (:attr:`Problem.likelihood_power`) is this over the mean number of returned
readings per cell that holds an endpoint (:func:`log_likelihood_power`). The model treats every beam as independent
evidence given the map; the beams of a log are not (a scan's beams share its pose error, neighbouring beams and
consecutive scans see the same surface through the same errors), so the plain posterior is overconfident about which
cell of a surface is the wall. Raising the likelihood to ``eta < 1`` counts each beam as a fraction of one (a power
posterior; :func:`bayesmap.model.generative.check_likelihood_power`). A scan taken a few centimeters from the last one
sees the same surface through the same errors, so a cell's evidence does not grow with the number of scans; a power that
does not follow the density over-counts a log with twice the scans, or cells of twice the size (README, "The likelihood
power follows the data"). Cross-validated (:data:`LOG_GEOMETRY`'s note)."""


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


LOG_RUN_LENGTH = 1.0
"""Default mean run length of the structured prior of a log's map, meters (:func:`log_coupling`;
:func:`bayesmap.model.prior.coupling_for_run_length`): the coupling whose runs of equal cells along a row are this
long on average, at any resolution; 0 would be the independent prior. Cross-validated (:data:`LOG_GEOMETRY`'s
note)."""

LOG_WALL_PASS_PROB = 0.5
"""Default probability that a beam passes through a wall cell of a log's map (``ModelParams.wall_pass_prob``; a
probability of the world, the same at every resolution). Cross-validated (:data:`LOG_GEOMETRY`'s note) over 0.1,
0.3 and 0.5; 0.5 is the largest value the model is meant for: a reading comes from the ray's first two wall cells
or from no wall, and at 0.5 the no-wall reading already carries a quarter of the mass (``pi^2``), a third wall's
share that the two-wall model cannot place (docs/sensor.md)."""


LOG_STRUCTURED_PRIOR = 0.1
"""Default ``prior_wall_prob`` of a log's map with the structured prior (coupling ``J > 0``, the default): the
probability that a cell is a wall *given as many wall as free 4-neighbours* (:mod:`bayesmap.model.prior`), not the
fraction of wall cells. Cross-validated (:data:`LOG_GEOMETRY`'s note) over 0.1, 0.3 and 0.5. With the fixed power
0.1 and noise 0.1 m (the third stage, 2026-11-24) 0.3 tied with 0.1 on the AUC and lowered the NLL, and was the
default until 2026-11-25; with the power that follows the data and noise 0.05 m, 0.1 has the larger mean AUC margin
(+0.0347 against +0.0340 at 0.3) and the NLL is higher by 0.28-0.39 nats per beam, still below log-odds' on every log
and resolution (README, "A check of the other settings at c 0.7"). Equal to :data:`LOG_PRIOR`, the independent
prior's (:func:`log_prior_wall_prob`), by the cross-validation, not by construction: the two mean different things."""


def log_prior_wall_prob(coupling: float) -> float:
    """The default ``prior_wall_prob`` of a log's map with the structured prior's coupling ``coupling`` (nats):
    :data:`LOG_STRUCTURED_PRIOR` when ``coupling > 0``, :data:`LOG_PRIOR` for independent cells."""
    return LOG_STRUCTURED_PRIOR if coupling > 0 else LOG_PRIOR


def log_wall_pass_prob(sampler: str | None = None) -> float:
    """The default ``wall_pass_prob`` of a log's map when it is mapped with ``sampler``: :data:`LOG_WALL_PASS_PROB`
    for the cellwise sampler (``None``: the default sampler of several scans, cellwise), 0 (opaque walls) for every
    other sampler, since only the cellwise sampler keeps the ray's second wall that a passing beam reaches."""
    return LOG_WALL_PASS_PROB if sampler in (None, "cellwise") else 0.0

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


# ---------------------------------------------------------------------------------------------------------------
# What was observed, and the scene
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Observations:
    """What the sensor observed in ``S`` scans of ``K`` beams each: fixed data, whatever the poses.

    Attributes:
        beam_angles: ``(S, K)`` float64 beam angles relative to the robot's heading (sensor frame), radians.
        readings: ``(S, K)`` float64 range readings, meters (max-range readings set to the max range).
        max_range_mask: ``(S, K)`` bool, True for readings that were max-range (no return); or None (none were).
        max_range: the sensor's max range, meters; ``math.inf`` when the data has no max-range readings.

    Raises:
        BayesmapError: when the arrays are not ``(S, K)`` of one shape.
    """

    beam_angles: np.ndarray
    readings: np.ndarray
    max_range_mask: np.ndarray | None = None
    max_range: float = math.inf

    def __post_init__(self) -> None:
        angles = np.asarray(self.beam_angles, dtype=np.float64)
        readings = np.asarray(self.readings, dtype=np.float64)
        if angles.ndim != 2 or readings.shape != angles.shape:
            raise BayesmapError(f"observations need beam angles and readings of one shape (S, K), got "
                                f"{angles.shape} and {readings.shape}")
        mask = self.max_range_mask
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != readings.shape:
                raise BayesmapError(f"max_range_mask has shape {mask.shape}, the readings {readings.shape}")
        object.__setattr__(self, "beam_angles", angles)
        object.__setattr__(self, "readings", readings)
        object.__setattr__(self, "max_range_mask", mask)
        object.__setattr__(self, "max_range", float(self.max_range))

    @property
    def num_scans(self) -> int:
        """``S``."""
        return self.readings.shape[0]

    @property
    def num_beams(self) -> int:
        """``K``, beams per scan."""
        return self.readings.shape[1]


@dataclass(frozen=True, eq=False)
class Problem:
    """A mapping problem: :class:`Observations` of ``S`` scans, the poses they were taken at, model parameters.

    One scan (the tutorial's case, ``multi_scan=False``) or ``S`` scans; the views :attr:`pos`, :attr:`beam_angles`,
    :attr:`readings` and :attr:`max_range_mask` drop the scan axis of a single-scan problem. Build one from
    world-frame arrays with :meth:`from_world_frame`.

    Attributes:
        params: model parameters; ``params.grid`` is the grid, ``params.max_range`` the max distance (meters) and
            ``params.beam_model`` the sensor model.
        observations: what was observed (sensor-frame beam angles, readings, max-range flags).
        poses: ``(S, 3)`` float64 robot poses ``(x m, y m, theta rad)``, world frame: what the map is conditioned on.
        truth: ``(nx, ny)`` float32 true map, or None for real data.
        source: a description for summaries.
        extra: more JSON-serializable facts for the summary.
        range_offset: meters subtracted from every returned (not max-range) reading before the model sees it
            (:attr:`model_readings`); 0 by default. The tutorial's entry geometry expects a reading at the face where
            the beam enters the wall cell, while a real surface lies inside the cell; no default uses one (the
            chord geometry of logs needs none).
        likelihood_power: ``eta`` in (0, 1]: the samplers target ``p(walls) p(readings | walls) ** eta``
            (:func:`bayesmap.model.generative.check_likelihood_power`); 1 (the posterior) except for logs
            (:func:`log_likelihood_power`). The reference samplers support only 1.
        multi_scan: False for a single-scan problem (the reference samplers apply; the views drop the scan axis).
        world_angles: ``(S, K)`` float64 world-frame beam angles, radians, exactly as the data source computed them
            (see the module docstring); None: ``theta + observations.beam_angles``.
        ray_table: the ray-cell table of these beams when it was already built (e.g. to simulate the readings); None:
            :attr:`table` builds it on first use.

    Raises:
        BayesmapError: when ``poses`` is not ``(S, 3)`` for the observations' ``S``, a single-scan problem has
            several scans, ``world_angles`` disagree with the poses and the sensor-frame angles, or ``ray_table`` has
            another number of rays.
    """

    params: ModelParams
    observations: Observations
    poses: np.ndarray
    truth: np.ndarray | None = None
    source: str = ""
    extra: dict = field(default_factory=dict)
    range_offset: float = 0.0
    likelihood_power: float = 1.0
    multi_scan: bool = True
    world_angles: np.ndarray | None = field(default=None, repr=False)
    ray_table: RayTable | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        poses = np.asarray(self.poses, dtype=np.float64)
        s = self.observations.num_scans
        if poses.shape != (s, 3):
            raise BayesmapError(f"poses must have shape ({s}, 3) (x, y, theta per scan), got {poses.shape}")
        if not self.multi_scan and s != 1:
            raise BayesmapError(f"a single-scan problem has one scan, got {s}")
        object.__setattr__(self, "poses", poses)
        if self.world_angles is not None:
            world = np.asarray(self.world_angles, dtype=np.float64)
            if world.shape != self.observations.beam_angles.shape or not np.allclose(
                    world, poses[:, 2:3] + self.observations.beam_angles, rtol=0.0, atol=1e-9):
                raise BayesmapError("world_angles must equal each pose's theta plus the sensor-frame beam angles")
            object.__setattr__(self, "world_angles", world)
        rays = s * self.observations.num_beams
        if self.ray_table is not None and self.ray_table.num_rays != rays:
            raise BayesmapError(f"ray_table has {self.ray_table.num_rays} rays, the scans {rays}")

    @classmethod
    def from_world_frame(cls, params, pos, beam_angles, readings, max_range_mask=None, **fields) -> Problem:
        """A problem from world-frame arrays: ``pos`` ``(2,)`` with ``beam_angles``, ``readings`` (and
        ``max_range_mask``) ``(K,)`` for one scan, or ``(S, 2)`` with ``(S, K)`` for ``S`` scans. The poses' heading is
        0, so the sensor-frame angles are the world-frame ones. ``fields``: the other attributes (``truth``,
        ``source``, ...).

        Raises:
            BayesmapError: on shapes that do not match.
        """
        pos = np.asarray(pos, dtype=np.float64)
        if pos.ndim not in (1, 2) or pos.shape[-1] != 2:
            raise BayesmapError(f"sensor positions must have shape (2,) or (S, 2), got {pos.shape}")
        scans = pos.reshape(-1, 2)
        k = np.shape(beam_angles)[-1]
        observations = Observations(
            beam_angles=np.reshape(beam_angles, (len(scans), k)), readings=np.reshape(readings, (len(scans), -1)),
            max_range_mask=None if max_range_mask is None else np.reshape(max_range_mask, (len(scans), -1)))
        poses = np.column_stack([scans, np.zeros(len(scans))])
        # the given angles are kept as the world-frame ones (0.0 + -0.0 would be 0.0)
        return cls(params=params, observations=observations, poses=poses, multi_scan=pos.ndim == 2,
                   world_angles=observations.beam_angles, **fields)

    def _view(self, a):
        """``a`` ``(S, ...)`` as the problem's arrays are seen: without the scan axis for a single scan."""
        return a if a is None or self.multi_scan else a[0]

    @property
    def grid(self) -> Grid:
        """The grid of the map (``params.grid``)."""
        return self.params.grid

    @property
    def num_scans(self) -> int:
        """``S``: 1 for a single-scan problem."""
        return self.observations.num_scans

    @property
    def pos(self) -> np.ndarray:
        """Sensor position(s), world meters: ``(2,)`` float64 for one scan, ``(S, 2)`` for ``S`` scans."""
        return self._view(self.poses[:, :2])

    @cached_property
    def scan_world_angles(self) -> np.ndarray:
        """``(S, K)`` float64 world-frame beam angles, radians: ``theta`` plus the sensor-frame angle (or
        ``world_angles`` as given)."""
        if self.world_angles is not None:
            return self.world_angles
        return self.poses[:, 2:3] + self.observations.beam_angles

    @property
    def beam_angles(self) -> np.ndarray:
        """World-frame beam angles, radians: ``(K,)`` for one scan, ``(S, K)`` for ``S`` scans."""
        return self._view(self.scan_world_angles)

    @property
    def readings(self) -> np.ndarray:
        """Range readings, meters, the shape of :attr:`beam_angles` (max-range readings set to the max range)."""
        return self._view(self.observations.readings)

    @property
    def max_range_mask(self) -> np.ndarray | None:
        """bool, the shape of :attr:`readings`: readings that were max-range (no return); or None."""
        return self._view(self.observations.max_range_mask)

    @cached_property
    def ray_origins(self) -> np.ndarray:
        """``(R, 2)`` float64 sensor position of every beam (scan-major), meters."""
        return np.repeat(self.poses[:, :2], self.observations.num_beams, axis=0)

    @property
    def ray_angles(self) -> np.ndarray:
        """``(R,)`` world-frame angle of every beam, radians."""
        return self.scan_world_angles.reshape(-1)

    @property
    def ray_readings(self) -> np.ndarray:
        """``(R,)`` reading of every beam, meters."""
        return self.observations.readings.reshape(-1)

    @cached_property
    def model_readings(self) -> np.ndarray:
        """The readings the model scores (shape of ``readings``, meters): ``readings`` minus ``range_offset`` (at
        least 0), max-range readings unchanged."""
        readings = self.readings
        if not self.range_offset:
            return readings
        shifted = np.maximum(readings - float(self.range_offset), 0.0)
        return shifted if self.max_range_mask is None else np.where(self.max_range_mask, readings, shifted)

    @property
    def model_ray_readings(self) -> np.ndarray:
        """``(R,)`` :attr:`model_readings` of every beam."""
        return self.model_readings.reshape(-1)

    @property
    def ray_max_range(self) -> np.ndarray | None:
        """``(R,)`` bool, max-range readings (or None)."""
        mask = self.observations.max_range_mask
        return None if mask is None else mask.reshape(-1)

    @property
    def scan_of_ray(self) -> np.ndarray:
        """``(R,)`` int64 index of the scan of every beam."""
        return np.repeat(np.arange(self.num_scans), self.observations.num_beams)

    def rays_of_scans(self, scans) -> np.ndarray:
        """``(len(scans) * K,)`` int64 indices of the rays (rows of :attr:`table`) of the scans ``scans``, in order.

        Raises:
            BayesmapError: on a scan index outside ``0..S-1``.
        """
        scans = np.asarray(scans, dtype=np.int64).reshape(-1)
        if scans.size and (scans.min() < 0 or scans.max() >= self.num_scans):
            raise BayesmapError(f"scan indices must lie in 0..{self.num_scans - 1}, got {scans.min()}..{scans.max()}")
        k = self.observations.num_beams
        return (scans[:, None] * k + np.arange(k)[None, :]).reshape(-1)

    def moved_scans(self, poses) -> np.ndarray:
        """``(M,)`` int64 indices of the scans whose pose in ``poses`` ``(S, 3)`` differs from :attr:`poses`: the
        scans whose table rows a pose move makes stale.

        Raises:
            BayesmapError: when ``poses`` is not ``(S, 3)``.
        """
        poses = self._check_poses(poses)
        return np.flatnonzero(np.any(poses != self.poses, axis=1))

    def _check_poses(self, poses) -> np.ndarray:
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != self.poses.shape or not np.all(np.isfinite(poses)):
            raise BayesmapError(f"poses must be finite numbers of shape {self.poses.shape}, got {poses.shape}")
        return poses

    def with_poses(self, poses) -> Problem:
        """The same scene (observations, parameters, truth) at the poses ``poses`` ``(S, 3)`` (x m, y m, theta rad).
        World-frame angles become ``theta`` plus the sensor-frame angles; the ray table is built again on first use.

        Raises:
            BayesmapError: when ``poses`` is not ``(S, 3)`` finite numbers, or a sensor position is outside the grid.
        """
        poses = self._check_poses(poses)
        for xy in poses[:, :2]:
            self.grid.check_inside(xy)
        return dataclasses.replace(self, poses=poses, world_angles=None, ray_table=None)

    @cached_property
    def table(self) -> RayTable:
        """The ray-cell table of all beams (``ray_table``, or built on first use)."""
        if self.ray_table is not None:
            return self.ray_table

        return build_ray_table(self.grid, self.ray_origins, self.ray_angles, self.params.max_range)

    def single_scan(self) -> tuple:
        """``(readings (K,), pos (2,), params, beam_angles (K,))`` for the single-scan (reference) samplers.

        Raises:
            BayesmapError: for a problem of several scans.
        """
        if self.num_scans != 1:
            raise BayesmapError(f"the reference samplers take one scan; this problem has {self.num_scans} "
                                "(use a fast sampler)")
        return (self.model_ray_readings, self.poses[0, :2], self.params, self.ray_angles)

    def log_joint(self, walls) -> float:
        """``log p(walls, readings)``: the GenJAX model's ``assess`` (:func:`~bayesmap.model.generative.log_joint`, or
        :func:`~bayesmap.model.generative.log_joint_scans` for several scans) when the problem is small enough for the
        dense geometry (beams x cells <= 2e7), else :meth:`table_log_joint` (equal to it, tested)."""
        if not self.multi_scan:
            return float(log_joint(walls, self.model_readings, self.pos, self.params, self.beam_angles))
        if self.table.num_rays * self.grid.num_cells <= 2e7:
            return float(log_joint_scans(walls, self.model_readings, self.pos, self.params, self.beam_angles))
        return self.table_log_joint(walls)

    def table_log_joint(self, walls) -> float:
        """``log p(walls, readings)`` from the ray-cell table: the prior's log-probability plus, per beam,
        the sensor model's log-density of its reading given its first wall (the max distance if none; its first two
        walls when a beam can pass a wall cell, :func:`bayesmap.model.generative.walls_log_likelihood`).
        With a structured prior, the prior's part is :func:`bayesmap.model.prior.log_prior` (``-J`` per differing
        pair of neighbours, as the model's observed connections score). Memory and time grow with the table's pairs,
        not beams x cells."""
        walls = np.asarray(walls) > 0.5
        p = float(self.params.prior_wall_prob)
        prior = walls.sum() * math.log(p) + (walls.size - walls.sum()) * math.log1p(-p)
        if self.params.structured:
            prior -= float(self.params.coupling) * int(disagreeing_pairs(walls))
        dtype = jnp.result_type(float)
        chords = jnp.asarray(self.table.wall_chords(walls, PASS_WALLS if self.params.penetrable else 1), dtype=dtype)
        ll = walls_log_likelihood(jnp.asarray(self.model_ray_readings), chords, self.params)
        return float(prior + float(jnp.sum(ll)))

    @cached_property
    def visible(self) -> np.ndarray | None:
        """``(nx, ny)`` bool cells seen by a ray given the true map (None without a truth); computed once."""
        return None if self.truth is None else visible_cells(self.table, self.truth)

    def wrong_visible_cells(self, posterior) -> int | None:
        """Number of visible cells where the rounded posterior disagrees with the truth (None without a truth)."""
        if self.truth is None:
            return None
        wrong = (np.round(np.asarray(posterior)) != (self.truth > 0.5)) & self.visible
        return int(wrong.sum())


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
                wall_pass_prob: float | None = None, readings_per_cell: float | None = None) -> Problem:
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
                         wall_pass_prob=LOG_WALL_PASS_PROB if wall_pass_prob is None else wall_pass_prob)
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
                                         "wall_pass_prob": params.wall_pass_prob},
                   range_offset=offset, likelihood_power=eta)
