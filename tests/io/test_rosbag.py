"""ROS bags in (bayesmap.io.rosbag.read_bag, `infer --bag`) and out (`convert`), on a slice of the real Intel log:
a bag written from a log reads back the log and maps to the same posterior (ROS 1, ROS 2 sqlite3 and mcap, an
off-center laser with --tf); poses are interpolated; "no return" readings follow the max-range rule; every bad bag
is one error line naming the topic or field (exit 2)."""

import json
import math

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.io.carmen import CarmenLog, read_carmen
from bayesmap.io.rosbag import compose_poses, invert_pose, read_bag, write_log_bag
from helpers import SHARED_DATA, run_cli, run_main

INTEL = SHARED_DATA / "carmen" / "intel-corrected.log.gz"
SCANS = 40
OFFSET = (0.3, -0.1, 0.2)  # an off-center laser, rotated 0.2 rad
# mapping settings: coarse cells and few sweeps, so each run is quick
MAPPING = ["--resolution", "0.5", "--sweeps", "6", "--seed", "3"]

# the module's tests share its bags and the log's posterior (module fixtures, ~10 s each): on one xdist worker
# (--dist loadgroup), so each is made once, not once per worker
pytestmark = pytest.mark.xdist_group("rosbag")


def _slice(log: CarmenLog, n: int) -> CarmenLog:
    return CarmenLog(path=log.path, ranges=log.ranges[:n], poses=log.poses[:n], angles=log.angles[:n],
                     timestamps=log.timestamps[:n], max_range=log.max_range, is_max_range=log.is_max_range[:n])


@pytest.fixture(scope="module")
def intel():
    return _slice(read_carmen(INTEL), SCANS)


@pytest.fixture(scope="module")
def bags(tmp_path_factory, intel):
    """Bags of the log's first 40 scans: ROS 1 and ROS 2 (sqlite3) written by `bayesmap convert`, ROS 2 mcap and an
    off-center laser (ROS 1) by write_log_bag."""
    folder = tmp_path_factory.mktemp("bags")
    out = {"ros1": folder / "intel.bag", "ros2": folder / "intel-ros2", "mcap": folder / "intel-mcap",
           "offset": folder / "offset.bag"}
    for args in (["convert", INTEL, out["ros1"], "--scans", f"0:{SCANS}"],
                 ["convert", INTEL, out["ros2"], "--ros2", "--scans", f"0:{SCANS}"]):
        assert run_main(*args) == 0
    write_log_bag(intel, out["mcap"], ros2=True, storage="mcap")
    write_log_bag(intel, out["offset"], laser_offset=OFFSET)
    return out


def _same_scans(bag: CarmenLog, log: CarmenLog) -> None:
    assert bag.ranges.shape == log.ranges.shape
    np.testing.assert_array_equal(bag.ranges, log.ranges)  # float32 in the bag, widened by shortest decimal
    np.testing.assert_array_equal(bag.is_max_range, log.is_max_range)
    assert bag.max_range == log.max_range == 81.83
    np.testing.assert_allclose(bag.poses[:, :2], log.poses[:, :2], atol=1e-9)
    heading = np.angle(np.exp(1j * (bag.poses[:, 2] - log.poses[:, 2])))  # the bag's yaw is wrapped to (-pi, pi]
    np.testing.assert_allclose(heading, 0.0, atol=1e-9)
    # beam angles come from float32 angle_min / angle_increment: 180 beams, up to 2e-7 rad apart
    np.testing.assert_allclose(np.angle(np.exp(1j * (bag.angles - log.angles))), 0.0, atol=5e-7)
    np.testing.assert_allclose(bag.timestamps, log.timestamps, atol=1e-6)


@pytest.mark.parametrize("kind", ["ros1", "ros2", "mcap"])
def test_a_bag_written_from_a_log_reads_back_the_log(bags, intel, kind):
    _same_scans(read_bag(bags[kind]), intel)
    _same_scans(read_bag(bags[kind], tf=True), intel)  # the same poses from /tf


def test_an_off_center_laser_gives_the_laser_poses_by_tf_and_by_odometry(bags, intel):
    for tf in (True, False):
        _same_scans(read_bag(bags["offset"], tf=tf), intel)
    # the base's poses are not the laser's: the offset was composed in
    from rosbags.highlevel import AnyReader

    with AnyReader([bags["offset"]]) as reader:
        conn = next(c for c in reader.connections if c.topic == "/odom")
        msg = reader.deserialize(next(reader.messages([conn]))[2], conn.msgtype)
    base = np.array([msg.pose.pose.position.x, msg.pose.pose.position.y])
    expected = compose_poses(intel.poses[0], invert_pose(OFFSET))[:2]
    np.testing.assert_allclose(base, expected, atol=1e-9)
    assert np.hypot(*(base - intel.poses[0, :2])) == pytest.approx(math.hypot(0.3, 0.1), abs=1e-9)


def test_compose_and_invert_are_inverse():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(compose_poses(compose_poses(a, b), invert_pose(b)), a, atol=1e-12)
    np.testing.assert_allclose(compose_poses([1.0, 2.0, np.pi / 2], [1.0, 0.0, 0.0]), [1.0, 3.0, np.pi / 2],
                               atol=1e-12)


@pytest.fixture(scope="module")
def log_posterior(tmp_path_factory):
    out = tmp_path_factory.mktemp("log") / "out"
    _infer(["--log", INTEL, "--scans", f"0:{SCANS}", *MAPPING, "--out", out])
    return np.load(out / "posterior.npy")


def _infer(args):
    assert run_main("infer", *args) == 0


@pytest.mark.parametrize("kind, extra", [("ros1", []), ("ros2", []), ("offset", ["--tf"])])
def test_mapping_the_bag_gives_the_logs_posterior(tmp_path, bags, log_posterior, kind, extra):
    _infer(["--bag", bags[kind], *extra, *MAPPING, "--out", tmp_path / "out"])
    posterior = np.load(tmp_path / "out" / "posterior.npy")
    assert posterior.shape == log_posterior.shape
    # same seed, same chain: only the float32 beam angles differ (<= 2e-7 rad, 16 microns at 80 m); measured 6e-6
    np.testing.assert_allclose(posterior, log_posterior, atol=1e-4)
    assert 0.02 < log_posterior.mean() < 0.5  # a real map, not an empty one


# -------------------------------------------------------------------------------------- hand-made bags, bad bags


def _write(path, scans=(), odoms=(), topic="/scan", odom_topic="/odom", scan_type="sensor_msgs/msg/LaserScan"):
    """A ROS 1 bag with LaserScans ``(t, ranges, range_min, range_max)`` and Odometry ``(t, x, y, yaw)``."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    t = store.types

    def header(ns, frame):
        return t["std_msgs/msg/Header"](seq=0, stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9,
                                                                                      nanosec=ns % 10**9),
                                        frame_id=frame)

    with Writer(path) as writer:
        sc = writer.add_connection(topic, scan_type, typestore=store)
        oc = writer.add_connection(odom_topic, "nav_msgs/msg/Odometry", typestore=store)
        for sec, ranges, lo, hi in scans:
            ns = int(sec * 1e9)
            msg = t["sensor_msgs/msg/LaserScan"](
                header=header(ns, "laser"), angle_min=-0.5, angle_max=0.5, angle_increment=0.5, time_increment=0.0,
                scan_time=0.0, range_min=lo, range_max=hi, ranges=np.asarray(ranges, dtype=np.float32),
                intensities=np.zeros(0, dtype=np.float32))
            writer.write(sc, ns, store.serialize_ros1(msg, sc.msgtype))
        for sec, x, y, yaw in odoms:
            ns = int(sec * 1e9)
            vec = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            msg = t["nav_msgs/msg/Odometry"](
                header=header(ns, "odom"), child_frame_id="base_link",
                pose=t["geometry_msgs/msg/PoseWithCovariance"](
                    pose=t["geometry_msgs/msg/Pose"](
                        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                                      w=math.cos(yaw / 2))),
                    covariance=np.zeros(36)),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t["geometry_msgs/msg/Twist"](linear=vec, angular=vec), covariance=np.zeros(36)))
            writer.write(oc, ns, store.serialize_ros1(msg, oc.msgtype))
    return path


def test_poses_are_interpolated_at_the_scan_stamp_and_the_heading_takes_the_short_arc(tmp_path):
    path = _write(tmp_path / "b.bag", scans=[(10.25, [1, 2, 3], 0.1, 30.0), (11.0, [1, 2, 3], 0.1, 30.0)],
                  odoms=[(10.2, 0.0, 0.0, 3.0), (10.3, 2.0, -1.0, -3.0), (11.0, 4.0, 0.0, 0.5)])
    log = read_bag(path)
    # 10.25 s: half-way; the heading from 3.0 to -3.0 rad goes through pi (0.283 rad), not through 0 (6 rad)
    np.testing.assert_allclose(log.poses[0, :2], [1.0, -0.5], atol=1e-12)
    assert np.angle(np.exp(1j * (log.poses[0, 2] - (3.0 + (2 * np.pi - 6.0) / 2)))) == pytest.approx(0, abs=1e-9)
    np.testing.assert_allclose(log.poses[1], [4.0, 0.0, 0.5], atol=1e-12)  # an exact stamp: that pose
    np.testing.assert_allclose(log.angles[1], 0.5 + np.array([-0.5, 0.0, 0.5]), atol=1e-12)


def test_readings_with_no_return_are_set_to_the_max_range(tmp_path):
    ranges = [np.nan, np.inf, 0.05, 30.0, 31.5, 2.5]  # NaN, inf, below range_min, at and above range_max, a reading
    path = _write(tmp_path / "b.bag", scans=[(1.0, ranges[:3], 0.1, 30.0), (2.0, ranges[3:], 0.1, 30.0)],
                  odoms=[(1.0, 0.0, 0.0, 0.0), (2.0, 0.0, 0.0, 0.0)])
    log = read_bag(path)
    assert log.max_range == 30.0
    np.testing.assert_array_equal(log.is_max_range, [[True, True, True], [True, True, False]])
    np.testing.assert_array_equal(log.ranges, [[30.0, 30.0, 30.0], [30.0, 30.0, 2.5]])
    override = read_bag(path, max_range=2.0)  # --max-range: readings at or above it are "no return" too
    assert override.max_range == 2.0 and override.is_max_range.all()


def _bad_bags(tmp, bags):
    """(CLI arguments after `infer`, words the one error line must hold)."""
    far = _write(tmp / "far.bag", scans=[(1.0, [1, 2, 3], 0.1, 30.0), (5.0, [1, 2, 3], 0.1, 30.0)],
                 odoms=[(1.0, 0.0, 0.0, 0.0), (1.05, 0.1, 0.0, 0.0)])
    wrong = _write(tmp / "wrong.bag", scans=[], topic="/scan", scan_type="nav_msgs/msg/Odometry")
    data = bags["ros1"].read_bytes()
    truncated = tmp / "truncated.bag"
    truncated.write_bytes(data[: len(data) // 3])
    ros2_truncated = tmp / "ros2-truncated"
    ros2_truncated.mkdir()
    for f in bags["ros2"].iterdir():
        (ros2_truncated / f.name).write_bytes(f.read_bytes()[:2000] if f.suffix == ".db3" else f.read_bytes())
    return [
        (["--bag", bags["ros1"], "--scan-topic", "/laser"], ["no topic '/laser'", "/scan"]),
        (["--bag", bags["ros1"], "--odom-topic", "/odometry"], ["no topic '/odometry'"]),
        (["--bag", wrong], ["'/scan'", "nav_msgs/msg/Odometry", "not sensor_msgs/msg/LaserScan"]),
        (["--bag", bags["ros1"], "--scan-topic", "/odom"], ["'/odom'", "not sensor_msgs/msg/LaserScan"]),
        (["--bag", far], ["scan 1", "no pose on '/odom'", "within 0.1 s"]),
        (["--bag", truncated], ["truncated.bag", "cannot be read"]),
        (["--bag", ros2_truncated], ["ros2-truncated", "cannot be read"]),
        (["--bag", tmp / "missing.bag"], ["missing.bag", "does not exist"]),
        (["--bag", bags["ros1"], "--log", INTEL], ["either --log or --bag"]),
        (["--log", INTEL, "--tf"], ["need --bag"]),
    ]


def test_every_bad_bag_is_one_error_line_and_exit_2(tmp_path, bags, monkeypatch, capsys):
    for args, words in _bad_bags(tmp_path, bags):
        code, out, err = run_cli(monkeypatch, capsys, "infer", *args, "--out", tmp_path / "out")
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 2, (args, err)
        assert len(lines) == 1 and lines[0].startswith("error: "), (args, err)
        for word in words:
            assert word in lines[0], (args, word, lines[0])
        assert not (tmp_path / "out").exists()


def test_read_bag_raises_bayesmap_error_on_a_missing_topic(bags):
    with pytest.raises(BayesmapError, match="no topic '/nope'"):
        read_bag(bags["ros2"], scan_topic="/nope")


def test_convert_refuses_an_existing_bag_and_bad_storage(tmp_path, bags, monkeypatch, capsys):
    for args, words in [
        (["convert", INTEL, bags["ros1"]], "already exists"),
        (["convert", INTEL, tmp_path / "x.bag", "--storage", "mcap"], "--ros2"),
        (["convert", INTEL, tmp_path / "x", "--ros2", "--storage", "zip"], "unknown --storage 'zip'"),
        (["convert", INTEL, tmp_path / "x.db"], "must end in '.bag'"),
        (["convert", INTEL, tmp_path / "x.bag", "--tf"], "apply to a bag"),
    ]:
        code, out, err = run_cli(monkeypatch, capsys, *args)
        assert code == 2 and err.count("\n") == 1 and words in err, (args, err)


def test_convert_turns_a_ros1_bag_into_a_ros2_bag(tmp_path, bags, intel, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "convert", bags["offset"], tmp_path / "r2", "--ros2", "--tf",
                             "--storage", "mcap")
    assert code == 0, err
    assert "40 scans of 180 beams" in out
    _same_scans(read_bag(tmp_path / "r2"), intel)


def test_evaluate_takes_a_bag_as_it_takes_the_log(tmp_path, bags, monkeypatch, capsys):
    scores = []
    for source in (["--log", INTEL, "--scans", f"0:{SCANS}"], ["--bag", bags["ros2"]]):
        out = tmp_path / f"scores{len(scores)}.json"
        code, _, err = run_cli(monkeypatch, capsys, "evaluate", *source, "--resolution", "0.5", "--sweeps", "2",
                               "--every", "5", "--json", out)
        assert code == 0, err
        scores.append(json.loads(out.read_text()))
    for method in ("bayesmap", "logodds"):
        assert scores[1][method]["beams"] == scores[0][method]["beams"] > 0
        assert scores[1][method]["auc"] == pytest.approx(scores[0][method]["auc"], abs=1e-4)
        assert scores[1][method]["nll"] == pytest.approx(scores[0][method]["nll"], abs=1e-4)
