"""The mapping problem: what a sensor observed, the poses the map is conditioned on, and the model parameters.

Observed versus conditioned on
------------------------------
A :class:`Problem` keeps apart what the sensor observed and what the map samplers condition on:

* :class:`Observations` are fixed data: per scan the beam angles relative to the robot's heading (sensor frame,
  ``(S, K)`` radians), the range readings (``(S, K)`` meters), which readings were max-range and the max range
  (the SLAM problem, :class:`bayesmap.slam.problem.SlamProblem`, adds the odometry).
* ``Problem.poses`` ``(S, 3)`` (x m, y m, theta rad) are the robot's poses the map is conditioned on: a log's
  corrected poses, or the current poses of a SLAM chain. Everything the samplers use is derived from them: the
  world-frame beam angles ``theta + relative angle`` (:attr:`Problem.ray_angles`), the ray origins and the ray-cell
  table (:attr:`Problem.table`, built lazily).

Poses that move
---------------
:meth:`Problem.with_poses` returns the same scene at other poses (same observations, parameters and truth); its
table is built again on first use. A SLAM chain (:mod:`bayesmap.slam.joint`, :mod:`bayesmap.slam.pipeline`) is a
Gibbs sweep over two blocks: (1) the poses given the current map, targeting ``p(poses | walls, readings,
odometry)`` (:mod:`bayesmap.slam.poses`: only the moved scans' beams change the likelihood), then (2) map sweeps on
the ray-cell table at the new poses. When only a few scans moved, :meth:`Problem.moved_scans` finds them,
:meth:`Problem.rays_of_scans` gives their rays and :meth:`bayesmap.geometry.raytable.RayTable.replace_rays` rebuilds
only those rows (the SLAM pipeline rebuilds the whole table once per round instead). Map samplers never read the
sensor-frame angles, only the table and the readings, so they need no change when poses move.

The world-frame angles of a log are kept exactly as :mod:`bayesmap.io.carmen` computed them
(``Problem.world_angles``, dropped by :meth:`Problem.with_poses`): ``theta + (angle - theta)`` can differ from
``angle`` in the last bit, and the ray table and every number downstream must stay the same.

The scenes that build a problem (the tutorial's, one scan, a log) and their defaults are in :mod:`bayesmap.scenes`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property

import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import scan_endpoints
from bayesmap.geometry.raytable import RayTable, build_ray_table, visible_cells
from bayesmap.geometry.tiles import table_chunks
from bayesmap.model.generative import ModelParams, cut_chords, log_joint, log_joint_scans, ray_limits
from bayesmap.model.likelihood import chunked_length, chunked_log_likelihoods, padded
from bayesmap.model.passable import PASS_WALLS, pass_mixture
from bayesmap.model.prior import disagreeing_pairs

TABLE_PIECE_PAIRS = 1 << 20
"""About how many (beam, cell) pairs one piece of :meth:`Problem.table_chunks` holds (whole scans): bounds the memory
that log-odds mapping, the log joint and the seen cells of a log take (about 100 MB of a piece and its temporaries
at this value), not what they compute."""

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
            (:func:`bayesmap.scenes.log_likelihood_power`). The reference samplers support only 1.
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
    def returned_endpoints(self) -> np.ndarray:
        """``(N, 2)`` float64 world endpoints of the readings that returned (not max-range), meters: where the
        sensor saw a surface."""
        ends = scan_endpoints(self.poses, self.observations.beam_angles, self.observations.readings, xp=np)
        mask = self.observations.max_range_mask
        return ends.reshape(-1, 2) if mask is None else ends[~mask]

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
        """The ray-cell table of all beams (``ray_table``, or built on first use and kept: memory grows with the
        log's pairs, about 8 bytes each; :meth:`table_chunks` reads the same table a piece at a time)."""
        if self.ray_table is not None:
            return self.ray_table

        return build_ray_table(self.grid, self.ray_origins, self.ray_angles, self.params.max_range,
                               ray_limits=self.ray_limits)

    @property
    def ray_limits(self) -> np.ndarray | None:
        """``(R,)`` each beam's own max distance in the table (its cut past the reading,
        :func:`bayesmap.model.generative.ray_limits`), meters; None: the max distance for every beam."""
        return ray_limits(self.model_ray_readings, self.params)

    def table_chunks(self, slots: int | None = None):
        """:attr:`table` a piece of whole scans at a time (:func:`bayesmap.geometry.tiles.table_chunks`, about
        ``slots`` pairs each, default :data:`TABLE_PIECE_PAIRS`): yields ``(rays, table)``, a slice of the rays and
        their ray-cell table. The table itself, in one piece, when it is already held (given as ``ray_table`` or
        built by :attr:`table`)."""
        if self.ray_table is not None or "table" in self.__dict__:
            yield slice(0, self.table.num_rays), self.table
            return
        yield from table_chunks(self.grid, self.ray_origins, self.ray_angles, self.params.max_range, self.ray_limits,
                                slots=TABLE_PIECE_PAIRS if slots is None else slots,
                                step=self.observations.num_beams)

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
        if len(self.ray_angles) * self.grid.num_cells <= 2e7:
            return float(log_joint_scans(walls, self.model_readings, self.pos, self.params, self.beam_angles))
        return self.table_log_joint(walls)

    def log_joints(self, maps) -> np.ndarray:
        """``(T,)`` float64 :meth:`log_joint` of each of ``maps`` ``(T, nx, ny)``; on a problem of several scans too
        large for the dense geometry, :meth:`table_log_joints` (one pass over the table's pieces for all maps)."""
        maps = np.asarray(maps)
        if self.multi_scan and len(self.ray_angles) * self.grid.num_cells > 2e7:
            return self.table_log_joints(maps)
        return np.array([self.log_joint(w) for w in maps], dtype=np.float64)

    def table_log_joint(self, walls) -> float:
        """:meth:`table_log_joints` of one map ``walls`` ``(nx, ny)``."""
        return float(self.table_log_joints(np.asarray(walls)[None])[0])

    def table_log_joints(self, maps) -> np.ndarray:
        """``(T,)`` float64 ``log p(walls, readings)`` of each of ``maps`` ``(T, nx, ny)`` from the ray-cell table, the
        table read once, a piece at a time, for all of them: the prior's log-probability plus, per beam,
        the sensor model's log-density of its reading given its first wall (the max distance if none; its first two
        walls when a beam can pass a wall cell, :func:`bayesmap.model.generative.walls_log_likelihood`).
        With a structured prior, the prior's part is :func:`bayesmap.model.prior.log_prior` (``-J`` per differing
        pair of neighbours, as the model's observed connections score). Time grows with the table's pairs, not beams x
        cells; memory with one piece of :meth:`table_chunks`."""
        maps = np.asarray(maps) > 0.5
        p = float(self.params.prior_wall_prob)
        walls_count = maps.sum(axis=(1, 2)).astype(np.float64)
        totals = walls_count * math.log(p) + (maps[0].size - walls_count) * math.log1p(-p)
        if self.params.structured:
            totals -= float(self.params.coupling) * np.array([int(disagreeing_pairs(w)) for w in maps], np.float64)
        walls_kept = PASS_WALLS if self.params.penetrable else 1
        for rays, table in self.table_chunks():
            readings = self.model_ray_readings[rays]  # the piece's, once for every map
            for t, walls in enumerate(maps):
                totals[t] += float(np.sum(self._beams_log_likelihoods(readings, table.wall_chords(walls, walls_kept)),
                                          dtype=np.float64))
        return totals

    def _beams_log_likelihoods(self, readings, chords) -> np.ndarray:
        """``(n,)`` :func:`~bayesmap.model.generative.walls_log_likelihood` of readings ``(n,)`` given their rays' wall
        chords ``(n, k, 2)`` (meters), by the same operations: the chords cut past the readings, the sensor model's
        log-density of each wall and of no wall from the compiled table the samplers use
        (:func:`~bayesmap.model.likelihood.chunked_log_likelihoods`, no compilation of its own), then
        :func:`~bayesmap.model.passable.pass_mixture` when wall cells can be passed."""
        params = self.params
        dtype = jnp.result_type(float)
        sensor_args = tuple(jnp.asarray(a, dtype=dtype) for a in params.sensor_args)
        n = len(readings)
        y = np.asarray(readings, dtype)
        # the operations run on arrays padded to the tables' length L (no wall past n): one compilation per L
        # instead of one per piece's n, whose first values they leave as they are
        size = chunked_length(n)
        chords = np.asarray(cut_chords(padded(y, size, 0.0), padded(np.asarray(chords, dtype), size, params.max_range),
                                       params))[:n]
        chord = params.geometry == "chord"

        def wall(entry, exit_):  # (L,) padded past n, as the samplers' tables
            return chunked_log_likelihoods(params.beam_model, sensor_args, y, entry, exit_ if chord else None)

        parts = [wall(chords[:, k, 0], chords[:, k, 1]) for k in range(chords.shape[1])]
        if not params.penetrable:
            return np.asarray(parts[0])[:n]
        none = np.full(n, params.max_range, dtype)
        return np.asarray(pass_mixture(parts[0], parts[1], wall(none, none), params.wall_pass_prob))[:n]

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
