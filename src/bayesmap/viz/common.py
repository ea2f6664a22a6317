"""What every figure shares: validation of grids and per-cell arrays, the map-drawing helpers (axes in world
coordinates, grid lines, true walls, their outline, the legend) and the output (:func:`figure_bytes`,
:func:`save_figure`).

Everything is drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas (never ``pyplot``), so it works
headless, in threads and in tests. :func:`save_figure` writes a figure as PNG or SVG, whole or not at all.

Conventions: ``walls[i, j]`` / ``posterior[i, j]`` is cell ``(i, j)`` with ``i`` along x and ``j`` along y, so
images are drawn transposed (``imshow(P.T, origin="lower", extent=grid.extent)``): x horizontal, y vertical, in
world coordinates. Axis labels say "cells" on the tutorial's unit grid (resolution 1, origin ``(-0.5, -0.5)``)
and "m" otherwise.

The figures themselves are in :mod:`bayesmap.viz.maps` (the map, the scan, the posterior) and
:mod:`bayesmap.viz.diagnostics` (importance weights, convergence of Gibbs chains); :mod:`bayesmap.viz.animation`
draws the chain's frames with the same helpers.
"""

from __future__ import annotations

from io import BytesIO
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import PathPatch, Rectangle
from matplotlib.path import Path as MplPath
from matplotlib.ticker import MaxNLocator

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.files import write_atomic

__all__ = [
    "check_cells",
    "check_grid",
    "check_point",
    "draw_gridlines",
    "draw_legend",
    "draw_truth",
    "draw_walls",
    "figure_bytes",
    "image_interpolation",
    "is_unit_grid",
    "new_figure",
    "save_figure",
    "setup_map_axes",
]

# Grid lines are drawn when neither side of the grid has more cells than this.
MAX_GRIDLINE_CELLS = 60
# Above this many wall cells, walls are drawn as one image plus an outline instead of one rectangle per cell.
MAX_WALL_PATCHES = 2000
# Images with at most this many cells per side are drawn with "nearest" (crisp cells); larger ones are
# antialiased so that one-cell walls do not vanish when the image is downsampled to screen pixels.
MAX_NEAREST_CELLS = 256

WALL_COLOR = "#2b2b2b"
WALL_EDGE_COLOR = "#8c8c8c"
TRUTH_COLOR = "#d62728"
SENSOR_COLOR = "#e31a1c"
GRIDLINE_COLOR = "#c8c8c8"

SAVE_FORMATS = {".png": "png", ".svg": "svg"}


# ---------------------------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------------------------


def check_grid(grid) -> Grid:
    """``grid`` itself, checked to be a :class:`~bayesmap.geometry.grid.Grid`.

    Raises:
        BayesmapError: if it is anything else (names its type).
    """
    if not isinstance(grid, Grid):
        raise BayesmapError(f"grid must be a bayesmap.geometry.grid.Grid, got {type(grid).__name__}")
    return grid


def check_cells(values, grid: Grid, what: str, unit_interval: bool = False) -> np.ndarray:
    """A per-cell array of shape ``grid.shape`` as finite float64 (in [0, 1] if ``unit_interval``, then clipped
    to it).

    Args:
        values: ``(nx, ny)`` numbers, one per cell (NumPy, JAX or nested lists).
        grid: the grid whose ``shape`` the array must have.
        what: the array's name in error messages.
        unit_interval: require probabilities in [0, 1] (with a tolerance of 1e-6).

    Raises:
        BayesmapError: if the shape is not ``grid.shape``, or a value is not finite (or outside [0, 1]); names
            the first offending cell and its value.
    """
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError(f"{what} must be an array of numbers of shape {grid.shape}") from None
    if arr.shape != grid.shape:
        raise BayesmapError(f"{what} has shape {arr.shape}, but the grid has shape {grid.shape}")
    bad = ~np.isfinite(arr)
    if unit_interval:
        bad |= (arr < -1e-6) | (arr > 1 + 1e-6)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        rule = "a probability in [0, 1]" if unit_interval else "finite"
        raise BayesmapError(f"{what}[{i}, {j}] is {arr[i, j]!r}: every value must be {rule}")
    return np.clip(arr, 0.0, 1.0) if unit_interval else arr


def check_point(xy, what: str) -> np.ndarray:
    """``xy`` as a ``(2,)`` float64 world point (meters; cells on the unit grid).

    Raises:
        BayesmapError: naming ``what`` and the value, if it is not two finite numbers.
    """
    try:
        arr = np.asarray(xy, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError(f"{what} must be two numbers (x, y), got {xy!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise BayesmapError(f"{what} must be two finite numbers (x, y), got {xy!r} (shape {arr.shape})")
    return arr


# ---------------------------------------------------------------------------------------------------------------
# Drawing helpers
# ---------------------------------------------------------------------------------------------------------------


def new_figure(figsize) -> Figure:
    """A new Figure of ``figsize`` ``(width, height)`` inches with constrained layout and an Agg canvas (no
    ``pyplot``: safe headless and in threads)."""
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def is_unit_grid(grid: Grid) -> bool:
    """True for the tutorial's unit grid (resolution 1, origin ``(-0.5, -0.5)``), whose axes are labelled in cells
    (else meters)."""
    return grid.resolution == 1.0 and grid.origin == (-0.5, -0.5)


def setup_map_axes(ax, grid: Grid, title: str) -> None:
    """Make ``ax`` show the whole grid in world coordinates: limits ``grid.extent``, equal aspect, axis labels in
    cells (unit grid, with integer ticks) or meters, and ``title``."""
    unit = "cells" if is_unit_grid(grid) else "m"
    xmin, xmax, ymin, ymax = grid.extent
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")
    ax.set_title(title)
    if unit == "cells":
        ax.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
        ax.yaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))


def image_interpolation(grid: Grid) -> str:
    """The ``imshow`` interpolation for a per-cell image of ``grid``: ``"nearest"`` (crisp cells) up to
    :data:`MAX_NEAREST_CELLS` cells per side, ``"auto"`` (antialiased, so that one-cell walls do not vanish) above."""
    return "nearest" if max(grid.shape) <= MAX_NEAREST_CELLS else "auto"


def draw_gridlines(ax, grid: Grid, alpha: float = 1.0) -> None:
    """The cell borders as one LineCollection (gid ``"gridlines"``, light grey, ``alpha`` in [0, 1]), only on grids
    of at most :data:`MAX_GRIDLINE_CELLS` cells per side."""
    if max(grid.shape) > MAX_GRIDLINE_CELLS:
        return
    xmin, xmax, ymin, ymax = grid.extent
    xs = grid.origin[0] + grid.resolution * np.arange(grid.shape[0] + 1)
    ys = grid.origin[1] + grid.resolution * np.arange(grid.shape[1] + 1)
    segs = [((x, ymin), (x, ymax)) for x in xs] + [((xmin, y), (xmax, y)) for y in ys]
    ax.add_collection(
        LineCollection(segs, colors=GRIDLINE_COLOR, linewidths=0.5, alpha=alpha, zorder=1.5, gid="gridlines"),
        autolim=False,
    )


def _boundary_segments(mask: np.ndarray, grid: Grid) -> np.ndarray:
    """Line segments ``(S, 2, 2)`` (world coordinates) along the boundary of the cells where ``mask`` is True,
    collinear neighbouring edges merged into one segment."""
    m = np.pad(mask.astype(bool), 1)
    ox, oy = grid.origin
    res = grid.resolution
    out = []
    # edges on the vertical line x = ox + i*res, between cells (i-1, j) and (i, j): (nx+1, ny)
    vertical = m[1:, 1:-1] != m[:-1, 1:-1]
    # edges on the horizontal line y = oy + j*res, between cells (i, j-1) and (i, j): (ny+1, nx) after transpose
    horizontal = (m[1:-1, 1:] != m[1:-1, :-1]).T
    for edges, is_vertical in ((vertical, True), (horizontal, False)):
        step = np.diff(np.pad(edges, ((0, 0), (1, 1))).astype(np.int8), axis=1)
        line, start = np.nonzero(step == 1)
        _, stop = np.nonzero(step == -1)
        fixed = (ox if is_vertical else oy) + line * res
        lo = (oy if is_vertical else ox) + start * res
        hi = (oy if is_vertical else ox) + stop * res
        if is_vertical:
            seg = np.stack([np.stack([fixed, lo], -1), np.stack([fixed, hi], -1)], axis=1)
        else:
            seg = np.stack([np.stack([lo, fixed], -1), np.stack([hi, fixed], -1)], axis=1)
        out.append(seg)
    return np.concatenate(out, axis=0)


def _outline(mask: np.ndarray, grid: Grid, **kwargs) -> PathPatch:
    """The boundary of the cells where ``mask`` is True as one unfilled compound path (one MOVETO / LINETO pair per
    merged edge): far faster to render than a LineCollection when the boundary has ~10^5 edges."""
    segs = _boundary_segments(mask, grid)
    codes = np.tile(np.array([MplPath.MOVETO, MplPath.LINETO], dtype=MplPath.code_type), len(segs))
    vertices = segs.reshape(-1, 2) if len(segs) else np.zeros((0, 2))
    return PathPatch(MplPath(vertices, codes), fill=False, capstyle="projecting", joinstyle="miter", **kwargs)


def draw_walls(ax, walls: np.ndarray, grid: Grid) -> None:
    """True walls (``walls > 0.5`` of the ``(nx, ny)`` map) as dark filled cells with a thin outline (gid
    ``"walls"``: a PatchCollection of cells, or above :data:`MAX_WALL_PATCHES` wall cells an image plus an outline
    path with gid ``"walls_outline"``)."""
    wall = walls > 0.5
    count = int(wall.sum())
    if count <= MAX_WALL_PATCHES:
        ox, oy = grid.origin
        res = grid.resolution
        cells = np.argwhere(wall)
        rects = [Rectangle((ox + i * res, oy + j * res), res, res) for i, j in cells]
        ax.add_collection(
            PatchCollection(
                rects,
                facecolors=WALL_COLOR,
                edgecolors=WALL_EDGE_COLOR,
                linewidths=0.6,
                zorder=2,
                gid="walls",
            )
        )
        return
    rgba = np.zeros(wall.T.shape + (4,), dtype=np.uint8)
    rgba[wall.T] = (43, 43, 43, 255)
    ax.imshow(
        rgba,
        origin="lower",
        extent=grid.extent,
        interpolation=image_interpolation(grid),
        zorder=2,
        gid="walls",
    )
    # add_artist, not add_patch: add_patch walks every vertex in Python to update the data limits
    ax.add_artist(_outline(wall, grid, edgecolor=WALL_COLOR, linewidth=0.4, zorder=2.1, gid="walls_outline"))


def draw_truth(ax, truth: np.ndarray, grid: Grid) -> None:
    """Outline of the true walls (``truth > 0.5`` of the ``(nx, ny)`` map) as one red PathPatch with gid
    ``"truth"`` (one MOVETO/LINETO pair per merged cell edge)."""
    small = max(grid.shape) <= MAX_GRIDLINE_CELLS
    ax.add_artist(  # not add_patch: see draw_walls
        _outline(
            truth > 0.5,
            grid,
            edgecolor=TRUTH_COLOR,
            linewidth=1.4 if small else 0.5,
            alpha=1.0 if small else 0.7,
            zorder=3,
            gid="truth",
        )
    )


def draw_legend(ax, handles) -> None:
    """A frameless legend of ``handles`` centred below the axes (up to 4 in a row, else 3); nothing without
    handles."""
    if not handles:
        return
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.1),
        ncol=len(handles) if len(handles) <= 4 else 3,
        fontsize="small",
        frameon=False,
        handlelength=1.5,
        columnspacing=1.2,
    )


# ---------------------------------------------------------------------------------------------------------------
# Output
# ---------------------------------------------------------------------------------------------------------------


def figure_bytes(fig, fmt: str = "png") -> bytes:
    """The figure rendered in memory as ``"png"`` (150 dpi) or ``"svg"``, with tight borders.

    Raises:
        BayesmapError: if ``fig`` is not a Figure or ``fmt`` is not png or svg.
    """
    if not isinstance(fig, Figure):
        raise BayesmapError(f"expected a matplotlib Figure, got {type(fig).__name__}")
    if fmt not in SAVE_FORMATS.values():
        raise BayesmapError(f"cannot render a figure as {fmt!r}: use png or svg")
    buffer = BytesIO()
    fig.savefig(buffer, format=fmt, dpi=150 if fmt == "png" else "figure", bbox_inches="tight", pad_inches=0.1)
    return buffer.getvalue()


def save_figure(fig, path, *, overwrite: bool = False) -> Path:
    """Save ``fig`` as PNG or SVG (chosen by the suffix of ``path``), whole or not at all.

    The figure is rendered to bytes in memory first, then written with :func:`bayesmap.io.files.write_atomic`.

    Returns:
        The path written.

    Raises:
        BayesmapError: if the suffix is not ``.png`` or ``.svg`` (names it), ``path`` exists and ``overwrite``
            is False, or the folder cannot be written.
    """
    if not isinstance(fig, Figure):
        raise BayesmapError(f"save_figure needs a matplotlib Figure, got {type(fig).__name__}")
    path = Path(path)
    fmt = SAVE_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise BayesmapError(
            f"cannot save a figure as {path.suffix or '(no suffix)'!r} ({str(path)!r}): use a .png or .svg file name"
        )
    if path.exists() and not overwrite:
        raise BayesmapError(f"{str(path)!r} already exists (refusing to overwrite it)")
    return write_atomic(path, figure_bytes(fig, fmt), overwrite=overwrite)
