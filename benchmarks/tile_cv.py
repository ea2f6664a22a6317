"""Tiles of a map chain against the whole table, and leave-one-log-out cross-validation of the tiles' band.

For each log (intel, aces, csail) at 0.1 m: every 10th scan held out, the other scans' keyframes mapped as ``bayesmap
infer`` maps them (the log's defaults, the cut past the reading, keyframes at 0.2 m / 0.2 rad), ``--sweeps`` cellwise
sweeps from the log-odds map (the first half burn-in), twice with the whole ray-cell table (seeds 0 and 1: the
chain's own Monte Carlo spread) and once for each band
(``--margins``, meters) in tiles of a quarter of the table's pairs (``bayesmap.inference.tiled.tiled_map_chain``
with ``max_pairs`` = pairs / 4, so four or more tiles, more tile edges than a log of this size would get at the
default budget). Each map is scored on the held-out beams (occupancy AUC, and the predictive NLL with independent
cells: a tiled chain's per-sweep records are not joint maps, so the samples' NLL is not used for either), with its
wall time, its tiles and the mean absolute difference of its marginals from the whole table's.

Selection, for each log held out: the smallest band whose mean NLL over the other logs is at most the whole table's
there (the mean of its two seeds) plus the mean distance between those two seeds (any band samples the same
posterior; the band only decides how far a tile's edges are from the cells it records, and a difference within the
chain's own seed-to-seed spread is not one). The last line is the band chosen on every log:
:data:`bayesmap.inference.tiled.TILE_MARGIN`.

Every run is appended to ``--cache`` (JSON lines) and not repeated.

Usage: PYTHONPATH=src python benchmarks/tile_cv.py [--logs intel,aces,csail] [--margins 0,0.5,1,2] [--sweeps 100]
           [--cache FILE.jsonl]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np
from seeded_logs import CORRECTED_LOGS

from bayesmap.evaluation.heldout import heldout_split, score_maps
from bayesmap.inference.driver import run_logodds
from bayesmap.inference.tiled import tiled_map_chain
from bayesmap.io.carmen import read_carmen
from bayesmap.scenes import LOG_CUT_PAST_READING, LOG_KEYFRAME_DISTANCE, LOG_KEYFRAME_TURN, log_problem
from bayesmap.slam.keyframes import select_keyframes

RESOLUTION = 0.1


def problems(path: Path):
    """``(train, test)`` problems of a log: the training scans' keyframes (cut past the reading) and the held-out
    scans, on one grid covering both."""
    log = read_carmen(path)
    scans = np.arange(len(log))
    train_pos, test_pos = heldout_split(len(scans), 10)
    grid = log_problem(log, scans, resolution=RESOLUTION).grid
    keyframes = train_pos[select_keyframes(log.poses[train_pos], LOG_KEYFRAME_DISTANCE, LOG_KEYFRAME_TURN)]
    train = log_problem(log, keyframes, resolution=RESOLUTION, grid=grid, cut_past_reading=LOG_CUT_PAST_READING)
    test = log_problem(log, test_pos, resolution=RESOLUTION, grid=grid)
    return train, test


def run_one(train, test, margin: float | None, sweeps: int, pairs: int, whole_posterior=None,
            seed: int = 0) -> tuple[dict, object]:
    """One chain (``margin`` None: the whole table) scored on ``test``: the cache row and the posterior."""
    walls = np.asarray(run_logodds(train).posterior > 0.5, np.float32)
    start = time.perf_counter()
    budget = 10**12 if margin is None else max(pairs // 4, 1)
    chain = tiled_map_chain(jax.random.key(seed), train.params, train.ray_origins, train.ray_angles,
                            np.asarray(train.model_ray_readings), walls, sweeps, train.likelihood_power,
                            max_pairs=budget, margin=0.0 if margin is None else margin)
    seconds = time.perf_counter() - start
    posterior = chain.wall_probs[sweeps // 2:].astype(np.float64).mean(axis=0)
    scores = score_maps(test, {"map": (posterior, None)})["map"]
    row = {"margin": margin, "seed": seed, "tiles": len(chain.tiles), "seconds": round(seconds, 1),
           "auc": scores["auc"], "nll": scores["nll"]}
    if whole_posterior is not None:
        row["mean_abs_diff"] = float(np.abs(posterior - whole_posterior).mean())
    return row, posterior


def choose(rows: list[dict], logs: list[str], margins: list[float]) -> float:
    """The smallest band whose mean NLL over ``logs`` is at most the whole table's (the mean of its two seeds) plus
    the mean distance of those two seeds there (the module docstring); the largest band if none is."""
    def nll(margin, seed=0, names=logs):
        return float(np.mean([r["nll"] for r in rows if r["log"] in names and r["margin"] == margin
                              and r.get("seed", 0) == seed]))

    spread = float(np.mean([abs(nll(None, 1, [n]) - nll(None, 0, [n])) for n in logs]))
    whole = (nll(None, 0) + nll(None, 1)) / 2
    ok = [m for m in sorted(margins) if nll(m) <= whole + spread]
    return ok[0] if ok else max(margins)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,aces,csail")
    parser.add_argument("--margins", default="0,0.5,1,2")
    parser.add_argument("--sweeps", type=int, default=100)
    parser.add_argument("--cache", type=Path, default=Path("tile_cv.jsonl"))
    args = parser.parse_args(argv)
    logs = args.logs.split(",")
    margins = [float(v) for v in args.margins.split(",")]
    rows = [json.loads(line) for line in args.cache.read_text().splitlines()] if args.cache.exists() else []
    for name in logs:
        chains = [(None, 0), (None, 1), *[(m, 0) for m in margins]]
        todo = [(m, seed) for m, seed in chains
                if not any(r["log"] == name and r["margin"] == m and r.get("seed", 0) == seed for r in rows)]
        if not todo:
            continue
        train, test = problems(CORRECTED_LOGS[name])
        pairs = int(train.table.num_pairs)
        first, whole = run_one(train, test, None, args.sweeps, pairs)
        for margin, seed in todo:
            row = first if (margin, seed) == (None, 0) else run_one(train, test, margin, args.sweeps, pairs, whole,
                                                                     seed)[0]
            row.update(log=name, pairs=pairs, sweeps=args.sweeps)
            print(json.dumps(row), flush=True)
            with args.cache.open("a") as f:
                f.write(json.dumps(row) + "\n")
            rows.append(row)
    print("| log | band m | tiles | AUC | NLL | mean abs diff | seconds |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        band = f"whole table, seed {r.get('seed', 0)}" if r["margin"] is None else f"{r['margin']:g}"
        diff = f"{r['mean_abs_diff']:.4f}" if "mean_abs_diff" in r else "-"
        print(f"| {r['log']} | {band} | {r['tiles']} | {r['auc']:.4f} | {r['nll']:.4f} | {diff} | {r['seconds']} |")
    for held in logs:
        others = [n for n in logs if n != held]
        print(f"held out {held}: band {choose(rows, others, margins):g} m (chosen on {', '.join(others)})")
    print(f"all logs: band {choose(rows, logs, margins):g} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
