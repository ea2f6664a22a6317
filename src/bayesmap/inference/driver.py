"""Running inference on a scene: chains of a sampler (or log-odds mapping), their posterior and a summary.

:func:`run_inference` runs in named steps (settings, chunk plan, sampler and compiled chain, chunks with progress,
summary); :func:`scene_summary` builds the part of the summary both drivers share."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.devices import on_sweep_devices
from bayesmap.errors import BayesmapError
from bayesmap.inference.chains import cell_diagnostics, compile_chain, posterior_mean, run_chain_from, run_chains_from
from bayesmap.inference.logodds import LogOddsParams, logodds_map, occupancy
from bayesmap.inference.registry import SAMPLERS, SEQUENTIAL_CHAINS, make_sampler
from bayesmap.inference.tiled import TILE_PAIRS, check_tile_pairs, map_chains
from bayesmap.memory import release_freed_memory
from bayesmap.model.sensor import BEAM_DEFAULTS
from bayesmap.progress import ProgressCallback, report, start_stage
from bayesmap.scenes import Problem

DEFAULT_SWEEPS = 100
"""Default number of sweeps of a chain (the tutorial's 100; the CLI and the app start from it)."""


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


def _check_settings(problem: Problem, sweeps: int, burn_in: int | None, chains: int, init: str | None
                    ) -> tuple[int, str]:
    """``(burn_in, init)`` with their defaults filled in (half the sweeps; ``"logodds"`` for several scans, else
    ``"free"``), after checking the run's settings (see :func:`run_inference` for what raises)."""
    if int(chains) != chains or chains < 1:
        raise BayesmapError(f"number of chains must be an integer >= 1, got {chains!r}")
    if int(sweeps) != sweeps or sweeps < 1:
        raise BayesmapError(f"number of sweeps must be an integer >= 1, got {sweeps!r}")
    burn_in = sweeps // 2 if burn_in is None else burn_in
    if int(burn_in) != burn_in or not (0 <= burn_in < sweeps):
        raise BayesmapError(f"burn-in must be an integer between 0 and {sweeps - 1} (sweeps - 1), got {burn_in!r}")
    if chains > 1 and sweeps - burn_in < 4:
        raise BayesmapError(f"diagnostics of {chains} chains need at least 4 sweeps after the burn-in, "
                            f"got {sweeps - burn_in}")
    init = ("logodds" if problem.multi_scan else "free") if init is None else init
    if init not in ("free", "logodds"):
        raise BayesmapError(f"unknown chain start {init!r}; choose free or logodds")
    return burn_in, init


class _Chunks(NamedTuple):
    """How the sweeps of a run are cut: ``chunk`` sweeps per compiled call, one key per chunk, ``at_once`` chains
    per compiled call (1 when the chains run one after another)."""

    chunk: int
    keys: jax.Array
    at_once: int
    one_by_one: bool


def _plan_chunks(sampler: str, sweeps: int, seed: int, chains: int) -> _Chunks:
    """Chunks of at most 10 sweeps (for progress), their keys split from ``seed``; chains at once (``vmap``) unless
    ``sampler`` is in :data:`SEQUENTIAL_CHAINS`."""
    one_by_one = chains > 1 and sampler in SEQUENTIAL_CHAINS
    chunk = max(1, min(sweeps, 10))
    keys = jax.random.split(jax.random.key(seed), -(-sweeps // chunk))
    return _Chunks(chunk, keys, 1 if one_by_one else chains, one_by_one)


def _prepare_chain(pool: ThreadPoolExecutor, problem: Problem, sampler: str, init: str, chains: int, plan: _Chunks):
    """``(algorithm, walls0, state0)``: the sampler, the first map and the chains' first state, with the chain
    compiled.

    Two cores (numpy, XLA's compiler and XLA's runtime release the GIL; the results are those of one step after
    another): the log-odds start map is computed on ``pool`` while the sampler is built, and the chain is compiled
    while its first state is computed.
    """
    if init == "logodds":
        problem.table.pair_rays  # (built before both threads use them)
        start_map = pool.submit(run_logodds, problem)
    algorithm = make_sampler(problem, sampler)
    if init == "logodds":
        walls0 = jnp.asarray(start_map.result().posterior > 0.5, jnp.float32)
    else:
        walls0 = jnp.zeros(problem.grid.shape, jnp.float32)
    at_once = plan.at_once

    def first_state():
        if at_once == 1:
            return algorithm.init(walls0)
        return jax.vmap(algorithm.init)(jnp.broadcast_to(walls0, (chains,) + walls0.shape))

    key_shape = jax.ShapeDtypeStruct((at_once,) if at_once > 1 else (), plan.keys.dtype)
    compiled = pool.submit(compile_chain, key_shape, jax.eval_shape(first_state), algorithm, plan.chunk,
                           at_once if at_once > 1 else None)
    state0 = first_state()
    compiled.result()  # JAX keeps the compiled chain: the first chunk does not compile it again
    return algorithm, walls0, state0


def _run_chunks(algorithm, keys, state, chains: int, sweeps: int, chunk: int, tick) -> tuple:
    """``(samples, wall_probs or None)`` of the chunks ``keys`` from ``state`` (``chains`` chains at once, or one),
    sweep axis -3; ``tick(n)`` after every chunk of ``n`` sweeps."""
    pieces, prob_pieces, done = [], [], 0
    for key in keys:
        n = min(chunk, sweeps - done)
        if chains == 1:
            samples, state, probs = run_chain_from(key, state, algorithm, n)
        else:
            samples, state, probs = run_chains_from(jax.random.split(key, chains), state, algorithm, n)
        pieces.append(np.asarray(samples))
        if probs is not None:
            prob_pieces.append(np.asarray(probs))
        done += n
        tick(n)
    return np.concatenate(pieces, axis=-3), np.concatenate(prob_pieces, axis=-3) if prob_pieces else None


def _run_all_chains(algorithm, state0, plan: _Chunks, chains: int, sweeps: int,
                    progress: ProgressCallback | None) -> tuple:
    """``(samples, wall_probs or None)`` of all chains (chain axis first with several), reporting the sweeps done
    (of every chain, when they run one after another) as stage ``"sweeps"`` after every chunk."""
    total = sweeps * chains if plan.one_by_one else sweeps
    finished = [0]  # sweeps run so far, all chains

    def tick(n):
        finished[0] += n
        report(progress, "sweeps", finished[0], total)

    if not plan.one_by_one:
        return _run_chunks(algorithm, plan.keys, state0, chains, sweeps, plan.chunk, tick)
    # chain c uses the keys chain c would get at once (split of each chunk's key)
    per_chain = jnp.stack([jax.random.split(key, chains) for key in plan.keys])  # (chunks, chains)
    runs = [_run_chunks(algorithm, per_chain[:, c], state0, 1, sweeps, plan.chunk, tick) for c in range(chains)]
    samples = np.stack([r[0] for r in runs])
    return samples, None if runs[0][1] is None else np.stack([r[1] for r in runs])


def scene_summary(problem: Problem, method: dict, results: dict, posterior, model: bool) -> dict:
    """The summary :func:`run_inference` and :func:`run_logodds` share (JSON-serializable), in this order: the source,
    ``method`` (the method's settings), with ``model`` the model's prior and noise, the beams and scans (or the
    sensor position), with ``model`` the sensor model, the grid and max distance, ``results`` (timings, ...),
    ``problem.extra``, with ``model`` the number of max-range readings, and with a truth the visible cells and how many
    of them ``posterior`` ``(nx, ny)`` gets wrong."""
    params = problem.params
    summary = {"source": problem.source, **method}
    if model:
        summary.update(prior_wall_prob=float(params.prior_wall_prob), sensor_noise=float(params.sensor_noise))
        if params.structured:  # the structured prior (bayesmap.model.prior); absent for the independent prior
            summary.update(coupling=float(params.coupling), neighbourhood=int(params.neighbourhood))
    summary["num_angles"] = int(np.shape(problem.beam_angles)[-1])
    if problem.multi_scan:
        summary.update(num_scans=problem.num_scans, num_beams=len(problem.ray_readings))
    else:
        summary["pos"] = [float(v) for v in problem.pos]
    if model:
        summary["beam_model"] = params.beam_model
        if params.beam_model == "beam":
            summary.update({name: float(getattr(params, name)) for name in BEAM_DEFAULTS})
    summary["grid"] = {"shape": list(problem.grid.shape), "resolution": problem.grid.resolution,
                       "origin": list(problem.grid.origin)}
    summary["max_distance"] = params.max_range
    summary.update(results)
    summary.update(problem.extra)
    if model and problem.max_range_mask is not None:
        summary["max_range_readings"] = int(problem.max_range_mask.sum())
    if problem.truth is not None:
        summary["visible_cells"] = int(problem.visible.sum())
        summary["wrong_visible_cells"] = problem.wrong_visible_cells(posterior)
    return summary


def _chain_summary(problem: Problem, samples, wall_probs, diagnostics, posterior, settings: dict,
                   runtime: float, final=None) -> dict:
    """:func:`scene_summary` of a chain run, with its log joints (of ``final``, the first chain's last map; default
    its last sample) and (several chains) convergence diagnostics."""
    results = {"runtime_s": round(runtime, 4),
               "posterior_estimate": "sample mean" if wall_probs is None else "rao-blackwellized",
               "likelihood_power": float(problem.likelihood_power)}
    summary = scene_summary(problem, settings, results, posterior, model=True)
    if problem.truth is not None:
        summary["log_joint_truth"] = problem.log_joint(problem.truth)
    if final is None:
        final = samples[-1] if settings["chains"] == 1 else samples[0, -1]
    summary["log_joint_final_sample"] = problem.log_joint(final)
    if diagnostics is not None:
        varying = np.isfinite(diagnostics["r_hat"])
        summary["cells_varying"] = int(varying.sum())
        summary["r_hat_max"] = float(diagnostics["r_hat"][varying].max()) if varying.any() else None
        summary["ess_min"] = float(diagnostics["ess"][varying].min()) if varying.any() else None
    return summary


def _run_log_chains(problem: Problem, sweeps: int, seed: int, chains: int, init: str, tile_pairs: int,
                    progress: ProgressCallback | None) -> tuple:
    """``(samples, wall_probs, tiles, final)`` of ``chains`` cellwise chains on a problem of several scans, by
    :func:`bayesmap.inference.tiled.map_chains` (a tile of the grid at a time beyond ``tile_pairs`` pairs, the chains
    one after another; within it, the chains split over the devices; one chain, or each beyond the budget, sweeping
    mostly the cells in doubt after its first sweeps: :mod:`bayesmap.inference.focus`). Chain ``c`` gets key ``c`` of
    ``seed``'s key split in ``chains`` (one chain: the key itself); ``final`` is the first chain's last map. The
    log-odds start map is computed a piece of the table at a time (the stage ``"log-odds start"`` of a
    :class:`bayesmap.progress.StageRecorder`); the sweeps report stage ``"sweeps"``, ``total`` the sweeps of every
    chain."""
    if init == "logodds":
        start_stage(progress, "log-odds start")
        walls0 = run_logodds(problem).posterior > 0.5
        release_freed_memory()  # (the pieces of the table)
    else:
        walls0 = np.zeros(problem.grid.shape, bool)
    with on_sweep_devices():  # the sweeps on the CPU, also where JAX's default device is a GPU (bayesmap.devices)
        key = jax.random.key(seed)
        keys = [key] if chains == 1 else list(jax.random.split(key, chains))
        runs = map_chains(keys, problem.params, problem.ray_origins, problem.ray_angles, problem.model_ray_readings,
                          jnp.asarray(walls0, jnp.float32), sweeps, problem.likelihood_power, max_pairs=tile_pairs,
                          progress=progress, focus=True)
    if chains == 1:
        return runs[0].samples, runs[0].wall_probs, runs[0].tiles, runs[0].walls
    return (np.stack([r.samples for r in runs]), np.stack([r.wall_probs for r in runs]), runs[0].tiles,
            runs[0].walls)


def run_inference(problem: Problem, sampler: str = "block", sweeps: int = DEFAULT_SWEEPS, burn_in: int | None = None,
                  seed: int = 0, progress: ProgressCallback | None = None, chains: int = 1,
                  init: str | None = None, tile_pairs: int = TILE_PAIRS) -> InferenceResult:
    """Run ``chains`` chains of ``sampler`` and summarize them: at once (``vmap``), or one after another for the
    samplers in :data:`SEQUENTIAL_CHAINS` (with the keys they would get at once, so the samples are the same).

    The cellwise sampler on a problem of several scans (a log) runs a tile of the grid at a time when its ray-cell
    table would hold more than ``tile_pairs`` pairs (:func:`bayesmap.inference.tiled.tiled_map_chain`; the samples
    of one sweep are then each cell's draw in that sweep of its tile, not one joint map), chain ``c`` with key ``c``
    of ``seed``'s key split in ``chains``; within the budget the chains run split over the CPU devices JAX sees
    (:func:`bayesmap.inference.tiled.map_chains`, :mod:`bayesmap.devices`), beyond it one after another. Its start
    map and the summary's log joint read the table a piece at a time (:meth:`bayesmap.problem.Problem.table_chunks`),
    so the memory is bounded by ``tile_pairs``, not by the log.

    Steps: check the settings, plan the chunks of sweeps and their keys, build the sampler and its compiled chain
    from the start map, run the chunks (with progress), then the posterior marginals, diagnostics and summary.

    Args:
        problem: the scene.
        sampler: a key of :data:`SAMPLERS`.
        sweeps: number of sweeps (>= 1).
        burn_in: sweeps dropped before averaging; default half of them.
        seed: the chain's PRNG seed.
        progress: a :data:`bayesmap.progress.ProgressCallback`, called with ``Progress("sweeps", done, total,
            "sweep")`` once the settings are checked (``done`` 0) and after every chunk of at most 10 sweeps, from the
            thread that runs the chain; ``total`` is ``sweeps``, or ``sweeps * chains`` for the samplers whose
            chains run one after another (:data:`SEQUENTIAL_CHAINS`). None: no reports.
        chains: number of independent chains (keys split from ``seed``); with 2 or more the summary reports the
            worst split R-hat and the smallest effective sample size over the cells that change.
        init: the chains' first map: ``"free"`` (no walls; the tutorial's, default for one scan) or ``"logodds"``
            (the cells log-odds mapping calls occupied, :func:`run_logodds`; default for several scans). Where the
            chain starts does not change its stationary distribution; with the robust beam model a chain started
            from the empty map can take very long to clear the spurious walls it draws first (a reading far beyond a
            wrong wall is only "random" under the mixture, so wrong walls on a beam hold each other in place).

        tile_pairs: the most pairs a tile of the cellwise sampler holds on a log
            (:data:`bayesmap.inference.tiled.TILE_PAIRS`).

    Raises:
        BayesmapError: on an unknown sampler, or a bad number of sweeps, burn-in, chains or ``tile_pairs``; with
            several chains, on fewer than 4 kept sweeps (too few for R-hat).
    """
    burn_in, init = _check_settings(problem, sweeps, burn_in, chains, init)
    check_tile_pairs(tile_pairs)
    if sampler == "cellwise" and problem.multi_scan:
        return _log_inference(problem, sweeps, burn_in, seed, chains, init, tile_pairs, progress)
    start = time.perf_counter()
    plan = _plan_chunks(sampler, sweeps, seed, chains)
    report(progress, "sweeps", 0, sweeps * chains if plan.one_by_one else sweeps)
    with ThreadPoolExecutor(max_workers=1) as pool:
        algorithm, walls0, state0 = _prepare_chain(pool, problem, sampler, init, chains, plan)
        # while the chain runs (on one core), the summary's log joint, evaluated op by op, compiles its small XLA
        # programs on the start map (the calls in the summary then find them compiled)
        warm = pool.submit(problem.log_joint, np.asarray(walls0) > 0.5)  # (bool, as the samples)
        samples, wall_probs = _run_all_chains(algorithm, state0, plan, chains, sweeps, progress)
        runtime = time.perf_counter() - start
        warm.result()
    # the posterior marginals: Rao-Blackwellized (mean of the conditional probabilities) where the sampler records
    # them, else the mean of the 0/1 samples
    posterior = posterior_mean(samples if wall_probs is None else wall_probs, burn_in)
    diagnostics = cell_diagnostics(samples, burn_in) if chains > 1 else None
    settings = {"sampler": sampler, "sampler_description": SAMPLERS[sampler][0], "sweeps": int(sweeps),
                "burn_in": int(burn_in), "seed": int(seed), "chains": int(chains), "init": init}
    summary = _chain_summary(problem, samples, wall_probs, diagnostics, posterior, settings, runtime)
    return InferenceResult(samples=samples, posterior=posterior, runtime_s=runtime, summary=summary,
                           diagnostics=diagnostics)


def _log_inference(problem: Problem, sweeps: int, burn_in: int, seed: int, chains: int, init: str, tile_pairs: int,
                   progress: ProgressCallback | None) -> InferenceResult:
    """:func:`run_inference` of the cellwise sampler on a problem of several scans (:func:`_run_log_chains`)."""
    start = time.perf_counter()
    samples, wall_probs, tiles, final = _run_log_chains(problem, sweeps, seed, chains, init, tile_pairs, progress)
    runtime = time.perf_counter() - start
    posterior = posterior_mean(wall_probs, burn_in)
    diagnostics = cell_diagnostics(samples, burn_in) if chains > 1 else None
    settings = {"sampler": "cellwise", "sampler_description": SAMPLERS["cellwise"][0], "sweeps": int(sweeps),
                "burn_in": int(burn_in), "seed": int(seed), "chains": int(chains), "init": init,
                "tile_pairs": int(tile_pairs), "tiles": len(tiles), "ray_cell_pairs": int(sum(t.pairs for t in tiles))}
    summary = _chain_summary(problem, samples, wall_probs, diagnostics, posterior, settings, runtime,
                             final=np.asarray(final) > 0.5)
    return InferenceResult(samples=samples, posterior=posterior, runtime_s=runtime, summary=summary,
                           diagnostics=diagnostics)


def run_logodds(problem: Problem, params=None) -> InferenceResult:
    """Map ``problem`` with classic log-odds occupancy mapping (:func:`bayesmap.inference.logodds.logodds_map`,
    one update per scan, in scan order) instead of a posterior: the baseline users know.

    Returns:
        An :class:`InferenceResult` whose ``posterior`` is the occupancy probability per cell (not a posterior),
        with no samples (``(0, nx, ny)``) and a summary like :func:`run_inference`'s (:func:`scene_summary`).
    """

    params = LogOddsParams() if params is None else params
    start = time.perf_counter()
    table_s, pairs, logodds = 0.0, 0, None
    readings, max_range, scans = problem.ray_readings, problem.ray_max_range, problem.scan_of_ray
    pieces = problem.table_chunks()  # (whole scans a piece; the scans in order: the same map as in one piece)
    while True:
        tic = time.perf_counter()
        rays, table = next(pieces, (None, None))
        table_s += time.perf_counter() - tic
        if table is None:
            break
        logodds = logodds_map(table, readings[rays], None if max_range is None else max_range[rays], scans[rays],
                              params, initial=logodds)
        pairs += table.num_pairs
        del table
    runtime = time.perf_counter() - start
    if logodds is None:  # (no beams)
        logodds = np.full(problem.grid.shape, params.l_prior)
    prob = occupancy(logodds)
    method = {"method": "logodds", "sampler": "logodds",
              "sampler_description": f"log-odds occupancy mapping, inverse sensor model (p_hit {params.p_hit}, p_miss "
                                     f"{params.p_miss}, clamping {params.clamp_min}-{params.clamp_max})"}
    results = {"ray_cell_pairs": int(pairs), "table_s": round(table_s, 4),
               "update_s": round(runtime - table_s, 4), "runtime_s": round(runtime, 4)}
    summary = scene_summary(problem, method, results, prob, model=False)
    empty = np.zeros((0,) + problem.grid.shape, dtype=bool)
    return InferenceResult(samples=empty, posterior=prob, runtime_s=runtime, summary=summary)
