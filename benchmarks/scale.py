"""Time and peak memory of SLAM on longer and longer prefixes of one real log, bayesmap beside Karto, in one run.

The log is Freiburg 079 (``../shared/data/slam/freiburg-079-odom.log.gz``: 4,791 scans of 360 beams, a scan about
every 0.1 m, raw odometry in the pose fields; its true trajectory ``freiburg-079-odom.truth.tum`` has one pose per
scan of the log, so a prefix's truth is its first rows, paired by order). For each prefix of ``--scans`` (the first
250, 500, 1,000, 2,000 and all 4,791 scans by default) and each method of ``--methods``:

* **bayesmap** runs as a subprocess, ``bayesmap slam --log LOG --scans 0:N --out TMP`` at every default, and its
  stages (each one's wall seconds and peak resident memory) are read from the run's summary.json
  (:class:`bayesmap.progress.StageRecorder`), its path from trajectory.tum;
* **Karto** (the ``yag-slam`` package in its own venv, ``benchmarks/.venv-karto``, made on first use with pip) runs
  through ``karto_peer.run_karto`` on the prefix's ranges and odometry, in a worker process of this script (so that
  the runner is watched as a process of its own).

Every run is watched (:func:`run_watched`): the resident memory of its whole process tree is polled every 0.5 s and
the tree killed above ``--memory-limit`` GB (default 10: bayesmap's size refusal lets through prefixes whose ray-cell
table then takes more than this machine has), and killed after ``--time-limit`` seconds (default 1,800). A killed
run is reported as "killed at 10 GB after N s", a refused one (exit 2) with its one-line message.

Each finished run is scored by ATE against the truth (``bayesmap.evaluation.trajectory.absolute_trajectory_error``:
the RMSE of the positions after the best rigid 2-D alignment). The script prints one Markdown table (prefix, method,
status, wall seconds and peak MB of the method's process, ATE, and bayesmap's seconds per stage: front end, loop
closure, the joint chain's rounds, final map, placing the scans between keyframes), a table of bayesmap's every
stage (seconds and peak MB per finished prefix), the raw odometry's ATE per prefix, and, per method, the slopes of
wall seconds and peak MB per 1,000 scans (least squares over the prefixes that finished).

Wall seconds are the method's whole process: for bayesmap the ``bayesmap`` command from start to exit (interpreter
start and imports included, about 5 s); for Karto the runner subprocess (``extra["wall_s"]`` of ``run_karto``; its
time in ``process_scan`` alone is ``runtime_s`` in the JSON). Peak MB (10**6 bytes) is the method's process's peak
resident set size: the largest high-water mark the watchdog read for it (``VmHWM`` of /proc/PID/status, every 0.5 s:
growth in a process's last half second is missed); for a finished bayesmap run the larger of that and summary.json's
``peak_rss_mb`` (its stage recorder's exact figure); for a killed run the largest resident memory of the whole tree
the watchdog saw. Not ``wait4``'s ``ru_maxrss`` (``/usr/bin/time -v``'s "Maximum resident set size"): it counts the
parent's memory copied at fork before the exec (the Karto worker's 355 MB, its imports), and bayesmap's stage
recorder resets the high-water mark at each stage, so at exit it holds only the last stage's peak.

Usage: PYTHONPATH=src nice -n 5 .venv/bin/python benchmarks/scale.py [--scans 250,500,1000,2000,all]
           [--methods bayesmap,karto] [--memory-limit 10] [--time-limit 1800] [--json FILE] [--cache DIR]
           [--bayesmap COMMAND]

``--cache DIR`` keeps each (prefix, method)'s record as ``DIR/freiburg-079-N-METHOD.json`` the moment it is done,
and a later call with the same folder loads it instead of running again (delete a file to rerun it).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple, Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT.parent / "shared" / "data" / "slam" / "freiburg-079-odom.log.gz"
TRUTH = LOG.with_name("freiburg-079-odom.truth.tum")
NAME = "freiburg-079"
DEFAULT_SCANS = "250,500,1000,2000,all"
METHODS = ("bayesmap", "karto")
POLL_S = 0.5
"""Seconds between two polls of a watched run's resident memory."""
MB = 1e6
STAGE_COLUMNS = (("front end", "front end"), ("loop closure", "loop closure"), ("round", "rounds"),
                 ("final map", "final map"), ("place scans", "place scans"))
"""bayesmap's stages in the table: (the stage names' start, the column); the rounds' map and pose stages sum."""


class Watched(NamedTuple):
    """A watched run: ``returncode`` (None if killed), ``wall_s``, ``polled_peak_mb`` (the largest resident memory
    of the whole tree the watchdog saw), ``peaks`` (per process of the tree, by :func:`process_label`: the largest
    high-water mark read, MB) and ``killed``: None, ``"memory"`` or ``"time"``."""

    returncode: Optional[int]
    wall_s: float
    polled_peak_mb: float
    peaks: dict
    killed: Optional[str]


def tree_processes(pid: int) -> list:
    """``psutil.Process`` of ``pid`` and all its descendants (none if it is gone)."""
    import psutil

    try:
        root = psutil.Process(pid)
        return [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def hwm_mb(pid: int) -> Optional[float]:
    """The high-water mark of ``pid``'s resident memory (``VmHWM`` of /proc/PID/status), MB; None if unreadable."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024 / MB
    except (OSError, ValueError, IndexError):
        return None
    return None


def process_label(cmdline: list[str]) -> str:
    """A process's label: the file names of its command's first two words (``"python karto_runner.py"``)."""
    return " ".join(Path(word).name for word in cmdline[:2])


def poll_tree(pid: int, peaks: dict) -> float:
    """The resident memory of ``pid`` and all its descendants, MB (each one's RSS, /proc/PID/statm); ``peaks``
    (label -> MB) keeps each process's largest high-water mark (:func:`hwm_mb`), a process whose command line reads
    empty (between fork and exec, or exiting) left out."""
    import psutil

    total = 0
    for proc in tree_processes(pid):
        try:
            total += proc.memory_info().rss
            label, hwm = process_label(proc.cmdline()), hwm_mb(proc.pid)
        except psutil.NoSuchProcess:
            continue
        if hwm is not None and label:  # an empty command line: a process between fork and exec, or one exiting
            peaks[label] = max(peaks.get(label, 0.0), hwm)
    return total / MB


def kill_tree(pid: int) -> None:
    """SIGKILL the process group ``pid`` leads (a run started with ``start_new_session``) and every descendant."""
    import psutil

    procs = tree_processes(pid)
    try:
        os.killpg(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    for proc in procs:
        try:
            proc.kill()
        except psutil.NoSuchProcess:
            pass


def run_watched(cmd: list, memory_limit_mb: float, time_limit_s: float, output: Optional[Path] = None,
                poll_s: float = POLL_S, env: Optional[dict] = None) -> Watched:
    """Run ``cmd`` in a session of its own, its stdout and stderr into ``output`` (or nowhere), polling the resident
    memory of its process tree every ``poll_s`` seconds (:func:`poll_tree`); kill the tree when that exceeds
    ``memory_limit_mb`` or the run exceeds ``time_limit_s``."""
    start = time.perf_counter()
    polled, killed, next_poll, peaks = 0.0, None, start, {}
    with open(output if output is not None else os.devnull, "wb") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True, env=env)
        while proc.poll() is None:
            now = time.perf_counter()
            if now >= next_poll and killed is None:
                rss = poll_tree(proc.pid, peaks)
                polled = max(polled, rss)
                if rss > memory_limit_mb or now - start > time_limit_s:
                    killed = "memory" if rss > memory_limit_mb else "time"
                    kill_tree(proc.pid)
                next_poll = now + poll_s
            time.sleep(0.02)
    return Watched(None if killed else proc.returncode, time.perf_counter() - start, polled, peaks, killed)


def parse_prefixes(text: str, total: int) -> list[int]:
    """Prefix lengths from ``"250,500,all"`` (``all``: ``total``), sorted, each in ``1..total``; raises ValueError
    naming the bad part."""
    sizes = set()
    for part in (p.strip() for p in text.split(",") if p.strip()):
        try:
            size = total if part == "all" else int(part)
        except ValueError:
            raise ValueError(f"bad prefix {part!r} in --scans {text!r}: a number of scans or 'all'") from None
        if not 1 <= size <= total:
            raise ValueError(f"prefix {size} in --scans {text!r} is not in 1..{total} (the log's scans)")
        sizes.add(size)
    if not sizes:
        raise ValueError(f"--scans {text!r} names no prefix")
    return sorted(sizes)


def stage_columns(stages: list[dict]) -> dict[str, float]:
    """bayesmap's stage seconds summed per column of :data:`STAGE_COLUMNS` (a column none of ``stages`` starts
    with is absent)."""
    columns: dict[str, float] = {}
    for stage in stages:
        for prefix, column in STAGE_COLUMNS:
            if stage["stage"].startswith(prefix):
                columns[column] = columns.get(column, 0.0) + float(stage["seconds"])
    return columns


def fit_slope(scans, values) -> Optional[float]:
    """The least-squares slope of ``values`` against ``scans``, per 1,000 scans; None with fewer than two distinct
    scan counts."""
    x, y = np.asarray(scans, np.float64), np.asarray(values, np.float64)
    if len(np.unique(x)) < 2:
        return None
    return float(np.polyfit(x / 1000.0, y, 1)[0])


def slopes(records: list[dict]) -> dict[str, dict]:
    """Per method: ``{"prefixes": [N, ...], "seconds_per_1000": s, "mb_per_1000": MB}`` over its finished runs."""
    out = {}
    for method in dict.fromkeys(r["method"] for r in records):
        done = [r for r in records if r["method"] == method and r["status"] == "ok"]
        scans = [r["scans"] for r in done]
        out[method] = {"prefixes": scans, "seconds_per_1000": fit_slope(scans, [r["wall_s"] for r in done]),
                       "mb_per_1000": fit_slope(scans, [r["peak_mb"] for r in done])}
    return out


def status_text(record: dict) -> str:
    """A run's status for the table: ok, "killed at 10 GB after 93 s", "refused: ...", "failed (exit 1): ..."."""
    status = record["status"]
    if status == "killed":
        limit = (f"{record['memory_limit_gb']:g} GB" if record["killed"] == "memory"
                 else f"the {record['time_limit_s']:g} s limit")
        return f"killed at {limit} after {record['wall_s']:.0f} s"
    if status in ("refused", "failed"):
        code = "" if status == "refused" else f" (exit {record['returncode']})"
        return f"{status}{code}: {record['message']}".replace("|", "\\|")
    return status


def markdown_table(records: list[dict]) -> str:
    """The records as one Markdown table, in prefix then method order; "-" where a figure does not apply."""

    def cell(value, digits: int) -> str:
        return "-" if value is None else f"{value:,.{digits}f}"

    head = ["prefix scans", "method", "status", "wall s", "peak MB", "ATE m",
            *(f"{column} s" for _, column in STAGE_COLUMNS)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    order = {m: i for i, m in enumerate(METHODS)}
    for r in sorted(records, key=lambda r: (r["scans"], order.get(r["method"], len(order)))):
        stages = stage_columns(r.get("stages", [])) if r["status"] == "ok" else {}
        row = [f"{r['scans']:,}", r["method"], status_text(r), cell(r.get("wall_s"), 0), cell(r.get("peak_mb"), 0),
               cell(r.get("ate_m"), 2), *(cell(stages.get(column), 0) for _, column in STAGE_COLUMNS)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def stage_table(records: list[dict]) -> str:
    """bayesmap's stages, one row each in the order they ran, as a Markdown table: seconds and peak MB per finished
    prefix ("" where a prefix has no such stage); empty if no bayesmap run finished."""
    runs = sorted((r for r in records if r["method"] == "bayesmap" and r["status"] == "ok"), key=lambda r: r["scans"])
    if not runs:
        return ""
    names: list[str] = []
    for r in runs:  # each stage after the one that ran before it (a stage only some prefixes have keeps its place)
        for k, stage in enumerate(r["stages"]):
            if stage["stage"] not in names:
                before = r["stages"][k - 1]["stage"] if k else None
                names.insert(names.index(before) + 1 if before in names else 0, stage["stage"])
    head = ["stage", *(f"{r['scans']:,} scans: {what}" for r in runs for what in ("s", "peak MB"))]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name in names:
        row = [name]
        for r in runs:
            stage = next((s for s in r["stages"] if s["stage"] == name), None)
            row += ["", ""] if stage is None else [f"{stage['seconds']:,.1f}", f"{stage['peak_rss_mb']:,.0f}"]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def error_line(text: str) -> str:
    """The ``error: ...`` line of a command's output (its last), else the output's last non-empty line."""
    lines = [line.strip() for line in text.replace("\r", "\n").splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    return (errors or lines or [""])[-1].removeprefix("error:").strip()


def watched_record(record: dict, watched: Watched, output: Path, limits: dict, label: str) -> dict:
    """``record`` with the status, wall time and peak memory of a watched run: the peak of its processes whose
    label holds ``label`` (the whole tree's largest resident memory if it was killed), the message of a refused or
    failed one from its ``output``."""
    peaks = [mb for name, mb in watched.peaks.items() if label in name]
    record.update(wall_s=watched.wall_s, polled_peak_mb=watched.polled_peak_mb, returncode=watched.returncode,
                  peaks=watched.peaks, peak_mb=max(peaks) if peaks else None)
    if watched.killed is not None:
        record.update(status="killed", killed=watched.killed, peak_mb=watched.polled_peak_mb, **limits)
    elif watched.returncode != 0:
        record.update(status="refused" if watched.returncode == 2 else "failed",
                      message=error_line(output.read_text(errors="replace")))
    else:
        record.update(status="ok")
    return record


def run_bayesmap(scans: int, truth: np.ndarray, limits: dict, folder: Path, command: Optional[str] = None) -> dict:
    """bayesmap slam on the first ``scans`` scans, watched; its stages, path and ATE when it finishes. ``command``:
    the ``bayesmap`` executable to run; default the one beside this Python."""
    from bayesmap.evaluation.trajectory import absolute_trajectory_error
    from bayesmap.io.tum import read_tum

    out, output = folder / f"bayesmap-{scans}", folder / f"bayesmap-{scans}.txt"
    command = command or str(Path(sys.executable).parent / "bayesmap")
    cmd = [command, "slam", "--log", str(LOG), "--scans", f"0:{scans}", "--out", str(out)]
    watched = run_watched(cmd, limits["memory_limit_gb"] * 1e3, limits["time_limit_s"], output)
    record = watched_record({"scans": scans, "method": "bayesmap", "command": " ".join(cmd[1:])}, watched, output,
                            limits, label="bayesmap")
    if record["status"] == "ok":
        summary = json.loads((out / "summary.json").read_text())
        _, poses = read_tum(out / "trajectory.tum")
        record.update(peak_mb=max(record["peak_mb"] or 0.0, summary["peak_rss_mb"]),
                      stages=summary["stages"], summary_peak_rss_mb=summary["peak_rss_mb"],
                      runtime_s=summary["runtime_s"], loop_edges=summary["loop_edges"],
                      ate_m=absolute_trajectory_error(poses, truth[:scans])["rmse_m"])
    return record


def run_karto(scans: int, limits: dict, folder: Path) -> dict:
    """Karto on the first ``scans`` scans, in a watched worker process of this script (:func:`karto_worker`)."""
    result, output = folder / f"karto-{scans}.json", folder / f"karto-{scans}.txt"
    cmd = [sys.executable, str(Path(__file__).resolve()), "--karto-worker", str(scans), "--json", str(result)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    watched = run_watched(cmd, limits["memory_limit_gb"] * 1e3, limits["time_limit_s"], output, env=env)
    record = watched_record({"scans": scans, "method": "karto"}, watched, output, limits, label="karto_runner.py")
    if record["status"] == "ok":
        worker = json.loads(result.read_text())
        record.update(worker, wall_s=worker["wall_s"], worker_wall_s=watched.wall_s)
    return record


def karto_worker(scans: int, result: Path) -> int:
    """In the worker process: Karto (``karto_peer.run_karto``) on the first ``scans`` scans of the log, its ATE and
    the runner's wall time, written to ``result`` as JSON."""
    from karto_peer import Problem, scan_beam_angles
    from karto_peer import run_karto as karto_peer_run

    from bayesmap.evaluation.trajectory import absolute_trajectory_error
    from bayesmap.io.carmen import read_carmen
    from bayesmap.io.tum import read_tum

    log, truth = read_carmen(LOG), read_tum(TRUTH)[1][:scans]
    ranges = np.asarray(log.ranges[:scans], np.float64)
    problem = Problem(NAME, 0, ranges, scan_beam_angles(ranges.shape[1], "bayesmap"), float(log.max_range),
                      np.asarray(log.poses[:scans], np.float64), truth, LOG)
    extra: dict = {}
    poses, runtime = karto_peer_run(problem, extra)
    record = {"runtime_s": runtime, "wall_s": extra["wall_s"], "loop_closures": extra["loop_closures"],
              "filled_scans": extra["filled_scans"], "ate_m": absolute_trajectory_error(poses, truth)["rmse_m"]}
    result.write_text(json.dumps(record) + "\n")
    return 0


def cached_run(scans: int, method: str, truth: np.ndarray, limits: dict, folder: Path, cache: Optional[Path],
               command: Optional[str] = None) -> dict:
    """The record of one (prefix, method): loaded from ``cache`` if there, else run (and saved there, whole);
    ``command`` the ``bayesmap`` executable (:func:`run_bayesmap`)."""
    saved = None if cache is None else cache / f"{NAME}-{scans}-{method}.json"
    if saved is not None and saved.exists():
        return json.loads(saved.read_text())
    record = (run_bayesmap(scans, truth, limits, folder, command) if method == "bayesmap"
              else run_karto(scans, limits, folder))
    if saved is not None:
        partial = saved.with_suffix(".json.part")
        partial.write_text(json.dumps(record, indent=1) + "\n")
        partial.replace(saved)
    return record


def odometry_ates(prefixes: list[int], truth: np.ndarray) -> dict[int, float]:
    """The raw odometry's ATE on each prefix (the log's pose fields against the truth)."""
    from bayesmap.evaluation.trajectory import absolute_trajectory_error
    from bayesmap.io.carmen import read_carmen

    odometry = np.asarray(read_carmen(LOG).poses, np.float64)
    return {n: absolute_trajectory_error(odometry[:n], truth[:n])["rmse_m"] for n in prefixes}


def report(records: list[dict], odometry: dict[int, float]) -> str:
    """The table, bayesmap's stages (:func:`stage_table`), the odometry's ATE per prefix and each method's slopes,
    as printed."""
    lines = [markdown_table(records), "", stage_table(records), "",
             "raw odometry ATE: " + ", ".join(f"{n:,} scans {ate:.2f} m" for n, ate in odometry.items())]
    for method, fit in slopes(records).items():
        if fit["seconds_per_1000"] is None:
            lines.append(f"{method}: fewer than two prefixes finished ({fit['prefixes']}), no slope")
        else:
            lines.append(f"{method}: {fit['seconds_per_1000']:,.0f} s and {fit['mb_per_1000']:,.0f} MB per 1,000 "
                         f"scans (least squares over the prefixes that finished: {fit['prefixes']})")
    return "\n".join(lines)


def parse_args(argv: Optional[list[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", default=DEFAULT_SCANS, help=f"prefix lengths, 'all' the whole log "
                        f"(default {DEFAULT_SCANS})")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated subset of bayesmap,karto")
    parser.add_argument("--memory-limit", type=float, default=10.0,
                        help="GB (10**9 bytes) of resident memory at which a run's process tree is killed")
    parser.add_argument("--time-limit", type=float, default=1800.0, help="seconds after which a run is killed")
    parser.add_argument("--json", type=Path, default=None, help="write every record and the slopes here")
    parser.add_argument("--cache", type=Path, default=None, help="keep each run's record here; reuse those found")
    parser.add_argument("--bayesmap", default=None, help="the bayesmap command to run (default: the bayesmap "
                        "script beside this Python, as a venv installs it)")
    parser.add_argument("--karto-worker", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in args.methods if m not in METHODS]
    if bad or not args.methods:
        parser.error(f"--methods: unknown or empty {bad or args.methods!r}; choose from {', '.join(METHODS)}")
    if args.memory_limit <= 0 or args.time_limit <= 0:
        parser.error("--memory-limit and --time-limit must be positive")
    return args


def main(argv: Optional[list[str]] = None) -> int:
    args = parse_args(argv)
    if args.karto_worker is not None:
        return karto_worker(args.karto_worker, args.json)
    missing = [str(p) for p in (LOG, TRUTH) if not p.exists()]
    if missing:
        print(f"shared data not found: {', '.join(missing)}", file=sys.stderr)
        return 2
    from bayesmap.io.tum import read_tum

    truth = read_tum(TRUTH)[1]
    try:
        prefixes = parse_prefixes(args.scans, len(truth))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.cache is not None:
        args.cache.mkdir(parents=True, exist_ok=True)
    limits = {"memory_limit_gb": args.memory_limit, "time_limit_s": args.time_limit}
    records, start = [], time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="scale-") as tmp:
        for scans in prefixes:
            for method in args.methods:  # one run at a time
                record = cached_run(scans, method, truth, limits, Path(tmp), args.cache, args.bayesmap)
                records.append(record)
                print(f"{scans} scans, {method}: {status_text(record)}, {record['wall_s']:.0f} s", file=sys.stderr,
                      flush=True)
    odometry = odometry_ates(prefixes, truth)
    print(report(records, odometry))
    print(f"\ntotal time {time.perf_counter() - start:.0f} s")
    if args.json is not None:
        args.json.write_text(json.dumps({"log": str(LOG), "limits": limits, "runs": records,
                                         "odometry_ate_m": odometry, "slopes": slopes(records)}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
