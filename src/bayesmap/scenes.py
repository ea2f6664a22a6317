"""One description of a mapping problem (grid, sensor, beams, readings, model parameters) and running inference on it.

The CLI, the benchmarks and the app all build a :class:`Problem` and call :func:`run_inference`; nothing downstream
re-derives geometry on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.ascii import tutorial_map
from bayesmap.model.generative import (
    ModelParams,
    check_likelihood_power,
    log_joint,
    log_joint_scans,
    make_params,
    reading_log_likelihood,
    simulate_readings,
)
from bayesmap.geometry.raytable import RayTable, build_ray_table, visible_cells
from bayesmap.geometry.raycast import angles

TUTORIAL_POS = (10.0, 10.0)

LOG_PRIOR = 0.1
"""Default prior wall probability for maps from many scans (logs, floor plans): indoor floor plans have about a tenth
of their cells occupied, and with 0.5 the robust beam model explains a long beam's reading as a sensor failure rather
than as free space (the prior odds of "no wall in 100 cells" are 2^-100 against a likelihood ratio of at most 9)."""

@dataclass(frozen=True, eq=False)
class Problem:
    """A mapping problem: one scan (the tutorial's case) or ``S`` scans, each from its own position.

    Attributes:
        params: model parameters; ``params.grid`` is the grid, ``params.cap`` the max distance (meters) and
            ``params.beam_model`` the sensor model.
        pos: sensor position(s), world meters: ``(2,)`` float64 for one scan, ``(S, 2)`` for ``S`` scans.
        beam_angles: world-frame beam angles, radians: ``(K,)`` for one scan, ``(S, K)`` for ``S`` scans (the pose's
            heading is folded in).
        readings: range readings, meters, the shape of ``beam_angles`` (max-range readings set to the max range).
        truth: ``(nx, ny)`` float32 true map, or None for real data.
        max_range_mask: bool, the shape of ``readings``: readings that were max-range (no return); or None.
        range_offset: meters subtracted from every returned (not max-range) reading before the model sees it
            (:attr:`model_readings`); 0 for simulated data. For real data the tutorial's geometry expects a reading at
            the face where the beam enters the wall cell, while a real surface lies inside the cell (default for logs:
            :data:`RANGE_OFFSET_CELLS` cells).
        likelihood_power: ``eta`` in (0, 1]: the samplers target ``p(walls) p(readings | walls) ** eta``
            (:func:`bayesmap.model.generative.check_likelihood_power`); 1 (the posterior) except for logs
            (:data:`LOG_LIKELIHOOD_POWER`). The reference samplers support only 1.
        source: a description for summaries.
        extra: more JSON-serializable facts for the summary.
    """

    params: ModelParams
    pos: np.ndarray
    beam_angles: np.ndarray
    readings: np.ndarray
    truth: np.ndarray | None = None
    max_range_mask: np.ndarray | None = None
    source: str = ""
    extra: dict = field(default_factory=dict)
    range_offset: float = 0.0
    likelihood_power: float = 1.0

    @property
    def grid(self) -> Grid:
        return self.params.grid

    @property
    def num_scans(self) -> int:
        """``S``: 1 for a single-scan problem."""
        return 1 if np.ndim(self.pos) == 1 else int(np.shape(self.pos)[0])

    @property
    def multi_scan(self) -> bool:
        """True when ``pos`` is ``(S, 2)`` (even with ``S = 1``)."""
        return np.ndim(self.pos) == 2

    @cached_property
    def ray_origins(self) -> np.ndarray:
        """``(R, 2)`` float64 sensor position of every beam (scan-major), meters."""
        k = np.shape(self.beam_angles)[-1]
        return np.repeat(np.asarray(self.pos, dtype=np.float64).reshape(-1, 2), k, axis=0)

    @property
    def ray_angles(self) -> np.ndarray:
        """``(R,)`` world-frame angle of every beam, radians."""
        return np.asarray(self.beam_angles, dtype=np.float64).reshape(-1)

    @property
    def ray_readings(self) -> np.ndarray:
        """``(R,)`` reading of every beam, meters."""
        return np.asarray(self.readings, dtype=np.float64).reshape(-1)

    @cached_property
    def model_readings(self) -> np.ndarray:
        """The readings the model scores (shape of ``readings``, meters): ``readings`` minus ``range_offset`` (at
        least 0), max-range readings unchanged."""
        readings = np.asarray(self.readings, dtype=np.float64)
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
        return None if self.max_range_mask is None else np.asarray(self.max_range_mask, bool).reshape(-1)

    @property
    def scan_of_ray(self) -> np.ndarray:
        """``(R,)`` int64 index of the scan of every beam."""
        return np.repeat(np.arange(self.num_scans), np.shape(self.beam_angles)[-1])

    @cached_property
    def table(self) -> RayTable:
        """The ray-cell table of all beams (built on first use)."""
        return build_ray_table(self.grid, self.ray_origins, self.ray_angles, self.params.cap)

    def single_scan(self) -> tuple:
        """``(readings (K,), pos (2,), params, beam_angles (K,))`` for the single-scan (reference) samplers.

        Raises:
            BayesmapError: for a problem of several scans.
        """
        if self.num_scans != 1:
            raise BayesmapError(f"the reference samplers take one scan; this problem has {self.num_scans} "
                                "(use a fast sampler)")
        return (self.model_ray_readings, np.asarray(self.pos, np.float64).reshape(2), self.params, self.ray_angles)

    def log_joint(self, walls) -> float:
        """``log p(walls, readings)``: the GenJAX model's ``assess`` (:func:`~bayesmap.model.generative.log_joint`, or
        :func:`~bayesmap.model.generative.log_joint_scans` for several scans) when the problem is small enough for the dense
        geometry (beams x cells <= 2e7), else :meth:`table_log_joint` (equal to it, tested)."""
        if not self.multi_scan:
            return float(log_joint(walls, self.model_readings, self.pos, self.params, self.beam_angles))
        if self.table.num_rays * self.grid.num_cells <= 2e7:
            return float(log_joint_scans(walls, self.model_readings, self.pos, self.params, self.beam_angles))
        return self.table_log_joint(walls)

    def table_log_joint(self, walls) -> float:
        """``log p(walls, readings)`` from the ray-cell table: the prior's log-probability plus, per beam,
        the sensor model's log-density of its reading at the distance of its first wall (the max distance if none).
        Memory and time grow with the table's pairs, not beams x cells."""
        walls = np.asarray(walls) > 0.5
        p = float(self.params.prior_wall_prob)
        prior = walls.sum() * math.log(p) + (walls.size - walls.sum()) * math.log1p(-p)
        d = self.table.first_wall_distances(walls)
        ll = reading_log_likelihood(jnp.asarray(self.model_ray_readings), jnp.asarray(d, dtype=jnp.result_type(float)),
                                    self.params)
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


def tutorial_problem(walls=None, pos=TUTORIAL_POS, seed: int = 0, prior_wall_prob: float = 0.5,
                     sensor_noise: float = 0.2, num_angles: int = 100, source: str = "tutorial map",
                     beam_model: str = "normal", sensor_params: dict | None = None) -> Problem:
    """The tutorial's scene: a map (default the built-in 21 x 21), the sensor at ``pos`` (default the center),
    ``num_angles`` equally spaced beams, readings simulated from the sensor model with ``jax.random.key(seed)``
    (seed 0 gives the tutorial's readings).

    Raises:
        BayesmapError: on bad parameters or a sensor position outside the grid.
    """
    walls = tutorial_map() if walls is None else (np.asarray(walls) > 0.5).astype(np.float32)
    grid = Grid(shape=walls.shape)
    params = make_params(prior_wall_prob, sensor_noise, num_angles, grid, beam_model=beam_model, **(sensor_params or {}))
    grid.check_inside(pos)
    pos = np.asarray(pos, dtype=np.float64)
    beam_angles = np.asarray(angles(num_angles), dtype=np.float64)
    readings = simulate_readings(jax.random.key(seed), walls, pos, params)
    # the Normal sensor model can go below 0 next to a wall; a real sensor cannot: clip to 0
    readings = np.maximum(np.asarray(readings, dtype=np.float64), 0.0)
    return Problem(params=params, pos=pos, beam_angles=beam_angles, readings=readings, truth=walls, source=source)


def scan_problem(log, index: int, resolution: float = 0.1, prior_wall_prob: float = 0.5, sensor_noise: float = 0.2,
                 margin: float = 1.0, beam_model: str = "normal", sensor_params: dict | None = None) -> Problem:
    """The area around one real scan at its pose.

    ``sensor_noise`` should be about half a cell for real data: with the tutorial's 0.2 m on 0.1 m cells the
    evidence of one beam spreads over four cells (the CLI's default for logs is ``resolution / 2``).

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
    scan = log.scan(index)
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    max_range = float(log.max_range) if math.isfinite(log.max_range) else float(ranges.max()) + 1.0
    is_max = ranges >= max_range
    pos = np.asarray(scan.pose[:2], dtype=np.float64)
    ends = pos + ranges[:, None] * np.stack([np.cos(scan.angles), np.sin(scan.angles)], axis=-1)
    grid = Grid.covering(np.vstack([ends[~is_max], pos[None]]), resolution=resolution, margin=margin)
    params = make_params(prior_wall_prob, sensor_noise, len(ranges), grid, max_distance=max_range, beam_model=beam_model,
                         **(sensor_params or {}))
    readings = np.where(is_max, max_range, ranges)
    return Problem(params=params, pos=pos, beam_angles=np.asarray(scan.angles, dtype=np.float64), readings=readings,
                   max_range_mask=is_max, source=f"{log.path} scan {index}",
                   extra={"pose": [float(v) for v in scan.pose], "max_range": max_range})


LOG_LIKELIHOOD_POWER = 0.1
"""Default likelihood power ``eta`` of a log (:attr:`Problem.likelihood_power`). The model treats every beam as
independent evidence given the map; the beams of a log are not (a scan's beams share its pose error, neighbouring
beams and consecutive scans see the same surface through the same errors), so the plain posterior is overconfident
about which cell of a surface is the wall. Raising the likelihood to ``eta < 1`` counts each beam as a fraction of
one (a power posterior; :func:`bayesmap.model.generative.check_likelihood_power`). Chosen on the validation scans of
:data:`RANGE_OFFSET_CELLS` (one-cell offset): held-out occupancy AUC 0.952 / 0.965 / 0.967 and predictive NLL
-0.263 / -0.307 nats at ``eta`` = 1 / 0.3 / 0.1 (log-odds mapping: 0.947 and 2.79)."""

RANGE_OFFSET_CELLS = 1.0
"""Default range offset of a log, in cells (:attr:`Problem.range_offset`). The tutorial's geometry puts a wall
cell's expected reading where the beam enters the cell; a real surface is read somewhere inside it, and beams from
other poses cross the cells along it. Chosen on validation scans that are never test scans (Intel, every other scan;
within the scans ``bayesmap evaluate`` maps with, those with index 4 mod 10 held out, mapped from the rest; cellwise,
60 sweeps): held-out occupancy AUC 0.929 with half a cell, 0.952 with one cell (log-odds mapping: 0.947)."""


def log_problem(log, scans=None, resolution: float = 0.1, prior_wall_prob: float = LOG_PRIOR,
                sensor_noise: float | None = None, beam_model: str = "beam", margin: float = 1.0,
                grid: Grid | None = None, range_offset: float | None = None,
                sensor_params: dict | None = None, likelihood_power: float | None = None) -> Problem:
    """Many scans of a real log at their poses: one map from all of them.

    The grid (``resolution`` meters per cell) covers the sensor positions and the endpoints of all beams that
    returned, plus ``margin`` meters. The model's max distance is the log's max range and max-range readings are set
    to exactly that value: with the beam model they are scored by its point mass at the max range (a beam with no
    wall within range makes them likely), not dropped.

    Args:
        log: a :class:`bayesmap.io.carmen.CarmenLog`.
        scans: scan indices (``(S,)`` ints); default all.
        resolution: meters per cell.
        prior_wall_prob: prior probability of a wall.
        sensor_noise: the hit component's standard deviation, meters; default half a cell.
        beam_model: ``"beam"`` (the robust mixture, default for real data) or ``"normal"``.
        margin: meters added around the data.
        grid: use this grid instead (e.g. one covering held-out scans too); its resolution wins.
        range_offset: meters the model subtracts from each returned reading (:attr:`Problem.range_offset`);
            default :data:`RANGE_OFFSET_CELLS` (one) cell.
        sensor_params: the beam mixture's ``z_hit``, ``z_short``, ``z_max``, ``z_rand``, ``lambda_short`` (keywords of
            :func:`bayesmap.model.generative.make_params`); default :data:`bayesmap.model.sensor.BEAM_DEFAULTS`.
        likelihood_power: :attr:`Problem.likelihood_power`; default :data:`LOG_LIKELIHOOD_POWER`.

    Raises:
        BayesmapError: on bad parameters or scan indices, or a sensor position outside ``grid``.
    """
    scans = np.arange(len(log)) if scans is None else np.asarray(scans, dtype=np.int64).reshape(-1)
    if len(scans) == 0:
        raise BayesmapError("no scan selected")
    for index in (scans.min(), scans.max()):
        log._check_index(int(index))
    ranges = np.asarray(log.ranges[scans], dtype=np.float64)
    max_range = float(log.max_range) if math.isfinite(log.max_range) else float(ranges.max()) + 1.0
    is_max = ranges >= max_range
    poses = np.asarray(log.poses[scans], dtype=np.float64)
    beam_angles = np.asarray(log.angles[scans], dtype=np.float64)
    ends = poses[:, None, :2] + ranges[..., None] * np.stack([np.cos(beam_angles), np.sin(beam_angles)], axis=-1)
    if grid is None:
        grid = Grid.covering(np.vstack([ends[~is_max], poses[:, :2]]), resolution=resolution, margin=margin)
    resolution = grid.resolution
    noise = resolution / 2 if sensor_noise is None else sensor_noise
    params = make_params(prior_wall_prob, noise, beam_angles.shape[1], grid, max_distance=max_range,
                         beam_model=beam_model, **(sensor_params or {}))
    readings = np.where(is_max, max_range, ranges)
    label = f"{log.path} scans {scans[0]}..{scans[-1]} ({len(scans)})" if len(scans) > 1 else f"{log.path} scan {scans[0]}"
    offset = RANGE_OFFSET_CELLS * resolution if range_offset is None else float(range_offset)
    if not (math.isfinite(offset) and 0 <= offset < max_range):
        raise BayesmapError(f"range_offset must be between 0 and the max range {max_range:g} m, got {range_offset!r}")
    eta = check_likelihood_power(LOG_LIKELIHOOD_POWER if likelihood_power is None else likelihood_power)
    return Problem(params=params, pos=poses[:, :2], beam_angles=beam_angles, readings=readings, max_range_mask=is_max,
                   source=label, extra={"max_range": max_range, "scans": len(scans), "range_offset": offset},
                   range_offset=offset, likelihood_power=eta)
