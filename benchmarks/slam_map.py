"""The map of bayesmap's real-log SLAM beside the map made at the true poses, on held-out beams: one table, one run.

For each log (intel, aces, csail) and each odometry noise seed, the script makes the SLAM problem with
``noisy_odometry.py`` (as ``karto_peer.py`` does: real scans, simulated wheel odometry, the corrected poses as the
truth) and runs :func:`bayesmap.evaluation.slammap.evaluate_slam_map`: every 10th scan held out, SLAM on the rest from
odometry alone, the reference map from the same scans at their true poses, both scored on the held-out beams at their
true poses (occupancy AUC and predictive NLL). Issue 15's target: the SLAM map's AUC within 0.01 of the reference's.

Usage: PYTHONPATH=src python benchmarks/slam_map.py [--seeds 0] [--logs intel,aces,csail] [--resolution 0.1]
                                                   [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import CORRECTED_LOGS, make_problem, parse_seeds  # noqa: E402

from bayesmap.evaluation.slammap import evaluate_slam_map  # noqa: E402
from bayesmap.io.carmen import read_carmen  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0", help="odometry noise seeds, e.g. 0-4 or 0,3 (default 0)")
    parser.add_argument("--logs", default="intel,aces,csail", help="comma-separated subset of intel,aces,csail")
    parser.add_argument("--resolution", type=float, default=0.1, help="meters per cell (default 0.1)")
    parser.add_argument("--json", type=Path, default=None, help="write every run's figures here")
    args = parser.parse_args(argv)
    logs = [name.strip() for name in args.logs.split(",") if name.strip()]
    unknown = sorted(set(logs) - set(CORRECTED_LOGS))
    if unknown:
        parser.error(f"unknown log(s) {', '.join(unknown)}; choose from {', '.join(CORRECTED_LOGS)}")
    records = []
    print("| log | seed | SLAM ATE m | SLAM map AUC | true-pose map AUC | AUC gap | SLAM map NLL | true-pose map NLL |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for name in logs:
            for seed in parse_seeds(args.seeds):
                problem = make_problem(name, seed, Path(folder))
                scores = evaluate_slam_map(read_carmen(problem.log_path), problem.truth, resolution=args.resolution)
                slam, ref = scores["slam"], scores["true_poses"]
                print(f"| {name} | {seed} | {scores['setup']['slam_ate_m']:.3f} | {slam['auc']:.4f} | "
                      f"{ref['auc']:.4f} | {ref['auc'] - slam['auc']:+.4f} | {slam['nll']:.3f} | {ref['nll']:.3f} |",
                      flush=True)
                records.append({"log": name, "seed": seed, **scores})
    if args.json is not None:
        args.json.write_text(json.dumps(records, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
