"""The SLAM figure: the posterior map with the true path, the odometry path, posterior path samples and the 95 %
pose ellipses (:func:`plot_slam`), cropped to the cells the beams saw (``seen``), the paths drawn thin and
semi-transparent above the map so that they never hide its walls."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse, Patch

from bayesmap.errors import BayesmapError
from bayesmap.viz.common import (
    MAP_WIDTH_INCHES,
    TRUTH_COLOR,
    check_cells,
    check_grid,
    check_seen,
    crop_extent,
    draw_cell_image,
    draw_gridlines,
    draw_legend,
    draw_truth,
    fit_colorbars,
    is_unit_grid,
    map_figsize,
    new_figure,
    setup_map_axes,
    unseen_handle,
)

TRUE_PATH_COLOR = "#2ca02c"
ODOMETRY_COLOR = "#ff7f0e"
SAMPLE_COLOR = "#1f77b4"
MEAN_COLOR = "#08519c"
ELLIPSE_COLOR = "#2171b5"
CHI2_2D_95 = -2.0 * math.log(0.05)
"""The 95 % quantile of the chi-square distribution with 2 degrees of freedom (``-2 ln 0.05``, about 5.99): a 2-D
Normal's 95 % ellipse is ``d^T Sigma^-1 d <= CHI2_2D_95``."""
MAX_SAMPLE_PATHS = 40
"""At most this many posterior path samples are drawn (evenly spaced over the kept sweeps)."""
MAX_MARKED_POSES = 50
"""Paths of at most this many poses are drawn with a marker per pose; longer ones (a real log's hundreds of scans)
with thin, semi-transparent lines and no markers, the odometry faint, so that the walls stay visible."""
MAX_ELLIPSES = 60
"""At most this many 95 % ellipses are drawn: on longer paths, poses evenly spaced along the path's length, plus the
pose with the largest position standard deviation."""


def _path(name: str, poses, count: int | None = None) -> np.ndarray:
    """``poses`` as a finite float64 ``(S, 3)`` array (``S == count`` if given), else a BayesmapError naming it."""
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or (count is not None and len(p) != count):
        want = f"({count}, 3)" if count is not None else "(S, 3)"
        raise BayesmapError(f"{name} must have shape {want} (x, y, theta per scan), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise BayesmapError(f"{name} must be finite")
    return p


def ellipse_95(mean_xy, cov_xy) -> Ellipse | None:
    """The 95 % ellipse of a 2-D Normal with mean ``mean_xy`` ``(2,)`` and covariance ``cov_xy`` ``(2, 2)`` (m, m^2),
    as a matplotlib Ellipse (width and height the full axes, angle in degrees), or None for a zero covariance."""
    values, vectors = np.linalg.eigh(np.asarray(cov_xy, dtype=np.float64))
    values = np.clip(values, 0.0, None)
    if values.max() <= 0:
        return None
    width, height = 2.0 * np.sqrt(CHI2_2D_95 * values[::-1])
    angle = math.degrees(math.atan2(vectors[1, 1], vectors[0, 1]))
    return Ellipse(tuple(mean_xy), width, height, angle=angle, fill=False, edgecolor=ELLIPSE_COLOR, lw=1.0, zorder=6)


def ellipse_poses(mean_path, sd, max_count: int = MAX_ELLIPSES) -> np.ndarray:
    """The poses whose ellipses are drawn: all of them up to ``max_count``; else ``max_count`` poses evenly spaced
    along the length of the path, plus the one with the largest position standard deviation.

    Args:
        mean_path: ``(S, >= 2)`` poses, x and y first (meters).
        sd: ``(S,)`` each pose's largest position standard deviation.
        max_count: the most poses to pick before the largest-sd one, >= 1.

    Returns:
        ``(E,)`` int64 increasing pose indexes, ``E <= max_count + 1``.
    """
    count = len(mean_path)
    if count <= max_count:
        return np.arange(count)
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(mean_path[:, :2], axis=0).T))])
    if travelled[-1] > 0:
        picks = np.searchsorted(travelled, np.linspace(0.0, travelled[-1], max_count))
    else:
        picks = np.linspace(0, count - 1, max_count).astype(np.int64)
    return np.unique(np.append(np.minimum(picks, count - 1), np.argmax(sd)))


def _check_slam(grid, posterior, mean_path, pose_cov, samples, seen):
    """The inputs of :func:`plot_slam`, checked: ``(grid, prob, mean, cov, paths, seen)``."""
    grid = check_grid(grid)
    prob = check_cells(posterior, grid, "posterior", unit_interval=True)
    mean = _path("mean_path", mean_path)
    s = len(mean)
    cov = np.asarray(pose_cov, dtype=np.float64)
    if cov.shape != (s, 3, 3) or not np.all(np.isfinite(cov)):
        raise BayesmapError(f"pose_cov must be finite with shape ({s}, 3, 3), got {cov.shape}")
    paths = np.asarray(samples, dtype=np.float64)
    if paths.ndim != 3 or paths.shape[1:] != (s, 3) or not np.all(np.isfinite(paths)):
        raise BayesmapError(f"samples must be finite with shape (N, {s}, 3), got {paths.shape}")
    return grid, prob, mean, cov, paths, check_seen(seen, grid)


def _marked(many: bool, marker: str, size: float | None = None) -> dict:
    """Line2D marker keywords: a marker per pose on short paths, none on long ones."""
    return {} if many else {"marker": marker} if size is None else {"marker": marker, "ms": size}


def _draw_samples(ax, paths, many: bool) -> list:
    """Up to :data:`MAX_SAMPLE_PATHS` posterior path samples as faint lines (gid ``"path_samples"`` on the first)."""
    picks = np.unique(np.linspace(0, len(paths) - 1, min(len(paths), MAX_SAMPLE_PATHS)).astype(int))
    for k, i in enumerate(picks):
        ax.plot(paths[i, :, 0], paths[i, :, 1], color=SAMPLE_COLOR, lw=0.3 if many else 0.6, alpha=0.25 if many
                else 0.35, zorder=4, gid="path_samples" if k == 0 else None)
    return [Line2D([], [], color=SAMPLE_COLOR, lw=1, alpha=0.6, label="posterior samples")]


def _draw_reference_paths(ax, true_path, odometry, s: int, many: bool, extent) -> list:
    """The odometry (orange, dashed, gid ``"odometry"``) and the true path (green, gid ``"true_path"``, with heading
    ticks on short paths), each if given."""
    handles = []
    if odometry is not None:
        odo = _path("odometry", odometry, s)
        style = _marked(many, "s", 3.5)
        ax.plot(odo[:, 0], odo[:, 1], "--", color=ODOMETRY_COLOR, lw=0.7 if many else 1.4,
                alpha=0.5 if many else None, zorder=4.5, gid="odometry", **style)
        handles.append(Line2D([], [], ls="--", color=ODOMETRY_COLOR, alpha=0.5 if many else None,
                              label="odometry", **style))
    if true_path is not None:
        true = _path("true_path", true_path, s)
        style = _marked(many, "o", 4)
        ax.plot(true[:, 0], true[:, 1], color=TRUE_PATH_COLOR, lw=0.8 if many else 1.6, alpha=0.7 if many else None,
                zorder=5, gid="true_path", **style)
        if not many:
            tick = 0.04 * max(extent[1] - extent[0], extent[3] - extent[2])
            ax.quiver(true[:, 0], true[:, 1], np.cos(true[:, 2]) * tick, np.sin(true[:, 2]) * tick, angles="xy",
                      scale_units="xy", scale=1, color=TRUE_PATH_COLOR, width=0.004, zorder=5)
        handles.append(Line2D([], [], color=TRUE_PATH_COLOR, label="true path", **style))
    return handles


def _draw_ellipses(ax, mean, cov, many: bool, unit: str) -> list:
    """The 95 % ellipses of the poses :func:`ellipse_poses` picks (gid ``"ellipses"`` on the first)."""
    sd = np.sqrt(np.clip(np.linalg.eigvalsh(cov[:, :2, :2])[:, -1], 0.0, None))  # each pose's largest position sd
    picks = ellipse_poses(mean, sd)
    ellipses = [e for e in (ellipse_95(mean[i, :2], cov[i, :2, :2]) for i in picks) if e is not None]
    for k, e in enumerate(ellipses):
        e.set_gid("ellipses" if k == 0 else None)
        e.set_linewidth(0.6 if many else 1.0)
        e.set_alpha(0.7 if many else None)
        ax.add_patch(e)
    shown = "" if len(picks) == len(mean) else f", {len(picks)} of {len(mean)} poses"
    return [Patch(facecolor="none", edgecolor=ELLIPSE_COLOR,
                  label=f"95 % ellipses{shown} (largest sd {sd.max():.2g} {unit})")]


def plot_slam(grid, posterior, mean_path, pose_cov, samples, *, true_path=None, odometry=None, truth=None,
              title: str | None = None, seen=None, focus=None) -> Figure:
    """The posterior map of a SLAM run with its paths.

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        posterior: ``(nx, ny)`` posterior wall probabilities in [0, 1].
        mean_path: ``(S, 3)`` posterior mean poses (x m, y m, theta rad): a blue line with a dot per scan (up to
            :data:`MAX_MARKED_POSES` poses; beyond, every line thin, semi-transparent and without markers, the
            odometry faint).
        pose_cov: ``(S, 3, 3)`` pose covariances: the 95 % ellipse of each position (its ``(x, y)`` block), of
            every pose up to :data:`MAX_ELLIPSES`, else of those :func:`ellipse_poses` picks.
        samples: ``(N, S, 3)`` posterior path samples: up to :data:`MAX_SAMPLE_PATHS` faint blue lines.
        true_path: optional ``(S, 3)`` true poses (green, with the heading as a short tick on short paths).
        odometry: optional ``(S, 3)`` odometry poses (orange, dashed; a real log's drifts off the map, clipped to
            the axes).
        truth: optional ``(nx, ny)`` true map (red outline).
        title: the axes' title; default "Posterior P(wall) and path".
        seen: optional ``(nx, ny)`` bool, the cells some beam crossed (e.g.
            :func:`bayesmap.io.maps_out.seen_cells_along` along ``mean_path``): the axes show their bounding box
            plus :data:`~bayesmap.viz.common.CROP_MARGIN`, clipped to the grid
            (:func:`~bayesmap.viz.common.crop_extent`), the other cells in
            :data:`~bayesmap.viz.common.UNSEEN_COLOR`; None shows the whole grid.
        focus: optional ``(N, 2)`` world points where the map's content is (the returned beams' endpoints at
            ``mean_path``): the frame holds their central :data:`~bayesmap.viz.common.FOCUS_COVERAGE` on each axis,
            and the whole mean path (:func:`~bayesmap.viz.common.crop_extent`); None: the seen cells' box.

    Returns:
        A Figure with one map panel and a colour bar as tall as the map; artists carry gids ``"posterior"`` (the
        map, zorder 1), ``"path_samples"``, ``"odometry"``, ``"true_path"``, ``"mean_path"``, ``"ellipses"`` (all
        above the map, zorder 4 to 6).

    Raises:
        BayesmapError: on a bad grid, arrays of the wrong shapes or non-finite values, or ``seen`` not an
            ``(nx, ny)`` bool array (the message names them).
    """
    grid, prob, mean, cov, paths, seen = _check_slam(grid, posterior, mean_path, pose_cov, samples, seen)
    extent = crop_extent(grid, seen, focus=focus, include=mean[:, :2])
    fig = new_figure(map_figsize(extent, 1, colorbar=True, width=MAP_WIDTH_INCHES))
    ax = fig.add_subplot(1, 1, 1)
    setup_map_axes(ax, grid, title or "Posterior P(wall) and path", extent)
    image = draw_cell_image(ax, grid, prob, gid="posterior", seen=seen, extent=extent)
    colorbar = fig.colorbar(image, ax=ax, label="P(wall)")
    if is_unit_grid(grid):
        draw_gridlines(ax, grid, alpha=0.4)
    handles = []
    if truth is not None:
        draw_truth(ax, check_cells(truth, grid, "truth"), grid)
        handles.append(Patch(facecolor="none", edgecolor=TRUTH_COLOR, label="true walls"))
    many = len(mean) > MAX_MARKED_POSES
    handles += _draw_samples(ax, paths, many)
    handles += _draw_reference_paths(ax, true_path, odometry, len(mean), many, extent)
    ax.plot(mean[:, 0], mean[:, 1], color=MEAN_COLOR, lw=0.8 if many else 1.4, alpha=0.7 if many else None,
            zorder=5.5, gid="mean_path", **_marked(many, ".", 5))
    handles.append(Line2D([], [], color=MEAN_COLOR, label="posterior mean", **_marked(many, ".")))
    handles += _draw_ellipses(ax, mean, cov, many, "cells" if is_unit_grid(grid) else "m")
    if seen is not None:
        handles.append(unseen_handle())
    draw_legend(ax, handles)
    fit_colorbars(fig, [(ax, colorbar)])
    return fig


def slam_report(png: bytes, summary: dict, title: str = "bayesmap slam") -> str:
    """A small self-contained HTML report of a SLAM run: the figure (``png``, embedded as base64) and every entry
    of ``summary`` (nested dicts flattened to dotted keys) in a table, escaped. Never raises for JSON-like input."""
    import base64
    import html

    def rows(d, prefix=""):
        for key, value in d.items():
            if isinstance(value, dict):
                yield from rows(value, f"{prefix}{key}.")
            else:
                shown = f"{value:.4g}" if isinstance(value, float) else str(value)
                yield f"<tr><th>{html.escape(prefix + str(key))}</th><td>{html.escape(shown)}</td></tr>"

    image = base64.b64encode(png).decode("ascii")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>body{{font-family:sans-serif;margin:2em;max-width:60em}}"
            "th{text-align:left;padding-right:2em;font-weight:normal;color:#555}td{font-family:monospace}</style>"
            f"</head><body><h1>{html.escape(title)}</h1>"
            f"<img alt=\"posterior map and paths\" src=\"data:image/png;base64,{image}\" style=\"max-width:100%\">"
            f"<h2>Summary</h2><table>{''.join(rows(summary))}</table></body></html>\n")
