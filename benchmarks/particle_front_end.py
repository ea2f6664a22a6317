"""The particle front end's time and path against the single track, on one log, at several particle counts.

For each count of ``--particles`` the script runs :func:`bayesmap.slam.pipeline.front_end` on the log's SLAM problem
(every scan, or every other with ``--scans every2``) twice, the first call with compilation, the second without,
then the loop closure (:func:`bayesmap.slam.posegraph.close_loops`), and records the front end's seconds, the
distinct heavy hypotheses, and, given the true trajectory, the ATE of the front end's path and of the start path
after loop closure (meters, after the best rigid 2-D alignment). One JSON line per count on stdout, and in
``--json FILE`` if given. The rest of ``slam --log`` does not depend on the particle count.

Usage: PYTHONPATH=src python benchmarks/particle_front_end.py --log SLAM.log.gz --truth SLAM.truth.tum
           [--scans all|every2] [--particles 1,8] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from bayesmap.evaluation.trajectory import absolute_trajectory_error
from bayesmap.io.carmen import read_carmen
from bayesmap.io.tum import read_tum
from bayesmap.slam import pipeline, posegraph
from bayesmap.slam.problem import log_slam_problem


def run(log_path: Path, truth_path: Path | None, scans: str, particles: int) -> dict:
    """One particle count's record (the module docstring)."""
    log = read_carmen(log_path)
    kept = np.arange(0, len(log), 2) if scans == "every2" else None
    problem = log_slam_problem(log, kept)
    data = pipeline.scan_data(problem)
    seconds = []
    for _ in range(2):
        began = time.perf_counter()
        matched = pipeline.front_end(problem, data, particles=particles)
        seconds.append(time.perf_counter() - began)
    closed = posegraph.close_loops(matched.path, data, step_cov=matched.step_cov).path
    record = {"log": log_path.name, "scans": scans, "num_scans": int(len(matched.path)), "particles": particles,
              "front_end_s_first": seconds[0], "front_end_s": seconds[1], "hypotheses": matched.hypotheses,
              "device": str(jax.devices()[0])}
    if truth_path is not None:
        truth = read_tum(truth_path)[1]
        truth = truth if kept is None else truth[kept]
        record["front_end_ate_m"] = absolute_trajectory_error(matched.path, truth)["rmse_m"]
        record["start_ate_m"] = absolute_trajectory_error(closed, truth)["rmse_m"]
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, required=True, help="a CARMEN log whose pose fields are the odometry")
    parser.add_argument("--truth", type=Path, help="its true trajectory, TUM")
    parser.add_argument("--scans", choices=("all", "every2"), default="all")
    parser.add_argument("--particles", default="1,8", help="comma-separated particle counts")
    parser.add_argument("--json", type=Path, help="also append the records to this file (JSON lines)")
    args = parser.parse_args(argv)
    counts = [int(v) for v in args.particles.split(",")]
    for count in counts:
        record = run(args.log, args.truth, args.scans, count)
        print(json.dumps(record), flush=True)
        if args.json is not None:
            with args.json.open("a") as out:
                out.write(json.dumps(record) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
