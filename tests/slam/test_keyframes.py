"""Keyframes (bayesmap.slam.keyframes): which scans SLAM runs on, and how every other scan is placed afterwards."""

import numpy as np
import pytest
from tests.slam.test_scanmatch import noisy_odometry, room_scans

from bayesmap.errors import BayesmapError
from bayesmap.model.motion import make_motion_params, odometry_controls
from bayesmap.slam.keyframes import (
    KEYFRAME_HEADING_SD,
    keyframe_problem,
    owners,
    place_scans,
    placed_uncertainty,
    select_keyframes,
    step_moves,
)
from bayesmap.slam.posegraph import relative
from bayesmap.slam.scanmatch import ScanData
from helpers import four_cpu_devices_env

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)


def test_keyframes_by_distance_and_by_turn_from_the_last_keyframe():
    """A straight run of 0.1 m steps gives a keyframe every 5th scan at 0.5 m; a turn in place of 0.1 rad per scan one
    every 5th at 0.5 rad; shuffling back and forth (1 m of travel, never 0.1 m from the start) none: the rule
    measures from the last keyframe, not along the path."""
    line = np.stack([np.arange(21) * 0.1, np.zeros(21), np.zeros(21)], axis=1)
    assert select_keyframes(line, 0.5, 0.5).tolist() == [0, 5, 10, 15, 20]
    spin = np.stack([np.zeros(21), np.zeros(21), np.arange(21) * 0.1], axis=1)
    assert select_keyframes(spin, 0.5, 0.5).tolist() == [0, 5, 10, 15, 20]
    shuffle = np.stack([0.05 * (np.arange(21) % 2), np.zeros(21), np.zeros(21)], axis=1)
    assert select_keyframes(shuffle, 0.5, 0.5).tolist() == [0]
    assert select_keyframes(line, 0.0, 0.0).tolist() == list(range(21))


def test_a_turn_across_pi_counts_as_the_short_way_round():
    """Headings 3.1 and -3.1 rad are 0.08 rad apart: no keyframe at a 0.5 rad turn."""
    odometry = np.array([[0.0, 0.0, 3.1], [0.0, 0.0, -3.1]])
    assert select_keyframes(odometry, 0.5, 0.5).tolist() == [0]


def test_a_keyframe_step_keeps_its_heading_within_the_front_ends_search():
    """With the motion model's steps, a scan also becomes a keyframe where the steps composed since the last keyframe
    would pass KEYFRAME_HEADING_SD (0.8 / 3.5 rad) of heading standard deviation (the heading variances add): a robot
    jittering on the spot (0.01 m steps, never 0.5 m or 0.5 rad from the start) with steps of heading sd 0.1 rad
    keeps every 5th scan (five steps compose to 0.224 rad, six to 0.245; a straight run of 0.1 m steps too, where
    0.7 m alone keeps every 7th), with sd 0.3 rad (one step alone past it) every scan that has a step after it;
    without the steps, or at heading_sd inf, none but the first. A bad heading_sd or shape is refused by name."""
    jitter = np.stack([0.01 * (np.arange(21) % 2), np.zeros(21), np.zeros(21)], axis=1)
    assert 5 * 0.1**2 <= KEYFRAME_HEADING_SD**2 < 6 * 0.1**2
    covs = np.tile(np.diag([1e-4, 1e-4, 0.1**2]), (20, 1, 1))
    assert select_keyframes(jitter, 0.5, 0.5, covs).tolist() == [0, 5, 10, 15]  # 15 -> 20: five steps, inside
    assert select_keyframes(jitter, 0.5, 0.5, covs * 9).tolist() == list(range(20))  # the last: no step after it
    assert select_keyframes(jitter, 0.5, 0.5).tolist() == [0]
    assert select_keyframes(jitter, 0.5, 0.5, covs, float("inf")).tolist() == [0]
    line = np.stack([np.arange(21) * 0.1, np.zeros(21), np.zeros(21)], axis=1)
    assert select_keyframes(line, 0.7, 0.5).tolist() == [0, 7, 14]
    assert select_keyframes(line, 0.7, 0.5, covs).tolist() == [0, 5, 10, 15]
    for bad in (0.0, -1.0, float("nan"), "1", True):
        with pytest.raises(BayesmapError, match="heading_sd"):
            select_keyframes(jitter, 0.5, 0.5, covs, bad)
    with pytest.raises(BayesmapError, match="step_covs"):
        select_keyframes(jitter, 0.5, 0.5, covs[:3])


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf"), "1", True])
def test_bad_thresholds_are_refused_by_name(bad):
    with pytest.raises(BayesmapError, match="keyframe distance"):
        select_keyframes(np.zeros((3, 3)), bad, 0.5)
    with pytest.raises(BayesmapError, match="keyframe turn"):
        select_keyframes(np.zeros((3, 3)), 0.5, bad)


def test_owners_and_step_moves_follow_the_last_keyframe():
    """Each scan's keyframe is the last one at or before it; its step is the odometry's motion from that keyframe,
    the same increment and covariance the motion model gives the two poses as one step, zero for the keyframes."""
    odometry = np.array([[0, 0, 0], [0.2, 0, 0.1], [0.6, 0.1, 0.2], [0.7, 0.2, 0.3], [1.3, 0.2, 0.3]], float)
    keyframes = np.array([0, 2, 4])
    assert owners(5, keyframes).tolist() == [0, 0, 1, 1, 2]
    inc, cov = step_moves(odometry_controls(odometry), keyframes)
    want_inc, want_cov = odometry_controls(odometry[[2, 3]])
    np.testing.assert_allclose(inc[3], np.asarray(want_inc)[0], atol=1e-6)
    np.testing.assert_allclose(cov[3], np.asarray(want_cov)[0], atol=1e-9)
    assert np.all(inc[keyframes] == 0) and np.all(cov[keyframes] == 0)


ROOM_MOTION = make_motion_params((0.1, 0.1, 0.1, 0.1), floor_xy=0.03, floor_theta=0.03)
"""The motion model of :func:`placed_room`: as noisy as :func:`dense_room`'s odometry."""


def dense_room(seed=0):
    """The scan-matching room, its arc sampled densely (48 scans), with odometry that drifts by 3 cm and 0.03 rad a
    step: keyframes every 4th scan."""
    grid, truth, _, beams, readings = room_scans(num_poses=48, seed=seed)
    return grid, truth, noisy_odometry(truth, np.random.default_rng(seed + 1)), beams, readings


def test_scans_between_keyframes_land_on_their_true_poses():
    """With the keyframes at their true poses, every other scan matched on their map lands within 4 cm and 0.02 rad
    of its true pose, 1.5 cm on average (the field's 0.05 m cells, its 5 cm sigma, the keyframes' endpoints up to 7 cm
    apart on the far walls), where composing the odometry from its keyframe is off by more than 8 cm on some of them
    (the motion model as noisy as the odometry: 3 cm and 0.03 rad a step). The keyframes keep their poses."""
    _, truth, odometry, _, _ = dense_room()
    keyframes = np.arange(0, len(truth), 4)
    poses = placed_room()
    np.testing.assert_array_equal(poses[keyframes], truth[keyframes])
    err = relative(truth, poses)
    dist = np.linalg.norm(err[:, :2], axis=1)
    assert dist.max() < 0.04 and dist.mean() < 0.015 and np.abs(err[:, 2]).max() < 0.02
    step_inc, _ = step_moves(odometry_controls(odometry, ROOM_MOTION), keyframes)
    own = truth[keyframes][owners(len(truth), keyframes)]
    predicted = np.stack([own[:, 0] + np.cos(own[:, 2]) * step_inc[:, 0] - np.sin(own[:, 2]) * step_inc[:, 1],
                          own[:, 1] + np.sin(own[:, 2]) * step_inc[:, 0] + np.cos(own[:, 2]) * step_inc[:, 1]], 1)
    assert np.linalg.norm(predicted - truth[:, :2], axis=1).max() > 0.08


def test_placed_scans_carry_their_keyframes_uncertainty_along_the_odometry():
    """A scan's covariance is its keyframe's plus the step's, the step's turned by the keyframe's heading (a step
    uncertain along the robot's x, taken heading +90 degrees, is uncertain along the world's y); a sample that moves
    a keyframe moves its scans with it, rigidly."""
    odometry = np.array([[0, 0, np.pi / 2], [0, 0.3, np.pi / 2], [0, 0.6, np.pi / 2]])
    poses = odometry.copy()
    keyframes = np.array([0, 2])
    kf_cov = np.stack([np.diag([1e-4, 2e-4, 1e-5])] * 2)
    samples = np.stack([poses[keyframes], poses[keyframes] + [0.1, -0.2, 0.0]])
    cov, placed = placed_uncertainty(poses, keyframes, odometry_controls(odometry), kf_cov, samples)
    _, step_cov = step_moves(odometry_controls(odometry), keyframes)
    assert step_cov[1, 0, 0] > step_cov[1, 1, 1]  # along the robot's x (its direction of travel)
    np.testing.assert_allclose(cov[1, 1, 1] - kf_cov[0, 1, 1], step_cov[1, 0, 0], rtol=1e-6)
    np.testing.assert_allclose(cov[1, 0, 0] - kf_cov[0, 0, 0], step_cov[1, 1, 1], rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(cov[keyframes], kf_cov)
    np.testing.assert_allclose(placed[1], poses + [[0.1, -0.2, 0.0]] * 3, atol=1e-12)
    assert np.all(cov == np.swapaxes(cov, 1, 2))


def test_keyframe_problem_takes_every_per_scan_array_at_the_keyframes():
    from bayesmap.slam.problem import slam_tutorial_problem

    problem = slam_tutorial_problem(num_poses=6)
    sub = keyframe_problem(problem, [0, 2, 5])
    for name in ("odometry", "sensor_angles", "readings", "true_poses"):
        np.testing.assert_array_equal(getattr(sub, name), np.asarray(getattr(problem, name))[[0, 2, 5]])
    assert sub.params is problem.params and sub.truth is problem.truth



PLACE_ON_DEVICES = """
import sys
import numpy as np
import jax
sys.path[:0] = sys.argv[2:]
from tests.slam.test_keyframes import dense_room, placed_room
assert len(jax.devices()) == 4, jax.devices()
np.save(sys.argv[1], placed_room())
"""


def placed_room():
    """Every scan of :func:`dense_room` placed on its keyframes' map (every 4th scan, at its true pose)."""
    grid, truth, odometry, beams, readings = dense_room()
    keyframes = np.arange(0, len(truth), 4)
    data = ScanData(beams, readings, readings < 20.0, *odometry_controls(odometry, ROOM_MOTION))
    return place_scans(truth[keyframes], keyframes, data, likelihood_power=1.0, batch=8)


def test_four_devices_place_every_scan_where_one_does(tmp_path):
    """The placement's batches split over four CPU devices (``XLA_FLAGS=--xla_force_host_platform_device_count=4``,
    in a fresh process) give the poses one device gives, to float32 rounding (each device scores its own scans with
    the same arithmetic; only the batch's width per device differs)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    env = four_cpu_devices_env()
    out = tmp_path / "poses.npy"
    subprocess.run([sys.executable, "-c", PLACE_ON_DEVICES, str(out), str(root), str(root / "tests")], env=env,
                   check=True, cwd=root, timeout=600)
    np.testing.assert_allclose(np.load(out), placed_room(), atol=1e-5)


def test_skipped_scans_take_the_odometry_between_them_composed(small_log):
    """Every other scan of a log that backs up: the step from scan 0 to scan 2 nets 0.6 m straight ahead, but the
    motion model's step is the two odometry steps composed (the first 0.05 m backwards: a half turn, a step and a
    half turn back), whose heading standard deviation is 0.45 rad (the default motion model's 10 % of each half
    turn), where the net motion taken as one step would claim 0.04 rad. A selection of consecutive scans keeps the
    per-scan steps, and keyframes of a selection compose its steps (the scans between them twice marginalized: the
    same step)."""
    from bayesmap.io.carmen import read_carmen
    from bayesmap.model.motion import composed_steps
    from bayesmap.slam.problem import log_slam_problem

    log = read_carmen(small_log)
    odometry = np.zeros((len(log), 3))
    odometry[:, 0] = 0.3 * np.arange(len(log))
    odometry[1::2, 0] -= 0.35  # scan 1 is 0.05 m behind scan 0, facing the same way: backed up
    log = log.with_poses(odometry)
    chosen = np.arange(0, len(log), 2)
    problem = log_slam_problem(log, chosen, resolution=0.2)
    increments, covs = problem.motion_steps()
    want_inc, want_cov = composed_steps(odometry, chosen[:-1], chosen[1:], problem.motion)
    np.testing.assert_allclose(increments, want_inc, atol=1e-9)
    np.testing.assert_allclose(covs, want_cov, rtol=1e-9)
    np.testing.assert_allclose(increments[0, :2], [0.6, 0.0], atol=1e-6)
    assert np.cos(increments[0, 2]) == pytest.approx(1.0)
    _, one_step = odometry_controls(odometry[chosen])
    assert np.sqrt(covs[0, 2, 2]) == pytest.approx(problem.motion.a1 * np.pi * np.sqrt(2), rel=0.03)
    assert np.sqrt(np.asarray(one_step)[0, 2, 2]) < 0.045
    assert log_slam_problem(log, np.arange(4, 9), resolution=0.2).steps is None
    sub = keyframe_problem(problem, [0, 2, 5])
    sub_inc, sub_cov = sub.motion_steps()
    want_inc, want_cov = composed_steps(odometry, [0, 4], [4, 10], problem.motion)
    np.testing.assert_allclose(sub_inc, want_inc, atol=1e-9)
    np.testing.assert_allclose(sub_cov, want_cov, rtol=1e-6)
