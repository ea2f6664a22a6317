"""``bayesmap bench``: the fast samplers against the tutorial's reference samplers, side by side, in one process.

On the tutorial scene (21 x 21 map, sensor at (10, 10), 100 beams, readings from key 0, prior 0.5) it measures for
each Gibbs variant:

* steady-state seconds per sweep of the fast sampler and of its reference (a compiled chain of several sweeps,
  timed after compilation; the best of a few repeats, the usual way to time code on a shared machine);
* their ratio;
* compile time: building the sampler (tables, schedule) plus tracing and compiling its chain;
* time to accuracy: wall time from nothing (sampler built, chain compiled, both included) until the chain mean
  has at most 2 wrong visible cells (the accuracy of the tutorial's Gibbs samplers). The chain runs one sweep per
  call, as an interactive user would, and the mean is over the second half of the sweeps so far;
* for the fast samplers, chains x sweeps per second with 64 chains at once (``vmap``), and the wall time of a
  fresh 100-sweep chain, compilation included.

The tutorial's own code, measured on a machine of the same kind, is in ``shared/reference/tutorial-baseline.md``;
its figures are printed beside ours for scale (a different run, so compare those ratios loosely).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.chains import compile_chain, run_chain_from
from bayesmap.inference.registry import SAMPLERS, make_sampler
from bayesmap.problem import Problem
from bayesmap.scenes import tutorial_problem

# fast sampler -> (reference sampler, tutorial baseline seconds per sweep or None, note)
PAIRS: dict[str, tuple[str, float | None, str]] = {
    "raster": ("reference-raster", 0.21, ""),
    "incremental": ("reference-incremental", 0.13, "fast side: the raster sampler (same kernel)"),
    "outward": ("reference-outward", 0.47, ""),
    "block": ("reference-block", 0.73, ""),
    "chromatic": ("reference-raster", None, "a different (chromatic) scan than its reference"),
    "chromatic-block": ("reference-block", None, "a different (chromatic) scan than its reference"),
}
FAST_NAME = {"incremental": "raster"}
ACCURACY_WRONG_CELLS = 2


@dataclass
class Timing:
    """Figures of one sampler on one problem (seconds)."""

    s_per_sweep: float
    compile_s: float
    time_to_accuracy_s: float | None
    sweeps_to_accuracy: int | None


def _start(problem: Problem, name: str):
    """Build the sampler and its state on the all-free map: ``(algorithm, state)``."""
    algorithm = make_sampler(problem, name)
    return algorithm, algorithm.init(jnp.zeros(problem.grid.shape, jnp.float32))


def time_sampler(problem: Problem, name: str, sweeps: int, repeats: int, max_sweeps: int) -> Timing:
    """Measure one sampler (see the module docstring).

    Args:
        problem: a scene with a known true map.
        name: a key of :data:`bayesmap.inference.registry.SAMPLERS`.
        sweeps: sweeps per timed chain for the steady state.
        repeats: timed chains; the fastest counts.
        max_sweeps: give up on the accuracy after this many sweeps (``time_to_accuracy_s`` is then None).
    """
    # time to accuracy, from nothing (compilation included)
    start = time.perf_counter()
    algorithm, state = _start(problem, name)
    one = compile_chain(jax.random.key(0), state, algorithm, 1)
    samples = []
    reached = None
    for t in range(1, max_sweeps + 1):
        out, state, _ = one(jax.random.key(t), state)
        samples.append(np.asarray(out[0], dtype=np.float64))
        kept = samples[t // 2:]
        if problem.wrong_visible_cells(sum(kept) / len(kept)) <= ACCURACY_WRONG_CELLS:
            reached = t
            break
    time_to_accuracy = time.perf_counter() - start if reached else None
    # compile time (building the sampler included) and steady state, on a new sampler object (nothing cached)
    start = time.perf_counter()
    algorithm, state = _start(problem, name)
    chain = compile_chain(jax.random.key(0), state, algorithm, sweeps)
    compile_s = time.perf_counter() - start
    jax.block_until_ready(chain(jax.random.key(0), state))
    best = np.inf
    for r in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(chain(jax.random.key(r + 1), state))
        best = min(best, (time.perf_counter() - start) / sweeps)
    return Timing(s_per_sweep=best, compile_s=compile_s, time_to_accuracy_s=time_to_accuracy,
                  sweeps_to_accuracy=reached)


def chain_throughput(problem: Problem, name: str, num_chains: int = 64, sweeps: int = 50, repeats: int = 3) -> float:
    """Chains x sweeps per second of ``num_chains`` chains run at once (steady state)."""
    algorithm = make_sampler(problem, name)
    states = jax.vmap(algorithm.init)(jnp.zeros((num_chains,) + problem.grid.shape, jnp.float32))
    keys = jax.random.split(jax.random.key(0), num_chains)
    run = compile_chain(keys, states, algorithm, sweeps, num_chains)
    jax.block_until_ready(run(keys, states))
    best = np.inf
    for r in range(repeats):
        keys = jax.random.split(jax.random.key(r + 1), num_chains)
        start = time.perf_counter()
        jax.block_until_ready(run(keys, states))
        best = min(best, time.perf_counter() - start)
    return num_chains * sweeps / best


def fresh_chain_seconds(problem: Problem, name: str, sweeps: int = 100) -> float:
    """Wall time of a new ``sweeps``-sweep chain from nothing: build the sampler, compile, run."""
    start = time.perf_counter()
    algorithm, state = _start(problem, name)
    samples, _, _ = run_chain_from(jax.random.key(0), state, algorithm, sweeps)
    jax.block_until_ready(samples)
    return time.perf_counter() - start


def run_bench(samplers=None, fast_sweeps: int = 200, reference_sweeps: int = 5, repeats: int = 5,
              num_chains: int = 64, progress=None) -> dict:
    """Run the benchmark on the tutorial scene.

    Args:
        samplers: names from :data:`PAIRS` (default: all).
        fast_sweeps: sweeps per timed chain of a fast sampler.
        reference_sweeps: sweeps per timed chain of a reference sampler.
        repeats: timed chains per sampler (the fastest counts).
        num_chains: chains for the throughput figure.
        progress: optional callable taking a message string.

    Returns:
        ``{name: {"reference": ..., "reference_s_per_sweep": ..., "fast_s_per_sweep": ..., "ratio": ...,
        "compile_s": ..., "time_to_accuracy_s": ..., ...}}`` (see :func:`format_table` for all fields).
    """

    samplers = list(PAIRS) if samplers is None else list(samplers)
    for name in samplers:
        if name not in PAIRS:
            raise BayesmapError(f"unknown benchmark sampler {name!r}; choose from {', '.join(PAIRS)}")
    problem = tutorial_problem()
    problem.visible  # noqa: B018 -- computed once, outside every timing
    # warm up JAX (backend start, first compilation) so that it is not charged to the first sampler timed
    warm, state = _start(problem, "chromatic")
    jax.block_until_ready(run_chain_from(jax.random.key(0), state, warm, 2))
    say = progress or (lambda msg: None)
    fast_cache: dict[str, tuple] = {}
    ref_cache: dict[str, Timing] = {}
    results = {}
    for name in samplers:
        reference, baseline, note = PAIRS[name]
        fast = FAST_NAME.get(name, name)
        if fast not in fast_cache:
            say(f"timing {fast} (fast)")
            timing = time_sampler(problem, fast, fast_sweeps, repeats, max_sweeps=500)
            fast_cache[fast] = (timing, chain_throughput(problem, fast, num_chains), fresh_chain_seconds(problem, fast))
        if reference not in ref_cache:
            say(f"timing {reference}")
            ref_cache[reference] = time_sampler(problem, reference, reference_sweeps, max(2, repeats // 2),
                                                max_sweeps=60)
        f, throughput, chain100 = fast_cache[fast]
        r = ref_cache[reference]
        results[name] = {
            "fast": fast,
            "reference": reference,
            "reference_s_per_sweep": r.s_per_sweep,
            "fast_s_per_sweep": f.s_per_sweep,
            "ratio": r.s_per_sweep / f.s_per_sweep,
            "compile_s": f.compile_s,
            "time_to_accuracy_s": f.time_to_accuracy_s,
            "sweeps_to_accuracy": f.sweeps_to_accuracy,
            "reference_compile_s": r.compile_s,
            "reference_time_to_accuracy_s": r.time_to_accuracy_s,
            "reference_sweeps_to_accuracy": r.sweeps_to_accuracy,
            "chain_sweeps_per_s_64": throughput if num_chains == 64 else None,
            "chain_sweeps_per_s": throughput,
            "num_chains": num_chains,
            "fresh_100_sweep_chain_s": chain100,
            "tutorial_baseline_s_per_sweep": baseline,
            "ratio_to_tutorial_baseline": baseline / f.s_per_sweep if baseline else None,
            "note": note,
        }
    return results


def _fmt(value, unit="", digits=3) -> str:
    if value is None:
        return "-"
    if unit == "ms":
        return f"{value * 1e3:.{digits}f}"
    if unit == "x":
        return f"{value:,.0f}x"
    return f"{value:.{digits}f}"


def format_table(results: dict) -> str:
    """The benchmark as a plain-text table (one row per sampler)."""
    header = ("sampler", "reference", "ref ms/sweep", "fast ms/sweep", "ratio", "compile s", "to 2 wrong s",
              "sweeps", "ref to 2 wrong s", "64-chain sweeps/s", "100-sweep chain s", "vs tutorial")
    rows = [header]
    for name, r in results.items():
        rows.append((
            name,
            r["reference"],
            _fmt(r["reference_s_per_sweep"], "ms", 1),
            _fmt(r["fast_s_per_sweep"], "ms", 4),
            _fmt(r["ratio"], "x"),
            _fmt(r["compile_s"], digits=2),
            _fmt(r["time_to_accuracy_s"], digits=2),
            "-" if r["sweeps_to_accuracy"] is None else str(r["sweeps_to_accuracy"]),
            _fmt(r["reference_time_to_accuracy_s"], digits=2),
            f"{r['chain_sweeps_per_s']:,.0f}",
            _fmt(r["fresh_100_sweep_chain_s"], digits=2),
            _fmt(r["ratio_to_tutorial_baseline"], "x"),
        ))
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(w) if i < 2 else cell.rjust(w) for i, (cell, w) in enumerate(zip(row, widths)))
             for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    notes = [f"  {name}: {r['note']}" for name, r in results.items() if r["note"]]
    return "\n".join(lines + (["notes:"] + notes if notes else []))


def describe_samplers() -> str:
    return "; ".join(f"{name}: {SAMPLERS[FAST_NAME.get(name, name)][0]}" for name in PAIRS)
