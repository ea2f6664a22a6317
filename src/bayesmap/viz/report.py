"""``report.html``: one self-contained, offline page with the settings, runtime, metrics, every figure and the
chain's animation of an inference run (``bayesmap demo``, ``bayesmap infer --report``).

Everything is inline: figures are PNG data URIs, the animation a GIF data URI plus the slider page of
:func:`bayesmap.viz.animation.chain_html` in an ``<iframe srcdoc>``; there is no script, style sheet, font or image
from anywhere else, so the file opens the same without a network.

The report only renders: the per-sweep log joints, wrong cells and the importance-sampling run it draws are
computed by the caller (:func:`bayesmap.inference.traces.chain_traces`) and passed in.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html

import numpy as np

from bayesmap.io.maps_out import seen_cells_in_pieces
from bayesmap.viz.animation import chain_animation
from bayesmap.viz.common import figure_bytes, is_unit_grid
from bayesmap.viz.diagnostics import plot_convergence, plot_importance
from bayesmap.viz.maps import plot_map, plot_posterior

__all__ = ["build_report"]

MAX_DRAWN_BEAMS = 3000  # beams drawn in the scan figures of a multi-scan problem (evenly spaced)

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 2em auto; max-width: 1100px;
       color: #222; line-height: 1.45; padding: 0 1em; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; } h2 { font-size: 1.25em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table.settings { border-collapse: collapse; font-size: 0.95em; }
table.settings td { padding: 0.2em 1.2em 0.2em 0; vertical-align: top; }
table.settings td:first-child { color: #555; }
.metrics { display: flex; flex-wrap: wrap; gap: 1em; margin: 1em 0; }
.metric { border: 1px solid #ccc; border-radius: 6px; padding: 0.6em 1em; min-width: 10em; }
.metric .value { font-size: 1.4em; font-weight: 600; } .metric .label { color: #555; font-size: 0.9em; }
figure { margin: 1.5em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { color: #444; font-size: 0.95em; margin-top: 0.3em; }
iframe.chain { width: 100%; height: 520px; border: 1px solid #ccc; }
"""


def _data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def _figure(png: bytes, caption: str, gid: str) -> str:
    alt = html.escape(caption, quote=True)
    return (f'<figure id="{gid}"><img src="{_data_uri(png, "image/png")}" alt="{alt}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _scan(problem) -> dict:
    """The scan keywords of :func:`~bayesmap.viz.maps.plot_map`: the one scan, or for several scans every beam of
    every scan, at most :data:`MAX_DRAWN_BEAMS` of them (evenly spaced) to keep the figures light."""
    if problem.multi_scan:
        keep = np.unique(np.linspace(0, problem.table.num_rays - 1,
                                     min(MAX_DRAWN_BEAMS, problem.table.num_rays)).astype(int))
        return dict(origins=problem.ray_origins[keep], beam_angles=problem.ray_angles[keep],
                    readings=problem.ray_readings[keep],
                    max_range_mask=None if problem.ray_max_range is None else problem.ray_max_range[keep])
    return dict(pos=problem.pos, beam_angles=problem.beam_angles, readings=problem.readings,
                max_range_mask=problem.max_range_mask)


def _map_figures(problem, result) -> list[str]:
    """The true map with the scan (when known), the scan alone and the posterior with its standard deviation."""
    summary = result.summary
    grid = problem.grid
    scan = _scan(problem)
    burn_in = int(summary["burn_in"])
    unit = "cells" if is_unit_grid(grid) else "m"
    figures = []
    if problem.truth is not None:
        figures.append(_figure(figure_bytes(plot_map(grid, problem.truth, title="The map, the rays and the readings",
                                                     **scan)),
                               "The true map (walls black), the sensor, its rays and the noisy readings (dots).",
                               "fig-map"))
    figures.append(_figure(figure_bytes(plot_map(grid, None, title="What the robot sees", **scan)),
                           f"The data alone: rays from the sensor to each reading, axes in {unit}.", "fig-scan"))
    # a real log's grid reaches as far as its longest beam: show the cells the beams crossed
    real_log = problem.multi_scan and problem.truth is None
    seen = seen_cells_in_pieces(problem.table_chunks(), problem.ray_readings, grid.shape) if real_log else None
    focus = problem.returned_endpoints if real_log else None
    figures.append(_figure(figure_bytes(plot_posterior(grid, result.posterior, truth=problem.truth, std=True,
                                                       title="Posterior wall probability", seen=seen, focus=focus,
                                                       include=np.reshape(problem.pos, (-1, 2)), **scan)),
                           f"Left: posterior probability that each cell is a wall (mean of sweeps {burn_in + 1}-"
                           f"{summary['sweeps']}{', all chains' if np.ndim(result.samples) == 4 else ''}); true walls "
                           "outlined when known. Right: posterior standard deviation (0 = certain, 0.5 = a coin flip).",
                           "fig-posterior"))
    return figures


def _importance_ess(traces) -> str | None:
    """"ESS of N" of the importance-sampling run, or None without one."""
    if traces.importance is None:
        return None
    return f"{float(traces.importance.ess):.2f} of {len(traces.importance.log_weights):,}"


def _diagnostic_figures(result, traces) -> list[str]:
    """The convergence of the chains and, when given, the importance weights."""
    summary = result.summary
    wrong = traces.wrong_cells
    figures = [_figure(figure_bytes(plot_convergence(traces.log_joints, wrong, burn_in=int(summary["burn_in"]),
                                                     truth_log_joint=summary.get("log_joint_truth"),
                                                     title="Convergence")),
                       "Log joint of each sweep's sample (higher is better)"
                       + ("; the true map's log joint for reference; below, visible cells each sample gets wrong."
                          if wrong is not None else ".") + " The dashed line ends the burn-in.", "fig-convergence")]
    imp = traces.importance
    if imp is not None:
        num = len(imp.log_weights)
        figures.append(_figure(figure_bytes(plot_importance(np.asarray(imp.log_weights), float(imp.ess))),
                               f"Importance sampling with {num:,} maps drawn from the prior: the "
                               f"normalized log-weights. Effective sample size {_importance_ess(traces)}: one map "
                               "takes (almost) all the weight, which is why the tutorial turns to Gibbs sampling.",
                               "fig-importance"))
    return figures


def _metrics_html(summary: dict, ess_text: str | None) -> str:
    """The boxes of headline numbers: runtime, accuracy, R-hat and ESS of the chains, log joint, importance ESS."""
    truth_lj = summary.get("log_joint_truth")
    metrics = [("runtime", f"{summary['runtime_s']:.2f} s", "compilation included")]
    if "wrong_visible_cells" in summary:
        metrics.append(("wrong visible cells", f"{summary['wrong_visible_cells']} of {summary['visible_cells']}",
                        "posterior mean rounded, against the true map"))
    if summary.get("r_hat_max") is not None:
        metrics.append(("worst split R-hat", f"{summary['r_hat_max']:.3f}", f"{summary['chains']} chains"))
        metrics.append(("smallest ESS", f"{summary['ess_min']:.0f}", "bulk effective sample size"))
    metrics.append(("log joint, last sample", f"{summary['log_joint_final_sample']:.1f}",
                    f"true map: {truth_lj:.1f}" if truth_lj is not None else "GenJAX assess"))
    if ess_text:
        metrics.append(("importance sampling ESS", ess_text, "particles"))
    return "".join(f'<div class="metric"><div class="value">{html.escape(v)}</div>'
                   f'<div class="label">{html.escape(k)}<br>{html.escape(note)}</div></div>'
                   for k, v, note in metrics)


def _settings_html(summary: dict) -> str:
    """The summary as table rows, one setting or metric per row."""
    rows = []
    for key, value in summary.items():
        if isinstance(value, float):
            value = f"{value:.6g}"
        elif isinstance(value, (dict, list)):
            value = ", ".join(f"{k}: {v}" for k, v in value.items()) if isinstance(value, dict) else str(value)
        rows.append(f"<tr><td>{html.escape(str(key))}</td><td>{html.escape(str(value))}</td></tr>")
    return "".join(rows)


def build_report(problem, result, traces, *, title: str, max_frames: int = 60) -> str:
    """The report of one run as an HTML string (UTF-8, self-contained). It only renders what it is given.

    Args:
        problem: the :class:`~bayesmap.scenes.Problem` that was solved (grid, scan, true map).
        result: its :class:`~bayesmap.inference.driver.InferenceResult` (``samples`` ``(T, nx, ny)`` or
            ``(C, T, nx, ny)`` bool, ``posterior`` ``(nx, ny)``, ``summary``).
        traces: the :class:`~bayesmap.inference.traces.ChainTraces` of the run (log joints and wrong cells per
            sweep, optional importance-sampling run: its figure and ESS are shown when it is not None).
        title: the page's title.
        max_frames: frames of the chain animation.
    """
    summary = result.summary
    grid = problem.grid
    samples = np.asarray(result.samples)
    figures = _map_figures(problem, result) + _diagnostic_figures(result, traces)
    chain = samples[0] if samples.ndim == 4 else samples
    gif, page = chain_animation(grid, chain, truth=problem.truth, pos=None if problem.multi_scan else problem.pos,
                                max_frames=max_frames,
                                title="Gibbs chain: sample and running mean")
    metric_html = _metrics_html(summary, _importance_ess(traces))
    stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    first_chain_note = " (first chain)" if samples.ndim == 4 else ""
    slider_srcdoc = html.escape(page, quote=True)
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>{html.escape(title)}</title><style>{_STYLE}</style></head>
<body>
<h1>{html.escape(title)}</h1>
<p>{html.escape(summary['source'])}: {summary['num_angles']} beams, grid {grid.shape[0]} x {grid.shape[1]} cells of
{grid.resolution:g} m; {html.escape(summary['sampler_description'])}, {summary['sweeps']} sweeps. Written by bayesmap
on {stamp}.</p>
<div class="metrics" id="metrics">{metric_html}</div>
<h2>Figures</h2>
{''.join(figures)}
<h2>The chain</h2>
<p>Left, the sample after each sweep; right, the running mean of the samples so far{first_chain_note}.</p>
<figure id="fig-animation"><img src="{_data_uri(gif, 'image/gif')}" alt="Animation of the Gibbs chain">
<figcaption>The chain as an animation.</figcaption></figure>
<iframe class="chain" id="chain-slider-page" title="Gibbs chain with a slider" srcdoc="{slider_srcdoc}"></iframe>
<h2>Settings</h2>
<table class="settings" id="settings">{_settings_html(summary)}</table>
</body></html>
"""
