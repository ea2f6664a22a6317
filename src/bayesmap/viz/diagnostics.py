"""Diagnostic figures of the samplers: the normalized importance weights with the effective sample size
(:func:`plot_importance`) and the convergence of Gibbs chains, log joint and wrong visible cells per sweep
(:func:`plot_convergence`).

Both return a :class:`matplotlib.figure.Figure` (Agg canvas, never ``pyplot``) or draw into given Axes; their
artists' gids are listed in their docstrings. Render or save them with :mod:`bayesmap.viz.common`.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from bayesmap.errors import BayesmapError
from bayesmap.viz.common import GRIDLINE_COLOR, TRUTH_COLOR, draw_legend, new_figure

__all__ = ["plot_convergence", "plot_importance"]

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
# Importance weights
# ---------------------------------------------------------------------------------------------------------------


def _normalize_log_weights(log_weights: np.ndarray) -> np.ndarray:
    """``log_weights - logsumexp(log_weights)`` in float64 (-inf stays -inf; at least one weight is finite)."""
    top = log_weights.max()
    return log_weights - (top + np.log(np.sum(np.exp(log_weights - top))))


def _particles(num: int) -> str:
    return f"{num:,} particle" + ("" if num == 1 else "s")


def _histogram(finite: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(counts, edges)`` of the finite normalized log-weights: sqrt(N) bins (10 to :data:`MAX_HISTOGRAM_BINS`),
    or one bar of width 0.2 centred on them when they are all equal."""
    top = float(finite.max())
    if top == finite.min():
        return np.array([finite.size]), top + np.array([-0.1, 0.1])
    bins = int(np.clip(np.ceil(np.sqrt(finite.size)), 10, MAX_HISTOGRAM_BINS))
    return np.histogram(finite, bins=bins)


def _draw_ess_box(ax, ess: float, num: int, zero_weight: int) -> None:
    """The text box (gid ``"importance-ess"``, top left): "ESS e of N particles" and the count of -inf weights."""
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
        fig = new_figure((6.4, 4.4))
        ax = fig.add_subplot()
    else:
        fig = ax.get_figure(root=True)
    top = float(finite.max())
    counts, edges = _histogram(finite)
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
    _draw_ess_box(ax, ess, num, zero_weight)
    if len(counts) == 1:  # a lone bar would fill the axes (sticky edges): show it narrow
        ax.set_xlim(top - 1.0, top + 1.0)
    # headroom above the tallest bar for the text box
    ax.set_ylim(0, max(int(counts.max()), 1) * 1.35)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))
    ax.set_xlabel("normalized log-weight")
    ax.set_ylabel("particles")
    ax.set_title(title)
    handles, _ = ax.get_legend_handles_labels()
    draw_legend(ax, handles)
    return fig


# ---------------------------------------------------------------------------------------------------------------
# Convergence of Gibbs chains
# ---------------------------------------------------------------------------------------------------------------


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
            the map after sweep ``t + 1`` (e.g. :func:`bayesmap.model.generative.log_joint` of each sample),
            natural log.
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
        fig = new_figure((8.0, 4.4) if panels == 1 else (8.0, 7.0))
        axes = fig.subplots(panels, 1, sharex=True, squeeze=False, height_ratios=[3, 2][:panels])[:, 0]
    else:
        axes = _check_convergence_axes(ax, panels)
        fig = axes[0].get_figure(root=True)
    sweeps = np.arange(1, num_sweeps + 1)
    styles = _chain_styles(num_chains)
    _draw_log_joint_panel(axes[0], sweeps, values, styles, truth, title)
    if wrong is not None:
        _draw_wrong_cells_panel(axes[1], sweeps, wrong, styles)
    for k, panel in enumerate(axes):
        _finish_sweep_panel(panel, k, num_sweeps, num_chains, burn_in)
    if shared:  # the panels share the sweep axis: label it once, at the bottom
        for panel in axes[:-1]:
            panel.tick_params(labelbottom=False)
        axes[-1].set_xlabel("sweep")
    else:
        for panel in axes:
            panel.set_xlabel("sweep")
    return fig


def _draw_log_joint_panel(ax, sweeps: np.ndarray, values: np.ndarray, styles: list[dict], truth: float | None,
                          title: str) -> None:
    """The top panel of :func:`plot_convergence`: one line per chain (``values`` ``(num_chains, num_sweeps)``), the
    true map's log joint, the y range clipped to the converged sweeps."""
    _draw_chains(ax, sweeps, values, styles, "chain")
    if truth is not None:
        ax.axhline(
            truth, color=TRUTH_COLOR, linestyle=(0, (6, 2, 1, 2)), linewidth=1.6, zorder=4,
            gid="truth-log-joint", label="true map",
        )
    _clip_to_converged(ax, values, truth)
    ax.set_ylabel("log joint  log p(walls, readings)")
    ax.set_title(title)


def _draw_wrong_cells_panel(ax, sweeps: np.ndarray, wrong: np.ndarray, styles: list[dict]) -> None:
    """The lower panel of :func:`plot_convergence`: wrong visible cells per chain and sweep, and the tutorial's
    accuracy (2 wrong cells) as a dotted line."""
    _draw_chains(ax, sweeps, wrong, styles, "wrong")
    ax.axhline(
        TUTORIAL_WRONG_CELLS, color="black", linestyle=":", linewidth=1.5, zorder=4,
        gid="tutorial-accuracy", label="2 wrong (tutorial's accuracy)",
    )
    _wrong_cells_scale(ax, wrong)
    ax.set_ylabel("wrong visible cells")


def _finish_sweep_panel(panel, k: int, num_sweeps: int, num_chains: int, burn_in: int | None) -> None:
    """Burn-in line, sweep axis, grid and legend of panel ``k`` of :func:`plot_convergence` (0 = log joint, 1 =
    wrong cells: its legend holds only the tutorial's accuracy, the chains are in the top one)."""
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
