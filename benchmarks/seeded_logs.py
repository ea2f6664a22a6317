"""The shared logs and their SLAM problems with other odometry noise seeds, for the benchmarks:
``shared/tools/noisy_odometry.py`` run on a corrected CARMEN log (``shared/data/carmen/NAME-corrected.log.gz``)."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.io.carmen import CarmenLog, read_carmen
from bayesmap.io.tum import read_tum

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"  # the project's data lives at ../shared/data (shared/data/README.md)
CORRECTED_LOGS = {name: SHARED / "data" / "carmen" / f"{name}-corrected.log.gz" for name in ("intel", "aces", "csail")}
NOISY_ODOMETRY = SHARED / "tools" / "noisy_odometry.py"


def write_seeded_log(name: str, seed: int, prefix: Path) -> tuple[CarmenLog, np.ndarray]:
    """Write log ``name``'s (a key of :data:`CORRECTED_LOGS`) noisy-odometry problem for ``seed`` as ``PREFIX.log.gz``
    and ``PREFIX.truth.tum`` and read it back: ``(the log, whose FLASER poses are the noisy odometry; its true poses
    (S, 3), x y m, theta rad)``.

    Raises:
        BayesmapError: noisy_odometry.py failed (its stderr's end in the message), or its outputs do not agree on the
            number of scans.
    """
    cmd = [sys.executable, str(NOISY_ODOMETRY), str(CORRECTED_LOGS[name]), str(prefix), "--seed", str(seed)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise BayesmapError(f"noisy_odometry.py failed for log {name!r} seed {seed}: {done.stderr.strip()[-500:]}")
    log = read_carmen(f"{prefix}.log.gz")
    truth = read_tum(f"{prefix}.truth.tum")[1]
    if len(truth) != len(log):
        raise BayesmapError(f"{prefix}: {len(log)} scans but {len(truth)} true poses")
    return log, truth


def seeded_log(name: str, seed: int) -> tuple[CarmenLog, np.ndarray]:
    """:func:`write_seeded_log` in a temporary folder (removed before returning).

    Raises:
        BayesmapError: as :func:`write_seeded_log`.
    """
    with tempfile.TemporaryDirectory() as tmp:
        return write_seeded_log(name, seed, Path(tmp) / f"{name}-odom")
