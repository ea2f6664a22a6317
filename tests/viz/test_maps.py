"""Tests for bayesmap.viz.maps: what is drawn where (checked on the artists' data) and validation."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.image import AxesImage

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles, sensor_distances
from bayesmap.viz.maps import plot_map, plot_occupancy_map, plot_posterior, plot_posterior_path, plot_prior_samples
from helpers import POS, blurred, by_gid


def expected_endpoints(origin, a, r):
    return np.asarray(origin) + r[:, None] * np.stack([np.cos(a), np.sin(a)], axis=-1)


# ---------------------------------------------------------------------------------------------------------------
# plot_map
# ---------------------------------------------------------------------------------------------------------------


def test_plot_map_structure(grid, walls, scan):
    a, r = scan
    fig = plot_map(grid, walls, POS, a, r)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 1
    ax = fig.axes[0]
    assert ax.get_xlim() == pytest.approx((-0.5, 20.5))
    assert ax.get_ylim() == pytest.approx((-0.5, 20.5))
    assert ax.get_xlabel() == "x (cells)" and ax.get_ylabel() == "y (cells)"
    assert ax.get_title() == "True map"
    assert ax.get_aspect() == 1.0
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["wall", "sensor", "ray", "reading"]


def test_plot_map_walls_are_the_true_wall_cells(grid, walls):
    fig = plot_map(grid, walls)
    patches = by_gid(fig.axes[0], "walls")
    assert isinstance(patches, PatchCollection)
    # each path is a unit square; its center is the cell (i, j) in the tutorial's convention
    centers = sorted(tuple(np.round(p.vertices[:4].mean(axis=0)).astype(int)) for p in patches.get_paths())
    expected = sorted((int(i), int(j)) for i, j in np.argwhere(walls > 0.5))
    assert centers == expected
    # line 2 of the ASCII map is ".XXX..........X......": x = 2 has walls at y = 1, 2, 3 and 14
    assert {(2, 1), (2, 2), (2, 3), (2, 14)} <= set(centers)
    assert (1, 2) not in set(centers)  # not transposed


def test_plot_map_sensor_and_endpoints(grid, walls, scan):
    a, r = scan
    ax = plot_map(grid, walls, POS, a, r).axes[0]
    np.testing.assert_allclose(by_gid(ax, "sensor").get_offsets(), [POS])
    ends = expected_endpoints(POS, a, r)
    np.testing.assert_allclose(by_gid(ax, "readings").get_offsets(), ends, atol=1e-9)
    rays = by_gid(ax, "rays")
    assert isinstance(rays, LineCollection)
    segs = np.array(rays.get_segments())
    assert segs.shape == (100, 2, 2)
    np.testing.assert_allclose(segs[:, 0], np.broadcast_to(POS, (100, 2)))
    np.testing.assert_allclose(segs[:, 1], ends, atol=1e-9)
    # a reading straight along +x from (10, 10) hits the wall cell (17, 10) at x = 16.5
    assert a[0] == 0.0
    np.testing.assert_allclose(segs[0, 1], [16.5, 10.0], atol=1e-5)


def test_sensor_at_an_asymmetric_position(grid, walls):
    pos = np.array([4.0, 8.0])
    a = np.asarray(angles(8), dtype=np.float64)
    r = np.asarray(sensor_distances(walls, pos, angles(8)), dtype=np.float64)
    figs = (plot_map(grid, walls, pos, a, r), plot_posterior(grid, blurred(walls), pos=pos, beam_angles=a, readings=r))
    for fig in figs:
        ax = fig.axes[0]
        np.testing.assert_allclose(by_gid(ax, "sensor").get_offsets(), [pos])
        np.testing.assert_allclose(by_gid(ax, "readings").get_offsets(), expected_endpoints(pos, a, r), atol=1e-9)
    # from (4, 8) straight down (-y) the first wall is cell (4, 1) (map line i = 4 is ".X............XXX...."),
    # whose top edge is at y = 1.5
    assert a[6] == pytest.approx(3 * np.pi / 2)
    assert r[6] == pytest.approx(6.5, abs=1e-5)


def test_plot_map_without_walls_shows_only_the_scan(grid, scan):
    a, r = scan
    ax = plot_map(grid, None, POS, a, r).axes[0]
    assert not [c for c in ax.get_children() if c.get_gid() == "walls"]
    assert ax.get_title() == "What the robot sees"
    by_gid(ax, "rays")
    by_gid(ax, "sensor")
    by_gid(ax, "gridlines")


def test_plot_map_origins_and_max_range(grid, walls):
    a = np.array([0.0, np.pi / 2, np.pi, 1.0])
    r = np.array([2.0, 3.0, 4.0, 5.0])
    origins = np.array([[5.0, 5.0], [5.0, 5.0], [12.0, 8.0], [12.0, 8.0]])
    mask = np.array([False, True, False, True])
    ax = plot_map(grid, walls, None, a, r, origins=origins, max_range_mask=mask).axes[0]
    ends = expected_endpoints(origins, a, r)
    np.testing.assert_allclose(by_gid(ax, "readings").get_offsets(), ends[~mask])
    np.testing.assert_allclose(by_gid(ax, "max_range_readings").get_offsets(), ends[mask])
    np.testing.assert_allclose(np.array(by_gid(ax, "rays").get_segments())[:, 0], origins)
    np.testing.assert_allclose(by_gid(ax, "sensor").get_offsets(), [[5.0, 5.0], [12.0, 8.0]])
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "max-range reading" in labels


def test_plot_map_into_given_axes(grid, walls):
    fig = Figure()
    ax = fig.add_subplot(1, 2, 2)
    assert plot_map(grid, walls, POS, ax=ax, title="mine") is fig
    assert ax.get_title() == "mine"
    assert len(fig.axes) == 1


def test_gridlines_only_on_small_grids(walls):
    small = plot_map(Grid((60, 30)), None).axes[0]
    lines = by_gid(small, "gridlines")
    assert len(lines.get_segments()) == 61 + 31
    big = plot_map(Grid((61, 30)), None).axes[0]
    assert not [c for c in big.get_children() if c.get_gid() == "gridlines"]


def test_large_wall_count_drawn_as_image():
    grid = Grid((200, 100), resolution=0.1, origin=(-3.2, 5.0))
    walls = np.zeros(grid.shape)
    walls[:, :20] = 1.0  # 4000 wall cells
    ax = plot_map(grid, walls).axes[0]
    image = by_gid(ax, "walls")
    assert isinstance(image, AxesImage)
    assert image.get_extent() == pytest.approx(grid.extent)
    rgba = np.asarray(image.get_array())
    assert rgba.shape == (100, 200, 4)  # transposed: rows are y
    assert (rgba[:20, :, 3] == 255).all() and (rgba[20:, :, 3] == 0).all()


# ---------------------------------------------------------------------------------------------------------------
# plot_posterior
# ---------------------------------------------------------------------------------------------------------------


def test_plot_posterior_heatmap(grid, walls, scan):
    a, r = scan
    post = blurred(walls)
    fig = plot_posterior(grid, post, truth=walls, pos=POS, beam_angles=a, readings=r, title="after 100 rays")
    assert len(fig.axes) == 2  # map + colour bar
    ax = fig.axes[0]
    image = by_gid(ax, "posterior")
    np.testing.assert_array_equal(np.asarray(image.get_array()), post.T)
    assert image.get_extent() == pytest.approx(grid.extent)
    assert image.origin == "lower"
    assert image.get_clim() == (0.0, 1.0)
    cbar = image.colorbar
    assert cbar is not None and cbar.ax in fig.axes
    assert cbar.ax.get_ylabel() == "P(wall)"
    assert cbar.ax.get_ylim() == pytest.approx((0.0, 1.0))
    assert ax.get_title() == "after 100 rays"
    assert ax.get_xlabel() == "x (cells)"
    np.testing.assert_allclose(by_gid(ax, "sensor").get_offsets(), [POS])
    np.testing.assert_allclose(by_gid(ax, "readings").get_offsets(), expected_endpoints(POS, a, r), atol=1e-9)


def test_colorbar_matches_map_height(grid, walls):
    fig = plot_posterior(grid, blurred(walls), std=True)
    for ax, cax in ((fig.axes[0], fig.axes[2]), (fig.axes[1], fig.axes[3])):
        ax.apply_aspect()
        a, c = ax.get_position(), cax.get_position()
        assert c.y0 == pytest.approx(a.y0) and c.height == pytest.approx(a.height)
        assert c.x0 > a.x1


def test_truth_outline_encloses_wall_cells(grid, walls):
    ax = plot_posterior(grid, blurred(walls), truth=walls).axes[0]
    path = by_gid(ax, "truth").get_path()
    assert (path.codes[0::2] == path.MOVETO).all() and (path.codes[1::2] == path.LINETO).all()
    segs = path.vertices.reshape(-1, 2, 2)
    # every outline edge lies on a cell boundary (half-integer coordinate) of the unit grid
    assert np.allclose(np.mod(segs[:, :, 0][segs[:, 0, 0] == segs[:, 1, 0]], 1.0), 0.5)
    # the outline's total length is the perimeter of the wall region
    wall = np.pad(walls > 0.5, 1)
    perimeter = (wall[1:, :] != wall[:-1, :]).sum() + (wall[:, 1:] != wall[:, :-1]).sum()
    length = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1).sum()
    assert length == pytest.approx(perimeter)


def test_plot_posterior_std_panel(grid, walls):
    post = blurred(walls)
    fig = plot_posterior(grid, post, std=True)
    assert len(fig.axes) == 4
    image = by_gid(fig.axes[1], "std")
    np.testing.assert_allclose(np.asarray(image.get_array()), np.sqrt(post * (1 - post)).T)
    assert image.get_clim() == (0.0, 0.5)
    assert image.colorbar.ax.get_ylim() == pytest.approx((0.0, 0.5))


def test_plot_posterior_path_on_each_map_panel(grid, walls):
    post = blurred(walls)
    path = np.array([[2.0, 3.0], [5.5, 3.0], [5.5, 8.25]])
    for std, maps in ((True, 2), (False, 1)):
        fig = plot_posterior_path(grid, post, path.ravel(), title="log", std=std)
        assert len(fig.axes) == 2 * maps  # the map panels and their colour bars
        assert fig.axes[0].get_title() == "log"
        for ax in fig.axes[:maps]:
            line = by_gid(ax, "sensor_path")
            np.testing.assert_array_equal(np.column_stack(line.get_data()), path)
        for ax in fig.axes[maps:]:  # not on the colour bars
            assert not [a for a in ax.get_children() if a.get_gid() == "sensor_path"]
    with pytest.raises(BayesmapError, match=r"path\[1\] is \[nan, 3.0\]"):
        plot_posterior_path(grid, post, [[2.0, 3.0], [np.nan, 3.0]])
    with pytest.raises(BayesmapError, match=r"got shape \(3,\)"):
        plot_posterior_path(grid, post, [1.0, 2.0, 3.0])


def test_metric_grid_labels_and_extent():
    grid = Grid((64, 48), resolution=0.1, origin=(-3.2, 5.0))
    post = np.full(grid.shape, 0.5)
    post[10, 40] = 0.9
    fig = plot_posterior(grid, post)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"
    assert grid.extent == pytest.approx((-3.2, 3.2, 5.0, 9.8))
    assert by_gid(ax, "posterior").get_extent() == pytest.approx(grid.extent)
    assert ax.get_xlim() == pytest.approx((-3.2, 3.2)) and ax.get_ylim() == pytest.approx((5.0, 9.8))
    # cell (10, 40) is the pixel in row 40, column 10 of the (transposed) image
    assert np.asarray(by_gid(ax, "posterior").get_array())[40, 10] == pytest.approx(0.9)
    assert plot_map(grid).axes[0].get_xlabel() == "x (m)"


def test_posterior_accepts_jax_arrays(grid, walls):
    import jax.numpy as jnp

    fig = plot_posterior(grid, jnp.asarray(blurred(walls), dtype=jnp.float32), truth=jnp.asarray(walls))
    assert np.asarray(by_gid(fig.axes[0], "posterior").get_array()).shape == (21, 21)


# ---------------------------------------------------------------------------------------------------------------
# The crop to the seen cells, the occupancy grid alone
# ---------------------------------------------------------------------------------------------------------------

# A log's grid sized for the laser's reach: 40 m x 30 m of 0.2 m cells, x from -20 to 20, y from -10 to 20.
LOG_GRID = Grid((200, 150), resolution=0.2, origin=(-20.0, -10.0))


def building():
    """``(posterior, seen)`` of a 10 m x 6 m building in the grid's lower left: walls (P = 0.95) round free cells
    (P = 0.02), seen cells the building and a metre beyond its left wall (x from -18 to -7 m, y from -9 to -3 m);
    the rest of the grid unseen at the prior 0.1."""
    post = np.full(LOG_GRID.shape, 0.1)
    seen = np.zeros(LOG_GRID.shape, dtype=bool)
    seen[10:65, 5:35] = True
    post[15:65, 5:35] = 0.95
    post[16:64, 6:34] = 0.02
    return post, seen


EXPECTED_CROP = (-19.5, -5.5, -10.0, -1.5)  # the seen box grown by 1.5 m, clipped at the grid's bottom (y = -10)


def test_occupancy_map_is_the_map_alone_cropped_to_the_seen_cells():
    post, seen = building()
    fig = plot_occupancy_map(LOG_GRID, post, seen=seen, title="occupancy grid")
    assert len(fig.axes) == 2  # the map and its colour bar, nothing else
    ax = fig.axes[0]
    assert (*ax.get_xlim(), *ax.get_ylim()) == pytest.approx(EXPECTED_CROP)
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)" and ax.get_title() == "occupancy grid"
    image = by_gid(ax, "posterior")  # the cells 2 to 72 along x, 0 to 42 along y cover the crop
    assert image.get_extent() == pytest.approx((-19.6, -5.4, -10.0, -1.4))
    np.testing.assert_array_equal(np.ma.getdata(image.get_array()), post[2:73, :43].T)
    np.testing.assert_array_equal(np.ma.getmaskarray(image.get_array()), ~seen[2:73, :43].T)  # unseen: neutral
    assert image.get_clim() == (0.0, 1.0)
    assert image.colorbar.ax is fig.axes[1] and image.colorbar.ax.get_ylabel() == "P(wall)"
    assert image.colorbar.ax.get_ylim() == pytest.approx((0.0, 1.0))
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["unseen cells"]
    # the colour bar is as tall as the map as drawn
    ax.apply_aspect()
    assert fig.axes[1].get_position().height == pytest.approx(ax.get_position().height)
    whole = plot_occupancy_map(LOG_GRID, post).axes[0]
    assert (*whole.get_xlim(), *whole.get_ylim()) == pytest.approx(LOG_GRID.extent)
    assert whole.get_legend() is None and whole.get_title() == ""
    assert not np.ma.is_masked(by_gid(whole, "posterior").get_array())


def test_posterior_path_is_cropped_and_drawn_above_the_map():
    post, seen = building()
    path = np.array([[-17.0, -8.0], [-10.0, -8.0], [-10.0, -4.0]])
    fig = plot_posterior_path(LOG_GRID, post, path, std=True, seen=seen)
    for ax, gid in zip(fig.axes[:2], ("posterior", "std")):
        assert (*ax.get_xlim(), *ax.get_ylim()) == pytest.approx(EXPECTED_CROP)
        line = by_gid(ax, "sensor_path")
        assert line.get_zorder() > by_gid(ax, gid).get_zorder()  # the path on top of the map
        assert line.get_alpha() < 1.0 and line.get_linewidth() < 1.0  # thin and see-through: never hides a wall
        np.testing.assert_array_equal(np.ma.getmaskarray(by_gid(ax, gid).get_array()), ~seen[2:73, :43].T)
    with pytest.raises(BayesmapError, match="seen has shape"):
        plot_posterior_path(LOG_GRID, post, path, seen=seen.T)


# ---------------------------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------------------------


def test_bad_posterior_shape_and_values(grid, walls):
    with pytest.raises(BayesmapError, match=r"\(21, 20\)"):
        plot_posterior(grid, np.full((21, 20), 0.5))
    with pytest.raises(BayesmapError, match=r"\(20, 21\)"):
        plot_posterior(grid, np.full((21, 20), 0.5).T)
    bad = blurred(walls)
    bad[3, 4] = 1.5
    with pytest.raises(BayesmapError, match=r"posterior\[3, 4\] is 1\.5"):
        plot_posterior(grid, bad)
    bad[3, 4] = np.nan
    with pytest.raises(BayesmapError, match=r"posterior\[3, 4\]"):
        plot_posterior(grid, bad)
    with pytest.raises(BayesmapError, match="truth has shape"):
        plot_posterior(grid, blurred(walls), truth=np.zeros((5, 5)))


def test_bad_scan_inputs(grid, walls, scan):
    a, r = scan
    with pytest.raises(BayesmapError, match=r"readings has shape \(99,\) but beam_angles has shape \(100,\)"):
        plot_map(grid, walls, POS, a, r[:99])
    with pytest.raises(BayesmapError, match=r"readings has shape \(99,\)"):
        plot_posterior(grid, blurred(walls), pos=POS, beam_angles=a, readings=r[:99])
    with pytest.raises(BayesmapError, match="without"):
        plot_map(grid, walls, POS, a)
    with pytest.raises(BayesmapError, match="sensor position"):
        plot_map(grid, walls, None, a, r)
    with pytest.raises(BayesmapError, match="pos"):
        plot_map(grid, walls, [1.0, 2.0, 3.0], a, r)
    with pytest.raises(BayesmapError, match=r"origins has shape \(3, 2\)"):
        plot_map(grid, walls, None, a, r, origins=np.zeros((3, 2)))
    with pytest.raises(BayesmapError, match=r"max_range_mask has shape \(4,\)"):
        plot_map(grid, walls, POS, a, r, max_range_mask=np.zeros(4, dtype=bool))
    with pytest.raises(BayesmapError, match=r"readings\[0\]"):
        plot_map(grid, walls, POS, a, -r)
    with pytest.raises(BayesmapError, match=r"walls has shape \(3, 3\)"):
        plot_map(grid, np.zeros((3, 3)))
    with pytest.raises(BayesmapError, match="Grid"):
        plot_map((21, 21), walls)



def test_plot_prior_samples(grid, walls):
    """One panel per sample, each with its walls (the wall cells of that sample), default titles give the fraction
    of walls; bad shapes and title counts are errors."""
    empty = np.zeros_like(walls)
    fig = plot_prior_samples(grid, np.stack([walls, empty, 1 - walls]), suptitle="prior")
    axes = fig.get_axes()
    assert len(axes) == 3
    assert axes[0].get_title() == f"sample 0: {walls.mean():.2f} walls"
    for ax, m in zip(axes, (walls, empty, 1 - walls)):
        found = [a for a in ax.get_children() if a.get_gid() == "walls"]
        assert len(found) == 1 and len(found[0].get_paths()) == int(m.sum())
    with pytest.raises(BayesmapError, match="samples"):
        plot_prior_samples(grid, walls)
    with pytest.raises(BayesmapError, match="titles"):
        plot_prior_samples(grid, np.stack([walls]), titles=["a", "b"])
