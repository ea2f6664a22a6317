"""What every figure shares: validation of grids and per-cell arrays, the crop of a map to the cells the beams saw
(:func:`crop_extent`), the map-drawing helpers (axes in world coordinates, the wall-probability image, grid lines,
true walls, their outline, the legend, colour bars) and the output (:func:`figure_bytes`, :func:`save_figure`).

Everything is drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas (never ``pyplot``), so it works
headless, in threads and in tests. :func:`save_figure` writes a figure as PNG or SVG, whole or not at all.

A real log's grid is sized for the laser's reach (80 m down a corridor), so its building can fill a small corner
of it: every map figure of a posterior takes the cells some beam crossed (``seen``, ``(nx, ny)`` bool, e.g. from
:func:`bayesmap.io.maps_out.seen_cells_along`) and shows only their bounding box plus :data:`CROP_MARGIN`
(:func:`crop_extent`), the cells outside ``seen`` ("unseen cells") in a neutral blue-grey (:data:`UNSEEN_COLOR`)
apart from the grey scale of P(wall). A map of more than :data:`MAX_IMAGE_BLOCKS` cells per side (a log's, with
about as many cells as the figure has pixels) is drawn in blocks, each as dark as its darkest cell
(:func:`draw_cell_image`), so that one-cell walls stay black.

Conventions: ``walls[i, j]`` / ``posterior[i, j]`` is cell ``(i, j)`` with ``i`` along x and ``j`` along y, so
images are drawn transposed (``imshow(P.T, origin="lower", extent=grid.extent)``): x horizontal, y vertical, in
world coordinates. Axis labels say "cells" on the tutorial's unit grid (resolution 1, origin ``(-0.5, -0.5)``)
and "m" otherwise.

The figures themselves are in :mod:`bayesmap.viz.maps` (the map, the scan, the posterior) and
:mod:`bayesmap.viz.diagnostics` (importance weights, convergence of Gibbs chains); :mod:`bayesmap.viz.animation`
draws the chain's frames with the same helpers.
"""

from __future__ import annotations

import math
from io import BytesIO
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Patch, PathPatch, Rectangle
from matplotlib.path import Path as MplPath
from matplotlib.ticker import MaxNLocator
from matplotlib.transforms import offset_copy

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.files import write_atomic

__all__ = [
    "check_cells",
    "check_grid",
    "check_point",
    "check_seen",
    "crop_cells",
    "crop_extent",
    "draw_cell_image",
    "draw_gridlines",
    "draw_legend",
    "draw_truth",
    "draw_walls",
    "figure_bytes",
    "fit_colorbars",
    "image_interpolation",
    "is_unit_grid",
    "map_figsize",
    "new_figure",
    "save_figure",
    "setup_map_axes",
    "unseen_handle",
]

# Grid lines are drawn when neither side of the grid has more cells than this.
MAX_GRIDLINE_CELLS = 60
# Above this many wall cells, walls are drawn as one image plus an outline instead of one rectangle per cell.
MAX_WALL_PATCHES = 2000
# Images with at most this many cells per side are drawn with "nearest" (crisp cells); larger ones are
# antialiased so that one-cell walls do not vanish when the image is downsampled to screen pixels.
MAX_NEAREST_CELLS = 256
# Maps of the probability per cell (draw_cell_image) with more cells per side than this are drawn in blocks of
# k x k cells, each its largest value: at 150 dpi a map 6.5 inches wide then has about 3 pixels per block.
MAX_IMAGE_BLOCKS = 320

WALL_COLOR = "#2b2b2b"
WALL_EDGE_COLOR = "#8c8c8c"
TRUTH_COLOR = "#d62728"
SENSOR_COLOR = "#e31a1c"
GRIDLINE_COLOR = "#c8c8c8"
UNSEEN_COLOR = "#cdd6e0"
"""Cells no beam crossed: a light blue-grey, apart from the grey scale of P(wall) (white free, black wall)."""
CROP_MARGIN = 1.5
"""The margin around the bounding box of the seen cells, in world units (meters; cells on the unit grid)."""
FOCUS_COVERAGE = 0.99
"""The share of the returned beams' endpoints a cropped map figure holds along each axis (:func:`crop_extent`): the
0.5 % farthest on each side (beams through doors and windows) do not set the frame. Chosen by looking at the figures
of the shared logs and of a simulated building: each building fills its frame and no wall of it is cut (CSAIL's SLAM
frame 60.0 x 88.7 m becomes 48.3 x 63.6 m); [validation](../validation/defaults.md#focus_coverage)."""
COLORBAR_GAP_INCHES = 0.15
LEGEND_DROP_POINTS = 32.0
"""How far below the axes a legend starts: the ticks, the tick labels and the x label at the default font sizes."""
MAP_WIDTH_INCHES = 6.5
"""The width of a figure's map when the map is the figure (the occupancy grid, the SLAM figure)."""

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


def check_seen(seen, grid: Grid) -> np.ndarray | None:
    """``seen`` (the cells some beam crossed) as an ``(nx, ny)`` bool array, or None for None.

    Raises:
        BayesmapError: if it is not a bool array of shape ``grid.shape``.
    """
    if seen is None:
        return None
    arr = np.asarray(seen)
    if arr.shape != grid.shape:
        raise BayesmapError(f"seen has shape {arr.shape}, but the grid has shape {grid.shape}")
    if arr.dtype != bool:
        raise BayesmapError(f"seen must be a bool array (the cells some beam crossed), got dtype {arr.dtype}")
    return arr


# ---------------------------------------------------------------------------------------------------------------
# The crop
# ---------------------------------------------------------------------------------------------------------------


def crop_extent(grid: Grid, seen=None, margin: float = CROP_MARGIN, focus=None,
                include=None) -> tuple[float, float, float, float]:
    """The part of the grid a map figure shows: the bounding box of the cells some beam crossed, narrowed to where
    the map's content is (``focus``), ``margin`` wider on every side, clipped to the grid.

    A beam through a doorway or a window can end tens of meters outside the building and cross a fan of cells on
    its way, which would set the frame alone. With ``focus``, the returned beams' endpoints, the box on each axis is
    the central :data:`FOCUS_COVERAGE` of the endpoints (the quantiles ``(1 - c) / 2`` and ``(1 + c) / 2``), widened
    to hold every point of ``include`` (the robot's path): the cells outside the frame are still in the posterior
    arrays, only not drawn.

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        seen: ``(nx, ny)`` bool, the cells some beam crossed; None (or no True cell) for the whole grid.
        margin: world units (meters; cells on the unit grid) added on each side, >= 0.
        focus: ``(N, 2)`` float world points where the map's content is (the returned beams' endpoints,
            :func:`bayesmap.geometry.raycast.scan_endpoints`), or None.
        include: ``(M, 2)`` float world points the frame must hold (the path), or None; used with ``focus``.

    Returns:
        ``(xmin, xmax, ymin, ymax)`` in world units, within ``grid.extent`` (equal to it for ``seen=None`` and
        ``focus=None``).

    Raises:
        BayesmapError: if ``seen`` is not an ``(nx, ny)`` bool array, ``margin`` is negative, or ``focus`` or
            ``include`` is not ``(N, 2)`` finite numbers.
    """
    seen = check_seen(seen, grid)
    if not margin >= 0:
        raise BayesmapError(f"the crop margin must be >= 0, got {margin!r}")
    box = list(grid.extent)
    if seen is not None and seen.any():
        xs = np.flatnonzero(seen.any(axis=1))
        ys = np.flatnonzero(seen.any(axis=0))
        (ox, oy), res = grid.origin, grid.resolution
        box = [ox + xs[0] * res, ox + (xs[-1] + 1) * res, oy + ys[0] * res, oy + (ys[-1] + 1) * res]
    points = _points(focus, "focus")
    if len(points):
        lo, hi = np.quantile(points, [(1 - FOCUS_COVERAGE) / 2, (1 + FOCUS_COVERAGE) / 2], axis=0)
        held = _points(include, "include")
        if len(held):
            lo, hi = np.minimum(lo, held.min(axis=0)), np.maximum(hi, held.max(axis=0))
        box = [max(box[0], lo[0]), min(box[1], hi[0]), max(box[2], lo[1]), min(box[3], hi[1])]
        if box[0] >= box[1] or box[2] >= box[3]:  # the points lie off the seen cells: keep the seen box
            return crop_extent(grid, seen, margin)
    gx0, gx1, gy0, gy1 = grid.extent
    return (max(gx0, box[0] - margin), min(gx1, box[1] + margin), max(gy0, box[2] - margin), min(gy1, box[3] + margin))


def _points(points, name: str) -> np.ndarray:
    """``points`` as ``(N, 2)`` float64 (``(0, 2)`` for None); a BayesmapError naming ``name`` otherwise."""
    if points is None:
        return np.zeros((0, 2))
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2 or not np.all(np.isfinite(arr)):
        raise BayesmapError(f"{name} must be (N, 2) finite world points, got shape {arr.shape}")
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


def setup_map_axes(ax, grid: Grid, title: str, extent=None) -> None:
    """Make ``ax`` show the grid in world coordinates: limits ``extent`` (``(xmin, xmax, ymin, ymax)``, e.g. from
    :func:`crop_extent`; default ``grid.extent``), equal aspect, axis labels in cells (unit grid, with integer
    ticks) or meters, and ``title``."""
    unit = "cells" if is_unit_grid(grid) else "m"
    xmin, xmax, ymin, ymax = grid.extent if extent is None else extent
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


def crop_cells(grid: Grid, extent) -> tuple[slice, slice]:
    """The cells ``(rows along x, columns along y)`` that cover ``extent`` (``(xmin, xmax, ymin, ymax)`` within
    the grid), as slices of an ``(nx, ny)`` array."""
    ox, oy = grid.origin
    res = grid.resolution
    nx, ny = grid.shape
    i0 = max(0, int(np.floor((extent[0] - ox) / res + 1e-9)))
    i1 = min(nx, int(np.ceil((extent[1] - ox) / res - 1e-9)))
    j0 = max(0, int(np.floor((extent[2] - oy) / res + 1e-9)))
    j1 = min(ny, int(np.ceil((extent[3] - oy) / res - 1e-9)))
    return slice(i0, max(i1, i0 + 1)), slice(j0, max(j1, j0 + 1))


def _max_pool(values: np.ndarray, seen: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(values, seen)`` of ``k x k`` blocks of cells (the last ones padded): each block's largest value over its
    seen cells (0 where none), and whether it has a seen cell."""
    pad = ((0, -values.shape[0] % k), (0, -values.shape[1] % k))
    vals = np.pad(np.where(seen, values, 0.0), pad)
    mask = np.pad(seen, pad)
    bx, by = vals.shape[0] // k, vals.shape[1] // k
    return vals.reshape(bx, k, by, k).max(axis=(1, 3)), mask.reshape(bx, k, by, k).any(axis=(1, 3))


def draw_cell_image(ax, grid: Grid, values: np.ndarray, *, gid: str, seen=None, cmap: str = "Greys",
                    vmax: float = 1.0, extent=None):
    """A per-cell image of the cells that cover ``extent`` (``(xmin, xmax, ymin, ymax)``, the part of the grid the
    axes show; default the whole grid): ``values`` ``(nx, ny)`` float, 0 to ``vmax`` on ``cmap``, in world
    coordinates at zorder 1, with ``"nearest"`` interpolation; cells outside ``seen`` (``(nx, ny)`` bool, or None for
    none) in :data:`UNSEEN_COLOR`.

    Above :data:`MAX_IMAGE_BLOCKS` cells per side the image shows blocks of ``k x k`` cells (the smallest ``k`` that
    brings it within the limit), each the largest value of its seen cells: a one-cell wall stays as dark as it is
    instead of being averaged away where the figure has about as many pixels as the map has cells (a 60 m crop of
    0.1 m cells), at the cost of drawing walls ``k`` cells thick.

    Returns:
        The AxesImage, with gid ``gid``, data the (pooled) values transposed (masked where unseen if ``seen`` is
        given) and extent the cells (blocks) it covers.
    """
    rows, cols = crop_cells(grid, grid.extent if extent is None else extent)
    part = values[rows, cols]
    part_seen = np.ones(part.shape, dtype=bool) if seen is None else seen[rows, cols]
    k = max(1, math.ceil(max(part.shape) / MAX_IMAGE_BLOCKS))
    if k > 1:
        part, part_seen = _max_pool(part, part_seen, k)
    data = part.T if seen is None else np.ma.masked_array(part.T, mask=~part_seen.T)
    ox, oy = grid.origin
    res = grid.resolution
    x0, y0 = ox + rows.start * res, oy + cols.start * res
    box = (x0, x0 + part.shape[0] * k * res, y0, y0 + part.shape[1] * k * res)
    colormap = matplotlib.colormaps[cmap].with_extremes(bad=UNSEEN_COLOR)
    return ax.imshow(data, origin="lower", extent=box, cmap=colormap, vmin=0.0, vmax=vmax,
                     interpolation="nearest", zorder=1, gid=gid)


def map_figsize(extent, panels: int, colorbar: bool, width: float = 5.0) -> tuple[float, float]:
    """A figure size ``(width, height)`` in inches for ``panels`` maps side by side, each showing ``extent``
    (``(xmin, xmax, ymin, ymax)``) about ``width`` inches wide (at most 1.3 ``width`` tall), that roughly follows the
    maps' aspect ratio (so colour bars match the axes)."""
    aspect = min(max((extent[3] - extent[2]) / (extent[1] - extent[0]), 0.35), 2.5)  # height / width of one map
    height = width * aspect
    if height > 1.3 * width:
        width, height = width * 1.3 * width / height, 1.3 * width
    extra_w = 1.2 if colorbar else 0.4
    return (panels * (width + extra_w) + 0.4, height + 1.5)


def fit_colorbars(fig: Figure, pairs) -> None:
    """Lay ``fig`` out once (constrained layout), then freeze the layout and give each colour bar of ``pairs``
    (``(map axes, Colorbar)``) the height of its map axes as drawn (with equal aspect the map is often shorter than
    the slot the layout gave it)."""
    fig.draw_without_rendering()
    slots = [cbar.ax.get_position(original=True) for _, cbar in pairs]
    fig.set_layout_engine("none")
    for (ax, cbar), cpos in zip(pairs, slots):
        ax.apply_aspect()
        drawn = ax.get_position(original=False)
        gap = COLORBAR_GAP_INCHES / fig.get_figwidth()
        cbar.ax.set_position([drawn.x1 + gap, drawn.y0, cpos.width, drawn.height])


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


def unseen_handle() -> Patch:
    """The legend entry "unseen cells" of the cells drawn in :data:`UNSEEN_COLOR`."""
    return Patch(facecolor=UNSEEN_COLOR, edgecolor=WALL_EDGE_COLOR, linewidth=0.5, label="unseen cells")


def draw_legend(ax, handles) -> None:
    """A frameless legend of ``handles`` centred below the axes, :data:`LEGEND_DROP_POINTS` under their bottom edge
    (below the tick labels and the x label, whatever the axes' height): up to 4 in a row, else 3, fewer where the
    row would be wider than the axes (constrained layout would shrink the map to make room); nothing without
    handles."""
    if not handles:
        return
    fig = ax.get_figure(root=True)
    # a figure of ours has an Agg canvas; one given without (a bare Figure) gets the widest rows, unmeasured
    renderer = fig.canvas.get_renderer() if hasattr(fig.canvas, "get_renderer") else None
    room = ax.get_position().width * fig.get_figwidth() * fig.dpi  # the axes' slot, in display pixels
    for ncol in range(len(handles) if len(handles) <= 4 else 3, 0, -1):
        legend = ax.legend(
            handles=handles,
            loc="upper center",
            bbox_to_anchor=(0.5, 0.0),
            bbox_transform=offset_copy(ax.transAxes, fig=fig, y=-LEGEND_DROP_POINTS, units="points"),
            ncol=ncol,
            fontsize="small",
            frameon=False,
            handlelength=1.5,
            columnspacing=1.2,
        )
        if renderer is None or legend.get_window_extent(renderer).width <= room:
            return


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
