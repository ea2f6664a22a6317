"""The SLAM job (``bayesmap slam``, the app's Run SLAM): the path and the map of a real log or bag
(:func:`bayesmap.slam.pipeline.run_log_slam`), or of a simulated scene (the tutorial's loop, a path drawn in the
app) by the joint chain (:func:`bayesmap.slam.joint.run_slam`), with its summary and its output folder.

In data-flow order: :func:`run_simulated_slam` / :func:`run_log_slam_job` (the job: a :class:`SlamRun`, result and
summary), :func:`slam_files` (the output files' bytes), :func:`bayesmap.runs.outputs.write_outputs`;
:func:`slam` does all of them for a :class:`SlamRequest` after checking the outputs, and records each stage's wall
time and peak memory in summary.json (:class:`bayesmap.progress.StageRecorder`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple, Optional

import numpy as np

from bayesmap import scenes
from bayesmap.errors import BayesmapError
from bayesmap.evaluation.trajectory import score_trajectory
from bayesmap.geometry.raycast import scan_endpoints
from bayesmap.inference.tiled import TILE_PAIRS
from bayesmap.io.maps_out import seen_cells_along
from bayesmap.io.rosmap import encode_rosmap
from bayesmap.io.tum import encode_tum, tum_stamps
from bayesmap.progress import ProgressCallback, StageRecorder, stage_summary, start_stage
from bayesmap.runs.inputs import check_slam_size, check_tile_pairs_option, motion_option, parse_scans, read_source
from bayesmap.runs.outputs import (
    OCCUPANCY_FILE,
    REPORT_FILE,
    ROSMAP_STEM,
    SLAM_OWNED_FILES,
    check_output_dir,
    json_bytes,
    map_files,
    npy_bytes,
    write_outputs,
)
from bayesmap.slam.branches import BRANCHES
from bayesmap.slam.joint import SlamResult, run_slam
from bayesmap.slam.keyframes import KEYFRAME_DISTANCE, KEYFRAME_TURN, keyframe_problem, select_keyframes
from bayesmap.slam.pipeline import (
    BURN_IN_ROUNDS,
    FINAL_MAP_SWEEPS,
    FRONT_END_PARTICLES,
    ROUNDS,
    hypothesis_counts,
    run_keyframe_slam,
)
from bayesmap.slam.problem import SLAM_ODOMETRY_ALPHAS, SlamProblem, log_slam_problem, slam_tutorial_problem
from bayesmap.viz.common import figure_bytes
from bayesmap.viz.maps import plot_occupancy_map
from bayesmap.viz.paths import plot_slam, slam_report

TUTORIAL_SLAM_SWEEPS = 60
"""``bayesmap slam``'s joint sweeps on the tutorial scene (a third burn-in): enough for the eight-pose loop's
posterior mean path to land far closer to the truth than the odometry it starts from (seed 0: ATE 0.046 m against
0.894 m)."""
TUTORIAL_SLAM_POSES = 8
"""Poses on the tutorial scene's loop (``--num-poses``)."""
LOG_SLAM_DEFAULTS = {"sweeps": ROUNDS, "burn_in": BURN_IN_ROUNDS}
"""``run_log_slam``'s own rounds and burn-in rounds: ``bayesmap slam --log`` without --sweeps and --burn-in runs them
(on a log, one "sweep" of the joint chain is a round: map sweeps given the poses, then pose sweeps given the map)."""


@dataclass(frozen=True)
class SlamRequest:
    """What ``bayesmap slam`` was asked: its options, named as they are; None where one was not given."""

    log: Optional[Path] = None
    bag: Optional[Path] = None
    scan_topic: str = "/scan"
    odom_topic: str = "/odom"
    tf: bool = False
    scans: Optional[str] = None
    resolution: Optional[float] = None
    sweeps: Optional[int] = None
    burn_in: Optional[int] = None
    seed: int = 0
    num_poses: Optional[int] = None
    keyframe_distance: Optional[float] = None
    keyframe_turn: Optional[float] = None
    tile_pairs: Optional[int] = None
    particles: Optional[int] = None
    branches: Optional[int] = None
    motion_alphas: Optional[str] = None
    rosmap: bool = False
    maps: bool = False
    report: bool = False
    out: Path = Path("bayesmap-out")
    force: bool = False


class SlamRun(NamedTuple):
    """A SLAM run: the ``problem`` (odometry ``(S, 3)``, readings ``(S, K)``, the true path where known), the
    ``result`` (:class:`~bayesmap.slam.joint.SlamResult`), the ``summary`` summary.json holds, ``stamps`` ``(S,)``
    float64 (trajectory.tum's: a log's scan timestamps, or scan indices), the figure's ``title`` and the
    ``keyframes`` ``(K,)`` int64 whose scans made the map (None: every scan)."""

    problem: SlamProblem
    result: SlamResult
    summary: dict
    stamps: np.ndarray
    title: str
    keyframes: Optional[np.ndarray] = None


class LogSlam(NamedTuple):
    """What :func:`log_slam` returns: the ``problem`` of the chosen scans, the ``result``
    (:class:`~bayesmap.slam.joint.SlamResult`), ``chosen`` ``(S,)`` int64 the log's scan indices, ``settings``
    (summary.json's) and ``keyframes`` ``(K,)`` int64, the problem's scans the chain and the map ran on."""

    problem: SlamProblem
    result: SlamResult
    chosen: np.ndarray
    settings: dict
    keyframes: np.ndarray


def slam_counts(sweeps: Optional[int], burn_in: Optional[int], default: dict) -> tuple[int, int]:
    """``(sweeps, burn_in)`` of a SLAM run: the given ones, ``default`` (``{"sweeps", "burn_in"}``) where neither
    is given, a third of the sweeps for a missing burn-in.

    Raises:
        BayesmapError: if the burn-in keeps no sweep.
    """
    if sweeps is None:
        sweeps = default["sweeps"]
        burn_in = default["burn_in"] if burn_in is None else burn_in
    burn_in = sweeps // 3 if burn_in is None else burn_in
    if burn_in >= sweeps:
        raise BayesmapError(f"--burn-in must be smaller than --sweeps ({sweeps}), got {burn_in}")
    return sweeps, burn_in


def run_simulated_slam(problem: SlamProblem, sweeps: int, burn_in: int, seed: int = 0,
                       progress: Optional[ProgressCallback] = None, title: str = "") -> SlamRun:
    """Run the joint chain on a simulated scene (its true path and map known) and score it: the path's ATE, RPE
    and 95 % ellipse coverage against the truth, the odometry's, and the map's wrong cells.

    Args:
        problem: a simulated :class:`~bayesmap.slam.problem.SlamProblem` (``true_poses`` and ``truth`` set).
        sweeps: joint sweeps (:func:`bayesmap.slam.joint.run_slam`), >= 1.
        burn_in: sweeps dropped, ``0 <= burn_in < sweeps``.
        seed: the chain's seed (and nothing else: the scene is simulated already).
        progress: called with a :class:`bayesmap.progress.Progress` (stage ``"joint chain"``, unit sweep) after
            each sweep.
        title: the figure's title.

    Raises:
        BayesmapError: on bad counts (named).
    """
    result = run_slam(problem, sweeps=sweeps, burn_in=burn_in, seed=seed, progress=progress)
    p = problem.params
    settings = {"sweeps": sweeps, "burn_in": burn_in, "seed": seed, "num_poses": problem.num_scans,
                "num_angles": p.num_angles, "prior_wall_prob": p.prior_wall_prob, "sensor_noise": p.sensor_noise,
                "odometry_alphas": list(SLAM_ODOMETRY_ALPHAS), "pose_kernel": "lattice_pose_mh",
                "map_kernel": "dense single-site Gibbs, raster order"}
    summary = {
        "source": problem.source,
        "settings": settings,
        "runtime_s": result.runtime_s,
        "acceptance_rate": result.acceptance_rate,
        "posterior": score_trajectory(result.mean_path, problem.true_poses, result.pose_cov,
                                      samples=result.pose_samples),
        "odometry": score_trajectory(problem.odometry, problem.true_poses),
        "map_cells_wrong": int(np.sum((result.posterior > 0.5) != (problem.truth > 0))),
    }
    return SlamRun(problem, result, summary, np.arange(problem.num_scans, dtype=np.float64), title)


def tutorial_slam(seed: int = 0, num_poses: Optional[int] = None, sweeps: Optional[int] = None,
                  burn_in: Optional[int] = None, progress: Optional[ProgressCallback] = None) -> SlamRun:
    """SLAM on the tutorial scene (:func:`bayesmap.slam.problem.slam_tutorial_problem`): ``num_poses`` poses on a
    loop (default :data:`TUTORIAL_SLAM_POSES`), :data:`TUTORIAL_SLAM_SWEEPS` sweeps by default.

    ``progress`` gets the stage "build problem" (:func:`bayesmap.progress.start_stage`) and the chain's reports.

    Raises:
        BayesmapError: on bad counts (named).
    """
    num_poses = TUTORIAL_SLAM_POSES if num_poses is None else num_poses
    sweeps, burn_in = slam_counts(sweeps, burn_in, {"sweeps": TUTORIAL_SLAM_SWEEPS, "burn_in": None})
    start_stage(progress, "build problem")
    problem = slam_tutorial_problem(seed=seed, num_poses=num_poses)
    title = f"bayesmap slam: {problem.num_scans} poses, {sweeps} sweeps"
    return run_simulated_slam(problem, sweeps, burn_in, seed, progress, title)


def log_slam(carmen, path: Path, scans: Optional[str] = None, resolution: Optional[float] = None,
             sweeps: Optional[int] = None, burn_in: Optional[int] = None, seed: int = 0, final_map: bool = True,
             progress: Optional[ProgressCallback] = None, notify: Optional[Callable[[str], None]] = None,
             keyframe_distance: float = KEYFRAME_DISTANCE, keyframe_turn: float = KEYFRAME_TURN,
             tile_pairs: int = TILE_PAIRS, particles: int = FRONT_END_PARTICLES, motion=None,
             branches: int = BRANCHES) -> LogSlam:
    """Run :func:`bayesmap.slam.pipeline.run_keyframe_slam` on the ``scans`` (a :func:`parse_scans` spec) of a log
    read from ``path``, its keyframes chosen by ``keyframe_distance`` meters and ``keyframe_turn`` radians
    (:func:`bayesmap.slam.keyframes.select_keyframes`; 0: every scan), its map blocks in tiles
    of at most ``tile_pairs`` pairs (:data:`bayesmap.inference.tiled.TILE_PAIRS`), its front end keeping ``particles``
    hypotheses (:data:`bayesmap.slam.pipeline.FRONT_END_PARTICLES`), at most ``branches`` branch points weighed
    (:data:`bayesmap.slam.branches.BRANCHES`), its motion noise ``motion``
    (:class:`bayesmap.model.motion.MotionParams`; None: the defaults); without ``final_map``, no final map (for
    scoring the path alone).

    Args:
        progress: passed on to ``run_log_slam``; a :class:`bayesmap.progress.StageRecorder` also gets the stage
            "build problem" (the problem and its size check; the time ``run_log_slam`` takes before its first
            report, the scans' data, counts in it too).
        notify: called with one line (the log, its scans and sweeps) before the long work starts.

    Returns:
        A :class:`LogSlam`.

    Raises:
        BayesmapError: on a bad scan selection or counts, or a problem too large to fit (named).
    """
    chosen = parse_scans(scans, len(carmen))
    resolution = scenes.RESOLUTION if resolution is None else resolution
    sweeps, burn_in = slam_counts(sweeps, burn_in, LOG_SLAM_DEFAULTS)
    start_stage(progress, "build problem")
    problem = log_slam_problem(carmen, chosen, resolution=resolution, motion=motion)
    keyframes = select_keyframes(problem.odometry, keyframe_distance, keyframe_turn)
    check_slam_size(keyframe_problem(problem, keyframes), tile_pairs)
    if notify is not None:
        notify(f"bayesmap slam: {path.name}, {len(chosen)} scans ({len(keyframes)} keyframes), {sweeps} sweeps ...")
    result = run_keyframe_slam(problem, keyframes, rounds=sweeps, burn_in=burn_in, seed=seed, progress=progress,
                               final_map_sweeps=FINAL_MAP_SWEEPS if final_map else 0, tile_pairs=tile_pairs,
                               particles=particles, branches=branches)
    p = problem.params
    settings = {"scans": scans if scans is not None else "all", "resolution": resolution,
                "keyframe_distance_m": float(keyframe_distance), "keyframe_turn_rad": float(keyframe_turn),
                "keyframes": int(len(keyframes)), "tile_pairs": int(tile_pairs),
                "front_end_particles": int(particles), "branches": int(branches), "sweeps": sweeps,
                "burn_in": burn_in, "seed": seed, "prior_wall_prob": float(p.prior_wall_prob),
                "sensor_noise": float(p.sensor_noise), "beam_model": p.beam_model, "geometry": p.geometry,
                "range_offset_m": float(problem.range_offset),
                "likelihood_power": float(problem.likelihood_power), "max_range_m": float(p.max_range),
                "motion": {name: float(getattr(problem.motion, name))
                           for name in ("a1", "a2", "a3", "a4", "floor_xy", "floor_theta")}}
    final = problem.final_map_params
    if result.chain_posterior is not None:  # posterior.npy is the final map at the mean path (run_log_slam stage 6)
        settings["final_map"] = {"sweeps": FINAL_MAP_SWEEPS, "burn_in": FINAL_MAP_SWEEPS // 2,
                                 "sensor_noise": float(result.final_map_noise), "geometry": final.geometry,
                                 "coupling": float(final.coupling), "wall_pass_prob": float(final.wall_pass_prob),
                                 "likelihood_power": float(result.final_map_power)}
    return LogSlam(problem, result, chosen, settings, np.asarray(keyframes, np.int64))


def slam_endpoints(problem: SlamProblem, path) -> np.ndarray:
    """``(N, 2)`` float64 world endpoints of the returned (not max-range) readings of ``problem``'s scans at
    ``path`` ``(S, 3)`` (x, y m, theta rad), meters."""
    ends = scan_endpoints(np.asarray(path, np.float64), problem.sensor_angles, problem.readings, xp=np)
    mask = problem.max_range_mask
    return ends.reshape(-1, 2) if mask is None else ends[~np.asarray(mask, bool)]


def loop_hypotheses_summary(hypotheses, num_samples: int) -> dict | None:
    """The last loop-closure round's hypotheses (:class:`bayesmap.slam.posegraph.LoopHypotheses`) as summary.json
    holds them: ``{"above_1_percent": how many weigh over 0.01, "weighed": how many were weighed (the empty set and
    the largest consistent sets), "consistent_sets": the maximal consistent sets found, "weights": the weights of
    the first five, "loop_edges": the loop edges of each of those, "samples": how many of the ``num_samples`` path
    samples each of those drew}`` (:func:`bayesmap.slam.pipeline.hypothesis_counts`); None without loop edges."""
    if hypotheses is None:
        return None
    return {"above_1_percent": int(np.sum(hypotheses.weights > 0.01)), "weighed": len(hypotheses.sets),
            "consistent_sets": int(hypotheses.enumerated),
            "weights": [float(w) for w in hypotheses.weights[:5]],
            "loop_edges": [len(c) for c in hypotheses.sets[:5]],
            "samples": [int(c) for c in hypothesis_counts(num_samples, hypotheses.weights)[:5]]}


def path_hypotheses_summary(hypotheses, scans) -> dict:
    """The start paths weighed where the front end's match and the odometry disagreed
    (:class:`bayesmap.slam.branches.PathHypotheses`, or None: no such step) as summary.json holds them:
    ``{"above_1_percent": how many weigh at least 0.01, "weighed": how many, "branch_scans": the log's scan index of
    each branch's odometry step (``scans`` ``(K,)``: the log's index of each keyframe; None for the front end's own
    path), "rejoin_scans": the log's scan index after which each branch's steps are the front end's (None for
    the front end's own path and a branch that never rejoined it), "disagreement": each step's squared Mahalanobis
    distance from the odometry, "evidence_nats": each path's evidence less the front end's, "weights", "chosen":
    the row the chain started from}``; with no branch point, the front end's path alone (one hypothesis, nothing
    weighed)."""
    if hypotheses is None:
        return {"above_1_percent": 1, "weighed": 1, "branch_scans": [None], "rejoin_scans": [None],
                "disagreement": [0.0], "evidence_nats": [0.0], "weights": [1.0], "chosen": 0}
    scans = np.asarray(scans)
    return {"above_1_percent": hypotheses.distinct, "weighed": len(hypotheses.weights),
            "branch_scans": [None if t == 0 else int(scans[t]) for t in hypotheses.odometry_steps],
            "rejoin_scans": [None if j <= 0 else int(scans[j]) for j in hypotheses.rejoined],
            "disagreement": [round(float(d), 2) for d in hypotheses.disagreement],
            "evidence_nats": [round(float(e - hypotheses.evidence[0]), 1) for e in hypotheses.evidence],
            "weights": [float(w) for w in hypotheses.weights], "chosen": int(hypotheses.chosen)}


def grid_summary(grid) -> dict:
    """A grid as summary.json holds it: ``{"shape": [nx, ny], "resolution": m, "origin": [x, y]}``."""
    return {"shape": [int(n) for n in grid.shape], "resolution": float(grid.resolution),
            "origin": [float(v) for v in grid.origin]}


def run_log_slam_job(carmen, path: Path, scans: Optional[str] = None, resolution: Optional[float] = None,
                     sweeps: Optional[int] = None, burn_in: Optional[int] = None, seed: int = 0,
                     progress: Optional[ProgressCallback] = None,
                     notify: Optional[Callable[[str], None]] = None,
                     keyframes: tuple[float, float] = (KEYFRAME_DISTANCE, KEYFRAME_TURN),
                     tile_pairs: int = TILE_PAIRS, particles: int = FRONT_END_PARTICLES, motion=None,
                     branches: int = BRANCHES) -> SlamRun:
    """SLAM on a real log or bag (:func:`log_slam`, its keyframes at ``keyframes`` = (meters, radians), its map
    blocks in tiles of at most ``tile_pairs`` pairs, its front end keeping ``particles`` hypotheses, at most
    ``branches`` branch points weighed, its motion noise ``motion``), with its
    summary; trajectory.tum's stamps are the scans' timestamps where they increase strictly, else their indices
    (:func:`bayesmap.io.tum.tum_stamps`).

    Raises:
        BayesmapError: as :func:`log_slam`.
    """
    problem, result, chosen, settings, kept = log_slam(carmen, path, scans, resolution, sweeps, burn_in, seed,
                                                       progress=progress, notify=notify,
                                                       keyframe_distance=keyframes[0], keyframe_turn=keyframes[1],
                                                       tile_pairs=tile_pairs, particles=particles, motion=motion,
                                                       branches=branches)
    all_stamps = tum_stamps(carmen.timestamps)
    grid = result.grid if result.grid is not None else problem.params.grid
    summary = {
        "source": problem.source,
        "settings": settings,
        "runtime_s": result.runtime_s,
        "num_scans": problem.num_scans,
        "num_beams": int(problem.readings.shape[1]),
        "pose_samples": int(len(result.pose_samples)),
        "acceptance_rate": result.acceptance_rate,
        "loop_edges": result.loop_edges,
        "loop_hypotheses": loop_hypotheses_summary(result.loop_hypotheses, len(result.pose_samples)),
        "front_end_hypotheses": result.front_end_hypotheses,
        "path_hypotheses": path_hypotheses_summary(result.path_hypotheses, chosen[kept]),
        "grid": grid_summary(grid),
        "trajectory_stamps": ("the scans' timestamps, seconds" if np.array_equal(all_stamps, carmen.timestamps)
                              else "scan indices of the log (its timestamps do not increase strictly)"),
    }
    title = f"bayesmap slam: {path.name}, {problem.num_scans} scans, {settings['sweeps']} sweeps"
    return SlamRun(problem, result, summary, all_stamps[chosen], title, kept)


def slam_files(run: SlamRun, report: bool = False, rosmap: bool = False, maps: bool = False,
               stages: Optional[StageRecorder] = None) -> dict[str, bytes]:
    """The output folder of a SLAM run, ``{name: bytes}``: trajectory.tum (the posterior mean pose per scan, at
    ``run.stamps``), trajectory_samples.npy ``(N, S, 3)``, pose_cov.npy ``(S, 3, 3)``, posterior.npy,
    posterior.png (the map with the paths), summary.json, and for a real log (no true map) occupancy.png (the map
    alone); with ``rosmap``, ``maps`` and ``report`` the maps and report.html as
    :func:`bayesmap.runs.infer.infer_files` writes them. The figures are cropped to the cells some beam of the
    keyframes (the scans the map was drawn from) crossed from the posterior mean path
    (:func:`bayesmap.io.maps_out.seen_cells_along`) and to where the readings returned (:func:`slam_endpoints`).

    With ``stages`` (a :class:`bayesmap.progress.StageRecorder`), the figures and the encoding of the files are its
    stages "figures" and "write outputs", and summary.json, encoded last, gets ``"stages"`` and ``"peak_rss_mb"``
    (:meth:`~bayesmap.progress.StageRecorder.summary`; ``run.summary`` is updated in place): the stages end when
    summary.json is encoded, before the folder is written. report.html's summary is the one without them."""
    problem, result = run.problem, run.result
    start_stage(stages, "figures")
    grid = result.grid if result.grid is not None else problem.params.grid
    mapped = slice(None) if run.keyframes is None else run.keyframes  # the scans the map was drawn from
    seen = seen_cells_along(grid, result.mean_path[mapped], problem.sensor_angles[mapped], problem.readings[mapped],
                            float(problem.params.max_range))
    focus = slam_endpoints(problem, result.mean_path)
    fig = plot_slam(grid, result.posterior, result.mean_path, result.pose_cov, result.pose_samples,
                    true_path=problem.true_poses, odometry=problem.odometry, truth=problem.truth, title=run.title,
                    seen=seen, focus=focus)
    png = figure_bytes(fig, "png")
    occupancy = None
    if problem.truth is None:  # a real log: the map alone too, without the paths over it
        occupancy = figure_bytes(plot_occupancy_map(grid, result.posterior, seen, title=run.title, focus=focus),
                                 "png")
    start_stage(stages, "write outputs")
    files = {
        "trajectory.tum": encode_tum(run.stamps, result.mean_path).encode(),
        "trajectory_samples.npy": npy_bytes(result.pose_samples),
        "pose_cov.npy": npy_bytes(result.pose_cov),
        "posterior.npy": npy_bytes(result.posterior.astype("float32")),
        "posterior.png": png,
        "summary.json": b"",  # (encoded last, below)
    }
    if occupancy is not None:
        files[OCCUPANCY_FILE] = occupancy
    if rosmap:
        files.update(encode_rosmap(ROSMAP_STEM, result.posterior, grid))
    if maps:
        files.update(map_files(result.posterior, grid, seen))
    if report:
        files[REPORT_FILE] = slam_report(png, run.summary, title=f"bayesmap slam: {problem.source}").encode("utf-8")
    run.summary.update(stage_summary(stages))
    files["summary.json"] = json_bytes(run.summary)
    return files


def check_slam_request(req: SlamRequest) -> None:
    """Refuse, before any work, contradictory options and an output folder that cannot be written.

    Raises:
        BayesmapError: naming the option or the folder.
    """
    if req.log is not None and req.bag is not None:
        raise BayesmapError("give either --log or --bag, not both")
    if req.log is None and req.bag is None:
        if (req.scans is not None or req.resolution is not None or req.keyframe_distance is not None
                or req.keyframe_turn is not None or req.tile_pairs is not None or req.particles is not None
                or req.branches is not None or req.motion_alphas is not None):
            raise BayesmapError("--scans, --resolution, --tile-pairs, --particles, --branches, --motion-alphas and "
                                "the keyframe options need --log FILE (or --bag PATH)")
    elif req.num_poses is not None:
        raise BayesmapError("--num-poses applies to the tutorial scene, not to --log / --bag")
    check_tile_pairs_option(req.tile_pairs)
    if req.particles is not None and req.particles < 1:
        raise BayesmapError(f"--particles must be at least 1, got {req.particles}")
    if req.branches is not None and req.branches < 0:
        raise BayesmapError(f"--branches must be at least 0, got {req.branches}")
    motion_option(req.motion_alphas)
    check_output_dir(req.out, req.force, owned=SLAM_OWNED_FILES)


def slam(req: SlamRequest, progress: Optional[ProgressCallback] = None,
         notify: Optional[Callable[[str], None]] = None) -> tuple[SlamRun, list[str]]:
    """``bayesmap slam``: check the request and its output folder, run SLAM on the log or bag (or the tutorial
    scene), write the outputs. Returns the run and the names written. ``progress`` gets every report of the long
    work through a :class:`bayesmap.progress.StageRecorder`, whose stages ("read log", "build problem", the
    library's, "figures", "write outputs") summary.json holds (:func:`slam_files`).

    Raises:
        BayesmapError: on a bad option, input or output (named), before any work where it can be told.
    """
    check_slam_request(req)
    stages = StageRecorder(progress)
    if req.log is not None or req.bag is not None:
        stages.start("read log")
    carmen = read_source(req.log, req.bag, req.scan_topic, req.odom_topic, req.tf, None)
    if carmen is None:
        run = tutorial_slam(req.seed, req.num_poses, req.sweeps, req.burn_in, stages)
    else:
        path = req.log if req.log is not None else req.bag
        keyframes = (KEYFRAME_DISTANCE if req.keyframe_distance is None else req.keyframe_distance,
                     KEYFRAME_TURN if req.keyframe_turn is None else req.keyframe_turn)
        run = run_log_slam_job(carmen, path, req.scans, req.resolution, req.sweeps, req.burn_in, req.seed,
                               stages, notify, keyframes, TILE_PAIRS if req.tile_pairs is None else req.tile_pairs,
                               FRONT_END_PARTICLES if req.particles is None else req.particles,
                               motion_option(req.motion_alphas),
                               BRANCHES if req.branches is None else req.branches)
    files = slam_files(run, report=req.report, rosmap=req.rosmap, maps=req.maps, stages=stages)
    return run, write_outputs(req.out, files, owned=SLAM_OWNED_FILES)


def summary_lines(run: SlamRun, out: Path, written: list[str]) -> list[str]:
    """The lines ``bayesmap slam`` prints: data, sweeps and acceptance, runtime, the path (against the truth where
    known, else its spread and the map's size), the start paths weighed where there were branch points
    (:func:`path_hypotheses_summary`), outputs."""
    problem, result, summary = run.problem, run.result, run.summary
    settings = summary["settings"]
    lines = [f"data:     {problem.source}, {problem.readings.shape[1]} beams per scan",
             f"sweeps:   {settings['sweeps']} (posterior over the last {settings['sweeps'] - settings['burn_in']}); "
             f"pose acceptance {result.acceptance_rate:.2f}",
             f"runtime:  {result.runtime_s:.2f} s (compilation included)"]
    if "posterior" in summary:
        post, odo = summary["posterior"], summary["odometry"]
        lines.append(f"path:     ATE {post['ate_rmse_m']:.3f} m (odometry {odo['ate_rmse_m']:.3f} m); 95 % ellipses "
                     f"cover {post['coverage']:.0%} of the true positions")
    else:
        sd = np.sqrt(np.clip(np.linalg.eigvalsh(np.asarray(result.pose_cov)[:, :2, :2])[:, -1], 0.0, None))
        g = summary["grid"]
        lines.append(f"path:     {problem.num_scans} poses; position sd median {np.median(sd):.3f} m, largest "
                     f"{sd.max():.3f} m; map {g['shape'][0]} x {g['shape'][1]} cells of {g['resolution']:g} m")
    weighed = summary.get("path_hypotheses")
    if weighed is not None and weighed["weighed"] > 1:
        chosen = weighed["branch_scans"][weighed["chosen"]]
        branches = weighed["branch_scans"][1:]
        at = ("scan " if len(branches) == 1 else "scans ") + ", ".join(str(t) for t in branches)
        lines.append(f"start:    {weighed['weighed']} paths weighed (the odometry's step at {at}); "
                     + ("the front end's own kept" if chosen is None else f"the one through scan {chosen} kept"))
    lines.append(f"outputs:  {out}/ ({', '.join(written)})")
    return lines
