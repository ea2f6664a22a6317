"""Where a real-log SLAM path's error comes from: the front end, the loop edges or the graph (docs/slam.md).

For each log and odometry seed (``seeded_logs.seeded_log``: the real scans, odometry from ``noisy_odometry.py``), the
script runs bayesmap's start (:func:`bayesmap.slam.pipeline.front_end`, then
:func:`bayesmap.slam.posegraph.close_loops`) and prints one row of ATEs (meters, after the best rigid 2-D
alignment):

* ``front end`` and ``loop closure``: the two stages as bayesmap runs them (the joint chain after them moves the ATE
  by a few millimeters on the runs measured, docs/slam.md);
* ``true loops``: the same graph with every kept loop edge replaced by the true relative pose (do the loop edges
  limit the path?);
* ``true steps``: the graph with the sequential edges replaced by the true relative poses, the measured loop edges
  kept (do the front end's steps limit it?);
* the loop edges' median error against the truth (m, m, rad) and the number of sequential steps off by more than
  ``--slip`` meters.

``--reading-scale F`` multiplies every range reading by ``F`` first: with ``F`` a few 1e-7 from 1 (less than a
micrometre) it shows how far the start path moves when float32 rounding breaks one near-tie of the search otherwise
(docs/validation/slam.md).

Usage: PYTHONPATH=src python benchmarks/slam_error_sources.py [--logs csail] [--seeds 4] [--slip 0.15]
                                                             [--reading-scale 1.0000003] [--json F]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import table_main  # noqa: E402

from bayesmap.evaluation.trajectory import absolute_trajectory_error  # noqa: E402
from bayesmap.model.motion import wrap_angle  # noqa: E402
from bayesmap.slam import pipeline, posegraph  # noqa: E402
from bayesmap.slam.problem import log_slam_problem  # noqa: E402

SLIP = 0.15
"""Meters: a sequential step of the front end off the true relative pose by more is a slip (``--slip``'s default)."""


def count_slips(path, truth, slip: float = SLIP) -> int:
    """How many consecutive steps of ``path`` ``(S, 3)`` are off the true relative pose (``truth`` ``(S, 3)``) by
    more than ``slip`` meters of position."""
    step_error = posegraph.relative(path[:-1], path[1:]) - posegraph.relative(truth[:-1], truth[1:])
    return int(np.sum(np.hypot(step_error[:, 0], step_error[:, 1]) > slip))


def error_sources(log, truth, slip: float, reading_scale: float = 1.0) -> dict:
    """The row of the module docstring for one SLAM problem: ``log`` a CARMEN log whose poses are odometry,
    ``truth`` ``(S, 3)`` its true poses; the scans' readings times ``reading_scale``."""
    problem = log_slam_problem(log)
    scans = pipeline.scan_data(problem)
    scans = scans._replace(readings=np.asarray(scans.readings) * reading_scale)
    matched = pipeline.front_end(problem, scans)
    front = matched.path
    closed, edges, _ = posegraph.close_loops(front, scans, step_cov=matched.step_cov)
    loop = np.arange(len(edges.i)) >= len(front) - 1  # close_loops puts the sequential edges first
    sequential = edges.take(~loop)
    loops = edges.take(loop)
    true_loops = loops._replace(z=posegraph.relative(truth[loops.i], truth[loops.j]))
    true_steps = sequential._replace(z=posegraph.relative(truth[:-1], truth[1:]))
    loop_error = loops.z - true_loops.z
    loop_error[:, 2] = wrap_angle(loop_error[:, 2])

    def ate(path):
        return absolute_trajectory_error(path, truth)["rmse_m"]

    return {
        "front_end_ate_m": ate(front),
        "loop_closure_ate_m": ate(closed),
        "true_loops_ate_m": ate(posegraph.optimize_pose_graph(front, posegraph.concat_edges(sequential, true_loops))),
        "true_steps_ate_m": ate(posegraph.optimize_pose_graph(front, posegraph.concat_edges(true_steps, loops))),
        "loop_edges": int(loop.sum()),
        "loop_edge_median_error": np.median(np.abs(loop_error), axis=0).tolist() if loop.any() else None,
        "slips": count_slips(front, truth, slip),  # the sequential edges are the front end's relative poses
        "steps": len(front) - 1,
    }


def table_row(name: str, seed: int, row: dict) -> str:
    """The markdown row of one run's :func:`error_sources`."""
    median = ("-" if row["loop_edge_median_error"] is None
              else ", ".join(f"{v:.3f}" for v in row["loop_edge_median_error"]))
    return (f"| {name} | {seed} | {row['front_end_ate_m']:.3f} | {row['loop_closure_ate_m']:.3f} | "
            f"{row['true_loops_ate_m']:.3f} | {row['true_steps_ate_m']:.3f} | {row['loop_edges']} | {median} | "
            f"{row['slips']} / {row['steps']} |")


def main(argv: list[str] | None = None) -> int:
    return table_main(
        argv, __doc__.splitlines()[0],
        "| log | seed | front end | loop closure | true loops | true steps | loop edges | loop edge median error "
        "(m, m, rad) | slips / steps |\n|---|---|---|---|---|---|---|---|---|",
        add_options,
        lambda args: lambda log, truth: error_sources(log, truth, args.slip, args.reading_scale), table_row,
        parse_seeds)


def add_options(parser) -> None:
    parser.add_argument("--slip", type=float, default=SLIP, help=f"meters: a step off by more is a slip ({SLIP})")
    parser.add_argument("--reading-scale", type=float, default=1.0,
                        help="multiply every range reading by this first (1: the log as it is)")


if __name__ == "__main__":
    sys.exit(main())
