"""Tests for bayesmap.viz.plots: what is drawn where (checked on the artists' data), validation, and saving."""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.image import AxesImage

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.ascii import tutorial_map
from bayesmap.viz.plots import (
    figure_bytes,
    plot_convergence,
    plot_importance,
    plot_map,
    plot_posterior,
    save_figure,
)
from bayesmap.geometry.raycast import angles, sensor_distances

POS = np.array([10.0, 10.0])


@pytest.fixture(scope="module")
def walls():
    return tutorial_map()


@pytest.fixture(scope="module")
def grid(walls):
    return Grid(shape=walls.shape)


@pytest.fixture(scope="module")
def scan(walls):
    a = np.asarray(angles(100), dtype=np.float64)
    r = np.asarray(sensor_distances(walls, POS, angles(100)), dtype=np.float64)
    return a, r


def blurred(walls):
    """A fake posterior: the true map blurred with a 3 x 3 binomial kernel, squeezed into [0.1, 0.9]."""
    out = np.asarray(walls, dtype=np.float64)
    kernel = np.array([1.0, 2.0, 1.0]) / 4
    for axis in (0, 1):
        out = np.apply_along_axis(lambda v: np.convolve(np.pad(v, 1, mode="edge"), kernel, mode="valid"), axis, out)
    return 0.1 + 0.8 * out


def by_gid(ax, gid):
    found = [a for a in ax.get_children() if a.get_gid() == gid]
    assert len(found) == 1, f"expected one artist with gid {gid!r}, found {len(found)}"
    return found[0]


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


# ---------------------------------------------------------------------------------------------------------------
# save_figure
# ---------------------------------------------------------------------------------------------------------------


def test_save_png_and_no_overwrite(tmp_path, grid, walls, scan):
    a, r = scan
    fig = plot_map(grid, walls, POS, a, r)
    path = tmp_path / "map.png"
    assert save_figure(fig, path) == path
    data = path.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 1000
    other = plot_posterior(grid, blurred(walls))
    with pytest.raises(BayesmapError, match="already exists"):
        save_figure(other, path)
    assert path.read_bytes() == data
    save_figure(other, path, overwrite=True)
    assert path.read_bytes() != data and path.read_bytes().startswith(b"\x89PNG")
    assert [p.name for p in tmp_path.iterdir()] == ["map.png"]  # no temporary files left


def test_save_svg(tmp_path, grid, walls):
    path = save_figure(plot_posterior(grid, blurred(walls), truth=walls), tmp_path / "post.SVG")
    text = path.read_text(encoding="utf-8")
    assert "<svg" in text[:2000]


def test_save_bad_suffix_and_folder(tmp_path, grid):
    fig = plot_map(grid)
    with pytest.raises(BayesmapError, match=r"'\.jpg'"):
        save_figure(fig, tmp_path / "map.jpg")
    with pytest.raises(BayesmapError, match="no suffix"):
        save_figure(fig, tmp_path / "map")
    with pytest.raises(BayesmapError, match="cannot write"):
        save_figure(fig, tmp_path / "missing" / "map.png")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------------------------
# Threads and speed
# ---------------------------------------------------------------------------------------------------------------


def test_plots_in_threads(tmp_path, grid, walls, scan):
    a, r = scan
    errors = []

    def work(k):
        try:
            fig = plot_posterior(grid, blurred(walls), truth=walls, pos=POS, beam_angles=a, readings=r)
            save_figure(fig, tmp_path / f"p{k}.png")
        except Exception as err:  # pragma: no cover - reported below
            errors.append(err)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert all((tmp_path / f"p{k}.png").read_bytes().startswith(b"\x89PNG") for k in range(4))




# ---------------------------------------------------------------------------------------------------------------
# plot_importance
# ---------------------------------------------------------------------------------------------------------------

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def ess_in_text(ax):
    """(ESS, N) read back from the text box."""
    match = re.match(r"ESS ([\d,.]+) of ([\d,]+) particles?", by_gid(ax, "importance-ess").get_text())
    assert match, by_gid(ax, "importance-ess").get_text()
    return float(match[1].replace(",", "")), int(match[2].replace(",", ""))


def test_importance_histogram_counts_the_finite_particles():
    rng = np.random.default_rng(3)
    raw = rng.normal(-500.0, 2.0, 300)  # unnormalized
    raw[[4, 50, 299]] = -np.inf
    ax = plot_importance(raw).axes[0]
    hist = by_gid(ax, "importance-histogram")
    counts, edges = hist.get_data().values, hist.get_data().edges
    assert counts.sum() == 297
    normalized = raw - (raw[np.isfinite(raw)].max() + np.log(np.exp(raw - raw[np.isfinite(raw)].max()).sum()))
    finite = normalized[np.isfinite(normalized)]
    assert edges[0] <= finite.min() and edges[-1] >= finite.max()
    # the bins hold the normalized (not the raw) log-weights: the same histogram for a shifted input
    shifted = by_gid(plot_importance(raw + 480.0).axes[0], "importance-histogram")
    np.testing.assert_array_equal(shifted.get_data().values, counts)
    assert ax.get_xlabel() == "normalized log-weight" and ax.get_ylabel() == "particles"
    assert ax.get_title() == "Importance sampling: normalized log-weights"
    text = by_gid(ax, "importance-ess").get_text()
    assert "3 with log-weight -inf" in text
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[0] == "297 particles (finite log-weight)" and labels[1].startswith("largest weight")


def test_importance_ess_of_two_equal_weights():
    ax = plot_importance([-3.0, -np.inf, -3.0, -np.inf, -np.inf]).axes[0]
    assert ess_in_text(ax) == (2.0, 5)
    text = by_gid(ax, "importance-ess").get_text()
    assert text == "ESS 2.0 of 5 particles\n3 with log-weight -inf (weight 0), not drawn"
    # both weights are 1/2: the largest normalized log-weight is log(1/2)
    np.testing.assert_allclose(by_gid(ax, "importance-max").get_xdata(), [np.log(0.5)] * 2)
    assert by_gid(ax, "importance-histogram").get_data().values.sum() == 2


def test_importance_ess_matches_the_formula_and_the_sampler():
    from bayesmap.inference.importance import effective_sample_size

    rng = np.random.default_rng(0)
    raw = rng.normal(0.0, 1.5, 2000)
    w = np.exp(raw - raw.max())
    w /= w.sum()
    expected = 1.0 / np.sum(w**2)
    ess, num = ess_in_text(plot_importance(raw).axes[0])
    assert num == 2000
    assert ess == pytest.approx(expected, abs=0.05)  # shown with one decimal
    assert float(effective_sample_size(raw)) == pytest.approx(expected, rel=1e-4)
    # a given ESS is shown as given
    assert ess_in_text(plot_importance(raw, ess=123.456).axes[0]) == (123.5, 2000)


def test_importance_one_dominant_weight():
    raw = np.concatenate([[700.0], 700.0 - np.linspace(800.0, 5000.0, 1999)])
    fig = plot_importance(raw)
    ax = fig.axes[0]
    np.testing.assert_allclose(by_gid(ax, "importance-max").get_xdata(), [0.0, 0.0], atol=1e-12)
    ess, num = ess_in_text(ax)
    assert (ess, num) == (1.0, 2000)
    assert by_gid(ax, "importance-ess").get_text() == "ESS 1.0 of 2,000 particles"
    assert by_gid(ax, "importance-histogram").get_data().values.sum() == 2000
    assert figure_bytes(fig, "png").startswith(PNG_MAGIC)


def test_importance_accepts_jax_and_given_axes():
    import jax.numpy as jnp

    fig = Figure()
    ax = fig.add_subplot(1, 2, 1)
    assert plot_importance(jnp.asarray([0.0, -1.0, -2.0], dtype=jnp.float32), ax=ax, title="mine") is fig
    assert ax.get_title() == "mine" and len(fig.axes) == 1
    assert ess_in_text(ax)[1] == 3


def test_importance_bad_inputs():
    with pytest.raises(BayesmapError, match="empty"):
        plot_importance([])
    with pytest.raises(BayesmapError, match=r"log_weights\[2\] is nan"):
        plot_importance([0.0, -1.0, np.nan, -2.0])
    with pytest.raises(BayesmapError, match=r"log_weights\[1\] is inf"):
        plot_importance([0.0, np.inf])
    with pytest.raises(BayesmapError, match=r"shape \(2, 3\)"):
        plot_importance(np.zeros((2, 3)))
    with pytest.raises(BayesmapError, match="-inf"):
        plot_importance([-np.inf, -np.inf])
    with pytest.raises(BayesmapError, match=r"ess is 7\.0.*between 1 and 3"):
        plot_importance([0.0, -1.0, -2.0], ess=7.0)
    with pytest.raises(BayesmapError, match="ess"):
        plot_importance([0.0, -1.0], ess=[1.0, 2.0])


# ---------------------------------------------------------------------------------------------------------------
# plot_convergence
# ---------------------------------------------------------------------------------------------------------------


def fake_chains(num_chains=3, num_sweeps=50, seed=0):
    """Log joints that start near -1e5 and settle near -300 after 5 sweeps; wrong cells from 80 down to 0-3."""
    rng = np.random.default_rng(seed)
    t = np.arange(num_sweeps)
    log_joints = -300.0 - 1e5 * np.exp(-2.0 * t) + rng.normal(0.0, 1.0, (num_chains, num_sweeps))
    wrong = np.round(80.0 * np.exp(-0.7 * t)).astype(int) + rng.integers(0, 4, (num_chains, num_sweeps))
    return log_joints, wrong


def lines_by_prefix(ax, prefix):
    return {line.get_gid(): line for line in ax.get_lines() if (line.get_gid() or "").startswith(prefix)}


def test_convergence_one_line_per_chain():
    log_joints, _ = fake_chains()
    fig = plot_convergence(log_joints, truth_log_joint=-301.5)
    assert len(fig.axes) == 1
    ax = fig.axes[0]
    chains = lines_by_prefix(ax, "chain-")
    assert sorted(chains) == ["chain-0", "chain-1", "chain-2"]
    for k in range(3):
        np.testing.assert_array_equal(chains[f"chain-{k}"].get_xdata(), np.arange(1, 51))
        np.testing.assert_array_equal(chains[f"chain-{k}"].get_ydata(), log_joints[k])
    np.testing.assert_array_equal(by_gid(ax, "truth-log-joint").get_ydata(), [-301.5, -301.5])
    assert ax.get_xlabel() == "sweep" and ax.get_title() == "Convergence"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["chain 0", "chain 1", "chain 2", "true map"]
    # a few chains differ in colour and in something that survives grayscale (line style or marker)
    styles = {(line.get_linestyle(), line.get_marker()) for line in chains.values()}
    assert len({line.get_color() for line in chains.values()}) == 3 and len(styles) == 3
    assert not [c for c in ax.get_children() if c.get_gid() == "burn-in"]


def test_convergence_y_range_ignores_the_early_sweeps():
    log_joints, _ = fake_chains()
    ax = plot_convergence(log_joints).axes[0]
    lo, hi = ax.get_ylim()
    converged = log_joints[:, 10:]
    assert lo <= converged.min() and hi >= converged.max()
    assert lo > -400.0  # the -1e5 of sweep 1 does not squash the converged part
    note = by_gid(ax, "off-scale").get_text()
    assert "below the axis" in note and "sweep 1" in note and f"{log_joints.min():.4g}" in note
    # the true map's log joint is always inside the range
    lo, hi = plot_convergence(log_joints, truth_log_joint=-250.0).axes[0].get_ylim()
    assert lo < -250.0 < hi
    # nothing off the scale: no note
    flat = plot_convergence(-300.0 + np.zeros((2, 10))).axes[0]
    assert not [c for c in flat.get_children() if c.get_gid() == "off-scale"]
    assert flat.get_ylim()[0] < -300.0 < flat.get_ylim()[1]


def test_convergence_wrong_cells_panel_and_burn_in():
    log_joints, wrong = fake_chains()
    fig = plot_convergence(log_joints, wrong, burn_in=20, truth_log_joint=-300.0, title="4 chains")
    assert len(fig.axes) == 2
    top, bottom = fig.axes
    assert top.get_shared_x_axes().joined(top, bottom)
    assert top.get_title() == "4 chains"
    assert bottom.get_ylabel() == "wrong visible cells" and bottom.get_xlabel() == "sweep"
    rows = lines_by_prefix(bottom, "wrong-")
    assert sorted(rows) == ["wrong-0", "wrong-1", "wrong-2"]
    for k in range(3):
        np.testing.assert_array_equal(rows[f"wrong-{k}"].get_xdata(), np.arange(1, 51))
        np.testing.assert_array_equal(rows[f"wrong-{k}"].get_ydata(), wrong[k])
        # the same chain has the same style in both panels
        assert rows[f"wrong-{k}"].get_color() == by_gid(top, f"chain-{k}").get_color()
    accuracy = by_gid(bottom, "tutorial-accuracy")
    np.testing.assert_array_equal(accuracy.get_ydata(), [2, 2])
    assert accuracy.get_linestyle() == ":" and accuracy.get_label() == "2 wrong (tutorial's accuracy)"
    assert [t.get_text() for t in bottom.get_legend().get_texts()] == ["2 wrong (tutorial's accuracy)"]
    for ax in (top, bottom):
        line = by_gid(ax, "burn-in")
        np.testing.assert_array_equal(line.get_xdata(), [20.5, 20.5])  # between sweep 20 (dropped) and 21 (kept)
        assert line.get_linestyle() == "--"
    assert "burn-in (20 sweeps dropped)" in [t.get_text() for t in top.get_legend().get_texts()]
    # 80 wrong cells at the start: symmetric-log, with 0 and 2 still on the axis
    assert bottom.get_yscale() == "symlog"
    assert {0, 2} <= set(bottom.get_yticks()) and bottom.get_ylim()[1] >= wrong.max()
    assert figure_bytes(fig, "png").startswith(PNG_MAGIC)


def test_convergence_single_chain_and_small_counts():
    log_joints, wrong = fake_chains(num_chains=1, num_sweeps=8)
    fig = plot_convergence(log_joints[0], np.minimum(wrong[0], 9))
    top, bottom = fig.axes
    assert list(lines_by_prefix(top, "chain-")) == ["chain-0"]
    np.testing.assert_array_equal(by_gid(top, "chain-0").get_xdata(), np.arange(1, 9))
    assert [t.get_text() for t in top.get_legend().get_texts()] == ["chain"]
    assert bottom.get_yscale() == "linear"


def test_convergence_many_chains_share_one_legend_entry():
    log_joints, wrong = fake_chains(num_chains=10, num_sweeps=30)
    top = plot_convergence(log_joints, wrong).axes[0]
    chains = lines_by_prefix(top, "chain-")
    assert len(chains) == 10
    assert len({tuple(line.get_color()) for line in chains.values()}) == 10
    labels = [t.get_text() for t in top.get_legend().get_texts()]
    assert len(labels) == 1 and labels[0].startswith("10 chains")


def test_convergence_into_given_axes():
    log_joints, wrong = fake_chains(num_chains=2, num_sweeps=12)
    fig = Figure()
    ax = fig.add_subplot()
    assert plot_convergence(log_joints, ax=ax) is fig and len(fig.axes) == 1
    fig2 = Figure()
    pair = fig2.subplots(2, 1)
    assert plot_convergence(log_joints, wrong, ax=pair) is fig2
    assert len(lines_by_prefix(pair[1], "wrong-")) == 2
    with pytest.raises(BayesmapError, match="pair of Axes"):
        plot_convergence(log_joints, wrong, ax=ax)


def test_convergence_bad_inputs():
    log_joints, wrong = fake_chains(num_chains=2, num_sweeps=12)
    with pytest.raises(BayesmapError, match="empty"):
        plot_convergence([])
    with pytest.raises(BayesmapError, match="empty"):
        plot_convergence(np.zeros((3, 0)))
    bad = log_joints.copy()
    bad[1, 3] = np.nan
    with pytest.raises(BayesmapError, match=r"log_joints\[1, 3\] is nan"):
        plot_convergence(bad)
    with pytest.raises(BayesmapError, match=r"log_joints\[4\] is nan"):
        plot_convergence([0.0, 1.0, 2.0, 3.0, np.nan])
    with pytest.raises(BayesmapError, match=r"shape \(2, 2, 2\)"):
        plot_convergence(np.zeros((2, 2, 2)))
    with pytest.raises(BayesmapError, match=r"wrong_cells has shape \(2, 11\) but log_joints has shape \(2, 12\)"):
        plot_convergence(log_joints, wrong[:, :11])
    with pytest.raises(BayesmapError, match=r"wrong_cells has shape \(12,\)"):
        plot_convergence(log_joints, wrong[0])
    with pytest.raises(BayesmapError, match=r"wrong_cells\[0, 5\] is -1\.0"):
        plot_convergence(log_joints, np.where(np.arange(12) == 5, -1, wrong))
    with pytest.raises(BayesmapError, match=r"wrong_cells\[1, 7\] is 2\.5"):
        plot_convergence(log_joints, np.where((np.arange(2)[:, None] == 1) & (np.arange(12) == 7), 2.5, wrong))
    with pytest.raises(BayesmapError, match=r"wrong_cells\[1, 2\] is nan"):
        plot_convergence(log_joints, np.where((np.arange(2)[:, None] == 1) & (np.arange(12) == 2), np.nan, wrong))
    with pytest.raises(BayesmapError, match=r"burn_in .* 0 and 11.*got 12"):
        plot_convergence(log_joints, burn_in=12)
    with pytest.raises(BayesmapError, match="got -1"):
        plot_convergence(log_joints, burn_in=-1)
    with pytest.raises(BayesmapError, match="truth_log_joint"):
        plot_convergence(log_joints, truth_log_joint=np.nan)
