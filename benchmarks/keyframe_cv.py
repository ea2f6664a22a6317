"""The path's error of ``bayesmap slam`` against the keyframe thresholds (and the cut past the readings).

For each log (``--logs``: intel, aces, csail from ``../shared/data/slam``, with their shared seed-0 odometry, or
another odometry seed of ``--seeds`` made by ``tools/noisy_odometry.py``), each keyframe threshold of
``--keyframes`` (meters and radians alike; 0 keeps every scan) and each cut of ``--cuts`` (meters; ``inf`` the whole
beam), ``bayesmap.runs.slam.log_slam`` runs the pipeline with every other default and no final map (the path is
scored, as ``bayesmap evaluate --truth-trajectory`` does), and the record holds the ATE of the posterior mean path
after the best rigid 2-D alignment, the coverage of its 95 % ellipses, the number of keyframes and the seconds.

Selection (for each log held out): the largest threshold whose ATE on each of the other logs is at most
``--spread`` meters (default 0.03, about the chain's own spread: ACES with 439 of its 440 scans lands 0.03 m from ACES
with all 440) above its ATE with every scan a keyframe (threshold 0, which ``--keyframes`` must hold): the cheapest
threshold that costs no log more than the noise. The last line is the threshold chosen on every log
(``bayesmap.slam.keyframes.KEYFRAME_DISTANCE``).

Every run is appended to ``--records`` (JSON lines) and not repeated.

Usage: PYTHONPATH=src:benchmarks python benchmarks/keyframe_cv.py --records FILE [--logs intel,aces,csail]
           [--keyframes 0,0.2,0.3,0.5] [--cuts 0.5] [--seeds 0] [--spread 0.03]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from seeded_logs import seeded_log

import bayesmap.slam.problem as slam_problem
from bayesmap.evaluation.trajectory import score_trajectory
from bayesmap.io.carmen import read_carmen
from bayesmap.io.tum import read_tum
from bayesmap.runs.slam import log_slam

SLAM_LOGS = Path(__file__).resolve().parents[2] / "shared" / "data" / "slam"


def log_and_truth(name: str, seed: int):
    """The log (odometry in its pose fields) and its true poses ``(S, 3)``: the shared files for seed 0, else made."""
    if seed == 0:
        return read_carmen(SLAM_LOGS / f"{name}-odom.log.gz"), read_tum(SLAM_LOGS / f"{name}-odom.truth.tum")[1]
    return seeded_log(name, seed)


def run_one(name: str, seed: int, threshold: float, cut: float) -> dict:
    """One SLAM run and its scores (the record)."""
    log, truth = log_and_truth(name, seed)
    slam_problem.LOG_CUT_PAST_READING = cut  # slam_map_settings reads it at each call
    start = time.perf_counter()
    run = log_slam(log, Path(f"{name}.log"), final_map=False, keyframe_distance=threshold, keyframe_turn=threshold)
    result, settings = run.result, run.settings
    scores = score_trajectory(result.mean_path, truth, result.pose_cov)
    return {"log": name, "seed": seed, "keyframe": threshold, "cut": cut, "ate_m": scores["ate_rmse_m"],
            "coverage": scores["coverage"], "keyframes": settings["keyframes"],
            "seconds": round(time.perf_counter() - start, 1)}


def choose(rows: list[dict], logs: list[str], thresholds: list[float], spread: float) -> float:
    """The largest threshold whose ATE on every log of ``logs`` is at most ``spread`` above the ATE with every scan
    a keyframe (threshold 0, which ``thresholds`` must hold); 0 if none is (module docstring)."""
    def ate(name, t):
        found = [r["ate_m"] for r in rows if r["log"] == name and r["keyframe"] == t]
        return float(np.mean(found)) if found else math.inf

    ok = [t for t in thresholds if all(ate(n, t) <= ate(n, 0.0) + spread for n in logs)]
    return max(ok, default=0.0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=Path, required=True)
    parser.add_argument("--logs", default="intel,aces,csail")
    parser.add_argument("--keyframes", default="0,0.2,0.3,0.5")
    parser.add_argument("--cuts", default="0.5")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--spread", type=float, default=0.03)
    args = parser.parse_args(argv)
    logs = args.logs.split(",")
    thresholds = [float(v) for v in args.keyframes.split(",")]
    cuts = [float(v) for v in args.cuts.split(",")]
    seeds = [int(v) for v in args.seeds.split(",")]
    rows = [json.loads(line) for line in args.records.read_text().splitlines()] if args.records.exists() else []
    done = {(r["log"], r["seed"], r["keyframe"], r["cut"]) for r in rows}
    for name in logs:
        for seed in seeds:
            for cut in cuts:
                for threshold in thresholds:
                    if (name, seed, threshold, cut) in done:
                        continue
                    row = run_one(name, seed, threshold, cut)
                    rows.append(row)
                    with args.records.open("a") as f:
                        f.write(json.dumps(row) + "\n")
                    print(json.dumps(row), flush=True)
    print("\nlog      seed  cut   keyframe  keyframes  ATE m   coverage  seconds")
    for r in sorted(rows, key=lambda r: (r["log"], r["seed"], r["cut"], r["keyframe"])):
        print(f"{r['log']:8s} {r['seed']:4d} {r['cut']:4.1f}  {r['keyframe']:8.2f}  {r['keyframes']:9d}  "
              f"{r['ate_m']:.4f}  {r['coverage']:.3f}     {r['seconds']:6.1f}")
    for cut in cuts:
        at_cut = [r for r in rows if r["cut"] == cut and r["log"] in logs]
        chosen = [choose(at_cut, [n for n in logs if n != held], thresholds, args.spread) for held in logs]
        print(f"\ncut {cut:g}: chosen per held-out log {dict(zip(logs, chosen))}; on every log "
              f"{choose(at_cut, logs, thresholds, args.spread)}")
    return 0 if all(math.isfinite(r["ate_m"]) for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
