"""Leave-one-log-out cross-validation of the loop edges' standard deviations (``posegraph.LOOP_STD``), by the ATE of
the path after loop closure (the chain's start).

For each log (intel, aces, csail) and odometry noise seed, the script makes the SLAM problem with
``shared/tools/noisy_odometry.py`` (``benchmarks/seeded_logs.py``), runs the front end once
(``logslam.front_end``), then ``posegraph.close_loops`` with ``LOOP_STD`` times each factor of ``--factors``, and
scores each path's ATE against the truth. For each log held out, the factor with the smallest mean ATE on the other
two logs is scored on it.

Usage: PYTHONPATH=src python benchmarks/loop_std_cv.py [--seeds 0-1] [--factors 0.5,1,2,4] [--logs intel,aces,csail]
"""

from __future__ import annotations

import argparse

import numpy as np
from karto_peer import parse_seeds
from seeded_logs import seeded_log

from bayesmap.evaluation.trajectory import absolute_trajectory_error
from bayesmap.slam import posegraph
from bayesmap.slam.pipeline import front_end, scan_data
from bayesmap.slam.problem import log_slam_problem

BASE = (0.05, 0.05, 0.02)
"""The factors multiply these (x m, y m, theta rad)."""


def ates(name: str, seed: int, factors: list[float]) -> list[float]:
    """The ATE (m) after loop closure of one log and seed, per factor."""
    log, truth = seeded_log(name, seed)
    problem = log_slam_problem(log)
    data = scan_data(problem)
    matched = front_end(problem, data)
    start = matched.path
    out = []
    saved = posegraph.LOOP_STD
    try:
        for f in factors:
            posegraph.LOOP_STD = tuple(f * v for v in BASE)  # read by loop_edges at call time
            path, _, _ = posegraph.close_loops(start, data, step_cov=matched.step_cov)
            out.append(absolute_trajectory_error(path, truth)["rmse_m"])
    finally:
        posegraph.LOOP_STD = saved
    print(f"{name} seed {seed}: " + ", ".join(f"x{f:g} {a:.3f}" for f, a in zip(factors, out)), flush=True)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-1")
    parser.add_argument("--factors", default="1,2,4")
    parser.add_argument("--logs", default="intel,aces,csail")
    args = parser.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    factors = [float(v) for v in args.factors.split(",")]
    logs = args.logs.split(",")
    table = {name: np.array([ates(name, s, factors) for s in seeds]) for name in logs}  # (seeds, factors)
    print("| held out | factor chosen on the others | its ATE per seed (m) | ATE at factor 1 (m) |")
    print("|---|---|---|---|")
    for name in logs:
        others = np.mean([table[o].mean(axis=0) for o in logs if o != name], axis=0)
        best = int(np.argmin(others))
        print(f"| {name} | {factors[best]:g} | {' / '.join(f'{a:.3f}' for a in table[name][:, best])} | "
              f"{' / '.join(f'{a:.3f}' for a in table[name][:, factors.index(1.0)]) if 1.0 in factors else '-'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
