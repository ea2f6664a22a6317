"""Figures: the true map with a scan, and the posterior wall probability (optionally its standard deviation).

Everything is drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas (never ``pyplot``), so it works
headless, in threads and in tests. Every plotting function returns the Figure; :func:`save_figure` writes it as
PNG or SVG, whole or not at all.

Conventions: ``walls[i, j]`` / ``posterior[i, j]`` is cell ``(i, j)`` with ``i`` along x and ``j`` along y, so
images are drawn transposed (``imshow(P.T, origin="lower", extent=grid.extent)``): x horizontal, y vertical, in
world coordinates. Axis labels say "cells" on the tutorial's unit grid (resolution 1, origin ``(-0.5, -0.5)``)
and "m" otherwise.

Artists carry a ``gid`` so that callers and tests can find them: ``"walls"`` (the true walls: a
PatchCollection of cells, or an image plus a ``"walls_outline"`` path on maps with many wall cells), ``"truth"``
(outline of the true walls on a posterior: a PathPatch, one MOVETO/LINETO pair per edge), ``"posterior"`` and
``"std"`` (the heatmaps), ``"gridlines"``, ``"rays"`` (a LineCollection, one segment per ray from its origin to
its reading endpoint), ``"sensor"`` (a scatter of the sensor position(s)), ``"readings"`` and
``"max_range_readings"`` (scatters of the reading endpoints). :func:`plot_importance` and :func:`plot_convergence`
(diagnostics of importance sampling and of Gibbs chains) list their gids in their docstrings.

Large grids (10^6 cells, 10^5 wall edges, hundreds of rays) plot and save in about a second: heatmaps and
large wall sets are images, outlines are one compound path, rays one LineCollection.
"""

from __future__ import annotations

from io import BytesIO
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, PathPatch, Rectangle
from matplotlib.path import Path as MplPath
from matplotlib.ticker import MaxNLocator

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.files import write_atomic

__all__ = ["plot_convergence", "plot_importance", "plot_map", "plot_posterior", "save_figure"]

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
RAY_COLOR = "#1f78b4"
READING_COLOR = "#1f78b4"
MAX_RANGE_COLOR = "#7f7f7f"
GRIDLINE_COLOR = "#c8c8c8"
# Above this many rays, rays are faded and reading dots shrunk in proportion.
CROWDED_RAYS = 400
COLORBAR_GAP_INCHES = 0.15

SAVE_FORMATS = {".png": "png", ".svg": "svg"}

# plot_importance
HISTOGRAM_FACE_COLOR = "#a6cee3"
HISTOGRAM_EDGE_COLOR = "#1f78b4"
MAX_HISTOGRAM_BINS = 60
# plot_convergence: up to this many chains get a colour, a marker and a legend entry each; more chains are shaded
# along a sequential colour map (dark = chain 0) and share one legend entry.
MAX_LEGEND_CHAINS = 6
# Okabe-Ito colours (distinguishable with colour-vision deficiencies) in an order that alternates dark and light
CHAIN_COLORS = ("#0072b2", "#e69f00", "#000000", "#56b4e9", "#d55e00", "#009e73")
CHAIN_MARKERS = ("o", "s", "^", "D", "v", "P")
CHAIN_CMAP = "viridis"
BURN_IN_COLOR = "#595959"
# The y range of the log-joint panel covers the values of the last (1 - CONVERGED_FRACTION_SKIPPED) of the sweeps
CONVERGED_FRACTION_SKIPPED = 0.2
# The wrong-cells panel switches to a symmetric-log scale (linear below WRONG_LINTHRESH) above this many cells
WRONG_SYMLOG_ABOVE = 20
WRONG_LINTHRESH = 10
# The accuracy of the tutorial's Gibbs samplers, in wrong visible cells (see bayesmap.bench)
TUTORIAL_WRONG_CELLS = 2


# ---------------------------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------------------------


def _check_grid(grid) -> Grid:
    if not isinstance(grid, Grid):
        raise BayesmapError(f"grid must be a bayesmap.geometry.grid.Grid, got {type(grid).__name__}")
    return grid


def _check_cells(values, grid: Grid, what: str, unit_interval: bool = False) -> np.ndarray:
    """A per-cell array of shape ``grid.shape`` as finite float64 (in [0, 1] if ``unit_interval``)."""
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


def _check_point(xy, what: str) -> np.ndarray:
    try:
        arr = np.asarray(xy, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError(f"{what} must be two numbers (x, y), got {xy!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise BayesmapError(f"{what} must be two finite numbers (x, y), got {xy!r} (shape {arr.shape})")
    return arr


def _check_vector(values, what: str) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError(f"{what} must be a 1-D array of numbers") from None
    if arr.ndim != 1:
        raise BayesmapError(f"{what} must be a 1-D array, got shape {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if len(bad):
        raise BayesmapError(f"{what}[{bad[0]}] is {arr[bad[0]]!r}: values must be finite")
    return arr


def _check_scan(pos, beam_angles, readings, origins, max_range_mask):
    """Validate a scan; returns ``(pos or None, origins (K, 2) or None, endpoints (K, 2) or None, mask (K,))``."""
    pos = None if pos is None else _check_point(pos, "pos")
    if (beam_angles is None) != (readings is None):
        given, missing = ("beam_angles", "readings") if readings is None else ("readings", "beam_angles")
        raise BayesmapError(f"{given} given without {missing}: pass both (one angle per reading) or neither")
    if beam_angles is None:
        if origins is not None or max_range_mask is not None:
            raise BayesmapError("origins and max_range_mask need beam_angles and readings")
        return pos, None, None, None
    angles = _check_vector(beam_angles, "beam_angles")
    ranges = _check_vector(readings, "readings")
    if angles.shape != ranges.shape:
        raise BayesmapError(
            f"readings has shape {ranges.shape} but beam_angles has shape {angles.shape}: need one angle per reading"
        )
    if (ranges < 0).any():
        k = int(np.flatnonzero(ranges < 0)[0])
        raise BayesmapError(f"readings[{k}] is {ranges[k]!r}: readings must be >= 0 (meters)")
    num = len(ranges)
    if origins is None:
        if pos is None:
            raise BayesmapError("readings need a sensor position: pass pos (one pose) or origins (one per ray)")
        starts = np.broadcast_to(pos, (num, 2))
    else:
        try:
            starts = np.asarray(origins, dtype=np.float64)
        except (TypeError, ValueError):
            raise BayesmapError(f"origins must be an array of numbers of shape ({num}, 2)") from None
        if starts.shape != (num, 2):
            raise BayesmapError(f"origins has shape {starts.shape}, expected ({num}, 2): one (x, y) per reading")
        if not np.all(np.isfinite(starts)):
            k = int(np.argwhere(~np.isfinite(starts))[0, 0])
            raise BayesmapError(f"origins[{k}] is {starts[k].tolist()!r}: origins must be finite")
    if max_range_mask is None:
        mask = np.zeros(num, dtype=bool)
    else:
        raw = np.asarray(max_range_mask)
        if raw.shape != (num,):
            raise BayesmapError(f"max_range_mask has shape {raw.shape}, expected ({num},): one flag per reading")
        if raw.dtype != bool:
            raise BayesmapError(f"max_range_mask must be a bool array, got dtype {raw.dtype}")
        mask = raw
    endpoints = starts + ranges[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    return pos, np.array(starts), endpoints, mask


def _check_log_weights(values) -> np.ndarray:
    """``(N,)`` log weights as float64: finite or -inf, at least one finite."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError("log_weights must be a 1-D array of numbers (one log weight per particle)") from None
    if arr.ndim != 1:
        raise BayesmapError(f"log_weights must be a 1-D array (one log weight per particle), got shape {arr.shape}")
    if arr.size == 0:
        raise BayesmapError("log_weights is empty: need at least one particle")
    bad = np.flatnonzero(np.isnan(arr) | (arr == np.inf))
    if len(bad):
        k = int(bad[0])
        raise BayesmapError(f"log_weights[{k}] is {float(arr[k])!r}: log weights must be finite or -inf")
    if np.all(arr == -np.inf):
        raise BayesmapError(f"every one of the {arr.size} log weights is -inf: the weights cannot be normalized")
    return arr


def _check_ess(ess, num: int) -> float:
    """A given effective sample size: a finite number between 1 and ``num`` (with a relative tolerance of 1e-3 for
    values computed in float32)."""
    try:
        arr = np.asarray(ess, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError(f"ess must be a number (the effective sample size), got {ess!r}") from None
    if arr.ndim != 0:
        raise BayesmapError(f"ess must be a single number (the effective sample size), got shape {arr.shape}")
    value = float(arr)
    if not (np.isfinite(value) and 1.0 - 1e-3 <= value <= num * (1.0 + 1e-3)):
        raise BayesmapError(
            f"ess is {value!r}: the effective sample size of {num:,} particles is between 1 and {num:,}"
        )
    return value


def _index(shape, flat: int) -> str:
    return ", ".join(str(int(i)) for i in np.unravel_index(flat, shape))


def _check_traces(values, what: str) -> np.ndarray:
    """``(num_sweeps,)`` or ``(num_chains, num_sweeps)`` finite numbers, returned as float64 of that shape."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError(
            f"{what} must be an array of numbers of shape (num_sweeps,) or (num_chains, num_sweeps)"
        ) from None
    if arr.ndim not in (1, 2):
        raise BayesmapError(f"{what} must have shape (num_sweeps,) or (num_chains, num_sweeps), got shape {arr.shape}")
    if arr.size == 0:
        raise BayesmapError(f"{what} is empty (shape {arr.shape}): need at least one chain and one sweep")
    bad = np.flatnonzero(~np.isfinite(arr))
    if len(bad):
        k = int(bad[0])
        raise BayesmapError(f"{what}[{_index(arr.shape, k)}] is {float(arr.flat[k])!r}: values must be finite")
    return arr


def _check_wrong_cells(values, shape: tuple) -> np.ndarray:
    """Counts of wrong cells with the same shape as the log joints: integers >= 0 (as float64)."""
    arr = _check_traces(values, "wrong_cells")
    if arr.shape != shape:
        raise BayesmapError(
            f"wrong_cells has shape {arr.shape} but log_joints has shape {shape}: need one count per chain and sweep"
        )
    bad = np.flatnonzero((arr < 0) | (arr != np.round(arr)))
    if len(bad):
        k = int(bad[0])
        raise BayesmapError(
            f"wrong_cells[{_index(arr.shape, k)}] is {float(arr.flat[k])!r}: counts of cells must be integers >= 0"
        )
    return arr


def _check_burn_in(burn_in, num_sweeps: int) -> int:
    if isinstance(burn_in, bool) or not isinstance(burn_in, (int, np.integer)) or not 0 <= burn_in < num_sweeps:
        raise BayesmapError(
            f"burn_in must be an integer between 0 and {num_sweeps - 1} (number of sweeps - 1), got {burn_in!r}"
        )
    return int(burn_in)


def _check_number(value, what: str) -> float:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BayesmapError(f"{what} must be a number, got {value!r}") from None
    if arr.ndim != 0 or not np.isfinite(arr):
        raise BayesmapError(f"{what} must be one finite number, got {value!r}")
    return float(arr)


# ---------------------------------------------------------------------------------------------------------------
# Drawing helpers
# ---------------------------------------------------------------------------------------------------------------


def _new_figure(figsize) -> Figure:
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _is_unit_grid(grid: Grid) -> bool:
    return grid.resolution == 1.0 and grid.origin == (-0.5, -0.5)


def _setup_axes(ax, grid: Grid, title: str) -> None:
    unit = "cells" if _is_unit_grid(grid) else "m"
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


def _interpolation(grid: Grid) -> str:
    return "nearest" if max(grid.shape) <= MAX_NEAREST_CELLS else "auto"


def _draw_gridlines(ax, grid: Grid, alpha: float = 1.0) -> None:
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


def _draw_walls(ax, walls: np.ndarray, grid: Grid) -> None:
    """True walls (``walls > 0.5``) as dark filled cells with a thin outline."""
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
        interpolation=_interpolation(grid),
        zorder=2,
        gid="walls",
    )
    # add_artist, not add_patch: add_patch walks every vertex in Python to update the data limits
    ax.add_artist(_outline(wall, grid, edgecolor=WALL_COLOR, linewidth=0.4, zorder=2.1, gid="walls_outline"))


def _draw_truth(ax, truth: np.ndarray, grid: Grid) -> None:
    """Outline of the true walls (red edges around the wall regions)."""
    small = max(grid.shape) <= MAX_GRIDLINE_CELLS
    ax.add_artist(  # not add_patch: see _draw_walls
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


def _draw_scan(ax, grid: Grid, pos, starts, endpoints, mask, *, faint: bool) -> list:
    """Rays, reading endpoints and the sensor; returns legend handles."""
    handles = []
    many = endpoints is not None and len(endpoints) > CROWDED_RAYS
    if endpoints is not None:
        # with many rays (scans from many poses) fade the rays and shrink the dots so the map stays visible
        crowd = min(1.0, CROWDED_RAYS / max(len(endpoints), 1))
        ray_alpha = (0.25 if faint else 0.45) * max(crowd, 0.1)
        ax.add_collection(
            LineCollection(
                np.stack([starts, endpoints], axis=1),
                colors=RAY_COLOR,
                linewidths=0.5 if faint else 0.7,
                alpha=ray_alpha,
                zorder=4,
                gid="rays",
            ),
            autolim=False,
        )
        handles.append(Line2D([], [], color=RAY_COLOR, lw=0.8, alpha=0.6, label="ray"))
        hit = endpoints[~mask]
        size = (10.0 if faint else 14.0) * max(np.sqrt(crowd), 0.15)
        ax.scatter(
            hit[:, 0],
            hit[:, 1],
            s=size,
            c=READING_COLOR,
            edgecolors="white" if not many else "none",
            linewidths=0.3,
            alpha=(0.8 if faint else 1.0) * (0.6 if many else 1.0),
            zorder=5,
            gid="readings",
            label="reading",
        )
        handles.append(
            Line2D([], [], ls="none", marker="o", ms=4, color=READING_COLOR, mec="white", mew=0.3, label="reading")
        )
        if mask.any():
            far = endpoints[mask]
            ax.scatter(
                far[:, 0],
                far[:, 1],
                s=size * 1.6,
                facecolors="none",
                edgecolors=MAX_RANGE_COLOR,
                linewidths=0.4 if many else 0.8,
                zorder=5,
                gid="max_range_readings",
                label="max-range reading",
            )
            handles.append(
                Line2D([], [], ls="none", marker="o", ms=5, mfc="none", mec=MAX_RANGE_COLOR, label="max-range reading")
            )
    sensors = []
    if pos is not None:
        sensors.append(pos[None, :])
    elif starts is not None:
        sensors.append(np.unique(starts, axis=0))
    if sensors:
        pts = np.concatenate(sensors, axis=0)
        label = "sensor" if len(pts) == 1 else "sensor poses"
        ax.scatter(
            pts[:, 0],
            pts[:, 1],
            s=60 if len(pts) == 1 else 12,
            c=SENSOR_COLOR,
            edgecolors="white",
            linewidths=0.8 if len(pts) == 1 else 0.3,
            zorder=6,
            gid="sensor",
            label=label,
        )
        handles.insert(
            0, Line2D([], [], ls="none", marker="o", ms=7, color=SENSOR_COLOR, mec="white", mew=0.8, label=label)
        )
    return handles


def _legend(ax, handles) -> None:
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


def _fit_colorbars(fig: Figure, pairs) -> None:
    """Lay the figure out once (constrained layout), then freeze the layout and give each colour bar the height
    of its map axes as drawn (with equal aspect the map is often shorter than the slot the layout gave it)."""
    fig.draw_without_rendering()
    slots = [cbar.ax.get_position(original=True) for _, cbar in pairs]
    fig.set_layout_engine("none")
    for (ax, cbar), cpos in zip(pairs, slots):
        ax.apply_aspect()
        drawn = ax.get_position(original=False)
        gap = COLORBAR_GAP_INCHES / fig.get_figwidth()
        cbar.ax.set_position([drawn.x1 + gap, drawn.y0, cpos.width, drawn.height])


def _figsize(grid: Grid, panels: int, colorbar: bool) -> tuple[float, float]:
    """A figure size whose panels roughly follow the grid's aspect ratio (so colour bars match the axes)."""
    nx, ny = grid.shape
    aspect = min(max(ny / nx, 0.35), 2.5)  # height / width of one map
    width = 5.0
    height = width * aspect
    if height > 6.5:
        width, height = width * 6.5 / height, 6.5
    extra_w = 1.2 if colorbar else 0.4
    return (panels * (width + extra_w) + 0.4, height + 1.5)


# ---------------------------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------------------------


def plot_map(
    grid,
    walls=None,
    pos=None,
    beam_angles=None,
    readings=None,
    *,
    origins=None,
    max_range_mask=None,
    title=None,
    ax=None,
) -> Figure:
    """Draw the true map and a scan.

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        walls: ``(nx, ny)`` true map (cells > 0.5 are walls, drawn as dark filled cells), or None to show only
            what the robot sees (the sensor, its rays and readings).
        pos: ``(2,)`` sensor position, world coordinates (red dot); the origin of every ray unless ``origins``.
        beam_angles: ``(K,)`` beam angles in radians (world frame).
        readings: ``(K,)`` range readings (meters); ray ``k`` is drawn from its origin to
            ``origin + readings[k] * (cos beam_angles[k], sin beam_angles[k])`` with a dot at the end.
        origins: ``(K, 2)`` one origin per ray (scans from many poses); the distinct origins are drawn as sensor
            poses when ``pos`` is None.
        max_range_mask: ``(K,)`` bool; True marks max-range readings (no return), drawn as hollow grey markers.
        title: the axes title; default "True map" or "What the robot sees" (``walls=None``).
        ax: draw into this Axes instead of a new figure.

    Returns:
        The Figure (``ax``'s figure when ``ax`` is given).

    Raises:
        BayesmapError: on a wrong shape or a non-finite value (names it), or readings without angles or a pose.
    """
    grid = _check_grid(grid)
    walls = None if walls is None else _check_cells(walls, grid, "walls")
    pos, starts, endpoints, mask = _check_scan(pos, beam_angles, readings, origins, max_range_mask)
    if ax is None:
        fig = _new_figure(_figsize(grid, 1, colorbar=False))
        ax = fig.add_subplot()
    else:
        fig = ax.get_figure(root=True)
    if title is None:
        title = "True map" if walls is not None else "What the robot sees"
    _setup_axes(ax, grid, title)
    _draw_gridlines(ax, grid)
    handles = []
    if walls is not None:
        _draw_walls(ax, walls, grid)
        handles.append(Patch(facecolor=WALL_COLOR, edgecolor=WALL_EDGE_COLOR, label="wall"))
    handles += _draw_scan(ax, grid, pos, starts, endpoints, mask, faint=False)
    _legend(ax, handles)
    return fig


def plot_posterior(
    grid,
    posterior,
    *,
    truth=None,
    pos=None,
    beam_angles=None,
    readings=None,
    origins=None,
    max_range_mask=None,
    title=None,
    std=False,
) -> Figure:
    """Draw the posterior wall probability per cell as a heatmap (white = free, black = wall).

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        posterior: ``(nx, ny)`` posterior probability that each cell is a wall, in [0, 1].
        truth: ``(nx, ny)`` true map; its walls (cells > 0.5) are outlined in red.
        pos, beam_angles, readings, origins, max_range_mask: the scan drawn on top, as in :func:`plot_map`
            (thinner and semi-transparent).
        title: the title of the probability panel; default "Posterior P(wall)".
        std: also draw a second panel with the posterior standard deviation ``sqrt(p (1 - p))`` (0 to 0.5).

    Returns:
        The Figure: ``fig.axes`` is ``[map, colour bar]`` (``[map, std map, colour bar, std colour bar]`` with
        ``std=True``). The heatmap is the image with gid ``"posterior"``; its colour bar is labelled "P(wall)"
        and spans 0 to 1. The layout is computed once and then frozen (so each colour bar is exactly as tall as
        its map); resizing the figure afterwards keeps the relative positions.

    Raises:
        BayesmapError: if ``posterior`` or ``truth`` does not have ``grid.shape``, ``posterior`` has a value
            outside [0, 1], or the scan is malformed (see :func:`plot_map`).
    """
    grid = _check_grid(grid)
    prob = _check_cells(posterior, grid, "posterior", unit_interval=True)
    truth = None if truth is None else _check_cells(truth, grid, "truth")
    pos, starts, endpoints, mask = _check_scan(pos, beam_angles, readings, origins, max_range_mask)
    panels = [("posterior", prob, "Greys", 1.0, "P(wall)", title or "Posterior P(wall)")]
    if std:
        panels.append(
            (
                "std",
                np.sqrt(prob * (1.0 - prob)),
                "viridis",
                0.5,
                "std. dev. sqrt(p(1 - p))",
                "Posterior standard deviation",
            )
        )
    fig = _new_figure(_figsize(grid, len(panels), colorbar=True))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    pairs = []
    for ax, (gid, values, cmap, vmax, label, panel_title) in zip(axes, panels):
        _setup_axes(ax, grid, panel_title)
        image = ax.imshow(
            values.T,
            origin="lower",
            extent=grid.extent,
            cmap=cmap,
            vmin=0.0,
            vmax=vmax,
            interpolation=_interpolation(grid),
            zorder=1,
            gid=gid,
        )
        colorbar = fig.colorbar(image, ax=ax, label=label)
        colorbar.ax.set_ylim(0.0, vmax)
        pairs.append((ax, colorbar))
        _draw_gridlines(ax, grid, alpha=0.35)
        handles = []
        if truth is not None:
            _draw_truth(ax, truth, grid)
            handles.append(Line2D([], [], color=TRUTH_COLOR, lw=1.4, label="true wall outline"))
        handles += _draw_scan(ax, grid, pos, starts, endpoints, mask, faint=True)
        _legend(ax, handles)
    _fit_colorbars(fig, pairs)
    return fig


def _normalize_log_weights(log_weights: np.ndarray) -> np.ndarray:
    """``log_weights - logsumexp(log_weights)`` in float64 (-inf stays -inf; at least one weight is finite)."""
    top = log_weights.max()
    return log_weights - (top + np.log(np.sum(np.exp(log_weights - top))))


def _particles(num: int) -> str:
    return f"{num:,} particle" + ("" if num == 1 else "s")


def plot_importance(log_weights, ess=None, *, title="Importance sampling: normalized log-weights", ax=None) -> Figure:
    """Draw the histogram of the normalized log importance weights, the largest weight and the effective sample size.

    Args:
        log_weights: ``(N,)`` log importance weights, normalized or not (e.g.
            :attr:`~bayesmap.inference.importance.ImportanceResult.log_weights`); they are normalized here in float64,
            ``log w_i = log_weights[i] - logsumexp(log_weights)``. Weights of -inf (particles of weight 0) are
            counted in the text box but not drawn.
        ess: the effective sample size to show; default ``1 / sum_i w_i^2`` of the normalized weights (between 1
            and N).
        title: the axes title.
        ax: draw into this Axes instead of a new figure.

    Returns:
        The Figure (``ax``'s figure when ``ax`` is given). The histogram of the finite normalized log-weights is one
        filled step patch (:class:`~matplotlib.patches.StepPatch`, gid ``"importance-histogram"``; its
        ``get_data()`` gives the counts per bin and the bin edges); the largest weight is a dashed vertical line
        (gid ``"importance-max"``, at 0 when one particle carries all the weight); the text box (gid
        ``"importance-ess"``) reads e.g. "ESS 1.0 of 2,000 particles" plus a line counting the -inf weights if
        any. The x axis is the normalized log-weight (natural log, no unit), the y axis counts particles.

    Raises:
        BayesmapError: if ``log_weights`` is not 1-D, is empty, has a NaN or +inf (names the first), or is -inf
            everywhere; or if ``ess`` is not a number between 1 and N.
    """
    raw = _check_log_weights(log_weights)
    num = raw.size
    lw = _normalize_log_weights(raw)
    finite = lw[np.isfinite(lw)]
    zero_weight = num - finite.size
    ess = 1.0 / np.sum(np.exp(2.0 * lw)) if ess is None else _check_ess(ess, num)
    if ax is None:
        fig = _new_figure((6.4, 4.4))
        ax = fig.add_subplot()
    else:
        fig = ax.get_figure(root=True)
    top = float(finite.max())
    if top == finite.min():  # all finite weights equal: one bar centred on them
        counts, edges = np.array([finite.size]), top + np.array([-0.1, 0.1])
    else:
        bins = int(np.clip(np.ceil(np.sqrt(finite.size)), 10, MAX_HISTOGRAM_BINS))
        counts, edges = np.histogram(finite, bins=bins)
    label = f"{_particles(finite.size)} (finite log-weight)" if zero_weight else _particles(finite.size)
    ax.stairs(
        counts,
        edges,
        fill=True,
        facecolor=HISTOGRAM_FACE_COLOR,
        edgecolor=HISTOGRAM_EDGE_COLOR,
        linewidth=1.0,
        zorder=2,
        gid="importance-histogram",
        label=label,
    )
    ax.axvline(
        top,
        color=TRUTH_COLOR,
        linestyle="--",
        linewidth=1.6,
        zorder=3,
        gid="importance-max",
        label=f"largest weight: log w = {top:.3g} (w = {np.exp(top):.3g})",
    )
    lines = [f"ESS {ess:,.1f} of {_particles(num)}"]
    if zero_weight:
        lines.append(f"{zero_weight:,} with log-weight -inf (weight 0), not drawn")
    ax.text(
        0.02,
        0.97,
        "\n".join(lines),
        transform=ax.transAxes,
        ha="left",
        va="top",
        fontsize="small",
        bbox=dict(boxstyle="round,pad=0.4", facecolor="white", edgecolor="#8c8c8c", alpha=0.9),
        zorder=4,
        gid="importance-ess",
    )
    if len(counts) == 1:  # a lone bar would fill the axes (sticky edges): show it narrow
        ax.set_xlim(top - 1.0, top + 1.0)
    # headroom above the tallest bar for the text box
    ax.set_ylim(0, max(int(counts.max()), 1) * 1.35)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
    ax.set_xlabel("normalized log-weight")
    ax.set_ylabel("particles")
    ax.set_title(title)
    handles, _ = ax.get_legend_handles_labels()
    _legend(ax, handles)
    return fig


def _chain_styles(num_chains: int) -> list[dict]:
    """Line properties per chain: a colour, a line style and a marker each for a few chains (distinguishable in
    grayscale); a sequential colour map (dark = chain 0) for many."""
    if num_chains <= MAX_LEGEND_CHAINS:
        dashes = ("-", "--", "-", "-.", "--", ":")
        return [
            dict(color=CHAIN_COLORS[k], linestyle=dashes[k], marker=CHAIN_MARKERS[k], linewidth=1.4, markersize=5)
            for k in range(num_chains)
        ]
    from matplotlib import colormaps

    cmap = colormaps[CHAIN_CMAP]
    return [
        dict(color=cmap(0.9 * k / (num_chains - 1)), linestyle="-", marker=None, linewidth=0.9, alpha=0.8)
        for k in range(num_chains)
    ]


def _draw_chains(ax, sweeps: np.ndarray, values: np.ndarray, styles: list[dict], prefix: str) -> None:
    num_chains, num_sweeps = values.shape
    # about 10 markers per line, staggered between chains so that they do not sit on top of each other
    step = max(1, num_sweeps // 10)
    for k, (row, style) in enumerate(zip(values, styles)):
        if num_chains == 1:
            label = "chain"
        elif num_chains <= MAX_LEGEND_CHAINS:
            label = f"chain {k}"
        else:
            label = "_nolegend_"
        markevery = (min(k * step // num_chains, num_sweeps - 1), step) if style["marker"] else None
        ax.plot(sweeps, row, markevery=markevery, gid=f"{prefix}-{k}", label=label, zorder=3, **style)


def _many_chains_handle(num_chains: int) -> Line2D:
    from matplotlib import colormaps

    cmap = colormaps[CHAIN_CMAP]
    label = f"{num_chains} chains (dark: chain 0,\nlight: chain {num_chains - 1})"
    return Line2D([], [], color=cmap(0.45), lw=1.2, label=label)


def _clip_to_converged(ax, values: np.ndarray, reference: float | None) -> None:
    """Limit the y range to the values of the last 80 % of the sweeps (and ``reference``) plus a margin; note what
    falls outside in a text (gid ``"off-scale"``) next to the legend."""
    num_sweeps = values.shape[1]
    first = int(np.floor(CONVERGED_FRACTION_SKIPPED * num_sweeps)) if num_sweeps >= 2 else 0
    kept = values[:, first:]
    lo, hi = float(kept.min()), float(kept.max())
    if reference is not None:
        lo, hi = min(lo, reference), max(hi, reference)
    margin = max(0.08 * (hi - lo), 1e-3 * max(abs(lo), abs(hi)), 0.5)
    lo, hi = lo - margin, hi + margin
    ax.set_ylim(lo, hi)
    notes = []
    for side, outside, extreme in (("below", values < lo, np.argmin), ("above", values > hi, np.argmax)):
        if outside.any():
            k, t = np.unravel_index(extreme(values), values.shape)
            notes.append(
                f"{int(outside.sum()):,} point{'s' if outside.sum() > 1 else ''} {side} the axis\n"
                f"({'lowest' if side == 'below' else 'highest'} {values[k, t]:.4g}, sweep {t + 1})"
            )
    if notes:
        ax.text(
            1.02,
            0.0,
            "\n".join(notes),
            transform=ax.transAxes,
            ha="left",
            va="bottom",
            fontsize="small",
            color="#404040",
            gid="off-scale",
        )


def _wrong_cells_scale(ax, wrong: np.ndarray) -> None:
    """Linear up to 20 wrong cells; above, symmetric-log (linear below 10) so the part near 0 stays readable."""
    top = float(wrong.max())
    if top <= WRONG_SYMLOG_ABOVE:
        ax.set_ylim(-0.5, max(top * 1.1, TUTORIAL_WRONG_CELLS + 2.0))
        ax.yaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
        return
    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    ax.set_yscale("symlog", linthresh=WRONG_LINTHRESH, linscale=1.0)
    ticks = [0, 2, 5, 10]
    decade = 10
    while decade * 2 <= top * 1.5:
        ticks += [t for t in (decade * 2, decade * 5, decade * 10) if t <= top * 1.5]
        decade *= 10
    ax.yaxis.set_major_locator(FixedLocator(sorted(set(ticks))))
    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_locator(NullLocator())
    ax.set_ylim(-0.5, top * 1.5)


def _check_convergence_axes(ax, panels: int):
    from matplotlib.axes import Axes

    if panels == 1:
        if not isinstance(ax, Axes):
            raise BayesmapError(f"ax must be a matplotlib Axes, got {type(ax).__name__}")
        return [ax]
    axes = list(ax) if isinstance(ax, (list, tuple, np.ndarray)) else [ax]
    if len(axes) != 2 or not all(isinstance(a, Axes) for a in axes):
        got = f"{len(axes)} items" if isinstance(ax, (list, tuple, np.ndarray)) else type(ax).__name__
        raise BayesmapError(f"with wrong_cells, ax must be a pair of Axes (log joint, wrong cells), got {got}")
    return axes


def plot_convergence(
    log_joints,
    wrong_cells=None,
    *,
    title="Convergence",
    burn_in=None,
    truth_log_joint=None,
    ax=None,
) -> Figure:
    """Draw the log joint of each chain's sample after each sweep and, optionally, its wrong visible cells.

    Args:
        log_joints: ``(num_sweeps,)`` (one chain) or ``(num_chains, num_sweeps)``: ``log p(walls, readings)`` of
            the map after sweep ``t + 1`` (e.g. :func:`bayesmap.model.generative.log_joint` of each sample), natural log.
        wrong_cells: integer counts of the same shape: the visible cells where the sample after each sweep
            disagrees with the true map (:meth:`bayesmap.scenes.Problem.wrong_visible_cells`). Adds a second
            panel below, sharing the sweep axis, with a dotted line at 2 (the tutorial's accuracy).
        title: the title of the top panel.
        burn_in: number of leading sweeps dropped before averaging (0 <= burn_in < num_sweeps); a dashed vertical
            line at ``burn_in + 0.5`` (between the last dropped and the first kept sweep) in each panel.
        truth_log_joint: the log joint of the true map; a horizontal line labelled "true map".
        ax: draw into this Axes (or, with ``wrong_cells``, this pair of Axes: log joint, wrong cells) instead of
            a new figure.

    Returns:
        The Figure: ``fig.axes`` is ``[log joint]`` or ``[log joint, wrong cells]`` (a new figure). Chain ``k``
        is the line with gid ``"chain-{k}"`` (``"wrong-{k}"`` in the lower panel), x = sweep 1 .. num_sweeps.
        Up to 6 chains get a colour, line style and marker each and a legend entry; more chains are shaded along
        a sequential colour map (dark = chain 0) with one legend entry. Other gids: ``"truth-log-joint"``,
        ``"burn-in"`` (one per panel), ``"tutorial-accuracy"`` (the line at 2 wrong cells) and ``"off-scale"``.

        Y range of the log joint: early sweeps are often 10^3 to 10^5 below the converged values, so the y axis
        is clipped (linear scale) to the range of the last 80% of the sweeps (and the true map's log joint) plus
        a margin; lines leave the axes where they are lower, and a note (gid ``"off-scale"``) beside the axes
        counts the points outside and gives the lowest one. The wrong-cells panel is linear up to 20 cells and
        symmetric-log above (linear below 10 cells).

    Raises:
        BayesmapError: if ``log_joints`` is empty, not 1-D or 2-D, or has a NaN or infinite value (names it);
            if ``wrong_cells`` does not have the same shape or is not integers >= 0; on a bad ``burn_in`` or
            ``truth_log_joint``; or if ``ax`` is not an Axes (a pair of Axes with ``wrong_cells``).
    """
    values = _check_traces(log_joints, "log_joints")
    wrong = None if wrong_cells is None else _check_wrong_cells(wrong_cells, values.shape)
    values = np.atleast_2d(values)
    num_chains, num_sweeps = values.shape
    if wrong is not None:
        wrong = np.atleast_2d(wrong)
    burn_in = None if burn_in is None else _check_burn_in(burn_in, num_sweeps)
    truth = None if truth_log_joint is None else _check_number(truth_log_joint, "truth_log_joint")
    panels = 1 if wrong is None else 2
    shared = ax is None
    if shared:
        fig = _new_figure((8.0, 4.4) if panels == 1 else (8.0, 7.0))
        axes = fig.subplots(panels, 1, sharex=True, squeeze=False, height_ratios=[3, 2][:panels])[:, 0]
    else:
        axes = _check_convergence_axes(ax, panels)
        fig = axes[0].get_figure(root=True)
    sweeps = np.arange(1, num_sweeps + 1)
    styles = _chain_styles(num_chains)
    top = axes[0]
    _draw_chains(top, sweeps, values, styles, "chain")
    if truth is not None:
        top.axhline(
            truth, color=TRUTH_COLOR, linestyle=(0, (6, 2, 1, 2)), linewidth=1.6, zorder=4,
            gid="truth-log-joint", label="true map",
        )
    _clip_to_converged(top, values, truth)
    top.set_ylabel("log joint  log p(walls, readings)")
    top.set_title(title)
    if wrong is not None:
        bottom = axes[1]
        _draw_chains(bottom, sweeps, wrong, styles, "wrong")
        bottom.axhline(
            TUTORIAL_WRONG_CELLS, color="black", linestyle=":", linewidth=1.5, zorder=4,
            gid="tutorial-accuracy", label="2 wrong (tutorial's accuracy)",
        )
        _wrong_cells_scale(bottom, wrong)
        bottom.set_ylabel("wrong visible cells")
    for k, panel in enumerate(axes):
        if burn_in is not None:
            panel.axvline(
                burn_in + 0.5, color=BURN_IN_COLOR, linestyle="--", linewidth=1.2, zorder=2, gid="burn-in",
                label=f"burn-in ({burn_in} sweep{'' if burn_in == 1 else 's'} dropped)" if k == 0 else "_nolegend_",
            )
        panel.set_xlim(0.5, num_sweeps + 0.5)
        panel.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
        panel.grid(True, color=GRIDLINE_COLOR, linewidth=0.5, zorder=0)
        handles, _ = panel.get_legend_handles_labels()
        if k == 0 and num_chains > MAX_LEGEND_CHAINS:
            handles.insert(0, _many_chains_handle(num_chains))
        if k == 1:  # the chains are already in the top legend
            handles = [h for h in handles if h.get_gid() == "tutorial-accuracy"]
        if handles:
            panel.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small",
                         frameon=False, borderaxespad=0.0)
    if shared:  # the panels share the sweep axis: label it once, at the bottom
        for panel in axes[:-1]:
            panel.tick_params(labelbottom=False)
        axes[-1].set_xlabel("sweep")
    else:
        for panel in axes:
            panel.set_xlabel("sweep")
    return fig


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
