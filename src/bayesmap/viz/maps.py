"""Map figures: the true map with a scan (:func:`plot_map`), the posterior wall probability alone (the occupancy grid,
:func:`plot_occupancy_map`) or optionally with its standard deviation and the robot's path (:func:`plot_posterior`,
:func:`plot_posterior_path`), and maps drawn from a prior side by side (:func:`plot_prior_samples`).

The posterior figures take ``seen``, the cells some beam crossed, and then show only those (their bounding box plus
a margin, the unseen cells in a neutral blue-grey): see :func:`bayesmap.viz.common.crop_extent`.

Every function returns a :class:`matplotlib.figure.Figure` (Agg canvas, never ``pyplot``); render it with
:func:`bayesmap.viz.common.figure_bytes` or save it with :func:`bayesmap.viz.common.save_figure`. The grid
conventions (cell ``(i, j)`` with ``i`` along x, images transposed with ``origin="lower"``, "cells" or "m" axes)
are those of :mod:`bayesmap.viz.common`.

Artists carry a ``gid`` so that callers and tests can find them: ``"walls"`` (the true walls: a
PatchCollection of cells, or an image plus a ``"walls_outline"`` path on maps with many wall cells), ``"truth"``
(outline of the true walls on a posterior: a PathPatch, one MOVETO/LINETO pair per edge), ``"posterior"`` and
``"std"`` (the heatmaps), ``"gridlines"``, ``"rays"`` (a LineCollection, one segment per ray from its origin to
its reading endpoint), ``"sensor"`` (a scatter of the sensor position(s)), ``"readings"`` and
``"max_range_readings"`` (scatters of the reading endpoints), ``"sensor_path"`` (the robot's path).

Large grids (10^6 cells, 10^5 wall edges, hundreds of rays) plot and save in about a second: heatmaps and
large wall sets are images, outlines are one compound path, rays one LineCollection.
"""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.viz.common import (
    MAP_WIDTH_INCHES,
    SENSOR_COLOR,
    TRUTH_COLOR,
    WALL_COLOR,
    WALL_EDGE_COLOR,
    check_cells,
    check_grid,
    check_point,
    check_seen,
    crop_extent,
    draw_cell_image,
    draw_gridlines,
    draw_legend,
    draw_truth,
    draw_walls,
    fit_colorbars,
    map_figsize,
    new_figure,
    setup_map_axes,
    unseen_handle,
)

__all__ = ["plot_map", "plot_occupancy_map", "plot_posterior", "plot_posterior_path", "plot_prior_samples"]

RAY_COLOR = "#1f78b4"
READING_COLOR = "#1f78b4"
MAX_RANGE_COLOR = "#7f7f7f"
PATH_COLOR = "tab:blue"
# Above this many rays, rays are faded and reading dots shrunk in proportion.
CROWDED_RAYS = 400


# ---------------------------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------------------------


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
    pos = None if pos is None else check_point(pos, "pos")
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


# ---------------------------------------------------------------------------------------------------------------
# Drawing helpers
# ---------------------------------------------------------------------------------------------------------------


def _draw_rays(ax, starts, endpoints, mask, *, faint: bool) -> list:
    """The rays (gid ``"rays"``), their endpoints (``"readings"``) and the max-range ones (``"max_range_readings"``);
    returns legend handles. With many rays (scans from many poses) the rays fade and the dots shrink so the map
    stays visible."""
    many = len(endpoints) > CROWDED_RAYS
    crowd = min(1.0, CROWDED_RAYS / max(len(endpoints), 1))
    ray_alpha = (0.25 if faint else 0.45) * max(crowd, 0.1)
    ax.add_collection(
        LineCollection(np.stack([starts, endpoints], axis=1), colors=RAY_COLOR, linewidths=0.5 if faint else 0.7,
                       alpha=ray_alpha, zorder=4, gid="rays"),
        autolim=False,
    )
    handles = [Line2D([], [], color=RAY_COLOR, lw=0.8, alpha=0.6, label="ray")]
    hit = endpoints[~mask]
    size = (10.0 if faint else 14.0) * max(np.sqrt(crowd), 0.15)
    ax.scatter(hit[:, 0], hit[:, 1], s=size, c=READING_COLOR, edgecolors="white" if not many else "none",
               linewidths=0.3, alpha=(0.8 if faint else 1.0) * (0.6 if many else 1.0), zorder=5, gid="readings",
               label="reading")
    handles.append(
        Line2D([], [], ls="none", marker="o", ms=4, color=READING_COLOR, mec="white", mew=0.3, label="reading")
    )
    if mask.any():
        far = endpoints[mask]
        ax.scatter(far[:, 0], far[:, 1], s=size * 1.6, facecolors="none", edgecolors=MAX_RANGE_COLOR,
                   linewidths=0.4 if many else 0.8, zorder=5, gid="max_range_readings", label="max-range reading")
        handles.append(
            Line2D([], [], ls="none", marker="o", ms=5, mfc="none", mec=MAX_RANGE_COLOR, label="max-range reading")
        )
    return handles


def _draw_sensors(ax, pos, starts) -> list:
    """The sensor (``pos``) or the distinct ray origins (``starts``) as red dots (gid ``"sensor"``); returns the
    legend handles (none when there is neither)."""
    if pos is not None:
        pts = pos[None, :]
    elif starts is not None:
        pts = np.unique(starts, axis=0)
    else:
        return []
    one = len(pts) == 1
    label = "sensor" if one else "sensor poses"
    ax.scatter(pts[:, 0], pts[:, 1], s=60 if one else 12, c=SENSOR_COLOR, edgecolors="white",
               linewidths=0.8 if one else 0.3, zorder=6, gid="sensor", label=label)
    return [Line2D([], [], ls="none", marker="o", ms=7, color=SENSOR_COLOR, mec="white", mew=0.8, label=label)]


def _draw_scan(ax, pos, starts, endpoints, mask, *, faint: bool) -> list:
    """Rays, reading endpoints and the sensor; returns legend handles (the sensor's first)."""
    handles = [] if endpoints is None else _draw_rays(ax, starts, endpoints, mask, faint=faint)
    return _draw_sensors(ax, pos, starts) + handles


def _map_panels(grid: Grid, panels, seen, extent, *, width: float = 5.0):
    """A figure of probability panels side by side, each ``width`` inches wide, an image of ``(gid, values, cmap,
    vmax, label, title)`` shown within ``extent`` with its colour bar; returns ``(fig, [(axes, colour bar), ...])``.
    The caller draws its overlays and legends, then calls :func:`~bayesmap.viz.common.fit_colorbars`."""
    fig = new_figure(map_figsize(extent, len(panels), colorbar=True, width=width))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    pairs = []
    for ax, (gid, values, cmap, vmax, label, panel_title) in zip(axes, panels):
        setup_map_axes(ax, grid, panel_title, extent)
        image = draw_cell_image(ax, grid, values, gid=gid, seen=seen, cmap=cmap, vmax=vmax, extent=extent)
        colorbar = fig.colorbar(image, ax=ax, label=label)
        colorbar.ax.set_ylim(0.0, vmax)
        pairs.append((ax, colorbar))
        draw_gridlines(ax, grid, alpha=0.35)
    return fig, pairs


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
    grid = check_grid(grid)
    walls = None if walls is None else check_cells(walls, grid, "walls")
    pos, starts, endpoints, mask = _check_scan(pos, beam_angles, readings, origins, max_range_mask)
    if ax is None:
        fig = new_figure(map_figsize(grid.extent, 1, colorbar=False))
        ax = fig.add_subplot()
    else:
        fig = ax.get_figure(root=True)
    if title is None:
        title = "True map" if walls is not None else "What the robot sees"
    setup_map_axes(ax, grid, title)
    draw_gridlines(ax, grid)
    handles = []
    if walls is not None:
        draw_walls(ax, walls, grid)
        handles.append(Patch(facecolor=WALL_COLOR, edgecolor=WALL_EDGE_COLOR, label="wall"))
    handles += _draw_scan(ax, pos, starts, endpoints, mask, faint=False)
    draw_legend(ax, handles)
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
    seen=None,
    focus=None,
    include=None,
) -> Figure:
    """Draw the posterior wall probability per cell as a heatmap (white = free, black = wall).

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        posterior: ``(nx, ny)`` posterior probability that each cell is a wall, in [0, 1].
        truth: ``(nx, ny)`` true map; its walls (cells > 0.5) are outlined in red.
        pos: sensor position(s) of the scan drawn on top, as in :func:`plot_map` (the scan is drawn thinner and
            semi-transparent).
        beam_angles: the scan's beam angles, as in :func:`plot_map`.
        readings: the scan's range readings, as in :func:`plot_map`.
        origins: the beams' origins, as in :func:`plot_map`.
        max_range_mask: which readings were max-range, as in :func:`plot_map`.
        title: the title of the probability panel; default "Posterior P(wall)".
        std: also draw a second panel with the posterior standard deviation ``sqrt(p (1 - p))`` (0 to 0.5).
        seen: ``(nx, ny)`` bool, the cells some beam crossed: every panel shows only their bounding box plus
            :data:`~bayesmap.viz.common.CROP_MARGIN` (clipped to the grid, see
            :func:`~bayesmap.viz.common.crop_extent`), the other cells in
            :data:`~bayesmap.viz.common.UNSEEN_COLOR`; None shows the whole grid.
        focus: ``(N, 2)`` world points where the map's content is (the returned beams' endpoints): the frame holds
            their central :data:`~bayesmap.viz.common.FOCUS_COVERAGE` on each axis
            (:func:`~bayesmap.viz.common.crop_extent`); None: the seen cells' box.
        include: ``(M, 2)`` world points the frame must hold with ``focus`` (the sensor path), or None.

    Returns:
        The Figure: ``fig.axes`` is ``[map, colour bar]`` (``[map, std map, colour bar, std colour bar]`` with
        ``std=True``). The heatmap is the image with gid ``"posterior"``; its colour bar is labelled "P(wall)"
        and spans 0 to 1. The layout is computed once and then frozen (so each colour bar is exactly as tall as
        its map); resizing the figure afterwards keeps the relative positions.

    Raises:
        BayesmapError: if ``posterior``, ``truth`` or ``seen`` does not have ``grid.shape``, ``posterior`` has a
            value outside [0, 1], ``seen`` is not bool, or the scan is malformed (see :func:`plot_map`).
    """
    grid = check_grid(grid)
    prob = check_cells(posterior, grid, "posterior", unit_interval=True)
    truth = None if truth is None else check_cells(truth, grid, "truth")
    seen = check_seen(seen, grid)
    pos, starts, endpoints, mask = _check_scan(pos, beam_angles, readings, origins, max_range_mask)
    panels = [("posterior", prob, "Greys", 1.0, "P(wall)", title or "Posterior P(wall)")]
    if std:
        panels.append(("std", np.sqrt(prob * (1.0 - prob)), "viridis", 0.5, "std. dev. sqrt(p(1 - p))",
                       "Posterior standard deviation"))
    fig, pairs = _map_panels(grid, panels, seen, crop_extent(grid, seen, focus=focus, include=include))
    for ax, _ in pairs:
        handles = []
        if truth is not None:
            draw_truth(ax, truth, grid)
            handles.append(Line2D([], [], color=TRUTH_COLOR, lw=1.4, label="true wall outline"))
        handles += _draw_scan(ax, pos, starts, endpoints, mask, faint=True)
        if seen is not None:
            handles.append(unseen_handle())
        draw_legend(ax, handles)
    fit_colorbars(fig, pairs)
    return fig


def plot_occupancy_map(grid, posterior, seen=None, title: str = "", focus=None) -> Figure:
    """The occupancy grid alone: the posterior wall probability per cell (white = free, black = wall), cropped to
    the cells some beam crossed.

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        posterior: ``(nx, ny)`` posterior probability that each cell is a wall, in [0, 1].
        seen: ``(nx, ny)`` bool, the cells some beam crossed (e.g.
            :func:`bayesmap.io.maps_out.seen_cells_along`): the axes show their bounding box plus
            :data:`~bayesmap.viz.common.CROP_MARGIN`, clipped to the grid, and the cells outside ``seen`` are drawn
            in :data:`~bayesmap.viz.common.UNSEEN_COLOR` (a legend entry says so); None shows the whole grid.
        title: the axes title ("" for none).
        focus: ``(N, 2)`` world points where the map's content is (the returned beams' endpoints): the frame holds
            their central :data:`~bayesmap.viz.common.FOCUS_COVERAGE` on each axis
            (:func:`~bayesmap.viz.common.crop_extent`); None: the seen cells' box.

    Returns:
        The Figure: ``fig.axes`` is ``[map, colour bar]``; axes in meters (cells on the unit grid); the image has
        gid ``"posterior"``, its colour bar is labelled "P(wall)" and spans 0 to 1, as tall as the map.

    Raises:
        BayesmapError: if ``posterior`` or ``seen`` does not have ``grid.shape``, ``posterior`` has a value outside
            [0, 1], or ``seen`` is not bool.
    """
    grid = check_grid(grid)
    prob = check_cells(posterior, grid, "posterior", unit_interval=True)
    seen = check_seen(seen, grid)
    fig, pairs = _map_panels(grid, [("posterior", prob, "Greys", 1.0, "P(wall)", title)], seen,
                             crop_extent(grid, seen, focus=focus), width=MAP_WIDTH_INCHES)
    if seen is not None:
        draw_legend(pairs[0][0], [unseen_handle()])
    fit_colorbars(fig, pairs)
    return fig


def plot_posterior_path(grid, posterior, path, *, title=None, std=False, seen=None, focus=None) -> Figure:
    """Draw the posterior of a whole log (:func:`plot_posterior` without a scan: a log has too many beams to draw)
    with the robot's path over every map panel.

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        posterior: ``(nx, ny)`` posterior probability that each cell is a wall, in [0, 1].
        path: the sensor poses in the order of the scans, world coordinates (meters): ``(S, 2)`` or any array of
            ``2 S`` numbers (reshaped to ``(S, 2)``, e.g. ``Problem.pos`` of a log).
        title: the title of the probability panel; default "Posterior P(wall)".
        std: also draw the posterior standard deviation panel (with the path too).
        seen: ``(nx, ny)`` bool, the cells some beam crossed: the panels are cropped to them, as in
            :func:`plot_posterior`; None shows the whole grid.
        focus: ``(N, 2)`` world points where the map's content is (the returned beams' endpoints): the frame holds
            their central :data:`~bayesmap.viz.common.FOCUS_COVERAGE` on each axis
            (:func:`~bayesmap.viz.common.crop_extent`); None: the seen cells' box. The path is always in the frame.

    Returns:
        The Figure of :func:`plot_posterior`; on each map panel the path is a thin, semi-transparent line above the
        map (zorder 4) with gid ``"sensor_path"`` (drawn after the legend, so not in it).

    Raises:
        BayesmapError: as :func:`plot_posterior`; or if ``path`` is not an even number of finite numbers.
    """
    try:
        points = np.asarray(path, dtype=np.float64).reshape(-1, 2)
    except (TypeError, ValueError):
        raise BayesmapError(f"path must be sensor positions of shape (S, 2), got shape {np.shape(path)}") from None
    if not np.all(np.isfinite(points)):
        k = int(np.argwhere(~np.isfinite(points))[0, 0])
        raise BayesmapError(f"path[{k}] is {points[k].tolist()!r}: sensor positions must be finite")
    fig = plot_posterior(grid, posterior, title=title, std=std, seen=seen, focus=focus, include=points)
    for ax in fig.axes[: 2 if std else 1]:  # the map panels (the colour bars come after them)
        ax.plot(points[:, 0], points[:, 1], color=PATH_COLOR, lw=0.6, alpha=0.6, zorder=4, label="sensor path",
                gid="sensor_path")
    return fig


def plot_prior_samples(grid, samples, titles=None, *, suptitle=None) -> Figure:
    """Maps drawn from a prior side by side, one panel each, walls drawn as on :func:`plot_map` (gid ``"walls"`` in
    every panel).

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        samples: ``(N, nx, ny)`` maps (cells > 0.5 are walls), ``1 <= N <= 8``; for example from
            :func:`bayesmap.model.prior.sample_prior`.
        titles: ``N`` panel titles; default "sample k: f walls" with the fraction ``f`` of wall cells.
        suptitle: a title over the panels, or None.

    Returns:
        The Figure.

    Raises:
        BayesmapError: on samples that are not ``(N, nx, ny)`` with ``1 <= N <= 8``, a non-finite value, or a number
            of titles other than ``N``.
    """
    grid = check_grid(grid)
    arr = np.asarray(samples)
    if arr.ndim != 3 or not 1 <= arr.shape[0] <= 8:
        raise BayesmapError(f"samples must have shape (N, nx, ny) with 1 <= N <= 8, got {arr.shape}")
    maps = [check_cells(m, grid, f"samples[{k}]") for k, m in enumerate(arr)]
    if titles is None:
        titles = [f"sample {k}: {float(np.mean(m > 0.5)):.2f} walls" for k, m in enumerate(maps)]
    if len(titles) != len(maps):
        raise BayesmapError(f"{len(maps)} samples need {len(maps)} titles, got {len(titles)}")
    width, height = map_figsize(grid.extent, 1, colorbar=False)
    fig = new_figure((min(len(maps) * (width - 0.4) * 0.75 + 0.4, 18.0), height * 0.75))
    for k, (walls, title) in enumerate(zip(maps, titles)):
        ax = fig.add_subplot(1, len(maps), k + 1)
        setup_map_axes(ax, grid, title)
        draw_walls(ax, walls, grid)
    if suptitle:
        fig.suptitle(suptitle)
    return fig
