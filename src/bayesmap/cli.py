"""The ``bayesmap`` command line (typer): it declares the options, calls a run of :mod:`bayesmap.runs` and prints.

User errors (bad files, values, folders) print one line ``error: ...`` on stderr and exit with code 2; Ctrl+C
prints one line and exits with code 130, as a shell does. Long runs draw a progress bar per stage on stderr, with a
rate and an ETA (:class:`bayesmap.progress.ProgressBar`).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from bayesmap import scenes  # the scene defaults
from bayesmap.errors import BayesmapError
from bayesmap.inference.registry import SAMPLERS
from bayesmap.inference.tiled import TILE_PAIRS
from bayesmap.io.rosbag import STORAGES, check_bag_path, write_log_bag
from bayesmap.progress import ProgressBar
from bayesmap.runs import evaluate as evaluate_run
from bayesmap.runs import infer as infer_run
from bayesmap.runs import slam as slam_run
from bayesmap.runs.inputs import parse_scans, read_log_or_bag, select_scans
from bayesmap.runs.outputs import check_output_file, write_json
from bayesmap.slam.branches import BRANCHES
from bayesmap.slam.keyframes import KEYFRAME_DISTANCE, KEYFRAME_TURN
from bayesmap.slam.pipeline import FRONT_END_PARTICLES

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Bayesian occupancy-grid mapping from range scans, with honest uncertainty.")

MAX_SWEEPS = 1_000_000
"""Largest --sweeps / --burn-in (a million sweeps of the whole Intel log would take weeks; larger integers overflow
JAX's int32 loop counters)."""
MAX_CHAINS = 1024
"""Largest --chains: a bound on the option alone (the chains' memory is bounded by
:data:`bayesmap.runs.inputs.MAX_GRID_CELLS`, which counts every chain's grid)."""
MAX_BEAMS_PER_SCAN = 100_000
"""Largest --num-angles, beams of a simulated scan: far above real scanners (1,440 beams for a 360 degree scan at
0.25 degrees); the ray-cell table's size is checked separately (:data:`bayesmap.runs.inputs.MAX_MEMORY_BYTES`)."""
MAX_POSES = 100_000
"""Largest ``evaluate --num-poses``, simulated scans: a bound on the option alone (the ray-cell table's size is
checked separately, :data:`bayesmap.runs.inputs.MAX_MEMORY_BYTES`)."""
MAX_RESOLUTION = 100.0
"""Meters per cell: a coarser grid has no room for a room."""
MAX_COORDINATE = 1e7
"""Meters: the largest sensor coordinate (10,000 km; bayesmap.io.carmen.MAX_PLAUSIBLE_COORDINATE for logs)."""
MAX_RANGE_LIMIT = 1000.0
"""Meters: the largest --max-range (bayesmap.io.carmen.MAX_PLAUSIBLE_RANGE)."""
SEED_RANGE = (-2**31, 2**32 - 1)
"""--seed: a 32-bit integer, signed or not (``jax.random.key`` takes either)."""


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


def _opt(kind, *names: str, help: str, **kwargs):
    """``Annotated[kind, typer.Option(*names, help=help, **kwargs)]``: one option, declared once."""
    return Annotated[kind, typer.Option(*names, help=help, **kwargs)]


# -- the options, each declared once (help texts are the CLI reference's: docs/cli.md is generated from them) ----

_RESOLUTION = _in_range("--resolution", 0, MAX_RESOLUTION, lo_open=True, unit=" m")
_MAX_RANGE = _in_range("--max-range", 0, MAX_RANGE_LIMIT, lo_open=True, unit=" m")
_GIBBS_SWEEPS = _in_range("--sweeps", 1, MAX_SWEEPS)
_BURN_IN = _in_range("--burn-in", 0, MAX_SWEEPS)

OutOpt = _opt(Path, "--out", help="output folder")
ForceOutputsOpt = _opt(bool, "--force", help="replace bayesmap's outputs already in the folder")
ForceJsonOpt = _opt(bool, "--force", help="replace the --json file if it exists")
BagOpt = _opt(Optional[Path], "--bag", help="a ROS bag (a ROS 1 .bag file, or a ROS 2 bag folder: .db3 or .mcap): "
              "its LaserScans, with poses from --odom-topic or --tf (as --log; 'no return' readings, see "
              "bayesmap.io.rosbag)")
ScanTopicOpt = _opt(str, "--scan-topic", help="--bag: topic of the sensor_msgs/LaserScan messages")
OdomTopicOpt = _opt(str, "--odom-topic", help="--bag: topic of the nav_msgs/Odometry poses")
TfOpt = _opt(bool, "--tf", help="--bag: the robot's poses from /tf (odom -> base_link), not odometry")
ScansOpt = _opt(Optional[str], "--scans", help="scans of --log to map: a range such as 10:20, a stride such as "
                "0:1000:5, a list such as 3,7,10:20, or 'all' (default); negative indexes count from the end")
RosmapOpt = _opt(bool, "--rosmap", help="also write the posterior mean as a ROS map_server map (map.pgm + map.yaml)")
MapsOpt = _opt(bool, "--maps", help="also write posterior.npz (probability, std, seen, resolution, origin) and "
               "probability.png / std.png (16-bit, with a map_server-style .yaml each)")
GibbsSweepsOpt = _opt(int, "--sweeps", help="number of Gibbs sweeps", callback=_GIBBS_SWEEPS)
GeometryOpt = _opt(Optional[str], "--geometry", help="--log: where a wall cell's reading is expected: entry (the "
                   "tutorial's, where the beam enters the cell) or chord (anywhere on the beam's chord through the "
                   f"cell); default {scenes.LOG_GEOMETRY}")
WallPassOpt = _opt(Optional[float], "--wall-pass-prob", help="--log (several scans): the probability that a beam "
                   "passes through a wall cell it meets (thin or partly filled cells; the reading then comes from "
                   f"the ray's next wall), in [0, 1); default {scenes.LOG_WALL_PASS_PROB:g} with the cellwise sampler "
                   "(the default), 0 with the others, which support only 0")
CutOpt = _opt(Optional[float], "--cut-past-reading", help="--log (several scans): meters past its reading beyond "
             "which a beam does not look at the map (a wall there counts as no wall for that beam), > 0: the ray-cell "
             "table keeps only the cells up to the cut, about 5 times fewer on real logs; default: the whole beam")
KeyframeDistanceOpt = _opt(Optional[float], "--keyframe-distance", help="--log / --bag (several scans): meters the "
                          "poses (slam: the odometry) must move from the last keyframe for a scan to be one "
                          "(keyframes are mapped; slam places every other scan on their map); 0 with "
                          f"--keyframe-turn 0: every scan; default {scenes.LOG_KEYFRAME_DISTANCE:g} (slam: "
                          f"{KEYFRAME_DISTANCE:g})")
KeyframeTurnOpt = _opt(Optional[float], "--keyframe-turn", help="--log / --bag (several scans): radians the heading "
                       f"must turn from the last keyframe for a scan to be one; default {scenes.LOG_KEYFRAME_TURN:g} "
                       f"(slam: {KEYFRAME_TURN:g})")
TilePairsOpt = _opt(Optional[int], "--tile-pairs", help="--log / --bag (several scans): the most (beam, cell) pairs "
                    "the map's sampler holds at once (about 35 bytes each); a map whose beams cross more cells is "
                    "swept a tile of the grid at a time, each with its own table (infer: the cellwise sampler); lower "
                    f"it to bound memory; default {TILE_PAIRS:,}")
ParticlesOpt = _opt(Optional[int], "--particles", help="--log / --bag: hypotheses the front end keeps (a particle "
                    "filter over the path, each particle with its own local map); on a CPU its time grows about "
                    "linearly with them and its memory by about 30 MB a particle, on a GPU little; default "
                    f"{FRONT_END_PARTICLES}, the single-track front end")
BranchesOpt = _opt(Optional[int], "--branches", help="--log / --bag: the most steps where the front end's match and "
                   "the odometry disagree (beyond the motion model's 99.9 % quantile) at which the other hypothesis, "
                   "the odometry's step, is also followed and both weighed by the model with the map integrated out; "
                   "each costs a front end, a loop closure and a short map chain; 0: the single track alone; "
                   f"default {BRANCHES}")
MotionAlphasOpt = _opt(Optional[str], "--motion-alphas", help="--log / --bag: the odometry's noise A1,A2,A3,A4, "
                       "Probabilistic Robotics Table 5.6's alphas as standard deviations (rotation per rotation, rad "
                       "per m, translation per translation, m per rad; not AMCL's odom_alpha, which are variances); "
                       "set them for your robot's wheels; default 0.1,0.05,0.1,0.05")
PowerOpt = _opt(Optional[float], "--likelihood-power", help="--log: power eta in (0, 1] of the likelihood, sampling "
                "p(walls) p(readings | walls)^eta (a power posterior for beams that are not independent evidence; 1 "
                f"is the plain posterior; default for logs: {scenes.LOG_READINGS_PER_CELL:g} over the mean number "
                "of returned readings that end in a cell, so it follows the scans' density and the cell size)")
CouplingOpt = _opt(Optional[float], "--coupling", help="the structured prior's coupling J >= 0, nats per pair of "
                   "neighbouring cells that agree (a 4-neighbour Markov random field, bayesmap.model.prior); default "
                   f"for several scans of a log: mean runs of {scenes.LOG_RUN_LENGTH:g} m (see --run-length), "
                   "elsewhere 0, independent cells (the tutorial's prior); with J > 0 --prior-wall-prob is a cell's "
                   "wall probability given as many wall as free neighbours")
RunLengthOpt = _opt(Optional[float], "--run-length", help="the structured prior's coupling from a mean run length "
                    "of equal cells, meters: J = log(L / resolution - 1) "
                    "(bayesmap.model.prior.coupling_for_run_length); instead of --coupling")
BeamWeightsOpt = _opt(Optional[str], "--beam-weights", help="beam model: mixture weights HIT,SHORT,MAX,RAND summing "
                      "to 1 (default 0.8,0.05,0.05,0.1, Probabilistic Robotics 6.3)")
LambdaShortOpt = _opt(Optional[float], "--lambda-short", help="beam model: rate of short readings, 1/m (default 0.1)")

# infer and demo
InferLogOpt = _opt(Optional[Path], "--log", help="a CARMEN log (.log or .log.gz): all its scans, or --scans / --scan")
InferMapOpt = _opt(Optional[Path], "--map", help="ASCII map ('X' wall, '.' free); default the tutorial map")
ScanOpt = _opt(Optional[int], "--scan", help="map only this scan of --log (one pose, the single-scan model)")
InferResolutionOpt = _opt(float, "--resolution", help="grid resolution for real data, meters per cell",
                          callback=_RESOLUTION)
InferMaxRangeOpt = _opt(Optional[float], "--max-range", help="--log: the laser's max range, meters; readings at or "
                        "above it are 'no return' (default: inferred from the log, see bayesmap.io.carmen)",
                        callback=_MAX_RANGE)
MethodOpt = _opt(str, "--method", help="gibbs (the posterior, with --sampler) or logodds (classic log-odds mapping, "
                 "no posterior)")
InferBeamModelOpt = _opt(Optional[str], "--beam-model", help="sensor model: normal (the tutorial's; default for "
                         "maps) or beam (robust mixture, Probabilistic Robotics 6.3; default for logs)")
InferRangeOffsetOpt = _opt(Optional[float], "--range-offset", help="meters the model subtracts from each returned "
                           "reading of a log (default 0; with --geometry entry a wall cell's reading is expected where "
                           "the beam enters it, while a real surface lies inside it)")
InferSamplerOpt = _opt(Optional[str], "--sampler", help=f"one of: {', '.join(SAMPLERS)} (default block; cellwise "
                       "for several scans of a log)")
InferBurnInOpt = _opt(Optional[int], "--burn-in", help="sweeps dropped before averaging (default: half)",
                      callback=_BURN_IN)
InferPriorOpt = _opt(Optional[float], "--prior-wall-prob", help="prior probability that a cell is a wall (default "
                     f"{scenes.TUTORIAL_PRIOR}, the tutorial's; for several scans of a log "
                     f"{scenes.LOG_STRUCTURED_PRIOR} with the structured prior, the default, where it is the "
                     f"probability given as many wall as free neighbours, and {scenes.LOG_PRIOR} with independent "
                     "cells)")
InferNoiseOpt = _opt(Optional[float], "--sensor-noise", help="standard deviation of a reading, meters (default "
                     f"{scenes.TUTORIAL_SENSOR_NOISE}, the tutorial's; for --log {scenes.LOG_SENSOR_NOISE:g}, for "
                     f"--scan N {scenes.SCAN_SENSOR_NOISE:g})")
InferAnglesOpt = _opt(int, "--num-angles", help="number of beams (simulated readings)",
                      callback=_in_range("--num-angles", 1, MAX_BEAMS_PER_SCAN))
PosOpt = _opt(Optional[tuple[float, float]], "--pos", help="sensor position X Y (simulated readings), in cells of the "
              "map: a free cell; default the map's center",
              callback=_in_range("--pos", -MAX_COORDINATE, MAX_COORDINATE))
InferSeedOpt = _opt(int, "--seed", help="seed of the simulated readings and of the chain",
                    callback=_in_range("--seed", *SEED_RANGE))
DemoSeedOpt = _opt(int, "--seed", help="seed of the chain (readings always use the tutorial's key 0)",
                   callback=_in_range("--seed", *SEED_RANGE))
ChainsOpt = _opt(int, "--chains", help="independent chains run at once; 2 or more add split R-hat and effective "
                 "sample size per cell", callback=_in_range("--chains", 1, MAX_CHAINS))
InferReportOpt = _opt(bool, "--report", help="also write report.html: settings, metrics, all figures and the chain's "
                      "animation, offline")
OutBagOpt = _opt(Optional[Path], "--out-bag", help="also write the posterior as a nav_msgs/OccupancyGrid on /map "
                 "(percent, -1 for unseen cells) into this bag: a .bag name is ROS 1, any other a ROS 2 folder")

# slam
SlamLogOpt = _opt(Optional[Path], "--log", help="a CARMEN log whose pose fields hold odometry (a raw log): infer its "
                  "path and map")
SlamResolutionOpt = _opt(Optional[float], "--resolution", help="--log / --bag: meters per cell (default "
                         f"{scenes.RESOLUTION:g})", callback=_RESOLUTION)
SlamSweepsOpt = _opt(Optional[int], "--sweeps", help="joint sweeps (pose moves, then a map sweep); default "
                     f"{slam_run.TUTORIAL_SLAM_SWEEPS} on the tutorial scene; on --log / --bag the joint chain's "
                     "rounds (map sweeps, then pose sweeps), default the runner's (bayesmap.slam.pipeline)",
                     callback=_GIBBS_SWEEPS)
SlamBurnInOpt = _opt(Optional[int], "--burn-in", help="sweeps dropped before averaging (default: a third of --sweeps; "
                     "on --log / --bag without --sweeps, the runner's)", callback=_BURN_IN)
SlamSeedOpt = _opt(int, "--seed", help="seed of the chain (and of the tutorial scene's odometry and readings)",
                   callback=_in_range("--seed", 0, 2**32 - 1))
SlamPosesOpt = _opt(Optional[int], "--num-poses", help="tutorial scene: poses on the loop (default "
                    f"{slam_run.TUTORIAL_SLAM_POSES})", callback=_in_range("--num-poses", 2, 64))
SlamReportOpt = _opt(bool, "--report", help="also write report.html (the figure and the summary)")

# evaluate
EvalLogOpt = _opt(Optional[Path], "--log", help="a CARMEN log: hold out every --every-th scan, map the rest, score "
                  "the held-out beams")
EvalBagOpt = _opt(Optional[Path], "--bag", help="a ROS bag, as --log (see infer --bag)")
TruthOpt = _opt(Optional[Path], "--truth", help="a floor plan (ROS .pgm or .yaml): simulate scans in it, map them, "
                "score against it")
TruthTrajectoryOpt = _opt(Optional[Path], "--truth-trajectory", help="a true trajectory (TUM: t x y z qx qy qz qw) "
                          "of --log's scans: score SLAM's path and the raw odometry against it (ATE, RPE over 1 and "
                          "10 scans, 95 % ellipse coverage)")
RunOpt = _opt(Optional[Path], "--run", help="with --truth-trajectory: score this bayesmap slam output folder "
              "(trajectory.tum, pose_cov.npy) instead of running SLAM on --log")
EvalScansOpt = _opt(Optional[str], "--scans", help="scans of --log to use: a range such as 10:20, a stride such as "
                    "0:1000:5, a list, or 'all' (default)")
EveryOpt = _opt(int, "--every", help="hold out every k-th scan")
EvalResolutionOpt = _opt(float, "--resolution", help="meters per cell (--log; for a bare .pgm --truth, its pixel "
                         "size)", callback=_RESOLUTION)
EvalSamplerOpt = _opt(str, "--sampler", help=f"one of: {', '.join(SAMPLERS)}")
EvalSweepsOpt = _opt(Optional[int], "--sweeps", help=f"Gibbs sweeps (default {evaluate_run.EVALUATE_SWEEPS}, half "
                     "burn-in); with --truth-trajectory the SLAM run's, as bayesmap slam --sweeps",
                     callback=_GIBBS_SWEEPS)
EvalBeamModelOpt = _opt(str, "--beam-model", help="sensor model of mapping and scoring: beam or normal")
EvalPosesOpt = _opt(int, "--num-poses", help="--truth: number of simulated scans",
                    callback=_in_range("--num-poses", 1, MAX_POSES))
EvalAnglesOpt = _opt(int, "--num-angles", help="--truth: beams per simulated scan (over 360 degrees)",
                     callback=_in_range("--num-angles", 1, MAX_BEAMS_PER_SCAN))
EvalMaxRangeOpt = _opt(Optional[float], "--max-range", help="max range, meters: --truth, of the simulated sensor "
                       f"(default {scenes.SIMULATED_MAX_RANGE:g}); --log, of the laser (default inferred from the log)",
                       callback=_MAX_RANGE)
EvalNoiseOpt = _opt(Optional[float], "--sensor-noise", help="standard deviation of a reading, meters (default "
                    f"{scenes.LOG_SENSOR_NOISE:g} for --log, {scenes.SIMULATED_SENSOR_NOISE:g} for --truth)")
EvalPriorOpt = _opt(Optional[float], "--prior-wall-prob", help="prior probability that a cell is a wall (default "
                    f"for --log {scenes.LOG_STRUCTURED_PRIOR} with the structured prior, the default, and "
                    f"{scenes.LOG_PRIOR} with independent cells; for --truth {scenes.LOG_PRIOR})")
EvalRangeOffsetOpt = _opt(Optional[float], "--range-offset", help="--log: meters the model subtracts from each "
                          "returned reading (default 0)")
EvalSeedOpt = _opt(int, "--seed", help="seed of the chain (and of the simulated scans)",
                   callback=_in_range("--seed", *SEED_RANGE))
EvalJsonOpt = _opt(Optional[Path], "--json", help="also write the table as JSON")

# convert
ConvertLogArg = Annotated[Path, typer.Argument(help="a CARMEN log (.log or .log.gz), or a ROS bag")]
ConvertOutArg = Annotated[Path, typer.Argument(help="the bag to write: a .bag file (ROS 1), or a folder with --ros2")]
Ros2Opt = _opt(bool, "--ros2", help="write a ROS 2 bag (a folder) instead of ROS 1")
StorageOpt = _opt(str, "--storage", help=f"ROS 2 storage: {' or '.join(STORAGES)}")
LaserOffsetOpt = _opt(tuple[float, float, float], "--laser-offset", help="the laser's mounting X Y THETA (m, m, rad) "
                      "on base_link, written to /tf_static; the base's poses are the log's composed with its inverse",
                      callback=_in_range("--laser-offset", -MAX_COORDINATE, MAX_COORDINATE))
ConvertScansOpt = _opt(Optional[str], "--scans", help="scans to write (as infer --scans); default all")
ConvertScanTopicOpt = _opt(str, "--scan-topic", help="a bag LOG: topic of its LaserScan messages")
ConvertOdomTopicOpt = _opt(str, "--odom-topic", help="a bag LOG: topic of its Odometry poses")
ConvertTfOpt = _opt(bool, "--tf", help="a bag LOG: its poses from /tf, not odometry")
ConvertForceOpt = _opt(bool, "--force", help="replace OUT if it exists (a ROS 2 folder only if it holds a bag alone)")

# bench and app
BenchJsonOpt = _opt(Optional[Path], "--json", help="also write the figures as JSON to this file")
BenchSamplersOpt = _opt(Optional[str], "--samplers", help="comma-separated subset of: raster, incremental, outward, "
                        "block, chromatic, chromatic-block")
BenchSweepsOpt = _opt(int, "--sweeps", help="sweeps per timed chain of a fast sampler")
ReferenceSweepsOpt = _opt(int, "--reference-sweeps", help="sweeps per timed chain of a reference sampler")
RepeatsOpt = _opt(int, "--repeats", help="timed chains per sampler; the fastest counts")
BenchChainsOpt = _opt(int, "--chains", help="chains run at once for the throughput figure")
HostOpt = _opt(str, "--host", help="interface to listen on (default: this machine only)")
PortOpt = _opt(int, "--port", help="TCP port")
NoBrowserOpt = _opt(bool, "--no-browser", help="do not open the page in a browser")


# -- printing -----------------------------------------------------------------------------------------------------


def _notify(line: str) -> None:
    """Say on stderr what a long run is about to do."""
    typer.echo(line, err=True)


def _echo(lines: list[str]) -> None:
    for line in lines:
        typer.echo(line)


# -- the commands -------------------------------------------------------------------------------------------------


@app.command()
def demo(out: OutOpt = Path("bayesmap-out"), sweeps: GibbsSweepsOpt = 100, seed: DemoSeedOpt = 0,
         force: ForceOutputsOpt = False) -> None:
    """The tutorial map, readings simulated with the tutorial's key, 2x2 block Gibbs; prints a summary, writes figures
    and report.html."""
    request = infer_run.InferRequest(sweeps=sweeps, seed=seed, report=True, out=out, force=force)
    title = "Posterior wall probability, 2x2 block Gibbs (tutorial map)"
    with ProgressBar() as bar:
        done = infer_run.map_and_write(scenes.tutorial_problem(), title, request, "block", bar)
    _echo(infer_run.summary_lines(done.run.summary, out, done.written))


@app.command()
def infer(
    map_file: InferMapOpt = None,
    log: InferLogOpt = None,
    bag: BagOpt = None,
    scan_topic: ScanTopicOpt = "/scan",
    odom_topic: OdomTopicOpt = "/odom",
    tf: TfOpt = False,
    scan: ScanOpt = None,
    scans: ScansOpt = None,
    resolution: InferResolutionOpt = scenes.RESOLUTION,
    max_range: InferMaxRangeOpt = None,
    method: MethodOpt = "gibbs",
    beam_model: InferBeamModelOpt = None,
    range_offset: InferRangeOffsetOpt = None,
    geometry: GeometryOpt = None,
    wall_pass_prob: WallPassOpt = None,
    cut_past_reading: CutOpt = None,
    keyframe_distance: KeyframeDistanceOpt = None,
    keyframe_turn: KeyframeTurnOpt = None,
    tile_pairs: TilePairsOpt = None,
    beam_weights: BeamWeightsOpt = None,
    lambda_short: LambdaShortOpt = None,
    likelihood_power: PowerOpt = None,
    coupling: CouplingOpt = None,
    run_length: RunLengthOpt = None,
    sampler: InferSamplerOpt = None,
    sweeps: GibbsSweepsOpt = 100,
    burn_in: InferBurnInOpt = None,
    prior_wall_prob: InferPriorOpt = None,
    sensor_noise: InferNoiseOpt = None,
    num_angles: InferAnglesOpt = scenes.TUTORIAL_NUM_ANGLES,
    pos: PosOpt = None,
    seed: InferSeedOpt = 0,
    chains: ChainsOpt = 1,
    report: InferReportOpt = False,
    rosmap: RosmapOpt = False,
    maps: MapsOpt = False,
    out_bag: OutBagOpt = None,
    out: OutOpt = Path("bayesmap-out"),
    force: ForceOutputsOpt = False,
) -> None:
    """Infer the walls from simulated readings on a map file, or from a real CARMEN log (all scans, a selection, or
    one scan)."""
    request = infer_run.InferRequest(**locals())  # (first statement: the locals are the options, named as the fields)
    with ProgressBar() as bar:  # one tqdm bar per stage on stderr, with a rate and an ETA
        done = infer_run.infer(request, bar)
    _echo(infer_run.summary_lines(done.run.summary, out, done.written))


@app.command()
def convert(
    log: ConvertLogArg,
    out: ConvertOutArg,
    ros2: Ros2Opt = False,
    storage: StorageOpt = "sqlite3",
    laser_offset: LaserOffsetOpt = (0.0, 0.0, 0.0),
    scans: ConvertScansOpt = None,
    scan_topic: ConvertScanTopicOpt = "/scan",
    odom_topic: ConvertOdomTopicOpt = "/odom",
    tf: ConvertTfOpt = False,
    force: ConvertForceOpt = False,
) -> None:
    """Write a log as a ROS bag: LaserScan on /scan, Odometry on /odom, tf (odom -> base_link) and /tf_static
    (base_link -> laser), at the log's timestamps."""
    if storage not in STORAGES:
        raise BayesmapError(f"unknown --storage {storage!r}; choose {' or '.join(STORAGES)}")
    if storage != "sqlite3" and not ros2:
        raise BayesmapError("--storage applies to ROS 2 bags (--ros2)")
    check_bag_path(out, ros2, storage, overwrite=force)
    source = read_log_or_bag(log, scan_topic, odom_topic, tf)
    source = select_scans(source, parse_scans(scans, len(source)))
    write_log_bag(source, out, ros2=ros2, storage=storage, laser_offset=laser_offset, overwrite=force)
    typer.echo(f"wrote {out} (ROS {2 if ros2 else 1}{', ' + storage if ros2 else ''}): {len(source)} scans of "
               f"{source.ranges.shape[1]} beams on /scan, /odom, /tf, /tf_static")


@app.command()
def bench(json_file: BenchJsonOpt = None, samplers: BenchSamplersOpt = None, sweeps: BenchSweepsOpt = 200,
          reference_sweeps: ReferenceSweepsOpt = 5, repeats: RepeatsOpt = 5, chains: BenchChainsOpt = 64,
          force: ForceJsonOpt = False) -> None:
    """Fast samplers against the tutorial's reference samplers on the tutorial scene, in one process."""
    import platform

    import jax

    from bayesmap.bench import format_table, run_bench

    for name, value, least in (("--sweeps", sweeps, 1), ("--reference-sweeps", reference_sweeps, 1),
                               ("--repeats", repeats, 1), ("--chains", chains, 1)):
        if value < least:
            raise BayesmapError(f"{name} must be >= {least}, got {value}")
    if json_file is not None:
        check_output_file(json_file, force)
    names = None if samplers is None else [n.strip() for n in samplers.split(",") if n.strip()]
    typer.echo(f"bayesmap bench: tutorial scene (21 x 21, 100 beams, prior 0.5); jax {jax.__version__} on "
               f"{jax.default_backend()}, {os.cpu_count()} cores, {platform.processor() or platform.machine()}")
    results = run_bench(names, fast_sweeps=sweeps, reference_sweeps=reference_sweeps, repeats=repeats,
                        num_chains=chains, progress=lambda msg: typer.echo(f"  {msg} ...", err=True))
    typer.echo(format_table(results))
    if json_file is not None:
        write_json(json_file, results)
        typer.echo(f"wrote {json_file}")


@app.command()
def evaluate(
    log: EvalLogOpt = None,
    bag: EvalBagOpt = None,
    scan_topic: ScanTopicOpt = "/scan",
    odom_topic: OdomTopicOpt = "/odom",
    tf: TfOpt = False,
    truth: TruthOpt = None,
    truth_trajectory: TruthTrajectoryOpt = None,
    run: RunOpt = None,
    scans: EvalScansOpt = None,
    every: EveryOpt = 10,
    resolution: EvalResolutionOpt = scenes.RESOLUTION,
    sampler: EvalSamplerOpt = "cellwise",
    sweeps: EvalSweepsOpt = None,
    beam_model: EvalBeamModelOpt = scenes.LOG_BEAM_MODEL,
    num_poses: EvalPosesOpt = scenes.SIMULATED_NUM_POSES,
    num_angles: EvalAnglesOpt = scenes.SIMULATED_NUM_ANGLES,
    max_range: EvalMaxRangeOpt = None,
    sensor_noise: EvalNoiseOpt = None,
    prior_wall_prob: EvalPriorOpt = None,
    range_offset: EvalRangeOffsetOpt = None,
    geometry: GeometryOpt = None,
    wall_pass_prob: WallPassOpt = None,
    cut_past_reading: CutOpt = None,
    likelihood_power: PowerOpt = None,
    coupling: CouplingOpt = None,
    run_length: RunLengthOpt = None,
    beam_weights: BeamWeightsOpt = None,
    lambda_short: LambdaShortOpt = None,
    seed: EvalSeedOpt = 0,
    json_file: EvalJsonOpt = None,
    force: ForceJsonOpt = False,
) -> None:
    """Score bayesmap against log-odds mapping: on held-out beams of a log (occupancy AUC, predictive NLL), or
    against a known floor plan (accuracy, AUC, Brier score). With --truth-trajectory, score SLAM's path (a new run
    on the log, or the folder --run) and the log's raw odometry against the true trajectory (ATE, RPE, coverage of
    the 95 % pose ellipses)."""
    request = evaluate_run.EvaluateRequest(**locals())  # (first statement: the locals are the options)
    with ProgressBar() as bar:
        done = evaluate_run.evaluate(request, bar, _notify)
    _echo([done.header, done.table])
    if json_file is not None:
        write_json(json_file, done.scores)
        typer.echo(f"wrote {json_file}")


@app.command()
def slam(
    log: SlamLogOpt = None,
    bag: BagOpt = None,
    scan_topic: ScanTopicOpt = "/scan",
    odom_topic: OdomTopicOpt = "/odom",
    tf: TfOpt = False,
    scans: ScansOpt = None,
    resolution: SlamResolutionOpt = None,
    sweeps: SlamSweepsOpt = None,
    burn_in: SlamBurnInOpt = None,
    seed: SlamSeedOpt = 0,
    num_poses: SlamPosesOpt = None,
    keyframe_distance: KeyframeDistanceOpt = None,
    keyframe_turn: KeyframeTurnOpt = None,
    tile_pairs: TilePairsOpt = None,
    particles: ParticlesOpt = None,
    branches: BranchesOpt = None,
    motion_alphas: MotionAlphasOpt = None,
    rosmap: RosmapOpt = False,
    maps: MapsOpt = False,
    report: SlamReportOpt = False,
    out: OutOpt = Path("bayesmap-out"),
    force: ForceOutputsOpt = False,
) -> None:
    """Joint SLAM: infer the path and the map together. With --log FILE (pose fields = odometry) or --bag PATH, a
    real robot's scans; with neither, the tutorial scene (a loop around the tutorial room, noisy odometry).

    Writes trajectory.tum (posterior mean pose per scan, stamped with the log's scan timestamps, or the scan indices
    where they do not increase strictly; the tutorial's: scan indices), trajectory_samples.npy (N, S, 3),
    pose_cov.npy (S, 3, 3), posterior.npy, posterior.png (the map with the paths), summary.json, with --log / --bag
    occupancy.png (the map alone), and with --rosmap, --maps and --report the maps and report.html as infer writes
    them."""
    request = slam_run.SlamRequest(**locals())  # (first statement: the locals are the options)
    with ProgressBar() as bar:
        done, written = slam_run.slam(request, bar, _notify)
    _echo(slam_run.summary_lines(done, out, written))


@app.command("app")
def explorer(host: HostOpt = "127.0.0.1", port: PortOpt = 8080, no_browser: NoBrowserOpt = False) -> None:
    """The interactive map explorer, a local web app: draw walls, drag the sensor, run inference, browse samples.

    It serves its own scripts and contacts nothing on the network. Stop it with Ctrl+C."""
    from bayesmap.app import run_app  # (here, not at the top: NiceGUI takes a second to import, only `app` needs it)

    typer.echo(f"bayesmap explorer at http://{host}:{port}/ (Ctrl+C stops it)")
    run_app(host=host, port=port, show=not no_browser)


# -- the entry point ----------------------------------------------------------------------------------------------


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


def _usage_error(err, argv: Optional[list[str]]) -> str:
    """One line for a click usage error: click's message, the value the user gave (click's conversion errors do
    not name it) and where to get help."""
    message = err.format_message() if hasattr(err, "format_message") else str(err)
    param = getattr(err, "param", None)
    given = None if param is None else _given_value(sys.argv[1:] if argv is None else list(argv), param)
    if given is not None and "got " not in message:
        message = f"{message.rstrip('.')}, got {given!r}"
    context = getattr(err, "ctx", None)
    hint = f" (see '{context.command_path} --help')" if context is not None else ""
    return f"error: {_one_line(message)}{hint}"


INTERRUPTED = 130
"""The exit code of a run stopped by Ctrl+C: 128 + SIGINT (2), what a shell reports for a process SIGINT ended."""


def main(argv: Optional[list[str]] = None) -> None:
    """Run the typer app on ``argv`` (default ``sys.argv[1:]``); the ``bayesmap`` command calls it through
    :mod:`bayesmap.__main__`, which first caps glibc's heaps and turns JAX's persistent compilation cache off.

    Every user error ends the process with ONE line ``error: ...`` on stderr and exit code 2: a
    :class:`BayesmapError` (bad file or value) and every command-line usage error of click (unknown command or
    option, a value of the wrong type, a missing value; typer ships its own copy of click, whose exceptions all
    derive from ``typer.TyperException``). ``--help`` exits 0. Ctrl+C prints one line and exits with
    :data:`INTERRUPTED` (typer turns the ``KeyboardInterrupt`` into that exit code, which it returns); outputs are
    written whole or not at all, so an interrupted run leaves none half-written.

    Raises:
        SystemExit: always, with the exit code (0 on success).
    """
    try:
        code = app(args=argv, prog_name="bayesmap", standalone_mode=False)
    except BayesmapError as err:
        typer.echo(f"error: {_one_line(err)}", err=True)
        sys.exit(2)
    except typer.Exit as ex:
        code = ex.exit_code
    except typer.Abort:  # end of input at a prompt
        typer.echo("aborted", err=True)
        sys.exit(1)
    except KeyboardInterrupt:  # (typer returns INTERRUPTED for one raised in a command)
        code = INTERRUPTED
    except typer.TyperException as err:  # click's UsageError, BadParameter, NoSuchOption, ...
        if type(err).__name__ == "NoArgsIsHelpError":  # bare `bayesmap`: the help (rich prints it while formatting)
            err.show()
            sys.exit(2)
        typer.echo(_usage_error(err, argv), err=True)
        sys.exit(2)
    if code == INTERRUPTED:
        typer.echo("interrupted (Ctrl+C)", err=True)
    sys.exit(code if isinstance(code, int) else 0)


click_command = typer.main.get_command(app)
"""The click command of the typer app, for the documentation's generated CLI reference (docs/cli.md)."""


if __name__ == "__main__":
    main()
