"""The mapping job (``bayesmap infer`` and ``demo``, the app's Run inference): a scene from a map file or a log, its
posterior by Gibbs sampling (or log-odds mapping), and the output folder.

In data-flow order: :func:`infer_scene` (the problem an :class:`InferRequest` describes), :func:`run_infer` (the
job: result and summary), :func:`infer_files` (the output files' bytes), :func:`write_infer` (the folder and the
``--out-bag`` bag); :func:`infer` does all four after checking the outputs, and records each stage's wall time and
peak memory in summary.json (:class:`bayesmap.progress.StageRecorder`).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, Optional

import numpy as np

from bayesmap import scenes
from bayesmap.errors import BayesmapError
from bayesmap.inference.driver import InferenceResult, run_inference, run_logodds
from bayesmap.inference.tiled import TILE_PAIRS
from bayesmap.inference.traces import chain_traces
from bayesmap.io.ascii import load_map, tutorial_map
from bayesmap.io.maps_out import seen_cells_in_pieces
from bayesmap.io.rosbag import write_occupancy_grid_bag
from bayesmap.io.rosmap import encode_rosmap
from bayesmap.model import prior
from bayesmap.progress import ProgressCallback, StageRecorder, stage_summary, start_stage
from bayesmap.runs.inputs import (
    check_free_cell,
    check_problem_size,
    check_tile_pairs_option,
    coupling_option,
    parse_scans,
    read_source,
    sensor_params,
)
from bayesmap.runs.outputs import (
    DIAGNOSTICS_FILE,
    REPORT_FILE,
    ROSMAP_STEM,
    check_out_bag,
    check_output_dir,
    json_bytes,
    map_files,
    npy_bytes,
    write_outputs,
)
from bayesmap.scenes import log_problem, scan_problem, tutorial_problem
from bayesmap.slam.keyframes import select_keyframes
from bayesmap.viz.common import figure_bytes
from bayesmap.viz.maps import plot_posterior, plot_posterior_path
from bayesmap.viz.report import build_report


@dataclass(frozen=True)
class InferRequest:
    """What ``bayesmap infer`` was asked: its options, named as they are (``--map`` is ``map_file``); None where
    an option was not given (its default then depends on the scene, see ``bayesmap infer --help``)."""

    map_file: Optional[Path] = None
    log: Optional[Path] = None
    bag: Optional[Path] = None
    scan_topic: str = "/scan"
    odom_topic: str = "/odom"
    tf: bool = False
    scan: Optional[int] = None
    scans: Optional[str] = None
    resolution: float = scenes.RESOLUTION
    max_range: Optional[float] = None
    method: str = "gibbs"
    beam_model: Optional[str] = None
    range_offset: Optional[float] = None
    geometry: Optional[str] = None
    wall_pass_prob: Optional[float] = None
    cut_past_reading: Optional[float] = None
    keyframe_distance: Optional[float] = None
    keyframe_turn: Optional[float] = None
    tile_pairs: Optional[int] = None
    beam_weights: Optional[str] = None
    lambda_short: Optional[float] = None
    likelihood_power: Optional[float] = None
    coupling: Optional[float] = None
    run_length: Optional[float] = None
    sampler: Optional[str] = None
    sweeps: int = 100
    burn_in: Optional[int] = None
    prior_wall_prob: Optional[float] = None
    sensor_noise: Optional[float] = None
    num_angles: int = scenes.TUTORIAL_NUM_ANGLES
    pos: Optional[tuple[float, float]] = None
    seed: int = 0
    chains: int = 1
    report: bool = False
    rosmap: bool = False
    maps: bool = False
    out_bag: Optional[Path] = None
    out: Path = Path("bayesmap-out")
    force: bool = False


class InferRun(NamedTuple):
    """A mapping run: its ``result`` (posterior ``(nx, ny)``, samples, diagnostics) and ``summary`` (the settings
    and figures summary.json holds)."""

    result: InferenceResult
    summary: dict


class InferOutcome(NamedTuple):
    """What :func:`infer` did: the ``problem`` mapped, the :class:`InferRun`, and the names ``written`` (the
    output folder's files, then the ``--out-bag`` path)."""

    problem: scenes.Problem
    run: InferRun
    written: list


def check_infer_request(req: InferRequest) -> None:
    """Refuse, before any work, contradictory options and outputs that cannot be written (the folder, the bag).

    Raises:
        BayesmapError: naming the option or the path.
    """
    if req.method not in ("gibbs", "logodds"):
        raise BayesmapError(f"unknown method {req.method!r}; choose gibbs or logodds")
    if req.method == "logodds" and (req.report or req.chains != 1):
        raise BayesmapError("--report and --chains need --method gibbs (log-odds mapping has no chain)")
    if req.log is None and req.bag is None:
        if req.scan is not None or req.scans is not None or req.likelihood_power is not None \
                or req.max_range is not None:
            raise BayesmapError("--scan, --scans, --likelihood-power and --max-range need --log FILE (or --bag)")
        if (req.geometry is not None or req.wall_pass_prob is not None or req.cut_past_reading is not None
                or req.keyframe_distance is not None or req.keyframe_turn is not None or req.tile_pairs is not None):
            raise BayesmapError("--geometry, --wall-pass-prob, --cut-past-reading, --tile-pairs and the keyframe "
                                "options apply to several scans of --log FILE (or --bag); maps keep the tutorial's "
                                "entry geometry, walls and whole beams")
    elif req.map_file is not None:
        raise BayesmapError("give either --map or --log / --bag, not both")
    check_tile_pairs_option(req.tile_pairs)
    check_output_dir(req.out, req.force)
    if req.out_bag is not None:
        check_out_bag(req.out_bag, req.force)


def infer_scene(req: InferRequest, progress: Optional[ProgressCallback] = None) -> tuple[scenes.Problem, str]:
    """``(problem, title)`` of a request: a log's scans (``--log`` / ``--bag``) or a map file's simulated readings.
    A :class:`bayesmap.progress.StageRecorder` as ``progress`` gets the stages "read log" (a log or bag) and
    "build problem".

    Raises:
        BayesmapError: on a bad option value or input file (named).
    """
    params = sensor_params(req.beam_weights, req.lambda_short)
    carmen_like = req.log is not None or req.bag is not None
    coupling = coupling_option(req.coupling, req.run_length, req.resolution if carmen_like else 1.0)
    if carmen_like:
        start_stage(progress, "read log")
    carmen = read_source(req.log, req.bag, req.scan_topic, req.odom_topic, req.tf, req.max_range)
    start_stage(progress, "build problem")
    if carmen is not None:
        problem, title = _log_scene(carmen, req, params, coupling)
    else:
        problem = _map_scene(req, params, coupling)
        title = problem.source
    return problem, ("Log-odds occupancy, " if req.method == "logodds" else "Posterior wall probability, ") + title


def _log_scene(carmen, req: InferRequest, params: dict, coupling):
    """``(problem, title)`` of ``infer --log/--bag``: one scan (``--scan N``, the single-scan model and the tutorial's
    defaults) or several (``--scans``, the log defaults of :mod:`bayesmap.scenes`). Walls a beam can pass
    (``wall_pass_prob`` > 0) need the cellwise sampler, so with another sampler the default is 0 (opaque walls)."""
    name = (req.log if req.log is not None else req.bag).name
    if req.scan is not None and req.scans is not None:
        raise BayesmapError("give either --scan N or --scans SPEC, not both")
    if req.scan is not None:
        if req.range_offset is not None or req.likelihood_power is not None:
            raise BayesmapError("--range-offset and --likelihood-power apply to several scans (--scans), "
                                "not to --scan N")
        if (req.geometry is not None or req.wall_pass_prob is not None or req.cut_past_reading is not None
                or req.keyframe_distance is not None or req.keyframe_turn is not None or req.tile_pairs is not None):
            raise BayesmapError("--geometry, --wall-pass-prob, --cut-past-reading, --tile-pairs and the keyframe "
                                "options apply to several scans (--scans), not to --scan N")
        scan = int(parse_scans(str(req.scan), len(carmen))[0])  # a negative index counts from the end, as in --scans
        problem = scan_problem(
            carmen, scan, resolution=req.resolution,
            prior_wall_prob=scenes.TUTORIAL_PRIOR if req.prior_wall_prob is None else req.prior_wall_prob,
            sensor_noise=scenes.SCAN_SENSOR_NOISE if req.sensor_noise is None else req.sensor_noise,
            beam_model=req.beam_model or scenes.TUTORIAL_BEAM_MODEL, sensor_params=params,
            coupling=prior.DEFAULT_COUPLING if coupling is None else coupling)
        return problem, f"{name} scan {scan}"
    chosen = parse_scans(req.scans, len(carmen))
    keyframes = (_given(req.keyframe_distance, scenes.LOG_KEYFRAME_DISTANCE),
                 _given(req.keyframe_turn, scenes.LOG_KEYFRAME_TURN))
    chosen = chosen[select_keyframes(carmen.poses[chosen], *keyframes)]
    wall_pass_prob = scenes.log_wall_pass_prob(req.sampler) if req.wall_pass_prob is None else req.wall_pass_prob
    problem = log_problem(carmen, chosen, resolution=req.resolution, prior_wall_prob=req.prior_wall_prob,
                          sensor_noise=req.sensor_noise, beam_model=req.beam_model or scenes.LOG_BEAM_MODEL,
                          range_offset=req.range_offset, sensor_params=params, likelihood_power=req.likelihood_power,
                          geometry=scenes.LOG_GEOMETRY if req.geometry is None else req.geometry, coupling=coupling,
                          wall_pass_prob=wall_pass_prob,
                          cut_past_reading=_given(req.cut_past_reading, scenes.LOG_CUT_PAST_READING))
    problem.extra.update(keyframe_distance_m=float(keyframes[0]), keyframe_turn_rad=float(keyframes[1]))
    return problem, f"{name}, {len(chosen)} scans"


def _given(value, default):
    return default if value is None else value


def _map_scene(req: InferRequest, params: dict, coupling):
    """The problem of ``infer --map`` (or the tutorial map): readings simulated from the sensor at ``pos`` (default
    the map's center, the tutorial's ``GRID_SIZE // 2``), which must be a free cell."""
    walls = load_map(req.map_file) if req.map_file is not None else tutorial_map()
    source = str(req.map_file) if req.map_file else "tutorial map"
    center = (float(walls.shape[0] // 2), float(walls.shape[1] // 2))
    if req.pos is not None:
        check_free_cell(walls, req.pos, str(req.map_file) if req.map_file else "the tutorial map")
    return tutorial_problem(
        walls, pos=req.pos if req.pos is not None else center, seed=req.seed,
        prior_wall_prob=scenes.TUTORIAL_PRIOR if req.prior_wall_prob is None else req.prior_wall_prob,
        sensor_noise=scenes.TUTORIAL_SENSOR_NOISE if req.sensor_noise is None else req.sensor_noise,
        num_angles=req.num_angles, source=source, beam_model=req.beam_model or scenes.TUTORIAL_BEAM_MODEL,
        sensor_params=params, coupling=prior.DEFAULT_COUPLING if coupling is None else coupling)


def run_infer(problem: scenes.Problem, method: str = "gibbs", sampler: str = "block", sweeps: int = 100,
              burn_in: Optional[int] = None, seed: int = 0, chains: int = 1,
              progress: Optional[ProgressCallback] = None, tile_pairs: int = TILE_PAIRS) -> InferRun:
    """Map ``problem``: its posterior by Gibbs sampling (:func:`bayesmap.inference.driver.run_inference`), or with
    ``method="logodds"`` classic log-odds mapping (:func:`~bayesmap.inference.driver.run_logodds`), after refusing
    a problem too large to fit (:func:`bayesmap.runs.inputs.check_problem_size`, on the whole table's pairs: they
    bound the work as well as the memory, and the per-sweep records grow with the grid whatever the tiles). On a log
    (several scans) the cellwise sampler holds at most ``tile_pairs`` pairs at once (a tile of the grid at a time
    beyond) and log-odds mapping one piece of the table (:meth:`bayesmap.problem.Problem.table_chunks`); other
    samplers hold the whole table.

    Args:
        problem: the scene.
        method: ``"gibbs"`` or ``"logodds"``.
        sampler: the sampler's name (:data:`bayesmap.inference.registry.SAMPLERS`).
        sweeps: sweeps per chain, >= 1.
        burn_in: sweeps dropped before averaging; default half.
        seed: the chain's seed.
        chains: chains run at once, >= 1.
        progress: called with a :class:`bayesmap.progress.Progress` after each chunk of sweeps; a
            :class:`bayesmap.progress.StageRecorder` also gets the stage "log-odds mapping" (``method="logodds"``,
            which reports nothing itself).

    Raises:
        BayesmapError: on a problem too large, or bad settings (named).
    """
    check_problem_size(problem, chains=chains)
    if method == "logodds":
        start_stage(progress, "log-odds mapping")
        result = run_logodds(problem)
    else:
        result = run_inference(problem, sampler=sampler, sweeps=sweeps, burn_in=burn_in, seed=seed, chains=chains,
                               progress=progress, tile_pairs=tile_pairs)
    return InferRun(result, result.summary)


def _holds_table(problem: scenes.Problem, method: str, sampler: str) -> bool:
    """Whether a mapping run holds the whole ray-cell table: not on a log mapped by the cellwise sampler (a tile at a
    time) or by log-odds mapping (a piece at a time)."""
    return not (problem.multi_scan and (method == "logodds" or sampler == "cellwise"))


def infer_seen(problem: scenes.Problem) -> np.ndarray:
    """``(nx, ny)`` bool, the cells some beam of ``problem`` crossed (:func:`bayesmap.io.maps_out.seen_cells`, a
    piece of the table at a time: :meth:`bayesmap.problem.Problem.table_chunks`)."""
    return seen_cells_in_pieces(problem.table_chunks(), problem.ray_readings, problem.grid.shape)


def infer_files(problem: scenes.Problem, run: InferRun, title: str, seed: int = 0, method: str = "gibbs",
                report: bool = False, rosmap: bool = False, maps: bool = False,
                seen: Optional[np.ndarray] = None, stages: Optional[StageRecorder] = None) -> dict[str, bytes]:
    """The output folder of a mapping run, ``{name: bytes}``: posterior.npy, readings.npy, posterior.png and
    summary.json; diagnostics.npz with several chains; map.pgm / map.yaml with ``rosmap``; posterior.npz and the
    16-bit maps with ``maps``; report.html with ``report`` (its chain's traces replayed with ``seed``). ``seen``:
    ``(nx, ny)`` bool, the cells some beam crossed (:func:`infer_seen`, computed here if None and needed): the
    figure of several scans is cropped to them and to where the readings returned
    (:attr:`bayesmap.problem.Problem.returned_endpoints`), and ``maps`` records them.

    With ``stages`` (a :class:`bayesmap.progress.StageRecorder`), the figure, the report and the encoding of the
    other files are its stages "figures", "report" and "write outputs", and summary.json, encoded last, gets
    ``"stages"`` and ``"peak_rss_mb"`` (:meth:`~bayesmap.progress.StageRecorder.summary`; ``run.summary`` is
    updated in place): the stages end when summary.json is encoded, before the folder and ``--out-bag`` are
    written. report.html's summary is the one without them."""
    result = run.result
    start_stage(stages, "figures")
    if problem.multi_scan:  # a whole log: the posterior with its standard deviation and the path (too many beams)
        fig = plot_posterior_path(problem.grid, result.posterior, problem.pos, title=title, std=method != "logodds",
                                  seen=infer_seen(problem) if seen is None else seen,
                                  focus=problem.returned_endpoints)
    else:
        fig = plot_posterior(problem.grid, result.posterior, truth=problem.truth, pos=problem.pos,
                             beam_angles=problem.beam_angles, readings=problem.readings,
                             max_range_mask=problem.max_range_mask, title=title)
    png = figure_bytes(fig, "png")
    report_html = None
    if report:
        start_stage(stages, "report")
        traces = chain_traces(problem, result, seed=seed)
        report_html = build_report(problem, result, traces, title=title).encode("utf-8")
    start_stage(stages, "write outputs")
    files = {"posterior.npy": npy_bytes(result.posterior.astype("float32")),
             "readings.npy": npy_bytes(problem.readings.astype("float32")),
             "posterior.png": png,
             "summary.json": b""}  # (encoded last, below)
    if result.diagnostics is not None:
        buf = io.BytesIO()
        np.savez(buf, r_hat=result.diagnostics["r_hat"], ess=result.diagnostics["ess"])
        files[DIAGNOSTICS_FILE] = buf.getvalue()
    if rosmap:
        files.update(encode_rosmap(ROSMAP_STEM, result.posterior, problem.grid))
    if maps:
        files.update(map_files(result.posterior, problem.grid, infer_seen(problem) if seen is None else seen))
    if report_html is not None:
        files[REPORT_FILE] = report_html
    run.summary.update(stage_summary(stages))
    files["summary.json"] = json_bytes(run.summary)
    return files


def write_infer(out: Path, files: dict[str, bytes], problem: scenes.Problem, run: InferRun,
                out_bag: Optional[Path] = None, force: bool = False, seen: Optional[np.ndarray] = None) -> list[str]:
    """Write the output folder ``out`` (whole, :func:`bayesmap.runs.outputs.write_outputs`), then the posterior as
    an OccupancyGrid into ``out_bag`` (replacing one there with ``force``); returns the names written.

    Raises:
        BayesmapError: naming a path that cannot be written.
    """
    written = write_outputs(out, files)
    if out_bag is not None:
        seen = infer_seen(problem) if seen is None else seen
        write_occupancy_grid_bag(out_bag, np.clip(run.result.posterior, 0.0, 1.0), problem.grid, seen,
                                 overwrite=force)
        written.append(str(out_bag))
    return written


def infer(req: InferRequest, progress: Optional[ProgressCallback] = None) -> InferOutcome:
    """``bayesmap infer``: check the request and its outputs, build the scene, map it, write the outputs.
    ``progress`` gets every report of the long work through a :class:`bayesmap.progress.StageRecorder`, whose
    stages ("read log", "build problem", "ray-cell table", the sampler's "sweeps", "figures", "write outputs")
    summary.json holds (:func:`map_and_write`).

    Raises:
        BayesmapError: on a bad option, input or output (named), before any work where it can be told.
    """
    check_infer_request(req)
    stages = StageRecorder(progress)
    problem, title = infer_scene(req, stages)
    sampler = req.sampler or ("cellwise" if problem.multi_scan else "block")
    return map_and_write(problem, title, req, sampler, stages)


def map_and_write(problem: scenes.Problem, title: str, req: InferRequest, sampler: str,
                  progress: Optional[ProgressCallback] = None) -> InferOutcome:
    """Map ``problem`` with the request's settings and write its outputs (:func:`run_infer`, :func:`infer_files`,
    :func:`write_infer`); ``demo`` calls it on the tutorial scene. With a :class:`bayesmap.progress.StageRecorder`
    as ``progress``, a problem of several scans builds its ray-cell table as the stage "ray-cell table" (after the
    size check), and summary.json gets the stages (:func:`infer_files`).

    Raises:
        BayesmapError: as those functions.
    """
    check_output_dir(req.out, req.force)
    tile_pairs = TILE_PAIRS if req.tile_pairs is None else req.tile_pairs
    if problem.multi_scan and isinstance(progress, StageRecorder) \
            and _holds_table(problem, req.method, sampler):
        check_problem_size(problem, chains=req.chains)  # (before the table is built)
        progress.start("ray-cell table")
        problem.table  # noqa: B018 (built on first use and kept: the sampler and the figure's seen cells read it)
    run = run_infer(problem, req.method, sampler, req.sweeps, req.burn_in, req.seed, req.chains, progress,
                    tile_pairs)
    recorder = progress if isinstance(progress, StageRecorder) else None
    start_stage(recorder, "figures")
    seen = infer_seen(problem) if (req.maps or req.out_bag is not None or problem.multi_scan) else None
    files = infer_files(problem, run, title, seed=req.seed, method=req.method, report=req.report, rosmap=req.rosmap,
                        maps=req.maps, seen=seen, stages=recorder)
    written = write_infer(req.out, files, problem, run, out_bag=req.out_bag, force=req.force, seen=seen)
    return InferOutcome(problem, run, written)


def summary_lines(summary: dict, out: Path, written: list[str]) -> list[str]:
    """The lines ``bayesmap infer`` and ``demo`` print: sampler, data, sweeps, runtime, accuracy (a scene with a
    truth), chains (with several), outputs."""
    beams = (f"{summary['num_scans']} scans, {summary['num_beams']} beams" if "num_scans" in summary
             else f"{summary['num_angles']} beams")
    shape = summary["grid"]["shape"]
    lines = [f"sampler:  {summary['sampler']} ({summary['sampler_description']})",
             f"data:     {summary['source']}, {beams}, grid {shape[0]} x {shape[1]} cells of "
             f"{summary['grid']['resolution']:g} m"]
    if "sweeps" in summary:
        lines.append(f"sweeps:   {summary['sweeps']} (posterior mean over the last "
                     f"{summary['sweeps'] - summary['burn_in']})")
    lines.append(f"runtime:  {summary['runtime_s']:.2f} s (compilation included)")
    if "wrong_visible_cells" in summary:
        lines.append(f"accuracy: {summary['wrong_visible_cells']} of {summary['visible_cells']} visible cells wrong")
    if summary.get("chains", 1) > 1 and summary.get("r_hat_max") is not None:
        lines.append(f"chains:   {summary['chains']}; over the {summary['cells_varying']} cells that change: worst "
                     f"split R-hat {summary['r_hat_max']:.3f}, smallest effective sample size "
                     f"{summary['ess_min']:.0f}")
    lines.append(f"outputs:  {out}/ ({', '.join(written)})")
    return lines
