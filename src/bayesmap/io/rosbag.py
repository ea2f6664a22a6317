"""Read 2-D laser scans with poses from ROS bags, and write logs and maps as ROS bags (the ``rosbags`` library).

A bag is read into the same :class:`bayesmap.io.carmen.CarmenLog` a CARMEN log gives, so every command and function
that takes a log takes a bag (``bayesmap infer --bag``; ``bayesmap slam`` reads it the same way). ROS 1 bags are one
``.bag`` file; ROS 2 bags are a folder (``metadata.yaml`` and a sqlite3 ``.db3`` or an ``.mcap`` file). No ROS
install is needed: ``rosbags`` (pure Python) reads and writes both, with its own message definitions
(ROS 1 Noetic, ROS 2 Humble) for bags that carry none.

Scans
-----
Every ``sensor_msgs/LaserScan`` message on the scan topic is one scan, in the order of its ``header.stamp``. Beam
``k`` is at ``angle_min + k * angle_increment`` radians in the laser's frame (the float32 fields widened to float64
first); every scan must have the first scan's number of beams, ``angle_min`` and ``angle_increment``.

Readings with no return
-----------------------
A reading that is NaN or infinite, below ``range_min``, or at or above ``range_max`` means "no return", as a CARMEN
reading at or above the log's max range does (:mod:`bayesmap.io.carmen`, "Maximum range"): the log's ``max_range``
is ``range_max`` (the largest over the scans; ``max_range=`` / ``--max-range`` overrides it) and every such reading
is set to exactly ``max_range`` and flagged in ``CarmenLog.is_max_range``. The model then scores it by the beam
mixture's point mass at the max range ("no wall within max range along this beam"); it never sets the map's extent.
float32 ranges are widened to float64 by their shortest decimal representation (``1.23f`` reads 1.23, not
1.2300000190734863), so a bag written from a CARMEN log reads back the log's ranges exactly.

Poses
-----
The pose of a scan is the pose of the LASER (``CarmenLog.poses``: x, y in meters, heading in radians, in the frame
of the odometry or of the tf tree's root), at the scan's ``header.stamp``:

* ``odom_topic`` (``--odom-topic``, default ``/odom``): ``nav_msgs/Odometry``, the pose of ``child_frame_id``
  (the robot's base) in ``header.frame_id``.
* ``tf=True`` (``--tf``): ``tf2_msgs/TFMessage`` on ``/tf``, the transform whose child is the robot's base (the
  frame ``/tf_static`` mounts the laser on, e.g. ``odom -> base_link``).

The base pose is interpolated linearly between the two poses around the scan's stamp (the heading along the shorter
arc; a pose at exactly the stamp is used as it is). A scan whose nearest pose is more than ``pose_tolerance``
seconds (default 0.1 s) away is refused. The laser's mounting offset (``base_link -> laser``, walking up from the
scan's ``header.frame_id``) comes from ``/tf_static`` and is composed in: laser pose = base pose o offset. A bag
without ``/tf_static`` is taken to have its laser at the base. Only the 2-D part of a transform is used (x, y, yaw).

Errors
------
Every problem raises :class:`bayesmap.errors.BayesmapError` with one line naming the bag and the topic or field: a
missing or truncated file, a missing topic, a topic of the wrong message type, scans that disagree in their beams, a
scan with no pose within the tolerance, a laser frame ``/tf_static`` does not connect to the base.

Writing
-------
:func:`write_log_bag` writes a log as a bag (what ``bayesmap convert`` does): ``sensor_msgs/LaserScan`` on
``/scan`` (frame ``laser``), ``nav_msgs/Odometry`` on ``/odom`` and ``tf2_msgs/TFMessage`` on ``/tf`` (``odom ->
base_link``) at every scan's stamp, and ``/tf_static`` (``base_link -> laser``, the ``laser_offset``).
:func:`write_occupancy_grid_bag` writes one ``nav_msgs/OccupancyGrid`` (``bayesmap infer --out-bag``).
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.carmen import CarmenLog
from bayesmap.io.files import check_own_folder, check_regular, make_staging, read_bytes

__all__ = ["read_bag", "write_log_bag", "write_occupancy_grid_bag", "read_occupancy_grid_bag", "compose_poses",
           "invert_pose", "occupancy_grid_data", "check_bag_path", "DEFAULT_POSE_TOLERANCE", "STORAGES"]

DEFAULT_POSE_TOLERANCE = 0.1
"""Seconds: a scan whose nearest pose (odometry or tf) is farther away in time than this is refused."""
STORAGES = ("sqlite3", "mcap")
"""ROS 2 storage formats :func:`write_log_bag` writes (both read by :func:`read_bag`)."""

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
_NS = 1_000_000_000


def _typestore(ros2: bool):
    """rosbags' message definitions: ROS 2 Humble, or ROS 1 Noetic plus ``tf2_msgs/TFMessage`` (not in its store)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    if TF_MESSAGE not in store.types:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_MESSAGE))
    return store


def _widen(values) -> np.ndarray:
    """float32 values as float64 by their shortest decimal representation (float64 values unchanged)."""
    a = np.asarray(values)
    if a.dtype == np.float32:
        return a.astype(str).astype(np.float64)
    return a.astype(np.float64)


def compose_poses(a, b) -> np.ndarray:
    """2-D pose composition ``a o b``: the pose ``b`` (given in the frame of ``a``) in ``a``'s parent frame.

    Args:
        a: ``(..., 3)`` float64 ``[x (m), y (m), theta (rad)]``.
        b: ``(..., 3)`` float64, the same (broadcast with ``a``).

    Returns:
        ``(..., 3)`` float64: ``[x_a + cos(t_a) x_b - sin(t_a) y_b, y_a + sin(t_a) x_b + cos(t_a) y_b, t_a + t_b]``
        (*Probabilistic Robotics* sec. 5.4's compounding).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     a[..., 2] + b[..., 2]], axis=-1)


def invert_pose(p) -> np.ndarray:
    """The inverse of a 2-D pose: ``compose_poses(p, invert_pose(p))`` is the identity.

    Args:
        p: ``(..., 3)`` float64 ``[x (m), y (m), theta (rad)]``.

    Returns:
        ``(..., 3)`` float64 ``[-cos(t) x - sin(t) y, sin(t) x - cos(t) y, -t]``.
    """
    p = np.asarray(p, dtype=np.float64)
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    return np.stack([-c * p[..., 0] - s * p[..., 1], s * p[..., 0] - c * p[..., 1], -p[..., 2]], axis=-1)


def _yaw(q) -> float:
    """Heading (rad) of a ``geometry_msgs/Quaternion`` (rotation about z; roll and pitch ignored)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec)


class _Scans(NamedTuple):
    stamps: np.ndarray  # (S,) int64 ns
    ranges: np.ndarray  # (S, K) float64, no-return readings already set to max_range
    no_return: np.ndarray  # (S, K) bool
    offsets: np.ndarray  # (K,) float64 beam angles in the laser frame
    frame: str
    max_range: float


class _Track(NamedTuple):
    stamps: np.ndarray  # (N,) int64 ns, increasing
    poses: np.ndarray  # (N, 3)
    base: str  # the frame whose poses these are (child_frame_id)


def _open(path: Path, name: str):
    """An open ``AnyReader`` on the bag (ROS 1 ``.bag`` file, or ROS 2 folder)."""
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise BayesmapError(f"ROS bag {name!r} does not exist")
    check_regular(path, "ROS bag", folder=True)  # a device would be read without end, a FIFO would block
    if path.is_file() and path.suffix != ".bag":
        raise BayesmapError(f"ROS bag {name!r}: a ROS 1 bag is a '.bag' file, a ROS 2 bag a folder "
                            "(metadata.yaml and its .db3 or .mcap files)")
    reader = AnyReader([path], default_typestore=_typestore(True))
    reader.open()
    return reader


def _connections(reader, name: str, topic: str, msgtype: str, required: bool = True):
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        if not required:
            return []
        topics = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
        raise BayesmapError(f"ROS bag {name!r} has no topic {topic!r} (its topics: {topics})")
    wrong = [c.msgtype for c in conns if c.msgtype != msgtype]
    if wrong:
        raise BayesmapError(f"topic {topic!r} of ROS bag {name!r} holds {wrong[0]} messages, not {msgtype}")
    return conns


def _messages(reader, conns):
    if not conns:  # (no connections would mean "all messages" to rosbags)
        return
    for conn, _, raw in reader.messages(connections=conns):
        yield reader.deserialize(raw, conn.msgtype)


def _read_scans(reader, name: str, topic: str, max_range: float | None) -> _Scans:
    """The LaserScans of ``topic``, checked, in stamp order (see the module docstring)."""
    stamps, rows, lows, highs = [], [], [], []
    first = None
    for msg in _messages(reader, _connections(reader, name, topic, LASER_SCAN)):
        fields = (len(msg.ranges), float(msg.angle_min), float(msg.angle_increment))
        if first is None:
            first, frame = fields, msg.header.frame_id
        for field_name, value, expected in zip(("ranges (number of beams)", "angle_min", "angle_increment"),
                                               fields, first):
            if value != expected:
                raise BayesmapError(f"{topic!r} of ROS bag {name!r}: scan {len(rows)} has {field_name} {value!r}, "
                                    f"the first scan {expected!r} (every scan must have the same beams)")
        stamps.append(_stamp_ns(msg.header))
        rows.append(np.asarray(msg.ranges))
        lows.append(_widen(np.float32(msg.range_min)))
        highs.append(_widen(np.float32(msg.range_max)))
    if not rows:
        raise BayesmapError(f"topic {topic!r} of ROS bag {name!r} has no messages")
    if first[0] == 0:
        raise BayesmapError(f"{topic!r} of ROS bag {name!r}: field ranges is empty (scans with no beam)")
    highs = np.asarray(highs, dtype=np.float64)
    if max_range is None:
        if not np.all(np.isfinite(highs) & (highs > 0)):
            raise BayesmapError(f"{topic!r} of ROS bag {name!r}: field range_max is {highs[~np.isfinite(highs)][0]!r} "
                                "or not positive; pass --max-range")
        max_range = float(highs.max())
    else:
        highs = np.full(len(rows), float(max_range))
    ranges = _widen(np.stack(rows).astype(np.float32))
    with np.errstate(invalid="ignore"):
        no_return = ~np.isfinite(ranges) | (ranges < np.asarray(lows)[:, None]) | (ranges >= highs[:, None])
    ranges = np.where(no_return, max_range, ranges)
    order = np.argsort(np.asarray(stamps, dtype=np.int64), kind="stable")
    k, angle_min, step = first
    angle_min, step = float(_widen(np.float32(angle_min))), float(_widen(np.float32(step)))
    offsets = angle_min + np.arange(k) * step
    return _Scans(np.asarray(stamps, dtype=np.int64)[order], ranges[order], no_return[order], offsets, frame,
                  max_range)


def _pose_of(translation, rotation) -> list[float]:
    return [float(translation.x), float(translation.y), _yaw(rotation)]


def _track(stamps, poses, base: str) -> _Track:
    stamps = np.asarray(stamps, dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    stamps, poses = stamps[order], np.asarray(poses, dtype=np.float64).reshape(-1, 3)[order]
    keep = np.append(stamps[1:] != stamps[:-1], True)  # of equal stamps, the last one
    return _Track(stamps[keep], poses[keep], base)


def _odometry_track(reader, name: str, topic: str) -> _Track:
    stamps, poses, bases = [], [], set()
    for msg in _messages(reader, _connections(reader, name, topic, ODOMETRY)):
        stamps.append(_stamp_ns(msg.header))
        poses.append(_pose_of(msg.pose.pose.position, msg.pose.pose.orientation))
        bases.add(msg.child_frame_id)
    if not poses:
        raise BayesmapError(f"topic {topic!r} of ROS bag {name!r} has no messages")
    if len(bases) > 1:
        raise BayesmapError(f"topic {topic!r} of ROS bag {name!r}: field child_frame_id takes several values "
                            f"{sorted(bases)}; one robot base is expected")
    return _track(stamps, poses, bases.pop())


def _static_transforms(reader, name: str) -> dict[str, tuple[str, np.ndarray]]:
    """``{child: (parent, pose of child in parent)}`` from ``/tf_static`` (empty without it)."""
    found = {}
    for msg in _messages(reader, _connections(reader, name, "/tf_static", TF_MESSAGE, required=False)):
        for t in msg.transforms:
            found[t.child_frame_id] = (t.header.frame_id,
                                       np.array(_pose_of(t.transform.translation, t.transform.rotation)))
    return found


def _mounting(static: dict, laser: str, is_base, name: str, base_hint: str | None) -> tuple[str, np.ndarray]:
    """The base frame (the first frame up from ``laser`` for which ``is_base``) and the laser's pose in it."""
    offset, frame, seen = np.zeros(3), laser, set()
    while not is_base(frame):
        if frame not in static or frame in seen:
            target = f" to {base_hint!r}" if base_hint else ""
            raise BayesmapError(f"ROS bag {name!r}: /tf_static has no transform chain from the scan's frame "
                                f"{laser!r} (header.frame_id){target}")
        seen.add(frame)
        parent, pose = static[frame]
        offset = compose_poses(pose, offset)
        frame = parent
    return frame, offset


def _tf_tracks(reader, name: str) -> dict[str, _Track]:
    """The dynamic transforms of ``/tf``, one track per child frame."""
    per_child: dict[str, tuple[list, list, str]] = {}
    for msg in _messages(reader, _connections(reader, name, "/tf", TF_MESSAGE)):
        for t in msg.transforms:
            stamps, poses, _ = per_child.setdefault(t.child_frame_id, ([], [], t.header.frame_id))
            stamps.append(_stamp_ns(t.header))
            poses.append(_pose_of(t.transform.translation, t.transform.rotation))
    return {child: _track(s, p, child) for child, (s, p, _) in per_child.items()}


def _interpolate(track: _Track, stamps: np.ndarray, tolerance: float, name: str, where: str) -> np.ndarray:
    """The track's poses at ``stamps`` (ns): linear in x, y, the heading along the shorter arc; exact at a pose's own
    stamp. Refuses a stamp whose nearest pose is more than ``tolerance`` seconds away."""
    t = track.stamps
    hi = np.clip(np.searchsorted(t, stamps), 0, len(t) - 1)
    lo = np.clip(hi - 1, 0, len(t) - 1)
    gap = np.minimum(np.abs(stamps - t[lo]), np.abs(t[hi] - stamps)) / _NS
    bad = np.nonzero(gap > tolerance)[0]
    if len(bad):
        s = bad[0]
        raise BayesmapError(f"ROS bag {name!r}: scan {s} (stamp {stamps[s] / _NS:.9f} s) has no pose on {where} "
                            f"within {tolerance:g} s (the nearest is {gap[s]:.3f} s away)")
    span = (t[hi] - t[lo]).astype(np.float64)
    w = np.where(span > 0, (stamps - t[lo]).astype(np.float64) / np.where(span > 0, span, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)
    a, b = track.poses[lo], track.poses[hi]
    dtheta = np.mod(b[:, 2] - a[:, 2] + np.pi, 2 * np.pi) - np.pi
    out = a + w[:, None] * np.stack([b[:, 0] - a[:, 0], b[:, 1] - a[:, 1], dtheta], axis=1)
    exact_hi = stamps == t[hi]
    out[exact_hi] = track.poses[hi][exact_hi]
    return out


def read_bag(path, scan_topic: str = "/scan", odom_topic: str | None = "/odom", tf: bool = False,
             pose_tolerance: float = DEFAULT_POSE_TOLERANCE, max_range: float | None = None) -> CarmenLog:
    """Read the laser scans of a ROS 1 or ROS 2 bag, with the laser's poses, as a CARMEN log.

    Args:
        path: a ROS 1 ``.bag`` file or a ROS 2 bag folder.
        scan_topic: topic of the ``sensor_msgs/LaserScan`` messages.
        odom_topic: topic of the ``nav_msgs/Odometry`` poses (unused with ``tf=True``).
        tf: take the robot's poses from ``/tf`` instead of odometry.
        pose_tolerance: seconds; the largest time from a scan to its nearest pose.
        max_range: meters; readings at or above it are "no return" (default: the scans' ``range_max``).

    Returns:
        a :class:`~bayesmap.io.carmen.CarmenLog` of S scans of K beams, in stamp order: ``poses`` ``(S, 3)`` float64,
        the LASER's pose (x m, y m, theta rad); ``angles`` ``(S, K)`` float64 world-frame beam angles;
        ``ranges`` ``(S, K)`` float64 meters with "no return" readings at exactly ``max_range``;
        ``timestamps`` ``(S,)`` float64 seconds (``header.stamp``).

    Raises:
        BayesmapError: one line naming the bag and the topic or field (module docstring, "Errors").
    """
    path = Path(path)
    name = str(path)
    if not (isinstance(pose_tolerance, (int, float)) and math.isfinite(pose_tolerance) and pose_tolerance >= 0):
        raise BayesmapError(f"pose tolerance must be a finite number of seconds >= 0, got {pose_tolerance!r}")
    if not tf and not odom_topic:
        raise BayesmapError("give an odometry topic, or read the poses from tf")
    try:
        reader = _open(path, name)
        try:
            scans = _read_scans(reader, name, scan_topic, max_range)
            static = _static_transforms(reader, name)
            if tf:
                tracks = _tf_tracks(reader, name)
                base, offset = _mounting(static, scans.frame, lambda f: f in tracks, name, None)
                track, where = tracks[base], f"/tf (frame {base!r})"
            else:
                track = _odometry_track(reader, name, odom_topic)
                if static:
                    _, offset = _mounting(static, scans.frame, lambda f: f == track.base, name, track.base)
                else:
                    offset = np.zeros(3)
                where = repr(odom_topic)
        finally:
            reader.close()
    except BayesmapError:
        raise
    except Exception as exc:  # rosbags' readers raise many kinds on a corrupt or truncated file
        raise BayesmapError(f"ROS bag {name!r} cannot be read (truncated or not a bag?): "
                            f"{type(exc).__name__}: {exc}") from None
    base_poses = _interpolate(track, scans.stamps, float(pose_tolerance), name, where)
    poses = compose_poses(base_poses, offset) if np.any(offset) else base_poses
    return CarmenLog(path=name, ranges=scans.ranges, poses=poses, angles=poses[:, 2:3] + scans.offsets,
                     timestamps=scans.stamps / _NS, max_range=scans.max_range, is_max_range=scans.no_return)


# ---------------------------------------------------------------------------------------------------------- writing


def _time(store, ns: int):
    return store.types["builtin_interfaces/msg/Time"](sec=int(ns // _NS), nanosec=int(ns % _NS))


def _header(store, ros2: bool, ns: int, frame: str, seq: int = 0):
    header = store.types["std_msgs/msg/Header"]
    if ros2:
        return header(stamp=_time(store, ns), frame_id=frame)
    return header(seq=seq, stamp=_time(store, ns), frame_id=frame)


def _quaternion(store, theta: float):
    return store.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2))


def _transform(store, ros2: bool, ns: int, parent: str, child: str, pose):
    t = store.types
    return t["geometry_msgs/msg/TransformStamped"](
        header=_header(store, ros2, ns, parent), child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=float(pose[0]), y=float(pose[1]), z=0.0),
            rotation=_quaternion(store, float(pose[2]))))


def _odometry(store, ros2: bool, ns: int, pose, seq: int):
    t = store.types
    return t[ODOMETRY](
        header=_header(store, ros2, ns, "odom", seq), child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                orientation=_quaternion(store, float(pose[2]))),
            covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                               angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36)))


def _scan(store, ros2: bool, ns: int, ranges, offsets, range_max: float, seq: int):
    step = float(offsets[-1] - offsets[0]) / (len(offsets) - 1) if len(offsets) > 1 else 0.0
    return store.types[LASER_SCAN](
        header=_header(store, ros2, ns, "laser", seq), angle_min=float(offsets[0]), angle_max=float(offsets[-1]),
        angle_increment=step, time_increment=0.0, scan_time=0.0, range_min=0.0, range_max=range_max,
        ranges=np.asarray(ranges, dtype=np.float32), intensities=np.zeros(0, dtype=np.float32))


def _stamps(log: CarmenLog) -> np.ndarray:
    """The scans' stamps (ns), made strictly increasing: a stamp not after the previous one (CSAIL's log prints
    ``1.13486e+09`` for many scans) becomes the previous one plus 1 ms."""
    raw = np.rint(np.asarray(log.timestamps, dtype=np.float64) * 1e6).astype(np.int64) * 1000  # microseconds
    out = raw.copy()
    for i in range(1, len(out)):
        out[i] = max(out[i], out[i - 1] + 1_000_000)
    return out


def _latched_qos():
    """ROS 2's QoS of a latched topic (``/tf_static``, ``/map``): reliable, transient local, keep last 1."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)  # 0: the middleware's default (no deadline, lifespan or lease)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, zero, zero,
               QosLiveliness.AUTOMATIC, zero, False)


class _BagWriter:
    """One writer for both ROS versions: ``add(topic, msgtype)`` then ``write(topic, ns, message)``."""

    def __init__(self, path: Path, ros2: bool, storage: str):
        self.ros2, self.store, self.conns = ros2, _typestore(ros2), {}
        if ros2:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=9, storage_plugin=plugin)
        else:
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)

    def __enter__(self):
        self.writer.open()
        return self

    def __exit__(self, *exc):
        self.writer.close()

    def add(self, topic: str, msgtype: str, latching: bool = False) -> None:
        if self.ros2:
            qos = (_latched_qos(),) if latching else ()
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store,
                                                           offered_qos_profiles=qos)
        else:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store,
                                                           latching=int(latching))

    def write(self, topic: str, ns: int, message) -> None:
        conn = self.conns[topic]
        data = (self.store.serialize_cdr(message, conn.msgtype) if self.ros2
                else self.store.serialize_ros1(message, conn.msgtype))
        self.writer.write(conn, int(ns), data)


ROS2_BAG_FILES = (".db3", ".mcap", ".db3-wal", ".db3-shm", ".db3-journal")
"""Name endings of the storage files a ROS 2 bag folder holds beside its ``metadata.yaml`` (sqlite3's database and
its journal files, or MCAP): with ``metadata.yaml``, all that a folder may hold for ``overwrite`` to replace it."""


def check_bag_path(path, ros2: bool, storage: str = "sqlite3", overwrite: bool = False) -> Path:
    """Check, before any work, that a bag can be written at ``path``: a ``.bag`` name for ROS 1; with
    ``overwrite``, an existing ``path`` of the right kind (a file for ROS 1, a folder for ROS 2) and, for a folder,
    an empty one or one that holds a ROS 2 bag (a rosbag2 ``metadata.yaml``) and nothing else
    (:data:`ROS2_BAG_FILES`); a folder to write in.

    Raises:
        BayesmapError: naming ``path``: an unknown ``storage``, a bad name, an existing path without ``overwrite``,
            a file where a folder is needed (or the reverse), a folder that is not only a bag, no folder to write in.
    """
    path = Path(path)
    if storage not in STORAGES:
        raise BayesmapError(f"unknown ROS 2 storage {storage!r}; choose one of {', '.join(STORAGES)}")
    if not ros2 and path.suffix != ".bag":
        raise BayesmapError(f"a ROS 1 bag's name must end in '.bag', got {str(path)!r} (or write a ROS 2 bag)")
    if path.exists() and not overwrite:
        raise BayesmapError(f"{str(path)!r} already exists; pass --force to replace it")
    if path.exists() and ros2 != path.is_dir():
        raise BayesmapError(f"{str(path)!r} is a {'file' if path.is_file() else 'folder'}; a ROS "
                            f"{'2 bag is a folder' if ros2 else '1 bag is a file'}")
    if ros2 and path.is_dir():  # replacing it removes all it holds: a user's files must stay
        check_own_folder(path, "metadata.yaml", ROS2_BAG_FILES, "a ROS 2 bag")
        metadata = read_bytes(path / "metadata.yaml", "bag metadata")[1] if any(path.iterdir()) else None
        if metadata is not None and b"rosbag2_bagfile_information" not in metadata:
            raise BayesmapError(f"{str(path)!r} is not a ROS 2 bag (its metadata.yaml is not a rosbag2 one); "
                                "bayesmap replaces only a bag: choose another name, or remove the folder yourself")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise BayesmapError(f"{str(path)!r} cannot be written (no folder {str(parent)!r} to write in)")
    return path


def _write_whole(path: Path, ros2: bool, storage: str, overwrite: bool, fill) -> Path:
    """Write a bag with ``fill(writer)`` beside ``path`` (:func:`bayesmap.io.files.make_staging`) and move it in:
    whole or not at all."""
    check_bag_path(path, ros2, storage, overwrite)
    try:
        tmp = make_staging(path, folder=True)
    except OSError as err:
        raise BayesmapError(f"cannot write {str(path)!r}: {err.strerror}") from None
    try:
        staged = tmp / path.name
        with _BagWriter(staged, ros2, storage) as writer:
            fill(writer)
        if path.is_dir():
            old = tmp / "old"
            path.rename(old)
        os.replace(staged, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def write_log_bag(log: CarmenLog, path, ros2: bool = False, storage: str = "sqlite3", laser_offset=(0.0, 0.0, 0.0),
                  overwrite: bool = False) -> Path:
    """Write a log as a ROS bag: LaserScan on ``/scan``, Odometry on ``/odom``, ``/tf`` and ``/tf_static``.

    The stamps are the log's timestamps, to the microsecond, made strictly increasing (a stamp not after the previous
    one becomes that one plus 1 ms: CSAIL's log prints ``1.13486e+09`` for many scans); each scan's Odometry and
    ``odom -> base_link`` transform carry the same stamp, so reading the bag back needs no interpolation. The laser
    (frame ``laser``) is mounted at ``laser_offset`` on ``base_link`` (``/tf_static``), and the base's poses are the
    log's laser poses composed with the offset's inverse, so :func:`read_bag` gives back the log's poses. Beam
    ``k`` is at ``angle_min + k * angle_increment`` (the log's beam offsets); ``range_max`` is the log's max range
    (a log with none: its longest reading plus 1 m), ``range_min`` 0.

    Args:
        log: the scans (a :class:`~bayesmap.io.carmen.CarmenLog`, e.g. from ``read_carmen`` or :func:`read_bag`).
        path: a ``.bag`` file (ROS 1) or a folder (ROS 2).
        ros2: write a ROS 2 bag (CDR messages, Humble definitions) instead of ROS 1 (Noetic).
        storage: ROS 2 storage, ``"sqlite3"`` (a ``.db3`` file) or ``"mcap"``.
        laser_offset: ``(x m, y m, theta rad)`` of the laser on the base.
        overwrite: replace ``path`` if it exists.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        BayesmapError: on a bad storage or offset, a ROS 1 name without ``.bag``, or an existing ``path`` without
            ``overwrite``.
    """
    offset = np.asarray(laser_offset, dtype=np.float64)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise BayesmapError(f"laser offset must be three finite numbers X Y THETA, got {laser_offset!r}")
    path = Path(path)
    stamps = _stamps(log)
    offsets = np.asarray(log.angles[0] - log.poses[0, 2])  # the laser-frame beam angles (CARMEN: beam_offsets)
    range_max = log.max_range if math.isfinite(log.max_range) else float(np.max(log.ranges)) + 1.0
    base = compose_poses(log.poses, invert_pose(offset)) if np.any(offset) else np.asarray(log.poses)

    def fill(w: _BagWriter) -> None:
        s, ros2_ = w.store, w.ros2
        w.add("/scan", LASER_SCAN)
        w.add("/odom", ODOMETRY)
        w.add("/tf", TF_MESSAGE)
        w.add("/tf_static", TF_MESSAGE, latching=True)
        t0 = int(stamps[0])
        w.write("/tf_static", t0, s.types[TF_MESSAGE](
            transforms=[_transform(s, ros2_, t0, "base_link", "laser", offset)]))
        for i, ns in enumerate(stamps):
            w.write("/odom", ns, _odometry(s, ros2_, int(ns), base[i], i))
            w.write("/tf", ns, s.types[TF_MESSAGE](
                transforms=[_transform(s, ros2_, int(ns), "odom", "base_link", base[i])]))
            w.write("/scan", ns, _scan(s, ros2_, int(ns), log.ranges[i], offsets, range_max, i))

    return _write_whole(path, ros2, storage, overwrite, fill)


def occupancy_grid_data(probability, seen=None) -> np.ndarray:
    """The ``data`` of a ``nav_msgs/OccupancyGrid``: probability in percent, -1 for unknown, row-major, x fastest.

    Args:
        probability: ``(nx, ny)`` float, wall probability of cell ``(i, j)`` (``i`` along x), in [0, 1].
        seen: ``(nx, ny)`` bool, cells some beam crossed (the others are -1); default all.

    Returns:
        ``(nx * ny,)`` int8: entry ``j * nx + i`` is ``round(100 * probability[i, j])`` or -1.

    Raises:
        BayesmapError: on a probability outside [0, 1] or not finite, or a ``seen`` of another shape.
    """
    p = np.asarray(probability, dtype=np.float64)
    if p.ndim != 2 or not np.all((p >= 0) & (p <= 1)):
        raise BayesmapError(f"probability must be a (nx, ny) array of values in [0, 1], got shape {p.shape}")
    values = np.rint(100.0 * p).astype(np.int8)
    if seen is not None:
        seen = np.asarray(seen, dtype=bool)
        if seen.shape != p.shape:
            raise BayesmapError(f"seen has shape {seen.shape}, the probability {p.shape}")
        values = np.where(seen, values, np.int8(-1)).astype(np.int8)
    return values.T.reshape(-1)


def write_occupancy_grid_bag(path, probability, grid: Grid, seen=None, stamp_ns: int = 0, topic: str = "/map",
                             frame_id: str = "map", overwrite: bool = False) -> Path:
    """Write one ``nav_msgs/OccupancyGrid`` message into a new bag: ROS 1 for a ``.bag`` name, else a ROS 2 folder.

    ``info.width`` is ``nx`` (cells along x), ``info.height`` ``ny``, ``info.resolution`` the grid's meters per cell,
    ``info.origin`` the outer corner of cell (0, 0); ``data`` is :func:`occupancy_grid_data` (percent, -1 unseen).

    Args:
        path: the bag to write (whole or not at all).
        probability: ``(nx, ny)`` float wall probability per cell.
        grid: the map's :class:`~bayesmap.geometry.grid.Grid`.
        seen: ``(nx, ny)`` bool, cells some beam crossed; default all.
        stamp_ns: the message's stamp and bag time, nanoseconds.
        topic: where the map is published.
        frame_id: the map's frame.
        overwrite: replace ``path`` if it exists.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        BayesmapError: as :func:`occupancy_grid_data`, on a shape other than the grid's, or an existing ``path``
            without ``overwrite``.
    """
    path = Path(path)
    data = occupancy_grid_data(probability, seen)
    if np.shape(probability) != tuple(grid.shape):
        raise BayesmapError(f"probability has shape {np.shape(probability)}, the grid {tuple(grid.shape)}")
    ros2 = path.suffix != ".bag"

    def fill(w: _BagWriter) -> None:
        t = w.store.types
        info = t["nav_msgs/msg/MapMetaData"](
            map_load_time=_time(w.store, stamp_ns), resolution=float(grid.resolution), width=int(grid.shape[0]),
            height=int(grid.shape[1]),
            origin=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=float(grid.origin[0]), y=float(grid.origin[1]), z=0.0),
                orientation=_quaternion(w.store, 0.0)))
        w.add(topic, OCCUPANCY_GRID, latching=True)
        w.write(topic, stamp_ns, t[OCCUPANCY_GRID](header=_header(w.store, w.ros2, stamp_ns, frame_id), info=info,
                                                   data=data))

    return _write_whole(path, ros2, "sqlite3", overwrite, fill)


def read_occupancy_grid_bag(path, topic: str = "/map") -> tuple[np.ndarray, Grid]:
    """The first ``nav_msgs/OccupancyGrid`` on ``topic`` of a bag, as bayesmap's arrays.

    Returns:
        ``(values, grid)``: ``values`` ``(nx, ny)`` int8, percent or -1 (cell ``(i, j)``, ``i`` along x), and the
        :class:`~bayesmap.geometry.grid.Grid` of ``info`` (resolution widened from float32 by its shortest decimal).

    Raises:
        BayesmapError: as :func:`read_bag` (missing topic, wrong type, corrupt file).
    """
    path = Path(path)
    name = str(path)
    try:
        reader = _open(path, name)
        try:
            for msg in _messages(reader, _connections(reader, name, topic, OCCUPANCY_GRID)):
                info = msg.info
                nx, ny = int(info.width), int(info.height)
                values = np.asarray(msg.data, dtype=np.int8).reshape(ny, nx).T
                grid = Grid((nx, ny), float(_widen(np.float32(info.resolution))),
                            (float(info.origin.position.x), float(info.origin.position.y)))
                return values, grid
        finally:
            reader.close()
    except BayesmapError:
        raise
    except Exception as exc:
        raise BayesmapError(f"ROS bag {name!r} cannot be read (truncated or not a bag?): "
                            f"{type(exc).__name__}: {exc}") from None
    raise BayesmapError(f"topic {topic!r} of ROS bag {name!r} has no messages")
