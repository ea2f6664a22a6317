"""Animations of a Gibbs chain: frames (PIL images), an animated GIF, and a self-contained offline HTML page.

A chain's ``samples`` is ``(num_sweeps, nx, ny)`` bool (``samples[t - 1]`` is the map after sweep ``t``), with the
grid conventions of :mod:`bayesmap.viz.common`: cell ``(i, j)`` has ``i`` along x and ``j`` along y, images are drawn
transposed with ``origin="lower"`` in world coordinates and equal aspect.

Each frame has two panels side by side: on the left the sample after sweep ``t`` (walls black, free cells white),
on the right the running mean of sweeps ``1..t`` (the Monte Carlo estimate of P(wall), grey scale 0 = white to
1 = black, the colour map of :func:`bayesmap.viz.maps.plot_posterior`), with the true walls outlined in red and the
sensor marked as a red dot when given. The figure is built and laid out once (Agg canvas, never ``pyplot``);
each frame only updates the two images' data (``AxesImage.set_data``) and the titles, redraws those on a saved
background and composites the fixed overlays (see :class:`ChainFigure`), so 100 frames of a 21 x 21 chain
render in about a second, whatever the number of wall edges outlined.

:func:`chain_gif` and :func:`chain_html` (or both at once, rendered once: :func:`chain_animation`) store the frames
with one shared palette (192 greys plus 64 colours): greys within one level of the rendered frame, only antialiased
edges of the red marks a few levels off. The HTML page itself is :func:`bayesmap.viz.player.player_page`.
"""

from __future__ import annotations

import math
import operator
from io import BytesIO

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from PIL import Image

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.viz.common import (
    SENSOR_COLOR,
    TRUTH_COLOR,
    check_cells,
    check_grid,
    check_point,
    draw_gridlines,
    draw_truth,
    image_interpolation,
    is_unit_grid,
)
from bayesmap.viz.player import player_page

__all__ = ["chain_animation", "chain_frames", "chain_gif", "chain_html", "frame_sweeps"]

DEFAULT_SIZE_PX = (600, 300)
DPI = 100
# Frames smaller than this (pixels) leave no room for the maps next to readable titles and tick labels.
MIN_SIZE_PX = (400, 200)
# Text and markers are sized for DEFAULT_SIZE_PX and scaled with the frame, within these factors.
MIN_TEXT_SCALE, MAX_TEXT_SCALE = 0.75, 2.5
DEFAULT_DURATION_MS = 120
DEFAULT_LAST_DURATION_MS = 1500
NUM_GREYS = 192  # of the 256 palette entries of GIF and HTML frames
CMAP = "Greys"  # as plot_posterior: 0 = white (free), 1 = black (wall)


# ---------------------------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------------------------


def _check_count(value, what: str) -> int:
    """A positive int (bools and non-integral numbers are refused)."""
    if isinstance(value, bool):
        raise BayesmapError(f"{what} must be an integer >= 1, got {value!r}")
    try:
        number = operator.index(value)
    except TypeError:
        if isinstance(value, float) and value.is_integer():
            number = int(value)
        else:
            raise BayesmapError(f"{what} must be an integer >= 1, got {value!r}") from None
    if number < 1:
        raise BayesmapError(f"{what} must be an integer >= 1, got {value!r}")
    return number


def _check_samples(samples, grid: Grid) -> np.ndarray:
    """``samples`` as a ``(T, nx, ny)`` bool array (numbers are walls where > 0.5)."""
    try:
        arr = np.asarray(samples)
    except Exception:  # noqa: BLE001 - anything numpy cannot turn into an array
        nx, ny = grid.shape
        raise BayesmapError(f"samples must be an array of shape (num_sweeps, {nx}, {ny})") from None
    if arr.ndim != 3:
        raise BayesmapError(
            f"samples has shape {arr.shape}, expected 3-D (num_sweeps, nx, ny) = (num_sweeps, {grid.shape[0]}, "
            f"{grid.shape[1]}): one map per sweep"
        )
    if arr.shape[1:] != grid.shape:
        raise BayesmapError(
            f"samples has maps of shape {arr.shape[1:]} (samples.shape = {arr.shape}), but the grid has shape "
            f"{grid.shape}"
        )
    if arr.shape[0] == 0:
        raise BayesmapError(f"samples is empty (shape {arr.shape}): the chain needs at least one sweep")
    if arr.dtype == bool:
        return arr
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise BayesmapError(f"samples must be bool (or 0/1 numbers), got dtype {arr.dtype}")
    bad = ~np.isfinite(arr)
    if bad.any():
        t, i, j = np.argwhere(bad)[0]
        raise BayesmapError(f"samples[{t}, {i}, {j}] is {arr[t, i, j]!r}: samples must be bool or finite 0/1 numbers")
    return arr > 0.5


def _check_size(size_px) -> tuple[int, int]:
    try:
        width, height = size_px
        width, height = operator.index(width), operator.index(height)
    except (TypeError, ValueError):
        raise BayesmapError(f"size_px must be two integers (width, height) in pixels, got {size_px!r}") from None
    if width < MIN_SIZE_PX[0] or height < MIN_SIZE_PX[1]:
        raise BayesmapError(
            f"size_px {size_px!r} is too small: frames need at least {MIN_SIZE_PX[0]} x {MIN_SIZE_PX[1]} pixels"
        )
    return int(width), int(height)


def frame_sweeps(num_sweeps: int, *, every: int = 1, max_frames: int = 100) -> np.ndarray:
    """The sweeps shown in an animation of a chain of ``num_sweeps`` sweeps.

    Sweeps ``1, 1 + s, 1 + 2 s, ...`` up to ``num_sweeps``, plus the last sweep ``num_sweeps`` if that stride
    misses it. The stride ``s`` is ``every``, widened just enough that there are at most ``max_frames`` frames
    (with ``max_frames == 1`` the only frame is the last sweep).

    Args:
        num_sweeps: ``T >= 1``, the length of the chain.
        every: show every ``every``-th sweep (>= 1).
        max_frames: at most this many frames (>= 1).

    Returns:
        ``(F,)`` int64, increasing 1-based sweep numbers, ``1 <= F <= max_frames``; the last is ``num_sweeps``.

    Raises:
        BayesmapError: if ``num_sweeps``, ``every`` or ``max_frames`` is not an integer >= 1 (names it).
    """
    total = _check_count(num_sweeps, "num_sweeps")
    every = _check_count(every, "every")
    max_frames = _check_count(max_frames, "max_frames")
    if max_frames == 1 or total == 1:
        return np.array([total], dtype=np.int64)
    stride = max(every, math.ceil((total - 1) / (max_frames - 1)))
    sweeps = np.arange(1, total + 1, stride, dtype=np.int64)
    if sweeps[-1] != total:
        sweeps = np.append(sweeps, np.int64(total))
    return sweeps


# ---------------------------------------------------------------------------------------------------------------
# The figure, built once
# ---------------------------------------------------------------------------------------------------------------


class ChainFigure:
    """The two-panel figure of a chain, built and laid out once.

    Rendering a frame costs two image draws, three texts and a numpy composite, whatever the size of the map:

    * ``background``: the pixels of everything that never changes (axes, ticks, labels, colour bar, legend),
      drawn once with the images hidden;
    * ``overlay``: the pixels of what lies on top of the images and never changes (grid lines, axes frame,
      true-wall outline, sensor), drawn once on a transparent canvas and kept as straight-alpha RGBA at the
      pixels it covers;
    * per frame (:meth:`render`): restore the background, draw the two images and the titles with their new
      data and text, grab the canvas and composite the overlay onto it (``out = over * a + under * (1 - a)``, the
      Agg blend, so the result matches a full redraw to within rounding).
    """

    def __init__(self, grid: Grid, truth, pos, size_px: tuple[int, int]):
        self.grid = grid
        width, height = size_px
        self.size_px = size_px
        fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI, layout="constrained")
        fig.get_layout_engine().set(w_pad=0.02, h_pad=0.02, wspace=0.04)
        self.canvas = FigureCanvasAgg(fig)
        self.fig = fig
        self.unit = "cells" if is_unit_grid(grid) else "m"
        k = min(width / DEFAULT_SIZE_PX[0], height / DEFAULT_SIZE_PX[1])
        k = min(max(k, MIN_TEXT_SCALE), MAX_TEXT_SCALE)  # scale of text and markers
        self.axes = fig.subplots(1, 2)
        self.images = []
        self.titles = []
        overlays = []
        for ax, gid in zip(self.axes, ("sample", "mean")):
            overlays += self._draw_panel(ax, gid, truth, pos, k)
        self.axes[0].set_ylabel(f"y ({self.unit})", fontsize=7 * k, labelpad=1)
        colorbar = self._draw_colorbar_and_legend(truth, pos, k)
        self.suptitle = fig.suptitle(" ", fontsize=9 * k)
        self._freeze_layout(colorbar)
        self._cache_layers(overlays)

    def _draw_panel(self, ax, gid: str, truth, pos, k: float) -> list:
        """One map panel: an empty image (gid ``gid``), its title, grid lines, true-wall outline and sensor, text
        and markers scaled by ``k``; returns the artists drawn over the image (the overlays), in drawing order."""
        grid = self.grid
        xmin, xmax, ymin, ymax = grid.extent
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6 * k, length=2 * k, pad=1)
        ax.set_xlabel(f"x ({self.unit})", fontsize=7 * k, labelpad=1)
        image = ax.imshow(
            np.zeros(grid.shape[::-1], dtype=np.float32),
            origin="lower",
            extent=grid.extent,
            cmap=CMAP,
            vmin=0.0,
            vmax=1.0,
            interpolation=image_interpolation(grid),
            zorder=1,
            gid=gid,
        )
        self.images.append(image)
        self.titles.append(ax.set_title(" ", fontsize=8 * k, pad=3))
        draw_gridlines(ax, grid, alpha=0.35)
        if truth is not None:
            draw_truth(ax, truth, grid)
            outline = next(a for a in ax.get_children() if a.get_gid() == "truth")
            outline.set_linewidth(outline.get_linewidth() * k)
        if pos is not None:
            ax.plot([pos[0]], [pos[1]], ls="none", marker="o", ms=5.5 * k, color=SENSOR_COLOR, mec="white",
                    mew=0.7 * k, zorder=6, gid="sensor")
        # the axes frame (spines) is drawn over the image too
        on_top = [a for a in ax.get_children() if a.get_gid() in ("gridlines", "truth", "sensor")]
        return sorted(on_top + list(ax.spines.values()), key=lambda a: a.get_zorder())

    def _draw_colorbar_and_legend(self, truth, pos, k: float):
        """The P(wall) colour bar of the right panel and the legend (true walls, sensor) below; returns the
        colour bar."""
        fig = self.fig
        colorbar = fig.colorbar(self.images[1], ax=self.axes[1], fraction=0.05, pad=0.02, aspect=25)
        colorbar.set_label("P(wall)", fontsize=7 * k, labelpad=1)
        colorbar.ax.tick_params(labelsize=6 * k, length=2 * k, pad=1)
        handles = []
        if truth is not None:
            handles.append(Line2D([], [], color=TRUTH_COLOR, lw=1.2, label="true walls"))
        if pos is not None:
            handles.append(
                Line2D([], [], ls="none", marker="o", ms=5 * k, color=SENSOR_COLOR, mec="white", mew=0.6 * k,
                       label="sensor")
            )
        if handles:
            fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=6 * k, frameon=False,
                       handlelength=1.4, borderpad=0.1, columnspacing=1.0)
        return colorbar

    def _cache_layers(self, overlays: list) -> None:
        """Render the fixed layers once: the background (everything but the images, titles and overlays) and the
        overlays alone on a transparent canvas, kept as straight-alpha RGBA where they cover pixels."""
        fig = self.fig
        dynamic = self.images + self.titles + [self.suptitle] + overlays
        for artist in dynamic:
            artist.set_animated(True)
        for image in self.images:  # Axes.draw draws animated images anyway: hide them
            image.set_visible(False)
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(fig.bbox)
        for image in self.images:
            image.set_visible(True)
        renderer = self.canvas.get_renderer()
        renderer.clear()
        for artist in overlays:
            fig.draw_artist(artist)
        layer = np.asarray(self.canvas.buffer_rgba())
        self.overlay_at = np.nonzero(layer[..., 3])
        covered = layer[self.overlay_at].astype(np.float32)
        self.overlay_alpha = covered[:, 3:4] / 255.0
        self.overlay_rgb = covered[:, :3] * self.overlay_alpha

    def _freeze_layout(self, colorbar) -> None:
        """Lay the figure out once (constrained layout, with the longest texts it will show), then freeze it: maps
        centred in their halves, the colour bar next to the right map and as tall as it, ticks spaced for the
        maps' size in pixels."""
        fig = self.fig
        self.set_texts(10**6, 10**6)
        fig.draw_without_rendering()
        slot = colorbar.ax.get_position(original=True)
        fig.set_layout_engine("none")
        width, height = self.size_px
        for ax in self.axes:
            ax.set_anchor("C")
            ax.apply_aspect()
            drawn = ax.get_position(original=False)
            steps = [1, 2, 5, 10] if self.unit == "cells" else [1, 2, 2.5, 5, 10]
            integer = self.unit == "cells"
            # about one tick per 40 px across and 25 px up, so narrow maps do not crowd their tick labels
            x_bins = max(2, int(drawn.width * width // 40))
            y_bins = max(2, int(drawn.height * height // 25))
            ax.xaxis.set_major_locator(MaxNLocator(x_bins, integer=integer, steps=steps))
            ax.yaxis.set_major_locator(MaxNLocator(y_bins, integer=integer, steps=steps))
        gap = 0.1 * DPI / width  # 0.1 inch
        colorbar.ax.set_position([drawn.x1 + gap, drawn.y0, slot.width, drawn.height])

    def set_texts(self, sweep: int, chain_length: int) -> None:
        self.suptitle.set_text(f"Gibbs chain: sweep {sweep} of {chain_length}")
        self.titles[0].set_text(f"sample after sweep {sweep}")
        self.titles[1].set_text(f"running mean of sweeps 1..{sweep}")

    def render(self, sample: np.ndarray, mean: np.ndarray, sweep: int, chain_length: int) -> Image.Image:
        """The frame for ``sample`` ``(nx, ny)`` and ``mean`` ``(nx, ny)`` as an RGB image of ``size_px``."""
        self.images[0].set_data(sample.T.astype(np.float32))
        self.images[1].set_data(mean.T.astype(np.float32))
        self.set_texts(sweep, chain_length)
        self.canvas.restore_region(self.background)
        for artist in self.images + self.titles + [self.suptitle]:
            self.fig.draw_artist(artist)
        rgb = np.asarray(self.canvas.buffer_rgba())[..., :3].copy()
        under = rgb[self.overlay_at].astype(np.float32)
        rgb[self.overlay_at] = np.rint(self.overlay_rgb + under * (1.0 - self.overlay_alpha)).astype(np.uint8)
        return Image.fromarray(rgb, mode="RGB")

    def cell_pixel(self, panel: int, i: int, j: int) -> tuple[int, int]:
        """Image pixel ``(column, row)`` (row 0 at the top) of the centre of cell ``(i, j)`` in panel 0 or 1."""
        x, y = self.grid.cell_centers()[i, j]
        px, py = self.axes[panel].transData.transform((x, y))
        return int(px), int(self.size_px[1] - py)


def _paletted(frames: list[Image.Image]) -> list[Image.Image]:
    """The RGB frames as palette images ("P") sharing one palette: 192 evenly spaced greys (maps, colour bar and
    text are neutral grey, so every grey is kept to within one level and white stays white) plus 64 colours for
    the red outline, the sensor and their antialiased edges (a median cut of the non-grey pixels of the first and
    last frame). Each pixel gets its nearest palette colour, computed exactly (Pillow's ``quantize(palette=...)``
    rounds colours to a coarser cube and turns some greys 3 levels darker). About half the bytes of RGB as PNG,
    and valid GIF frames; no dithering, so flat areas stay flat."""
    greys = np.repeat(np.rint(np.linspace(0.0, 255.0, NUM_GREYS)).astype(np.uint8)[:, None], 3, axis=1)
    pixels = np.concatenate([np.asarray(frames[0]).reshape(-1, 3), np.asarray(frames[-1]).reshape(-1, 3)])
    colourful = np.unique(pixels[~_is_grey(pixels)], axis=0)
    colours = np.zeros((0, 3), dtype=np.uint8)
    if len(colourful):
        strip = Image.fromarray(colourful[None, :, :], mode="RGB")
        reduced = strip.quantize(colors=256 - NUM_GREYS, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        used = sorted(set(np.asarray(reduced).ravel().tolist()))
        colours = np.asarray(reduced.getpalette()[: 3 * 256], dtype=np.uint8).reshape(-1, 3)[used]
    table = np.concatenate([greys, colours])
    table = np.concatenate([table, np.repeat(table[-1:], 256 - len(table), axis=0)])
    grey_index = _nearest(np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1), table)
    out = []
    for frame in frames:
        rgb = np.asarray(frame)
        index = grey_index[rgb[..., 0]]
        other = ~_is_grey(rgb)
        if other.any():
            unique, inverse = np.unique(rgb[other], axis=0, return_inverse=True)
            index[other] = _nearest(unique, table)[inverse.ravel()]
        image = Image.fromarray(index, mode="P")
        image.putpalette(table.ravel().tolist())
        out.append(image)
    return out


def _is_grey(rgb: np.ndarray) -> np.ndarray:
    return (rgb[..., 0] == rgb[..., 1]) & (rgb[..., 1] == rgb[..., 2])


def _nearest(colours: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Index ``(n,)`` uint8 of the nearest (Euclidean RGB) entry of ``table`` ``(256, 3)`` for each of ``colours``
    ``(n, 3)``."""
    diff = colours[:, None, :].astype(np.int32) - table[None, :, :].astype(np.int32)
    return np.argmin((diff * diff).sum(axis=-1), axis=1).astype(np.uint8)


# ---------------------------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------------------------


def chain_frames(
    grid,
    samples,
    *,
    truth=None,
    pos=None,
    every: int = 1,
    max_frames: int = 100,
    size_px=DEFAULT_SIZE_PX,
) -> list[Image.Image]:
    """One frame per shown sweep of a Gibbs chain: the sample (left) and the running mean of the samples (right).

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        samples: ``(T, nx, ny)`` bool (or 0/1 numbers; > 0.5 is a wall), ``samples[t - 1]`` the map after sweep
            ``t``; ``(nx, ny) == grid.shape``. NumPy or JAX arrays.
        truth: ``(nx, ny)`` true map; its walls (cells > 0.5) are outlined in red on both panels.
        pos: ``(2,)`` sensor position in world coordinates (meters; cells on the tutorial's unit grid), a red dot.
        every: show every ``every``-th sweep (>= 1); see :func:`frame_sweeps`.
        max_frames: at most this many frames (>= 1); the stride is widened to fit and the last sweep is always
            shown. See :func:`frame_sweeps`.
        size_px: ``(width, height)`` of every frame in pixels (rendered at 100 dpi), at least 400 x 200; text and
            markers scale with the frame.

    Returns:
        A list of ``F = len(frame_sweeps(T, every=every, max_frames=max_frames))`` RGB :class:`PIL.Image.Image`
        of size ``size_px``. Frame ``k`` shows sweep ``t = frame_sweeps(...)[k]``: on the left the sample after
        sweep ``t`` (walls black, free white), on the right the mean of ``samples[:t]`` (P(wall), grey scale from
        white = 0 to black = 1, with a colour bar), and the title "Gibbs chain: sweep t of T".

    Raises:
        BayesmapError: if ``grid`` is not a Grid; ``samples`` is not 3-D, its maps are not ``grid.shape``, it has
            no sweeps, or a value is not finite; ``truth`` does not have ``grid.shape``; ``pos`` is not two finite
            numbers; ``every`` or ``max_frames`` is not an integer >= 1; ``size_px`` is malformed or too small.
    """
    frames, _, _ = _render(grid, samples, truth=truth, pos=pos, every=every, max_frames=max_frames, size_px=size_px)
    return frames


def _render(
    grid, samples, *, truth=None, pos=None, every=1, max_frames=100, size_px=DEFAULT_SIZE_PX
) -> tuple[list[Image.Image], np.ndarray, int]:
    """:func:`chain_frames`, also returning the sweep of each frame ``(F,)`` and the chain length ``T``."""
    grid = check_grid(grid)
    walls = _check_samples(samples, grid)
    truth = None if truth is None else check_cells(truth, grid, "truth")
    pos = None if pos is None else check_point(pos, "pos")
    size = _check_size(size_px)
    total = walls.shape[0]
    sweeps = frame_sweeps(total, every=every, max_frames=max_frames)
    figure = ChainFigure(grid, truth, pos, size)
    frames = []
    running = np.zeros(grid.shape, dtype=np.float64)
    done = 0
    for sweep in sweeps:
        running += walls[done:sweep].sum(axis=0, dtype=np.float64)
        done = int(sweep)
        frames.append(figure.render(walls[sweep - 1], running / sweep, int(sweep), total))
    return frames, sweeps, total


def chain_gif(
    grid,
    samples,
    *,
    duration_ms: int = DEFAULT_DURATION_MS,
    last_duration_ms: int = DEFAULT_LAST_DURATION_MS,
    **kw,
) -> bytes:
    """An animated GIF of a Gibbs chain (looping forever), one GIF frame per frame of :func:`chain_frames`.

    Args:
        grid: the grid, as in :func:`chain_frames`.
        samples: the chain's maps, as in :func:`chain_frames`.
        duration_ms: how long each frame is shown, in milliseconds (>= 1).
        last_duration_ms: how long the last frame is shown before the loop restarts, in milliseconds (>= 1).
        **kw: ``truth``, ``pos``, ``every``, ``max_frames``, ``size_px``, passed to :func:`chain_frames`.

    Returns:
        The GIF file's bytes: ``F`` frames of ``size_px`` (``Image.open(BytesIO(data)).n_frames == F``).

    Raises:
        BayesmapError: as :func:`chain_frames`, or if a duration is not an integer >= 1 (names it).
    """
    duration = _check_count(duration_ms, "duration_ms")
    last = _check_count(last_duration_ms, "last_duration_ms")
    frames, _, _ = _render(grid, samples, **kw)
    return _gif_bytes(_paletted(frames), duration, last)


def _gif_bytes(paletted: list[Image.Image], duration: int, last: int) -> bytes:
    buffer = BytesIO()
    paletted[0].save(
        buffer,
        format="GIF",
        save_all=True,
        append_images=paletted[1:],
        duration=[duration] * (len(paletted) - 1) + [last],
        loop=0,
        disposal=1,
        optimize=False,
    )
    return buffer.getvalue()


def chain_html(
    grid,
    samples,
    *,
    title: str = "Gibbs chain",
    duration_ms: int = DEFAULT_DURATION_MS,
    **kw,
) -> str:
    """One self-contained, offline HTML page that steps through the frames of :func:`chain_frames`.

    The frames are embedded as base64 PNG data URIs (``data:image/png;base64,...``) in a JavaScript array, each
    exactly once; the page has no external resource or link (plain inline CSS and JavaScript). Elements:
    ``<img id="chain-frame">`` (the current frame), ``<input type="range" id="chain-slider">`` (frame index,
    ``0 .. F - 1``), ``<output id="chain-sweep">`` (the sweep number of the current frame), and
    ``<button id="chain-play">`` (play / pause; playing stops on the last frame). With focus on the page, the
    arrow keys step and the space bar plays and pauses.

    Args:
        grid: the grid, as in :func:`chain_frames`.
        samples: the chain's maps, as in :func:`chain_frames`.
        title: the page title and heading (plain text; HTML-escaped).
        duration_ms: milliseconds per frame while playing (>= 1).
        **kw: ``truth``, ``pos``, ``every``, ``max_frames``, ``size_px``, passed to :func:`chain_frames`.

    Returns:
        The HTML document as a str (roughly 5 to 20 kB per frame at the default size).

    Raises:
        BayesmapError: as :func:`chain_frames`, if ``title`` is not a str, or ``duration_ms`` is not an integer
            >= 1.
    """
    if not isinstance(title, str):
        raise BayesmapError(f"title must be a str, got {type(title).__name__}: {title!r}")
    delay = _check_count(duration_ms, "duration_ms")
    frames, sweeps, total = _render(grid, samples, **kw)
    return player_page(_paletted(frames), sweeps, total, title, delay)


def chain_animation(
    grid,
    samples,
    *,
    title: str = "Gibbs chain",
    duration_ms: int = DEFAULT_DURATION_MS,
    last_duration_ms: int = DEFAULT_LAST_DURATION_MS,
    **kw,
) -> tuple[bytes, str]:
    """Both :func:`chain_gif` and :func:`chain_html` of the same chain, rendering the frames once:
    ``(gif bytes, html str)``, each identical to what those functions return for these arguments.

    Raises:
        BayesmapError: as :func:`chain_gif` and :func:`chain_html`.
    """
    if not isinstance(title, str):
        raise BayesmapError(f"title must be a str, got {type(title).__name__}: {title!r}")
    duration = _check_count(duration_ms, "duration_ms")
    last = _check_count(last_duration_ms, "last_duration_ms")
    frames, sweeps, total = _render(grid, samples, **kw)
    paletted = _paletted(frames)
    return _gif_bytes(paletted, duration, last), player_page(paletted, sweeps, total, title, duration)
