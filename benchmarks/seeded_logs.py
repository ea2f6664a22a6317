"""The shared SLAM problems with other odometry noise seeds, for the benchmarks: ``shared/tools/noisy_odometry.py``
run on a corrected CARMEN log (``shared/data/carmen/NAME-corrected.log.gz``) in a temporary folder."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bayesmap.io.carmen import CarmenLog, read_carmen
from bayesmap.io.tum import read_tum

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
NOISY_ODOMETRY = SHARED / "tools" / "noisy_odometry.py"


def seeded_log(name: str, seed: int) -> tuple[CarmenLog, np.ndarray]:
    """Log ``name`` (``"intel"``, ``"aces"``, ``"csail"``) with odometry noise seed ``seed``: ``(the log, whose FLASER
    poses are the noisy odometry; its true poses (S, 3), x y m, theta rad)``.

    Raises:
        subprocess.CalledProcessError: if noisy_odometry.py fails (a missing log, a bad seed).
    """
    with tempfile.TemporaryDirectory() as tmp:
        prefix = Path(tmp) / f"{name}-odom"
        corrected = SHARED / "data" / "carmen" / f"{name}-corrected.log.gz"
        subprocess.run([sys.executable, str(NOISY_ODOMETRY), str(corrected), str(prefix), "--seed", str(seed)],
                       check=True, capture_output=True)
        _, truth = read_tum(f"{prefix}.truth.tum")
        return read_carmen(f"{prefix}.log.gz"), truth
