"""Read and write planar trajectories in the TUM format.

The TUM RGB-D benchmark's trajectory format (Sturm et al. 2012, "A benchmark for the evaluation of RGB-D SLAM
systems", IROS; the format evo and most SLAM tools read) is a text file with one pose per line::

    t x y z qx qy qz qw

``t`` a time stamp (seconds, or here a scan index), ``x y z`` the position in meters and ``qx qy qz qw`` the
orientation as a unit quaternion (scalar last). Blank lines and lines starting with ``#`` are ignored.

bayesmap's poses are planar, ``(x, y, theta)`` with ``theta`` the heading in radians, counter-clockwise from the
x axis. Reading keeps ``x``, ``y`` and the quaternion's yaw (``z``, roll and pitch are dropped); writing puts
``z = 0`` and the yaw-only quaternion ``(0, 0, sin(theta/2), cos(theta/2))``, positions with 6 decimals (1 um),
quaternions with 9, the format of the project's data (``tools/noisy_odometry.py``).

Every problem with a file raises :class:`bayesmap.errors.BayesmapError` with a one-line message naming the file,
the 1-based line number and the offending value.
"""

from __future__ import annotations

import math

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.io.files import read_bytes, write_atomic

QUATERNION_NORM_TOLERANCE = 1e-3
"""Largest accepted ``| |q| - 1 |`` of a quaternion read (files written with 4 decimals stay well inside it)."""

_COLUMNS = 8


def tum_stamps(log_timestamps) -> np.ndarray:
    """The TUM time stamps of a log's scans: ``(S,)`` float64.

    The scans' own timestamps (seconds) where they increase strictly, else the scan indices ``0, 1, 2, ...``
    (CSAIL's timestamps are written with 6 digits and repeat; some logs' are all 0): the rule of the project's
    data (``data/README.md``, ``tools/noisy_odometry.py``), so that stamps identify scans.

    Args:
        log_timestamps: ``(S,)`` timestamps of the scans in log order (``CarmenLog.timestamps``), seconds.

    Raises:
        BayesmapError: if ``log_timestamps`` is not one-dimensional or holds a non-finite value.
    """
    t = np.asarray(log_timestamps, dtype=np.float64)
    if t.ndim != 1:
        raise BayesmapError(f"log timestamps must be a 1-D array, got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise BayesmapError(f"log timestamp {bad[0]} is {t[bad[0]]!r}, not a finite number")
    if np.all(np.diff(t) > 0):
        return t.copy()
    return np.arange(len(t), dtype=np.float64)


def _parse_line(name: str, lineno: int, line: str) -> tuple[float, float, float, float]:
    """``(t, x, y, theta)`` of one TUM line; raises naming the file, line and value."""
    where = f"TUM trajectory {name!r}, line {lineno}"
    toks = line.split()
    if len(toks) != _COLUMNS:
        raise BayesmapError(f"{where}: expected {_COLUMNS} columns (t x y z qx qy qz qw), got {len(toks)}")
    values = []
    for col, tok in zip("t x y z qx qy qz qw".split(), toks):
        try:
            v = float(tok)
        except ValueError:
            raise BayesmapError(f"{where}: {col} is {tok!r}, not a number") from None
        if not math.isfinite(v):
            raise BayesmapError(f"{where}: {col} is {tok!r}, not a finite number")
        values.append(v)
    t, x, y, _z, qx, qy, qz, qw = values
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise BayesmapError(f"{where}: quaternion ({qx}, {qy}, {qz}, {qw}) has norm {norm:.6g}, not 1 "
                            f"(tolerance {QUATERNION_NORM_TOLERANCE})")
    # yaw (rotation about z) of the quaternion, Z-Y-X Euler convention; atan2 does not need |q| = 1
    theta = math.atan2(2.0 * (qw * qz + qx * qy), qw * qw + qx * qx - qy * qy - qz * qz)
    return t, x, y, theta


def read_tum(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a planar trajectory from a TUM file (format in the module docstring).

    Args:
        path: the file (string or path-like).

    Returns:
        ``(stamps, poses)``: ``stamps`` ``(S,)`` float64 (seconds or scan indices, strictly increasing) and
        ``poses`` ``(S, 3)`` float64 rows ``(x, y, theta)``: meters, meters, radians in ``[-pi, pi]`` (the
        quaternion's yaw).

    Raises:
        BayesmapError: naming the file, and for a bad line its number and value: the file cannot be read or is not
            UTF-8 text, a line does not have 8 columns, a value is not a finite number, a quaternion's norm is
            further than :data:`QUATERNION_NORM_TOLERANCE` from 1, a stamp does not exceed the one before it, or
            the file holds no pose.
    """
    name, raw = read_bytes(path, "TUM trajectory")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise BayesmapError(f"TUM trajectory {name!r} is not UTF-8 text (byte {err.start})") from None
    rows = []
    prev = None
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        row = _parse_line(name, lineno, line)
        if prev is not None and not row[0] > prev:
            raise BayesmapError(f"TUM trajectory {name!r}, line {lineno}: stamp {line.split()[0]!r} does not "
                                f"increase (the line before has {prev!r})")
        prev = row[0]
        rows.append(row)
    if not rows:
        raise BayesmapError(f"TUM trajectory {name!r} holds no pose")
    table = np.array(rows, dtype=np.float64)
    return table[:, 0].copy(), table[:, 1:].copy()


def _format_stamp(s: float) -> str:
    """An integral stamp (a scan index) as an integer, any other by its shortest exact decimal form."""
    return str(int(s)) if s.is_integer() and abs(s) < 2.0**53 else repr(s)


def write_tum(path, stamps, poses, overwrite: bool = False):
    """Write a planar trajectory as a TUM file, whole or not at all (:func:`bayesmap.io.files.write_atomic`).

    Each line is ``t x y 0 0 0 sin(theta/2) cos(theta/2)``: positions with 6 decimals (meters), the yaw-only
    quaternion with 9; stamps that are whole numbers (scan indices) are written as integers, others in their
    shortest exact decimal form. :func:`read_tum` reads the file back to the same stamps, to within 5e-7 m and
    about 1e-8 rad (theta comes back wrapped to ``[-pi, pi]``).

    Args:
        path: the file to write.
        stamps: ``(S,)`` time stamps, strictly increasing (seconds or scan indices, see :func:`tum_stamps`).
        poses: ``(S, 3)`` rows ``(x, y, theta)``: meters, meters, radians.
        overwrite: replace an existing file (else refuse it).

    Returns:
        The path written (a :class:`pathlib.Path`).

    Raises:
        BayesmapError: if the shapes do not match, a value is not finite, the stamps do not increase strictly,
            there is no pose, the file exists and ``overwrite`` is False, or it cannot be written.
    """
    t = np.asarray(stamps, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    if t.ndim != 1 or t.size == 0:
        raise BayesmapError(f"stamps must be a non-empty 1-D array, got shape {t.shape}")
    if p.shape != (len(t), 3):
        raise BayesmapError(f"poses must have shape ({len(t)}, 3) to match the stamps, got {p.shape}")
    for what, arr in (("stamp", t), ("pose", p)):
        bad = np.argwhere(~np.isfinite(arr))
        if len(bad):
            raise BayesmapError(f"{what} {tuple(int(i) for i in bad[0])} is {arr[tuple(bad[0])]!r}, not finite")
    drop = np.flatnonzero(np.diff(t) <= 0)
    if len(drop):
        i = int(drop[0]) + 1
        raise BayesmapError(f"stamps must increase strictly: stamp {i} is {t[i]!r}, after {t[i - 1]!r}")
    lines = [f"{_format_stamp(float(s))} {x:.6f} {y:.6f} 0 0 0 {math.sin(th / 2):.9f} {math.cos(th / 2):.9f}\n"
             for s, (x, y, th) in zip(t, p)]
    return write_atomic(path, "".join(lines), overwrite=overwrite)
