"""The SLAM figure (bayesmap.viz.paths): ellipses, paths, the crop to the seen cells and checks."""

import math

import numpy as np
import pytest
from matplotlib.patches import Ellipse

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.viz.paths import (
    CHI2_2D_95,
    MAX_ELLIPSES,
    MAX_MARKED_POSES,
    ellipse_95,
    ellipse_poses,
    plot_slam,
    slam_report,
)
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


def test_ellipse_poses_spaced_along_the_path_with_the_widest():
    """1000 poses: 400 standing at the start, then 600 moving 60 m along x; the ellipses go to poses evenly spaced
    along the 60 m (not 400 of them piled up at the start), plus the pose of the widest ellipse."""
    x = np.concatenate([np.zeros(400), np.linspace(0.1, 60.0, 600)])
    path = np.column_stack([x, np.zeros(1000), np.zeros(1000)])
    sd = np.full(1000, 0.1)
    sd[123] = 0.5
    picks = ellipse_poses(path, sd)
    assert np.all(np.diff(picks) > 0) and 123 in picks
    assert len(picks) == MAX_ELLIPSES + 1
    assert np.sum(picks < 400) == 2  # the first pose and the widest one
    gaps = np.diff(x[picks[picks >= 400]])
    assert np.allclose(gaps, 60.0 / (MAX_ELLIPSES - 1), atol=0.11)  # within one pose's step (0.1 m)
    np.testing.assert_array_equal(ellipse_poses(path[:MAX_ELLIPSES], sd[:MAX_ELLIPSES]), np.arange(MAX_ELLIPSES))


def test_plot_slam_is_cropped_to_the_seen_cells_with_the_paths_light_on_top():
    """A real log's grid is much larger than what the beams saw: the axes show the seen cells' bounding box plus
    1.5 m; every path and ellipse lies above the map, thin and see-through; the ellipses are subsampled."""
    grid = Grid((200, 150), resolution=0.2, origin=(-20.0, -10.0))
    seen = np.zeros(grid.shape, dtype=bool)
    seen[10:65, 5:35] = True  # x from -18 to -7 m, y from -9 to -3 m
    s = 300
    t = np.linspace(0, 2 * np.pi, s)
    mean = np.column_stack([-12.5 + 4 * np.cos(t), -6 + 2 * np.sin(t), t])
    cov = np.tile(np.diag([0.01, 0.01, 0.001]), (s, 1, 1))
    cov[77, :2, :2] *= 9.0  # the widest, sd 0.3 m
    rng = np.random.default_rng(1)
    fig = plot_slam(grid, np.full(grid.shape, 0.1), mean, cov, mean + rng.normal(0, 0.05, (5, s, 3)),
                    true_path=mean + 0.05, odometry=mean * 1.5, seen=seen)
    ax = fig.axes[0]
    assert (*ax.get_xlim(), *ax.get_ylim()) == pytest.approx((-19.5, -5.5, -10.0, -1.5))
    base = by_gid(ax, "posterior")
    np.testing.assert_array_equal(np.ma.getmaskarray(base.get_array()), ~seen[2:73, :43].T)
    for gid in ("path_samples", "odometry", "true_path", "mean_path", "ellipses"):
        artist = by_gid(ax, gid)
        assert artist.get_zorder() > base.get_zorder(), gid
        assert artist.get_alpha() < 1.0 and artist.get_linewidth() < 1.0, gid
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == MAX_ELLIPSES + 1
    assert any(np.allclose(e.center, mean[77, :2]) for e in ellipses)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert f"95 % ellipses, {MAX_ELLIPSES + 1} of {s} poses (largest sd 0.3 m)" in labels
    assert "unseen cells" in labels
    with pytest.raises(BayesmapError, match="seen must be a bool array"):
        plot_slam(grid, np.zeros(grid.shape), mean, cov, mean[None], seen=seen.astype(float))
