"""Tests for bayesmap.viz.common: rendering and saving figures (whole or not at all), figures drawn in threads, and
the crop of a map to the cells the beams saw."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.viz.common import (
    CROP_MARGIN,
    FOCUS_COVERAGE,
    MAX_IMAGE_BLOCKS,
    crop_extent,
    draw_cell_image,
    draw_legend,
    new_figure,
    save_figure,
)
from bayesmap.viz.maps import plot_map, plot_posterior
from helpers import POS, blurred

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
# crop_extent
# ---------------------------------------------------------------------------------------------------------------

# A 10 m x 8 m grid of 0.1 m cells whose origin is (-2, 3): x from -2 to 8, y from 3 to 11.
METRIC = Grid((100, 80), resolution=0.1, origin=(-2.0, 3.0))


def seen_box(grid, i0, i1, j0, j1):
    """Cells ``i0 <= i < i1``, ``j0 <= j < j1`` seen, the rest not."""
    seen = np.zeros(grid.shape, dtype=bool)
    seen[i0:i1, j0:j1] = True
    return seen


def test_crop_is_the_seen_cells_bounding_box_plus_the_margin_clipped_to_the_grid():
    seen = seen_box(METRIC, 30, 50, 10, 20)  # x from 1.0 to 3.0 m, y from 4.0 to 5.0 m
    seen[35, 15] = False  # a hole inside the box changes nothing
    # the margin of 1.5 m reaches below the grid's bottom edge (y = 3): clipped there
    assert CROP_MARGIN == 1.5
    assert crop_extent(METRIC, seen) == pytest.approx((-0.5, 4.5, 3.0, 6.5))
    assert crop_extent(METRIC, seen, margin=0.0) == pytest.approx((1.0, 3.0, 4.0, 5.0))
    # a single stray cell far out stretches the box: the crop is the bounding box, nothing trimmed
    seen[99, 79] = True
    assert crop_extent(METRIC, seen) == pytest.approx((-0.5, 8.0, 3.0, 11.0))


def test_crop_without_seen_cells_is_the_whole_grid():
    assert crop_extent(METRIC, None) == METRIC.extent
    assert crop_extent(METRIC, np.zeros(METRIC.shape, dtype=bool)) == METRIC.extent
    assert crop_extent(METRIC, np.ones(METRIC.shape, dtype=bool)) == pytest.approx(METRIC.extent)


def test_the_crop_holds_the_central_endpoints_and_the_path_not_a_beam_through_a_door():
    """1,000 endpoints on a room's walls (x 1..3 m, y 4..5 m) and 5 of a beam through a door ending at the grid's far
    corner: the frame holds the room (the 0.5 % beyond the 99.5th percentile do not set it), the whole path even
    where it leaves the room, and never more than the seen cells."""
    assert FOCUS_COVERAGE == 0.99
    seen = seen_box(METRIC, 0, 100, 0, 80)  # every cell crossed, the door's beam included
    rng = np.random.default_rng(0)
    room = np.column_stack([rng.uniform(1.0, 3.0, 1000), rng.uniform(4.0, 5.0, 1000)])
    door = np.tile([7.9, 10.9], (5, 1))
    box = crop_extent(METRIC, seen, margin=0.0, focus=np.vstack([room, door]))
    assert box[0] == pytest.approx(1.0, abs=0.02) and box[1] == pytest.approx(3.0, abs=0.02)
    assert box[2] == pytest.approx(4.0, abs=0.02) and box[3] == pytest.approx(5.0, abs=0.02)
    # the door's beam is 0.5 % of the points: at 2 % it sets the frame again
    wide = crop_extent(METRIC, seen, margin=0.0, focus=np.vstack([room, np.tile(door, (4, 1))]))
    assert wide[1] == pytest.approx(7.9) and wide[3] == pytest.approx(10.9)
    path = np.array([[2.0, 4.5], [5.0, 4.5]])  # the robot drives out of the room to x = 5 m
    assert crop_extent(METRIC, seen, margin=0.0, focus=room, include=path)[1] == pytest.approx(5.0)
    # the frame never leaves the seen cells: a room the beams did not cross keeps the seen box
    small = seen_box(METRIC, 30, 50, 10, 20)
    assert crop_extent(METRIC, small, margin=0.0, focus=room + 3.0) == pytest.approx((1.0, 3.0, 4.0, 5.0))
    with pytest.raises(BayesmapError, match=r"focus must be \(N, 2\) finite world points"):
        crop_extent(METRIC, seen, focus=np.zeros((3, 3)))


def test_crop_refuses_a_bad_seen_or_margin():
    with pytest.raises(BayesmapError, match=r"seen has shape \(80, 100\), but the grid has shape \(100, 80\)"):
        crop_extent(METRIC, np.ones((80, 100), dtype=bool))
    with pytest.raises(BayesmapError, match="seen must be a bool array"):
        crop_extent(METRIC, np.ones(METRIC.shape))
    with pytest.raises(BayesmapError, match="margin must be >= 0"):
        crop_extent(METRIC, None, margin=-1.0)


def test_a_map_with_more_cells_than_pixels_keeps_its_one_cell_walls():
    """1000 x 200 cells of 5 cm: drawn in blocks of 4 x 4 cells (the fewest within MAX_IMAGE_BLOCKS per side), each
    as dark as its darkest seen cell, so a one-cell wall keeps its P(wall) of 0.9 (a mean would show 0.24)."""
    grid = Grid((1000, 200), resolution=0.05, origin=(0.0, 0.0))
    post = np.full(grid.shape, 0.02)
    post[:, 101] = 0.9  # a one-cell wall along x
    post[:, 170] = 0.7  # one no beam crossed: not drawn
    seen = np.zeros(grid.shape, dtype=bool)
    seen[:, :150] = True
    ax = new_figure((6.0, 2.0)).add_subplot()
    image = draw_cell_image(ax, grid, post, gid="posterior", seen=seen)
    assert 1000 / 4 <= MAX_IMAGE_BLOCKS < 1000 / 3  # so 4 x 4 blocks
    data = image.get_array()
    assert data.shape == (50, 250) and image.get_extent() == pytest.approx((0.0, 50.0, 0.0, 10.0))
    assert image.get_interpolation() == "nearest"
    np.testing.assert_allclose(data[25], 0.9)  # the block row of cells 100 to 103
    assert np.ma.getmaskarray(data)[:38].sum() == 0 and np.ma.getmaskarray(data)[38:].all()  # cells 148-151 seen
    np.testing.assert_allclose(np.ma.compressed(data[np.arange(50) != 25]), 0.02)  # the unseen wall is hidden


def test_a_legend_too_wide_for_its_axes_wraps_instead_of_shrinking_the_map():
    """Four long entries under a narrow map: fewer columns, so that the legend is no wider than the axes' slot (the
    constrained layout would otherwise shrink the map to make room for it); short ones stay on one row."""
    from matplotlib.lines import Line2D

    fig = new_figure((4.0, 6.0))
    ax = fig.add_subplot()
    long = [Line2D([], [], label=f"a rather long legend entry number {k}") for k in range(4)]
    renderer = fig.canvas.get_renderer()

    def rows():
        fig.draw_without_rendering()
        return len({round(t.get_window_extent(renderer).y0) for t in ax.get_legend().get_texts()})

    draw_legend(ax, long)
    assert rows() > 1
    assert ax.get_legend().get_window_extent(renderer).width <= ax.get_position().width * 4.0 * fig.dpi
    draw_legend(ax, [Line2D([], [], label=f"e{k}") for k in range(4)])
    assert rows() == 1
