"""The map of a SLAM run scored on held-out beams at their true poses, beside the map made at the true poses.

Protocol (issue 15's map-quality target):

1. Every ``every``-th scan is held out (:func:`bayesmap.evaluation.heldout.heldout_split`); SLAM
   (:func:`bayesmap.inference.logslam.run_log_slam`) maps the other scans from their odometry alone.
2. The SLAM map lives in the frame of its own path, which is anchored at the first odometry pose. The rigid 2-D
   alignment of that path onto the true poses of the same scans (:func:`bayesmap.evaluation.trajectory.frame_of`, the
   inverse of the ATE's) carries the held-out scans' true poses into the map's frame: ``p = R^T (g - t)``,
   ``theta = theta_g - angle(R)``.
3. The reference map is made with the true poses of the same mapped scans
   (:func:`bayesmap.inference.driver.run_inference`, the cellwise sampler, as ``bayesmap evaluate --log`` does on a
   corrected log), in the map model of the SLAM run's map: the map model of a log at known poses (the defaults of
   :func:`bayesmap.scenes.log_problem`) when the run drew a final map at its mean path (stage 6 of
   :func:`bayesmap.inference.logslam.run_log_slam`, the default), the SLAM model's own
   (:func:`bayesmap.scenes.slam_map_settings`) otherwise; so the two maps differ only in their poses.
4. Both maps are scored on the held-out beams at their true poses with the occupancy AUC and the predictive NLL of
   :func:`bayesmap.evaluation.heldout.score_maps`, each map as independent wall probabilities (the SLAM run keeps
   its posterior marginals, not map samples, so the reference is scored the same way), each in its own map model.
   With a final map, the joint chain's own map is scored too (``"slam_chain"``, in the SLAM model).
"""

from __future__ import annotations

import time

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.heldout import heldout_split, score_maps
from bayesmap.evaluation.trajectory import absolute_trajectory_error, frame_of
from bayesmap.inference.driver import run_inference
from bayesmap.inference.logslam import run_log_slam
from bayesmap.scenes import RESOLUTION, log_problem, log_slam_problem, slam_map_settings

REFERENCE_SWEEPS = 100
"""Cellwise sweeps of the map made at the true poses (half burn-in): ``bayesmap evaluate --log``'s default."""


def evaluate_slam_map(log, truth, every: int = 10, resolution: float = RESOLUTION, seed: int = 0,
                      reference_sweeps: int = REFERENCE_SWEEPS, **slam_options) -> dict:
    """Held-out map quality of SLAM beside the map made at the true poses (the protocol of the module docstring).

    Args:
        log: a :class:`bayesmap.io.carmen.CarmenLog` whose poses are odometry (S scans).
        truth: ``(S, 3)`` true poses of its scans (x m, y m, theta rad).
        every: hold out every ``every``-th scan.
        resolution: meters per cell of both maps.
        seed: the random seed of both runs.
        reference_sweeps: cellwise sweeps of the reference map.
        slam_options: keywords of :func:`bayesmap.inference.logslam.run_log_slam` (rounds, sweeps).

    Returns:
        ``{"slam": {"auc", "nll", ...}, "true_poses": {...}, "setup": {...}}`` (JSON-serializable), and
        ``"slam_chain"`` with a final map; ``setup`` has the SLAM path's ATE on the mapped scans, both runtimes and
        the map model (``"log at known poses"`` or ``"SLAM chain"``).

    Raises:
        BayesmapError: if ``truth`` is not ``(S, 3)`` finite, and on bad arguments (see :func:`heldout_split`,
            :func:`bayesmap.scenes.log_problem`).
    """
    truth = np.asarray(truth, np.float64)
    if truth.shape != (len(log), 3) or not np.all(np.isfinite(truth)):
        raise BayesmapError(f"truth must be ({len(log)}, 3) finite poses, one per scan of the log, got shape "
                            f"{truth.shape}")
    train, test = heldout_split(len(log), every)
    start = time.perf_counter()
    slam = run_log_slam(log_slam_problem(log, train, resolution=resolution), seed=seed, **slam_options)
    slam_s = time.perf_counter() - start
    poses = truth.copy()
    poses[test] = frame_of(slam.mean_path, truth[train], truth[test])
    final = slam.chain_posterior is not None
    chain_model = slam_map_settings()
    same = {} if final else chain_model  # the model of slam.posterior: the log's at known poses, or the chain's

    def slam_test(settings):
        return log_problem(log.with_poses(poses), test, resolution=resolution, grid=slam.grid, **settings)

    scores = score_maps(slam_test(same), {"slam": (slam.posterior, None)})
    if final:
        scores.update(score_maps(slam_test(chain_model), {"slam_chain": (slam.chain_posterior, None)}))

    true_log = log.with_poses(truth)
    grid = log_problem(true_log, resolution=resolution).grid  # covers the held-out scans too
    start = time.perf_counter()
    reference = run_inference(log_problem(true_log, train, resolution=resolution, grid=grid, **same), "cellwise",
                              reference_sweeps, seed=seed, progress=False)
    reference_s = time.perf_counter() - start
    scores.update(score_maps(log_problem(true_log, test, resolution=resolution, grid=grid, **same),
                             {"true_poses": (reference.posterior, None)}))
    scores["setup"] = {"log": str(log.path), "scans": len(log), "train_scans": len(train), "test_scans": len(test),
                       "every": int(every), "resolution": float(resolution),
                       "slam_ate_m": absolute_trajectory_error(slam.mean_path, truth[train])["rmse_m"],
                       "slam_runtime_s": round(slam_s, 3), "reference_runtime_s": round(reference_s, 3),
                       "reference_sweeps": int(reference_sweeps),
                       "map_model": "log at known poses" if final else "SLAM chain"}
    return scores
