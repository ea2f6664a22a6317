"""The path's uncertainty from the front end's step posteriors, at the start path: a quick check of the ellipses'
calibration (minutes per run, where ``pose_cov_cv.py`` runs the whole chain).

For each log, odometry seed (``seeded_logs.seeded_log``) and scan set (``all``, or ``every2``: every other scan),
the script runs bayesmap's start as :func:`bayesmap.slam.pipeline.run_log_slam` does (the front end, which returns
each step's posterior covariance, :func:`bayesmap.slam.scanmatch.step_posterior`; then
:func:`bayesmap.slam.posegraph.close_loops` with them), and prints the start path's ATE, the 95 % coverage of the
pose graph's Laplace covariance with those step covariances (what stage 5 reports less the chain's millimetre
spread) at the start path against the truth, the same for the graph's loop edges and every step at its fixed
deviations (:data:`bayesmap.slam.posegraph.SEQUENTIAL_STD`) times 0.36 (the retired ``GRAPH_COV_SCALE``, a factor
fitted on truth), the graph's variance of unit weight ``s0^2`` (the sum of its squared whitened residuals at the
closed path over its redundancy, three per loop edge: Förstner & Wrobel 2016, *Photogrammetric Computer Vision*,
sec. 4.2.3; a scale estimated from the graph's own consistency, not from truth) and the coverage with the covariance
times it, the front end's steps against the true steps (the root mean square of each component's error over that of
its posterior standard deviation: 1 for calibrated step posteriors; then the steps whose heading error exceeds
:data:`FAR` standard deviations, and the same ratios without them), the steps' median and 90th-percentile
position standard deviation (m) and the front end's seconds.

With ``--aligned``, one more column: the coverage of the same graph's covariance with the rigid motion of the whole
path aligned out (:func:`aligned_covariances`: the covariance in the gauge of the ATE's alignment, which the coverage
applies to the truth, instead of relative to the fixed first pose).

With ``--step-power W``, one more column: the coverage with every step's covariance times ``P / W``, ``P`` the front
end's likelihood power (the problem's, :data:`bayesmap.slam.problem.SLAM_LIKELIHOOD_POWER`): the steps' posteriors
at power ``W`` where the scan, not the motion model, sets them (a quick look at another power, such as one from
``beam_correlation.py``; the path and the loop edges stay those of power ``P``). ``--step-power beams``: each step's
covariance times ``P / w_t``, ``w_t`` its scan's own magnitude adjustment at the beams' automatic bandwidth
(``beam_correlation.py``'s ``scan_adjustments``, at most 1; ``P`` where the beams' gradients are degenerate).

With ``--local-maps``, three more columns: the coverage with each step's scan information tied to the scans of its
local map (:class:`bayesmap.slam.posegraph.LocalMaps`, :func:`bayesmap.slam.scanmatch.local_map_shares`), the
median position standard deviation (m) of that graph's covariance against the plain graph's, and the coverage with
the loop edges' covariances their matches' posteriors as well (:func:`bayesmap.slam.posegraph.loop_posteriors`; what
``slam --log`` reports).

With ``--self-coverage`` (and ``--local-maps``), five more columns: what a calibrated posterior would score.
:data:`SELF_DRAWS` paths are drawn from a graph's Laplace approximation
(:func:`bayesmap.slam.posegraph.sample_deviations`), each put in the truth's place and scored against that graph's
ellipses by the same coverage (:func:`bayesmap.evaluation.trajectory.coverage_rank`). First the rank of the truth's
coverage among them (the fraction of draws scoring less, ties counted half; uniform over runs for a calibrated
posterior) for three graphs:
the step posteriors' (the second column's), the steps tied to their local maps, and the loop edges' posteriors as
well (what ``slam --log`` reports); then, for the last, the median and 5-95 % range of the draws' coverages and the
fraction of them inside 85-99 %.

With ``--first-pose``, one more column per covariance above (the reported one, and the one at ``--step-power``
where given): the coverage in the model's own gauge, the truth placed by its first pose on the path's first pose
(which the model holds fixed; :func:`first_pose_coverage`) instead of by the best rigid alignment.

Usage: PYTHONPATH=src python benchmarks/step_covariance.py [--logs aces] [--seeds 0] [--scans all,every2]
    [--step-power W|beams] [--aligned] [--first-pose] [--local-maps [--self-coverage]]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from beam_correlation import BANDWIDTHS, scan_adjustments  # noqa: E402
from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import scan_set_problem, scan_set_runs  # noqa: E402
from target_at_truth import in_model_frame  # noqa: E402

from bayesmap.evaluation.trajectory import (  # noqa: E402
    absolute_trajectory_error,
    coverage_rank,
    ellipse_coverage,
    sample_coverages,
)
from bayesmap.model.motion import wrap_angle  # noqa: E402
from bayesmap.slam import pipeline, posegraph  # noqa: E402
from bayesmap.slam.scanmatch import local_map_shares  # noqa: E402

RETIRED_SCALE = 0.36
"""The factor on the graph's fixed edge deviations that bayesmap reported before the step posteriors."""

SELF_DRAWS = 400
"""Paths drawn from the graph's Laplace approximation for ``--self-coverage`` (the Monte Carlo standard error of a
fraction near 0.8 among them is 0.02)."""

FAR = 10.0
"""Standard deviations: a step whose heading error exceeds this many is listed on its own."""


def _ratio(error, cov) -> str:
    """Each component's root mean square error over its root mean square posterior standard deviation."""
    ratio = np.sqrt(np.mean(error**2, axis=0) / np.mean(cov[:, [0, 1, 2], [0, 1, 2]], axis=0))
    return ", ".join(f"{r:.2f}" for r in ratio)


def step_errors(steps, truth) -> np.ndarray:
    """``(S - 1, 3)`` float64: ``steps`` ``(S - 1, 3)`` (each in its previous pose's frame) less the true steps of
    ``truth`` ``(S, 3)``, the headings wrapped to [-pi, pi)."""
    error = np.asarray(steps, np.float64) - posegraph.relative(truth[:-1], truth[1:])
    error[:, 2] = np.asarray(wrap_angle(error[:, 2]))
    return error


def aligned_covariances(path, edges, draws: int = 4000, seed: int = 0) -> np.ndarray:
    """``(S, 3, 3)``: the covariance of the graph's deviations ``d ~ N(0, H^-1)`` at ``path`` after the best rigid
    alignment of the whole path, to first order (translation the mean position deviation, rotation ``sum_i r_i x d_i /
    sum_i |r_i|^2`` about the positions' centroid, ``r_i`` the positions less it), estimated from ``draws``
    perturb-and-solve draws (:func:`bayesmap.slam.posegraph.sample_deviations`)."""
    d = posegraph.sample_deviations(seed, path, edges, draws)
    r = path[:, :2] - path[:, :2].mean(axis=0)
    lever = np.stack([-r[:, 1], r[:, 0]], axis=-1)  # d(position) / d(rotation) about the centroid
    shift = d[:, :, :2].mean(axis=1)
    turn = np.einsum("si,nsi->n", lever, d[:, :, :2]) / np.sum(r**2)
    d = d.copy()
    d[:, :, :2] -= shift[:, None, :] + turn[:, None, None] * lever[None]
    d[:, :, 2] -= turn[:, None]
    return np.einsum("nsi,nsj->sij", d, d) / draws


def first_pose_coverage(path, cov, truth, level: float = 0.95) -> float:
    """The fraction of true positions inside the ``level`` ellipses of ``cov`` ``(S, 3, 3)`` about ``path`` ``(S,
    3)``, the truth ``(S, 3)`` carried rigidly so that its first pose is the path's (``target_at_truth.py``'s
    :func:`in_model_frame`): the gauge of a posterior whose first pose is fixed (the SLAM model's), where
    :func:`ellipse_coverage` aligns the truth by the best rigid motion of every pose. A pose whose difference from
    the truth is zero (the first) counts as inside."""
    diff = in_model_frame(truth, path[0])[:, :2] - path[:, :2]
    squared = np.einsum("si,sij,sj->s", diff, np.linalg.pinv(cov[:, :2, :2], hermitian=True), diff)
    inside = (squared <= -2.0 * math.log1p(-level)) | np.all(np.abs(diff) < 1e-9, axis=1)
    return float(np.mean(inside))


def run(name: str, seed: int, scans: str, step_power: float | str | None = None, aligned: bool = False,
        first_pose: bool = False, local_maps: bool = False, self_coverage: bool = False) -> str:
    """One row of the table (module docstring)."""
    problem, truth = scan_set_problem(name, seed, scans)
    data = pipeline.scan_data(problem)
    began = time.perf_counter()
    front = pipeline.front_end(problem, data)
    seconds = time.perf_counter() - began
    path, edges, _ = posegraph.close_loops(front.path, data, step_cov=front.step_cov)
    cov = posegraph.marginal_covariances(path, edges)
    loop_edges = edges.take(slice(len(path) - 1, None))  # close_loops puts the S - 1 sequential edges first
    fixed = posegraph.concat_edges(posegraph.sequential_edges(front.path), loop_edges)
    scaled = RETIRED_SCALE**2 * posegraph.marginal_covariances(path, fixed)
    loops = len(loop_edges.i)
    unit_weight = float(np.sum(posegraph.edge_residuals(path, edges) ** 2)) / (3 * loops) if loops else float("nan")
    sd = np.sqrt(front.step_cov[:, [0, 1], [0, 1]])
    error = step_errors(posegraph.relative(front.path[:-1], front.path[1:]), truth)
    far = np.abs(error[:, 2]) > FAR * np.sqrt(front.step_cov[:, 2, 2])
    weighted = ellipse_coverage(path, unit_weight * cov, truth) if loops else float("nan")
    other = ""
    if step_power is not None:
        if step_power == "beams":  # each step's own power, at the beams' automatic bandwidth (beam_correlation.py)
            found = scan_adjustments(data, front.path, range(1, len(path)))
            power = np.array([problem.likelihood_power if w is None else min(1.0, w[len(BANDWIDTHS)]) for w in found])
        else:
            power = np.full(len(path) - 1, float(step_power))
        sequential = posegraph.with_step_covariances(edges.take(slice(0, len(path) - 1)),
                                                     front.step_cov * (problem.likelihood_power / power)[:, None, None])
        graph = posegraph.concat_edges(sequential, loop_edges)
        powered = posegraph.marginal_covariances(path, graph)
        other = f" {ellipse_coverage(path, powered, truth):.3f} |"
    if aligned:
        other += f" {ellipse_coverage(path, aligned_covariances(path, edges), truth):.3f} |"
    if local_maps:
        tied = posegraph.marginal_covariances(path, edges, posegraph.LocalMaps(local_map_shares(front.path, data),
                                                                               np.asarray(data.covs, np.float64)))
        median_sd = [np.median(np.sqrt(c[:, 0, 0] + c[:, 1, 1])) for c in (tied, cov)]
        loops = edges.take(slice(len(path) - 1, None))
        own = posegraph.with_covariances(loops, posegraph.loop_posteriors(path, data, loops, problem.likelihood_power))
        both = posegraph.marginal_covariances(path, posegraph.concat_edges(edges.take(slice(0, len(path) - 1)), own),
                                              posegraph.LocalMaps(local_map_shares(front.path, data),
                                                                  np.asarray(data.covs, np.float64)))
        other += (f" {ellipse_coverage(path, tied, truth):.3f} | {median_sd[0]:.3f} / {median_sd[1]:.3f} |"
                  f" {ellipse_coverage(path, both, truth):.3f} |")
        if self_coverage:
            graph = posegraph.concat_edges(edges.take(slice(0, len(path) - 1)), own)
            shares = posegraph.LocalMaps(local_map_shares(front.path, data), np.asarray(data.covs, np.float64))
            for ellipses, drawn_from, tie in ((cov, edges, None), (tied, edges, shares), (both, graph, shares)):
                drawn = path + posegraph.sample_deviations(seed, path, drawn_from, SELF_DRAWS, tie)
                other += f" {coverage_rank(path, ellipses, truth, drawn)['coverage_rank']:.2f} |"
            scores = sample_coverages(path, both, drawn)
            inside = float(np.mean((scores >= 0.85) & (scores <= 0.99)))
            low, mid, high = np.percentile(scores, [5, 50, 95])
            other += f" {mid:.3f} ({low:.3f}-{high:.3f}) | {inside:.2f} |"
    if first_pose:
        other += f" {first_pose_coverage(path, cov, truth):.3f} |"
        if step_power is not None:
            other += f" {first_pose_coverage(path, powered, truth):.3f} |"
    return (f"| {name} | {seed} | {scans} | {absolute_trajectory_error(path, truth)['rmse_m']:.3f} | "
            f"{ellipse_coverage(path, cov, truth):.3f} | {ellipse_coverage(path, scaled, truth):.3f} | "
            f"{unit_weight:.3f} | {weighted:.3f} | {_ratio(error, front.step_cov)} | "
            f"{', '.join(map(str, np.flatnonzero(far))) or 'none'} | {_ratio(error[~far], front.step_cov[~far])} | "
            f"{np.median(sd):.4f} | {np.percentile(sd, 90):.4f} | {seconds:.1f} |" + other)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="aces")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--scans", default="all", help="comma-separated subset of all,every2")
    parser.add_argument("--step-power", default=None,
                        help="also the coverage with the steps' covariances at this likelihood power, or 'beams': "
                             "each step's at its scan's own (beam_correlation.py's automatic bandwidth)")
    parser.add_argument("--aligned", action="store_true",
                        help="also the coverage of the covariance with the path's rigid motion aligned out")
    parser.add_argument("--local-maps", action="store_true",
                        help="also the coverage with each step tied to its local map's scans, then with the loop "
                             "edges' posteriors too (slam --log's)")
    parser.add_argument("--self-coverage", action="store_true",
                        help="with --local-maps: also the coverage that paths drawn from the reported graph's "
                             "posterior score, and the truth's rank among them")
    parser.add_argument("--first-pose", action="store_true",
                        help="also the coverages with the truth placed by its first pose (the model's gauge)")
    args = parser.parse_args(argv)
    if args.self_coverage and not args.local_maps:
        parser.error("--self-coverage needs --local-maps (it draws from that graph)")
    if args.step_power is not None and args.step_power != "beams":
        try:
            power = float(args.step_power)
        except ValueError:
            power = math.nan
        if not 0 < power <= 1:
            parser.error(f"--step-power must be a number in (0, 1] or 'beams', got {args.step_power!r}")
        args.step_power = power
    runs = scan_set_runs(parser, args.logs, parse_seeds(args.seeds), args.scans)
    print("| log | seed | scans | start ATE m | coverage, step posteriors | coverage, retired scale 0.36 | "
          "s0^2 | coverage, times s0^2 | "
          "step error / sd (x, y, theta) | steps beyond 10 sd in heading | error / sd without them | "
          "step sd median m | p90 m | front end s |"
          + ("" if args.step_power is None else f" coverage, steps at power {args.step_power} |")
          + (" coverage, rigid motion aligned out |" if args.aligned else "")
          + (" coverage, steps tied to their local maps | position sd median m, tied / plain |"
             " coverage, and the loop edges' posteriors |" if args.local_maps else "")
          + (" the truth's rank among draws, step posteriors | the same, tied | the same, and the loop edges'"
             " posteriors | coverage of those draws, median (5-95 %) | those draws inside 85-99 % |"
             if args.self_coverage else "")
          + (" coverage, truth placed by its first pose |" if args.first_pose else "")
          + (" the same, steps at that power |" if args.first_pose and args.step_power is not None else ""))
    extra = ((args.step_power is not None) + args.aligned + 3 * args.local_maps + 5 * args.self_coverage
             + args.first_pose * (1 + (args.step_power is not None)))
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|" + "---|" * extra)
    for name, seed, scans in runs:
        print(run(name, seed, scans, args.step_power, args.aligned, args.first_pose, args.local_maps,
                  args.self_coverage), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
