"""Focused sweeps against the plain chain, and leave-one-log-out cross-validation of their settings.

For each log (intel, aces, csail) at 0.1 m: every 10th scan held out, the other scans' keyframes mapped as ``bayesmap
infer`` maps them (``tile_cv.problems``), ``--sweeps`` cellwise sweeps of the whole table from the log-odds map (the
first half burn-in): the plain chain twice (seeds 0 and 1: the chain's own Monte Carlo spread; ``every`` 1, every
sweep visits every cell) and once for each setting (``--settings``, ``EVERY:DOUBT`` pairs) of
:func:`bayesmap.inference.focus.focused_chain` (seed 0, ``start`` :data:`bayesmap.inference.focus.FOCUS_START`).
Each map is scored on the held-out beams (occupancy AUC and the predictive NLL with independent cells), with the
chain's seconds (the sampler built before the clock starts, its compilation included in every run alike) and the
mean absolute difference of its marginals from the plain chain's (seed 0).

Selection, for each log held out: among the settings whose mean NLL over the other logs is at most the plain
chain's there (the mean of its two seeds) plus the mean distance between those two seeds (any setting samples the
same posterior; a difference within the chain's own seed-to-seed spread is not one), the one with the least time
over the other logs. The last line is the setting chosen on every log: :data:`bayesmap.inference.focus.FOCUS_EVERY`
and :data:`bayesmap.inference.focus.FOCUS_DOUBT`.

Every run is appended to ``--cache`` (JSON lines) and not repeated.

Usage: PYTHONPATH=src:benchmarks python benchmarks/focus_cv.py [--logs intel,aces,csail]
           [--settings 5:0.001,10:0.001,5:0.0001,10:0.0001] [--sweeps 100] [--cache FILE.jsonl]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np
from seeded_logs import CORRECTED_LOGS
from tile_cv import problems

from bayesmap.evaluation.heldout import score_maps
from bayesmap.inference.cellwise import CellwiseGibbs
from bayesmap.inference.driver import run_logodds
from bayesmap.inference.focus import focused_chain


def run_one(train, test, every: int, doubt: float, sweeps: int, plain_posterior=None,
            seed: int = 0) -> tuple[dict, object]:
    """One focused chain (``every`` 1: the plain chain) scored on ``test``: the cache row and the posterior."""
    walls = np.asarray(run_logodds(train).posterior > 0.5, np.float32)
    readings = np.asarray(train.model_ray_readings).reshape(-1)
    gibbs = CellwiseGibbs(train.table, readings, train.params, train.likelihood_power)
    jax.clear_caches()  # every run compiles its sweep alike
    start = time.perf_counter()
    chain = focused_chain(jax.random.key(seed), gibbs.kernel, walls, sweeps, every=every, doubt=doubt)
    seconds = time.perf_counter() - start
    posterior = chain.wall_probs[sweeps // 2:].astype(np.float64).mean(axis=0)
    scores = score_maps(test, {"map": (posterior, None)})["map"]
    row = {"every": every, "doubt": doubt, "seed": seed, "seconds": round(seconds, 1), "auc": scores["auc"],
           "nll": scores["nll"]}
    if plain_posterior is not None:
        row["mean_abs_diff"] = float(np.abs(posterior - plain_posterior).mean())
    return row, posterior


def choose(rows: list[dict], logs: list[str], settings: list[tuple[int, float]]) -> tuple[int, float]:
    """The fastest setting whose mean NLL over ``logs`` is at most the plain chain's (the mean of its two seeds)
    plus the mean distance of those two seeds there (the module docstring); the plain chain's ``(1, 0.0)`` if none
    is."""
    def mean(key, every, doubt, seed=0, names=logs):
        return float(np.mean([r[key] for r in rows if r["log"] in names and r["every"] == every
                              and (every == 1 or r["doubt"] == doubt) and r["seed"] == seed]))

    spread = float(np.mean([abs(mean("nll", 1, 0.0, 1, [n]) - mean("nll", 1, 0.0, 0, [n])) for n in logs]))
    plain = (mean("nll", 1, 0.0) + mean("nll", 1, 0.0, 1)) / 2
    ok = [s for s in settings if mean("nll", *s) <= plain + spread]
    return min(ok, key=lambda s: mean("seconds", *s)) if ok else (1, 0.0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,aces,csail")
    parser.add_argument("--settings", default="5:0.001,10:0.001,5:0.0001,10:0.0001")
    parser.add_argument("--sweeps", type=int, default=100)
    parser.add_argument("--cache", type=Path, default=Path("focus_cv.jsonl"))
    args = parser.parse_args(argv)
    logs = args.logs.split(",")
    settings = [(int(e), float(d)) for e, d in (s.split(":") for s in args.settings.split(","))]
    rows = [json.loads(line) for line in args.cache.read_text().splitlines()] if args.cache.exists() else []
    for name in logs:
        chains = [(1, 0.0, 0), (1, 0.0, 1), *[(e, d, 0) for e, d in settings]]
        todo = [c for c in chains if not any(r["log"] == name and (r["every"], r["doubt"], r["seed"]) == c
                                             for r in rows)]
        if not todo:
            continue
        train, test = problems(CORRECTED_LOGS[name])
        first, plain = run_one(train, test, 1, 0.0, args.sweeps)
        for every, doubt, seed in todo:
            row = first if (every, seed) == (1, 0) else run_one(train, test, every, doubt, args.sweeps, plain,
                                                                  seed)[0]
            row.update(log=name, sweeps=args.sweeps)
            print(json.dumps(row), flush=True)
            with args.cache.open("a") as f:
                f.write(json.dumps(row) + "\n")
            rows.append(row)
    print("| log | chain | AUC | NLL | mean abs diff | seconds |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        chain = (f"plain, seed {r['seed']}" if r["every"] == 1
                 else f"every {r['every']}, doubt {r['doubt']:g}")
        diff = f"{r['mean_abs_diff']:.4f}" if "mean_abs_diff" in r else "-"
        print(f"| {r['log']} | {chain} | {r['auc']:.4f} | {r['nll']:.4f} | {diff} | {r['seconds']} |")
    for held in logs:
        others = [n for n in logs if n != held]
        every, doubt = choose(rows, others, settings)
        print(f"held out {held}: every {every}, doubt {doubt:g} (chosen on {', '.join(others)})")
    every, doubt = choose(rows, logs, settings)
    print(f"all logs: every {every}, doubt {doubt:g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
