"""Tests for bayesmap.viz.animation: which sweeps become frames, what a frame shows where (pixel colours at cell
centres), the GIF and the offline HTML page, and validation."""

from __future__ import annotations

import base64
import re
from io import BytesIO

import matplotlib
import numpy as np
import pytest
from PIL import Image

import bayesmap.viz.animation as animation
from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.viz.animation import ChainFigure, chain_frames, chain_gif, chain_html, frame_sweeps

GRID = Grid((5, 6))
SIZE = (600, 300)
A, B, C, D = (0, 0), (4, 5), (2, 3), (1, 4)  # cells


def grey_of(p: float) -> np.ndarray:
    """The RGB (0-255) that the "Greys" colour map gives to probability ``p``."""
    return np.rint(np.asarray(matplotlib.colormaps["Greys"](p)[:3]) * 255)


def two_sweeps() -> np.ndarray:
    """Sweep 1: walls at A and C. Sweep 2: walls at B and C. (D is never a wall.)"""
    samples = np.zeros((2,) + GRID.shape, dtype=bool)
    samples[0][A] = samples[0][C] = True
    samples[1][B] = samples[1][C] = True
    return samples


def random_samples(num_sweeps: int, seed: int = 0, grid: Grid = GRID) -> np.ndarray:
    return np.random.default_rng(seed).random((num_sweeps,) + grid.shape) < 0.3


def red_pixels(frame: Image.Image) -> int:
    rgb = np.asarray(frame).astype(int)
    return int(((rgb[..., 0] > 150) & (rgb[..., 1] < 90) & (rgb[..., 2] < 90)).sum())


# ---------------------------------------------------------------------------------------------------------------
# frame_sweeps
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "total, every, max_frames, expected",
    [
        (1, 1, 100, [1]),
        (10, 1, 100, list(range(1, 11))),
        (10, 3, 100, [1, 4, 7, 10]),
        (11, 3, 100, [1, 4, 7, 10, 11]),  # the last sweep is added when the stride misses it
        (7, 1, 3, [1, 4, 7]),
        (10, 1, 4, [1, 4, 7, 10]),
        (10, 1, 1, [10]),
        (5, 10, 100, [1, 5]),
    ],
)
def test_frame_sweeps_examples(total, every, max_frames, expected):
    assert frame_sweeps(total, every=every, max_frames=max_frames).tolist() == expected


def test_frame_sweeps_invariants():
    for total in range(1, 41):
        for every in range(1, 6):
            for max_frames in range(1, 13):
                sweeps = frame_sweeps(total, every=every, max_frames=max_frames)
                assert 1 <= len(sweeps) <= max_frames
                assert sweeps[-1] == total
                assert np.all(np.diff(sweeps) > 0) and sweeps[0] >= 1
                if max_frames > 1:
                    assert sweeps[0] == 1
                fits = -(-(total - 1) // every) + 1 <= max_frames
                if fits and total > 1:  # no subsampling needed beyond `every`: the stride is exactly `every`
                    assert np.all(np.diff(sweeps)[:-1] == every) and np.diff(sweeps)[-1] <= every


# ---------------------------------------------------------------------------------------------------------------
# chain_frames: what is drawn where
# ---------------------------------------------------------------------------------------------------------------


def test_frames_count_size_and_mode():
    frames = chain_frames(GRID, random_samples(9), every=2, max_frames=4)
    assert len(frames) == len(frame_sweeps(9, every=2, max_frames=4)) == 4  # sweeps 1, 4, 7, 9
    assert all(isinstance(f, Image.Image) and f.mode == "RGB" and f.size == SIZE for f in frames)
    small = chain_frames(GRID, random_samples(2), size_px=(400, 200))
    assert [f.size for f in small] == [(400, 200)] * 2


def test_left_panel_is_the_sample_and_right_panel_the_running_mean():
    frames = chain_frames(GRID, two_sweeps())
    layout = ChainFigure(GRID, None, None, SIZE)  # same grid, size, no truth / pos: the frames' layout

    def colour(frame, panel, cell):
        col, row = layout.cell_pixel(panel, *cell)
        return np.asarray(frames[frame])[row, col].astype(int)

    black, white, half = grey_of(1.0), grey_of(0.0), grey_of(0.5)
    assert np.array_equal(white, [255, 255, 255]) and black.max() < 10
    # left: the sample after each sweep
    for frame, walls, free in ((0, [A, C], [B, D]), (1, [B, C], [A, D])):
        for cell in walls:
            assert np.abs(colour(frame, 0, cell) - black).max() <= 2, (frame, cell)
        for cell in free:
            assert np.abs(colour(frame, 0, cell) - white).max() <= 2, (frame, cell)
    # right: mean of sweeps 1..t
    expected = {0: {A: 1.0, B: 0.0, C: 1.0, D: 0.0}, 1: {A: 0.5, B: 0.5, C: 1.0, D: 0.0}}
    for frame, cells in expected.items():
        for cell, p in cells.items():
            assert np.abs(colour(frame, 1, cell) - grey_of(p)).max() <= 2, (frame, cell, p)
    assert not np.array_equal(half, white) and not np.array_equal(half, black)


def test_frames_of_different_samples_differ_in_the_maps():
    frames = chain_frames(GRID, two_sweeps())
    layout = ChainFigure(GRID, None, None, SIZE)
    x0, _ = layout.cell_pixel(0, 0, 0)
    x1, _ = layout.cell_pixel(0, GRID.shape[0] - 1, 0)
    _, y_top = layout.cell_pixel(0, 0, GRID.shape[1] - 1)
    _, y_bottom = layout.cell_pixel(0, 0, 0)
    left = [np.asarray(f)[y_top : y_bottom + 1, x0 : x1 + 1] for f in frames]
    assert not np.array_equal(left[0], left[1])


def test_truth_outline_and_sensor_are_drawn_in_red():
    samples = random_samples(3)
    truth = np.zeros(GRID.shape)
    truth[1:4, 2:5] = 1
    plain = chain_frames(GRID, samples)
    with_truth = chain_frames(GRID, samples, truth=truth)
    with_pos = chain_frames(GRID, samples, pos=(2.0, 2.5))
    assert red_pixels(plain[-1]) == 0
    assert red_pixels(with_truth[-1]) > 200  # two outlines (+ legend)
    assert red_pixels(with_pos[-1]) > 20
    # the outline is the same in every frame: it does not depend on the samples
    assert all(red_pixels(f) == red_pixels(with_truth[0]) for f in with_truth)


def test_blitted_frame_matches_a_full_redraw():
    """The fast path (saved background, images redrawn, overlays composited) gives the pixels of a full draw."""
    rng = np.random.default_rng(3)
    truth = rng.random(GRID.shape) < 0.3
    figure = ChainFigure(GRID, truth, np.array([2.0, 2.5]), SIZE)
    fast = np.asarray(figure.render(rng.random(GRID.shape) < 0.5, rng.random(GRID.shape), 4, 9)).astype(int)
    for artist in figure.fig.findobj():
        artist.set_animated(False)
    figure.canvas.draw()
    full = np.asarray(figure.canvas.buffer_rgba())[..., :3].astype(int)
    assert np.abs(fast - full).max() <= 3


def test_figure_is_built_once_per_chain(monkeypatch):
    built = []
    real = animation.Figure

    def counting_figure(*args, **kwargs):
        built.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(animation, "Figure", counting_figure)
    frames = chain_frames(GRID, random_samples(8))
    assert len(frames) == 8 and len(built) == 1


def test_numeric_samples_are_accepted():
    samples = two_sweeps()
    as_bool = chain_frames(GRID, samples)
    as_float = chain_frames(GRID, samples.astype(np.float32))
    assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(as_bool, as_float))


def test_metric_grid_renders():
    grid = Grid((7, 4), resolution=0.25, origin=(-3.0, 1.0))
    frames = chain_frames(grid, random_samples(3, grid=grid), truth=np.eye(7, 4), pos=(-2.0, 1.5))
    assert len(frames) == 3 and frames[0].size == SIZE


# ---------------------------------------------------------------------------------------------------------------
# GIF
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("total, kw, count", [(7, {"max_frames": 3}, 3), (10, {"every": 4}, 4), (1, {}, 1)])
def test_gif_frames(total, kw, count):
    data = chain_gif(GRID, random_samples(total), duration_ms=80, last_duration_ms=900, **kw)
    gif = Image.open(BytesIO(data))
    assert gif.format == "GIF"
    assert gif.n_frames == count == len(frame_sweeps(total, **kw))
    assert gif.size == SIZE
    durations = []
    for k in range(gif.n_frames):
        gif.seek(k)
        durations.append(gif.info["duration"])
    assert durations == [80] * (count - 1) + [900]
    if count > 1:
        assert gif.info["loop"] == 0


def test_gif_frames_keep_the_rendered_colours():
    samples = random_samples(4)
    frames = chain_frames(GRID, samples, truth=samples[0])
    gif = Image.open(BytesIO(chain_gif(GRID, samples, truth=samples[0])))
    for k, frame in enumerate(frames):
        gif.seek(k)
        decoded = np.asarray(gif.convert("RGB")).astype(int)
        rendered = np.asarray(frame).astype(int)
        diff = np.abs(decoded - rendered).max(axis=-1)
        grey = (rendered[..., 0] == rendered[..., 1]) & (rendered[..., 1] == rendered[..., 2])
        assert diff[grey].max() <= 1  # maps, text, colour bar: greys kept (white stays white)
        assert (diff > 4).mean() < 0.002  # only a few antialiased red edge pixels move more


# ---------------------------------------------------------------------------------------------------------------
# HTML
# ---------------------------------------------------------------------------------------------------------------


def test_html_is_self_contained_with_one_data_uri_per_frame():
    total, kw = 9, {"every": 3}
    sweeps = frame_sweeps(total, **kw)
    page = chain_html(GRID, random_samples(total), title="Chain <b>&</b> \"map\"", truth=random_samples(1)[0],
                      pos=(1, 1), **kw)
    uris = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert page.count("data:image/png;base64,") == len(uris) == len(sweeps) == 4
    for payload in uris:
        frame = Image.open(BytesIO(base64.b64decode(payload)))
        assert frame.format == "PNG" and frame.size == SIZE
    # no external resource anywhere
    without_data = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "DATA", page)
    for needle in ("http://", "https://", "//cdn", "<script src", "<link", "@import", "url("):
        assert needle not in without_data.lower(), needle
    for attribute in re.findall(r"\b(?:src|href)\s*=\s*[\"']([^\"']*)", page):
        assert attribute.startswith("data:"), attribute
    # controls
    slider = re.search(r"<input[^>]*id=\"chain-slider\"[^>]*>", page).group(0)
    assert 'type="range"' in slider and 'min="0"' in slider and f'max="{len(sweeps) - 1}"' in slider
    for element in ('<img id="chain-frame"', 'id="chain-sweep"', '<button id="chain-play"'):
        assert element in page
    assert f"var sweeps = {sweeps.tolist()};" in page
    # the title is escaped
    assert "Chain &lt;b&gt;&amp;&lt;/b&gt; &quot;map&quot;" in page
    assert "<b>" not in page


def test_html_single_frame():
    page = chain_html(GRID, random_samples(5), max_frames=1)
    assert page.count("data:image/png;base64,") == 1
    assert 'max="0"' in page and "var sweeps = [5];" in page


# ---------------------------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "samples, kw, message",
    [
        (np.zeros((5, 6), dtype=bool), {}, r"\(5, 6\).*3-D"),
        (np.zeros((2, 1, 5, 6), dtype=bool), {}, r"\(2, 1, 5, 6\).*3-D"),
        (np.zeros((3, 6, 5), dtype=bool), {}, r"\(6, 5\).*\(5, 6\)"),
        (np.zeros((0, 5, 6), dtype=bool), {}, r"empty.*\(0, 5, 6\)"),
        (np.full((2, 5, 6), np.nan), {}, r"samples\[0, 0, 0\] is nan"),
        (np.full((2, 5, 6), "x"), {}, r"dtype"),
        (np.zeros((2, 5, 6), dtype=bool), {"every": 0}, r"every .* got 0"),
        (np.zeros((2, 5, 6), dtype=bool), {"every": 1.5}, r"every .* got 1.5"),
        (np.zeros((2, 5, 6), dtype=bool), {"max_frames": 0}, r"max_frames .* got 0"),
        (np.zeros((2, 5, 6), dtype=bool), {"max_frames": -3}, r"max_frames .* got -3"),
        (np.zeros((2, 5, 6), dtype=bool), {"truth": np.zeros((6, 5))}, r"truth has shape \(6, 5\)"),
        (np.zeros((2, 5, 6), dtype=bool), {"pos": (1.0,)}, r"pos .*\(1.0,\)"),
        (np.zeros((2, 5, 6), dtype=bool), {"size_px": (100, 50)}, r"size_px \(100, 50\)"),
        (np.zeros((2, 5, 6), dtype=bool), {"size_px": "big"}, r"size_px .*'big'"),
    ],
)
@pytest.mark.parametrize("function", [chain_frames, chain_gif, chain_html])
def test_bad_inputs_raise(function, samples, kw, message):
    with pytest.raises(BayesmapError, match=message):
        function(GRID, samples, **kw)


def test_bad_grid_title_and_durations_raise():
    samples = np.zeros((2, 5, 6), dtype=bool)
    with pytest.raises(BayesmapError, match="Grid, got tuple"):
        chain_frames((5, 6), samples)
    with pytest.raises(BayesmapError, match="title must be a str, got int"):
        chain_html(GRID, samples, title=3)
    with pytest.raises(BayesmapError, match="duration_ms .* got 0"):
        chain_gif(GRID, samples, duration_ms=0)
    with pytest.raises(BayesmapError, match="last_duration_ms .* got -1"):
        chain_gif(GRID, samples, last_duration_ms=-1)
    with pytest.raises(BayesmapError, match="duration_ms .* got 0"):
        chain_html(GRID, samples, duration_ms=0)
    with pytest.raises(BayesmapError, match="num_sweeps .* got 0"):
        frame_sweeps(0)
    with pytest.raises(TypeError):
        chain_gif(GRID, samples, colour="red")  # unknown options are not swallowed


def test_chain_animation_is_gif_and_html_rendered_once(monkeypatch):
    """``chain_animation`` returns exactly ``chain_gif`` and ``chain_html`` of the same arguments, from one render."""
    grid = Grid((5, 6))
    rng = np.random.default_rng(2)
    samples = rng.random((7, 5, 6)) < 0.4
    kw = dict(truth=samples[0], pos=(1.0, 2.0), max_frames=4)
    gif, page = animation.chain_animation(grid, samples, title="t <1>", **kw)
    assert gif == animation.chain_gif(grid, samples, **kw)
    assert page == animation.chain_html(grid, samples, title="t <1>", **kw)
    calls = []
    render = animation._render
    monkeypatch.setattr(animation, "_render", lambda *a, **k: calls.append(1) or render(*a, **k))
    animation.chain_animation(grid, samples, **kw)
    assert len(calls) == 1
