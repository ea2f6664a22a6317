"""The scoring job (``bayesmap evaluate``): bayesmap's maps against log-odds mapping on held-out beams of a log or
against a known floor plan (:mod:`bayesmap.evaluation.heldout`), or a SLAM path and the log's odometry against a
true trajectory (:func:`bayesmap.evaluation.trajectory.score_trajectory`).

:func:`evaluate` runs the job an :class:`EvaluateRequest` describes and returns an :class:`EvaluateRun` (the scores,
with each stage's wall time and peak memory, one line saying what was scored, the table);
:func:`bayesmap.runs.outputs.write_json` writes the scores.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple, Optional

import numpy as np

from bayesmap import scenes
from bayesmap.errors import BayesmapError
from bayesmap.evaluation.heldout import evaluate_log, evaluate_truth
from bayesmap.evaluation.trajectory import score_trajectory
from bayesmap.io.tum import STAMP_TOLERANCE, match_stamps, read_tum, tum_stamps
from bayesmap.progress import ProgressCallback, StageRecorder, start_stage
from bayesmap.runs.inputs import (
    check_problem_size,
    check_truth_scene,
    coupling_option,
    parse_scans,
    read_slam_run,
    read_source,
    sensor_params,
)
from bayesmap.runs.outputs import check_output_file
from bayesmap.runs.slam import log_slam
from bayesmap.scenes import log_problem

EVALUATE_SWEEPS = 100
"""``evaluate``'s Gibbs sweeps of a map (half burn-in), the default of ``bayesmap infer``; with
--truth-trajectory a SLAM run's (``bayesmap slam``'s) default applies instead."""
TRAJECTORY_COLUMNS = (("ate_rmse_m", "ATE m"), ("rpe1_trans_rmse_m", "RPE1 m"), ("rpe1_rot_rmse_deg", "RPE1 deg"),
                      ("rpe10_trans_rmse_m", "RPE10 m"), ("rpe10_rot_rmse_deg", "RPE10 deg"),
                      ("scale_pct", "scale %"), ("coverage", "cover95"))
"""The columns of ``evaluate --truth-trajectory``'s table: the keys of
:func:`bayesmap.evaluation.trajectory.score_trajectory` and their headings."""


@dataclass(frozen=True)
class EvaluateRequest:
    """What ``bayesmap evaluate`` was asked: its options, named as they are (``--json`` is ``json_file``); None
    where one was not given."""

    log: Optional[Path] = None
    bag: Optional[Path] = None
    scan_topic: str = "/scan"
    odom_topic: str = "/odom"
    tf: bool = False
    truth: Optional[Path] = None
    truth_trajectory: Optional[Path] = None
    run: Optional[Path] = None
    scans: Optional[str] = None
    every: int = 10
    resolution: float = scenes.RESOLUTION
    sampler: str = "cellwise"
    sweeps: Optional[int] = None
    beam_model: str = scenes.LOG_BEAM_MODEL
    num_poses: int = scenes.SIMULATED_NUM_POSES
    num_angles: int = scenes.SIMULATED_NUM_ANGLES
    max_range: Optional[float] = None
    sensor_noise: Optional[float] = None
    prior_wall_prob: Optional[float] = None
    range_offset: Optional[float] = None
    geometry: Optional[str] = None
    wall_pass_prob: Optional[float] = None
    cut_past_reading: Optional[float] = None
    likelihood_power: Optional[float] = None
    coupling: Optional[float] = None
    run_length: Optional[float] = None
    beam_weights: Optional[str] = None
    lambda_short: Optional[float] = None
    seed: int = 0
    json_file: Optional[Path] = None
    force: bool = False


class EvaluateRun(NamedTuple):
    """An evaluation: its ``scores`` (``{"setup": ..., method: metrics}``, what ``--json`` writes), a ``header``
    line saying what was scored, and the ``table`` of the scores."""

    scores: dict
    header: str
    table: str


def format_scores(scores: dict) -> str:
    """The map evaluation's table: one row per method (a dict of metrics other than ``"setup"``), its metrics as
    columns."""
    rows = [(name, vals) for name, vals in scores.items() if name != "setup" and isinstance(vals, dict)]
    keys = [k for k in ("auc", "nll", "accuracy", "brier", "beams", "cells", "runtime_s")
            if any(k in v for _, v in rows)]
    lines = [f"{'method':<10}" + "".join(f"{k:>12}" for k in keys)]
    for name, vals in rows:
        cells = []
        for k in keys:
            v = vals.get(k)
            cells.append(f"{'-':>12}" if v is None else f"{v:>12,}" if isinstance(v, int) else f"{v:>12.4f}")
        lines.append(f"{name:<10}" + "".join(cells))
    return "\n".join(lines)


def format_trajectory_scores(scores: dict) -> str:
    """The trajectory table: one row per method (bayesmap, odometry), :data:`TRAJECTORY_COLUMNS` as columns; with
    the samples' coverages (:func:`bayesmap.evaluation.trajectory.coverage_rank`), two lines of them below."""
    lines = [f"{'method':<10}" + "".join(f"{head:>11}" for _, head in TRAJECTORY_COLUMNS)]
    for name in ("bayesmap", "odometry"):
        vals = scores[name]
        lines.append(f"{name:<10}" + "".join(f"{'-':>11}" if vals.get(key) is None else f"{vals[key]:>11.4f}"
                                              for key, _ in TRAJECTORY_COLUMNS))
    run = scores["bayesmap"]
    if run.get("coverage_rank") is not None:
        lines.append(f"the {run['samples']} posterior samples, each scored as the truth is: cover95 "
                     f"{run['samples_coverage_min']:.4f} to {run['samples_coverage_max']:.4f} (median "
                     f"{run['samples_coverage_median']:.4f})")
        lines.append(f"the truth's cover95 ranks {run['coverage_rank']:.2f} among them (over many runs, evenly "
                     "spread over 0-1 for a calibrated posterior)")
    return "\n".join(lines)


def _span(stamps) -> str:
    """``"first to last"`` of a stamp array, to the millisecond."""
    return f"{float(stamps[0]):.3f} to {float(stamps[-1]):.3f}"


def truth_of_scans(truth_stamps, truth_poses, scans, stamps, num_log_scans: int, name: str = "the truth",
                   stamped: bool = False):
    """The true pose of each scan of a run, and how it was paired: ``((S, 3) poses, "order" or "timestamp")``.

    By order when the truth has one pose per scan of the run (``S`` poses) or of the whole log (``num_log_scans``
    poses: those of the run's ``scans``), provided, for a run ``stamped`` with the log's timestamps, that the poses
    so paired carry the scans' stamps (within :data:`bayesmap.io.tum.STAMP_TOLERANCE`; a truth stamped with scan
    indices ``0, 1, ...`` is paired by order as it is); otherwise by timestamp
    (:func:`bayesmap.io.tum.match_stamps`: each of the run's ``stamps`` to the truth stamp within the tolerance).

    Args:
        truth_stamps: ``(T,)`` stamps of the truth (seconds or scan indices); truth_poses: ``(T, 3)`` (x, y m,
            theta rad).
        scans: ``(S,)`` indices of the run's scans in the log; stamps: ``(S,)`` their TUM stamps.
        num_log_scans: the log's number of scans; name: the truth's name for messages.
        stamped: True when ``stamps`` are the log's timestamps (seconds), False for scan indices.

    Raises:
        BayesmapError: naming the counts, if neither rule pairs every scan; naming both stamp ranges, if the truth
            has a pose per scan but at other stamps (the path of other scans).
    """
    truth_stamps = np.asarray(truth_stamps, dtype=np.float64)
    truth_poses = np.asarray(truth_poses, dtype=np.float64)
    stamps = np.asarray(stamps, dtype=np.float64)
    count, s = len(truth_poses), len(scans)
    rows = np.arange(s) if count == s else np.asarray(scans) if count == num_log_scans else None
    if rows is not None:
        by_index = np.array_equal(truth_stamps, np.arange(count))
        if not stamped or by_index or np.all(np.abs(truth_stamps[rows] - stamps) <= STAMP_TOLERANCE):
            return truth_poses[rows], "order"
    try:
        return truth_poses[match_stamps(stamps, truth_stamps)], "timestamp"
    except BayesmapError as err:
        if rows is not None:
            raise BayesmapError(f"{name} has a pose per scan, but its stamps ({_span(truth_stamps[rows])} s) are not "
                                f"the scans' ({_span(stamps)} s): it is the path of other scans; give the true "
                                "trajectory of these scans") from None
        raise BayesmapError(f"{name} has {count} poses, not one per scan of the run ({s}) or of the log "
                            f"({num_log_scans}), and its stamps do not pair with the run's: {err}") from None


def _check_trajectory_request(req: EvaluateRequest) -> None:
    """Refuse contradictory ``--truth-trajectory`` options and a ``--json`` that cannot be written."""
    if req.truth_trajectory is None:
        raise BayesmapError("--run DIR needs --truth-trajectory TRUE.tum (and --log FILE)")
    if req.truth is not None:
        raise BayesmapError("give either --truth (a floor plan) or --truth-trajectory (a true path), not both")
    if req.log is None and req.bag is None:
        raise BayesmapError("--truth-trajectory needs --log FILE (or --bag PATH): the log whose path it is")
    if req.json_file is not None:
        check_output_file(req.json_file, req.force)
    if req.run is not None and (req.scans is not None or req.sweeps is not None):
        raise BayesmapError("--scans and --sweeps describe a new SLAM run; --run DIR is scored on its own scans")


def evaluate_trajectory(req: EvaluateRequest, progress: Optional[ProgressCallback] = None,
                        notify: Optional[Callable[[str], None]] = None) -> EvaluateRun:
    """``evaluate --truth-trajectory``: the scores of SLAM's path (a new run of
    :func:`bayesmap.runs.slam.log_slam` on the log, or the folder ``--run``) and of the log's odometry against the
    true trajectory; the truth is paired with the scans (:func:`truth_of_scans`) before SLAM runs.

    Raises:
        BayesmapError: on a bad option or file (named), a run folder whose stamps are not the log's, or a truth
            that does not pair with the scans.
    """
    _check_trajectory_request(req)
    start_stage(progress, "read truth")
    truth_stamps, truth_poses = read_tum(req.truth_trajectory)
    if req.run is not None:
        stamps, mean, cov, samples = read_slam_run(req.run)
    start_stage(progress, "read log")
    carmen = read_source(req.log, req.bag, req.scan_topic, req.odom_topic, req.tf, req.max_range)
    path = req.log if req.log is not None else req.bag
    log_stamps = tum_stamps(carmen.timestamps)
    setup = {"log": str(path), "truth": str(req.truth_trajectory), "log_scans": len(carmen)}
    if req.run is not None:
        try:
            chosen = match_stamps(stamps, log_stamps)
        except BayesmapError as err:
            raise BayesmapError(f"{str(req.run / 'trajectory.tum')!r} is not a path of {path.name}'s scans: its stamps "
                                f"are not the log's (scan timestamps, or indices where they do not increase "
                                f"strictly): {err}") from None
        setup["run"] = str(req.run)
    else:
        chosen = parse_scans(req.scans, len(carmen))
        stamps = log_stamps[chosen]
    truth, paired = truth_of_scans(truth_stamps, truth_poses, chosen, stamps, len(carmen),
                                   name=str(req.truth_trajectory),
                                   stamped=np.array_equal(log_stamps, carmen.timestamps))
    if req.run is None:
        run = log_slam(carmen, path, req.scans, req.resolution, req.sweeps, None, req.seed, final_map=False,
                       progress=progress, notify=notify)
        result, chosen, settings = run.result, run.chosen, run.settings
        mean, cov, samples = result.mean_path, result.pose_cov, result.pose_samples
        setup.update(settings=settings, runtime_s=result.runtime_s, acceptance_rate=result.acceptance_rate)
    setup.update(scans=len(chosen), paired_by=paired)
    start_stage(progress, "score")
    scores = {"setup": setup, "bayesmap": score_trajectory(mean, truth, cov, samples=samples),
              "odometry": score_trajectory(np.asarray(carmen.poses, np.float64)[chosen], truth)}
    source = f"the run in {req.run}" if req.run is not None else f"a new run ({setup['runtime_s']:.1f} s)"
    header = (f"{path.name}: {len(chosen)} scans, {source}, against {req.truth_trajectory.name} (paired by "
              f"{paired}); ATE after the best rigid 2-D alignment, RPE over 1 and 10 scans, coverage of the 95 % "
              "ellipses")
    return EvaluateRun(scores, header, format_trajectory_scores(scores))


def _evaluate_on_truth(req: EvaluateRequest, mapping: dict, progress: Optional[ProgressCallback]) -> EvaluateRun:
    """``evaluate --truth``: simulated scans of a floor plan, mapped, scored against it."""
    if req.likelihood_power is not None or req.range_offset is not None:
        raise BayesmapError("--likelihood-power and --range-offset apply to --log, not to --truth")
    if req.geometry is not None or req.wall_pass_prob is not None or req.cut_past_reading is not None:
        raise BayesmapError("--geometry, --wall-pass-prob and --cut-past-reading apply to --log, not to --truth")
    max_range = scenes.SIMULATED_MAX_RANGE if req.max_range is None else req.max_range
    check_truth_scene(req.truth, req.resolution, req.num_poses, req.num_angles, max_range)
    start_stage(progress, "maps and scores")
    scores = evaluate_truth(req.truth, resolution=req.resolution, num_poses=req.num_poses,
                            num_angles=req.num_angles, max_range=max_range, progress=progress, **mapping)
    setup = scores["setup"]
    header = (f"{req.truth.name}: {setup['num_poses']} simulated scans of {req.num_angles} beams; "
              f"grid {setup['grid'][0]} x {setup['grid'][1]} cells of {setup['resolution']:g} m; "
              f"scored on {setup['cells_scored']:,} known cells seen by a beam; {mapping['sampler']}, "
              f"{mapping['sweeps']} sweeps")
    return EvaluateRun(scores, header, format_scores(scores))


def evaluate_maps(req: EvaluateRequest, progress: Optional[ProgressCallback] = None) -> EvaluateRun:
    """``evaluate --log`` (held-out beams of a log: occupancy AUC, predictive NLL) or ``evaluate --truth`` (a
    floor plan: accuracy, AUC, Brier score), bayesmap against log-odds mapping.

    Raises:
        BayesmapError: on a bad option or file (named), or a problem too large to fit.
    """
    sweeps = EVALUATE_SWEEPS if req.sweeps is None else req.sweeps
    if (req.log is None and req.bag is None) == (req.truth is None):
        raise BayesmapError("give either --log FILE or --truth FILE (a ROS bag: --bag PATH, as --log)")
    if req.json_file is not None:
        check_output_file(req.json_file, req.force)
    mapping = dict(sampler=req.sampler, sweeps=sweeps, seed=req.seed, sensor_noise=req.sensor_noise,
                   beam_model=req.beam_model, prior_wall_prob=req.prior_wall_prob,
                   sensor_params=sensor_params(req.beam_weights, req.lambda_short),
                   coupling=coupling_option(req.coupling, req.run_length, req.resolution))
    if req.truth is None:
        start_stage(progress, "read log")
    carmen = read_source(req.log, req.bag, req.scan_topic, req.odom_topic, req.tf, req.max_range)
    if carmen is None:
        return _evaluate_on_truth(req, mapping, progress)
    name = (req.log if req.log is not None else req.bag).name
    chosen = parse_scans(req.scans, len(carmen))
    start_stage(progress, "build problem")
    check_problem_size(log_problem(carmen, chosen, resolution=req.resolution))  # the grid of all chosen scans
    start_stage(progress, "maps and scores")
    scores = evaluate_log(carmen, chosen, every=req.every, resolution=req.resolution, range_offset=req.range_offset,
                          likelihood_power=req.likelihood_power,
                          geometry=scenes.LOG_GEOMETRY if req.geometry is None else req.geometry,
                          wall_pass_prob=req.wall_pass_prob, progress=progress, **mapping,
                          cut_past_reading=scenes.LOG_CUT_PAST_READING if req.cut_past_reading is None
                          else req.cut_past_reading)
    setup = scores["setup"]
    header = (f"{name}: mapped {setup['train_scans']} scans, scored the {setup['test_scans']} held out "
              f"(every {req.every}-th); grid {setup['grid'][0]} x {setup['grid'][1]} cells of {req.resolution:g} m; "
              f"{req.sampler}, {sweeps} sweeps, {req.beam_model} model, {setup['geometry']} geometry")
    return EvaluateRun(scores, header, format_scores(scores))


def evaluate(req: EvaluateRequest, progress: Optional[ProgressCallback] = None,
             notify: Optional[Callable[[str], None]] = None) -> EvaluateRun:
    """``bayesmap evaluate``: a SLAM path against a true trajectory (``--truth-trajectory``,
    :func:`evaluate_trajectory`) or maps against held-out beams or a floor plan (:func:`evaluate_maps`).
    ``progress`` and ``notify`` are passed on to the long work, ``progress`` through a
    :class:`bayesmap.progress.StageRecorder` whose stages the scores get as ``"stages"`` and ``"peak_rss_mb"``
    (the JSON ``--json`` writes; the stages end when the scores are done). Reading the inputs, building the
    problem and scoring are stages of their own ("read truth", "read log", "build problem", "score"); the time
    the library spends after its last report (log-odds mapping and the held-out scores of a map evaluation) counts
    in its last stage.

    Raises:
        BayesmapError: on a bad option, input or output (named), before any work where it can be told.
    """
    stages = StageRecorder(progress)
    if req.truth_trajectory is not None or req.run is not None:
        done = evaluate_trajectory(req, stages, notify)
    else:
        done = evaluate_maps(req, stages)
    done.scores.update(stages.summary())
    return done
