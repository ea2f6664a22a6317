"""The SLAM figure (bayesmap.viz.paths): ellipses, paths and checks."""

import math

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.viz.paths import CHI2_2D_95, MAX_MARKED_POSES, ellipse_95, plot_slam, slam_report
from helpers import by_gid


def test_ellipse_95_axes_and_angle():
    """A covariance with standard deviations 2 and 1 along axes rotated by 30 degrees: full axes 2 sqrt(5.99) sd."""
    rot = np.array([[math.cos(math.pi / 6), -math.sin(math.pi / 6)], [math.sin(math.pi / 6), math.cos(math.pi / 6)]])
    cov = rot @ np.diag([4.0, 1.0]) @ rot.T
    e = ellipse_95([1.0, 2.0], cov)
    assert np.isclose(e.width, 2 * math.sqrt(CHI2_2D_95) * 2) and np.isclose(e.height, 2 * math.sqrt(CHI2_2D_95))
    assert np.isclose(e.angle % 180, 30.0)
    assert np.isclose(CHI2_2D_95, 5.991464547, atol=1e-8)
    assert ellipse_95([0.0, 0.0], np.zeros((2, 2))) is None


def test_plot_slam_draws_every_layer():
    grid = Grid((8, 6))
    rng = np.random.default_rng(0)
    mean = np.column_stack([np.linspace(1, 6, 4), np.full(4, 2.0), np.zeros(4)])
    samples = mean + rng.normal(0, 0.05, (10, 4, 3))
    cov = np.stack([np.zeros((3, 3))] + [np.eye(3) * 0.01] * 3)
    fig = plot_slam(grid, rng.random(grid.shape), mean, cov, samples, true_path=mean + 0.1, odometry=mean - 0.2,
                    truth=rng.random(grid.shape) < 0.2)
    ax = fig.axes[0]
    for gid in ("posterior", "path_samples", "mean_path", "ellipses", "true_path", "odometry", "truth"):
        by_gid(ax, gid)
    assert np.allclose(by_gid(ax, "odometry").get_xydata(), (mean - 0.2)[:, :2])
    assert len([p for p in ax.patches if type(p).__name__ == "Ellipse"]) == 3  # pose 0 has no ellipse
    with pytest.raises(BayesmapError, match="pose_cov"):
        plot_slam(grid, np.zeros(grid.shape), mean, cov[:3], samples)
    with pytest.raises(BayesmapError, match="odometry"):
        plot_slam(grid, np.zeros(grid.shape), mean, cov, samples, odometry=mean[:2])


def test_plot_slam_of_a_long_path_draws_every_ellipse_thin_without_markers():
    """A real log's hundreds of poses: every ellipse drawn, thinner; no markers; the odometry faint."""
    s = MAX_MARKED_POSES + 1
    grid = Grid((40, 30), resolution=0.5, origin=(-1.0, -1.0))
    t = np.linspace(0, 2 * np.pi, s)
    mean = np.column_stack([8 + 5 * np.cos(t), 6 + 4 * np.sin(t), t])
    cov = np.tile(np.eye(3) * 0.01, (s, 1, 1))
    fig = plot_slam(grid, np.zeros(grid.shape), mean, cov, mean[None], odometry=mean * 1.1)
    ax = fig.axes[0]
    ellipses = [p for p in ax.patches if type(p).__name__ == "Ellipse"]
    assert len(ellipses) == s and all(e.get_linewidth() < 1.0 for e in ellipses)
    for gid in ("mean_path", "odometry"):
        assert by_gid(ax, gid).get_marker() in (None, "None", "")
    assert by_gid(ax, "odometry").get_alpha() < 1.0
    short = plot_slam(grid, np.zeros(grid.shape), mean[:MAX_MARKED_POSES], cov[:MAX_MARKED_POSES],
                      mean[None, :MAX_MARKED_POSES], odometry=mean[:MAX_MARKED_POSES]).axes[0]
    assert by_gid(short, "mean_path").get_marker() == "." and by_gid(short, "odometry").get_alpha() is None


def test_slam_report_escapes_and_embeds():
    html = slam_report(b"\x89PNG", {"source": "<x>", "posterior": {"ate_rmse_m": 0.05}}, title="a & b")
    assert "&lt;x&gt;" in html and "posterior.ate_rmse_m" in html and "a &amp; b" in html
    assert "data:image/png;base64,iVBORw==" in html
