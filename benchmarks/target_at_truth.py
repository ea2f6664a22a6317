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
* scores each (path, walls) by the target's log-density: the motion model's (:func:`bayesmap.model.motion.
  path_logpdf`), the prior's and ``p`` times the readings' (:meth:`bayesmap.problem.Problem.table_log_joint` less
  the prior).

A row: the start path's ATE (m), the target at the truth less at the start path (nats; the mean over the chains,
and its smallest and largest), and that difference's parts: the motion model's and ``p`` times the readings'. The
walls are one draw, not the posterior's marginal over maps, so the chains' spread says how far one draw's score
carries.

Usage: PYTHONPATH=src:benchmarks python benchmarks/target_at_truth.py [--logs csail] [--seeds 0] [--scans every2]
                                                                       [--sweeps 20] [--chains 2] [--json F]
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import table_main  # noqa: E402

from bayesmap.errors import BayesmapError  # noqa: E402
from bayesmap.evaluation.trajectory import absolute_trajectory_error  # noqa: E402
from bayesmap.inference.tiled import tiled_map_chain  # noqa: E402
from bayesmap.io.rosbag import compose_poses  # noqa: E402
from bayesmap.model.motion import path_logpdf  # noqa: E402
from bayesmap.model.prior import log_prior  # noqa: E402
from bayesmap.problem import Problem  # noqa: E402
from bayesmap.slam import pipeline, posegraph  # noqa: E402
from bayesmap.slam.problem import log_slam_problem  # noqa: E402


def in_model_frame(truth, first_pose) -> np.ndarray:
    """``(S, 3)``: the true path ``truth`` ``(S, 3)`` moved rigidly so that its first pose is ``first_pose``, the
    headings unwrapped (the model's heading is a real number)."""
    truth = np.asarray(truth, np.float64)
    moved = compose_poses(np.asarray(first_pose, np.float64), posegraph.relative(truth[0], truth))
    moved[:, 2] = first_pose[2] + np.unwrap(truth[:, 2]) - truth[0, 2]
    return moved


def target_log_density(problem, params, path, walls) -> tuple[float, float, float]:
    """``(target, motion, p readings)``: the target's log-density (nats) at ``path`` ``(S, 3)`` and ``walls``
    ``(nx, ny)`` on ``params``' grid: the motion model's log-density of the path, the prior's of the walls and the
    problem's power ``p`` times the readings' (at ``p = 1``, the SLAM model's ``assess``)."""
    path = np.array(path, np.float64)
    path[:, 2] = np.unwrap(path[:, 2])
    increments, covs = problem.motion_steps()
    motion = float(path_logpdf(jnp.asarray(path), jnp.asarray(path[0]), jnp.asarray(increments), jnp.asarray(covs)))
    walls = np.asarray(walls)
    prior = float(log_prior(walls, params.prior_wall_prob, params.coupling))
    angles = path[:, 2:3] + problem.sensor_angles
    joint = Problem.from_world_frame(params, path[:, :2], angles, problem.readings).table_log_joint(walls)
    readings = problem.likelihood_power * (joint - prior)
    return motion + prior + readings, motion, readings


def drawn_walls(problem, params, path, key, sweeps: int) -> np.ndarray:
    """``(nx, ny)`` walls drawn by ``sweeps`` cellwise sweeps from an empty map at ``path`` ``(S, 3)`` with the chain's
    map model (``params``' grid, the problem's power)."""
    path = np.asarray(path, np.float64)
    angles = path[:, 2:3] + problem.sensor_angles
    origins = np.repeat(path[:, :2], angles.shape[1], axis=0)
    chain = tiled_map_chain(key, params, origins, angles.reshape(-1), problem.readings.reshape(-1),
                            jnp.zeros(params.grid.shape, jnp.float32), sweeps, problem.likelihood_power)
    return np.asarray(chain.walls)


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
    rows = []
    for c in range(chains):
        at_truth = target_log_density(problem, params, true_path,
                                      drawn_walls(problem, params, true_path, jax.random.key(c), sweeps))
        at_start = target_log_density(problem, params, start, drawn_walls(problem, params, start, jax.random.key(c),
                                                                          sweeps))
        rows.append([a - b for a, b in zip(at_truth, at_start)])
    rows = np.array(rows)
    return {"scans": scans, "start_ate_m": absolute_trajectory_error(start, truth)["rmse_m"],
            "target_gap": rows[:, 0].tolist(), "motion_gap": float(rows[0, 1]), "readings_gap": rows[:, 2].tolist(),
            "sweeps": sweeps, "power": float(problem.likelihood_power)}


def table_row(name: str, seed: int, row: dict) -> str:
    gap, readings = np.array(row["target_gap"]), np.array(row["readings_gap"])
    return (f"| {name} | {seed} | {row['scans']} | {row['start_ate_m']:.3f} | {gap.mean():+.0f} ({gap.min():+.0f} to "
            f"{gap.max():+.0f}) | {row['motion_gap']:+.1f} | {readings.mean():+.0f} |")


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
        "| log | seed | scans | start ATE (m) | target at the truth less at the start path (nats; chains' range) | "
        "motion part | readings part (times p) |\n|---|---|---|---|---|---|---|",
        add_options, score_of, table_row, parse_seeds)


if __name__ == "__main__":
    sys.exit(main())
