"""Leave-one-log-out cross-validation of a front-end setting (judged by the path's error): the likelihood power, the
least hit fraction of a trusted match, or the local map's length.

The front end (:func:`bayesmap.slam.scanmatch.correlative_path`) places each scan at the maximum of
``p S + L``: ``S`` the scan's likelihood-field score, a sum over its beams of ``log(field + floor)``, and ``L`` the
motion model's log-density. Two of its settings are chosen here:

* ``power``, ``p``: at 1 every beam counts as independent evidence, and a scan's hundreds of correlated beams
  outweigh the odometry wherever the field is nearly flat along one direction (a corridor), which is where the front
  end slipped by 0.15-0.44 m (docs/slam.md);
* ``min_hit_fraction``: a scan whose best match puts fewer of its returned endpoints on the local map takes the
  odometry's prediction (:data:`bayesmap.slam.scanmatch.MIN_HIT_FRACTION`; 0 trusts every match);
* ``window``: the meters of travel whose scans make the local map
  (:data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE`; 20 m was tried against the default 10 m and not adopted,
  docs/slam.md, "A longer local map").
* ``consistency_gate``: not the front end's but the loop closure's, the squared norm up to which two loop edges
  count as consistent (:data:`bayesmap.slam.posegraph.CONSISTENCY_GATE`).
* ``loop_window_sigmas``: the loop closure's too, how many standard deviations of a candidate's drift along the
  chain the first round's search window covers (:data:`bayesmap.slam.posegraph.LOOP_WINDOW_SIGMAS`; 0: every
  window +-1.5 m).
* ``step_covariances``: the loop closure's too, 1 to weigh each sequential edge by the front end's step posterior
  (``close_loops(step_cov=...)``, what ``run_log_slam`` does), 0 for every step at
  :data:`bayesmap.slam.posegraph.SEQUENTIAL_STD`. The loop closure's settings reuse one front end per (log, seed,
  scans).
* ``loop_map_travel``: the loop closure's too, the meters of travel on each side of a loop candidate's scan that
  its local map may span (:data:`bayesmap.slam.posegraph.LOOP_MAP_TRAVEL`; ``inf``: ten scans either side however
  far apart).
* ``particles``: how many hypotheses the front end keeps (:data:`bayesmap.slam.pipeline.FRONT_END_PARTICLES`;
  :mod:`bayesmap.slam.particles`).
* ``first_heading_step``, ``first_heading_reach`` and ``second_heading_steps``: the heading lattice of the front
  end's search (:data:`bayesmap.slam.scanmatch.MATCH_LEVELS`): the first level's step (radians, its reach kept), its
  reach (radians either side, its step of 0.04 rad kept) and the second level's half width in its steps of 0.007
  rad.
* ``keyframe_heading_sd``: the composed heading standard deviation (radians) past which a scan between keyframes
  becomes one (:data:`bayesmap.slam.keyframes.KEYFRAME_HEADING_SD`, 0.229; ``inf``, the default here as in
  ``slam --log``: distance and turn alone), for the
  ``keyframes`` scan set.
* ``field_seed``: 1 for the front end's search to descend also from its first level's best fit of the scan alone
  (:data:`bayesmap.slam.scanmatch.FIELD_SEED`), 0 for the best with the motion term alone.
* ``motion_tail``: the weight of the broad component of the front end's motion density
  (:data:`bayesmap.slam.scanmatch.MOTION_TAIL_WEIGHT`; 0: the motion model's Normal alone).

``--noise 1,2`` runs each (log, seed) also with odometry noise twice ``noisy_odometry.py``'s default alphas (1: the
shared logs' noise; ``seeded_logs.seeded_log``); the leave-one-log-out means pool a log's runs over the noise levels.

(A third, the weight of a uniform outlier component in a max-mixture with the motion model, was chosen here at commit
a14f5a3 and removed: docs/slam.md, "Every other scan, and a robust motion term".)

For each log and odometry seed (``seeded_logs.seeded_log``), each kept-scan set of ``--scans`` (``all``, or
``heldout``: every 10th scan dropped, as the held-out map scores do, which is where the front end lost CSAIL's
track; ``every2``: every other scan, steps of about twice the logs' median 0.7-1 m, each step the odometry's two
composed, as ``slam --scans ::2`` takes them; ``every2-log``: the same scans as a log that holds only them, recorded
at half the rate, each step one step of the odometry's net motion; ``keyframes``: every scan's keyframes, as ``slam
--log`` runs them, :func:`bayesmap.slam.keyframes.select_keyframes` at its defaults) and each value of ``--values``,
the script runs the start as ``run_log_slam`` does (the front end, then
:func:`bayesmap.slam.posegraph.close_loops`) with the other settings at their defaults, and records the ATE of the
path after loop closure (meters, after the best rigid 2-D alignment; within 0.003 m of the whole chain's ATE on the
runs where both were measured, docs/slam.md), the front end's alone, its steps off by more than 0.15 m, and its steps
equal to the odometry's (those that followed it).

Then, for each log held out, the value with the lowest mean ATE over the runs of the other logs (a tie, which the
fraction's runs that never take the odometry's step give, goes to the largest value: the most cautious setting the
other logs show no cost for), and the held-out log's mean ATE at that value and at the default. The last line is the
value chosen on every log.

For ``min_hit_fraction`` the values run from the largest down, and a run in which no scan took the odometry's step
stands for the same (log, seed, scans) at every smaller value (no scan's hit fraction fell below the larger one, so
none falls below a smaller one, and the run is the same computation; its records say ``same_run_as``).

Each run is appended to ``--records FILE`` (JSON lines) as soon as it is done, and runs already in the file are not
repeated, so the grid can be split between processes and resumed.

Usage: PYTHONPATH=src python benchmarks/front_end_cv.py --records F
           [--parameter power|min_hit_fraction|window|consistency_gate|particles|loop_window_sigmas|step_covariances|
                        first_heading_step|first_heading_reach|second_heading_steps|keyframe_heading_sd|
                        field_seed|motion_tail|loop_map_travel]
           [--values 1,0.3,0.1,0.03] [--seeds 0-2] [--logs intel,aces,csail] [--scans all,heldout] [--noise 1]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import add_log_seed_options, chosen_logs, seeded_log  # noqa: E402
from slam_error_sources import count_slips  # noqa: E402

from bayesmap.evaluation.heldout import heldout_split  # noqa: E402
from bayesmap.evaluation.trajectory import absolute_trajectory_error  # noqa: E402
from bayesmap.runs.inputs import select_scans  # noqa: E402
from bayesmap.slam import pipeline, posegraph, scanmatch  # noqa: E402
from bayesmap.slam.keyframes import keyframe_problem, select_keyframes  # noqa: E402
from bayesmap.slam.problem import SLAM_LIKELIHOOD_POWER, log_slam_problem  # noqa: E402

DEFAULTS = {"power": SLAM_LIKELIHOOD_POWER, "min_hit_fraction": scanmatch.MIN_HIT_FRACTION,
            "window": scanmatch.LOCAL_MAP_DISTANCE, "consistency_gate": posegraph.CONSISTENCY_GATE,
            "particles": pipeline.FRONT_END_PARTICLES, "loop_window_sigmas": posegraph.LOOP_WINDOW_SIGMAS,
            "first_heading_step": scanmatch.MATCH_LEVELS[0][1],
            "first_heading_reach": scanmatch.MATCH_LEVELS[0][1] * scanmatch.MATCH_LEVELS[0][3],
            "second_heading_steps": scanmatch.MATCH_LEVELS[1][3],
            "step_covariances": 1, "motion_tail": scanmatch.MOTION_TAIL_WEIGHT,
            "keyframe_heading_sd": math.inf, "field_seed": int(scanmatch.FIELD_SEED),
            "loop_map_travel": posegraph.LOOP_MAP_TRAVEL}
"""The settings this script can vary, and the value each takes while the other is varied (the defaults of
:func:`bayesmap.slam.pipeline.front_end`)."""

SCAN_SETS = ("all", "heldout", "every2", "every2-log", "keyframes")
"""``all``: every scan of the log; ``heldout``: the scans the held-out map scores keep (every 10th dropped);
``every2``: every other scan (the odometry through the scans skipped composed into each step,
:func:`bayesmap.slam.problem.log_slam_problem`); ``every2-log``: every other scan as a log of those scans alone (no
odometry between them); ``keyframes``: the keyframes of every scan at the default thresholds (the problem
``slam --log`` runs its front end on, :func:`bayesmap.slam.keyframes.keyframe_problem`)."""


FRONT_ENDS: dict = {}
"""The last front end run (:func:`start_path`), by the log and the front end's settings."""


def start_path(log, truth, scans: str, parameter: str, value: float, name: tuple = ()) -> dict:
    """One run's figures: the start path of ``run_log_slam`` (:func:`bayesmap.slam.pipeline.front_end`, then loop
    closure) for the log's SLAM problem on the scans ``scans`` (:data:`SCAN_SETS`), with the front-end setting
    ``parameter`` at ``value``. The power is passed as the problem's likelihood power, which only the front end
    reads here. ``name`` (the log's name and seed) keys the front end kept for the loop closure's settings."""
    began = time.perf_counter()
    every2 = np.arange(0, len(log), 2)
    kept = {"all": None, "keyframes": None, "heldout": heldout_split(len(log), 10)[0], "every2": every2,
            "every2-log": every2}[scans]
    setting = {**DEFAULTS, parameter: value}
    if scans == "every2-log":
        problem = log_slam_problem(select_scans(log, every2), likelihood_power=setting["power"])
    else:
        problem = log_slam_problem(log, kept, likelihood_power=setting["power"])
    if scans == "keyframes":
        kept = select_keyframes(problem.odometry, step_covs=problem.motion_steps()[1],
                                heading_sd=float(setting["keyframe_heading_sd"]))
        problem = keyframe_problem(problem, kept)
    data = pipeline.scan_data(problem)
    key = (name, scans, *(setting[k] for k in ("power", "min_hit_fraction", "window", "particles",
                                               "first_heading_step", "first_heading_reach", "second_heading_steps",
                                               "motion_tail", "keyframe_heading_sd", "field_seed")))
    if not name or key not in FRONT_ENDS:  # the loop closure's settings share one front end
        FRONT_ENDS.clear()
        FRONT_ENDS[key] = pipeline.front_end(problem, data, min_hit_fraction=setting["min_hit_fraction"],
                                             window=setting["window"], particles=int(setting["particles"]),
                                             levels=search_levels(setting), motion_tail=setting["motion_tail"],
                                             field_seed=bool(setting["field_seed"]))
    matched = FRONT_ENDS[key]
    front = matched.path
    saved = posegraph.LOOP_MAP_TRAVEL
    posegraph.LOOP_MAP_TRAVEL = float(setting["loop_map_travel"])  # read by the loop closure at the call
    try:
        closed, edges, _ = posegraph.close_loops(front, data, consistency_gate=setting["consistency_gate"],
                                                 window_sigmas=setting["loop_window_sigmas"],
                                                 step_cov=matched.step_cov if setting["step_covariances"] else None)
    finally:
        posegraph.LOOP_MAP_TRAVEL = saved
    truth = truth if kept is None else truth[kept]
    return {"parameter": parameter, "value": value, "scans": scans,
            "front_end_ate_m": absolute_trajectory_error(front, truth)["rmse_m"],
            "start_ate_m": absolute_trajectory_error(closed, truth)["rmse_m"], "slips": count_slips(front, truth),
            "odometry_steps": odometry_steps(front, np.asarray(data.increments)),
            "loop_edges": int(len(edges.i) - (len(front) - 1)), "hypotheses": matched.hypotheses,
            "seconds": time.perf_counter() - began}


def search_levels(setting: dict) -> tuple:
    """The front end's search (:data:`bayesmap.slam.scanmatch.MATCH_LEVELS`) with the first level's heading step
    ``first_heading_step`` and reach ``first_heading_reach`` (radians; the half width the nearest whole number of
    steps) and the second level's heading half width ``second_heading_steps`` (in its own steps of 0.007 rad)."""
    (xy, _, w_xy, _, f), (xy2, theta2, w_xy2, _, f2), *rest = scanmatch.MATCH_LEVELS
    step = float(setting["first_heading_step"])
    first = (xy, step, w_xy, int(round(float(setting["first_heading_reach"]) / step)), f)
    return (first, (xy2, theta2, w_xy2, int(setting["second_heading_steps"]), f2), *rest)


def odometry_steps(path, increments, tolerance: float = 1e-4) -> int:
    """How many steps of ``path`` ``(S, 3)`` equal the odometry's increments ``(S - 1, 3)`` to ``tolerance`` (meters
    and radians): the scans that took the odometry's prediction (or whose match landed exactly on it)."""
    steps = posegraph.relative(path[:-1], path[1:])
    return int(np.sum(np.all(np.abs(steps - increments) < tolerance, axis=1)))


def leave_one_log_out(records: list[dict], parameter: str, values: list[float]) -> list[str]:
    """The markdown table of the module docstring from ``records`` (every log's runs at every value of
    ``parameter``)."""
    logs = list(dict.fromkeys(r["log"] for r in records))

    def mean_ate(subset_logs, value):
        ates = [r["start_ate_m"] for r in records if r["log"] in subset_logs and r["value"] == value]
        return float(np.mean(ates)) if ates else float("nan")

    default = DEFAULTS[parameter]
    lines = [f"| held out | {parameter} chosen on the others (their mean ATE, m) | held-out mean ATE at it (m) | "
             f"at {default:g}, the default (m) |", "|---|---|---|---|"]
    for held in logs:
        others = [name for name in logs if name != held]
        chosen = min(values, key=lambda v: (round(mean_ate(others, v), 9), -v))
        lines.append(f"| {held} | {chosen:g} ({mean_ate(others, chosen):.3f}) | {mean_ate([held], chosen):.3f} | "
                     f"{mean_ate([held], default):.3f} |")
    best = min(values, key=lambda v: (round(mean_ate(logs, v), 9), -v))
    lines.append("")
    means = ", ".join(f"{parameter} {v:g}: {mean_ate(logs, v):.3f} m" for v in values)
    lines.append(f"mean ATE over every run: {means}; chosen on every log: {best:g}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_log_seed_options(parser, json_option=False)  # the runs are in --records
    parser.add_argument("--parameter", choices=sorted(DEFAULTS), default="power", help="the setting to choose")
    parser.add_argument("--values", default="1,0.3,0.1,0.03", help="comma-separated values of the setting")
    parser.add_argument("--scans", default="all", help=f"comma-separated subset of {','.join(SCAN_SETS)}")
    parser.add_argument("--records", type=Path, required=True, help="JSON lines file of the runs (appended to)")
    parser.add_argument("--noise", default="1", help="odometry noise levels, multiples of noisy_odometry.py's alphas")
    args = parser.parse_args(argv)
    logs, seeds = chosen_logs(parser, args.logs), parse_seeds(args.seeds)
    try:
        values = [float(v) for v in args.values.split(",")]
    except ValueError:
        parser.error(f"--values must be numbers, got {args.values!r}")
    try:
        noises = [float(v) for v in args.noise.split(",")]
    except ValueError:
        parser.error(f"--noise must be numbers, got {args.noise!r}")
    if not noises or not all(v > 0 for v in noises):
        parser.error(f"--noise must be numbers > 0, got {args.noise!r}")
    scan_sets = [s.strip() for s in args.scans.split(",") if s.strip()]
    if not scan_sets or set(scan_sets) - set(SCAN_SETS):
        parser.error(f"--scans must be a subset of {','.join(SCAN_SETS)}, got {args.scans!r}")
    done = ([json.loads(line) for line in args.records.read_text().splitlines() if line.strip()]
            if args.records.exists() else [])
    have = {(r["log"], r["seed"], r.get("noise", 1.0), r["scans"], r["parameter"], r["value"]) for r in done}
    for name, seed, noise in ((n, s, v) for n in logs for s in seeds for v in noises):
        todo = [(s, v) for s in scan_sets for v in values
                if (name, seed, noise, s, args.parameter, v) not in have]
        if not todo:
            continue
        log, truth = seeded_log(name, seed, noise)
        if args.parameter == "min_hit_fraction":  # largest first, so that a run can stand for the smaller ones
            todo.sort(key=lambda item: (item[0], -item[1]))
        for scans, value in todo:
            if (name, seed, noise, scans, args.parameter, value) in have:
                continue
            figures = start_path(log, truth, scans, args.parameter, value, (name, seed, noise))
            record = {"log": name, "seed": seed, "noise": noise, **figures}
            records = [record]
            if args.parameter == "min_hit_fraction" and record["odometry_steps"] == 0:
                # no scan fell below this fraction, so none falls below a smaller one: the same run
                records += [{**record, "value": v, "same_run_as": value}
                            for s, v in todo if s == scans and v < value]
            for record in records:
                print(json.dumps(record), flush=True)
                with args.records.open("a") as out:
                    out.write(json.dumps(record) + "\n")
                done.append(record)
                have.add((name, seed, noise, scans, args.parameter, record["value"]))
    chosen = [r for r in done if r["log"] in logs and r["seed"] in seeds and r["scans"] in scan_sets
              and r.get("noise", 1.0) in noises and r["parameter"] == args.parameter and r["value"] in values]
    print("\n".join(leave_one_log_out(chosen, args.parameter, values)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
