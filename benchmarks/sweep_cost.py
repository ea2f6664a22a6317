"""Seconds per cellwise sweep of a whole log, by map model (the cost target: the structured prior at most 1.5x
the independent prior's sweep).

For each setting, the log's problem is built at ``--resolution``, the cellwise sampler is started from the log-odds
map and a chain of ``--sweeps`` sweeps is compiled (``bayesmap.inference.chains.compile_chain``); the figure is the
best of ``--repeats`` timed runs of the compiled chain, divided by its sweeps (compilation and table building
excluded, as ``bayesmap bench`` times its samplers). Settings:

* ``entry``: the tutorial's entry geometry, a 0.1 m range offset, power 0.1, the independent prior (the log
  defaults before the map model was cross-validated);
* ``chord``: the chord geometry, no offset, the default power, the independent prior;
* ``opaque``: the log defaults with wall cells that stop every beam (``wall_pass_prob`` 0: each ray's first two
  walls in the rows, as before passable walls);
* ``default``: the log defaults of ``bayesmap.scenes`` (chord geometry, the structured prior and passable walls).

With ``--speculative CELLS,LANES`` (repeatable), each setting is timed with the sweep scoring at least ``CELLS``
cells at once, or ``LANES // width`` in a narrow group (``bayesmap.inference.cellwise.SPECULATIVE_CELLS`` and
``SPECULATIVE_LANES``; the draws are the same whatever they are), one row per pair.

With ``--compile``, each setting's one-sweep program is compiled instead (``jax.jit`` of the kernel's ``step``, the
kernel passed as an argument, as the chains pass it): the table prints its width groups and the seconds of lowering
and of XLA's compilation, for the first ``--scans`` scans of the log (all by default; repeatable, one row each).

With ``--profile DIR``, one more compiled sweep per setting runs under ``jax.profiler.trace`` (a Perfetto trace in
``DIR/SETTING``), and the script prints the compiled program's steps (XLA:CPU thunks: fusions, loops, conditionals)
with the largest self time, their calls and microseconds per call. The profiler drops events when a sweep has more
than its buffer holds (tens of thousands of steps), so compare the time per call, not the totals.

Usage: PYTHONPATH=src python benchmarks/sweep_cost.py [--log intel] [--resolution 0.1] [--sweeps 20] [--repeats 3]
[--settings entry,chord,opaque,default] [--speculative CELLS,LANES ...] [--profile DIR] [--compile [--scans N ...]]
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import time
from pathlib import Path

import jax
import numpy as np
from seeded_logs import CORRECTED_LOGS

from bayesmap import scenes
from bayesmap.inference import cellwise
from bayesmap.inference.chains import compile_chain
from bayesmap.inference.driver import run_logodds
from bayesmap.inference.registry import make_sampler
from bayesmap.io.carmen import read_carmen

SETTINGS = {
    "entry": dict(geometry="entry", range_offset=0.1, likelihood_power=0.1, coupling=0.0, wall_pass_prob=0.0),
    "chord": dict(coupling=0.0, wall_pass_prob=0.0),
    "opaque": dict(wall_pass_prob=0.0),
    "default": {},
}


def seconds_per_sweep(problem, sweeps: int, repeats: int, profile: Path | None = None) -> float:
    """Best of ``repeats`` runs of a compiled ``sweeps``-sweep cellwise chain, per sweep; with ``profile``, then one
    compiled sweep from the chain's last state under the profiler, its trace written into that folder."""
    algorithm = make_sampler(problem, "cellwise")
    state = algorithm.init(np.asarray(run_logodds(problem).posterior) > 0.5)
    key = jax.random.key(0)
    run = compile_chain(key, state, algorithm, sweeps)
    final = jax.block_until_ready(run(key, state))[1]
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(run(key, state))
        best = min(best, time.perf_counter() - start)
    if profile is not None:
        one = compile_chain(key, final, algorithm, 1)
        with jax.profiler.trace(str(profile), create_perfetto_trace=True):
            jax.block_until_ready(one(jax.random.key(1), final))
    return best / sweeps


def compile_seconds(problem) -> tuple[list[int], float, float]:
    """The cellwise sweep of ``problem``: its width groups, and the seconds to lower and to compile one sweep."""
    algorithm = make_sampler(problem, "cellwise")
    kernel = algorithm.step.args[0]  # a jax.tree_util.Partial of the kernel's step
    state = algorithm.init(np.zeros(problem.params.grid.shape, np.float32))
    start = time.perf_counter()
    lowered = jax.jit(lambda k, key, s: k.step(key, s)).lower(kernel, jax.random.key(0), state)
    lowering = time.perf_counter() - start
    start = time.perf_counter()
    lowered.compile()
    return [width for width, _ in kernel.shapes.groups], lowering, time.perf_counter() - start


def self_times(trace_file: Path) -> list[tuple[str, float, int]]:
    """``(name, self time in ms, calls)`` of every complete event of a Chrome/Perfetto trace (``.json.gz``), largest
    self time first: an event's duration minus that of the events nested in it on the same thread."""
    with gzip.open(trace_file) as f:
        events = json.load(f)
    events = events["traceEvents"] if isinstance(events, dict) else events
    threads = collections.defaultdict(list)
    for event in events:
        if event.get("ph") == "X":
            threads[event["pid"], event["tid"]].append(event)
    own, calls = collections.Counter(), collections.Counter()
    for thread in threads.values():
        thread.sort(key=lambda e: (e["ts"], -e.get("dur", 0)))
        stack = []
        for event in thread:
            while stack and stack[-1]["ts"] + stack[-1].get("dur", 0) <= event["ts"]:
                stack.pop()
            if stack:
                own[stack[-1]["name"]] -= event.get("dur", 0)
            own[event["name"]] += event.get("dur", 0)
            calls[event["name"]] += 1
            stack.append(event)
    return [(name, us / 1e3, calls[name]) for name, us in own.most_common()]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", default="intel")
    parser.add_argument("--resolution", type=float, default=scenes.RESOLUTION)
    parser.add_argument("--sweeps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--profile", type=Path, default=None, help="folder for a profiled sweep per setting")
    parser.add_argument("--top", type=int, default=12, help="steps printed per profiled setting (12)")
    parser.add_argument("--settings", default=",".join(SETTINGS), help="comma-separated settings (all)")
    parser.add_argument("--compile", action="store_true", help="time the compilation of one sweep instead")
    parser.add_argument("--scans", type=int, action="append", default=None,
                        help="--compile: the first N scans (repeatable; default all)")
    parser.add_argument("--speculative", action="append", default=None, metavar="CELLS,LANES",
                        help="cells / lanes scored at once (repeatable; default the module's)")
    args = parser.parse_args(argv)
    log = read_carmen(CORRECTED_LOGS[args.log])
    names = args.settings.split(",")
    unknown = sorted(set(names) - set(SETTINGS))
    if unknown:
        parser.error(f"unknown settings {unknown}; choose from {sorted(SETTINGS)}")
    speculative = [tuple(int(v) for v in text.split(",")) for text in args.speculative or
                   [f"{cellwise.SPECULATIVE_CELLS},{cellwise.SPECULATIVE_LANES}"]]
    if args.compile:
        print("| setting | scans | width groups | lowering s | compiling s |\n|---|---|---|---|---|")
        for name in names:
            for scans in args.scans or [len(log.poses)]:
                problem = scenes.log_problem(log, scans=np.arange(min(scans, len(log.poses))),
                                             resolution=args.resolution, **SETTINGS[name])
                groups, lowering, compiling = compile_seconds(problem)
                print(f"| {name} | {scans} | {len(groups)} ({groups[0]}-{groups[-1]}) | {lowering:.1f} | "
                      f"{compiling:.1f} |", flush=True)
        return 0
    print(f"| setting | coupling J | cells, lanes at once | seconds per sweep | ratio to {names[0]} |\n"
          "|---|---|---|---|---|")
    base = None
    for name in names:
        problem = scenes.log_problem(log, resolution=args.resolution, **SETTINGS[name])
        for cells, lanes in speculative:
            cellwise.SPECULATIVE_CELLS, cellwise.SPECULATIVE_LANES = cells, lanes
            jax.clear_caches()  # the sweep is traced with these
            folder = None if args.profile is None else args.profile / f"{name}-{cells}-{lanes}"
            cost = seconds_per_sweep(problem, args.sweeps, args.repeats, folder)
            base = cost if base is None else base
            print(f"| {name} | {problem.params.coupling:.3f} | {cells}, {lanes} | {cost:.3f} | {cost / base:.2f} |",
                  flush=True)
            if folder is not None:
                trace = max(folder.glob("**/perfetto_trace.json.gz"), key=lambda p: p.stat().st_mtime)
                steps = [row for row in self_times(trace) if not row[0].startswith(("ThunkExecutor", "$"))]
                for step, ms, count in steps[:args.top]:
                    print(f"    {name}: {step[:60]}: {ms:.1f} ms self, {count} calls, {1e3 * ms / count:.1f} us per "
                          "call")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
