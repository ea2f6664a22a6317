"""Read 2-D laser scans with poses from CARMEN log files.

A CARMEN log is a text file, optionally gzip-compressed (detected by the gzip magic bytes
``1f 8b``, never by the file name), with one message per line and fields separated by
whitespace. Only front-laser messages are read::

    FLASER n r_1 ... r_n x y theta odom_x odom_y odom_theta timestamp [host [logger_timestamp]]

``n`` ranges in meters, taken at the pose ``(x, y, theta)`` in meters and radians (world frame).
``timestamp`` (the IPC timestamp, seconds) is the field after ``odom_theta``; the trailing
``host`` and ``logger_timestamp`` fields may be absent and are not used. Every other line
(``ODOM``, ``PARAM``, ``NEFF``, ``RLASER``, ``ROBOTLASER1``, ``#`` comments, blank lines, ...)
is ignored.

Beam-angle rule
---------------
The ``n`` beams span the field of view ``fov`` (radians, ``math.pi`` for the SICK scanners in
these logs) counter-clockwise, starting at ``-fov/2`` relative to the robot heading:

* ``n`` odd (181, 361, ...): the beams include both ends, spacing ``fov / (n - 1)``;
  beam ``k`` is at ``-fov/2 + k * fov / (n - 1)``, the middle beam points straight ahead.
* ``n`` even (180, 360, ...): spacing ``fov / n``, beam ``k`` at ``-fov/2 + k * fov / n``;
  the first beam is at ``-fov/2`` and the last one at ``fov/2 - fov/n``.
* ``n == 1``: the single beam points straight ahead.

The absolute (world-frame) angle of beam ``k`` is ``theta + offset_k`` (not wrapped to any
interval). This rule was checked on the real Intel, ACES (180 beams) and CSAIL (361 beams)
logs: projecting the endpoints of 1500 pairs of scans taken 0.5-3 m apart into the world frame,
the mean (5 cm truncated) nearest-neighbour distance between the two point clouds is smallest
for exactly this rule among a grid over the fan's centre direction (0.1 degree steps) and
beam spacing (fov/n, fov/(n-1) and +-1 %). Alternatives such as spacing ``fov/(n-1)`` for
``n = 180`` or a half-beam centred fan fit measurably worse; a clockwise fan fits far worse.

Maximum range
-------------
A range at or above the sensor's maximum range means "no return" (the beam hit nothing).
With ``read_carmen(..., max_range=m)`` (the CLI's ``--max-range``) every range ``>= m`` is
flagged in ``CarmenLog.is_max_range``. With ``max_range=None`` (the default) it is inferred
from the readings by a rule that one corrupt value cannot move. A saturating sensor repeats
its maximum on many beams: let ``need = max(2, 0.1 % of all beams)``.

1. If the largest range ``v`` of the log is read by ``>= need`` beams, ``max_range = v``.
2. Else (a few readings above the real maximum, as a corrupt value makes), take ``v``, the
   largest range read by ``>= need`` beams, and ``a``, the number of beams reading more than
   ``v``. ``v`` is the max range if it stands for saturation rather than a common reading:
   ``v > 0``, more than half of all beams read less than ``v``, and ``v`` is read by more than
   ``2 a`` beams (it outnumbers the values above it twice over). The ``a`` readings above it
   are then flagged as no return like any reading at or above the max range, and never set
   the map's extent.
3. Otherwise the log is taken to hold no max-range readings: ``max_range = math.inf`` and no
   beam is flagged.
(Intel: 81.83 m; ACES: 50.0 m, on 0.78 % of its beams, which is why the threshold is 0.1 %
rather than 1 %; CSAIL: 81.91 m.) ``PARAM`` lines are not used: CSAIL's log says
``PARAM robot_front_laser_max 50`` while its FLASER "no return" readings are 81.91 m (none
lies between 50 and 81.91 m): a PARAM line describes a configuration, the readings what the
laser wrote, and the two can disagree. Pass ``max_range`` (``--max-range``) to override.

Plausibility
------------
A range that is not a finite number, is negative, or exceeds :data:`MAX_PLAUSIBLE_RANGE`
(1000 m, beyond any 2-D laser scanner's reach) is refused, as is a pose coordinate beyond
:data:`MAX_PLAUSIBLE_COORDINATE` (10,000 km) or a heading beyond :data:`MAX_PLAUSIBLE_HEADING`
radians; the message names the file, the line and the value. A log whose every range is 0 has
nothing to map and is refused too.

Errors
------
Every problem with the input raises :class:`bayesmap.errors.BayesmapError` (a ``ValueError``)
with a one-line message naming the file and, for a bad line, its 1-based line number.
"""

from __future__ import annotations

import gzip
import math
import os
import zlib
from dataclasses import dataclass, field
from typing import Union

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.io.files import read_bytes

__all__ = ["Scan", "CarmenLog", "read_carmen", "beam_offsets", "infer_max_range", "MAX_PLAUSIBLE_RANGE"]

PathLike = Union[str, "os.PathLike[str]"]

_GZIP_MAGIC = b"\x1f\x8b"
# Fields after the n ranges that we need: x y theta odom_x odom_y odom_theta timestamp.
_N_NUMERIC_TAIL = 7
# Optional trailing fields: host, logger_timestamp.
_N_OPTIONAL_TAIL = 2
# Inferred max range: the largest value must occur on at least this fraction of all beams.
_MAX_RANGE_MIN_FRACTION = 0.001

MAX_PLAUSIBLE_RANGE = 1000.0
"""Meters: a range above this is refused as corrupt (2-D laser scanners reach 4-300 m; Intel's saturates at 81.83)."""
MAX_PLAUSIBLE_COORDINATE = 1e7
"""Meters: a pose ``x`` or ``y`` beyond this (10,000 km, a quarter of the Earth's circumference) is refused."""
MAX_PLAUSIBLE_HEADING = 1e6
"""Radians: a heading beyond this is refused (its beam angles would have lost their precision)."""


def beam_offsets(n: int, fov: float = math.pi) -> np.ndarray:
    """Beam angles relative to the robot heading for a scan of ``n`` beams over ``fov``.

    Args:
        n: number of beams, ``n >= 1``.
        fov: field of view in radians, ``0 < fov <= 2*pi``.

    Returns:
        ``(n,)`` float64 array of angles in radians, increasing (counter-clockwise):
        ``-fov/2 + k * fov/(n-1)`` for odd ``n`` (both ends included),
        ``-fov/2 + k * fov/n`` for even ``n``, ``[0.0]`` for ``n == 1``.

    Raises:
        BayesmapError: ``n`` is not a positive integer or ``fov`` is not in ``(0, 2*pi]``.
    """
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
        raise BayesmapError(f"number of beams must be a positive integer, got {n!r}")
    _check_fov(fov)
    n = int(n)
    if n == 1:
        return np.zeros(1)
    step = fov / (n - 1) if n % 2 == 1 else fov / n
    return -fov / 2 + np.arange(n) * step


def _check_fov(fov: float) -> None:
    if isinstance(fov, (bool, np.bool_)) or not isinstance(fov, (int, float, np.integer, np.floating)):
        raise BayesmapError(f"fov must be a number of radians, got {fov!r}")
    if not (math.isfinite(fov) and 0 < fov <= 2 * math.pi + 1e-12):
        raise BayesmapError(f"fov must be in (0, 2*pi] radians, got {fov!r}")


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Scan:
    """One FLASER message.

    Attributes:
        ranges: ``(K,)`` float64, meters. Values ``>= CarmenLog.max_range`` mean "no return".
        pose: ``(3,)`` float64, ``[x (m), y (m), theta (rad)]`` of the robot in the world frame.
        angles: ``(K,)`` float64, absolute world-frame beam angles in radians
            (``theta + beam_offsets(K, fov)``, not wrapped).
        timestamp: the message's IPC timestamp in seconds.

    The arrays are read-only.
    """

    ranges: np.ndarray
    pose: np.ndarray
    angles: np.ndarray
    timestamp: float


@dataclass(frozen=True, eq=False)
class CarmenLog:
    """All FLASER scans of a CARMEN log, in file order. S scans of K beams each.

    Attributes:
        path: the file the log was read from.
        ranges: ``(S, K)`` float64, meters, finite and ``>= 0``.
        poses: ``(S, 3)`` float64, ``[x (m), y (m), theta (rad)]`` per scan, finite.
        angles: ``(S, K)`` float64, absolute world-frame beam angles in radians
            (``poses[:, 2:3] + beam_offsets(K, fov)``, not wrapped).
        timestamps: ``(S,)`` float64, seconds (IPC timestamps as written in the log; they may be
            printed with few significant digits, e.g. the CSAIL log's ``1.13486e+09``).
        max_range: meters; ``math.inf`` when the log has no max-range readings.
        is_max_range: ``(S, K)`` bool, ``ranges >= max_range`` (beams with no return).

    The arrays are read-only copies. Constructing a ``CarmenLog`` directly checks that the
    shapes agree and raises :class:`BayesmapError` otherwise.
    """

    path: str
    ranges: np.ndarray
    poses: np.ndarray
    angles: np.ndarray
    timestamps: np.ndarray
    max_range: float
    is_max_range: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        ranges = np.array(self.ranges, dtype=np.float64)
        poses = np.array(self.poses, dtype=np.float64)
        angles = np.array(self.angles, dtype=np.float64)
        timestamps = np.array(self.timestamps, dtype=np.float64)
        is_max = np.array(self.is_max_range, dtype=bool)
        if ranges.ndim != 2:
            raise BayesmapError(f"CarmenLog ranges must have shape (S, K), got {ranges.shape}")
        s, k = ranges.shape
        for name, arr, shape in (
            ("poses", poses, (s, 3)),
            ("angles", angles, (s, k)),
            ("timestamps", timestamps, (s,)),
            ("is_max_range", is_max, (s, k)),
        ):
            if arr.shape != shape:
                raise BayesmapError(f"CarmenLog {name} must have shape {shape}, got {arr.shape}")
        object.__setattr__(self, "path", str(self.path))
        object.__setattr__(self, "ranges", _readonly(ranges))
        object.__setattr__(self, "poses", _readonly(poses))
        object.__setattr__(self, "angles", _readonly(angles))
        object.__setattr__(self, "timestamps", _readonly(timestamps))
        object.__setattr__(self, "max_range", float(self.max_range))
        object.__setattr__(self, "is_max_range", _readonly(is_max))

    def __len__(self) -> int:
        """Number of scans S."""
        return self.ranges.shape[0]

    def __repr__(self) -> str:
        s, k = self.ranges.shape
        return (
            f"CarmenLog(path={self.path!r}, scans={s}, beams={k}, max_range={self.max_range}, "
            f"max_range_beams={int(self.is_max_range.sum())})"
        )

    def with_poses(self, poses) -> "CarmenLog":
        """The same scans at other poses ``(S, 3)`` (x m, y m, theta rad): each beam keeps its angle relative to the
        heading, so its world angle turns with the pose.

        Raises:
            BayesmapError: if ``poses`` is not ``(S, 3)`` finite.
        """
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != self.poses.shape or not np.all(np.isfinite(poses)):
            raise BayesmapError(f"poses must be {self.poses.shape} finite (x m, y m, theta rad), got shape "
                                f"{poses.shape}")
        angles = self.angles - self.poses[:, 2:3] + poses[:, 2:3]
        return CarmenLog(path=self.path, ranges=self.ranges, poses=poses, angles=angles, timestamps=self.timestamps,
                         max_range=self.max_range, is_max_range=self.is_max_range)

    def check_index(self, index: int) -> int:
        """``index`` as an int, checked: ``0 <= index < len(self)``.

        Raises:
            BayesmapError: ``index`` is not an integer, is negative, or is ``>= len(self)``; the message names the
                index and the number of scans.
        """
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)):
            raise BayesmapError(f"scan index must be an integer, got {index!r}")
        n = len(self)
        if not 0 <= index < n:
            raise BayesmapError(
                f"scan index {int(index)} is out of range for {self.path!r}, which has {n} scans "
                f"(valid indexes 0..{n - 1}; negative indexes are not allowed)"
            )
        return int(index)

    def scan(self, index: int) -> Scan:
        """The scan at ``index`` (``0 <= index < len(self)``) as a :class:`Scan` (views, read-only).

        Raises:
            BayesmapError: ``index`` is not an integer, is negative, or is ``>= len(self)``;
                the message names the index and the number of scans.
        """
        i = self.check_index(index)
        return Scan(
            ranges=self.ranges[i],
            pose=self.poses[i],
            angles=self.angles[i],
            timestamp=float(self.timestamps[i]),
        )

    def endpoints(self, index: int) -> np.ndarray:
        """World-frame endpoints of all K beams of scan ``index``.

        Returns:
            ``(K, 2)`` float64 array of ``[x, y]`` in meters:
            ``pose[:2] + ranges[:, None] * [cos(angle), sin(angle)]``. Max-range beams are
            included (at their reported range); use ``is_max_range[index]`` to drop them.

        Raises:
            BayesmapError: as :meth:`scan`.
        """
        i = self.check_index(index)
        r = self.ranges[i]
        a = self.angles[i]
        x, y = self.poses[i, 0], self.poses[i, 1]
        return np.stack([x + r * np.cos(a), y + r * np.sin(a)], axis=1)


def _decode(name: str, raw: bytes) -> str:
    if raw[:2] == _GZIP_MAGIC:
        try:
            raw = gzip.decompress(raw)
        except EOFError:
            raise BayesmapError(
                f"CARMEN log {name!r} is a truncated gzip stream (it ends before the end-of-stream marker)"
            ) from None
        except (OSError, zlib.error) as exc:
            raise BayesmapError(f"CARMEN log {name!r} is not valid gzip data: {exc}") from None
    if b"\x00" in raw:
        raise BayesmapError(f"CARMEN log {name!r} is binary data, not a text log (it contains NUL bytes)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BayesmapError(
            f"CARMEN log {name!r} is binary data, not a text log (byte {exc.start} is not UTF-8)"
        ) from None


def _line_error(name: str, lineno: int, what: str) -> BayesmapError:
    return BayesmapError(f"{name}:{lineno}: {what}")


def _parse_flaser(name: str, lineno: int, toks: list[str]) -> tuple[int, np.ndarray]:
    """Parse a tokenised FLASER line; returns (n, float64 array of n ranges + 7 numeric fields)."""
    if len(toks) < 2:
        raise _line_error(name, lineno, "FLASER line has no beam count")
    try:
        n = int(toks[1])
    except ValueError:
        raise _line_error(name, lineno, f"FLASER beam count {toks[1]!r} is not an integer") from None
    if n < 1:
        raise _line_error(name, lineno, f"FLASER beam count {n} must be at least 1")
    need = 2 + n + _N_NUMERIC_TAIL
    if len(toks) < need:
        raise _line_error(
            name,
            lineno,
            f"FLASER line with {n} beams has too few fields: {len(toks)}, needs at least {need} "
            "(FLASER n, n ranges, x y theta, odom_x odom_y odom_theta, timestamp)",
        )
    if len(toks) > need + _N_OPTIONAL_TAIL:
        raise _line_error(
            name,
            lineno,
            f"FLASER line with {n} beams has too many fields: {len(toks)}, at most {need + _N_OPTIONAL_TAIL} "
            "(is the beam count right?)",
        )
    try:
        vals = np.array(toks[2:need], dtype=np.float64)
    except ValueError:
        for j, tok in enumerate(toks[2:need], start=2):
            try:
                float(tok)
            except ValueError:
                raise _line_error(
                    name, lineno, f"FLASER field {j + 1} {tok!r} ({_field_name(j - 2, n)}) is not a number"
                ) from None
        raise  # pragma: no cover - np.array failed but every token parses
    return n, vals


def _field_name(j: int, n: int) -> str:
    if j < n:
        return f"range {j + 1} of {n}"
    return ("x", "y", "theta", "odom_x", "odom_y", "odom_theta", "timestamp")[j - n]


def _check_plausible(name: str, linenos: list[int], table: np.ndarray, k: int) -> None:
    """Refuse the first implausible value of ``table`` (rows: k ranges then the 7 numeric fields), naming
    ``name:line`` and the value; see the module docstring's "Plausibility"."""
    ranges = table[:, :k]
    tail = table[:, k : k + 7]
    checks = (
        (~np.isfinite(ranges), 0, "not a finite number"),
        (ranges < 0, 0, "which is negative"),
        (ranges > MAX_PLAUSIBLE_RANGE, 0,
         f"beyond any laser's reach ({MAX_PLAUSIBLE_RANGE:g} m): a corrupt reading (fix or drop the line)"),
        (~np.isfinite(tail), k, "not a finite number"),
        (np.abs(tail[:, :2]) > MAX_PLAUSIBLE_COORDINATE, k,
         f"beyond {MAX_PLAUSIBLE_COORDINATE:g} m from the origin: a corrupt pose"),
        (np.abs(tail[:, 2:3]) > MAX_PLAUSIBLE_HEADING, k + 2,
         f"beyond {MAX_PLAUSIBLE_HEADING:g} radians: a corrupt heading"),
    )
    for bad, first, what in checks:
        if bad.any():
            s, j = np.argwhere(bad)[0]
            raise _line_error(name, linenos[s], f"{_field_name(first + j, k)} is {table[s, first + j]!r}, {what}")
    if not ranges.any():
        raise BayesmapError(f"CARMEN log {name!r}: all {ranges.size} ranges are 0 m (no reading): nothing to map")


def infer_max_range(ranges) -> float:
    """The laser's max range inferred from its readings (meters, or ``math.inf`` for none).

    The rule of the module docstring ("Maximum range"): the largest range if ``need = max(2, 0.1 %)`` beams read
    it; else the largest range ``v`` read by ``need`` beams if more than half of the beams read less and more than
    twice as many beams read ``v`` as read more; else ``math.inf``.

    Args:
        ranges: any shape, float, meters (finite, ``>= 0``).
    """
    ranges = np.asarray(ranges, dtype=np.float64).reshape(-1)
    if ranges.size == 0:
        return math.inf
    values, counts = np.unique(ranges, return_counts=True)  # ascending
    need = max(2, math.ceil(_MAX_RANGE_MIN_FRACTION * ranges.size))
    frequent = np.nonzero((counts >= need) & (values > 0))[0]
    if len(frequent) == 0:
        return math.inf
    top = frequent[-1]
    above = int(counts[top + 1 :].sum())
    below = int(counts[:top].sum())
    if above == 0 or (2 * below > ranges.size and counts[top] > 2 * above):
        return float(values[top])
    return math.inf


def read_carmen(path: PathLike, max_range: float | None = None, fov: float = math.pi) -> CarmenLog:
    """Read all FLASER scans of a CARMEN log (plain text or gzip, detected by magic bytes).

    Args:
        path: file to read (``str`` or path-like).
        max_range: sensor maximum range in meters (finite, ``> 0``); ranges ``>=`` it are flagged
            as no-return in ``is_max_range``. ``None`` infers it with :func:`infer_max_range`
            (module docstring, "Maximum range"): the largest range if ``>= max(2, 0.1 %)`` of all
            beams read it, else the saturation value below a few corrupt readings, else
            ``math.inf`` (no max-range readings).
        fov: the laser's field of view in radians, ``0 < fov <= 2*pi`` (default ``pi``).
            See the module docstring for how beam angles follow from it.

    Returns:
        A :class:`CarmenLog` with S scans of K beams, in file order.

    Raises:
        BayesmapError: with a one-line message naming the file (and ``file:line`` for a bad line)
            when the file does not exist, is a directory or cannot be read; is binary junk or
            invalid / truncated gzip; has a FLASER line with a bad beam count, too few or too many
            fields, or a non-numeric field; mixes scans of different beam counts; has a range that is
            non-finite, negative or above :data:`MAX_PLAUSIBLE_RANGE`, a non-finite or implausible
            pose, a non-finite timestamp, or only ranges of 0; has no FLASER line at all;
            or when ``max_range`` or ``fov`` is not a valid positive number.
    """
    _check_fov(fov)
    if max_range is not None:
        if isinstance(max_range, (bool, np.bool_)) or not isinstance(
            max_range, (int, float, np.integer, np.floating)
        ):
            raise BayesmapError(f"max_range must be a number of meters or None, got {max_range!r}")
        if not (math.isfinite(max_range) and max_range > 0):
            raise BayesmapError(f"max_range must be a finite positive number of meters, got {max_range!r}")
    name, raw = read_bytes(path, "CARMEN log")
    text = _decode(name, raw)

    rows: list[np.ndarray] = []
    linenos: list[int] = []
    k_first = None
    for lineno, line in enumerate(text.split("\n"), start=1):
        if "FLASER" not in line:
            continue
        toks = line.split()
        if not toks or toks[0] != "FLASER":
            continue
        n, vals = _parse_flaser(name, lineno, toks)
        if k_first is None:
            k_first = (n, lineno)
        elif n != k_first[0]:
            raise _line_error(
                name,
                lineno,
                f"FLASER scan has {n} beams but the scan on line {k_first[1]} has {k_first[0]}; "
                "all scans of a log must have the same number of beams",
            )
        rows.append(vals)
        linenos.append(lineno)

    if not rows:
        raise BayesmapError(f"CARMEN log {name!r} contains no FLASER lines (no laser scans)")

    k = k_first[0]
    table = np.stack(rows)
    ranges = table[:, :k]
    poses = table[:, k : k + 3]
    timestamps = table[:, k + 6]

    _check_plausible(name, linenos, table, k)
    if max_range is None:
        max_range = infer_max_range(ranges)
    max_range = float(max_range)

    angles = poses[:, 2:3] + beam_offsets(k, fov)[None, :]
    return CarmenLog(
        path=name,
        ranges=ranges,
        poses=poses,
        angles=angles,
        timestamps=timestamps,
        max_range=max_range,
        is_max_range=ranges >= max_range,
    )
