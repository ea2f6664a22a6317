"""Tests for bayesmap.io.tum: round trips, the quaternion's yaw, every error case, the project's SLAM files."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.io.carmen import read_carmen
from bayesmap.io.tum import STAMP_TOLERANCE, encode_tum, match_stamps, read_tum, tum_stamps, write_tum

SLAM = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "slam"
LINE = re.compile(r"^-?\d+(\.\d+)? -?\d+\.\d{6} -?\d+\.\d{6} 0 0 0 -?\d\.\d{9} -?\d\.\d{9}$")


def write_text(tmp_path, text, name="traj.tum"):
    p = tmp_path / name
    p.write_text(text)
    return p


def tum_line(t, x, y, theta, z=0.0):
    return f"{t} {x} {y} {z} 0 0 {math.sin(theta / 2)!r} {math.cos(theta / 2)!r}"


def wrapped_difference(a, b):
    return (np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    stamps = np.cumsum(rng.uniform(0.01, 2.0, size=50)) + 1e3
    poses = np.column_stack([rng.uniform(-50, 50, (50, 2)), rng.uniform(-7, 7, 50)])  # headings beyond +-pi too
    path = write_tum(tmp_path / "t.tum", stamps, poses)
    got_stamps, got_poses = read_tum(path)
    np.testing.assert_array_equal(got_stamps, stamps)  # stamps are written in their shortest exact form
    np.testing.assert_allclose(got_poses[:, :2], poses[:, :2], rtol=0, atol=5e-7)  # 6 decimals
    # 9-decimal quaternion components move theta by at most ~2 * 5e-10 / |q| per component
    assert np.max(np.abs(wrapped_difference(got_poses[:, 2], poses[:, 2]))) < 1e-8
    assert np.all(np.abs(got_poses[:, 2]) <= np.pi)
    assert all(LINE.match(line) for line in path.read_text().splitlines())


def test_written_format(tmp_path):
    path = write_tum(tmp_path / "t.tum", [0, 1, 2.5], [[1, 2, 0], [-1.5, 0.25, math.pi / 2], [0, 0, -math.pi / 2]])
    h = math.sqrt(0.5)
    assert path.read_text().splitlines() == [
        "0 1.000000 2.000000 0 0 0 0.000000000 1.000000000",
        f"1 -1.500000 0.250000 0 0 0 {h:.9f} {h:.9f}",
        f"2.5 0.000000 0.000000 0 0 0 {-h:.9f} {h:.9f}",
    ]


def test_yaw_of_general_quaternions(tmp_path):
    theta = 0.7
    s, c = math.sin(theta / 2), math.cos(theta / 2)
    text = "\n".join([
        "# t x y z qx qy qz qw",
        "",
        f"1 0.5 -0.5 3.0 0 0 {s} {c}",  # z is dropped
        f"2 0 0 0 0 0 {-s} {-c}",  # -q is the same rotation
    ]) + "\n"
    path = write_text(tmp_path, text)
    stamps, poses = read_tum(path)
    np.testing.assert_array_equal(stamps, [1.0, 2.0])
    np.testing.assert_allclose(poses, [[0.5, -0.5, theta], [0.0, 0.0, theta]], rtol=0, atol=1e-12)
    # a pure roll of 180 degrees about x composed with yaw: the yaw is read from the full rotation
    # q = q_yaw(theta) * q_roll(pi) = (cos(theta/2), sin(theta/2) k) * (i): (qx, qy, qz, qw) = (c, s, 0, 0)
    path = write_text(tmp_path, f"0 0 0 0 {c} {s} 0 0\n", "roll.tum")
    assert read_tum(path)[1][0, 2] == pytest.approx(theta, abs=1e-12)


def test_slightly_denormalized_quaternion_is_accepted(tmp_path):
    theta = -2.0
    k = 1.0005  # within the 1e-3 tolerance (4-decimal files are off by ~1e-4)
    path = write_text(tmp_path, f"0 1 2 0 0 0 {k * math.sin(theta / 2)} {k * math.cos(theta / 2)}\n")
    assert read_tum(path)[1][0, 2] == pytest.approx(theta, abs=1e-12)


@pytest.mark.parametrize("line, message", [
    ("0 1 2 0 0 0 1", r"line 2: expected 8 columns \(t x y z qx qy qz qw\), got 7"),
    ("0 1 2 0 0 0 1 0 7", r"line 2: expected 8 columns .*got 9"),
    ("0 1 abc 0 0 0 0 1", r"line 2: y is 'abc', not a number"),
    ("0 nan 2 0 0 0 0 1", r"line 2: x is 'nan', not a finite number"),
    ("0 1 2 0 0 0 inf 1", r"line 2: qz is 'inf', not a finite number"),
    ("0 1 2 0 0 0 0.5 0.5", r"line 2: quaternion \(0.0, 0.0, 0.5, 0.5\) has norm 0.707107, not 1"),
    ("0 1 2 0 0 0 0 1.002", r"line 2: quaternion .* has norm 1.002, not 1"),
    ("-1 1 2 0 0 0 0 1", r"line 2: stamp '-1' does not increase \(the line before has 0.0\)"),
    ("0.0 1 2 0 0 0 0 1", r"line 2: stamp '0.0' does not increase"),
])
def test_bad_lines(tmp_path, line, message):
    path = write_text(tmp_path, "0 0 0 0 0 0 0 1\n" + line + "\n")
    with pytest.raises(BayesmapError, match=re.escape(repr(str(path))) + ", " + message) as err:
        read_tum(path)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
def test_no_pose(tmp_path, text):
    path = write_text(tmp_path, text)
    with pytest.raises(BayesmapError, match=re.escape(repr(str(path))) + " holds no pose"):
        read_tum(path)


def test_unreadable_files(tmp_path):
    with pytest.raises(BayesmapError, match="TUM trajectory .*missing.tum' does not exist"):
        read_tum(tmp_path / "missing.tum")
    bad = tmp_path / "bin.tum"
    bad.write_bytes(b"0 0 0 0 0 0 0 1\n\xff\xfe\n")
    with pytest.raises(BayesmapError, match=r"bin.tum' is not UTF-8 text \(byte 16\)"):
        read_tum(bad)


def test_write_whole_or_not_at_all(tmp_path):
    path = write_tum(tmp_path / "t.tum", [0, 1], [[0, 0, 0], [1, 0, 0]])
    before = path.read_bytes()
    with pytest.raises(BayesmapError, match="already exists"):
        write_tum(path, [0], [[5, 5, 0]])
    assert path.read_bytes() == before
    write_tum(path, [0], [[5, 5, 0]], overwrite=True)
    np.testing.assert_array_equal(read_tum(path)[1], [[5.0, 5.0, 0.0]])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.tum"]  # no temporary file left


@pytest.mark.parametrize("stamps, poses, message", [
    ([], np.zeros((0, 3)), r"stamps must be a non-empty 1-D array, got shape \(0,\)"),
    ([[0, 1]], np.zeros((2, 3)), r"stamps must be a non-empty 1-D array, got shape \(1, 2\)"),
    ([0, 1], np.zeros((2, 2)), r"poses must have shape \(2, 3\) to match the stamps, got \(2, 2\)"),
    ([0, 1, 2], np.zeros((2, 3)), r"poses must have shape \(3, 3\)"),
    ([0, np.nan], np.zeros((2, 3)), r"stamp \(1,\) is nan, not finite"),
    ([0, 1], [[0, 0, 0], [0, np.inf, 0]], r"pose \(1, 1\) is inf, not finite"),
    ([0, 2, 2], np.zeros((3, 3)), r"stamps must increase strictly: stamp 2 is 2.0, after 2.0"),
    ([3, 2], np.zeros((2, 3)), r"stamp 1 is 2.0, after 3.0"),
])
def test_write_refuses_bad_input(tmp_path, stamps, poses, message):
    with pytest.raises(BayesmapError, match=message):
        write_tum(tmp_path / "t.tum", stamps, poses)
    assert not (tmp_path / "t.tum").exists()


def test_tum_stamps():
    np.testing.assert_array_equal(tum_stamps([1.5, 2.0, 7.25]), [1.5, 2.0, 7.25])
    np.testing.assert_array_equal(tum_stamps([5.0]), [5.0])
    np.testing.assert_array_equal(tum_stamps([1.5, 1.5, 2.0]), [0.0, 1.0, 2.0])  # repeats (CSAIL)
    np.testing.assert_array_equal(tum_stamps([0.0, 0.0, 0.0, 0.0]), [0.0, 1.0, 2.0, 3.0])  # all 0 (Orebro)
    np.testing.assert_array_equal(tum_stamps([2.0, 1.0]), [0.0, 1.0])
    assert tum_stamps([1.5, 2.0]).dtype == np.float64
    with pytest.raises(BayesmapError, match=r"1-D array, got shape \(1, 2\)"):
        tum_stamps([[1.0, 2.0]])
    with pytest.raises(BayesmapError, match="log timestamp 1 is nan"):
        tum_stamps([1.0, float("nan")])


@pytest.mark.parametrize("name, scans, indices", [("intel", 910, True), ("aces", 440, False),
                                                  ("csail", 406, True)])
def test_project_slam_files(tmp_path, name, scans, indices):
    if not SLAM.is_dir():
        pytest.skip(f"{SLAM} not present")
    truth_stamps, truth = read_tum(SLAM / f"{name}-odom.truth.tum")
    odom_stamps, odom = read_tum(SLAM / f"{name}-odom.odom.tum")
    assert truth.shape == odom.shape == (scans, 3)
    np.testing.assert_array_equal(truth_stamps, odom_stamps)
    np.testing.assert_array_equal(odom[0], truth[0])  # the first odometry pose is the first true pose
    log = read_carmen(SLAM / f"{name}-odom.log.gz")
    # the data's stamp rule: the log's timestamps, or the scan indices where they do not increase strictly
    np.testing.assert_array_equal(tum_stamps(log.timestamps), truth_stamps)
    assert np.array_equal(truth_stamps, np.arange(scans)) == indices
    # the log's poses (6 decimals) are the odometry file's
    np.testing.assert_allclose(log.poses[:, :2], odom[:, :2], rtol=0, atol=1e-6)
    assert np.max(np.abs(wrapped_difference(log.poses[:, 2], odom[:, 2]))) < 1e-6
    # writing the trajectory back gives the same lines up to the last digit of a quaternion component
    out = write_tum(tmp_path / "t.tum", truth_stamps, truth)
    assert read_tum(out)[0].tolist() == truth_stamps.tolist()
    for ours, theirs in zip(out.read_text().splitlines(), (SLAM / f"{name}-odom.truth.tum").read_text().splitlines()):
        assert ours.split()[:6] == theirs.split()[:6]


def test_encode_tum_is_the_text_write_tum_writes(tmp_path):
    stamps, poses = np.array([0.0, 1.0, 2.5]), np.array([[0.0, 1.0, 0.3], [2.0, -1.5, -3.0], [1e3, 2.0, 3.1]])
    text = encode_tum(stamps, poses)
    assert text == write_tum(tmp_path / "t.tum", stamps, poses).read_text()
    assert len(text.splitlines()) == 3 and all(LINE.match(line) for line in text.splitlines())
    with pytest.raises(BayesmapError, match="increase strictly"):
        encode_tum([1.0, 1.0], poses[:2])


def test_match_stamps_pairs_the_nearest_within_the_tolerance():
    reference = np.array([10.0, 10.5, 11.0, 12.0])
    np.testing.assert_array_equal(match_stamps([10.5, 12.0 + 0.5 * STAMP_TOLERANCE, 10.0], reference), [1, 3, 0])
    assert match_stamps([3.0], [3.0]).tolist() == [0]  # one reference stamp
    assert match_stamps(np.arange(5.0), np.arange(10.0)).tolist() == list(range(5))  # scan indices
    with pytest.raises(BayesmapError, match=r"stamp 11.5 \(pose 1\) has no match within 0.0001 s \(the nearest is "):
        match_stamps([10.0, 11.5], reference)
    with pytest.raises(BayesmapError, match="two stamps pair with the same stamp 11.0"):
        match_stamps([11.0, 11.0], reference, tolerance=0.0)
