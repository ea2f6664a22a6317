"""One description of a mapping problem (grid, sensor, beams, readings, model parameters) and running inference on it.

The CLI, the benchmarks and the app all build a :class:`Problem` and call :func:`run_inference`; nothing downstream
re-derives geometry on its own.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.grid import Grid, tutorial_map
from bayesmap.inference.cellwise import cellwise_gibbs
from bayesmap.inference.chains import (
    SamplingAlgorithm,
    _run,
    _run_many,
    cell_diagnostics,
    compile_chain,
    posterior_mean,
)
from bayesmap.inference.fast import fast_gibbs
from bayesmap.inference.reference import reference_gibbs, reference_incremental_gibbs
from bayesmap.model import (ModelParams, check_likelihood_power, log_joint, log_joint_scans, make_params,
                            reading_log_likelihood, simulate_readings)
from bayesmap.raycast import RayTable, angles, build_ray_table, visible_cells

TUTORIAL_POS = (10.0, 10.0)

MAX_FAST_PAIRS = 8_000_000
"""Most (beam, cell) pairs the level-based fast samplers (:data:`LEVEL_SAMPLERS`) take: they need about 1.9 KB per
pair (measured: 11.4 GB peak for CSAIL's 6.1 million pairs), so a whole log at 0.1 m (Intel: 42 million pairs) would
exhaust memory. The ``cellwise`` sampler needs about 22 bytes per pair and has no limit."""

LEVEL_SAMPLERS = ("block", "raster", "outward", "chromatic", "chromatic-block")
"""The samplers of :mod:`bayesmap.inference.fast` (levels of blocks updated at once)."""

SEQUENTIAL_CHAINS = ("cellwise",)
"""Samplers whose chains run one after another rather than at once under ``vmap`` (which would turn their
conditional writes into selects that always run)."""

LOG_PRIOR = 0.1
"""Default prior wall probability for maps from many scans (logs, floor plans): indoor floor plans have about a tenth
of their cells occupied, and with 0.5 the robust beam model explains a long beam's reading as a sensor failure rather
than as free space (the prior odds of "no wall in 100 cells" are 2^-100 against a likelihood ratio of at most 9)."""

def _fast(order: str, block_size: int, schedule: str):
    """Factory of a :func:`~bayesmap.inference.fast.fast_gibbs` sampler for a problem (its table, readings,
    parameters, first sensor position and likelihood power)."""
    return lambda pb: fast_gibbs(pb.table, pb.model_ray_readings, pb.params, order, block_size, schedule,
                                 pb.ray_origins[0], pb.likelihood_power)


# name -> (description, factory(problem) -> SamplingAlgorithm)
SAMPLERS: dict[str, tuple[str, object]] = {
    "block": ("2x2 block Gibbs, fast (ray-cell table), raster order", _fast("raster", 2, "sequential")),
    "raster": ("single-site Gibbs, fast, raster order", _fast("raster", 1, "sequential")),
    "outward": ("single-site Gibbs, fast, sensor-outward order", _fast("outward", 1, "sequential")),
    "chromatic": ("single-site Gibbs, fast, chromatic (colour classes updated in parallel)",
                  _fast("raster", 1, "chromatic")),
    "chromatic-block": ("2x2 block Gibbs, fast, chromatic", _fast("raster", 2, "chromatic")),
    "cellwise": ("single-site Gibbs, one cell at a time, each ray's first two walls in the state (whole logs)",
                 lambda pb: cellwise_gibbs(pb.table, pb.model_ray_readings, pb.params, pb.likelihood_power)),
    "reference-raster": ("the tutorial's single-site Gibbs with assess, raster order",
                         lambda pb: reference_gibbs(*pb.single_scan(), "raster", 1)),
    "reference-incremental": ("the tutorial's single-site Gibbs with incremental trace edit",
                              lambda pb: reference_incremental_gibbs(*pb.single_scan())),
    "reference-outward": ("the tutorial's single-site Gibbs with assess, sensor-outward order",
                          lambda pb: reference_gibbs(*pb.single_scan(), "outward", 1)),
    "reference-block": ("the tutorial's 2x2 block Gibbs with assess",
                        lambda pb: reference_gibbs(*pb.single_scan(), "raster", 2)),
}


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
            (:func:`bayesmap.model.check_likelihood_power`); 1 (the posterior) except for logs
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
        """``log p(walls, readings)``: the GenJAX model's ``assess`` (:func:`~bayesmap.model.log_joint`, or
        :func:`~bayesmap.model.log_joint_scans` for several scans) when the problem is small enough for the dense
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


def parse_scans(spec: str | None, num_scans: int) -> np.ndarray:
    """Scan indices from a spec: None or ``"all"`` (every scan), ``"i"`` (one), ``"a:b"`` or ``"a:b:step"``
    (Python slice syntax, any part may be empty), or a comma-separated list of those.

    Raises:
        BayesmapError: on a malformed spec, an index out of range, or no scan selected.
    """
    if spec is None or spec.strip().lower() == "all":
        return np.arange(num_scans)
    chosen = []
    for part in spec.split(","):
        part = part.strip()
        try:
            if ":" in part:
                bits = [int(b) if b.strip() else None for b in part.split(":")]
                if len(bits) > 3 or (len(bits) == 3 and bits[2] is not None and bits[2] <= 0):
                    raise ValueError
                chosen.append(np.arange(num_scans)[slice(*bits)])
            else:
                index = int(part)
        except ValueError:  # (BayesmapError is a ValueError too: none is raised inside)
            raise BayesmapError(f"bad scan selection {part!r}: use an index, a range a:b or a:b:step, or 'all'") from None
        if ":" not in part:
            if not (-num_scans <= index < num_scans):
                raise BayesmapError(f"scan {index} is out of range: the log has {num_scans} scans (0..{num_scans - 1})")
            chosen.append(np.array([index % num_scans]))
    scans = np.unique(np.concatenate(chosen)) if chosen else np.zeros(0, int)
    if len(scans) == 0:
        raise BayesmapError(f"the scan selection {spec!r} selects no scan of the {num_scans}")
    return scans


LOG_LIKELIHOOD_POWER = 0.1
"""Default likelihood power ``eta`` of a log (:attr:`Problem.likelihood_power`). The model treats every beam as
independent evidence given the map; the beams of a log are not (a scan's beams share its pose error, neighbouring
beams and consecutive scans see the same surface through the same errors), so the plain posterior is overconfident
about which cell of a surface is the wall. Raising the likelihood to ``eta < 1`` counts each beam as a fraction of
one (a power posterior; :func:`bayesmap.model.check_likelihood_power`). Chosen on the validation scans of
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
            :func:`bayesmap.model.make_params`); default :data:`bayesmap.sensor.BEAM_DEFAULTS`.
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


def make_sampler(problem: Problem, name: str) -> SamplingAlgorithm:
    """The sampler ``name`` (a key of :data:`SAMPLERS`) for ``problem``.

    Raises:
        BayesmapError: on an unknown name, a fast sampler on more than :data:`MAX_FAST_PAIRS` pairs, or a reference
            sampler on a tempered problem (``likelihood_power`` < 1).
    """
    if name not in SAMPLERS:
        raise BayesmapError(f"unknown sampler {name!r}; choose one of {', '.join(SAMPLERS)}")
    if name.startswith("reference-") and problem.likelihood_power != 1.0:
        raise BayesmapError(f"the sampler {name!r} samples the posterior itself (likelihood power 1), not a tempered "
                            f"one (likelihood power {problem.likelihood_power!r}); use a fast sampler or cellwise")
    if name in LEVEL_SAMPLERS and problem.table.num_pairs > MAX_FAST_PAIRS:
        pairs = problem.table.num_pairs
        raise BayesmapError(
            f"{problem.source or 'this problem'} has {pairs:,} (beam, cell) pairs; the sampler {name!r} takes at most "
            f"{MAX_FAST_PAIRS:,} (about 1.9 KB each, {pairs * 1.9e-6:.0f} GB here): use --sampler cellwise (about "
            "22 bytes per pair), map fewer scans (--scans ::k) or use coarser cells (--resolution)")
    return SAMPLERS[name][1](problem)


@dataclass
class InferenceResult:
    """What :func:`run_inference` returns.

    Attributes:
        samples: ``(num_sweeps, nx, ny)`` bool, the map after each sweep (``(num_chains, num_sweeps, nx, ny)``
            with several chains).
        posterior: ``(nx, ny)`` float64 posterior wall probability per cell, over the sweeps after the burn-in (and
            all chains): the mean of the conditional wall probabilities the sweeps drew from (Rao-Blackwellized) for
            samplers whose state records them (``"cellwise"``), else the mean of the samples
            (``summary["posterior_estimate"]`` says which).
        runtime_s: wall time of the whole run in seconds, compilation included.
        summary: settings and metrics (JSON-serializable).
        diagnostics: with 2 or more chains, per-cell ``{"r_hat": (nx, ny), "ess": (nx, ny)}`` float64 of the kept
            sweeps (:func:`~bayesmap.inference.chains.cell_diagnostics`); else None.
    """

    samples: np.ndarray
    posterior: np.ndarray
    runtime_s: float
    summary: dict
    diagnostics: dict | None = None


def run_inference(problem: Problem, sampler: str = "block", sweeps: int = 100, burn_in: int | None = None,
                  seed: int = 0, progress: bool = True, chains: int = 1,
                  on_progress=None, init: str | None = None) -> InferenceResult:
    """Run ``chains`` chains of ``sampler`` and summarize them: at once (``vmap``), or one after another for the
    samplers in :data:`SEQUENTIAL_CHAINS` (with the keys they would get at once, so the samples are the same).

    Args:
        problem: the scene.
        sampler: a key of :data:`SAMPLERS`.
        sweeps: number of sweeps (>= 1).
        burn_in: sweeps dropped before averaging; default half of them.
        seed: the chain's PRNG seed.
        progress: show a progress bar (tqdm, on stderr) when the run takes longer than a second.
        chains: number of independent chains (keys split from ``seed``); with 2 or more the summary reports the
            worst split R-hat and the smallest effective sample size over the cells that change.
        init: the chains' first map: ``"free"`` (no walls; the tutorial's, default for one scan) or ``"logodds"``
            (the cells log-odds mapping calls occupied, :func:`run_logodds`; default for several scans). Where the
            chain starts does not change its stationary distribution; with the robust beam model a chain started
            from the empty map can take very long to clear the spurious walls it draws first (a reading far beyond a
            wrong wall is only "random" under the mixture, so wrong walls on a beam hold each other in place).
        on_progress: called as ``on_progress(done, total)`` after every chunk of at most 10 sweeps (from the
            thread that runs the chain), for a progress display such as the app's.

    Raises:
        BayesmapError: on an unknown sampler, or a bad number of sweeps, burn-in or chains; with several chains,
            on fewer than 4 kept sweeps (too few for R-hat).
    """
    if int(chains) != chains or chains < 1:
        raise BayesmapError(f"number of chains must be an integer >= 1, got {chains!r}")
    if int(sweeps) != sweeps or sweeps < 1:
        raise BayesmapError(f"number of sweeps must be an integer >= 1, got {sweeps!r}")
    burn_in = sweeps // 2 if burn_in is None else burn_in
    if int(burn_in) != burn_in or not (0 <= burn_in < sweeps):
        raise BayesmapError(f"burn-in must be an integer between 0 and {sweeps - 1} (sweeps - 1), got {burn_in!r}")
    from tqdm import tqdm

    if chains > 1 and sweeps - burn_in < 4:
        raise BayesmapError(f"diagnostics of {chains} chains need at least 4 sweeps after the burn-in, got {sweeps - burn_in}")
    start = time.perf_counter()
    init = ("logodds" if problem.multi_scan else "free") if init is None else init
    if init not in ("free", "logodds"):
        raise BayesmapError(f"unknown chain start {init!r}; choose free or logodds")
    one_by_one = chains > 1 and sampler in SEQUENTIAL_CHAINS
    at_once = 1 if one_by_one else chains  # chains per compiled run
    chunk = max(1, min(sweeps, 10))
    keys = jax.random.split(jax.random.key(seed), -(-sweeps // chunk))
    # Two cores (numpy, XLA's compiler and XLA's runtime release the GIL; the results are those of one step after
    # another): the log-odds start map is computed while the sampler is built, the chain is compiled while its first
    # state is computed, and while the chain runs (on one core) the summary's log joint, evaluated op by op, compiles
    # its small XLA programs on the start map (the calls below then find them compiled).
    with ThreadPoolExecutor(max_workers=1) as pool:
        if init == "logodds":
            problem.table.pair_rays  # (built before both threads use them)
            start_map = pool.submit(run_logodds, problem)
        algorithm = make_sampler(problem, sampler)
        if init == "logodds":
            walls0 = jnp.asarray(start_map.result().posterior > 0.5, jnp.float32)
        else:
            walls0 = jnp.zeros(problem.grid.shape, jnp.float32)

        def first_state():
            if at_once == 1:
                return algorithm.init(walls0)
            return jax.vmap(algorithm.init)(jnp.broadcast_to(walls0, (chains,) + walls0.shape))

        key_shape = jax.ShapeDtypeStruct((at_once,) if at_once > 1 else (), keys.dtype)
        compiled = pool.submit(compile_chain, key_shape, jax.eval_shape(first_state), algorithm, chunk,
                               at_once if at_once > 1 else None)
        state0 = first_state()
        compiled.result()  # JAX keeps the compiled chain: the first chunk below does not compile it again
        warm = pool.submit(problem.log_joint, np.asarray(walls0) > 0.5)  # (bool, as the samples)
        with tqdm(total=sweeps * chains if one_by_one else sweeps, unit="sweep", delay=1.0, disable=not progress,
                  leave=False) as bar:
            finished = [0]  # sweeps run so far, all chains (a disabled tqdm does not count)

            def run(keys, state, chains, total):
                """``(samples, wall_probs or None)`` of the chunks ``keys``, sweep axis -3."""
                pieces, prob_pieces, done = [], [], 0
                for key in keys:
                    n = min(chunk, sweeps - done)
                    if chains == 1:
                        samples, state, probs = _run(key, state, algorithm, n)
                    else:
                        samples, state, probs = _run_many(jax.random.split(key, chains), state, algorithm, n)
                    pieces.append(np.asarray(samples))
                    if probs is not None:
                        prob_pieces.append(np.asarray(probs))
                    done += n
                    finished[0] += n
                    bar.update(n)
                    if on_progress is not None:
                        on_progress(finished[0], total)
                return (np.concatenate(pieces, axis=-3),
                        np.concatenate(prob_pieces, axis=-3) if prob_pieces else None)

            if one_by_one:  # chain c uses the keys chain c would get at once (split of each chunk's key)
                per_chain = jnp.stack([jax.random.split(key, chains) for key in keys])  # (chunks, chains)
                runs = [run(per_chain[:, c], state0, 1, sweeps * chains) for c in range(chains)]
                samples = np.stack([r[0] for r in runs])
                wall_probs = None if runs[0][1] is None else np.stack([r[1] for r in runs])
            else:
                samples, wall_probs = run(keys, state0, chains, sweeps)
        runtime = time.perf_counter() - start
        warm.result()
    # the posterior marginals: Rao-Blackwellized (mean of the conditional probabilities) where the sampler records
    # them, else the mean of the 0/1 samples
    posterior = posterior_mean(samples if wall_probs is None else wall_probs, burn_in)
    diagnostics = cell_diagnostics(samples, burn_in) if chains > 1 else None
    summary = {
        "source": problem.source,
        "sampler": sampler,
        "sampler_description": SAMPLERS[sampler][0],
        "sweeps": int(sweeps),
        "burn_in": int(burn_in),
        "seed": int(seed),
        "chains": int(chains),
        "init": init,
        "prior_wall_prob": float(problem.params.prior_wall_prob),
        "sensor_noise": float(problem.params.sensor_noise),
        "num_angles": int(np.shape(problem.beam_angles)[-1]),
        **({"num_scans": problem.num_scans, "num_beams": int(problem.table.num_rays)} if problem.multi_scan
           else {"pos": [float(v) for v in problem.pos]}),
        "beam_model": problem.params.beam_model,
        **({name: float(getattr(problem.params, name)) for name in ("z_hit", "z_short", "z_max", "z_rand", "lambda_short")}
           if problem.params.beam_model == "beam" else {}),
        "grid": {"shape": list(problem.grid.shape), "resolution": problem.grid.resolution, "origin": list(problem.grid.origin)},
        "max_distance": problem.params.cap,
        "runtime_s": round(runtime, 4),
        "posterior_estimate": "sample mean" if wall_probs is None else "rao-blackwellized",
        "likelihood_power": float(problem.likelihood_power),
        **problem.extra,
    }
    if problem.max_range_mask is not None:
        summary["max_range_readings"] = int(problem.max_range_mask.sum())
    if problem.truth is not None:
        summary["visible_cells"] = int(problem.visible.sum())
        summary["wrong_visible_cells"] = problem.wrong_visible_cells(posterior)
        summary["log_joint_truth"] = problem.log_joint(problem.truth)
    last = samples[-1] if chains == 1 else samples[0, -1]
    summary["log_joint_final_sample"] = problem.log_joint(last)
    if diagnostics is not None:
        varying = np.isfinite(diagnostics["r_hat"])
        summary["cells_varying"] = int(varying.sum())
        summary["r_hat_max"] = float(diagnostics["r_hat"][varying].max()) if varying.any() else None
        summary["ess_min"] = float(diagnostics["ess"][varying].min()) if varying.any() else None
    return InferenceResult(samples=samples, posterior=posterior, runtime_s=runtime, summary=summary, diagnostics=diagnostics)


def run_logodds(problem: Problem, params=None) -> InferenceResult:
    """Map ``problem`` with classic log-odds occupancy mapping (:func:`bayesmap.inference.logodds.logodds_map`,
    one update per scan, in scan order) instead of a posterior: the baseline users know.

    Returns:
        An :class:`InferenceResult` whose ``posterior`` is the occupancy probability per cell (not a posterior),
        with no samples (``(0, nx, ny)``) and a summary like :func:`run_inference`'s.
    """
    from bayesmap.inference.logodds import LogOddsParams, logodds_map, occupancy

    params = LogOddsParams() if params is None else params
    start = time.perf_counter()
    table = problem.table
    table_s = time.perf_counter() - start
    logodds = logodds_map(table, problem.ray_readings, problem.ray_max_range, problem.scan_of_ray, params)
    runtime = time.perf_counter() - start
    prob = occupancy(logodds)
    summary = {
        "source": problem.source,
        "method": "logodds",
        "sampler": "logodds",
        "sampler_description": f"log-odds occupancy mapping, inverse sensor model (p_hit {params.p_hit}, p_miss "
                               f"{params.p_miss}, clamping {params.clamp_min}-{params.clamp_max})",
        "num_angles": int(np.shape(problem.beam_angles)[-1]),
        **({"num_scans": problem.num_scans, "num_beams": int(table.num_rays)} if problem.multi_scan
           else {"pos": [float(v) for v in problem.pos]}),
        "grid": {"shape": list(problem.grid.shape), "resolution": problem.grid.resolution, "origin": list(problem.grid.origin)},
        "max_distance": problem.params.cap,
        "ray_cell_pairs": int(table.num_pairs),
        "table_s": round(table_s, 4),
        "update_s": round(runtime - table_s, 4),
        "runtime_s": round(runtime, 4),
        **problem.extra,
    }
    if problem.truth is not None:
        summary["visible_cells"] = int(problem.visible.sum())
        summary["wrong_visible_cells"] = problem.wrong_visible_cells(prob)
    empty = np.zeros((0,) + problem.grid.shape, dtype=bool)
    return InferenceResult(samples=empty, posterior=prob, runtime_s=runtime, summary=summary)

