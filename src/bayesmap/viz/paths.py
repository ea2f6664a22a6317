"""The SLAM figure: the posterior map with the true path, the odometry path, posterior path samples and the 95 %
pose ellipses (:func:`plot_slam`)."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse, Patch

from bayesmap.errors import BayesmapError
from bayesmap.viz.common import (
    check_cells,
    check_grid,
    draw_gridlines,
    draw_legend,
    draw_truth,
    image_interpolation,
    is_unit_grid,
    new_figure,
    setup_map_axes,
)

TRUE_PATH_COLOR = "#2ca02c"
ODOMETRY_COLOR = "#ff7f0e"
SAMPLE_COLOR = "#1f77b4"
MEAN_COLOR = "#08306b"
CHI2_2D_95 = -2.0 * math.log(0.05)
"""The 95 % quantile of the chi-square distribution with 2 degrees of freedom (``-2 ln 0.05``, about 5.99): a 2-D
Normal's 95 % ellipse is ``d^T Sigma^-1 d <= CHI2_2D_95``."""
MAX_SAMPLE_PATHS = 40
"""At most this many posterior path samples are drawn (evenly spaced over the kept sweeps)."""
MAX_MARKED_POSES = 50
"""Paths of at most this many poses are drawn with a marker per pose; longer ones (a real log's hundreds of scans)
with thin lines and no markers, the odometry faint, so that every ellipse stays visible."""


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
    return Ellipse(tuple(mean_xy), width, height, angle=angle, fill=False, edgecolor=MEAN_COLOR, lw=1.0, zorder=6)


def plot_slam(grid, posterior, mean_path, pose_cov, samples, *, true_path=None, odometry=None, truth=None,
              title: str | None = None) -> Figure:
    """The posterior map of a SLAM run with its paths.

    Args:
        grid: the :class:`~bayesmap.geometry.grid.Grid`.
        posterior: ``(nx, ny)`` posterior wall probabilities in [0, 1].
        mean_path: ``(S, 3)`` posterior mean poses (x m, y m, theta rad): a dark line with a dot per scan (up to
            :data:`MAX_MARKED_POSES` poses; beyond, every line thin and without markers, the odometry faint).
        pose_cov: ``(S, 3, 3)`` pose covariances: the 95 % ellipse of each position (its ``(x, y)`` block), every
            one drawn.
        samples: ``(N, S, 3)`` posterior path samples: up to :data:`MAX_SAMPLE_PATHS` thin blue lines.
        true_path: optional ``(S, 3)`` true poses (green, with the heading as a short tick).
        odometry: optional ``(S, 3)`` odometry poses (orange, dashed; a real log's drifts off the map, clipped to
            the grid).
        truth: optional ``(nx, ny)`` true map (red outline).
        title: the axes' title; default "Posterior P(wall) and path".

    Returns:
        A Figure with one map panel and a colour bar; artists carry gids ``"posterior"``, ``"path_samples"``,
        ``"mean_path"``, ``"ellipses"``, ``"true_path"``, ``"odometry"``.

    Raises:
        BayesmapError: on a bad grid, arrays of the wrong shapes or non-finite values (the message names them).
    """
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
    fig = new_figure((7.2, 6.6))
    ax = fig.add_subplot(1, 1, 1)
    setup_map_axes(ax, grid, title or "Posterior P(wall) and path")
    image = ax.imshow(prob.T, origin="lower", extent=grid.extent, cmap="Greys", vmin=0, vmax=1,
                      interpolation=image_interpolation(grid), gid="posterior")
    fig.colorbar(image, ax=ax, shrink=0.8, label="P(wall)")
    if is_unit_grid(grid):
        draw_gridlines(ax, grid, alpha=0.4)
    handles = []
    if truth is not None:
        draw_truth(ax, check_cells(truth, grid, "truth"), grid)
        handles.append(Patch(facecolor="none", edgecolor="#d62728", label="true walls"))
    many = s > MAX_MARKED_POSES
    thin = 0.5 if many else 1.0  # line width factor

    def marked(marker: str, size: float | None = None) -> dict:  # a marker per pose, on short paths only
        return {} if many else {"marker": marker} if size is None else {"marker": marker, "ms": size}

    picks = np.unique(np.linspace(0, len(paths) - 1, min(len(paths), MAX_SAMPLE_PATHS)).astype(int))
    for k, i in enumerate(picks):
        ax.plot(paths[i, :, 0], paths[i, :, 1], color=SAMPLE_COLOR, lw=0.6 * thin, alpha=0.35, zorder=4,
                gid="path_samples" if k == 0 else None)
    handles.append(Line2D([], [], color=SAMPLE_COLOR, lw=1, alpha=0.6, label="posterior samples"))
    if odometry is not None:
        odo = _path("odometry", odometry, s)
        style = marked("s", 3.5)
        ax.plot(odo[:, 0], odo[:, 1], "--", color=ODOMETRY_COLOR, lw=1.4 * thin, alpha=0.5 if many else None,
                zorder=5, gid="odometry", **style)
        handles.append(Line2D([], [], ls="--", color=ODOMETRY_COLOR, alpha=0.5 if many else None,
                              label="odometry", **style))
    if true_path is not None:
        true = _path("true_path", true_path, s)
        style = marked("o", 4)
        ax.plot(true[:, 0], true[:, 1], color=TRUE_PATH_COLOR, lw=1.6 * thin, zorder=5, gid="true_path", **style)
        if not many:
            tick = 0.04 * max(grid.extent[1] - grid.extent[0], grid.extent[3] - grid.extent[2])
            ax.quiver(true[:, 0], true[:, 1], np.cos(true[:, 2]) * tick, np.sin(true[:, 2]) * tick, angles="xy",
                      scale_units="xy", scale=1, color=TRUE_PATH_COLOR, width=0.004, zorder=5)
        handles.append(Line2D([], [], color=TRUE_PATH_COLOR, label="true path", **style))
    ax.plot(mean[:, 0], mean[:, 1], color=MEAN_COLOR, lw=1.4 * thin, zorder=6, gid="mean_path", **marked(".", 5))
    handles.append(Line2D([], [], color=MEAN_COLOR, label="posterior mean", **marked(".")))
    ellipses = [e for e in (ellipse_95(m[:2], c[:2, :2]) for m, c in zip(mean, cov)) if e is not None]
    for k, e in enumerate(ellipses):
        e.set_gid("ellipses" if k == 0 else None)
        e.set_linewidth(0.4 if many else 1.0)
        ax.add_patch(e)
    sd = np.sqrt(np.clip(np.linalg.eigvalsh(cov[:, :2, :2])[:, -1], 0.0, None))  # each pose's largest position sd
    unit = "cells" if is_unit_grid(grid) else "m"
    handles.append(Patch(facecolor="none", edgecolor=MEAN_COLOR,
                         label=f"95 % ellipses (largest sd {sd.max():.2g} {unit})"))
    draw_legend(ax, handles)
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
