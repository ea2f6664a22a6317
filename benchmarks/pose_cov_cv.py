"""How well bayesmap's reported path uncertainty is calibrated, with leave-one-log-out cross-validation of a factor
on it as a diagnostic: the reported covariance is the chain's plus the pose graph's, whose sequential edges carry the
front end's step posteriors (``bayesmap.slam.pipeline``, stage 5), with no factor; a factor ``k`` on the graph's
standard deviations that a fit needs far from 1 would say the ellipses are too wide (``k < 1``) or too narrow.

For each log (intel, aces, csail) and each odometry noise seed, the script makes the SLAM problem with
``shared/tools/noisy_odometry.py`` (``benchmarks/seeded_logs.py``), runs ``run_log_slam`` at its defaults (no final
map: the path is scored) and keeps, per scan, the mean path, the chain's covariance, the graph's covariance and the
true pose (``--cache DIR`` keeps them in ``DIR/LOG-sSEED.npz``, so a second call only refits). It prints each run's
ATE and coverage as reported (``k = 1``); then, for each log held out, the ``k`` fitted on the other logs (the ``k``
whose 95 % ellipses, covariance ``chain + k^2 graph``, hold the true position for 95 % of the scans, every run
weighted equally; bisection: coverage grows with ``k``) and the held-out log's coverage at that ``k``; the last line
is ``k`` fitted on every log. (Before the step posteriors, such a fitted ``k``, 0.36, was bayesmap's
``GRAPH_COV_SCALE``.)

Usage: PYTHONPATH=src python benchmarks/pose_cov_cv.py [--seeds 0-1] [--logs intel,aces,csail] [--cache DIR]
                                                     [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from karto_peer import parse_seeds
from seeded_logs import run_file, seeded_log, slam_run_arrays

from bayesmap.evaluation.trajectory import absolute_trajectory_error, ellipse_coverage
from bayesmap.progress import ProgressBar
from bayesmap.slam.pipeline import run_log_slam
from bayesmap.slam.problem import log_slam_problem

LEVEL = 0.95


def run_one(name: str, seed: int, cache: Path) -> dict:
    """The cached arrays of one run (made on first use)."""
    out = run_file(cache, name, seed, "npz")
    if not out.exists():
        log, truth = seeded_log(name, seed)
        with ProgressBar() as bar:
            result = run_log_slam(log_slam_problem(log), progress=bar, final_map_sweeps=0)  # the path is scored
        np.savez(out, **slam_run_arrays(result, truth))
        print(f"{name} seed {seed}: ATE {absolute_trajectory_error(result.mean_path, truth)['rmse_m']:.3f} m, "
              f"{result.runtime_s:.0f} s", flush=True)
    return dict(np.load(out))


def coverage(run: dict, k: float) -> float:
    """The run's 95 % coverage with the graph's covariance scaled by ``k ** 2``."""
    return ellipse_coverage(run["mean"], run["chain_cov"] + k**2 * run["graph_cov"], run["truth"], LEVEL)


def fit_scale(runs: list[dict], low: float = 0.0, high: float = 4.0, steps: int = 40) -> float:
    """The factor whose mean coverage over ``runs`` is :data:`LEVEL` (bisection; coverage is nondecreasing in k)."""
    for _ in range(steps):
        mid = 0.5 * (low + high)
        if np.mean([coverage(r, mid) for r in runs]) < LEVEL:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-1")
    parser.add_argument("--logs", default="intel,aces,csail")
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    logs, seeds = args.logs.split(","), parse_seeds(args.seeds)
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        runs = {name: [run_one(name, s, cache) for s in seeds] for name in logs}
    print("| log | seed | ATE m | coverage as reported (k = 1) |\n|---|---|---|---|")
    for name in logs:
        for s, r in zip(seeds, runs[name]):
            print(f"| {name} | {s} | {absolute_trajectory_error(r['mean'], r['truth'])['rmse_m']:.3f} | "
                  f"{coverage(r, 1.0):.3f} |")
    rows = []
    print(f"\n| held out | k fitted on the others | its coverage per seed ({', '.join(map(str, seeds))}) | "
          "coverage at k = 1 |")
    print("|---|---|---|---|")
    for name in logs:
        others = [r for other in logs if other != name for r in runs[other]]
        k = fit_scale(others)
        held = [coverage(r, k) for r in runs[name]]
        reported = [coverage(r, 1.0) for r in runs[name]]
        rows.append({"held_out": name, "k": k, "coverage": held, "coverage_reported": reported})
        print(f"| {name} | {k:.3f} | {' / '.join(f'{c:.3f}' for c in held)} | "
              f"{' / '.join(f'{c:.3f}' for c in reported)} |")
    k_all = fit_scale([r for name in logs for r in runs[name]])
    print(f"k fitted on every log: {k_all:.3f}")
    if args.json:
        args.json.write_text(json.dumps({"seeds": seeds, "rows": rows, "k_all": k_all}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
