"""The whole-log single-site sampler (bayesmap.inference.cellwise): conditionals against the multi-scan model's
assess, the state's per-ray rows against those recomputed from the map, and marginals against exact enumeration."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference import cellwise
from bayesmap.inference.cellwise import CellwiseGibbs, width_groups
from bayesmap.inference.chains import run_chain, run_chains
from bayesmap.model.generative import make_params, prior_log_odds
from helpers import (
    assess_cell_differences,
    beam_enumeration_scene,
    replayed_sweeps,
    scenes,
    sweeps_keep_ray_rows,
)


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_conditionals_match_the_multi_scan_model(beam_model):
    """3 scans in one table, max-range readings at exactly the max range: for random maps every cell's log-odds
    from the sweep's scoring equals the difference of the model's assess with the cell set to 1 and to 0; with a
    likelihood power eta (1 and, for the beam model, 0.3, against the one assess reference), the prior's log-odds
    plus eta times the rest of that difference.
    Tolerance 1e-4 as tests/test_multiscan.py::test_fast_conditionals_match_the_multi_scan_model (float64 on both
    sides; the model's float32 prior carries ~3e-6 of rounding); a wrong case of the three (first wall before,
    after, at the cell) changes some difference by far more than 1e-2, and the check below makes sure the data
    are informative."""
    with enable_x64():
        grid, params, angles, _, y, table = scenes(beam_model, 7)
        powers = (1.0, 0.3) if beam_model == "beam" else (1.0,)
        samplers = {eta: CellwiseGibbs(table, y.reshape(-1), params, likelihood_power=eta) for eta in powers}
        brute = assess_cell_differences(grid, params, angles, y)
        logit = prior_log_odds(params.prior_wall_prob)

        rng = np.random.default_rng(3)
        for density in (0.15, 0.35, 0.6):
            walls = (rng.random(grid.shape) < density).astype(np.float64)
            differences = np.asarray(brute(jnp.asarray(walls)))
            for likelihood_power, sampler in samplers.items():
                got = np.asarray(sampler.cell_log_odds(walls))
                want = logit + likelihood_power * (differences - logit)
                np.testing.assert_allclose(got, want, atol=1e-4, rtol=0)
                assert np.ptp(want) > 2.0


def test_lanes_hold_each_cells_pairs_in_ray_order():
    """Each cell crossed by a ray is in exactly one group of lanes (the width of its count); its row holds its pairs
    in ray order (ray, position along the ray, the pair's log-likelihood), then padding (ray R, position 0, 0)."""
    grid, params, angles, _, y, table = scenes("beam", 5, num_beams=30)
    kernel = CellwiseGibbs(table, y.reshape(-1), params).kernel
    pair_ll = np.asarray(kernel._pair_ll)
    counts = table.rays_per_cell()
    seen = []
    for (width, cells), lanes in zip(width_groups(counts), kernel._lanes, strict=True):
        np.testing.assert_array_equal(np.asarray(lanes.cells), cells)
        rays, positions, log_lik = (np.asarray(a) for a in (lanes.rays, lanes.positions, lanes.log_lik))
        assert rays.shape == positions.shape == log_lik.shape == (len(cells), width)
        for row, cell in enumerate(cells):
            pairs = np.flatnonzero(table.pair_cells == cell)
            n = len(pairs)
            np.testing.assert_array_equal(rays[row, :n], table.pair_rays[pairs])
            np.testing.assert_array_equal(positions[row, :n], table.pair_positions[pairs])
            np.testing.assert_array_equal(log_lik[row, :n], pair_ll[pairs])
            assert (rays[row, n:] == table.num_rays).all() and (positions[row, n:] == 0).all()
            assert (log_lik[row, n:] == 0).all()
        seen.extend(cells)
    np.testing.assert_array_equal(np.sort(seen), np.flatnonzero(counts))


@pytest.mark.parametrize("beam_model, batch", [("normal", 16), ("beam", 16), ("beam", 1)])
def test_sweeps_keep_the_ray_rows_consistent(beam_model, batch, monkeypatch):
    """After each sweep, the state's first and second wall of every ray (and their log-likelihoods) equal those
    recomputed from the new map: the rows are rewritten exactly when a cell changes, including the walk to a
    ray's next wall when its first or second wall is removed (with batch 1, one ray walked at a time, so that
    removals needing several batches are exercised). Maps are dense enough that many cells change."""
    monkeypatch.setattr(cellwise, "SEARCH_BATCH", batch)
    grid, params, angles, _, y, table = scenes(beam_model, 11, num_beams=30)
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    assert sweeps_keep_ray_rows(sampler, table, grid, 2, 15) > 20


@pytest.mark.parametrize("speculative, lanes", [(16, 2048), (8, 0), (3, 0)])
def test_sweep_is_the_one_cell_at_a_time_sweep(speculative, lanes, monkeypatch):
    """The sweep scores consecutive cells at once (SPECULATIVE_CELLS, or SPECULATIVE_LANES // width: the whole of a
    narrow group here at the defaults) and keeps those up to the first draw that changes a row: its draws are exactly
    those of updating one cell at a time in the visiting order, each drawn with the same uniform from its
    conditional given the current map (cell_log_odds, the same scoring), then the cells no ray crosses from the
    prior. 3 at once leaves partial runs at the ends of groups. Dense maps, so that many cells change."""
    monkeypatch.setattr(cellwise, "SPECULATIVE_CELLS", speculative)
    monkeypatch.setattr(cellwise, "SPECULATIVE_LANES", lanes)
    grid, params, angles, _, y, table = scenes("beam", 11, num_beams=30)
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    kernel = sampler.kernel
    order = np.concatenate([np.asarray(lanes.cells) for lanes in kernel._lanes])
    free = np.asarray(kernel._free)
    prior = float(jax.nn.sigmoid(kernel._prior_log_odds))
    step, log_odds = jax.jit(sampler.step), jax.jit(sampler.cell_log_odds)
    state = sampler.init(jnp.asarray(np.random.default_rng(1).random(grid.shape) < 0.5, jnp.float32))
    changed = 0
    for state, info, _, walls, probs, n in replayed_sweeps(step, log_odds, state, grid.shape, order, free, prior):
        changed += n
        np.testing.assert_array_equal(np.asarray(state.walls).reshape(-1), walls)
        np.testing.assert_allclose(np.asarray(info.wall_prob).reshape(-1), probs, rtol=1e-6, atol=1e-7)
    assert changed > 20


def test_sampler_matches_exact_enumeration():
    """The whole sweep with the beam model and two scans: 3 x 4 grid (4,096 maps enumerated with the model's
    assess), 2 poses x 6 beams, two max-range readings and one short reading; 64 chains x 300 sweeps. Tolerance
    0.06 as tests/test_multiscan.py::test_beam_sampler_matches_exact_enumeration (each marginal averages 64 x 250
    kept sweeps; Monte Carlo standard error <= 0.014)."""
    table, y, params, exact = beam_enumeration_scene()
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    result = run_chains(jax.random.key(3), sampler.algorithm, jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.samples[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.06, (est, exact)
    assert np.abs(exact - 0.3).max() > 0.3


def test_one_chain_runs_and_cells_without_rays_follow_the_prior():
    """A 1-scan problem on a large grid (most cells never crossed by a ray): one chain under lax.scan runs, and the
    uncrossed cells are drawn from the prior (mean over 40 sweeps x ~1,500 cells within 5 standard errors)."""
    grid = Grid((40, 40))
    params = make_params(0.2, 0.3, 8, grid, 5.0, beam_model="beam")
    pose = np.array([[20.0, 20.0]])
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)[None]
    y = np.full((1, 8), 3.0)
    table = build_ray_table(grid, np.repeat(pose, 8, axis=0), angles.reshape(-1), params.max_range)
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    free = table.rays_per_cell().reshape(grid.shape) == 0
    result = run_chain(jax.random.key(0), sampler.algorithm, jnp.zeros(grid.shape), 40)
    frac = np.asarray(result.samples)[:, free].mean()
    se = np.sqrt(0.2 * 0.8 / (40 * free.sum()))
    assert abs(frac - 0.2) < 5 * se
    np.testing.assert_allclose(np.asarray(result.wall_probs)[:, free], 0.2, rtol=1e-6)  # their recorded probability


def test_width_groups_and_errors():
    counts = np.array([0, 1, 8, 9, 16, 17, 100])
    groups = width_groups(counts)
    assert [(w, list(c)) for w, c in groups] == [(8, [1, 2]), (16, [3, 4]), (32, [5]), (128, [6])]
    with pytest.raises(BayesmapError, match="65,537 rays"):
        width_groups(np.array([65537]))
    grid, params, angles, _, y, table = scenes("beam", 7)
    with pytest.raises(BayesmapError, match="readings"):
        CellwiseGibbs(table, y.reshape(-1)[:-1], params)
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(BayesmapError, match="likelihood_power"):
            CellwiseGibbs(table, y.reshape(-1), params, likelihood_power=bad)


def test_rao_blackwellized_marginals_match_exact_enumeration():
    """The sweep's conditional wall probabilities (``info.wall_prob``), averaged over 64 chains x 250 kept sweeps,
    estimate the exact marginals of the two-scan beam scene. Their error is at most that of the 0/1 mean (standard
    error <= 0.014); tolerance 0.03, half the 0/1 test's. The chain's draws are the same with or without them."""
    table, y, params, exact = beam_enumeration_scene()
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    result = run_chains(jax.random.key(3), sampler.algorithm, jnp.zeros((3, 4)), 300, 64)
    probs = np.asarray(result.wall_probs)
    assert probs.shape == (64, 300, 3, 4) and probs.dtype == np.float32
    est = probs[:, 50:].astype(float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.03, (est, exact)
    # each draw is a draw from the recorded probability: where it is (near) 0 or 1 the cell follows it
    samples = np.asarray(result.samples)
    assert not samples[probs < 1e-6].any() and samples[probs > 1 - 1e-6].all()


def test_wall_prob_of_the_last_cell_is_its_conditional_given_the_final_map():
    """The last cell a sweep updates is drawn given the final map of the sweep: its recorded probability equals the
    sigmoid of :meth:`CellwiseKernel.cell_log_odds` on that map (float32 rounding). Both jitted once (as the chains
    run them; un-jitted, each sweep re-traced its loops: 2 s a sweep)."""
    grid, params, angles, _, y, table = scenes("beam", 7)
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    last = int(sampler.kernel._lanes[-1].cells[-1])
    state = sampler.init(jnp.zeros(grid.shape))
    step, cell_log_odds = jax.jit(sampler.step), jax.jit(sampler.cell_log_odds)
    for k in range(5):
        state, info = step(jax.random.key(k), state)
        cond = np.asarray(jax.nn.sigmoid(cell_log_odds(state.walls))).reshape(-1)
        prob = np.asarray(info.wall_prob).reshape(-1)
        np.testing.assert_allclose(prob[last], cond[last], rtol=1e-5, atol=1e-6)


_KERNEL_STEP = jax.jit(lambda kernel, key, state: kernel.step(key, state))
"""A sweep of any cellwise kernel, its arrays passed as arguments (as the chains pass them): kernels of equal shapes
and model flags share one compilation."""


@pytest.mark.parametrize("model", [{}, {"beam_model": "normal"}, {"coupling": 0.4, "neighbourhood": 4},
                                   {"wall_pass_prob": 0.2}, {"frozen": True}])
def test_a_padded_sweep_makes_the_same_draws(model, monkeypatch):
    """A kernel padded to larger sizes (headroom 0.5, and a width group of 4,096 lanes its table lacks, so cells that
    are all padding) draws every cell as the exact one does: the same maps, conditional probabilities and per-ray
    rows, sweep after sweep with the same keys, for each sensor and prior kind and with frozen cells. Another table
    built to its shapes has the same array shapes (one compilation) and again the draws of its exact kernel.
    Exact equality: the real lanes, rows and uniforms are the same numbers in the same order."""
    import dataclasses

    import bayesmap.inference.cellwise as cellwise

    monkeypatch.setattr(cellwise, "MAX_PADDED_LANES", float("inf"))  # (padding far past the table's own work)
    model = dict(model)
    frozen = np.random.default_rng(5).random((6, 7)) < 0.3 if model.pop("frozen", False) else None
    beam_model = model.pop("beam_model", "beam")

    def sampler_of(seed, **kwargs):
        grid, params, angles, _, y, table = scenes(beam_model, seed, num_beams=30)
        params = dataclasses.replace(params, **model)
        return CellwiseGibbs(table, y.reshape(-1), params, frozen=frozen, **kwargs), grid

    def run(sampler, grid, sweeps=4):
        state = sampler.init(jnp.asarray(np.random.default_rng(1).random(grid.shape) < 0.5, jnp.float32))
        out = []
        for k in range(sweeps):
            state, info = _KERNEL_STEP(sampler.kernel, jax.random.key(k), state)
            out.append((np.asarray(state.walls), np.asarray(info.wall_prob), np.asarray(state.ray_walls)))
        return out

    exact, grid = sampler_of(11)
    needed = exact.kernel.shapes
    wider = needed._replace(groups=((4096, 3),), rest=0, rays=0, pairs=0)  # too small but for the added group
    padded, _ = sampler_of(11, shapes=wider, headroom=0.5)
    got = padded.kernel.shapes
    assert got.rays > needed.rays and got.pairs > needed.pairs and (4096, 3) in got.groups
    assert all(n > dict(needed.groups)[w] for w, n in got.groups if w in dict(needed.groups))
    num_rays = needed.rays
    changed = 0
    for (walls, probs, rows), (walls_p, probs_p, rows_p) in zip(run(exact, grid), run(padded, grid), strict=True):
        changed += int((walls != walls_p).sum())
        np.testing.assert_array_equal(walls_p, walls)
        np.testing.assert_array_equal(probs_p, probs)
        np.testing.assert_array_equal(rows_p[:num_rays], rows[:num_rays])
        np.testing.assert_array_equal(rows_p[got.rays], rows[num_rays])  # the padding lanes' row
    assert changed == 0
    assert len({tuple(np.asarray(w).ravel()) for w, _, _ in run(exact, grid)}) > 2  # the maps change between sweeps

    other_exact, _ = sampler_of(12)
    other, _ = sampler_of(12, shapes=got)
    assert other.kernel.shapes == got
    assert jax.tree.structure(other.kernel) == jax.tree.structure(padded.kernel)
    assert [a.shape for a in jax.tree.leaves(other.kernel)] == [a.shape for a in jax.tree.leaves(padded.kernel)]
    compiled = _KERNEL_STEP._cache_size()
    other_runs = run(other, grid)
    assert _KERNEL_STEP._cache_size() == compiled  # the padded kernel's compiled sweep
    for (walls, probs, _), (walls_p, probs_p, _) in zip(run(other_exact, grid), other_runs, strict=True):
        np.testing.assert_array_equal(walls_p, walls)
        np.testing.assert_array_equal(probs_p, probs)


def test_fitted_shapes():
    """A size that fits the given one takes it; one that does not grows by the headroom, rounded up to 8; a group
    only given is kept; a bad headroom is refused."""
    from bayesmap.inference.cellwise import SweepShapes, fitted_shapes

    needed = SweepShapes(groups=((8, 100), (16, 30)), rest=0, rays=500, pairs=9000)
    assert fitted_shapes(needed) == needed
    had = SweepShapes(groups=((8, 120), (32, 4)), rest=8, rays=496, pairs=9000)
    assert fitted_shapes(needed, had, 0.1) == SweepShapes(groups=((8, 120), (16, 40), (32, 4)), rest=8, rays=552,
                                                          pairs=9000)
    assert fitted_shapes(needed, had) == SweepShapes(groups=((8, 120), (16, 30), (32, 4)), rest=8, rays=500,
                                                     pairs=9000)
    for bad in (-0.1, float("nan"), True):
        with pytest.raises(BayesmapError, match="headroom"):
            fitted_shapes(needed, None, bad)


def test_fitted_shapes_reserve_the_next_width():
    """With a headroom, new sizes also hold a group of twice the widest width, as large as the widest group, so that
    a table with a cell crossed by more rays than any before fits them; sizes that fit keep theirs (no group added
    again), and none is added past the widest width supported or without a headroom."""
    from bayesmap.inference.cellwise import MAX_WIDTH, SweepShapes, fitted_shapes

    needed = SweepShapes(groups=((8, 1000), (16, 30)), rest=0, rays=500, pairs=9000)
    first = fitted_shapes(needed, None, 0.1)
    assert first == SweepShapes(groups=((8, 1104), (16, 40), (32, 40)), rest=0, rays=552, pairs=9904)
    wider = SweepShapes(groups=((8, 1040), (16, 28), (32, 6)), rest=0, rays=520, pairs=9500)
    assert fitted_shapes(wider, first, 0.1) == first  # the same compiled sweep
    assert fitted_shapes(needed, first, 0.1) == first
    grown = fitted_shapes(needed._replace(pairs=9999), first, 0.1)
    assert grown.groups == first.groups and grown.pairs == 11000  # the reserved group already there
    widest = SweepShapes(groups=((8, 1000), (MAX_WIDTH, 3)), rest=0, rays=500, pairs=9000)
    assert fitted_shapes(widest, None, 0.1).groups == ((8, 1104), (MAX_WIDTH, 8))
    assert fitted_shapes(needed) == needed


def test_fitted_shapes_do_not_pad_a_small_table_to_a_large_ones_work():
    """Sizes from ``at_least`` whose width groups would hold more than ``MAX_PADDED_LANES`` times the lanes (cells
    times width) of the table's own sizes are not taken (a small tile after a dense one would sweep the dense one's
    padding): the table is sized for itself, with its headroom; at the limit they are still taken."""
    from bayesmap.inference.cellwise import MAX_PADDED_LANES, SweepShapes, fitted_shapes

    dense = SweepShapes(groups=((8, 1000), (64, 4000)), rest=16, rays=9000, pairs=300000)
    small = SweepShapes(groups=((8, 900), (64, 100)), rest=8, rays=400, pairs=9000)
    assert fitted_shapes(small, dense, 0.1) == fitted_shapes(small, None, 0.1)
    lanes = 8 * 1000 + 64 * 4000
    cells = int(np.ceil((lanes / MAX_PADDED_LANES - 8 * 1000) / 64))  # the fewest 64-wide cells within the limit
    assert fitted_shapes(small._replace(groups=((8, 1000), (64, cells))), dense) == dense
    assert fitted_shapes(small._replace(groups=((8, 1000), (64, cells - 1))), dense).groups == ((8, 1000),
                                                                                                (64, cells - 1))
