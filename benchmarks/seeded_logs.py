"""The shared logs and their SLAM problems with other odometry noise seeds, for the benchmarks:
``shared/tools/noisy_odometry.py`` run on a corrected CARMEN log (``shared/data/carmen/NAME-corrected.log.gz``)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.io.carmen import CarmenLog, read_carmen
from bayesmap.io.tum import read_tum
from bayesmap.slam.problem import SLAM_ODOMETRY_ALPHAS, log_slam_problem

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"  # the project's data lives at ../shared/data (shared/data/README.md)
CORRECTED_LOGS = {name: SHARED / "data" / "carmen" / f"{name}-corrected.log.gz" for name in ("intel", "aces", "csail")}
LARGE_LOGS = {"fr079": SHARED / "data" / "carmen" / "freiburg-079-corrected.log.gz"}  # 4,791 scans; never a default
NOISY_ODOMETRY = SHARED / "tools" / "noisy_odometry.py"
SIMULATED_LOGS = ("willow",)  # made by benchmarks/willow_log.py from the floor plan; never in a default --logs
ALL_LOGS = (*CORRECTED_LOGS, *SIMULATED_LOGS, *LARGE_LOGS)


def corrected_log(name: str, folder: Path) -> Path:
    """The corrected log of ``name`` (a key of :data:`CORRECTED_LOGS` or :data:`LARGE_LOGS`, or ``"willow"``, which is
    simulated into ``folder/willow-corrected.log.gz`` by ``willow_log.write_willow_log`` unless it is there already).

    Raises:
        BayesmapError: ``name`` is neither.
    """
    if name in CORRECTED_LOGS or name in LARGE_LOGS:
        return {**CORRECTED_LOGS, **LARGE_LOGS}[name]
    if name not in SIMULATED_LOGS:
        raise BayesmapError(f"unknown log {name!r}; choose from {', '.join(ALL_LOGS)}")
    from willow_log import write_willow_log

    path = Path(folder) / f"{name}-corrected.log.gz"
    if not path.exists():
        write_willow_log(path)
    return path


def write_seeded_log(name: str, seed: int, prefix: Path, noise: float = 1.0) -> tuple[CarmenLog, np.ndarray]:
    """Write log ``name``'s (one of :data:`ALL_LOGS`, :func:`corrected_log`) noisy-odometry problem for ``seed`` as
    ``PREFIX.log.gz`` and ``PREFIX.truth.tum`` and read it back: ``(the log, whose FLASER poses are the noisy odometry;
    its true poses (S, 3), x y m, theta rad)``. ``noise`` multiplies ``noisy_odometry.py``'s default alphas
    (:data:`bayesmap.slam.problem.SLAM_ODOMETRY_ALPHAS`; 1: its defaults, the shared logs' noise).

    Raises:
        BayesmapError: noisy_odometry.py failed (its stderr's end in the message), or its outputs do not agree on the
            number of scans.
    """
    corrected = corrected_log(name, Path(prefix).parent)
    cmd = [sys.executable, str(NOISY_ODOMETRY), str(corrected), str(prefix), "--seed", str(seed)]
    if noise != 1.0:
        cmd += ["--alphas", ",".join(f"{noise * a:g}" for a in SLAM_ODOMETRY_ALPHAS)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise BayesmapError(f"noisy_odometry.py failed for log {name!r} seed {seed}: {done.stderr.strip()[-500:]}")
    log = read_carmen(f"{prefix}.log.gz")
    truth = read_tum(f"{prefix}.truth.tum")[1]
    if len(truth) != len(log):
        raise BayesmapError(f"{prefix}: {len(log)} scans but {len(truth)} true poses")
    return log, truth


def seeded_log(name: str, seed: int, noise: float = 1.0) -> tuple[CarmenLog, np.ndarray]:
    """:func:`write_seeded_log` in a temporary folder (removed before returning).

    Raises:
        BayesmapError: as :func:`write_seeded_log`.
    """
    with tempfile.TemporaryDirectory() as tmp:
        return write_seeded_log(name, seed, Path(tmp) / f"{name}-odom", noise)


def scan_set_problem(name: str, seed: int, scans: str):
    """The SLAM problem of log ``name``'s odometry ``seed`` (:func:`seeded_log`) on the scan set ``scans``: ``"all"``,
    or ``"every2"``, scans 0, 2, 4, ... as ``slam --scans ::2`` takes them; returns ``(problem, truth (S, 3))``, the
    truth at those scans."""
    log, truth = seeded_log(name, seed)
    kept = None if scans == "all" else np.arange(0, len(log), 2)
    return log_slam_problem(log, kept), truth if kept is None else truth[kept]


def add_log_seed_options(parser: argparse.ArgumentParser, json_option: bool = True) -> None:
    """The options every per-(log, seed) benchmark takes: ``--seeds`` (default 0), ``--logs`` (default all of
    :data:`CORRECTED_LOGS`) and, with ``json_option``, ``--json`` (a file for every run's figures)."""
    parser.add_argument("--seeds", default="0", help="odometry noise seeds, e.g. 0-4 or 0,3 (default 0)")
    parser.add_argument("--logs", default=",".join(CORRECTED_LOGS),
                        help=f"comma-separated subset of {','.join(ALL_LOGS)} (default {','.join(CORRECTED_LOGS)}; "
                             "willow is simulated, benchmarks/willow_log.py)")
    if json_option:
        parser.add_argument("--json", type=Path, default=None, help="write every run's figures here")


def run_file(cache: Path, name: str, seed: int, suffix: str) -> Path:
    """Where a benchmark keeps one (log, seed) run in its cache folder: ``cache/NAME-sSEED.SUFFIX`` (``karto_peer.py``
    writes its records and bayesmap's arrays there)."""
    return cache / f"{name}-s{seed}.{suffix}"


def slam_run_arrays(result, truth: np.ndarray) -> dict:
    """The arrays of one ``run_log_slam`` result: the mean path, the chain's covariance (the reported one less the
    graph's, exact where one loop-closure hypothesis holds every sample), the graph's covariance, the true poses and
    the runtime."""
    return {"mean": result.mean_path, "chain_cov": result.pose_cov - result.graph_cov,
            "graph_cov": result.graph_cov, "truth": truth, "runtime_s": result.runtime_s}


def chosen_logs(parser: argparse.ArgumentParser, text: str) -> list[str]:
    """The log names of a ``--logs`` value; an unknown name is a usage error of ``parser`` (exit code 2)."""
    logs = [name.strip() for name in text.split(",") if name.strip()]
    unknown = sorted(set(logs) - set(ALL_LOGS))
    if unknown or not logs:
        parser.error(f"unknown or no log(s) {', '.join(unknown)}; choose from {', '.join(ALL_LOGS)}")
    return logs


SCAN_SETS = ("all", "every2")
"""The scan sets of :func:`scan_set_problem`: every scan, every other scan."""


def scan_set_runs(parser: argparse.ArgumentParser, logs: str, seeds: list[int],
                  scans: str) -> list[tuple[str, int, str]]:
    """``(log, seed, scan set)`` for every log of a ``--logs`` value (:func:`chosen_logs`), seed of ``seeds`` and scan
    set of a comma-separated ``--scans`` value (a subset of :data:`SCAN_SETS`), in that nesting order; a bad value is a
    usage error of ``parser`` (exit code 2)."""
    sets = [s for s in scans.split(",") if s]
    if not sets or set(sets) - set(SCAN_SETS):
        parser.error(f"--scans must be a subset of {','.join(SCAN_SETS)}, got {scans!r}")
    return [(name, seed, s) for name in chosen_logs(parser, logs) for seed in seeds for s in sets]


def run_table(logs: list[str], seeds: list[int], score: Callable[[CarmenLog, np.ndarray], dict],
              row: Callable[[str, int, dict], str], json_path: Path | None = None) -> list[dict]:
    """For every log of ``logs`` and seed of ``seeds``: the problem (:func:`seeded_log`), ``score(log, truth)`` (a
    dict of figures) and its markdown row ``row(name, seed, figures)`` printed at once; the records ``{"log", "seed",
    **figures}`` are returned and, with ``json_path``, written there (indented JSON)."""
    records = []
    for name in logs:
        for seed in seeds:
            figures = score(*seeded_log(name, seed))
            print(row(name, seed, figures), flush=True)
            records.append({"log": name, "seed": seed, **figures})
    if json_path is not None:
        json_path.write_text(json.dumps(records, indent=2) + "\n")
    return records


def table_main(argv: list[str] | None, description: str, header: str, add_options: Callable, score_of: Callable,
               row: Callable[[str, int, dict], str], parse_seeds: Callable[[str], list[int]]) -> int:
    """The ``main`` of a per-(log, seed) table benchmark: the options of :func:`add_log_seed_options` plus
    ``add_options(parser)``, then ``header`` (the markdown table's first two lines) and :func:`run_table` with
    ``score_of(args)`` (a ``score(log, truth)``) and ``row``. Returns the exit code 0."""
    parser = argparse.ArgumentParser(description=description)
    add_log_seed_options(parser)
    add_options(parser)
    args = parser.parse_args(argv)
    logs = chosen_logs(parser, args.logs)
    print(header)
    run_table(logs, parse_seeds(args.seeds), score_of(args), row, args.json)
    return 0
