"""Karto graph SLAM beside bayesmap on the same CARMEN logs and odometry seeds: one Markdown table, one run.

For each log (intel, aces, csail) and each odometry noise seed, the script
  1. makes the SLAM problem with ``/work/shared/tools/noisy_odometry.py CORRECTED.log.gz PREFIX --seed N``
     (real scans, simulated wheel odometry, the corrected poses as ground truth) in a temporary folder,
  2. runs every method of ``--methods`` on it; a method is a function ``(Problem) -> (poses (S, 3), runtime_s)``
     (see ``METHODS``): ``karto`` runs the ``yag-slam`` package (OpenKarto's scan matcher, loop closure and sparse
     pose adjustment, all at their defaults) in a virtual environment of its own, ``benchmarks/.venv-karto``, made
     on first use with ``python3.11 -m venv`` and pip; ``bayesmap`` runs bayesmap's real-log SLAM
     (``bayesmap.runs.slam.log_slam``, what ``bayesmap slam --log`` runs, keyframes included) in this process,
  3. scores each trajectory against the truth with ``bayesmap.evaluation.trajectory.absolute_trajectory_error``
     (absolute trajectory error: RMSE of the positions after the best rigid 2-D alignment, no scale), and raw
     odometry the same way.
It prints, per log, the mean and the worst (largest) ATE over the seeds and the mean runtime of each method.
Karto's result varies several-fold with the odometry seed, so one seed says little.

Usage: PYTHONPATH=src python benchmarks/karto_peer.py [--seeds 0-4] [--logs intel,aces,csail]
                                                    [--methods karto,bayesmap] [--beam-spacing bayesmap]
                                                    [--every 1] [--noise 1] [--json FILE] [--cache DIR]

``--every N`` gives both methods every Nth scan of the log only (scans 0, N, 2N, ...): Karto those scans' ranges and
odometry poses, bayesmap the same scans as ``bayesmap slam --scans ::N`` takes them (each step the odometry's steps
through the scans left out, composed); the truth is scored at those scans. ``fr079`` is Freiburg 079 (4,791 scans),
never part of the default ``--logs``. ``--noise X`` makes the odometry with ``X`` times ``noisy_odometry.py``'s default
alphas (``--alphas``; the problems named ``LOG-noiseX``): a robot with worse wheels than the shared logs'.

``--cache DIR`` keeps every (log, seed)'s record as ``DIR/LOG-sSEED.json`` the moment it is done, and a later call
with the same folder loads it instead of running the methods again (delete a file to rerun it): a long grid can be
split between processes (``--logs``) or stopped and resumed, and one last call with every log prints the whole
table. bayesmap's run also leaves ``DIR/LOG-sSEED.npz``, the arrays ``pose_cov_cv.py --cache DIR`` reads (mean path,
the chain's and the graph's covariances, the truth), so that the ellipses' calibration can be checked on the same
runs.

Runtime is each method's own measurement in seconds: for Karto the time spent in ``GraphSlam.process_scan`` over
all scans (the Karto venv's interpreter start-up, imports and file exchange, about 0.5 s per run, are excluded;
the JSON file also holds the whole subprocess's wall time as ``wall_s``).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
from seeded_logs import (
    ALL_LOGS,
    NOISY_ODOMETRY,
    SIMULATED_LOGS,
    corrected_log,
    run_file,
    slam_run_arrays,
    write_seeded_log,
)

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.trajectory import absolute_trajectory_error, coverage_rank
from bayesmap.io.carmen import beam_offsets, read_carmen
from bayesmap.io.rosbag import compose_poses, invert_pose
from bayesmap.progress import StageRecorder
from bayesmap.runs.slam import log_slam, path_hypotheses_summary

ROOT = Path(__file__).resolve().parents[1]
KARTO_VENV = ROOT / "benchmarks" / ".venv-karto"
KARTO_RUNNER = ROOT / "benchmarks" / "karto_runner.py"
KARTO_PACKAGES = ("yag-slam", "opencv-python-headless")  # yag-slam 0.3.0 imports cv2 without declaring it
KARTO_RANGE_THRESHOLD = 20.0
"""Meters: readings beyond this are not matched (yag-slam's default matcher ``range_threshold``)."""
BEAM_SPACINGS = ("bayesmap", "both-ends")


class Problem(NamedTuple):
    """One SLAM problem: a log's scans with one seed's odometry, and the true trajectory.

    Fields:
        name: log name (``"intel"``, ...).
        seed: odometry noise seed given to noisy_odometry.py.
        ranges: ``(S, K)`` float64, meters; values ``>= max_range`` mean "no return".
        beam_angles: ``(K,)`` float64, radians, evenly spaced beam directions relative to the robot heading
            (:func:`scan_beam_angles`; by default bayesmap's rule, ``bayesmap.io.carmen.beam_offsets``).
        max_range: meters, the log's saturation range (``math.inf`` if none).
        odometry: ``(S, 3)`` float64 odometry poses (x m, y m, theta rad), the first one the first true pose.
        truth: ``(S, 3)`` float64 true (corrected) poses, same units.
        log_path: the noisy-odometry CARMEN log (what a method reads).
        scans: ``(S,)`` int64, the log's scans the problem keeps (``ranges``, ``odometry`` and ``truth`` are theirs).
    """

    name: str
    seed: int
    ranges: np.ndarray
    beam_angles: np.ndarray
    max_range: float
    odometry: np.ndarray
    truth: np.ndarray
    log_path: Path
    scans: np.ndarray


class MethodUnavailable(Exception):
    """A method cannot run on this machine (yet); its table cells show "-"."""


def scan_beam_angles(beams: int, spacing: str) -> np.ndarray:
    """Beam directions ``(beams,)`` float64 in radians relative to the heading, over a 180 degree field of view.

    ``spacing="bayesmap"`` is bayesmap's rule (``bayesmap.io.carmen.beam_offsets``: spacing pi/n for even n, the
    last beam one step short of +90 degrees); ``"both-ends"`` spaces every scan's beams pi/(n-1) from -90 to +90
    degrees. The two differ only for the 180-beam logs (intel, aces), and Karto's ATE depends on it (README).

    Raises:
        BayesmapError: ``spacing`` is neither, or ``beams < 2``.
    """
    if beams < 2 or spacing not in BEAM_SPACINGS:
        raise BayesmapError(f"scan_beam_angles: need beams >= 2 and spacing in {BEAM_SPACINGS}, "
                            f"got {beams!r}, {spacing!r}")
    if spacing == "bayesmap":
        return beam_offsets(beams)
    return np.linspace(-math.pi / 2, math.pi / 2, beams)


def make_problem(name: str, seed: int, folder: Path, spacing: str = "bayesmap", every: int = 1,
                 noise: float = 1.0) -> Problem:
    """Write ``name``'s noisy-odometry log for ``seed`` (its noise ``noise`` times ``noisy_odometry.py``'s default
    alphas, ``seeded_logs.write_seeded_log``) into ``folder`` and read it back as a :class:`Problem` of its scans
    ``0, every, 2 every, ...``.

    ``spacing`` chooses the beam angles (:func:`scan_beam_angles`).

    Raises:
        BayesmapError: noisy_odometry.py failed, or its outputs do not agree on the number of scans.
    """
    prefix = folder / f"{name}-s{seed}"
    log, truth = write_seeded_log(name, seed, prefix, noise)
    kept = np.arange(0, len(log), every)
    return Problem(problem_label(name, every, noise), seed, np.asarray(log.ranges)[kept],
                   scan_beam_angles(log.ranges.shape[1], spacing), log.max_range, np.asarray(log.poses)[kept],
                   truth[kept], Path(f"{prefix}.log.gz"), kept)


def problem_label(name: str, every: int, noise: float = 1.0) -> str:
    """A problem's name in records, cache files and tables: the log's name, ``-everyN`` added where ``every > 1``
    and ``-noiseX`` where the odometry's noise is ``X`` times the default (``noise != 1``)."""
    return name + ("" if every == 1 else f"-every{every}") + ("" if noise == 1 else f"-noise{noise:g}")


def fill_dropped_scans(poses: np.ndarray, kept: np.ndarray, odometry: np.ndarray) -> np.ndarray:
    """A pose for every scan: a scan the SLAM method did not keep gets the last kept scan's pose composed with
    the odometry increment from that scan to it (scans before the first kept one keep their odometry pose).

    Args:
        poses: ``(S, 3)`` float poses, rows of dropped scans arbitrary (NaN).
        kept: ``(S,)`` bool, True where ``poses`` holds the method's estimate.
        odometry: ``(S, 3)`` float odometry poses.

    Returns:
        ``(S, 3)`` float64 poses (x m, y m, theta rad).
    """
    out = np.array(poses, dtype=np.float64)
    last = None
    for i in range(len(out)):
        if kept[i]:
            last = i
        elif last is None:
            out[i] = odometry[i]
        else:
            out[i] = compose_poses(out[last], compose_poses(invert_pose(odometry[last]), odometry[i]))
    return out


def ensure_karto_venv() -> Path:
    """The Karto venv's python: made with ``python3.11 -m venv`` and pip on first use, reused afterwards.

    Raises:
        MethodUnavailable: python3.11 is not on PATH, or creating the venv or installing the packages failed.
    """
    python = KARTO_VENV / "bin" / "python"
    check = [str(python), "-c", "import cv2, yag_slam.graph_slam"]
    if python.exists() and subprocess.run(check, capture_output=True).returncode == 0:
        return python
    base = shutil.which("python3.11")
    if base is None:
        raise MethodUnavailable("python3.11 is not on PATH: cannot make the Karto venv")
    print(f"making the Karto venv at {KARTO_VENV} (once) ...", file=sys.stderr)
    for cmd in ([base, "-m", "venv", str(KARTO_VENV)],
                [str(python), "-m", "pip", "install", "--quiet", *KARTO_PACKAGES]):
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise MethodUnavailable(f"{' '.join(cmd[:4])} failed: {done.stderr.strip()[-500:]}")
    if subprocess.run(check, capture_output=True).returncode != 0:
        raise MethodUnavailable(f"{KARTO_VENV}: yag_slam or cv2 does not import after installing")
    return python


def run_karto(problem: Problem, extra: dict) -> tuple[np.ndarray, float]:
    """Karto's pose of every scan, by ``karto_runner.py`` in the Karto venv (see that file for the algorithm).

    yag-slam's GraphSlam keeps every scan it is given (it has no minimum-travel filter); should a scan be missing
    from its graph, :func:`fill_dropped_scans` gives it a pose and ``extra["filled_scans"]`` counts it.

    Returns:
        ``(S, 3)`` float64 poses (x m, y m, theta rad) and the runtime in seconds (time in ``process_scan``).
        ``extra`` receives ``filled_scans``, ``loop_closures`` and ``wall_s`` (the whole subprocess).

    Raises:
        MethodUnavailable: the Karto venv cannot be made.
        BayesmapError: the runner failed (its stderr's tail is in the message).
    """
    python = ensure_karto_venv()
    with tempfile.TemporaryDirectory(prefix="karto-") as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        increment = float(problem.beam_angles[1] - problem.beam_angles[0])
        np.savez(src, ranges=problem.ranges, odom=problem.odometry, min_angle=float(problem.beam_angles[0]),
                 angle_increment=increment, max_range=problem.max_range, range_threshold=KARTO_RANGE_THRESHOLD)
        start = time.perf_counter()
        done = subprocess.run([str(python), str(KARTO_RUNNER), str(src), str(dst)], capture_output=True, text=True)
        extra["wall_s"] = time.perf_counter() - start
        if done.returncode != 0:
            raise BayesmapError(f"karto_runner.py failed on {problem.name} seed {problem.seed}: "
                                f"{done.stderr.strip()[-800:]}")
        with np.load(dst) as out:
            poses, kept = out["poses"], out["kept"]
            runtime, extra["loop_closures"] = float(out["runtime_s"]), int(out["loop_closures"])
    extra["filled_scans"] = int((~kept).sum())
    return fill_dropped_scans(poses, kept, problem.odometry), runtime


def run_bayesmap(problem: Problem, extra: dict) -> tuple[np.ndarray, float]:
    """bayesmap's SLAM: the posterior mean pose of every scan, by what ``bayesmap slam --log`` runs
    (``bayesmap.runs.slam.log_slam`` at its defaults, keyframes included, in this process; ``--scans ::N`` for a
    problem of every Nth scan), without the final map (the path is scored). ``extra`` gets the 95 % ellipse coverage
    of the truth with the coverages of the posterior's samples and the truth's rank among them
    (:func:`bayesmap.evaluation.trajectory.coverage_rank`, as ``evaluate --truth-trajectory`` prints them), the
    posterior's median position standard deviation and the number of keyframes. Runtime: the whole
    run, compilation included."""
    log = read_carmen(problem.log_path)
    stride = 1 if len(problem.scans) < 2 else int(problem.scans[1] - problem.scans[0])
    stages = StageRecorder()
    run = log_slam(log, problem.log_path, scans=None if stride == 1 else f"::{stride}", seed=problem.seed,
                   final_map=False, progress=stages)
    result, chosen, settings = run.result, run.chosen, run.settings
    if not np.array_equal(chosen, problem.scans):
        raise BayesmapError(f"bayesmap took scans {chosen[:3]}... where the problem has {problem.scans[:3]}...")
    extra.update(coverage_rank(result.mean_path, result.pose_cov, problem.truth, result.pose_samples))
    extra["position_sd_median_m"] = float(np.median(np.sqrt(result.pose_cov[:, 0, 0] + result.pose_cov[:, 1, 1])))
    extra["keyframes"] = settings["keyframes"]
    extra["path_hypotheses"] = path_hypotheses_summary(result.path_hypotheses, chosen[run.keyframes])
    extra["branches_s"] = sum(r.seconds for r in stages.finish() if r.stage == "branches")
    extra[ARRAYS] = slam_run_arrays(result, problem.truth)
    return result.mean_path, result.runtime_s


ARRAYS = "arrays"
"""The key under which a method may leave arrays in its ``extra`` (not part of the record; saved with ``--cache``)."""

Method = Callable[[Problem, dict], tuple[np.ndarray, float]]
METHODS: dict[str, Method] = {"karto": run_karto, "bayesmap": run_bayesmap}
TABLE_METHODS = ("karto", "bayesmap")  # the table always has these columns; "-" where a method did not run


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"0-4"``, ``"0,2,7"`` or a mix (``"0-2,5"``); raises ValueError naming the bad part."""
    seeds: list[int] = []
    for part in text.split(","):
        lo, sep, hi = part.strip().partition("-")
        try:
            first, last = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise ValueError(f"bad seed range {part!r} in --seeds {text!r}") from None
        if first < 0 or last < first:
            raise ValueError(f"bad seed range {part!r} in --seeds {text!r}")
        seeds.extend(range(first, last + 1))
    return sorted(set(seeds))


def run_one(problem: Problem, methods: list[str], cache: Path | None = None) -> dict:
    """Scores of raw odometry and every method on one problem (method errors become an "unavailable" note); with
    ``cache``, a method's arrays (``extra[ARRAYS]``) are saved as ``cache/LOG-sSEED.npz``."""
    record: dict = {"log": problem.name, "seed": problem.seed, "scans": len(problem.truth),
                    "odometry": {"ate_m": absolute_trajectory_error(problem.odometry, problem.truth)["rmse_m"]}}
    for name in methods:
        extra: dict = {}
        try:
            poses, runtime = METHODS[name](problem, extra)
        except MethodUnavailable as exc:
            record[name] = {"unavailable": str(exc)}
            continue
        arrays = extra.pop(ARRAYS, None)
        if arrays is not None and cache is not None:
            np.savez(run_file(cache, problem.name, problem.seed, "npz"), **arrays)
        ate = absolute_trajectory_error(poses, problem.truth)["rmse_m"]
        record[name] = {"ate_m": ate, "runtime_s": runtime, **extra}
    return record


def summarize(records: list[dict]) -> dict:
    """Per log and per method: seed count, ATE mean and worst (m), runtime mean (s); None where nothing ran."""
    summary: dict = {}
    for log in dict.fromkeys(r["log"] for r in records):
        rows = [r for r in records if r["log"] == log]
        entry: dict = {"seeds": len(rows)}
        for name in ("odometry", *TABLE_METHODS):
            ates = [r[name]["ate_m"] for r in rows if "ate_m" in r.get(name, {})]
            times = [r[name]["runtime_s"] for r in rows if "runtime_s" in r.get(name, {})]
            entry[name] = {"ate_mean_m": float(np.mean(ates)) if ates else None,
                           "ate_worst_m": float(np.max(ates)) if ates else None,
                           "runtime_mean_s": float(np.mean(times)) if times else None, "runs": len(ates)}
        summary[log] = entry
    return summary


def markdown_table(summary: dict) -> str:
    """The summary as a Markdown table, "-" for figures of methods that did not run."""

    def cell(value: float | None, digits: int) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    head = ["log", "seeds", "odometry ATE mean (m)", "odometry ATE worst (m)"]
    for name in TABLE_METHODS:
        head += [f"{name} ATE mean (m)", f"{name} ATE worst (m)", f"{name} runtime mean (s)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for log, entry in summary.items():
        row = [log, str(entry["seeds"]), cell(entry["odometry"]["ate_mean_m"], 2),
               cell(entry["odometry"]["ate_worst_m"], 2)]
        for name in TABLE_METHODS:
            m = entry[name]
            row += [cell(m["ate_mean_m"], 2), cell(m["ate_worst_m"], 2), cell(m["runtime_mean_s"], 1)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-4", help="odometry noise seeds, e.g. 0-4 or 0,3 (default 0-4)")
    parser.add_argument("--logs", default="intel,aces,csail",
                        help=f"comma-separated subset of {','.join(ALL_LOGS)} (willow: simulated, willow_log.py)")
    parser.add_argument("--methods", default="karto", help="comma-separated subset of karto,bayesmap")
    parser.add_argument("--beam-spacing", choices=BEAM_SPACINGS, default="bayesmap",
                        help="beam angles given to every method: bayesmap's rule (default) or pi/(n-1) for all n")
    parser.add_argument("--every", type=int, default=1, help="give the methods every Nth scan only (default 1)")
    parser.add_argument("--noise", type=float, default=1.0,
                        help="odometry noise, a multiple of noisy_odometry.py's default alphas (default 1)")
    parser.add_argument("--json", type=Path, default=None, help="write every run's figures and the summary here")
    parser.add_argument("--cache", type=Path, default=None,
                        help="keep each run's record (and bayesmap's arrays) here; reuse the records found")
    args = parser.parse_args(argv)
    try:
        args.seeds = parse_seeds(args.seeds)
    except ValueError as exc:
        parser.error(str(exc))
    if args.every < 1:
        parser.error(f"--every must be at least 1, got {args.every}")
    if not args.noise > 0:
        parser.error(f"--noise must be a number > 0, got {args.noise}")
    args.logs = [v.strip() for v in args.logs.split(",") if v.strip()]
    args.methods = [v.strip() for v in args.methods.split(",") if v.strip()]
    for value, known, option in ((args.logs, ALL_LOGS, "--logs"), (args.methods, METHODS, "--methods")):
        bad = [v for v in value if v not in known]
        if bad or not value:
            parser.error(f"{option}: unknown or empty {bad or value!r}; choose from {', '.join(known)}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    shared = [corrected_log(n, ROOT) for n in args.logs if n not in SIMULATED_LOGS]  # willow's is made, not read
    missing = [str(p) for p in (NOISY_ODOMETRY, *shared) if not p.exists()]
    if missing:
        print(f"shared data not found: {', '.join(missing)}", file=sys.stderr)
        return 2
    if args.cache is not None:
        args.cache.mkdir(parents=True, exist_ok=True)
    records = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="karto-peer-") as tmp:
        for log in args.logs:
            for seed in args.seeds:
                label = problem_label(log, args.every, args.noise)
                saved = None if args.cache is None else run_file(args.cache, label, seed, "json")
                if saved is not None and saved.exists():
                    record = json.loads(saved.read_text())
                else:
                    problem = make_problem(log, seed, Path(tmp), args.beam_spacing, args.every, args.noise)
                    record = run_one(problem, args.methods, args.cache)
                    if saved is not None:  # whole or not at all: a stopped run leaves no partial record
                        partial = saved.with_suffix(".json.part")
                        partial.write_text(json.dumps(record, indent=1) + "\n")
                        partial.replace(saved)
                records.append(record)
                figures = ", ".join(f"{k} {v['ate_m']:.2f} m" for k, v in record.items()
                                    if isinstance(v, dict) and "ate_m" in v)
                print(f"{label} seed {seed}: ATE {figures}", file=sys.stderr, flush=True)
    summary = summarize(records)
    print(markdown_table(summary))
    notes = sorted({r[m]["unavailable"] for r in records for m in args.methods if "unavailable" in r[m]})
    filled = sum(r[m].get("filled_scans", 0) for r in records for m in args.methods)
    for note in notes:
        print(f"\nnot run: {note}")
    print(f"\nscans given a pose from odometry because a method dropped them: {filled}")
    print(f"beam spacing: {args.beam_spacing}; total time {time.perf_counter() - start:.0f} s")
    if args.json is not None:
        args.json.write_text(json.dumps({"beam_spacing": args.beam_spacing, "seeds": args.seeds, "runs": records,
                                              "summary": summary}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
