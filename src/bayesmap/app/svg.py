"""The explorer's drawing as SVG: the grid, the inferred walls (cell opacity or a heatmap), the true walls, the
beams and readings and the sensor, or in path mode the drawn path and the last SLAM run's odometry, pose samples and
posterior mean path. Plain strings, read by the tests and shown by the page (:mod:`bayesmap.app.page`).

Pixels: cell ``(i, j)`` spans ``cell_px`` pixels; y grows up in the world and down on screen
(:meth:`bayesmap.app.explorer.Explorer.to_px`).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from bayesmap.app.explorer import Explorer


def draw(ex: Explorer, shown: np.ndarray | None = None, heatmap: bool = False) -> str:
    """The SVG content of the explorer's drawing: grid, inferred walls ``shown`` (``(nx, ny)`` probabilities, as
    opacity or heatmap), true walls, and the beams, readings and sensor (in path mode :func:`path_layer` instead).
    Elements carry classes and ``data-i``/``data-j`` (and ``data-p`` for inferred cells) so that tests can read the
    drawing."""
    s = ex.cell_px()
    nx, ny = ex.grid.shape
    width, height = nx * s, ny * s
    out = [f'<rect x="0" y="0" width="{width}" height="{height}" fill="white" stroke="#999"/>']
    if s >= 8:
        lines = [f"M{i * s} 0V{height}" for i in range(1, nx)] + [f"M0 {j * s}H{width}" for j in range(1, ny)]
        out.append(f'<path d="{" ".join(lines)}" stroke="#eee" stroke-width="1"/>')
    if shown is not None:
        colors = heat_colors() if heatmap else None
        for i, j in zip(*np.nonzero(shown > 0.005 if not heatmap else np.ones_like(shown, bool))):
            p = float(shown[i, j])
            x, y = i * s, (ny - 1 - j) * s
            if heatmap:
                style = f'fill="{colors[int(round(p * 255))]}"'
            else:
                style = f'fill="#d62728" fill-opacity="{p:.3f}"'
            out.append(f'<rect class="inferred" data-i="{i}" data-j="{j}" data-p="{p:.3f}" x="{x}" y="{y}" '
                       f'width="{s}" height="{s}" {style}/>')
    for i, j in zip(*np.nonzero(ex.walls > 0.5)):
        x, y = i * s, (ny - 1 - j) * s
        if heatmap and shown is not None:
            out.append(f'<rect class="wall" data-i="{i}" data-j="{j}" x="{x + 1}" y="{y + 1}" width="{s - 2}" '
                       f'height="{s - 2}" fill="none" stroke="black" stroke-width="2"/>')
        else:
            inset = max(1, s // 5) if shown is not None else 0
            out.append(f'<rect class="wall" data-i="{i}" data-j="{j}" x="{x + inset}" y="{y + inset}" '
                       f'width="{s - 2 * inset}" height="{s - 2 * inset}" fill="#333"/>')
    if ex.path_mode:
        out.append(path_layer(ex))
        return "".join(out)
    hits, readings = ex.beams()
    sx, sy = ex.to_px(ex.pos)
    hx, hy = ex.to_px(hits)
    path = " ".join(f"M{sx:.1f} {sy:.1f}L{a:.1f} {b:.1f}" for a, b in zip(hx, hy))
    out.append(f'<path class="beams" d="{path}" stroke="#1f77b4" stroke-opacity="0.35" stroke-width="1"/>')
    rx, ry = ex.to_px(readings)
    radius = max(1.5, s / 8)
    out.append('<g class="readings" fill="#1f77b4">'
               + "".join(f'<circle cx="{a:.1f}" cy="{b:.1f}" r="{radius:.1f}"/>' for a, b in zip(rx, ry)) + "</g>")
    out.append(f'<circle class="sensor" cx="{sx:.1f}" cy="{sy:.1f}" r="{max(4.0, s * 0.4):.1f}" fill="#ff7f0e" '
               'stroke="black" stroke-width="1.5" style="cursor: grab">'
               '<title>sensor: drag to move</title></circle>')
    return "".join(out)


def path_layer(ex: Explorer) -> str:
    """The path mode's layer: the drawn path (orange) with its numbered poses and headings; after a SLAM run,
    above it, the odometry (grey dashes), the pose samples (small purple dots) and the posterior mean path
    (green)."""
    s = ex.cell_px()
    out = []
    if ex.path:
        true = ex.true_path()
        out.append(polyline(ex, true, "path", 'stroke="#ff7f0e" stroke-width="1.5"'))
        px, py = ex.to_px(true[:, :2])
        r = max(4.0, s * 0.35)
        for k, (a, b, t) in enumerate(zip(px, py, true[:, 2])):
            hx, hy = a + 1.6 * r * np.cos(t), b - 1.6 * r * np.sin(t)
            out.append(f'<g class="pose" data-k="{k}"><line x1="{a:.1f}" y1="{b:.1f}" x2="{hx:.1f}" '
                       f'y2="{hy:.1f}" stroke="black" stroke-width="1.5"/><circle cx="{a:.1f}" cy="{b:.1f}" '
                       f'r="{r:.1f}" fill="#ff7f0e" fill-opacity="0.6" stroke="black"/><text x="{a:.1f}" '
                       f'y="{b:.1f}" font-size="{r * 1.3:.0f}" text-anchor="middle" '
                       f'dominant-baseline="central">{k + 1}</text></g>')
    if ex.slam is not None:
        res = ex.slam.result
        out.append(polyline(ex, ex.slam.problem.odometry, "odometry",
                             'stroke="#777" stroke-width="2" stroke-dasharray="5 3"'))
        samples = res.pose_samples[:: max(1, len(res.pose_samples) // 100)].reshape(-1, 3)
        sx, sy = ex.to_px(samples[:, :2])
        out.append('<g class="pose-samples" fill="#9467bd" fill-opacity="0.5">' + "".join(
            f'<circle class="pose-sample" cx="{a:.1f}" cy="{b:.1f}" r="2"/>' for a, b in zip(sx, sy)) + "</g>")
        out.append(polyline(ex, res.mean_path, "mean-path", 'stroke="#2ca02c" stroke-width="2"'))
    return "".join(out)


def polyline(ex: Explorer, xy, cls: str, style: str) -> str:
    """An SVG polyline of world points ``xy`` ``(S, 2+)`` (meters) with class ``cls``."""
    px, py = ex.to_px(np.asarray(xy, dtype=np.float64)[:, :2])
    points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(px, py))
    return f'<polyline class="{cls}" points="{points}" fill="none" {style}/>'


@functools.cache
def heat_colors() -> tuple[str, ...]:
    """256 hex colors of matplotlib's "viridis" colormap, for probabilities 0..1."""
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    cmap = colormaps["viridis"]
    return tuple(to_hex(cmap(k / 255)) for k in range(256))


def legend_gradient(heatmap: bool) -> str:
    """CSS gradient of the drawing's colour scale for probabilities 0..1 (heatmap, or red opacity on white)."""
    if heatmap:
        colors = heat_colors()
        return "linear-gradient(to right, " + ", ".join(colors[k] for k in range(0, 256, 51)) + ")"
    return "linear-gradient(to right, rgba(214, 39, 40, 0), rgba(214, 39, 40, 1))"
