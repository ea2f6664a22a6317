"""Tests for bayesmap.viz.diagnostics: the importance-weight histogram and the convergence of chains."""

from __future__ import annotations

import re

import numpy as np
import pytest
from matplotlib.figure import Figure

from bayesmap.errors import BayesmapError
from bayesmap.viz.common import figure_bytes
from bayesmap.viz.diagnostics import plot_convergence, plot_importance
from helpers import by_gid

# ---------------------------------------------------------------------------------------------------------------
# plot_importance
# ---------------------------------------------------------------------------------------------------------------

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def ess_in_text(ax):
    """(ESS, N) read back from the text box."""
    match = re.match(r"ESS ([\d,.]+) of ([\d,]+) particles?", by_gid(ax, "importance-ess").get_text())
    assert match, by_gid(ax, "importance-ess").get_text()
    return float(match[1].replace(",", "")), int(match[2].replace(",", ""))


def test_importance_histogram_counts_the_finite_particles():
    rng = np.random.default_rng(3)
    raw = rng.normal(-500.0, 2.0, 300)  # unnormalized
    raw[[4, 50, 299]] = -np.inf
    ax = plot_importance(raw).axes[0]
    hist = by_gid(ax, "importance-histogram")
    counts, edges = hist.get_data().values, hist.get_data().edges
    assert counts.sum() == 297
    normalized = raw - (raw[np.isfinite(raw)].max() + np.log(np.exp(raw - raw[np.isfinite(raw)].max()).sum()))
    finite = normalized[np.isfinite(normalized)]
    assert edges[0] <= finite.min() and edges[-1] >= finite.max()
    # the bins hold the normalized (not the raw) log-weights: the same histogram for a shifted input
    shifted = by_gid(plot_importance(raw + 480.0).axes[0], "importance-histogram")
    np.testing.assert_array_equal(shifted.get_data().values, counts)
    assert ax.get_xlabel() == "normalized log-weight" and ax.get_ylabel() == "particles"
    assert ax.get_title() == "Importance sampling: normalized log-weights"
    text = by_gid(ax, "importance-ess").get_text()
    assert "3 with log-weight -inf" in text
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[0] == "297 particles (finite log-weight)" and labels[1].startswith("largest weight")


def test_importance_ess_of_two_equal_weights():
    ax = plot_importance([-3.0, -np.inf, -3.0, -np.inf, -np.inf]).axes[0]
    assert ess_in_text(ax) == (2.0, 5)
    text = by_gid(ax, "importance-ess").get_text()
    assert text == "ESS 2.0 of 5 particles\n3 with log-weight -inf (weight 0), not drawn"
    # both weights are 1/2: the largest normalized log-weight is log(1/2)
    np.testing.assert_allclose(by_gid(ax, "importance-max").get_xdata(), [np.log(0.5)] * 2)
    assert by_gid(ax, "importance-histogram").get_data().values.sum() == 2


def test_importance_ess_matches_the_formula_and_the_sampler():
    from bayesmap.inference.importance import effective_sample_size

    rng = np.random.default_rng(0)
    raw = rng.normal(0.0, 1.5, 2000)
    w = np.exp(raw - raw.max())
    w /= w.sum()
    expected = 1.0 / np.sum(w**2)
    ess, num = ess_in_text(plot_importance(raw).axes[0])
    assert num == 2000
    assert ess == pytest.approx(expected, abs=0.05)  # shown with one decimal
    assert float(effective_sample_size(raw)) == pytest.approx(expected, rel=1e-4)
    # a given ESS is shown as given
    assert ess_in_text(plot_importance(raw, ess=123.456).axes[0]) == (123.5, 2000)


def test_importance_one_dominant_weight():
    raw = np.concatenate([[700.0], 700.0 - np.linspace(800.0, 5000.0, 1999)])
    fig = plot_importance(raw)
    ax = fig.axes[0]
    np.testing.assert_allclose(by_gid(ax, "importance-max").get_xdata(), [0.0, 0.0], atol=1e-12)
    ess, num = ess_in_text(ax)
    assert (ess, num) == (1.0, 2000)
    assert by_gid(ax, "importance-ess").get_text() == "ESS 1.0 of 2,000 particles"
    assert by_gid(ax, "importance-histogram").get_data().values.sum() == 2000
    assert figure_bytes(fig, "png").startswith(PNG_MAGIC)


def test_importance_accepts_jax_and_given_axes():
    import jax.numpy as jnp

    fig = Figure()
    ax = fig.add_subplot(1, 2, 1)
    assert plot_importance(jnp.asarray([0.0, -1.0, -2.0], dtype=jnp.float32), ax=ax, title="mine") is fig
    assert ax.get_title() == "mine" and len(fig.axes) == 1
    assert ess_in_text(ax)[1] == 3


def test_importance_bad_inputs():
    with pytest.raises(BayesmapError, match="empty"):
        plot_importance([])
    with pytest.raises(BayesmapError, match=r"log_weights\[2\] is nan"):
        plot_importance([0.0, -1.0, np.nan, -2.0])
    with pytest.raises(BayesmapError, match=r"log_weights\[1\] is inf"):
        plot_importance([0.0, np.inf])
    with pytest.raises(BayesmapError, match=r"shape \(2, 3\)"):
        plot_importance(np.zeros((2, 3)))
    with pytest.raises(BayesmapError, match="-inf"):
        plot_importance([-np.inf, -np.inf])
    with pytest.raises(BayesmapError, match=r"ess is 7\.0.*between 1 and 3"):
        plot_importance([0.0, -1.0, -2.0], ess=7.0)
    with pytest.raises(BayesmapError, match="ess"):
        plot_importance([0.0, -1.0], ess=[1.0, 2.0])


# ---------------------------------------------------------------------------------------------------------------
# plot_convergence
# ---------------------------------------------------------------------------------------------------------------


def fake_chains(num_chains=3, num_sweeps=50, seed=0):
    """Log joints that start near -1e5 and settle near -300 after 5 sweeps; wrong cells from 80 down to 0-3."""
    rng = np.random.default_rng(seed)
    t = np.arange(num_sweeps)
    log_joints = -300.0 - 1e5 * np.exp(-2.0 * t) + rng.normal(0.0, 1.0, (num_chains, num_sweeps))
    wrong = np.round(80.0 * np.exp(-0.7 * t)).astype(int) + rng.integers(0, 4, (num_chains, num_sweeps))
    return log_joints, wrong


def lines_by_prefix(ax, prefix):
    return {line.get_gid(): line for line in ax.get_lines() if (line.get_gid() or "").startswith(prefix)}


def test_convergence_one_line_per_chain():
    log_joints, _ = fake_chains()
    fig = plot_convergence(log_joints, truth_log_joint=-301.5)
    assert len(fig.axes) == 1
    ax = fig.axes[0]
    chains = lines_by_prefix(ax, "chain-")
    assert sorted(chains) == ["chain-0", "chain-1", "chain-2"]
    for k in range(3):
        np.testing.assert_array_equal(chains[f"chain-{k}"].get_xdata(), np.arange(1, 51))
        np.testing.assert_array_equal(chains[f"chain-{k}"].get_ydata(), log_joints[k])
    np.testing.assert_array_equal(by_gid(ax, "truth-log-joint").get_ydata(), [-301.5, -301.5])
    assert ax.get_xlabel() == "sweep" and ax.get_title() == "Convergence"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["chain 0", "chain 1", "chain 2", "true map"]
    # a few chains differ in colour and in something that survives grayscale (line style or marker)
    styles = {(line.get_linestyle(), line.get_marker()) for line in chains.values()}
    assert len({line.get_color() for line in chains.values()}) == 3 and len(styles) == 3
    assert not [c for c in ax.get_children() if c.get_gid() == "burn-in"]


def test_convergence_y_range_ignores_the_early_sweeps():
    log_joints, _ = fake_chains()
    ax = plot_convergence(log_joints).axes[0]
    lo, hi = ax.get_ylim()
    converged = log_joints[:, 10:]
    assert lo <= converged.min() and hi >= converged.max()
    assert lo > -400.0  # the -1e5 of sweep 1 does not squash the converged part
    note = by_gid(ax, "off-scale").get_text()
    assert "below the axis" in note and "sweep 1" in note and f"{log_joints.min():.4g}" in note
    # the true map's log joint is always inside the range
    lo, hi = plot_convergence(log_joints, truth_log_joint=-250.0).axes[0].get_ylim()
    assert lo < -250.0 < hi
    # nothing off the scale: no note
    flat = plot_convergence(-300.0 + np.zeros((2, 10))).axes[0]
    assert not [c for c in flat.get_children() if c.get_gid() == "off-scale"]
    assert flat.get_ylim()[0] < -300.0 < flat.get_ylim()[1]


def test_convergence_wrong_cells_panel_and_burn_in():
    log_joints, wrong = fake_chains()
    fig = plot_convergence(log_joints, wrong, burn_in=20, truth_log_joint=-300.0, title="4 chains")
    assert len(fig.axes) == 2
    top, bottom = fig.axes
    assert top.get_shared_x_axes().joined(top, bottom)
    assert top.get_title() == "4 chains"
    assert bottom.get_ylabel() == "wrong visible cells" and bottom.get_xlabel() == "sweep"
    rows = lines_by_prefix(bottom, "wrong-")
    assert sorted(rows) == ["wrong-0", "wrong-1", "wrong-2"]
    for k in range(3):
        np.testing.assert_array_equal(rows[f"wrong-{k}"].get_xdata(), np.arange(1, 51))
        np.testing.assert_array_equal(rows[f"wrong-{k}"].get_ydata(), wrong[k])
        # the same chain has the same style in both panels
        assert rows[f"wrong-{k}"].get_color() == by_gid(top, f"chain-{k}").get_color()
    accuracy = by_gid(bottom, "tutorial-accuracy")
    np.testing.assert_array_equal(accuracy.get_ydata(), [2, 2])
    assert accuracy.get_linestyle() == ":" and accuracy.get_label() == "2 wrong (tutorial's accuracy)"
    assert [t.get_text() for t in bottom.get_legend().get_texts()] == ["2 wrong (tutorial's accuracy)"]
    for ax in (top, bottom):
        line = by_gid(ax, "burn-in")
        np.testing.assert_array_equal(line.get_xdata(), [20.5, 20.5])  # between sweep 20 (dropped) and 21 (kept)
        assert line.get_linestyle() == "--"
    assert "burn-in (20 sweeps dropped)" in [t.get_text() for t in top.get_legend().get_texts()]
    # 80 wrong cells at the start: symmetric-log, with 0 and 2 still on the axis
    assert bottom.get_yscale() == "symlog"
    assert {0, 2} <= set(bottom.get_yticks()) and bottom.get_ylim()[1] >= wrong.max()
    assert figure_bytes(fig, "png").startswith(PNG_MAGIC)


def test_convergence_single_chain_and_small_counts():
    log_joints, wrong = fake_chains(num_chains=1, num_sweeps=8)
    fig = plot_convergence(log_joints[0], np.minimum(wrong[0], 9))
    top, bottom = fig.axes
    assert list(lines_by_prefix(top, "chain-")) == ["chain-0"]
    np.testing.assert_array_equal(by_gid(top, "chain-0").get_xdata(), np.arange(1, 9))
    assert [t.get_text() for t in top.get_legend().get_texts()] == ["chain"]
    assert bottom.get_yscale() == "linear"


def test_convergence_many_chains_share_one_legend_entry():
    log_joints, wrong = fake_chains(num_chains=10, num_sweeps=30)
    top = plot_convergence(log_joints, wrong).axes[0]
    chains = lines_by_prefix(top, "chain-")
    assert len(chains) == 10
    assert len({tuple(line.get_color()) for line in chains.values()}) == 10
    labels = [t.get_text() for t in top.get_legend().get_texts()]
    assert len(labels) == 1 and labels[0].startswith("10 chains")


def test_convergence_into_given_axes():
    log_joints, wrong = fake_chains(num_chains=2, num_sweeps=12)
    fig = Figure()
    ax = fig.add_subplot()
    assert plot_convergence(log_joints, ax=ax) is fig and len(fig.axes) == 1
    fig2 = Figure()
    pair = fig2.subplots(2, 1)
    assert plot_convergence(log_joints, wrong, ax=pair) is fig2
    assert len(lines_by_prefix(pair[1], "wrong-")) == 2
    with pytest.raises(BayesmapError, match="pair of Axes"):
        plot_convergence(log_joints, wrong, ax=ax)


def test_convergence_bad_inputs():
    log_joints, wrong = fake_chains(num_chains=2, num_sweeps=12)
    with pytest.raises(BayesmapError, match="empty"):
        plot_convergence([])
    with pytest.raises(BayesmapError, match="empty"):
        plot_convergence(np.zeros((3, 0)))
    bad = log_joints.copy()
    bad[1, 3] = np.nan
    with pytest.raises(BayesmapError, match=r"log_joints\[1, 3\] is nan"):
        plot_convergence(bad)
    with pytest.raises(BayesmapError, match=r"log_joints\[4\] is nan"):
        plot_convergence([0.0, 1.0, 2.0, 3.0, np.nan])
    with pytest.raises(BayesmapError, match=r"shape \(2, 2, 2\)"):
        plot_convergence(np.zeros((2, 2, 2)))
    with pytest.raises(BayesmapError, match=r"wrong_cells has shape \(2, 11\) but log_joints has shape \(2, 12\)"):
        plot_convergence(log_joints, wrong[:, :11])
    with pytest.raises(BayesmapError, match=r"wrong_cells has shape \(12,\)"):
        plot_convergence(log_joints, wrong[0])
    with pytest.raises(BayesmapError, match=r"wrong_cells\[0, 5\] is -1\.0"):
        plot_convergence(log_joints, np.where(np.arange(12) == 5, -1, wrong))
    with pytest.raises(BayesmapError, match=r"wrong_cells\[1, 7\] is 2\.5"):
        plot_convergence(log_joints, np.where((np.arange(2)[:, None] == 1) & (np.arange(12) == 7), 2.5, wrong))
    with pytest.raises(BayesmapError, match=r"wrong_cells\[1, 2\] is nan"):
        plot_convergence(log_joints, np.where((np.arange(2)[:, None] == 1) & (np.arange(12) == 2), np.nan, wrong))
    with pytest.raises(BayesmapError, match=r"burn_in .* 0 and 11.*got 12"):
        plot_convergence(log_joints, burn_in=12)
    with pytest.raises(BayesmapError, match="got -1"):
        plot_convergence(log_joints, burn_in=-1)
    with pytest.raises(BayesmapError, match="truth_log_joint"):
        plot_convergence(log_joints, truth_log_joint=np.nan)

