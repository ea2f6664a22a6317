"""The focused chain (bayesmap.inference.focus): a sweep of the cells in doubt is the one-cell-at-a-time Gibbs sweep
of those cells, the chain's Rao-Blackwellized marginals match exact enumeration, its first sweeps are the plain
chain's, and the whole and the focused sweeps share one compilation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.inference.cellwise import CellwiseGibbs
from bayesmap.inference.chains import compiled_chain_count, run_chain
from bayesmap.inference.focus import cells_in_doubt, focused_chain
from helpers import mrf_enumeration_scene, replayed_sweeps, scenes


def _visiting_order(kernel):
    """The cells a sweep of ``kernel`` visits, in order (each group's first ``count`` rows)."""
    return np.concatenate([np.asarray(lanes.cells)[:int(lanes.count)] for lanes in kernel._lanes])


def test_a_focused_sweep_is_the_one_cell_at_a_time_sweep_of_its_cells():
    """Cells in doubt picked at random: the focused kernel visits exactly them (the whole kernel, reordered in place,
    every crossed cell, those in doubt first within each width group, with the same conditionals), and each of its
    sweeps draws them one at a time in that order,
    each with the sweep's uniform from its conditional given the current map (the scoring of the original kernel,
    which the order does not change), then the cells no ray crosses from the prior; the other crossed cells keep
    their values and the per-ray rows stay those of the map. Dense maps, so that many cells change."""
    grid, params, angles, _, y, table = scenes("beam", 11, num_beams=30)
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    crossed = table.rays_per_cell() > 0
    doubt = np.random.default_rng(2).random(grid.shape).reshape(-1) < 0.4
    plain = CellwiseGibbs(table, y.reshape(-1), params).kernel
    whole = sampler.kernel
    focused = whole.focus(doubt.reshape(grid.shape))  # (whole reordered in place)
    order = _visiting_order(focused)
    np.testing.assert_array_equal(np.sort(order), np.flatnonzero(doubt & crossed))
    np.testing.assert_array_equal(np.sort(_visiting_order(whole)), np.flatnonzero(crossed))
    assert not np.array_equal(_visiting_order(plain), _visiting_order(whole))  # reordered, the same conditionals
    some = jnp.asarray(np.random.default_rng(4).random(grid.shape) < 0.4, jnp.float32)
    np.testing.assert_allclose(np.asarray(jax.jit(whole.cell_log_odds)(some)),
                               np.asarray(jax.jit(plain.cell_log_odds)(some)), rtol=1e-6, atol=1e-6)
    free = np.asarray(whole._free)
    prior = float(jax.nn.sigmoid(whole._prior_log_odds))
    step, log_odds = jax.jit(focused.step), jax.jit(plain.cell_log_odds)
    state = sampler.init(jnp.asarray(np.random.default_rng(1).random(grid.shape) < 0.5, jnp.float32))
    changed = 0
    for state, info, before, walls, probs, n in replayed_sweeps(step, log_odds, state, grid.shape, order, free, prior):
        changed += n
        np.testing.assert_array_equal(np.asarray(state.walls).reshape(-1), walls)
        visited = doubt & crossed | free
        np.testing.assert_allclose(np.asarray(info.wall_prob).reshape(-1)[visited], probs[visited], rtol=1e-6,
                                   atol=1e-7)
        assert (walls[crossed & ~doubt] == before[crossed & ~doubt]).all()
        np.testing.assert_allclose(np.asarray(state.ray_walls), np.asarray(plain.ray_walls(state.walls)),
                                   rtol=1e-6)
    assert changed > 10


def test_focused_chain_marginals_match_exact_enumeration():
    """The one-scan scene of the structured prior (3 x 4 grid, J = 0.8, 4,096 maps enumerated with the model's
    assess, connections observed; the prior's neighbour terms are where reordering the cells could go wrong): 64
    focused chains of 300 sweeps, the cells in doubt chosen after 4 sweeps with a threshold of 0.2 (so that several
    cells are settled and visited every 3rd sweep only), the Rao-Blackwellized marginals over the last 250 sweeps
    within 0.03 of the exact ones (the 0/1 mean's standard error is at most 0.014: tests/inference/
    test_cellwise.py); filling the settled cells' records with 0 instead of their last probability is caught
    (checked: errors of 0.6 and more)."""
    problem, exact = mrf_enumeration_scene(0.8)
    table, y, params = problem.table, problem.model_ray_readings, problem.params
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    settled, est = 0, np.zeros(exact.shape)
    for c, key in enumerate(jax.random.split(jax.random.key(3), 64)):
        chain = focused_chain(key, sampler.kernel, jnp.zeros((3, 4)), 300, start=4, every=3, doubt=0.2)
        est += chain.wall_probs[50:].astype(float).mean(axis=0) / 64
        settled += int((~cells_in_doubt(chain.wall_probs[2:4], 0.2)).sum())
    assert settled > 64  # more than one settled cell per chain on average
    assert np.abs(est - exact).max() < 0.03, (est, exact)
    assert np.abs(exact - 0.5).max() > 0.3


def test_first_sweeps_are_the_plain_chains_and_one_compilation_serves_both_kernels():
    """The first ``start`` sweeps of a focused chain are those of run_chain with the same key, bit for bit; the whole
    and the focused sweeps after them reuse the one compiled sweep (the count of compiled chains grows by one over
    the whole chain, then not at all for a second chain); the settled cells' records repeat their last whole
    sweep's probability, the cells in doubt get new ones."""
    grid, params, angles, _, y, table = scenes("beam", 11, num_beams=30)
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    walls = jnp.asarray(np.random.default_rng(1).random(grid.shape) < 0.5, jnp.float32)
    plain = run_chain(jax.random.key(7), sampler.algorithm, walls, 12)
    jax.clear_caches()
    before = compiled_chain_count()
    chain = focused_chain(jax.random.key(7), sampler.kernel, walls, 12, start=6, every=3, doubt=0.05)
    assert compiled_chain_count() == before + 1
    focused_chain(jax.random.key(8), sampler.kernel, walls, 12, start=6, every=3, doubt=0.05)
    assert compiled_chain_count() == before + 1
    np.testing.assert_array_equal(chain.samples[:6], np.asarray(plain.samples[:6]))
    np.testing.assert_array_equal(chain.wall_probs[:6], np.asarray(plain.wall_probs[:6]))
    settled = ~cells_in_doubt(chain.wall_probs[3:6], 0.05)
    assert 0 < settled.sum() < settled.size
    # sweeps 6 and 9 visit every cell, 7-8 and 10-11 the cells in doubt
    for t in (7, 8):
        np.testing.assert_array_equal(chain.wall_probs[t][settled], chain.wall_probs[6][settled])
    np.testing.assert_array_equal(chain.wall_probs[11][settled], chain.wall_probs[9][settled])
    assert (chain.wall_probs[9][settled] != chain.wall_probs[6][settled]).any()
    assert chain.samples.shape == chain.wall_probs.shape == (12, *grid.shape)


def test_cells_in_doubt_and_errors():
    probs = np.array([[[0.5, 1e-4, 0.9999, 0.01]], [[0.5, 2e-3, 1.0, 0.0]]], np.float32)
    np.testing.assert_array_equal(cells_in_doubt(probs, 1e-3), [[True, True, False, True]])
    np.testing.assert_array_equal(cells_in_doubt(probs, 0.02), [[True, False, False, False]])
    for bad in (-0.1, 0.5, True):
        with pytest.raises(BayesmapError, match="doubt"):
            cells_in_doubt(probs, bad)
    with pytest.raises(BayesmapError, match="wall_probs"):
        cells_in_doubt(probs[:0])
    grid, params, angles, _, y, table = scenes("beam", 7)
    kernel = CellwiseGibbs(table, y.reshape(-1), params).kernel
    for name, bad in (("sweeps", 0), ("start", 0), ("every", 1.5)):
        kwargs = {"num_sweeps": 5, "start": 2, "every": 2, name if name != "sweeps" else "num_sweeps": bad}
        with pytest.raises(BayesmapError, match="integer >= 1"):
            focused_chain(jax.random.key(0), kernel, jnp.zeros(grid.shape), **kwargs)
