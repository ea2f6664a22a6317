"""The map of bayesmap's real-log SLAM beside the map made at the true poses, on held-out beams: one table, one run.

For each log (intel, aces, csail) and each odometry noise seed, the script makes the SLAM problem with
``noisy_odometry.py`` (as ``karto_peer.py`` does: real scans, simulated wheel odometry, the corrected poses as the
truth) and runs :func:`bayesmap.evaluation.slammap.evaluate_slam_map`: every 10th scan held out, SLAM on the rest from
odometry alone, the reference map from the same scans at their true poses, both scored on the held-out beams at their
true poses (occupancy AUC and predictive NLL), each in its own map model. The target: the SLAM map's AUC within
0.01 of the reference's. The ``registered`` columns score the same two maps with each held-out scan first registered
into the map's frame by scan matching against its neighbours at that map's poses (step 5 of
:mod:`bayesmap.evaluation.slammap`), with the RMS distance the held-out positions moved: the map's quality without
the error of its frame. The last column scores the joint chain's own map (the SLAM model's), which the final map at
the mean path replaces in ``posterior.npy``.

Usage: PYTHONPATH=src python benchmarks/slam_map.py [--seeds 0] [--logs intel,aces,csail] [--resolution 0.1]
                                                   [--json FILE]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import table_main  # noqa: E402

from bayesmap.evaluation.slammap import evaluate_slam_map  # noqa: E402
from bayesmap.progress import ProgressBar  # noqa: E402


def scores_with_bars(log, truth, resolution: float) -> dict:
    """:func:`bayesmap.evaluation.slammap.evaluate_slam_map` of one run, its stages drawn on stderr."""
    with ProgressBar() as bar:
        return evaluate_slam_map(log, truth, resolution=resolution, progress=bar)


def table_row(name: str, seed: int, scores: dict) -> str:
    """The markdown row of one run's :func:`bayesmap.evaluation.slammap.evaluate_slam_map` scores."""
    slam, ref = scores["slam"], scores["true_poses"]
    chain = scores.get("slam_chain")
    chain_cell = "-" if chain is None else f"{chain['auc']:.4f} / {chain['nll']:.3f}"
    slam_r, ref_r = scores["slam_registered"], scores["true_poses_registered"]
    return (f"| {name} | {seed} | {scores['setup']['slam_ate_m']:.3f} | {slam['auc']:.4f} | {ref['auc']:.4f} | "
            f"{ref['auc'] - slam['auc']:+.4f} | {slam['nll']:.3f} | {ref['nll']:.3f} | "
            f"{slam_r['auc']:.4f} / {slam_r['nll']:.3f} ({slam_r['shift_rms_m']:.3f}) | "
            f"{ref_r['auc']:.4f} / {ref_r['nll']:.3f} ({ref_r['shift_rms_m']:.3f}) | "
            f"{ref_r['auc'] - slam_r['auc']:+.4f} | {chain_cell} |")


def main(argv: list[str] | None = None) -> int:
    return table_main(
        argv, __doc__.splitlines()[0],
        "| log | seed | SLAM ATE m | SLAM map AUC | true-pose map AUC | AUC gap | SLAM map NLL | true-pose map NLL | "
        "registered: SLAM map AUC / NLL (shift m) | registered: true-pose map AUC / NLL (shift m) | "
        "registered AUC gap | the chain's own map: AUC / NLL |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        lambda parser: parser.add_argument("--resolution", type=float, default=0.1, help="meters per cell (0.1)"),
        lambda args: lambda log, truth: scores_with_bars(log, truth, args.resolution), table_row,
        parse_seeds)


if __name__ == "__main__":
    sys.exit(main())
