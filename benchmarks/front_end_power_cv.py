"""Leave-one-log-out cross-validation of the front end's likelihood power (issue 15: the path's error).

The front end (:func:`bayesmap.inference.scanmatch.correlative_path`) places each scan at the maximum of
``p S + L``: ``S`` the scan's likelihood-field score, a sum over its beams, and ``L`` the motion model's
log-density. At ``p = 1`` every beam counts as independent evidence, and a scan's hundreds of correlated beams
outweigh the odometry wherever the field is nearly flat along one direction (a corridor), which is where the front
end slipped by 0.15-0.44 m (docs/slam.md). For each log and odometry seed (``seeded_logs.seeded_log``) and each
power of ``--powers`` the script runs the start as ``run_log_slam`` does (the front end, then
:func:`bayesmap.inference.posegraph.close_loops`) and records the ATE of the path after loop closure (meters, after
the best rigid 2-D alignment; within 0.003 m of the whole chain's ATE on the runs where both were measured,
docs/slam.md), the front end's alone, and its steps off by more than 0.15 m.

Then, for each log held out, the power with the lowest mean ATE over the runs of the other logs, and the held-out
log's mean ATE at that power, at 1 and at the default (:data:`bayesmap.scenes.SLAM_LIKELIHOOD_POWER`, which
``logslam.front_end`` uses: the target's own power). The last line is the power chosen on every log.

Each run is appended to ``--records FILE`` (JSON lines) as soon as it is done, and runs already in the file are not
repeated, so the grid can be split between processes and resumed.

Usage: PYTHONPATH=src python benchmarks/front_end_power_cv.py --records F [--seeds 0-2] [--logs intel,aces,csail]
                                                             [--powers 1,0.3,0.1,0.03]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import add_log_seed_options, chosen_logs, seeded_log  # noqa: E402
from slam_error_sources import count_slips  # noqa: E402

from bayesmap import scenes  # noqa: E402
from bayesmap.evaluation.trajectory import absolute_trajectory_error  # noqa: E402
from bayesmap.inference import logslam, posegraph  # noqa: E402


def start_path(log, truth, power: float) -> dict:
    """One run's figures: the start path of ``run_log_slam`` (:func:`bayesmap.inference.logslam.front_end`, then
    loop closure) for the log's SLAM problem at likelihood power ``power``, which only the front end reads here."""
    began = time.perf_counter()
    problem = scenes.log_slam_problem(log, likelihood_power=power)
    scans = logslam.scan_data(problem)
    front = logslam.front_end(problem, scans)
    closed, edges = posegraph.close_loops(front, scans)
    return {"power": power, "front_end_ate_m": absolute_trajectory_error(front, truth)["rmse_m"],
            "start_ate_m": absolute_trajectory_error(closed, truth)["rmse_m"], "slips": count_slips(front, truth),
            "loop_edges": int(len(edges.i) - (len(front) - 1)), "seconds": time.perf_counter() - began}


def leave_one_log_out(records: list[dict], powers: list[float]) -> list[str]:
    """The markdown table of the module docstring from ``records`` (every log's runs at every power)."""
    logs = list(dict.fromkeys(r["log"] for r in records))

    def mean_ate(subset_logs, power):
        ates = [r["start_ate_m"] for r in records if r["log"] in subset_logs and r["power"] == power]
        return float(np.mean(ates)) if ates else float("nan")

    default = scenes.SLAM_LIKELIHOOD_POWER
    lines = ["| held out | power chosen on the others (their mean ATE, m) | held-out mean ATE at it (m) | at 1 (m) | "
             f"at {default:g}, the default (m) |", "|---|---|---|---|---|"]
    for held in logs:
        others = [name for name in logs if name != held]
        chosen = min(powers, key=lambda p: mean_ate(others, p))
        lines.append(f"| {held} | {chosen:g} ({mean_ate(others, chosen):.3f}) | {mean_ate([held], chosen):.3f} | "
                     f"{mean_ate([held], 1.0):.3f} | {mean_ate([held], default):.3f} |")
    best = min(powers, key=lambda p: mean_ate(logs, p))
    lines.append("")
    lines.append("mean ATE over every run: " + ", ".join(f"power {p:g}: {mean_ate(logs, p):.3f} m" for p in powers)
                 + f"; chosen on every log: {best:g}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_log_seed_options(parser, json_option=False)  # the runs are in --records
    parser.add_argument("--powers", default="1,0.3,0.1,0.03", help="comma-separated powers in (0, 1]")
    parser.add_argument("--records", type=Path, required=True, help="JSON lines file of the runs (appended to)")
    args = parser.parse_args(argv)
    logs, seeds = chosen_logs(parser, args.logs), parse_seeds(args.seeds)
    try:
        powers = [float(p) for p in args.powers.split(",")]
    except ValueError:
        parser.error(f"--powers must be numbers, got {args.powers!r}")
    done = ([json.loads(line) for line in args.records.read_text().splitlines() if line.strip()]
            if args.records.exists() else [])
    have = {(r["log"], r["seed"], r["power"]) for r in done}
    for name in logs:
        for seed in seeds:
            todo = [p for p in powers if (name, seed, p) not in have]
            if not todo:
                continue
            log, truth = seeded_log(name, seed)
            for power in todo:
                record = {"log": name, "seed": seed, **start_path(log, truth, power)}
                print(json.dumps(record), flush=True)
                with args.records.open("a") as out:
                    out.write(json.dumps(record) + "\n")
                done.append(record)
    chosen = [r for r in done if r["log"] in logs and r["seed"] in seeds and r["power"] in powers]
    print("\n".join(leave_one_log_out(chosen, powers)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
