"""The inputs of a run: the log or bag it reads, the scans it selects, the options that shape its model, and the
size checks that refuse, before anything is allocated, a problem that cannot fit in memory.

Every file is read through :mod:`bayesmap.io`'s readers, which read only regular files: a device (``/dev/zero``),
a FIFO or a socket is refused at once, by name (:func:`bayesmap.io.files.read_bytes`,
:func:`bayesmap.io.files.check_regular`).
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Optional

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.tiles import ray_cells
from bayesmap.io.carmen import CarmenLog, read_carmen
from bayesmap.io.files import read_bytes
from bayesmap.io.rosbag import read_bag
from bayesmap.io.rosmap import read_rosmap
from bayesmap.io.tum import read_tum
from bayesmap.model.generative import beam_lengths
from bayesmap.model.motion import make_motion_params
from bayesmap.model.prior import check_coupling, coupling_for_run_length

MAX_GRID_CELLS = 50_000_000
"""Cells of one grid (times the chains run at once): each float32 map of the posterior is 200 MB at this size, and a
chain keeps several."""
MAX_MEMORY_BYTES = 16e9
"""Bytes a run may take (estimated with :data:`BYTES_PER_PAIR`): the machine the limits were set on has 24 GB, and
the operating system and the user's other work need the rest."""
BYTES_PER_PAIR = 80
"""Peak resident bytes of a whole-log run per (beam, cell) pair of its ray-cell table (:func:`ray_cells` counts them
to within 1 %), everything included: the largest measured, 78 bytes for ``infer --log`` of the whole Intel log at
0.1 m (42.4 million pairs, 3.3 GB peak) and 75 for ``slam --log`` of CSAIL (70 million pairs, 5.2 GB); runs of 10
sweeps peak at 22 bytes per pair plus 0.6 GB ([validation](../validation/speed.md#memory))."""
MIN_TRUTH_RESOLUTION = 0.01
"""Meters per pixel: the finest floor plan ``evaluate --truth`` takes (its poses keep 0.5 m of clearance, checked
over a square of ``(2 * 0.5 / resolution + 1) ** 2`` shifted copies of the map)."""


def parse_scans(spec: str | None, num_scans: int) -> np.ndarray:
    """Scan indices from a spec: None or ``"all"`` (every scan), ``"i"`` (one), ``"a:b"`` or ``"a:b:step"``
    (Python slice syntax, any part may be empty), or a comma-separated list of those.

    Returns:
        ``(n,)`` int64 indices, sorted and distinct, ``n >= 1``.

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


def read_source(log: Optional[Path], bag: Optional[Path], scan_topic: str = "/scan", odom_topic: str = "/odom",
                tf: bool = False, max_range: Optional[float] = None) -> Optional[CarmenLog]:
    """The scans of ``--log`` (a CARMEN log) or ``--bag`` (a ROS 1 or 2 bag) as a ``CarmenLog``, or None for neither.

    Raises:
        BayesmapError: for both, for bag options without a bag, or as the readers do (a missing, unreadable,
            malformed or non-regular file, named).
    """
    if log is not None and bag is not None:
        raise BayesmapError("give either --log or --bag, not both")
    if bag is None:
        if tf or scan_topic != "/scan" or odom_topic != "/odom":
            raise BayesmapError("--scan-topic, --odom-topic and --tf need --bag PATH")
        return None if log is None else read_carmen(log, max_range=max_range)
    return read_bag(bag, scan_topic=scan_topic, odom_topic=odom_topic, tf=tf, max_range=max_range)


def read_log_or_bag(path: Path, scan_topic: str = "/scan", odom_topic: str = "/odom", tf: bool = False) -> CarmenLog:
    """``bayesmap convert``'s input: a ROS bag (a ``.bag`` file or a folder) or else a CARMEN log.

    Raises:
        BayesmapError: on bag options for a CARMEN log, or as the readers do.
    """
    is_bag = path.is_dir() or path.suffix == ".bag"
    if not is_bag and (tf or scan_topic != "/scan" or odom_topic != "/odom"):
        raise BayesmapError(f"--scan-topic, --odom-topic and --tf apply to a bag, and {str(path)!r} is not one "
                            "(a ROS 1 bag ends in .bag, a ROS 2 bag is a folder)")
    return read_bag(path, scan_topic=scan_topic, odom_topic=odom_topic, tf=tf) if is_bag else read_carmen(path)


def select_scans(log: CarmenLog, chosen) -> CarmenLog:
    """The log of the scans ``chosen`` (``(n,)`` indices, as :func:`parse_scans` returns) of ``log``."""
    if len(chosen) == len(log):
        return log
    return CarmenLog(path=log.path, ranges=log.ranges[chosen], poses=log.poses[chosen], angles=log.angles[chosen],
                     timestamps=log.timestamps[chosen], max_range=log.max_range, is_max_range=log.is_max_range[chosen])


def _four_numbers(text: str, option: str, names: str) -> list[float]:
    """The four comma-separated numbers of an option's value ``text`` (``option`` and its ``names`` for the
    message); raises BayesmapError naming the value when there are not four numbers."""
    try:
        values = [float(p.strip()) for p in text.split(",")]
    except ValueError:
        raise BayesmapError(f"{option} must be four numbers {names}, got {text!r}") from None
    if len(values) != 4:
        raise BayesmapError(f"{option} must be four numbers {names}, got {len(values)} in {text!r}")
    return values


def sensor_params(beam_weights: Optional[str], lambda_short: Optional[float]) -> dict:
    """The beam mixture's parameters from ``--beam-weights HIT,SHORT,MAX,RAND`` and ``--lambda-short`` (keywords of
    ``make_params``, which checks them); empty for the defaults.

    Raises:
        BayesmapError: if ``beam_weights`` is not four comma-separated numbers.
    """
    params = {}
    if beam_weights is not None:
        values = _four_numbers(beam_weights, "--beam-weights", "HIT,SHORT,MAX,RAND")
        params.update(zip(("z_hit", "z_short", "z_max", "z_rand"), values))
    if lambda_short is not None:
        params["lambda_short"] = lambda_short
    return params


def motion_option(motion_alphas: Optional[str]):
    """The odometry motion model's noise from ``--motion-alphas A1,A2,A3,A4`` (*Probabilistic Robotics* Table 5.6's
    alphas as standard deviations, :class:`bayesmap.model.motion.MotionParams`; the floors kept at their defaults);
    None for the defaults.

    Raises:
        BayesmapError: if ``motion_alphas`` is not four comma-separated finite numbers >= 0 (named).
    """
    if motion_alphas is None:
        return None
    values = _four_numbers(motion_alphas, "--motion-alphas", "A1,A2,A3,A4")
    try:
        return make_motion_params(values)
    except BayesmapError as err:
        raise BayesmapError(f"--motion-alphas: {err} (in {motion_alphas!r})") from None


def coupling_option(coupling: Optional[float], run_length: Optional[float], resolution: float) -> Optional[float]:
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


def check_free_cell(walls, pos, source: str) -> None:
    """Refuse a sensor position ``pos`` (x, y in cells of ``walls`` ``(nx, ny)``) that lies in a wall cell, naming
    the cell (positions outside the map are refused later, by :meth:`Grid.check_inside`).

    Raises:
        BayesmapError: naming the position, the cell and ``source``.
    """
    i, j = (int(math.floor(v + 0.5)) for v in pos)  # cell (i, j) spans [i - 0.5, i + 0.5) (the tutorial's frame)
    if 0 <= i < walls.shape[0] and 0 <= j < walls.shape[1] and walls[i, j] > 0.5:
        raise BayesmapError(f"sensor position ({pos[0]:g}, {pos[1]:g}) is in wall cell ({i}, {j}) of {source}; "
                            "put the sensor in a free cell ('.')")


def check_sizes(shape: tuple[int, int], resolution: float, pairs: float, chains: int = 1) -> None:
    """Refuse a grid of ``shape`` cells over :data:`MAX_GRID_CELLS` (times ``chains``), or a ray-cell table of
    ``pairs`` (estimated) pairs whose run would take more than :data:`MAX_MEMORY_BYTES` at :data:`BYTES_PER_PAIR`.

    Raises:
        BayesmapError: naming the figure and the way out.
    """
    nx, ny = shape
    if nx * ny * max(chains, 1) > MAX_GRID_CELLS:
        raise BayesmapError(f"the grid would have {nx:,} x {ny:,} = {nx * ny:,} cells of {resolution:g} m (x {chains} "
                            f"chains; at most {MAX_GRID_CELLS:,}): use a coarser --resolution, fewer --chains or fewer "
                            "--scans (a far-away pose widens the grid)")
    if pairs * BYTES_PER_PAIR > MAX_MEMORY_BYTES:
        raise BayesmapError(f"the ray-cell table would take about {pairs * BYTES_PER_PAIR / 1e9:,.0f} GB with the "
                            f"run's other arrays ({pairs:,.0f} (beam, cell) pairs at {BYTES_PER_PAIR} bytes; at most "
                            f"{MAX_MEMORY_BYTES / 1e9:g} GB): use a coarser --resolution, fewer --scans or a larger "
                            "--keyframe-distance, fewer poses or beams, or a shorter --cut-past-reading or "
                            "--max-range")


def check_tile_pairs_option(tile_pairs: Optional[int]) -> None:
    """Refuse a ``--tile-pairs`` below 1 (None, the default, passes).

    Raises:
        BayesmapError: naming the option and the value.
    """
    if tile_pairs is not None and tile_pairs < 1:
        raise BayesmapError(f"--tile-pairs must be an integer >= 1, got {tile_pairs}")


def check_problem_size(problem, chains: int = 1) -> None:
    """Refuse, before anything is allocated, a mapping problem (a :class:`bayesmap.scenes.Problem`) whose grid or
    ray-cell table cannot fit in memory (:func:`check_sizes`); a beam's length is bounded by the max distance and
    the grid's diagonal.

    Raises:
        BayesmapError: naming the grid's cells or the estimated pairs and gigabytes, and the way out.
    """
    grid = problem.grid
    if grid.num_cells * max(chains, 1) > MAX_GRID_CELLS:
        check_sizes(grid.shape, grid.resolution, 0.0, chains)
    pairs = ray_cells(grid, problem.ray_origins, problem.ray_angles,
                      beam_lengths(problem.model_ray_readings, problem.params)).sum()
    check_sizes(grid.shape, grid.resolution, float(pairs), chains)


def check_slam_size(problem, tile_pairs: int) -> None:
    """Refuse a SLAM problem (:class:`bayesmap.slam.problem.SlamProblem`) whose grid or largest ray-cell table cannot
    fit (:func:`check_sizes`), before any work. Its map blocks hold at most ``tile_pairs`` pairs at once (the map is
    swept a tile at a time beyond: :mod:`bayesmap.inference.tiled`), so the table counted is the smaller of the
    whole log's and ``tile_pairs``.

    Raises:
        BayesmapError: as :func:`check_sizes`.
    """
    grid = problem.params.grid
    odometry = np.asarray(problem.odometry, dtype=np.float64)
    angles = odometry[:, 2:3] + np.asarray(problem.sensor_angles)
    origins = np.repeat(odometry[:, :2], angles.shape[1], axis=0)
    pairs = ray_cells(grid, origins, angles, beam_lengths(problem.readings, problem.params)).sum()
    check_sizes(grid.shape, grid.resolution, float(min(pairs, tile_pairs)))


def check_truth_scene(truth: Path, resolution: float, num_poses: int, num_angles: int, max_range: float) -> None:
    """Refuse an ``evaluate --truth`` scene that cannot be simulated or cannot fit, before any work.

    Raises:
        BayesmapError: on a floor plan finer than :data:`MIN_TRUTH_RESOLUTION`, a max range shorter than one cell,
            or sizes over :func:`check_sizes`' limits (or as :func:`bayesmap.io.rosmap.read_rosmap`).
    """
    grid = read_rosmap(truth, resolution=resolution if truth.suffix.lower() == ".pgm" else None).grid
    if grid.resolution < MIN_TRUTH_RESOLUTION:
        raise BayesmapError(f"{truth}: {grid.resolution:g} m per pixel is finer than {MIN_TRUTH_RESOLUTION:g} m; "
                            "resample the floor plan (or give a bare .pgm a coarser --resolution)")
    if max_range < grid.resolution:
        raise BayesmapError(f"--max-range {max_range:g} m is shorter than one cell of {truth} ({grid.resolution:g} m): "
                            "no beam would cross a cell")
    # the poses are drawn later, anywhere in the plan: each beam as long as the max range or the plan's diagonal
    length = min(max_range, math.hypot(*grid.shape) * grid.resolution)
    angles = np.linspace(0, 2 * np.pi, num_angles, endpoint=False)
    per_scan = np.sum(length * (np.abs(np.cos(angles)) + np.abs(np.sin(angles))) / grid.resolution + 2.0)
    check_sizes(grid.shape, grid.resolution, num_poses * float(per_scan))


def load_npy(path: Path, what: str) -> np.ndarray:
    """A ``.npy`` array read whole (no pickles).

    Raises:
        BayesmapError: naming ``what`` and the file, if it cannot be read or is not a ``.npy`` array.
    """
    name, data = read_bytes(path, what)
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        raise BayesmapError(f"{what} {name!r} is not a .npy array: {' '.join(str(err).split())}") from None


def read_slam_run(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The trajectory of a ``bayesmap slam`` output folder: ``(stamps (S,), mean path (S, 3), pose_cov (S, 3, 3),
    samples (N, S, 3) or None)`` from its trajectory.tum, pose_cov.npy and trajectory_samples.npy (x, y m, theta
    rad; covariances m^2, m rad, rad^2), float64; None where the folder has no trajectory_samples.npy.

    Raises:
        BayesmapError: naming the folder or file: not a folder, a file missing (trajectory.tum or pose_cov.npy),
            unreadable or not a regular file, or a pose_cov.npy or trajectory_samples.npy whose shape does not match
            the trajectory's poses.
    """
    run = Path(run)
    if not run.is_dir():
        raise BayesmapError(f"--run {str(run)!r} is not a folder (give the --out folder of bayesmap slam)")
    stamps, mean = read_tum(run / "trajectory.tum")
    cov = load_npy(run / "pose_cov.npy", "pose covariances")
    if cov.shape != (len(mean), 3, 3):
        raise BayesmapError(f"{str(run / 'pose_cov.npy')!r} has shape {cov.shape}, but trajectory.tum has "
                            f"{len(mean)} poses: expected ({len(mean)}, 3, 3)")
    samples = None
    if (run / "trajectory_samples.npy").exists():
        samples = load_npy(run / "trajectory_samples.npy", "trajectory samples")
        if samples.ndim != 3 or samples.shape[1:] != (len(mean), 3) or samples.shape[0] == 0:
            raise BayesmapError(f"{str(run / 'trajectory_samples.npy')!r} has shape {samples.shape}, but "
                                f"trajectory.tum has {len(mean)} poses: expected (N, {len(mean)}, 3), N >= 1")
        samples = samples.astype(np.float64)
    return stamps, mean, cov.astype(np.float64), samples
