"""The map of a SLAM run scored on held-out beams at their true poses, beside the map made at the true poses.

Protocol (the SLAM map's quality target: its held-out AUC within 0.01 of the map made at the true poses):

1. Every ``every``-th scan is held out (:func:`bayesmap.evaluation.heldout.heldout_split`); SLAM
   (:func:`bayesmap.slam.pipeline.run_log_slam`) maps the other scans from their odometry alone.
2. The SLAM map lives in the frame of its own path, which is anchored at the first odometry pose. The rigid 2-D
   alignment of that path onto the true poses of the same scans (:func:`bayesmap.evaluation.trajectory.frame_of`, the
   inverse of the ATE's) carries the held-out scans' true poses into the map's frame: ``p = R^T (g - t)``,
   ``theta = theta_g - angle(R)``.
3. The reference map is made with the true poses of the same mapped scans
   (:func:`bayesmap.inference.driver.run_inference`, the cellwise sampler, as ``bayesmap evaluate --log`` does on a
   corrected log), in the map model of the SLAM run's map: the map model of a log at known poses (the defaults of
   :func:`bayesmap.scenes.log_problem`) when the run drew a final map at its mean path (stage 6 of
   :func:`bayesmap.slam.pipeline.run_log_slam`, the default), the SLAM model's own
   (:func:`bayesmap.slam.problem.slam_map_settings`) otherwise; so the two maps differ only in their poses.
4. Both maps are scored on the held-out beams at their true poses with the occupancy AUC and the predictive NLL of
   :func:`bayesmap.evaluation.heldout.score_maps`, each map as independent wall probabilities (the SLAM run keeps
   its posterior marginals, not map samples, so the reference is scored the same way), each in its own map model.
   With a final map, the joint chain's own map is scored too (``"slam_chain"``, in the SLAM model).
5. The same maps are scored again with each held-out scan registered into each map's frame
   (``"slam_registered"``, ``"true_poses_registered"``, ``"slam_chain_registered"``; :func:`register_heldout`): the scan
   is matched, from the pose step 2 gives it (for the reference, its true pose), against the local map of the
   :data:`REGISTER_NEIGHBOURS` mapped scans on each side of it in the log at that map's poses (the SLAM run's mean
   path, or the true poses), by the loop closure's correlative matcher
   (:func:`bayesmap.slam.posegraph.match_to_local_maps`, window :data:`REGISTER_LEVELS`). Each entry adds
   ``shift_rms_m``, the RMS distance the held-out positions moved. Step 4 scores a map together with the error of
   its frame: a path warped by 0.1 m puts the held-out beams 0.1 m off walls that are right relative to the path (the
   truth's held-out scans move by 3-5 cm when registered into the map of their neighbours' true poses: the truth's
   own error and the matcher's together). Step 5 scores the map up to that registration, as a robot localizing in it
   would use it; both maps get the same registration.
"""

from __future__ import annotations

import time

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.heldout import heldout_split, score_maps
from bayesmap.evaluation.trajectory import absolute_trajectory_error, frame_of
from bayesmap.inference.driver import run_inference
from bayesmap.progress import ProgressCallback
from bayesmap.scenes import RESOLUTION, log_problem
from bayesmap.slam.pipeline import run_log_slam, scan_data
from bayesmap.slam.posegraph import match_to_local_maps
from bayesmap.slam.problem import log_slam_problem, slam_map_settings

REGISTER_NEIGHBOURS = 10
"""Mapped scans on each side of a held-out scan (nearest in the log's order) whose endpoints make the local map it is
registered against (the loop closure's :data:`bayesmap.slam.posegraph.LOOP_NEIGHBOURS`)."""

REGISTER_LEVELS = ((0.1, 0.02, 3, 5, 1), (0.03, 0.007, 3, 3, 0), (0.01, 0.0025, 2, 2, 0), (0.003, 0.0008, 2, 2, 0))
"""The registration's search (as :data:`bayesmap.slam.scanmatch.MATCH_LEVELS`): +-0.3 m and +-0.1 rad around
the starting pose, down to 3 mm and 0.05 degrees. Narrower than the loop closure's +-1.5 m: a path whose ATE is
0.1-0.2 m is off by less than 0.3 m almost everywhere, and a wide window lets a scan in a corridor slide along it
to wherever it scores best."""

REFERENCE_SWEEPS = 100
"""Cellwise sweeps of the map made at the true poses (half burn-in): ``bayesmap evaluate --log``'s default."""


def register_heldout(path, data, train, test, starts, progress: ProgressCallback | None = None) -> np.ndarray:
    """Register held-out scans into the frame of a map made from the other scans (step 5 of the module docstring).

    Args:
        path: ``(S, 3)`` poses of every scan of ``data`` in the map's frame; only the rows of ``train`` are read.
        data: the log's scans (:func:`bayesmap.slam.pipeline.scan_data`).
        train: ``(M,)`` sorted indices of the mapped scans.
        test: ``(T,)`` indices of the held-out scans.
        starts: ``(T, 3)`` where each held-out scan's search starts, in the map's frame.
        progress: gets ``Progress("registration", done, T, "scan")`` per scan registered; None: no reports.

    Returns:
        ``(T, 3)`` float64 registered poses (x m, y m, theta rad).

    Raises:
        BayesmapError: as :func:`bayesmap.slam.posegraph.match_to_local_maps`, or if ``train`` is empty.
    """
    train, test = np.asarray(train, np.int64), np.asarray(test, np.int64)
    if len(train) == 0:
        raise BayesmapError("no mapped scan to register the held-out scans against")
    at = np.searchsorted(train, test)[:, None] + np.arange(-REGISTER_NEIGHBOURS, REGISTER_NEIGHBOURS)
    neighbours = train[np.clip(at, 0, len(train) - 1)]
    return match_to_local_maps(path, data, test, neighbours, starts, levels=REGISTER_LEVELS, progress=progress,
                               stage="registration")[0]


def evaluate_slam_map(log, truth, every: int = 10, resolution: float = RESOLUTION, seed: int = 0,
                      reference_sweeps: int = REFERENCE_SWEEPS, progress: ProgressCallback | None = None,
                      **slam_options) -> dict:
    """Held-out map quality of SLAM beside the map made at the true poses (the protocol of the module docstring).

    Args:
        log: a :class:`bayesmap.io.carmen.CarmenLog` whose poses are odometry (S scans).
        truth: ``(S, 3)`` true poses of its scans (x m, y m, theta rad).
        every: hold out every ``every``-th scan.
        resolution: meters per cell of both maps.
        seed: the random seed of both runs.
        reference_sweeps: cellwise sweeps of the reference map.
        progress: gets the SLAM run's stages (:func:`bayesmap.slam.pipeline.run_log_slam`), the registrations
            (stage ``"registration"``, per scan) and the reference map's sweeps (stage ``"sweeps"``); None: no
            reports.
        slam_options: keywords of :func:`bayesmap.slam.pipeline.run_log_slam` (rounds, sweeps).

    Returns:
        ``{"slam": {"auc", "nll", ...}, "true_poses": {...}, "setup": {...}}`` (JSON-serializable), and
        ``"slam_chain"`` with a final map; the ``"..._registered"`` scores of step 5 (each with ``shift_rms_m``);
        ``setup`` has the SLAM path's ATE on the mapped scans, both runtimes and
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
    slam = run_log_slam(log_slam_problem(log, train, resolution=resolution), seed=seed, progress=progress,
                        **slam_options)
    slam_s = time.perf_counter() - start
    poses = truth.copy()
    poses[test] = frame_of(slam.mean_path, truth[train], truth[test])
    final = slam.chain_posterior is not None
    chain_model = slam_map_settings()
    same = {} if final else chain_model  # the model of slam.posterior: the log's at known poses, or the chain's

    def slam_test(settings, at):
        return log_problem(log.with_poses(at), test, resolution=resolution, grid=slam.grid, **settings)

    def shift(moved, start):
        return float(np.sqrt(np.mean(np.sum((moved[test, :2] - start[test, :2]) ** 2, axis=1))))

    data = scan_data(log_slam_problem(log, resolution=resolution))  # every scan, the readings as measured
    slam_path = poses.copy()
    slam_path[train] = slam.mean_path
    registered = poses.copy()
    registered[test] = register_heldout(slam_path, data, train, test, poses[test], progress)
    slam_shift = shift(registered, poses)  # the same registration for the final map and the chain's
    scores = score_maps(slam_test(same, poses), {"slam": (slam.posterior, None)})
    scores.update(_with_shift(score_maps(slam_test(same, registered), {"slam_registered": (slam.posterior, None)}),
                              slam_shift))
    if final:
        scores.update(score_maps(slam_test(chain_model, poses), {"slam_chain": (slam.chain_posterior, None)}))
        scores.update(_with_shift(score_maps(slam_test(chain_model, registered),
                                             {"slam_chain_registered": (slam.chain_posterior, None)}), slam_shift))

    true_log = log.with_poses(truth)
    grid = log_problem(true_log, resolution=resolution).grid  # covers the held-out scans too
    start = time.perf_counter()
    reference = run_inference(log_problem(true_log, train, resolution=resolution, grid=grid, **same), "cellwise",
                              reference_sweeps, seed=seed, progress=progress)
    reference_s = time.perf_counter() - start
    scores.update(score_maps(log_problem(true_log, test, resolution=resolution, grid=grid, **same),
                             {"true_poses": (reference.posterior, None)}))
    true_registered = truth.copy()
    true_registered[test] = register_heldout(truth, data, train, test, truth[test], progress)
    scores.update(_with_shift(score_maps(log_problem(log.with_poses(true_registered), test, resolution=resolution,
                                                     grid=grid, **same),
                                         {"true_poses_registered": (reference.posterior, None)}),
                              shift(true_registered, truth)))
    scores["setup"] = {"log": str(log.path), "scans": len(log), "train_scans": len(train), "test_scans": len(test),
                       "every": int(every), "resolution": float(resolution),
                       "slam_ate_m": absolute_trajectory_error(slam.mean_path, truth[train])["rmse_m"],
                       "slam_runtime_s": round(slam_s, 3), "reference_runtime_s": round(reference_s, 3),
                       "reference_sweeps": int(reference_sweeps),
                       "map_model": "log at known poses" if final else "SLAM chain"}
    return scores


def _with_shift(scores: dict, shift_m: float) -> dict:
    """``scores`` (name -> figures) with ``shift_rms_m`` added to every entry."""
    return {name: {**figures, "shift_rms_m": shift_m} for name, figures in scores.items()}
