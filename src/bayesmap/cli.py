"""The ``bayesmap`` command line (typer).

User errors (bad files, values, folders) print one line ``error: ...`` on stderr and exit with code 2.
"""

from __future__ import annotations

import io
import json
import math
import os
import sys
from pathlib import Path
from typing import Optional

import jax
import numpy as np
import typer

from bayesmap import scenes  # the scene defaults
from bayesmap.bench import format_table, run_bench
from bayesmap.errors import BayesmapError
from bayesmap.evaluation.heldout import evaluate_log, evaluate_truth
from bayesmap.evaluation.trajectory import score_trajectory
from bayesmap.inference.driver import run_inference, run_logodds
from bayesmap.inference.registry import SAMPLERS
from bayesmap.inference.traces import chain_traces
from bayesmap.io.ascii import load_map, tutorial_map
from bayesmap.io.carmen import CarmenLog, read_carmen
from bayesmap.io.files import check_replaceable_folder, read_bytes, replace_folder, write_atomic
from bayesmap.io.maps_out import (
    NPZ_FILE,
    encode_png16,
    encode_posterior_npz,
    posterior_std,
    seen_cells,
    seen_cells_along,
)
from bayesmap.io.rosbag import STORAGES, read_bag, write_log_bag, write_occupancy_grid_bag
from bayesmap.io.rosmap import encode_rosmap, read_rosmap
from bayesmap.io.tum import encode_tum, match_stamps, read_tum, tum_stamps
from bayesmap.model import prior
from bayesmap.model.prior import check_coupling, coupling_for_run_length
from bayesmap.scenes import log_problem, scan_problem, tutorial_problem
from bayesmap.slam.joint import run_slam
from bayesmap.slam.pipeline import BURN_IN_ROUNDS, FINAL_MAP_SWEEPS, GRAPH_COV_SCALE, ROUNDS, run_log_slam
from bayesmap.slam.problem import SLAM_ODOMETRY_ALPHAS, log_slam_problem, slam_tutorial_problem
from bayesmap.viz.common import figure_bytes
from bayesmap.viz.maps import plot_posterior, plot_posterior_path
from bayesmap.viz.paths import plot_slam, slam_report
from bayesmap.viz.report import build_report


def parse_scans(spec: str | None, num_scans: int) -> np.ndarray:
    """Scan indices from a spec: None or ``"all"`` (every scan), ``"i"`` (one), ``"a:b"`` or ``"a:b:step"``
    (Python slice syntax, any part may be empty), or a comma-separated list of those.

    Raises:
        BayesmapError: on a malformed spec, an index out of range, or no scan selected.
    """
    if spec is None or spec.strip().lower() == "all":
        return np.arange(num_scans)
    chosen = []
    for part in spec.split(","):
        part = part.strip()
        try:
            if ":" in part:
                bits = [int(b) if b.strip() else None for b in part.split(":")]
                if len(bits) > 3 or (len(bits) == 3 and bits[2] is not None and bits[2] <= 0):
                    raise ValueError
                chosen.append(np.arange(num_scans)[slice(*bits)])
            else:
                index = int(part)
        except ValueError:  # (BayesmapError is a ValueError too: none is raised inside)
            raise BayesmapError(f"bad scan selection {part!r}: use an index, a range a:b or a:b:step, "
                                "or 'all'") from None
        if ":" not in part:
            if not (-num_scans <= index < num_scans):
                raise BayesmapError(f"scan {index} is out of range: the log has {num_scans} scans (0..{num_scans - 1})")
            chosen.append(np.array([index % num_scans]))
    scans = np.unique(np.concatenate(chosen)) if chosen else np.zeros(0, int)
    if len(scans) == 0:
        raise BayesmapError(f"the scan selection {spec!r} selects no scan of the {num_scans}")
    return scans


app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Bayesian occupancy-grid mapping from range scans, with honest uncertainty.")

OUTPUT_FILES = ("posterior.npy", "readings.npy", "posterior.png", "summary.json")
DIAGNOSTICS_FILE = "diagnostics.npz"  # written with --chains >= 2
REPORT_FILE = "report.html"  # written by demo, and by infer --report
ROSMAP_STEM = "map"  # infer --rosmap writes map.pgm and map.yaml (ROS map_server)
ROSMAP_FILES = (ROSMAP_STEM + ".pgm", ROSMAP_STEM + ".yaml")
MAPS_FILES = (NPZ_FILE, "probability.png", "probability.yaml", "std.png", "std.yaml")  # infer --maps
ALL_OUTPUT_FILES = OUTPUT_FILES + (DIAGNOSTICS_FILE, REPORT_FILE) + ROSMAP_FILES + MAPS_FILES
"""Every file a run may write into its output folder (an old run's that the new one does not write are removed)."""


def _check_output_dir(out: Path, force: bool) -> None:
    """Fail before any work if ``out`` cannot be written or would overwrite files without ``--force``."""
    if out.exists() and not out.is_dir():
        raise BayesmapError(f"output folder {str(out)!r} exists and is not a folder")
    if out.is_dir() and not force:
        clash = [name for name in ALL_OUTPUT_FILES if (out / name).exists()]
        if clash:
            raise BayesmapError(f"{str(out / clash[0])!r} already exists; pass --force to replace bayesmap's outputs "
                                f"in {str(out)!r}")

    check_replaceable_folder(out, ALL_OUTPUT_FILES)
    parent = out if out.is_dir() else out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BayesmapError(f"output folder {str(out)!r} cannot be written (no write permission on {str(parent)!r})")


def _write_outputs(out: Path, files: dict[str, bytes]) -> None:
    """Replace the output folder ``out`` as a whole by one holding ``files`` (plus the user's own files already
    there): see :func:`bayesmap.io.files.replace_folder`."""

    replace_folder(out, files, owned=ALL_OUTPUT_FILES)


def _npy(array) -> bytes:

    buf = io.BytesIO()
    np.save(buf, np.asarray(array))
    return buf.getvalue()


def _check_free_cell(walls, pos, source: str) -> None:
    """Refuse a sensor position ``pos`` (x, y in cells of ``walls`` ``(nx, ny)``) that lies in a wall cell, naming
    the cell (positions outside the map are refused later, by :meth:`Grid.check_inside`)."""
    i, j = (int(math.floor(v + 0.5)) for v in pos)  # cell (i, j) spans [i - 0.5, i + 0.5) (the tutorial's frame)
    if 0 <= i < walls.shape[0] and 0 <= j < walls.shape[1] and walls[i, j] > 0.5:
        raise BayesmapError(f"sensor position ({pos[0]:g}, {pos[1]:g}) is in wall cell ({i}, {j}) of {source}; "
                            "put the sensor in a free cell ('.')")


def _beam_cells(length: float, resolution: float, beam_angles) -> float:
    """An upper bound on the (beam, cell) pairs of beams at ``beam_angles`` (radians) of ``length`` meters on a
    grid of ``resolution`` meters per cell: at most ``length (|cos a| + |sin a|) / resolution + 2`` cells each (one
    new cell per grid line crossed; Amanatides & Woo 1987)."""

    a = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
    return float(np.sum(length * (np.abs(np.cos(a)) + np.abs(np.sin(a))) / resolution + 2.0))


def _check_sizes(shape: tuple[int, int], resolution: float, pairs: float, chains: int = 1) -> None:
    """Refuse a grid of ``shape`` cells over :data:`MAX_GRID_CELLS` (times ``chains``), or a ray-cell table of
    ``pairs`` (estimated) pairs over :data:`MAX_MEMORY_BYTES` at :data:`BYTES_PER_PAIR`, naming the figure and the
    way out."""
    nx, ny = shape
    if nx * ny * max(chains, 1) > MAX_GRID_CELLS:
        raise BayesmapError(f"the grid would have {nx:,} x {ny:,} = {nx * ny:,} cells of {resolution:g} m (x {chains} "
                            f"chains; at most {MAX_GRID_CELLS:,}): use a coarser --resolution, fewer --chains or fewer "
                            "--scans (a far-away pose widens the grid)")
    if pairs * BYTES_PER_PAIR > MAX_MEMORY_BYTES:
        raise BayesmapError(f"the ray-cell table would take about {pairs * BYTES_PER_PAIR / 1e9:,.0f} GB ({pairs:,.0f} "
                            f"(beam, cell) pairs; at most {MAX_MEMORY_BYTES / 1e9:g} GB): use a coarser --resolution, "
                            "fewer --scans, fewer poses or beams, or a shorter --max-range")


def check_problem_size(problem, chains: int = 1) -> None:
    """Refuse, before anything is allocated, a problem whose grid or ray-cell table cannot fit in memory
    (:func:`_check_sizes`); a beam's length is bounded by the max distance and the grid's diagonal.

    Raises:
        BayesmapError: naming the grid's cells or the estimated pairs and gigabytes, and the way out.
    """
    grid = problem.grid
    if grid.num_cells * max(chains, 1) > MAX_GRID_CELLS:
        _check_sizes(grid.shape, grid.resolution, 0.0, chains)
    length = min(float(problem.params.max_range), math.hypot(*grid.shape) * grid.resolution)
    _check_sizes(grid.shape, grid.resolution, _beam_cells(length, grid.resolution, problem.ray_angles), chains)


MIN_TRUTH_RESOLUTION = 0.01
"""Meters per pixel: the finest floor plan ``evaluate --truth`` takes (its poses keep 0.5 m of clearance, checked
over a square of ``(2 * 0.5 / resolution + 1) ** 2`` shifted copies of the map)."""


def _check_truth_scene(truth: Path, resolution: float, num_poses: int, num_angles: int, max_range: float) -> None:
    """Refuse an ``evaluate --truth`` scene that cannot be simulated or cannot fit, before any work: a floor plan
    finer than :data:`MIN_TRUTH_RESOLUTION`, a max range shorter than one cell, or sizes over
    :func:`_check_sizes`' limits."""

    grid = read_rosmap(truth, resolution=resolution if truth.suffix.lower() == ".pgm" else None).grid
    if grid.resolution < MIN_TRUTH_RESOLUTION:
        raise BayesmapError(f"{truth}: {grid.resolution:g} m per pixel is finer than {MIN_TRUTH_RESOLUTION:g} m; "
                            "resample the floor plan (or give a bare .pgm a coarser --resolution)")
    if max_range < grid.resolution:
        raise BayesmapError(f"--max-range {max_range:g} m is shorter than one cell of {truth} ({grid.resolution:g} m): "
                            "no beam would cross a cell")
    length = min(max_range, math.hypot(*grid.shape) * grid.resolution)

    angles = np.linspace(0, 2 * np.pi, num_angles, endpoint=False)
    _check_sizes(grid.shape, grid.resolution, num_poses * _beam_cells(length, grid.resolution, angles))


def _run_and_write(problem, sampler: str, sweeps: int, burn_in: Optional[int], seed: int, out: Path, force: bool,
                   title: str, chains: int = 1, report: bool = False, method: str = "gibbs",
                   rosmap: bool = False, maps: bool = False, out_bag: Optional[Path] = None) -> tuple[dict, list[str]]:
    """Map ``problem`` (Gibbs sampling, or log-odds mapping with ``method="logodds"``) and write the outputs into
    ``out`` (and the OccupancyGrid bag ``out_bag``, after the folder); returns the summary and the names of the files
    written."""

    _check_output_dir(out, force)
    if out_bag is not None:
        _check_out_bag(out_bag, force)
    check_problem_size(problem, chains=chains)
    if method == "logodds":
        result = run_logodds(problem)
    else:
        result = run_inference(problem, sampler=sampler, sweeps=sweeps, burn_in=burn_in, seed=seed, chains=chains)
    if problem.multi_scan:
        # a whole log: the posterior with its standard deviation and the robot's path (too many beams to draw)
        fig = plot_posterior_path(problem.grid, result.posterior, problem.pos, title=title, std=method != "logodds")
    else:
        fig = plot_posterior(problem.grid, result.posterior, truth=problem.truth, pos=problem.pos,
                             beam_angles=problem.beam_angles, readings=problem.readings,
                             max_range_mask=problem.max_range_mask, title=title)
    files = {
        "posterior.npy": _npy(result.posterior.astype("float32")),
        "readings.npy": _npy(problem.readings.astype("float32")),
        "posterior.png": figure_bytes(fig, "png"),
        "summary.json": (json.dumps(result.summary, indent=2) + "\n").encode(),
    }
    if result.diagnostics is not None:

        buf = io.BytesIO()
        np.savez(buf, r_hat=result.diagnostics["r_hat"], ess=result.diagnostics["ess"])
        files[DIAGNOSTICS_FILE] = buf.getvalue()
    if rosmap:

        files.update(encode_rosmap(ROSMAP_STEM, result.posterior, problem.grid))
    seen = seen_cells(problem.table, problem.ray_readings) if (maps or out_bag is not None) else None
    if maps:
        files.update(_map_files(result.posterior, problem.grid, seen))
    if report:

        traces = chain_traces(problem, result, seed=seed)
        files[REPORT_FILE] = build_report(problem, result, traces, title=title).encode("utf-8")
    _write_outputs(out, files)
    written = list(files)
    if out_bag is not None:
        write_occupancy_grid_bag(out_bag, np.clip(result.posterior, 0.0, 1.0), problem.grid, seen, overwrite=force)
        written.append(str(out_bag))
    return result.summary, written


def _map_files(posterior, grid, seen) -> dict[str, bytes]:
    """``infer --maps``: posterior.npz, and probability and std as 16-bit PNGs with their YAML
    (:mod:`bayesmap.io.maps_out`)."""
    probability = np.clip(np.asarray(posterior, dtype=np.float64), 0.0, 1.0)
    files = {NPZ_FILE: encode_posterior_npz(probability, grid, seen)}
    files.update(encode_png16("probability", probability, grid, "probability"))
    files.update(encode_png16("std", posterior_std(probability), grid, "std"))
    return files


def _check_out_bag(path: Path, force: bool) -> None:
    """Refuse, before any work, an ``--out-bag`` that exists (without ``--force``) or cannot be written."""
    if path.exists() and not force:
        raise BayesmapError(f"{str(path)!r} already exists; pass --force to replace it")
    if path.exists() and (path.suffix == ".bag") != path.is_file():
        raise BayesmapError(f"--out-bag {str(path)!r}: a '.bag' name is a ROS 1 bag file, any other a ROS 2 bag "
                            "folder")
    parent = path.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise BayesmapError(f"--out-bag {str(path)!r} cannot be written (no folder {str(parent)!r} to write in)")


def _print_summary(summary: dict, out: Path, written: list[str]) -> None:
    typer.echo(f"sampler:  {summary['sampler']} ({summary['sampler_description']})")
    beams = (f"{summary['num_scans']} scans, {summary['num_beams']} beams" if "num_scans" in summary
             else f"{summary['num_angles']} beams")
    typer.echo(f"data:     {summary['source']}, {beams}, grid {summary['grid']['shape'][0]} x "
               f"{summary['grid']['shape'][1]} cells of {summary['grid']['resolution']:g} m")
    if "sweeps" in summary:
        typer.echo(f"sweeps:   {summary['sweeps']} (posterior mean over the last "
                   f"{summary['sweeps'] - summary['burn_in']})")
    typer.echo(f"runtime:  {summary['runtime_s']:.2f} s (compilation included)")
    if "wrong_visible_cells" in summary:
        typer.echo(f"accuracy: {summary['wrong_visible_cells']} of {summary['visible_cells']} visible cells wrong")
    if summary.get("chains", 1) > 1 and summary.get("r_hat_max") is not None:
        typer.echo(f"chains:   {summary['chains']}; over the {summary['cells_varying']} cells that change: worst split "
                   f"R-hat {summary['r_hat_max']:.3f}, smallest effective sample size {summary['ess_min']:.0f}")
    typer.echo(f"outputs:  {out}/ ({', '.join(written)})")


def _sensor_params(beam_weights: Optional[str], lambda_short: Optional[float]) -> dict:
    """The beam mixture's parameters from ``--beam-weights HIT,SHORT,MAX,RAND`` and ``--lambda-short`` (keywords of
    ``make_params``, which checks them); empty for the defaults."""
    params = {}
    if beam_weights is not None:
        parts = [p.strip() for p in beam_weights.split(",")]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise BayesmapError(f"--beam-weights must be four numbers HIT,SHORT,MAX,RAND, "
                                f"got {beam_weights!r}") from None
        if len(values) != 4:
            raise BayesmapError(f"--beam-weights must be four numbers HIT,SHORT,MAX,RAND, "
                                f"got {len(values)} in {beam_weights!r}")
        params.update(zip(("z_hit", "z_short", "z_max", "z_rand"), values))
    if lambda_short is not None:
        params["lambda_short"] = lambda_short
    return params


MAX_SWEEPS = 1_000_000
"""Largest --sweeps / --burn-in (a million sweeps of the whole Intel log would take weeks; larger integers overflow
JAX's int32 loop counters)."""
MAX_CHAINS = 1024
MAX_BEAMS_PER_SCAN = 100_000
MAX_POSES = 100_000
MAX_RESOLUTION = 100.0
"""Meters per cell: a coarser grid has no room for a room."""
MAX_COORDINATE = 1e7
"""Meters: the largest sensor coordinate (10,000 km; bayesmap.io.carmen.MAX_PLAUSIBLE_COORDINATE for logs)."""
MAX_RANGE_LIMIT = 1000.0
"""Meters: the largest --max-range (bayesmap.io.carmen.MAX_PLAUSIBLE_RANGE)."""
MAX_GRID_CELLS = 50_000_000
"""Cells of one grid: each float32 map of the posterior is 200 MB at this size, and a chain keeps several."""
MAX_MEMORY_BYTES = 16e9
"""Bytes the ray-cell table may take (estimated): the machine has 24 GB, JAX and the figures need the rest."""
BYTES_PER_PAIR = 40
"""Bytes per (beam, cell) pair of the estimate :func:`_estimate_pairs` (an upper bound, about twice the real count
on the Intel log): the whole Intel log at 0.1 m has 42.4 million pairs and peaks at 2.9 GB, 68 bytes per real pair."""


def _in_range(name: str, lo: float | None = None, hi: float | None = None, lo_open: bool = False, unit: str = ""):
    """An option callback that refuses a value (or each value of a tuple) that is not a finite number in
    ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``), naming the option and the value; click turns the
    ``typer.BadParameter`` into one line and exit code 2 (:func:`main`)."""
    def show(x: float) -> str:
        return f"{int(x)}" if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"

    left = "(" if lo_open else "["
    span = (f"in {left}{show(lo)}, {show(hi)}]" if lo is not None and hi is not None
            else f"{'>' if lo_open else '>='} {show(lo)}" if lo is not None else f"<= {show(hi)}")

    def check(value):
        for v in value if isinstance(value, tuple) else (value,):
            if v is None:
                continue
            if not (math.isfinite(v) and (lo is None or v > lo or (v == lo and not lo_open))
                    and (hi is None or v <= hi)):
                raise typer.BadParameter(f"must be a finite number {span}{unit}, got {v!r}", param_hint=name)
        return value

    return check


POWER_HELP = ("--log: power eta in (0, 1] of the likelihood, sampling p(walls) p(readings | walls)^eta "
              "(a power posterior for beams that are not independent evidence; 1 is the plain posterior; "
              f"default for logs: {scenes.LOG_READINGS_PER_CELL:g} over the mean number of returned readings that "
              "end in a cell, so it follows the scans' density and the cell size)")
COUPLING_HELP = ("the structured prior's coupling J >= 0, nats per pair of neighbouring cells that agree (a "
                 "4-neighbour Markov random field, bayesmap.model.prior); default for several scans of a log: mean "
                 f"runs of {scenes.LOG_RUN_LENGTH:g} m (see --run-length), elsewhere 0, independent cells (the "
                 "tutorial's prior); with J > 0 --prior-wall-prob is a cell's wall probability given as many wall as "
                 "free neighbours")
RUN_LENGTH_HELP = ("the structured prior's coupling from a mean run length of equal cells, meters: "
                   "J = log(L / resolution - 1) (bayesmap.model.prior.coupling_for_run_length); instead of --coupling")
BEAM_WEIGHTS_HELP = ("beam model: mixture weights HIT,SHORT,MAX,RAND summing to 1 (default 0.8,0.05,0.05,0.1, "
                     "Probabilistic Robotics 6.3)")
LAMBDA_SHORT_HELP = "beam model: rate of short readings, 1/m (default 0.1)"
SCANS_HELP = ("scans of --log to map: a range such as 10:20, a stride such as 0:1000:5, a list such as 3,7,10:20, "
              "or 'all' (default); negative indexes count from the end")
MAX_RANGE_HELP = ("--log: the laser's max range, meters; readings at or above it are 'no return' "
                  "(default: inferred from the log, see bayesmap.io.carmen)")
METHOD_HELP = "gibbs (the posterior, with --sampler) or logodds (classic log-odds mapping, no posterior)"
BEAM_MODEL_HELP = ("sensor model: normal (the tutorial's; default for maps) or beam (robust mixture, "
                   "Probabilistic Robotics 6.3; default for logs)")
RANGE_OFFSET_HELP = ("meters the model subtracts from each returned reading of a log (default 0; with --geometry "
                     "entry a wall cell's reading is expected where the beam enters it, while a real surface lies "
                     "inside it)")
GEOMETRY_HELP = (f"--log: where a wall cell's reading is expected: entry (the tutorial's, where the beam enters the "
                 f"cell) or chord (anywhere on the beam's chord through the cell); default {scenes.LOG_GEOMETRY}")
PASS_HELP = ("--log (several scans): the probability that a beam passes through a wall cell it meets (thin or "
             "partly filled cells; the reading then comes from the ray's next wall), in [0, 1); default "
             f"{scenes.LOG_WALL_PASS_PROB:g} with the cellwise sampler (the default), 0 with the others, which "
             "support only 0")
EVALUATE_PRIOR_HELP = (f"prior probability that a cell is a wall (default for --log {scenes.LOG_STRUCTURED_PRIOR} "
                       f"with the structured prior, the default, and {scenes.LOG_PRIOR} with independent cells; "
                       f"for --truth {scenes.LOG_PRIOR})")
PRIOR_HELP = (f"prior probability that a cell is a wall (default {scenes.TUTORIAL_PRIOR}, the tutorial's; for "
              f"several scans of a log {scenes.LOG_STRUCTURED_PRIOR} with the structured prior, the default, where "
              f"it is the probability given as many wall as free neighbours, and {scenes.LOG_PRIOR} with "
              "independent cells)")
SENSOR_NOISE_HELP = (f"standard deviation of a reading, meters (default {scenes.TUTORIAL_SENSOR_NOISE}, "
                     f"the tutorial's; for --log {scenes.LOG_SENSOR_NOISE:g}, for --scan N "
                     f"{scenes.SCAN_SENSOR_NOISE:g})")
POS_HELP = "sensor position X Y (simulated readings), in cells of the map: a free cell; default the map's center"
CHAINS_HELP = "independent chains run at once; 2 or more add split R-hat and effective sample size per cell"
REPORT_HELP = "also write report.html: settings, metrics, all figures and the chain's animation, offline"
BENCH_SAMPLERS_HELP = "comma-separated subset of: raster, incremental, outward, block, chromatic, chromatic-block"
EVALUATE_LOG_HELP = "a CARMEN log: hold out every --every-th scan, map the rest, score the held-out beams"
EVALUATE_TRUTH_HELP = "a floor plan (ROS .pgm or .yaml): simulate scans in it, map them, score against it"
EVALUATE_SCANS_HELP = ("scans of --log to use: a range such as 10:20, a stride such as 0:1000:5, a list, "
                       "or 'all' (default)")
EVALUATE_MAX_RANGE_HELP = ("max range, meters: --truth, of the simulated sensor "
                           f"(default {scenes.SIMULATED_MAX_RANGE:g}); "
                           "--log, of the laser (default inferred from the log)")
EVALUATE_SENSOR_NOISE_HELP = (f"standard deviation of a reading, meters (default {scenes.LOG_SENSOR_NOISE:g} for "
                              f"--log, {scenes.SIMULATED_SENSOR_NOISE:g} for --truth)")
EVALUATE_SWEEPS = 100
"""``evaluate``'s Gibbs sweeps of a map (half burn-in); with --truth-trajectory a SLAM run's (``bayesmap slam``'s)."""
EVALUATE_SWEEPS_HELP = (f"Gibbs sweeps (default {EVALUATE_SWEEPS}, half burn-in); with --truth-trajectory the "
                        "SLAM run's, as bayesmap slam --sweeps")
TRUTH_TRAJECTORY_HELP = ("a true trajectory (TUM: t x y z qx qy qz qw) of --log's scans: score SLAM's path and the "
                         "raw odometry against it (ATE, RPE over 1 and 10 scans, 95 % ellipse coverage)")
RUN_HELP = ("with --truth-trajectory: score this bayesmap slam output folder (trajectory.tum, pose_cov.npy) instead "
            "of running SLAM on --log")
EVALUATE_RANGE_OFFSET_HELP = "--log: meters the model subtracts from each returned reading (default 0)"


BAG_HELP = ("a ROS bag (a ROS 1 .bag file, or a ROS 2 bag folder: .db3 or .mcap): its LaserScans, with poses from "
            "--odom-topic or --tf (as --log; 'no return' readings, see bayesmap.io.rosbag)")
MAPS_HELP = ("also write posterior.npz (probability, std, seen, resolution, origin) and probability.png / std.png "
             "(16-bit, with a map_server-style .yaml each)")
OUT_BAG_HELP = ("also write the posterior as a nav_msgs/OccupancyGrid on /map (percent, -1 for unseen cells) into "
                "this bag: a .bag name is ROS 1, any other a ROS 2 folder")
LASER_OFFSET_HELP = ("the laser's mounting X Y THETA (m, m, rad) on base_link, written to /tf_static; the base's "
                     "poses are the log's composed with its inverse")


def _coupling(coupling: Optional[float], run_length: Optional[float], resolution: float) -> Optional[float]:
    """The structured prior's coupling from ``--coupling`` or ``--run-length`` (meters, at ``resolution`` meters per
    cell); None when neither is given (the scene's default: :func:`bayesmap.scenes.log_coupling` for several scans
    of a log, 0 elsewhere).

    Raises:
        BayesmapError: when both are given, or on a bad value (named).
    """
    if coupling is not None and run_length is not None:
        raise BayesmapError("give either --coupling or --run-length, not both")
    if run_length is not None:
        return coupling_for_run_length(run_length, resolution)
    return None if coupling is None else check_coupling(coupling)


def _sampler_option(default: Optional[str], note: str = ""):

    return typer.Option(default, "--sampler", help=f"one of: {', '.join(SAMPLERS)}{note}")


@app.command()
def demo(
    out: Path = typer.Option(Path("bayesmap-out"), "--out", help="output folder"),
    sweeps: int = typer.Option(100, help="number of Gibbs sweeps", callback=_in_range("--sweeps", 1, MAX_SWEEPS)),
    seed: int = typer.Option(0, help="seed of the chain (readings always use the tutorial's key 0)",
                             callback=_in_range("--seed", -2**31, 2**32 - 1)),
    force: bool = typer.Option(False, "--force", help="replace bayesmap's outputs already in the folder"),
) -> None:
    """The tutorial map, readings simulated with the tutorial's key, 2x2 block Gibbs; prints a summary, writes figures
    and report.html."""

    problem = tutorial_problem()
    summary, written = _run_and_write(problem, "block", sweeps, None, seed, out, force,
                                      title="Posterior wall probability, 2x2 block Gibbs (tutorial map)", report=True)
    _print_summary(summary, out, written)


@app.command()
def infer(
    map_file: Optional[Path] = typer.Option(None, "--map",
                                            help="ASCII map ('X' wall, '.' free); default the tutorial map"),
    log: Optional[Path] = typer.Option(None, "--log",
                                       help="a CARMEN log (.log or .log.gz): all its scans, or --scans / --scan"),
    bag: Optional[Path] = typer.Option(None, "--bag", help=BAG_HELP),
    scan_topic: str = typer.Option("/scan", "--scan-topic", help="--bag: topic of the sensor_msgs/LaserScan messages"),
    odom_topic: str = typer.Option("/odom", "--odom-topic", help="--bag: topic of the nav_msgs/Odometry poses"),
    tf: bool = typer.Option(False, "--tf", help="--bag: the robot's poses from /tf (odom -> base_link), not odometry"),
    scan: Optional[int] = typer.Option(None, "--scan",
                                       help="map only this scan of --log (one pose, the single-scan model)"),
    scans: Optional[str] = typer.Option(None, "--scans", help=SCANS_HELP),
    resolution: float = typer.Option(scenes.RESOLUTION, help="grid resolution for real data, meters per cell",
                                     callback=_in_range("--resolution", 0, MAX_RESOLUTION, lo_open=True, unit=" m")),
    max_range: Optional[float] = typer.Option(None, "--max-range", help=MAX_RANGE_HELP,
                                              callback=_in_range("--max-range", 0, MAX_RANGE_LIMIT, lo_open=True,
                                                                 unit=" m")),
    method: str = typer.Option("gibbs", "--method", help=METHOD_HELP),
    beam_model: Optional[str] = typer.Option(None, "--beam-model", help=BEAM_MODEL_HELP),
    range_offset: Optional[float] = typer.Option(None, "--range-offset", help=RANGE_OFFSET_HELP),
    geometry: Optional[str] = typer.Option(None, "--geometry", help=GEOMETRY_HELP),
    wall_pass_prob: Optional[float] = typer.Option(None, "--wall-pass-prob", help=PASS_HELP),
    beam_weights: Optional[str] = typer.Option(None, "--beam-weights", help=BEAM_WEIGHTS_HELP),
    lambda_short: Optional[float] = typer.Option(None, "--lambda-short", help=LAMBDA_SHORT_HELP),
    likelihood_power: Optional[float] = typer.Option(None, "--likelihood-power", help=POWER_HELP),
    coupling: Optional[float] = typer.Option(None, "--coupling", help=COUPLING_HELP),
    run_length: Optional[float] = typer.Option(None, "--run-length", help=RUN_LENGTH_HELP),
    sampler: Optional[str] = _sampler_option(None, " (default block; cellwise for several scans of a log)"),
    sweeps: int = typer.Option(100, help="number of Gibbs sweeps", callback=_in_range("--sweeps", 1, MAX_SWEEPS)),
    burn_in: Optional[int] = typer.Option(None, "--burn-in", help="sweeps dropped before averaging (default: half)",
                                          callback=_in_range("--burn-in", 0, MAX_SWEEPS)),
    prior_wall_prob: Optional[float] = typer.Option(None, "--prior-wall-prob", help=PRIOR_HELP),
    sensor_noise: Optional[float] = typer.Option(None, "--sensor-noise", help=SENSOR_NOISE_HELP),
    num_angles: int = typer.Option(scenes.TUTORIAL_NUM_ANGLES, "--num-angles",
                                   help="number of beams (simulated readings)",
                                   callback=_in_range("--num-angles", 1, MAX_BEAMS_PER_SCAN)),
    pos: Optional[tuple[float, float]] = typer.Option(None, "--pos", help=POS_HELP,
                                                      callback=_in_range("--pos", -MAX_COORDINATE, MAX_COORDINATE)),
    seed: int = typer.Option(0, help="seed of the simulated readings and of the chain",
                             callback=_in_range("--seed", -2**31, 2**32 - 1)),
    chains: int = typer.Option(1, help=CHAINS_HELP, callback=_in_range("--chains", 1, MAX_CHAINS)),
    report: bool = typer.Option(False, "--report", help=REPORT_HELP),
    rosmap: bool = typer.Option(False, "--rosmap",
                                help="also write the posterior mean as a ROS map_server map (map.pgm + map.yaml)"),
    maps: bool = typer.Option(False, "--maps", help=MAPS_HELP),
    out_bag: Optional[Path] = typer.Option(None, "--out-bag", help=OUT_BAG_HELP),
    out: Path = typer.Option(Path("bayesmap-out"), "--out", help="output folder"),
    force: bool = typer.Option(False, "--force", help="replace bayesmap's outputs already in the folder"),
) -> None:
    """Infer the walls from simulated readings on a map file, or from a real CARMEN log (all scans, a selection, or
    one scan)."""

    if method not in ("gibbs", "logodds"):
        raise BayesmapError(f"unknown method {method!r}; choose gibbs or logodds")
    sensor_params = _sensor_params(beam_weights, lambda_short)
    carmen_like = log is not None or bag is not None
    coupling = _coupling(coupling, run_length, resolution if carmen_like else 1.0)
    if method == "logodds" and (report or chains != 1):
        raise BayesmapError("--report and --chains need --method gibbs (log-odds mapping has no chain)")
    carmen = _read_log(log, bag, scan_topic, odom_topic, tf, max_range)
    if carmen is not None:
        if map_file is not None:
            raise BayesmapError("give either --map or --log / --bag, not both")
        problem, title = _log_scene(carmen, log if log is not None else bag, scan, scans, resolution, prior_wall_prob,
                                    sensor_noise, beam_model, range_offset, likelihood_power, sensor_params, geometry,
                                    coupling, wall_pass_prob, sampler)
    else:
        if scan is not None or scans is not None or likelihood_power is not None or max_range is not None:
            raise BayesmapError("--scan, --scans, --likelihood-power and --max-range need --log FILE (or --bag)")
        if geometry is not None or wall_pass_prob is not None:
            raise BayesmapError("--geometry and --wall-pass-prob apply to several scans of --log FILE (or --bag); "
                                "maps keep the tutorial's entry geometry and walls")
        problem = _map_scene(map_file, pos, seed, prior_wall_prob, sensor_noise, num_angles, beam_model,
                             sensor_params, coupling)
        title = problem.source
    title = ("Log-odds occupancy, " if method == "logodds" else "Posterior wall probability, ") + title
    if sampler is None:
        sampler = "cellwise" if problem.multi_scan else "block"
    summary, written = _run_and_write(problem, sampler, sweeps, burn_in, seed, out, force, title=title,
                                      chains=chains, report=report, method=method, rosmap=rosmap, maps=maps,
                                      out_bag=out_bag)
    _print_summary(summary, out, written)


def _log_scene(carmen, path: Path, scan, scans, resolution, prior_wall_prob, sensor_noise, beam_model, range_offset,
               likelihood_power, sensor_params, geometry=None, coupling=None, wall_pass_prob=None, sampler=None):
    """``(problem, title)`` of ``infer --log/--bag``: one scan (``--scan N``, the single-scan model and the tutorial's
    defaults) or several (``--scans``, the log defaults of :mod:`bayesmap.scenes`). Walls a beam can pass
    (``wall_pass_prob`` > 0) need the cellwise sampler, so with another ``sampler`` the default is 0 (opaque walls)."""
    if scan is not None and scans is not None:
        raise BayesmapError("give either --scan N or --scans SPEC, not both")
    if scan is not None:
        noise = scenes.SCAN_SENSOR_NOISE if sensor_noise is None else sensor_noise
        if range_offset is not None or likelihood_power is not None:
            raise BayesmapError("--range-offset and --likelihood-power apply to several scans (--scans), "
                                "not to --scan N")
        if geometry is not None or wall_pass_prob is not None:
            raise BayesmapError("--geometry and --wall-pass-prob apply to several scans (--scans), not to --scan N")
        scan = int(parse_scans(str(scan), len(carmen))[0])  # a negative index counts from the end, as in --scans
        problem = scan_problem(carmen, scan, resolution=resolution,
                               prior_wall_prob=scenes.TUTORIAL_PRIOR if prior_wall_prob is None else prior_wall_prob,
                               sensor_noise=noise, beam_model=beam_model or scenes.TUTORIAL_BEAM_MODEL,
                               sensor_params=sensor_params,
                               coupling=prior.DEFAULT_COUPLING if coupling is None else coupling)
        return problem, f"{path.name} scan {scan}"
    chosen = parse_scans(scans, len(carmen))
    wall_pass_prob = scenes.log_wall_pass_prob(sampler) if wall_pass_prob is None else wall_pass_prob
    problem = log_problem(carmen, chosen, resolution=resolution,
                          prior_wall_prob=prior_wall_prob,
                          sensor_noise=sensor_noise, beam_model=beam_model or scenes.LOG_BEAM_MODEL,
                          range_offset=range_offset, sensor_params=sensor_params, likelihood_power=likelihood_power,
                          geometry=scenes.LOG_GEOMETRY if geometry is None else geometry, coupling=coupling,
                          wall_pass_prob=wall_pass_prob)
    return problem, f"{path.name}, {len(chosen)} scans"


def _map_scene(map_file, pos, seed, prior_wall_prob, sensor_noise, num_angles, beam_model, sensor_params,
               coupling=None):
    """The problem of ``infer --map`` (or the tutorial map): readings simulated from the sensor at ``pos`` (default
    the map's center, the tutorial's ``GRID_SIZE // 2``), which must be a free cell."""
    walls = load_map(map_file) if map_file is not None else tutorial_map()
    center = (float(walls.shape[0] // 2), float(walls.shape[1] // 2))
    if pos is not None:
        _check_free_cell(walls, pos, str(map_file) if map_file else "the tutorial map")
    return tutorial_problem(walls, pos=pos if pos is not None else center, seed=seed,
                            prior_wall_prob=scenes.TUTORIAL_PRIOR if prior_wall_prob is None else prior_wall_prob,
                            sensor_noise=scenes.TUTORIAL_SENSOR_NOISE if sensor_noise is None else sensor_noise,
                            num_angles=num_angles, source=str(map_file) if map_file else "tutorial map",
                            beam_model=beam_model or scenes.TUTORIAL_BEAM_MODEL, sensor_params=sensor_params,
                            coupling=prior.DEFAULT_COUPLING if coupling is None else coupling)


def _read_log(log: Optional[Path], bag: Optional[Path], scan_topic: str, odom_topic: str, tf: bool,
              max_range: Optional[float]):
    """The scans of ``--log`` (CARMEN) or ``--bag`` (ROS 1 or 2) as a ``CarmenLog``, or None for neither."""
    if log is not None and bag is not None:
        raise BayesmapError("give either --log or --bag, not both")
    if bag is None:
        if tf or scan_topic != "/scan" or odom_topic != "/odom":
            raise BayesmapError("--scan-topic, --odom-topic and --tf need --bag PATH")
        return None if log is None else read_carmen(log, max_range=max_range)
    return read_bag(bag, scan_topic=scan_topic, odom_topic=odom_topic, tf=tf, max_range=max_range)


@app.command()
def convert(
    log: Path = typer.Argument(..., help="a CARMEN log (.log or .log.gz), or a ROS bag"),
    out: Path = typer.Argument(..., help="the bag to write: a .bag file (ROS 1), or a folder with --ros2"),
    ros2: bool = typer.Option(False, "--ros2", help="write a ROS 2 bag (a folder) instead of ROS 1"),
    storage: str = typer.Option("sqlite3", "--storage", help=f"ROS 2 storage: {' or '.join(STORAGES)}"),
    laser_offset: tuple[float, float, float] = typer.Option(
        (0.0, 0.0, 0.0), "--laser-offset", help=LASER_OFFSET_HELP,
        callback=_in_range("--laser-offset", -MAX_COORDINATE, MAX_COORDINATE)),
    scans: Optional[str] = typer.Option(None, "--scans", help="scans to write (as infer --scans); default all"),
    scan_topic: str = typer.Option("/scan", "--scan-topic", help="a bag LOG: topic of its LaserScan messages"),
    odom_topic: str = typer.Option("/odom", "--odom-topic", help="a bag LOG: topic of its Odometry poses"),
    tf: bool = typer.Option(False, "--tf", help="a bag LOG: its poses from /tf, not odometry"),
    force: bool = typer.Option(False, "--force", help="replace OUT if it exists"),
) -> None:
    """Write a log as a ROS bag: LaserScan on /scan, Odometry on /odom, tf (odom -> base_link) and /tf_static
    (base_link -> laser), at the log's timestamps."""

    if storage not in STORAGES:
        raise BayesmapError(f"unknown --storage {storage!r}; choose {' or '.join(STORAGES)}")
    if storage != "sqlite3" and not ros2:
        raise BayesmapError("--storage applies to ROS 2 bags (--ros2)")
    is_bag = log.is_dir() or log.suffix == ".bag"
    if not is_bag and (tf or scan_topic != "/scan" or odom_topic != "/odom"):
        raise BayesmapError(f"--scan-topic, --odom-topic and --tf apply to a bag, and {str(log)!r} is not one "
                            "(a ROS 1 bag ends in .bag, a ROS 2 bag is a folder)")
    source = read_bag(log, scan_topic=scan_topic, odom_topic=odom_topic, tf=tf) if is_bag else read_carmen(log)
    chosen = parse_scans(scans, len(source))
    if len(chosen) < len(source):
        source = CarmenLog(path=source.path, ranges=source.ranges[chosen], poses=source.poses[chosen],
                           angles=source.angles[chosen], timestamps=source.timestamps[chosen],
                           max_range=source.max_range, is_max_range=source.is_max_range[chosen])
    write_log_bag(source, out, ros2=ros2, storage=storage, laser_offset=laser_offset, overwrite=force)
    typer.echo(f"wrote {out} (ROS {2 if ros2 else 1}{', ' + storage if ros2 else ''}): {len(source)} scans of "
               f"{source.ranges.shape[1]} beams on /scan, /odom, /tf, /tf_static")


@app.command()
def bench(
    json_file: Optional[Path] = typer.Option(None, "--json", help="also write the figures as JSON to this file"),
    samplers: Optional[str] = typer.Option(None, "--samplers", help=BENCH_SAMPLERS_HELP),
    sweeps: int = typer.Option(200, help="sweeps per timed chain of a fast sampler"),
    reference_sweeps: int = typer.Option(5, "--reference-sweeps", help="sweeps per timed chain of a reference sampler"),
    repeats: int = typer.Option(5, help="timed chains per sampler; the fastest counts"),
    chains: int = typer.Option(64, help="chains run at once for the throughput figure"),
    force: bool = typer.Option(False, "--force", help="replace the --json file if it exists"),
) -> None:
    """Fast samplers against the tutorial's reference samplers on the tutorial scene, in one process."""
    import platform


    for name, value, least in (("--sweeps", sweeps, 1), ("--reference-sweeps", reference_sweeps, 1),
                               ("--repeats", repeats, 1), ("--chains", chains, 1)):
        if value < least:
            raise BayesmapError(f"{name} must be >= {least}, got {value}")
    if json_file is not None and json_file.exists() and not force:
        raise BayesmapError(f"{str(json_file)!r} already exists; pass --force to replace it")
    names = None if samplers is None else [n.strip() for n in samplers.split(",") if n.strip()]

    typer.echo(f"bayesmap bench: tutorial scene (21 x 21, 100 beams, prior 0.5); jax {jax.__version__} on "
               f"{jax.default_backend()}, {os.cpu_count()} cores, {platform.processor() or platform.machine()}")
    results = run_bench(names, fast_sweeps=sweeps, reference_sweeps=reference_sweeps, repeats=repeats,
                        num_chains=chains, progress=lambda msg: typer.echo(f"  {msg} ...", err=True))
    typer.echo(format_table(results))
    if json_file is not None:
        write_atomic(json_file, json.dumps(results, indent=2) + "\n", overwrite=True)
        typer.echo(f"wrote {json_file}")


def _format_scores(scores: dict) -> str:
    """The evaluation table: one row per method, its metrics as columns."""
    rows = [(name, vals) for name, vals in scores.items() if name != "setup"]
    keys = [k for k in ("auc", "nll", "accuracy", "brier", "beams", "cells", "runtime_s")
            if any(k in v for _, v in rows)]
    head = f"{'method':<10}" + "".join(f"{k:>12}" for k in keys)
    lines = [head]
    for name, vals in rows:
        cells = []
        for k in keys:
            v = vals.get(k)
            cells.append(f"{'-':>12}" if v is None else f"{v:>12,}" if isinstance(v, int) else f"{v:>12.4f}")
        lines.append(f"{name:<10}" + "".join(cells))
    return "\n".join(lines)


TRAJECTORY_COLUMNS = (("ate_rmse_m", "ATE m"), ("rpe1_trans_rmse_m", "RPE1 m"), ("rpe1_rot_rmse_deg", "RPE1 deg"),
                      ("rpe10_trans_rmse_m", "RPE10 m"), ("rpe10_rot_rmse_deg", "RPE10 deg"),
                      ("coverage", "cover95"))
"""The columns of ``evaluate --truth-trajectory``'s table: the keys of
:func:`bayesmap.evaluation.trajectory.score_trajectory` and their headings."""


def _format_trajectory_scores(scores: dict) -> str:
    """The trajectory table: one row per method (bayesmap, odometry), :data:`TRAJECTORY_COLUMNS` as columns."""
    lines = [f"{'method':<10}" + "".join(f"{head:>11}" for _, head in TRAJECTORY_COLUMNS)]
    for name in ("bayesmap", "odometry"):
        vals = scores[name]
        lines.append(f"{name:<10}" + "".join(f"{'-':>11}" if vals.get(key) is None else f"{vals[key]:>11.4f}"
                                              for key, _ in TRAJECTORY_COLUMNS))
    return "\n".join(lines)


def _load_npy(path: Path, what: str) -> np.ndarray:
    """A ``.npy`` array (no pickles), or a BayesmapError naming the file."""
    name, data = read_bytes(path, what)
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        raise BayesmapError(f"{what} {name!r} is not a .npy array: {_one_line(err)}") from None


def read_slam_run(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The trajectory of a ``bayesmap slam`` output folder: ``(stamps (S,), mean path (S, 3), pose_cov (S, 3, 3))``
    from its trajectory.tum and pose_cov.npy (x, y m, theta rad; covariances m^2, m rad, rad^2).

    Raises:
        BayesmapError: naming the folder or file: not a folder, a file missing or unreadable, or a pose_cov.npy
            whose shape does not match the trajectory's poses.
    """
    run = Path(run)
    if not run.is_dir():
        raise BayesmapError(f"--run {str(run)!r} is not a folder (give the --out folder of bayesmap slam)")
    stamps, mean = read_tum(run / "trajectory.tum")
    cov = _load_npy(run / "pose_cov.npy", "pose covariances")
    if cov.shape != (len(mean), 3, 3):
        raise BayesmapError(f"{str(run / 'pose_cov.npy')!r} has shape {cov.shape}, but trajectory.tum has "
                            f"{len(mean)} poses: expected ({len(mean)}, 3, 3)")
    return stamps, mean, cov.astype(np.float64)


def truth_of_scans(truth_stamps, truth_poses, scans, stamps, num_log_scans: int, name: str = "the truth"):
    """The true pose of each scan of a run, and how it was paired: ``((S, 3) poses, "order" or "timestamp")``.

    By order when the truth has one pose per scan of the run (``S`` poses) or of the whole log (``num_log_scans``
    poses: those of the run's ``scans``); otherwise by timestamp (:func:`bayesmap.io.tum.match_stamps`: each of the
    run's ``stamps`` to the truth stamp within :data:`bayesmap.io.tum.STAMP_TOLERANCE`).

    Args:
        truth_stamps: ``(T,)`` stamps of the truth (seconds or scan indices); truth_poses: ``(T, 3)`` (x, y m,
            theta rad).
        scans: ``(S,)`` indices of the run's scans in the log; stamps: ``(S,)`` their TUM stamps.
        num_log_scans: the log's number of scans; name: the truth's name for messages.

    Raises:
        BayesmapError: naming the counts, if neither rule pairs every scan.
    """
    truth_poses = np.asarray(truth_poses, dtype=np.float64)
    count, s = len(truth_poses), len(scans)
    if count == s:
        return truth_poses, "order"
    if count == num_log_scans:
        return truth_poses[np.asarray(scans)], "order"
    try:
        return truth_poses[match_stamps(stamps, truth_stamps)], "timestamp"
    except BayesmapError as err:
        raise BayesmapError(f"{name} has {count} poses, not one per scan of the run ({s}) or of the log "
                            f"({num_log_scans}), and its stamps do not pair with the run's: {err}") from None


def _evaluate_trajectory(log, bag, scan_topic, odom_topic, tf, max_range, truth_path: Path, run: Optional[Path],
                         scans, resolution, sweeps, seed, json_file) -> None:
    """``evaluate --truth-trajectory``: the scores of SLAM's path (a run of :func:`run_log_slam` on the log, or the
    folder ``run``) and of the log's odometry against the true trajectory; prints the table, writes ``json_file``."""
    truth_stamps, truth_poses = read_tum(truth_path)
    if run is not None:
        if scans is not None or sweeps is not None:
            raise BayesmapError("--scans and --sweeps describe a new SLAM run; --run DIR is scored on its own scans")
        stamps, mean, cov = read_slam_run(run)
    carmen = _read_log(log, bag, scan_topic, odom_topic, tf, max_range)
    path = log if log is not None else bag
    log_stamps = tum_stamps(carmen.timestamps)
    setup = {"log": str(path), "truth": str(truth_path), "log_scans": len(carmen)}
    if run is not None:
        try:
            chosen = match_stamps(stamps, log_stamps)
        except BayesmapError as err:
            raise BayesmapError(f"{str(run / 'trajectory.tum')!r} is not a path of {path.name}'s scans: its stamps "
                                f"are not the log's (scan timestamps, or indices where they do not increase "
                                f"strictly): {err}") from None
        setup["run"] = str(run)
    else:
        _, result, chosen, settings = _log_slam(carmen, path, scans, resolution, sweeps, None, seed, final_map=False)
        stamps, mean, cov = log_stamps[chosen], result.mean_path, result.pose_cov
        setup.update(settings=settings, runtime_s=result.runtime_s, acceptance_rate=result.acceptance_rate)
    truth, paired = truth_of_scans(truth_stamps, truth_poses, chosen, stamps, len(carmen), name=str(truth_path))
    setup.update(scans=len(chosen), paired_by=paired)
    scores = {"setup": setup, "bayesmap": score_trajectory(mean, truth, cov),
              "odometry": score_trajectory(np.asarray(carmen.poses, np.float64)[chosen], truth)}
    source = f"the run in {run}" if run is not None else f"a new run ({setup['runtime_s']:.1f} s)"
    typer.echo(f"{path.name}: {len(chosen)} scans, {source}, against {truth_path.name} (paired by {paired}); "
               "ATE after the best rigid 2-D alignment, RPE over 1 and 10 scans, coverage of the 95 % ellipses")
    typer.echo(_format_trajectory_scores(scores))
    if json_file is not None:
        write_atomic(json_file, json.dumps(scores, indent=2) + "\n", overwrite=True)
        typer.echo(f"wrote {json_file}")


@app.command()
def evaluate(
    log: Optional[Path] = typer.Option(None, "--log", help=EVALUATE_LOG_HELP),
    bag: Optional[Path] = typer.Option(None, "--bag", help="a ROS bag, as --log (see infer --bag)"),
    scan_topic: str = typer.Option("/scan", "--scan-topic", help="--bag: topic of the sensor_msgs/LaserScan messages"),
    odom_topic: str = typer.Option("/odom", "--odom-topic", help="--bag: topic of the nav_msgs/Odometry poses"),
    tf: bool = typer.Option(False, "--tf", help="--bag: the robot's poses from /tf (odom -> base_link), not odometry"),
    truth: Optional[Path] = typer.Option(None, "--truth", help=EVALUATE_TRUTH_HELP),
    truth_trajectory: Optional[Path] = typer.Option(None, "--truth-trajectory", help=TRUTH_TRAJECTORY_HELP),
    run: Optional[Path] = typer.Option(None, "--run", help=RUN_HELP),
    scans: Optional[str] = typer.Option(None, "--scans", help=EVALUATE_SCANS_HELP),
    every: int = typer.Option(10, "--every", help="hold out every k-th scan"),
    resolution: float = typer.Option(scenes.RESOLUTION,
                                     help="meters per cell (--log; for a bare .pgm --truth, its pixel size)",
                                     callback=_in_range("--resolution", 0, MAX_RESOLUTION, lo_open=True, unit=" m")),
    sampler: str = _sampler_option("cellwise"),
    sweeps: Optional[int] = typer.Option(None, "--sweeps", help=EVALUATE_SWEEPS_HELP,
                                         callback=_in_range("--sweeps", 1, MAX_SWEEPS)),
    beam_model: str = typer.Option(scenes.LOG_BEAM_MODEL, "--beam-model",
                                   help="sensor model of mapping and scoring: beam or normal"),
    num_poses: int = typer.Option(scenes.SIMULATED_NUM_POSES, "--num-poses", help="--truth: number of simulated scans",
                                  callback=_in_range("--num-poses", 1, MAX_POSES)),
    num_angles: int = typer.Option(scenes.SIMULATED_NUM_ANGLES, "--num-angles",
                                   help="--truth: beams per simulated scan (over 360 degrees)",
                                   callback=_in_range("--num-angles", 1, MAX_BEAMS_PER_SCAN)),
    max_range: Optional[float] = typer.Option(None, "--max-range", help=EVALUATE_MAX_RANGE_HELP,
                                              callback=_in_range("--max-range", 0, MAX_RANGE_LIMIT, lo_open=True,
                                                                 unit=" m")),
    sensor_noise: Optional[float] = typer.Option(None, "--sensor-noise", help=EVALUATE_SENSOR_NOISE_HELP),
    prior_wall_prob: Optional[float] = typer.Option(None, "--prior-wall-prob", help=EVALUATE_PRIOR_HELP),
    range_offset: Optional[float] = typer.Option(None, "--range-offset", help=EVALUATE_RANGE_OFFSET_HELP),
    geometry: Optional[str] = typer.Option(None, "--geometry", help=GEOMETRY_HELP),
    wall_pass_prob: Optional[float] = typer.Option(None, "--wall-pass-prob", help=PASS_HELP),
    likelihood_power: Optional[float] = typer.Option(None, "--likelihood-power", help=POWER_HELP),
    coupling: Optional[float] = typer.Option(None, "--coupling", help=COUPLING_HELP),
    run_length: Optional[float] = typer.Option(None, "--run-length", help=RUN_LENGTH_HELP),
    beam_weights: Optional[str] = typer.Option(None, "--beam-weights", help=BEAM_WEIGHTS_HELP),
    lambda_short: Optional[float] = typer.Option(None, "--lambda-short", help=LAMBDA_SHORT_HELP),
    seed: int = typer.Option(0, help="seed of the chain (and of the simulated scans)",
                             callback=_in_range("--seed", -2**31, 2**32 - 1)),
    json_file: Optional[Path] = typer.Option(None, "--json", help="also write the table as JSON"),
    force: bool = typer.Option(False, "--force", help="replace the --json file if it exists"),
) -> None:
    """Score bayesmap against log-odds mapping: on held-out beams of a log (occupancy AUC, predictive NLL), or
    against a known floor plan (accuracy, AUC, Brier score). With --truth-trajectory, score SLAM's path (a new run
    on the log, or the folder --run) and the log's raw odometry against the true trajectory (ATE, RPE, coverage of
    the 95 % pose ellipses)."""

    if truth_trajectory is not None or run is not None:
        if truth_trajectory is None:
            raise BayesmapError("--run DIR needs --truth-trajectory TRUE.tum (and --log FILE)")
        if truth is not None:
            raise BayesmapError("give either --truth (a floor plan) or --truth-trajectory (a true path), not both")
        if log is None and bag is None:
            raise BayesmapError("--truth-trajectory needs --log FILE (or --bag PATH): the log whose path it is")
        if json_file is not None and json_file.exists() and not force:
            raise BayesmapError(f"{str(json_file)!r} already exists; pass --force to replace it")
        _evaluate_trajectory(log, bag, scan_topic, odom_topic, tf, max_range, truth_trajectory, run, scans,
                             resolution, sweeps, seed, json_file)
        return
    sweeps = EVALUATE_SWEEPS if sweeps is None else sweeps
    if (log is None and bag is None) == (truth is None):
        raise BayesmapError("give either --log FILE or --truth FILE (a ROS bag: --bag PATH, as --log)")
    if json_file is not None and json_file.exists() and not force:
        raise BayesmapError(f"{str(json_file)!r} already exists; pass --force to replace it")
    mapping = dict(sampler=sampler, sweeps=sweeps, seed=seed, sensor_noise=sensor_noise, beam_model=beam_model,
                   prior_wall_prob=prior_wall_prob, sensor_params=_sensor_params(beam_weights, lambda_short),
                   coupling=_coupling(coupling, run_length, resolution))
    carmen = _read_log(log, bag, scan_topic, odom_topic, tf, max_range)
    if carmen is not None:
        log = log if log is not None else bag
        chosen = parse_scans(scans, len(carmen))
        check_problem_size(log_problem(carmen, chosen, resolution=resolution))  # the grid of all chosen scans
        scores = evaluate_log(carmen, chosen, every=every, resolution=resolution,
                              range_offset=range_offset, likelihood_power=likelihood_power,
                              geometry=scenes.LOG_GEOMETRY if geometry is None else geometry,
                              wall_pass_prob=wall_pass_prob, **mapping)
        setup = scores["setup"]
        typer.echo(f"{log.name}: mapped {setup['train_scans']} scans, scored the {setup['test_scans']} held out "
                   f"(every {every}-th); grid {setup['grid'][0]} x {setup['grid'][1]} cells of {resolution:g} m; "
                   f"{sampler}, {sweeps} sweeps, {beam_model} model, {setup['geometry']} geometry")
    else:

        if likelihood_power is not None or range_offset is not None:
            raise BayesmapError("--likelihood-power and --range-offset apply to --log, not to --truth")
        if geometry is not None or wall_pass_prob is not None:
            raise BayesmapError("--geometry and --wall-pass-prob apply to --log, not to --truth")

        max_range = scenes.SIMULATED_MAX_RANGE if max_range is None else max_range
        _check_truth_scene(truth, resolution, num_poses, num_angles, max_range)
        scores = evaluate_truth(truth, resolution=resolution, num_poses=num_poses, num_angles=num_angles,
                                max_range=max_range, **mapping)
        setup = scores["setup"]
        typer.echo(f"{truth.name}: {setup['num_poses']} simulated scans of {num_angles} beams; "
                   f"grid {setup['grid'][0]} x {setup['grid'][1]} cells of {setup['resolution']:g} m; "
                   f"scored on {setup['cells_scored']:,} known cells seen by a beam; {sampler}, {sweeps} sweeps")
    typer.echo(_format_scores(scores))
    if json_file is not None:
        write_atomic(json_file, json.dumps(scores, indent=2) + "\n", overwrite=True)
        typer.echo(f"wrote {json_file}")


SLAM_OUTPUT_FILES = ("trajectory.tum", "trajectory_samples.npy", "pose_cov.npy")
"""What ``bayesmap slam`` writes besides posterior.npy, posterior.png, summary.json and report.html."""
SLAM_OWNED_FILES = ALL_OUTPUT_FILES + SLAM_OUTPUT_FILES
"""Every file a ``bayesmap slam`` run may write into its output folder."""

TUTORIAL_SLAM_SWEEPS = 60
"""``bayesmap slam``'s sweeps on the tutorial scene (a third burn-in); on a log the runner's default."""
TUTORIAL_SLAM_POSES = 8
"""Poses on the tutorial scene's loop (``--num-poses``)."""
LOG_SLAM_DEFAULTS = {"sweeps": ROUNDS, "burn_in": BURN_IN_ROUNDS}
"""``run_log_slam``'s own rounds and burn-in rounds: ``bayesmap slam --log`` without --sweeps and --burn-in runs them
(on a log, one "sweep" of the joint chain is a round: map sweeps given the poses, then pose sweeps given the map)."""

SLAM_LOG_HELP = "a CARMEN log whose pose fields hold odometry (a raw log): infer its path and map"
SLAM_SWEEPS_HELP = (f"joint sweeps (pose moves, then a map sweep); default {TUTORIAL_SLAM_SWEEPS} on the tutorial "
                    "scene; on --log / --bag the joint chain's rounds (map sweeps, then pose sweeps), default "
                    "the runner's (bayesmap.slam.pipeline)")
SLAM_BURN_IN_HELP = ("sweeps dropped before averaging (default: a third of --sweeps; on --log / --bag without "
                     "--sweeps, the runner's)")


def _check_slam_output_dir(out: Path, force: bool) -> None:
    """:func:`_check_output_dir` for ``bayesmap slam``, whose outputs include :data:`SLAM_OUTPUT_FILES`."""
    _check_output_dir(out, force)
    clash = [name for name in SLAM_OUTPUT_FILES if (out / name).exists()] if out.is_dir() and not force else []
    if clash:
        raise BayesmapError(f"{str(out / clash[0])!r} already exists; pass --force to replace bayesmap's outputs "
                            f"in {str(out)!r}")


def _slam_counts(sweeps: Optional[int], burn_in: Optional[int], default: dict) -> tuple[int, int]:
    """``(sweeps, burn_in)`` of a SLAM run: the given ones, ``default`` (``{"sweeps", "burn_in"}``) where neither
    is given, a third of the sweeps for a missing burn-in; refuses a burn-in that keeps no sweep."""
    if sweeps is None:
        sweeps = default["sweeps"]
        burn_in = default["burn_in"] if burn_in is None else burn_in
    burn_in = sweeps // 3 if burn_in is None else burn_in
    if burn_in >= sweeps:
        raise BayesmapError(f"--burn-in must be smaller than --sweeps ({sweeps}), got {burn_in}")
    return sweeps, burn_in


def _slam_files(problem, result, summary: dict, stamps, title: str, report: bool, rosmap: bool = False,
                maps: bool = False) -> dict[str, bytes]:
    """The output files of a ``bayesmap slam`` run (see :func:`slam`): ``stamps`` ``(S,)`` those of
    trajectory.tum."""
    grid = result.grid if result.grid is not None else problem.params.grid
    fig = plot_slam(grid, result.posterior, result.mean_path, result.pose_cov, result.pose_samples,
                    true_path=problem.true_poses, odometry=problem.odometry, truth=problem.truth, title=title)
    png = figure_bytes(fig, "png")
    files = {
        "trajectory.tum": encode_tum(stamps, result.mean_path).encode(),
        "trajectory_samples.npy": _npy(result.pose_samples),
        "pose_cov.npy": _npy(result.pose_cov),
        "posterior.npy": _npy(result.posterior.astype("float32")),
        "posterior.png": png,
        "summary.json": (json.dumps(summary, indent=2) + "\n").encode(),
    }
    if rosmap:
        files.update(encode_rosmap(ROSMAP_STEM, result.posterior, grid))
    if maps:
        seen = seen_cells_along(grid, result.mean_path, problem.sensor_angles, problem.readings,
                                float(problem.params.max_range))
        files.update(_map_files(result.posterior, grid, seen))
    if report:
        files[REPORT_FILE] = slam_report(png, summary, title=f"bayesmap slam: {problem.source}").encode("utf-8")
    return files


def _grid_summary(grid) -> dict:
    return {"shape": [int(n) for n in grid.shape], "resolution": float(grid.resolution),
            "origin": [float(v) for v in grid.origin]}


def _check_slam_size(problem) -> None:
    """Refuse a SLAM problem whose grid or ray-cell table cannot fit (:func:`_check_sizes`), before any work."""
    grid = problem.params.grid
    length = min(float(problem.params.max_range), math.hypot(*grid.shape) * grid.resolution)
    angles = np.asarray(problem.odometry)[:, 2:3] + np.asarray(problem.sensor_angles)
    _check_sizes(grid.shape, grid.resolution, _beam_cells(length, grid.resolution, angles))


def _log_slam(carmen, path: Path, scans: Optional[str], resolution: Optional[float], sweeps: Optional[int],
              burn_in: Optional[int], seed: int, final_map: bool = True):
    """Run ``run_log_slam`` on the ``scans`` of a log (with a progress bar; without ``final_map``, no final map,
    for scoring the path alone): ``(problem, result, chosen scan indices, settings)``."""
    chosen = parse_scans(scans, len(carmen))
    resolution = scenes.RESOLUTION if resolution is None else resolution
    sweeps, burn_in = _slam_counts(sweeps, burn_in, LOG_SLAM_DEFAULTS)
    problem = log_slam_problem(carmen, chosen, resolution=resolution)
    _check_slam_size(problem)
    typer.echo(f"bayesmap slam: {path.name}, {len(chosen)} scans, {sweeps} sweeps ...", err=True)
    result = run_log_slam(problem, rounds=sweeps, burn_in=burn_in, seed=seed, progress=True,
                          final_map_sweeps=FINAL_MAP_SWEEPS if final_map else 0)
    p = problem.params
    settings = {"scans": scans if scans is not None else "all", "resolution": resolution, "sweeps": sweeps,
                "burn_in": burn_in, "seed": seed, "prior_wall_prob": float(p.prior_wall_prob),
                "sensor_noise": float(p.sensor_noise), "beam_model": p.beam_model, "geometry": p.geometry,
                "range_offset_m": float(problem.range_offset),
                "likelihood_power": float(problem.likelihood_power), "max_range_m": float(p.max_range),
                "motion": {name: float(getattr(problem.motion, name))
                           for name in ("a1", "a2", "a3", "a4", "floor_xy", "floor_theta")},
                "graph_cov_scale": GRAPH_COV_SCALE}
    final = problem.final_map_params
    if result.chain_posterior is not None:  # posterior.npy is the final map at the mean path (run_log_slam stage 6)
        settings["final_map"] = {"sweeps": FINAL_MAP_SWEEPS, "burn_in": FINAL_MAP_SWEEPS // 2,
                                 "sensor_noise": float(result.final_map_noise), "geometry": final.geometry,
                                 "coupling": float(final.coupling), "wall_pass_prob": float(final.wall_pass_prob),
                                 "likelihood_power": float(result.final_map_power)}
    return problem, result, chosen, settings


@app.command()
def slam(
    log: Optional[Path] = typer.Option(None, "--log", help=SLAM_LOG_HELP),
    bag: Optional[Path] = typer.Option(None, "--bag", help=BAG_HELP),
    scan_topic: str = typer.Option("/scan", "--scan-topic", help="--bag: topic of the sensor_msgs/LaserScan messages"),
    odom_topic: str = typer.Option("/odom", "--odom-topic", help="--bag: topic of the nav_msgs/Odometry poses"),
    tf: bool = typer.Option(False, "--tf", help="--bag: the robot's poses from /tf (odom -> base_link), not odometry"),
    scans: Optional[str] = typer.Option(None, "--scans", help=SCANS_HELP),
    resolution: Optional[float] = typer.Option(None, "--resolution",
                                               help=f"--log / --bag: meters per cell (default {scenes.RESOLUTION:g})",
                                               callback=_in_range("--resolution", 0, MAX_RESOLUTION, lo_open=True,
                                                                  unit=" m")),
    sweeps: Optional[int] = typer.Option(None, "--sweeps", help=SLAM_SWEEPS_HELP,
                                         callback=_in_range("--sweeps", 1, MAX_SWEEPS)),
    burn_in: Optional[int] = typer.Option(None, "--burn-in", help=SLAM_BURN_IN_HELP,
                                          callback=_in_range("--burn-in", 0, MAX_SWEEPS)),
    seed: int = typer.Option(0, help="seed of the chain (and of the tutorial scene's odometry and readings)",
                             callback=_in_range("--seed", 0, 2**32 - 1)),
    num_poses: Optional[int] = typer.Option(None, "--num-poses",
                                            help=f"tutorial scene: poses on the loop (default {TUTORIAL_SLAM_POSES})",
                                            callback=_in_range("--num-poses", 2, 64)),
    rosmap: bool = typer.Option(False, "--rosmap",
                                help="also write the posterior mean as a ROS map_server map (map.pgm + map.yaml)"),
    maps: bool = typer.Option(False, "--maps", help=MAPS_HELP),
    report: bool = typer.Option(False, "--report", help="also write report.html (the figure and the summary)"),
    out: Path = typer.Option(Path("bayesmap-out"), "--out", help="output folder"),
    force: bool = typer.Option(False, "--force", help="replace bayesmap's outputs already in the folder"),
) -> None:
    """Joint SLAM: infer the path and the map together. With --log FILE (pose fields = odometry) or --bag PATH, a
    real robot's scans; with neither, the tutorial scene (a loop around the tutorial room, noisy odometry).

    Writes trajectory.tum (posterior mean pose per scan, stamped with the log's scan timestamps, or the scan indices
    where they do not increase strictly; the tutorial's: scan indices), trajectory_samples.npy (N, S, 3),
    pose_cov.npy (S, 3, 3), posterior.npy, posterior.png, summary.json, and with --rosmap, --maps and --report
    the maps and report.html as infer writes them."""

    if log is not None and bag is not None:
        raise BayesmapError("give either --log or --bag, not both")
    if log is None and bag is None:
        if scans is not None or resolution is not None:
            raise BayesmapError("--scans and --resolution need --log FILE (or --bag PATH)")
    elif num_poses is not None:
        raise BayesmapError("--num-poses applies to the tutorial scene, not to --log / --bag")
    _check_slam_output_dir(out, force)
    carmen = _read_log(log, bag, scan_topic, odom_topic, tf, None)
    if carmen is None:
        num_poses = TUTORIAL_SLAM_POSES if num_poses is None else num_poses
        sweeps, burn_in = _slam_counts(sweeps, burn_in, {"sweeps": TUTORIAL_SLAM_SWEEPS, "burn_in": None})
        problem = slam_tutorial_problem(seed=seed, num_poses=num_poses)
        result = run_slam(problem, sweeps=sweeps, burn_in=burn_in, seed=seed)
        settings = {"sweeps": sweeps, "burn_in": burn_in, "seed": seed, "num_poses": num_poses,
                    "num_angles": problem.params.num_angles, "prior_wall_prob": problem.params.prior_wall_prob,
                    "sensor_noise": problem.params.sensor_noise, "odometry_alphas": list(SLAM_ODOMETRY_ALPHAS),
                    "pose_kernel": "lattice_pose_mh", "map_kernel": "dense single-site Gibbs, raster order"}
        summary = {
            "source": problem.source,
            "settings": settings,
            "runtime_s": result.runtime_s,
            "acceptance_rate": result.acceptance_rate,
            "posterior": score_trajectory(result.mean_path, problem.true_poses, result.pose_cov),
            "odometry": score_trajectory(problem.odometry, problem.true_poses),
            "map_cells_wrong": int(np.sum((result.posterior > 0.5) != (problem.truth > 0))),
        }
        stamps = np.arange(problem.num_scans)
        title = f"bayesmap slam: {problem.num_scans} poses, {sweeps} sweeps"
    else:
        path = log if log is not None else bag
        problem, result, chosen, settings = _log_slam(carmen, path, scans, resolution, sweeps, burn_in, seed)
        sweeps, burn_in = settings["sweeps"], settings["burn_in"]
        all_stamps = tum_stamps(carmen.timestamps)
        stamps = all_stamps[chosen]
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
            "grid": _grid_summary(grid),
            "trajectory_stamps": ("the scans' timestamps, seconds" if np.array_equal(all_stamps, carmen.timestamps)
                                  else "scan indices of the log (its timestamps do not increase strictly)"),
        }
        title = f"bayesmap slam: {path.name}, {problem.num_scans} scans, {sweeps} sweeps"
    files = _slam_files(problem, result, summary, stamps, title, report, rosmap=rosmap, maps=maps)
    replace_folder(out, files, owned=SLAM_OWNED_FILES)
    typer.echo(f"data:     {problem.source}, {problem.readings.shape[1]} beams per scan")
    typer.echo(f"sweeps:   {sweeps} (posterior over the last {sweeps - burn_in}); pose acceptance "
               f"{result.acceptance_rate:.2f}")
    typer.echo(f"runtime:  {result.runtime_s:.2f} s (compilation included)")
    if "posterior" in summary:
        post, odo = summary["posterior"], summary["odometry"]
        typer.echo(f"path:     ATE {post['ate_rmse_m']:.3f} m (odometry {odo['ate_rmse_m']:.3f} m); 95 % ellipses "
                   f"cover {post['coverage']:.0%} of the true positions")
    else:
        sd = np.sqrt(np.clip(np.linalg.eigvalsh(np.asarray(result.pose_cov)[:, :2, :2])[:, -1], 0.0, None))
        g = summary["grid"]
        typer.echo(f"path:     {problem.num_scans} poses; position sd median {np.median(sd):.3f} m, largest "
                   f"{sd.max():.3f} m; map {g['shape'][0]} x {g['shape'][1]} cells of {g['resolution']:g} m")
    typer.echo(f"outputs:  {out}/ ({', '.join(files)})")


@app.command("app")
def explorer(
    host: str = typer.Option("127.0.0.1", help="interface to listen on (default: this machine only)"),
    port: int = typer.Option(8080, help="TCP port"),
    no_browser: bool = typer.Option(False, "--no-browser", help="do not open the page in a browser"),
) -> None:
    """The interactive map explorer, a local web app: draw walls, drag the sensor, run inference, browse samples.

    It serves its own scripts and contacts nothing on the network. Stop it with Ctrl+C."""
    from bayesmap.app import run_app  # (here, not at the top: NiceGUI takes a second to import, only `app` needs it)

    typer.echo(f"bayesmap explorer at http://{host}:{port}/ (Ctrl+C stops it)")
    run_app(host=host, port=port, show=not no_browser)


def _one_line(text: str) -> str:
    """``text`` with every run of whitespace (newlines included) made one space."""
    return " ".join(str(text).split())


def _given_value(argv: list[str], param) -> Optional[str]:
    """The value(s) the user gave the option ``param`` (a click parameter) in ``argv``, as typed, the last time it
    appears (click keeps the last); None if it is not there (a positional argument, say)."""
    names = [*getattr(param, "opts", []), *getattr(param, "secondary_opts", [])]
    nargs = max(1, int(getattr(param, "nargs", 1) or 1))
    given = None
    for i, token in enumerate(argv):
        for name in names:
            if token == name and i + 1 < len(argv):
                given = " ".join(argv[i + 1:i + 1 + nargs])
            elif token.startswith(name + "="):
                given = token[len(name) + 1:]
    return given


def main(argv: Optional[list[str]] = None) -> None:
    """Entry point of ``bayesmap``: run the typer app on ``argv`` (default ``sys.argv[1:]``).

    Every user error ends the process with ONE line ``error: ...`` on stderr and exit code 2: a
    :class:`BayesmapError` (bad file or value) and every command-line usage error of click (unknown command or
    option, a value of the wrong type, a missing value; typer ships its own copy of click, whose exceptions all
    derive from ``typer.TyperException``). ``--help`` exits 0; Ctrl+C prints ``aborted`` and exits 1.

    Raises:
        SystemExit: always, with the exit code (0 on success).
    """
    try:
        app(args=argv, prog_name="bayesmap", standalone_mode=False)
    except BayesmapError as err:
        typer.echo(f"error: {_one_line(err)}", err=True)
        sys.exit(2)
    except typer.Exit as ex:
        sys.exit(ex.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        typer.echo("aborted", err=True)
        sys.exit(1)
    except typer.TyperException as err:  # click's UsageError, BadParameter, NoSuchOption, ...
        if type(err).__name__ == "NoArgsIsHelpError":  # bare `bayesmap`: the help (rich prints it while formatting)
            err.show()
            sys.exit(2)
        message = err.format_message() if hasattr(err, "format_message") else str(err)
        param = getattr(err, "param", None)
        given = None if param is None else _given_value(sys.argv[1:] if argv is None else list(argv), param)
        if given is not None and "got " not in message:  # name the offending value (click's conversion does not)
            message = f"{message.rstrip('.')}, got {given!r}"
        context = getattr(err, "ctx", None)
        hint = f" (see '{context.command_path} --help')" if context is not None else ""
        typer.echo(f"error: {_one_line(message)}{hint}", err=True)
        sys.exit(2)
    sys.exit(0)


if __name__ == "__main__":
    main()
