"""The path's uncertainty without a factor fitted on truth, measured: each sequential edge's covariance from the front
end's own step posterior, then the pose graph's Laplace covariance (an experiment, not what bayesmap reports).

For each log and odometry seed (``seeded_logs.seeded_log``), the script runs bayesmap's start
(:func:`bayesmap.slam.pipeline.front_end`, then :func:`bayesmap.slam.posegraph.close_loops`). For each scan ``t``
from ``--neighbours`` on, it scores the candidates of a lattice around the front end's pose of ``t`` (+-0.4 m in
0.02 m steps, +-0.12 rad in 0.006 rad steps) as the front end does, ``p * S + L``: ``S`` the scan's likelihood-field
score against the local map of the ``--neighbours`` scans before it at their front-end poses
(:func:`bayesmap.slam.scanmatch.lattice_scores`, interpolated), ``p`` the problem's likelihood power, ``L`` the motion
model's log-density from the front end's pose of ``t - 1``; normalized over the lattice, the candidates' covariance
is the step's posterior covariance, turned into the frame of pose ``t - 1`` (the sequential edge's frame; the first
scans keep :data:`bayesmap.slam.posegraph.SEQUENTIAL_STD`). The graph of these sequential covariances and the loop
edges (:data:`bayesmap.slam.posegraph.LOOP_STD`) at the loop-closed path gives ``H^-1`` (dense); the row printed is
the coverage of its 95 % ellipses at that path against the truth, beside the coverage of the graph's covariance at
unit edge deviations times :data:`bayesmap.slam.pipeline.GRAPH_COV_SCALE` squared (what bayesmap reports, less the
chain's millimetre spread), and the steps' median and 90th-percentile position standard deviation (m).

Usage: PYTHONPATH=src python benchmarks/step_covariance.py [--logs aces] [--seeds 0] [--neighbours 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import chosen_logs, seeded_log  # noqa: E402

from bayesmap.evaluation.trajectory import absolute_trajectory_error, ellipse_coverage  # noqa: E402
from bayesmap.model.motion import motion_logpdf  # noqa: E402
from bayesmap.slam import pipeline, posegraph  # noqa: E402
from bayesmap.slam.problem import log_slam_problem  # noqa: E402
from bayesmap.slam.scanmatch import add_to_fields, empty_fields, lattice_scores  # noqa: E402

XY_HALF, XY_STEP, THETA_HALF, THETA_STEP = 0.4, 0.02, 0.12, 0.006
"""The lattice of each step's posterior: meters and radians."""


def lattice() -> tuple[jax.Array, jax.Array]:
    """``(xy (A, 2), theta (B,))`` offsets of the step lattice."""
    r = np.arange(-round(XY_HALF / XY_STEP), round(XY_HALF / XY_STEP) + 1) * XY_STEP
    xy = np.stack(np.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)
    return jnp.asarray(xy), jnp.asarray(np.arange(-round(THETA_HALF / THETA_STEP), round(THETA_HALF / THETA_STEP) + 1)
                                        * THETA_STEP)


def step_posterior(grid, xy, theta, local_poses, neighbour_scans, center, prev, increment, cov, scan, power):
    """The mean ``(3,)`` and covariance ``(3, 3)`` of the front end's score ``power * S + L`` normalized over the
    lattice ``center + (xy, theta)`` (world frame shifted to the local map's center)."""
    fields = add_to_fields(empty_fields(grid), grid, local_poses, *neighbour_scans)
    scores = lattice_scores(fields[0], grid, center, xy, theta, *scan, interpolate=True)
    cands = jnp.concatenate([jnp.repeat(center[:2] + xy, len(theta), axis=0),
                             jnp.tile(center[2] + theta, len(xy))[:, None]], axis=1)
    weights = jax.nn.softmax(power * scores + motion_logpdf(prev, cands, increment, cov))
    mean = weights @ cands
    return mean, jnp.einsum("n,ni,nj->ij", weights, cands - mean, cands - mean)


def run(name: str, seed: int, neighbours: int) -> str:
    """One row of the table (module docstring)."""
    began = time.perf_counter()
    log, truth = seeded_log(name, seed)
    problem = log_slam_problem(log)
    data = pipeline.scan_data(problem)
    front = pipeline.front_end(problem, data)
    path, edges, _ = posegraph.close_loops(front, data)
    grid, (xy, theta) = posegraph.local_map_grid(), lattice()
    posterior = jax.jit(step_posterior, static_argnums=0)
    angles, readings, returned = (np.asarray(a) for a in (data.sensor_angles, data.readings, data.returned))
    increments, covs = np.asarray(data.increments), np.asarray(data.covs)
    count = len(front)
    sequential = np.tile(np.diag(np.square(posegraph.SEQUENTIAL_STD)), (count - 1, 1, 1))
    for t in range(neighbours, count):
        near = np.arange(t - neighbours, t)
        shift = np.array([front[t, 0], front[t, 1], 0.0])
        _, cov = posterior(grid, xy, theta, jnp.asarray(front[near] - shift),
                           (jnp.asarray(angles[near]), jnp.asarray(readings[near]), jnp.asarray(returned[near])),
                           jnp.asarray(front[t] - shift), jnp.asarray(front[t - 1] - shift),
                           jnp.asarray(increments[t - 1]), jnp.asarray(covs[t - 1]),
                           (jnp.asarray(angles[t]), jnp.asarray(readings[t]), jnp.asarray(returned[t])),
                           problem.likelihood_power)
        c, s = np.cos(front[t - 1, 2]), np.sin(front[t - 1, 2])
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        sequential[t - 1] = turn.T @ np.asarray(cov, np.float64) @ turn
    first, second = posegraph.edge_jacobians(path, edges._replace(std=np.ones_like(edges.std)))
    information = np.concatenate([np.linalg.inv(sequential),
                                  np.array([np.diag(1 / np.square(s)) for s in edges.std[count - 1:]])])
    h = np.zeros((3 * (count - 1), 3 * (count - 1)))
    for e in range(len(edges.i)):
        for a, ja in ((edges.i[e], first[e]), (edges.j[e], second[e])):
            for b, jb in ((edges.i[e], first[e]), (edges.j[e], second[e])):
                if a > 0 and b > 0:
                    h[3 * (a - 1):3 * a, 3 * (b - 1):3 * b] += ja.T @ information[e] @ jb
    inverse = np.linalg.inv(h)
    inverse = (inverse + inverse.T) / 2
    cov = np.zeros((count, 3, 3))
    for k in range(1, count):
        cov[k] = inverse[3 * (k - 1):3 * k, 3 * (k - 1):3 * k]
    sd = np.sqrt(sequential[:, [0, 1], [0, 1]])
    scaled = pipeline.GRAPH_COV_SCALE**2 * posegraph.marginal_covariances(path, edges)
    return (f"| {name} | {seed} | {absolute_trajectory_error(path, truth)['rmse_m']:.3f} | "
            f"{ellipse_coverage(path, cov, truth):.3f} | {ellipse_coverage(path, scaled, truth):.3f} | "
            f"{np.median(sd):.4f} | {np.percentile(sd, 90):.4f} | {time.perf_counter() - began:.0f} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="aces")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--neighbours", type=int, default=5, help="scans before t in its local map")
    args = parser.parse_args(argv)
    print("| log | seed | start ATE m | coverage, step posteriors | coverage, scaled graph | step sd median m | "
          "p90 m | s |")
    print("|---|---|---|---|---|---|---|---|")
    for name in chosen_logs(parser, args.logs):
        for seed in parse_seeds(args.seeds):
            print(run(name, seed, args.neighbours), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
