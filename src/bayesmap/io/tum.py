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


STAMP_TOLERANCE = 1e-4
"""Seconds: the largest difference of two stamps :func:`match_stamps` pairs (0.1 ms: CARMEN writes microseconds,
scanners scan at most about every 10 ms, and a bag's repeated stamps are spread 1 ms apart,
:mod:`bayesmap.io.rosbag`); scan-index stamps are whole numbers, 1 apart."""


def match_stamps(stamps, reference, tolerance: float = STAMP_TOLERANCE) -> np.ndarray:
    """For each stamp, the index of the reference stamp it pairs with: the nearest one, if within ``tolerance``.

    This is how TUM trajectories are paired pose by pose (as evo's ``associate`` does, with a tolerance far below
    the time between scans, so that no stamp can pair with two).

    Args:
        stamps: ``(S,)`` stamps to pair (seconds or scan indices).
        reference: ``(R,)`` stamps, strictly increasing (as :func:`read_tum` returns them).
        tolerance: the largest accepted difference, seconds (``>= 0``).

    Returns:
        ``(S,)`` int64 indices into ``reference``, distinct.

    Raises:
        BayesmapError: naming the first stamp with no reference stamp within ``tolerance`` (and its position), or
            two stamps that pair with the same reference stamp.
    """
    t = np.asarray(stamps, dtype=np.float64).reshape(-1)
    ref = np.asarray(reference, dtype=np.float64).reshape(-1)
    if ref.size == 0:
        raise BayesmapError("no reference stamp to pair with")
    right = np.clip(np.searchsorted(ref, t), 1, max(len(ref) - 1, 1)) if len(ref) > 1 else np.zeros(len(t), int)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(ref[left] - t) <= np.abs(ref[right] - t), left, right).astype(np.int64)
    off = np.flatnonzero(~(np.abs(ref[nearest] - t) <= tolerance))
    if len(off):
        i = int(off[0])
        raise BayesmapError(f"stamp {t[i]!r} (pose {i}) has no match within {tolerance:g} s (the nearest is "
                            f"{ref[nearest[i]]!r})")
    twice = np.flatnonzero(np.diff(np.sort(nearest)) == 0)
    if len(twice):
        value = ref[np.sort(nearest)[twice[0]]]
        raise BayesmapError(f"two stamps pair with the same stamp {value!r}")
    return nearest


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


def encode_tum(stamps, poses) -> str:
    """A planar trajectory as the text of a TUM file (what :func:`write_tum` writes; for a caller that writes the
    file itself, such as an output folder replaced as a whole).

    Each line is ``t x y 0 0 0 sin(theta/2) cos(theta/2)``: positions with 6 decimals (meters), the yaw-only
    quaternion with 9; stamps that are whole numbers (scan indices) are written as integers, others in their
    shortest exact decimal form. :func:`read_tum` reads the text back to the same stamps, to within 5e-7 m and
    about 1e-8 rad (theta comes back wrapped to ``[-pi, pi]``).

    Args:
        stamps: ``(S,)`` time stamps, strictly increasing (seconds or scan indices, see :func:`tum_stamps`).
        poses: ``(S, 3)`` rows ``(x, y, theta)``: meters, meters, radians.

    Returns:
        The file's text, ``S`` lines each ending in a newline.

    Raises:
        BayesmapError: if the shapes do not match, a value is not finite, the stamps do not increase strictly, or
            there is no pose.
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
    return "".join(f"{_format_stamp(float(s))} {x:.6f} {y:.6f} 0 0 0 {math.sin(th / 2):.9f} {math.cos(th / 2):.9f}\n"
                   for s, (x, y, th) in zip(t, p))


def write_tum(path, stamps, poses, overwrite: bool = False):
    """Write a planar trajectory as a TUM file (:func:`encode_tum`'s text), whole or not at all
    (:func:`bayesmap.io.files.write_atomic`).

    Args:
        path: the file to write.
        stamps: ``(S,)`` time stamps, strictly increasing (seconds or scan indices, see :func:`tum_stamps`).
        poses: ``(S, 3)`` rows ``(x, y, theta)``: meters, meters, radians.
        overwrite: replace an existing file (else refuse it).

    Returns:
        The path written (a :class:`pathlib.Path`).

    Raises:
        BayesmapError: as :func:`encode_tum`, or if the file exists and ``overwrite`` is False, or it cannot be
            written.
    """
    return write_atomic(path, encode_tum(stamps, poses), overwrite=overwrite)
