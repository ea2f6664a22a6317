"""The SLAM model (bayesmap.model.slam.slam_model): poses as random choices, the known-pose special case."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.model import motion
from bayesmap.model.generative import log_joint_scans, make_params
from bayesmap.model.slam import log_joint_slam, simulate_slam, slam_args, slam_choices, slam_model

ODOMETRY = np.array([[1.2, 1.1, 0.2], [2.0, 1.6, 0.7], [2.6, 2.9, 1.5], [2.5, 4.0, 2.2]])  # inside a 6 x 7 grid


def scene(beam_model, seed, noise=True, num_beams=8):
    rng = np.random.default_rng(seed)
    params = make_params(0.3, 0.4, num_beams, Grid((6, 7)), 6.0, beam_model=beam_model)
    mp = motion.MotionParams() if noise else motion.make_motion_params((0, 0, 0, 0), 0, 0)
    inc, cov = motion.odometry_controls(ODOMETRY, mp)
    angles = rng.uniform(-np.pi, np.pi, (len(ODOMETRY), num_beams))
    return params, inc, cov, angles


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_addresses_and_log_joint_is_assess(beam_model):
    """simulate -> the trace's choices at "poses", "walls", "readings"; log_joint_slam of them equals the trace's
    score and assess (float64, 1e-9: the same computation)."""
    with enable_x64():
        params, inc, cov, angles = scene(beam_model, 0)
        args = slam_args(ODOMETRY[0], inc, cov, params, angles)
        trace = jax.jit(slam_model.simulate)(jax.random.key(2), args)
        poses, walls, y = trace.get_retval()
        chm = trace.get_choices()
        np.testing.assert_array_equal(np.asarray(chm["poses"]), np.asarray(poses[1:]))
        np.testing.assert_array_equal(np.asarray(chm["walls"]), np.asarray(walls))
        np.testing.assert_array_equal(np.asarray(chm["readings"]), np.asarray(y))
        assert poses.shape == (4, 3) and y.shape == (4, 8) and walls.shape == (6, 7)
        np.testing.assert_array_equal(np.asarray(poses[0]), ODOMETRY[0])
        got = float(log_joint_slam(poses, walls, y, inc, cov, params, angles))
        want = float(jax.jit(slam_model.assess)(slam_choices(poses, walls, y), args)[0])
        assert np.isfinite(got) and got == pytest.approx(want, abs=1e-9)
        assert got == pytest.approx(float(trace.get_score()), abs=1e-6)


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
@pytest.mark.parametrize("seed", range(2))
def test_log_joint_is_motion_plus_known_pose_model(beam_model, seed):
    """At any path: log_joint_slam = path_logpdf (motion model) + log_joint_scans at the path's positions with
    world-frame angles theta + sensor angles (the map part is multi_scan_model). Float64 to 1e-9."""
    with enable_x64():
        params, inc, cov, angles = scene(beam_model, seed)
        rng = np.random.default_rng(seed)
        poses = ODOMETRY + np.concatenate([np.zeros((1, 3)), rng.normal(0, 0.1, (3, 3))])
        walls = (rng.random((6, 7)) < 0.3).astype(np.float64)
        y = np.abs(rng.normal(2.0, 1.0, angles.shape))
        got = float(log_joint_slam(poses, walls, y, inc, cov, params, angles))
        world = poses[:, 2:3] + angles
        want = float(motion.path_logpdf(poses, ODOMETRY[0], inc, cov)) + float(
            log_joint_scans(walls, y, poses[:, :2], params, world))
        assert got == pytest.approx(want, abs=1e-9)


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_zero_noise_is_the_known_pose_model(beam_model):
    """With zero motion noise, simulate puts the poses on the odometry path, and assess there equals
    multi_scan_model's assess at the same poses (log_joint_scans); off the path the score is -inf."""
    with enable_x64():
        params, inc, cov, angles = scene(beam_model, 1, noise=False)
        poses, walls, y = simulate_slam(jax.random.key(5), ODOMETRY[0], inc, cov, params, angles)
        np.testing.assert_allclose(np.asarray(poses), ODOMETRY, atol=1e-9)
        got = float(log_joint_slam(poses, walls, y, inc, cov, params, angles))
        want = float(log_joint_scans(walls, y, np.asarray(poses[:, :2]), params, np.asarray(poses[:, 2:3]) + angles))
        assert np.isfinite(got) and got == pytest.approx(want, abs=1e-9)
        off = jnp.asarray(poses).at[3, 1].add(1e-3)
        assert float(log_joint_slam(off, walls, y, inc, cov, params, angles)) == -np.inf


def test_first_pose_is_not_a_choice():
    params, inc, cov, angles = scene("normal", 0)
    trace = slam_model.simulate(jax.random.key(0), slam_args(ODOMETRY[0], inc, cov, params, angles))
    assert trace.get_choices()["poses"].shape == (3, 3)


def test_bad_shapes_are_errors():
    params, inc, cov, angles = scene("normal", 0)
    with pytest.raises(BayesmapError, match="first_pose"):
        slam_args(np.zeros(2), inc, cov, params, angles)
    with pytest.raises(BayesmapError, match="odometry_increments"):
        slam_args(ODOMETRY[0], inc[:2], cov, params, angles)
    with pytest.raises(BayesmapError, match="odometry_covs"):
        slam_args(ODOMETRY[0], inc, cov[:, :2], params, angles)
    with pytest.raises(BayesmapError, match="poses"):
        log_joint_slam(ODOMETRY[:3], np.zeros((6, 7)), np.zeros(angles.shape), inc, cov, params, angles)
    with pytest.raises(BayesmapError, match="readings"):
        log_joint_slam(ODOMETRY, np.zeros((6, 7)), np.zeros((4, 3)), inc, cov, params, angles)
