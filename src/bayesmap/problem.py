"""One description of a mapping problem (grid, sensor, beams, readings, model parameters) and running inference on it.

The CLI, the benchmarks and the app all build a :class:`Problem` and call :func:`run_inference`; nothing downstream
re-derives geometry on its own.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.grid import Grid, tutorial_map
from bayesmap.inference.chains import SamplingAlgorithm, _run, _run_many, cell_diagnostics, posterior_mean
from bayesmap.inference.fast import fast_gibbs
from bayesmap.inference.reference import reference_gibbs, reference_incremental_gibbs
from bayesmap.model import ModelParams, log_joint, make_params, simulate_readings
from bayesmap.raycast import RayTable, angles, build_ray_table, check_readings, visible_cells

TUTORIAL_POS = (10.0, 10.0)

# name -> (description, factory(problem) -> SamplingAlgorithm)
SAMPLERS: dict[str, tuple[str, object]] = {
    "block": ("2x2 block Gibbs, fast (ray-cell table), raster order",
              lambda pb: fast_gibbs(pb.table, pb.readings, pb.params, "raster", 2, "sequential", pb.pos)),
    "raster": ("single-site Gibbs, fast, raster order",
               lambda pb: fast_gibbs(pb.table, pb.readings, pb.params, "raster", 1, "sequential", pb.pos)),
    "outward": ("single-site Gibbs, fast, sensor-outward order",
                lambda pb: fast_gibbs(pb.table, pb.readings, pb.params, "outward", 1, "sequential", pb.pos)),
    "chromatic": ("single-site Gibbs, fast, chromatic (colour classes updated in parallel)",
                  lambda pb: fast_gibbs(pb.table, pb.readings, pb.params, "raster", 1, "chromatic", pb.pos)),
    "chromatic-block": ("2x2 block Gibbs, fast, chromatic",
                        lambda pb: fast_gibbs(pb.table, pb.readings, pb.params, "raster", 2, "chromatic", pb.pos)),
    "reference-raster": ("the tutorial's single-site Gibbs with assess, raster order",
                         lambda pb: reference_gibbs(pb.readings, pb.pos, pb.params, pb.beam_angles, "raster", 1)),
    "reference-incremental": ("the tutorial's single-site Gibbs with incremental trace edit",
                              lambda pb: reference_incremental_gibbs(pb.readings, pb.pos, pb.params, pb.beam_angles)),
    "reference-outward": ("the tutorial's single-site Gibbs with assess, sensor-outward order",
                          lambda pb: reference_gibbs(pb.readings, pb.pos, pb.params, pb.beam_angles, "outward", 1)),
    "reference-block": ("the tutorial's 2x2 block Gibbs with assess",
                        lambda pb: reference_gibbs(pb.readings, pb.pos, pb.params, pb.beam_angles, "raster", 2)),
}


@dataclass(frozen=True, eq=False)
class Problem:
    """A single-scan mapping problem.

    Attributes:
        params: model parameters; ``params.grid`` is the grid and ``params.cap`` the max distance (meters).
        pos: ``(2,)`` float64 sensor position, world meters.
        beam_angles: ``(K,)`` float64 world-frame beam angles, radians.
        readings: ``(K,)`` float64 range readings, meters (max-range readings already set to the max range).
        truth: ``(nx, ny)`` float32 true map, or None for real data.
        max_range_mask: ``(K,)`` bool, readings that were max-range (no return), or None.
        source: a description for summaries.
    """

    params: ModelParams
    pos: np.ndarray
    beam_angles: np.ndarray
    readings: np.ndarray
    truth: np.ndarray | None = None
    max_range_mask: np.ndarray | None = None
    source: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def grid(self) -> Grid:
        return self.params.grid

    @cached_property
    def table(self) -> RayTable:
        """The ray-cell table of this scan (built on first use)."""
        return build_ray_table(self.grid, self.pos, self.beam_angles, self.params.cap)

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
                     sensor_noise: float = 0.2, num_angles: int = 100, source: str = "tutorial map") -> Problem:
    """The tutorial's scene: a map (default the built-in 21 x 21), the sensor at ``pos`` (default the center),
    ``num_angles`` equally spaced beams, readings simulated from the sensor model with ``jax.random.key(seed)``
    (seed 0 gives the tutorial's readings).

    Raises:
        BayesmapError: on bad parameters or a sensor position outside the grid.
    """
    walls = tutorial_map() if walls is None else (np.asarray(walls) > 0.5).astype(np.float32)
    grid = Grid(shape=walls.shape)
    params = make_params(prior_wall_prob, sensor_noise, num_angles, grid)
    grid.check_inside(pos)
    pos = np.asarray(pos, dtype=np.float64)
    beam_angles = np.asarray(angles(num_angles), dtype=np.float64)
    readings = simulate_readings(jax.random.key(seed), walls, pos, params)
    # the Normal sensor model can go below 0 next to a wall; a real sensor cannot: clip to 0
    readings = np.maximum(np.asarray(readings, dtype=np.float64), 0.0)
    return Problem(params=params, pos=pos, beam_angles=beam_angles, readings=readings, truth=walls, source=source)


def scan_problem(log, index: int, resolution: float = 0.1, prior_wall_prob: float = 0.5, sensor_noise: float = 0.2,
                 margin: float = 1.0) -> Problem:
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
    params = make_params(prior_wall_prob, sensor_noise, len(ranges), grid, max_distance=max_range)
    readings = np.where(is_max, max_range, ranges)
    return Problem(params=params, pos=pos, beam_angles=np.asarray(scan.angles, dtype=np.float64), readings=readings,
                   max_range_mask=is_max, source=f"{log.path} scan {index}",
                   extra={"pose": [float(v) for v in scan.pose], "max_range": max_range})


def make_sampler(problem: Problem, name: str) -> SamplingAlgorithm:
    """The sampler ``name`` (a key of :data:`SAMPLERS`) for ``problem``.

    Raises:
        BayesmapError: on an unknown name.
    """
    if name not in SAMPLERS:
        raise BayesmapError(f"unknown sampler {name!r}; choose one of {', '.join(SAMPLERS)}")
    return SAMPLERS[name][1](problem)


@dataclass
class InferenceResult:
    """What :func:`run_inference` returns.

    Attributes:
        samples: ``(num_sweeps, nx, ny)`` bool, the map after each sweep (``(num_chains, num_sweeps, nx, ny)``
            with several chains).
        posterior: ``(nx, ny)`` float64 mean of the samples after the burn-in (over all chains).
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
                  on_progress=None) -> InferenceResult:
    """Run ``chains`` chains of ``sampler`` from the all-free map (at once, ``vmap``) and summarize them.

    Args:
        problem: the scene.
        sampler: a key of :data:`SAMPLERS`.
        sweeps: number of sweeps (>= 1).
        burn_in: sweeps dropped before averaging; default half of them.
        seed: the chain's PRNG seed.
        progress: show a progress bar (tqdm, on stderr) when the run takes longer than a second.
        chains: number of independent chains (keys split from ``seed``); with 2 or more the summary reports the
            worst split R-hat and the smallest effective sample size over the cells that change.
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
    algorithm = make_sampler(problem, sampler)
    walls0 = jnp.zeros(problem.grid.shape, jnp.float32)
    state = algorithm.init(walls0) if chains == 1 else jax.vmap(algorithm.init)(jnp.broadcast_to(walls0, (chains,) + walls0.shape))
    chunk = max(1, min(sweeps, 10))
    keys = jax.random.split(jax.random.key(seed), -(-sweeps // chunk))
    pieces = []
    with tqdm(total=sweeps, unit="sweep", delay=1.0, disable=not progress, leave=False) as bar:
        done = 0
        for key in keys:
            n = min(chunk, sweeps - done)
            if chains == 1:
                samples, state = _run(key, state, algorithm, n)
            else:
                samples, state = _run_many(jax.random.split(key, chains), state, algorithm, n)
            pieces.append(np.asarray(samples))
            done += n
            bar.update(n)
            if on_progress is not None:
                on_progress(done, sweeps)
    samples = np.concatenate(pieces, axis=-3)
    runtime = time.perf_counter() - start
    posterior = posterior_mean(samples, burn_in)
    diagnostics = cell_diagnostics(samples, burn_in) if chains > 1 else None
    summary = {
        "source": problem.source,
        "sampler": sampler,
        "sampler_description": SAMPLERS[sampler][0],
        "sweeps": int(sweeps),
        "burn_in": int(burn_in),
        "seed": int(seed),
        "chains": int(chains),
        "prior_wall_prob": float(problem.params.prior_wall_prob),
        "sensor_noise": float(problem.params.sensor_noise),
        "num_angles": int(len(problem.beam_angles)),
        "pos": [float(v) for v in problem.pos],
        "grid": {"shape": list(problem.grid.shape), "resolution": problem.grid.resolution, "origin": list(problem.grid.origin)},
        "max_distance": problem.params.cap,
        "runtime_s": round(runtime, 4),
        **problem.extra,
    }
    if problem.max_range_mask is not None:
        summary["max_range_readings"] = int(problem.max_range_mask.sum())
    if problem.truth is not None:
        summary["visible_cells"] = int(problem.visible.sum())
        summary["wrong_visible_cells"] = problem.wrong_visible_cells(posterior)
        summary["log_joint_truth"] = float(log_joint(problem.truth, problem.readings, problem.pos, problem.params, problem.beam_angles))
    last = samples[-1] if chains == 1 else samples[0, -1]
    summary["log_joint_final_sample"] = float(log_joint(last, problem.readings, problem.pos, problem.params, problem.beam_angles))
    if diagnostics is not None:
        varying = np.isfinite(diagnostics["r_hat"])
        summary["cells_varying"] = int(varying.sum())
        summary["r_hat_max"] = float(diagnostics["r_hat"][varying].max()) if varying.any() else None
        summary["ess_min"] = float(diagnostics["ess"][varying].min()) if varying.any() else None
    return InferenceResult(samples=samples, posterior=posterior, runtime_s=runtime, summary=summary, diagnostics=diagnostics)
