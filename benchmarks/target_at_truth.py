"""Does the SLAM target prefer the true path to bayesmap's? The target's density at both, with the map drawn at each.

``bayesmap slam --log`` targets the SLAM model's posterior at the log's likelihood power ``p`` (docs/slam.md):
``log p(x | u) + log p(w) + p log p(y | w, x)``. Its path starts at the front end and loop closure (the start path),
and the chain moves it by millimeters (docs/validation/slam.md). Where the start path is decimeters off, is that the
target's own preference (the model), or a better path the search did not find (the inference)? For each log and
odometry seed (``seeded_logs.seeded_log``) on the scans ``--scans`` (``all``, or ``every2`` as ``slam --scans ::2``
takes them), the script:

* runs the start (:func:`bayesmap.slam.pipeline.front_end`, :func:`bayesmap.slam.posegraph.close_loops`);
* carries the true path into the model's frame (its first pose on the fixed first pose);
* at each path, draws the walls by ``--sweeps`` cellwise sweeps from an empty map with the chain's map model
  (:func:`bayesmap.inference.tiled.tiled_map_chain`, the problem's parameters on a grid fitted to the start path
  with 1 m more margin, at the power ``p``), ``--chains`` times with different keys;
* scores each (path, walls) by the target's log-density (:func:`bayesmap.slam.evidence.target_log_density`: the
  motion model's, the prior's and ``p`` times the readings') and by the bound with the walls integrated out
  (:func:`bayesmap.slam.evidence.map_entropy_bound`).

A row: the start path's ATE (m); at the truth less at the start path (nats), the lower bound of
:func:`bayesmap.slam.evidence.map_entropy_bound` (the walls integrated out under independent cells at the chain's
wall probabilities; the mean over the chains, and its smallest and largest), one draw's joint density (the mean),
and the draw's parts: the motion model's and ``p`` times the readings'. One draw's density alone does not weigh two
paths: a path whose map is less certain draws a map of lower density, which the map's entropy makes up for
(docs/validation/slam.md, "The target's own preference").

Usage: PYTHONPATH=src:benchmarks python benchmarks/target_at_truth.py [--logs csail] [--seeds 0] [--scans every2]
                                                                       [--sweeps 20] [--chains 2] [--json F]
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import table_main  # noqa: E402

from bayesmap.errors import BayesmapError  # noqa: E402
from bayesmap.evaluation.trajectory import absolute_trajectory_error  # noqa: E402
from bayesmap.io.rosbag import compose_poses  # noqa: E402
from bayesmap.slam import pipeline, posegraph  # noqa: E402
from bayesmap.slam.evidence import drawn_walls, map_entropy_bound, target_log_density  # noqa: E402
from bayesmap.slam.problem import log_slam_problem  # noqa: E402


def in_model_frame(truth, first_pose) -> np.ndarray:
    """``(S, 3)``: the true path ``truth`` ``(S, 3)`` moved rigidly so that its first pose is ``first_pose``, the
    headings unwrapped (the model's heading is a real number)."""
    truth = np.asarray(truth, np.float64)
    moved = compose_poses(np.asarray(first_pose, np.float64), posegraph.relative(truth[0], truth))
    moved[:, 2] = first_pose[2] + np.unwrap(truth[:, 2]) - truth[0, 2]
    return moved


def target_at_truth(log, truth, scans: str, sweeps: int, chains: int) -> dict:
    """One row's figures (module docstring) for a log whose poses are odometry and its true poses ``truth``."""
    kept = np.arange(0, len(log), 2) if scans == "every2" else None
    problem = log_slam_problem(log, kept)
    truth = np.asarray(truth, np.float64) if kept is None else np.asarray(truth, np.float64)[kept]
    data = pipeline.scan_data(problem)
    front = pipeline.front_end(problem, data)
    start, _, _ = posegraph.close_loops(front.path, data, step_cov=front.step_cov)
    grid = pipeline.fitted_grid(data, start, problem.params.grid.resolution, margin=pipeline.MAP_MARGIN + 1.0)
    params = pipeline.with_grid(problem.params, grid)
    true_path = in_model_frame(truth, start[0])
    if params.coupling:
        raise BayesmapError("the bound assumes the independent prior of the chain's map model")
    rows = []
    for c in range(chains):
        row = []
        for path in (true_path, start):
            walls, probabilities = drawn_walls(problem, params, path, jax.random.key(c), sweeps)
            target, motion, readings = target_log_density(problem, params, path, walls)
            row.append((map_entropy_bound(params, probabilities, target, walls), target, motion, readings))
        rows.append([a - b for a, b in zip(*row)])
    rows = np.array(rows)
    return {"scans": scans, "start_ate_m": absolute_trajectory_error(start, truth)["rmse_m"],
            "bound_gap": rows[:, 0].tolist(), "target_gap": rows[:, 1].tolist(), "motion_gap": float(rows[0, 2]),
            "readings_gap": rows[:, 3].tolist(), "sweeps": sweeps, "power": float(problem.likelihood_power)}


def table_row(name: str, seed: int, row: dict) -> str:
    bound, gap, readings = (np.array(row[k]) for k in ("bound_gap", "target_gap", "readings_gap"))
    return (f"| {name} | {seed} | {row['scans']} | {row['start_ate_m']:.3f} | {bound.mean():+.0f} "
            f"({bound.min():+.0f} to {bound.max():+.0f}) | {gap.mean():+.0f} | {row['motion_gap']:+.1f} | "
            f"{readings.mean():+.0f} |")


def add_options(parser) -> None:
    parser.add_argument("--scans", default="all", choices=("all", "every2"), help="every scan, or every other")
    parser.add_argument("--sweeps", type=int, default=20, help="cellwise sweeps of each map draw (20)")
    parser.add_argument("--chains", type=int, default=2, help="map draws at each path, each its own key (2)")


def main(argv: list[str] | None = None) -> int:
    def score_of(args):
        if args.sweeps < 1 or args.chains < 1:
            raise BayesmapError(f"--sweeps and --chains must be >= 1, got {args.sweeps} and {args.chains}")
        return lambda log, truth: target_at_truth(log, truth, args.scans, args.sweeps, args.chains)

    return table_main(
        argv, __doc__.splitlines()[0],
        "| log | seed | scans | start ATE (m) | bound at the truth less at the start path (nats; the draws' range) | "
        "one draw's target, the same | motion part | readings part (times p) |\n|---|---|---|---|---|---|---|---|",
        add_options, score_of, table_row, parse_seeds)


if __name__ == "__main__":
    sys.exit(main())
