"""The joint chain with and without segment moves: what rigid moves of ten-pose stretches add to the single-pose
random walk on real logs.

For each log, odometry seed (``seeded_logs.seeded_log``) and scan set (``all``, or ``every2``: every other scan),
the script runs :func:`bayesmap.slam.pipeline.run_log_slam` at its defaults twice, with ``segment_length=0``
(single-pose moves only) and at :data:`bayesmap.slam.poses.SEGMENT_LENGTH` (each pose sweep followed by a sweep of
:func:`bayesmap.slam.poses.segment_pose_mh`), the same seed, and prints the start path's ATE (the front end and the
loop closure, where the chain starts; the same in both runs) and per run the chain's mean path's ATE, how far (RMS,
m) the chain's mean moved from the start, its acceptance rate (a pose counts as moved when either sweep moved it),
the 95 % ellipse coverage and the run's seconds.

Usage: PYTHONPATH=src python benchmarks/segment_moves.py [--logs intel] [--seeds 0] [--scans every2]
    [--segment-length 10]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import scan_set_problem, scan_set_runs  # noqa: E402

from bayesmap.evaluation.trajectory import absolute_trajectory_error, ellipse_coverage  # noqa: E402
from bayesmap.slam import pipeline, posegraph  # noqa: E402
from bayesmap.slam.poses import SEGMENT_LENGTH  # noqa: E402


def start_path(problem) -> np.ndarray:
    """``(S, 3)`` where :func:`bayesmap.slam.pipeline.run_log_slam`'s chain starts: its front end and loop closure."""
    scans = pipeline.scan_data(problem)
    front = pipeline.front_end(problem, scans)
    return posegraph.close_loops(front.path, scans, step_cov=front.step_cov)[0]


def run(problem, truth, start, segment_length: int) -> str:
    """The columns of one run (module docstring)."""
    began = time.perf_counter()
    result = pipeline.run_log_slam(problem, segment_length=segment_length)
    seconds = time.perf_counter() - began
    mean = result.mean_path
    moved = np.sqrt(np.mean(np.sum((mean[:, :2] - start[:, :2]) ** 2, axis=1)))
    return (f"{absolute_trajectory_error(mean, truth)['rmse_m']:.4f} | {moved:.4f} | {result.acceptance_rate:.3f} | "
            f"{ellipse_coverage(mean, result.pose_cov, truth):.3f} | {seconds:.0f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--scans", default="every2", help="comma-separated subset of all,every2")
    parser.add_argument("--segment-length", type=int, default=SEGMENT_LENGTH)
    args = parser.parse_args(argv)
    runs = scan_set_runs(parser, args.logs, parse_seeds(args.seeds), args.scans)
    if args.segment_length < 1:
        parser.error(f"--segment-length must be at least 1, got {args.segment_length}")
    print("| log | seed | scans | start ATE m | segments | chain mean ATE m | moved from start m | acceptance | "
          "coverage 95 % | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, seed, scans in runs:
        problem, truth = scan_set_problem(name, seed, scans)
        start = start_path(problem)
        ate = absolute_trajectory_error(start, truth)["rmse_m"]
        for length in (0, args.segment_length):
            row = run(problem, truth, start, length)
            print(f"| {name} | {seed} | {scans} | {ate:.4f} | {length or 'none'} | {row} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
