"""Beams cut past their readings (``ModelParams.cut_past_reading``): the cut table lists exactly the cells the cut
model looks at, the fast paths' conditionals and log joints equal the GenJAX model's assess, and the sampler's
marginals match exact enumeration of the cut model."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.cellwise import CellwiseGibbs
from bayesmap.inference.chains import run_chains
from bayesmap.inference.fast import FastGibbs
from bayesmap.model.generative import (
    log_joint_scans,
    make_params,
    prior_log_odds,
    ray_limits,
    replace_params,
    walls_log_likelihood,
)
from bayesmap.model.passable import PASS_WALLS
from helpers import (
    POSES,
    assert_block_weights_match_assess,
    assess_cell_differences,
    beam_enumeration_scene,
    enumerated_marginals,
    scenes,
)

CUT = 0.6
"""Meters past the reading in these tests: about two cells of the 1 m test grids, so that most rays lose pairs."""


def cut_scene(beam_model, seed, geometry="entry", wall_pass_prob=0.0):
    """:func:`helpers.scenes` with the model cut :data:`CUT` m past each reading and its table built with the cut."""
    grid, params, angles, truth, y, full = scenes(beam_model, seed, geometry=geometry)
    params = replace_params(params, cut_past_reading=CUT, wall_pass_prob=wall_pass_prob)
    table = build_ray_table(grid, np.repeat(POSES, angles.shape[1], axis=0), angles.reshape(-1), params.max_range,
                            ray_limits=ray_limits(y.reshape(-1), params))
    return grid, params, angles, truth, y, table, full


def test_cut_table_is_the_full_table_below_each_limit():
    """Ray by ray, the cut table's cells and distances are the full table's pairs whose distance is below the
    ray's limit min(y + cut, max range), in the same order; the max-range beams keep their whole ray; replacing rays
    keeps their limits."""
    grid, params, angles, _, y, table, full = cut_scene("beam", 2)
    limits = ray_limits(y.reshape(-1), params)
    for r in range(full.num_rays):
        cells, dists = full.ray(r)
        keep = dists < limits[r]
        np.testing.assert_array_equal(table.ray(r)[0], cells[keep])
        np.testing.assert_array_equal(table.ray(r)[1], dists[keep])
    whole = y.reshape(-1) >= params.max_range
    np.testing.assert_array_equal(table.lengths[whole], full.lengths[whole])
    assert table.num_pairs < 0.8 * full.num_pairs
    rays = np.array([3, 11])
    moved = table.replace_rays(rays, table.origins[rays], table.beam_angles[rays] + 0.4)
    np.testing.assert_array_equal(moved.ray_limits, table.ray_limits)
    rebuilt = build_ray_table(grid, moved.origins, moved.beam_angles, params.max_range, ray_limits=limits)
    np.testing.assert_array_equal(moved.offsets, rebuilt.offsets)
    np.testing.assert_array_equal(moved.pair_cells, rebuilt.pair_cells)


@pytest.mark.parametrize("beam_model, geometry, wall_pass_prob", [
    ("normal", "entry", 0.0), ("beam", "entry", 0.0), ("beam", "chord", 0.0), ("beam", "entry", 0.3),
    ("beam", "chord", 0.3)])
def test_table_log_joint_equals_assess(beam_model, geometry, wall_pass_prob):
    """For random maps, the log joint from the cut table (the prior plus walls_log_likelihood of each ray's first
    walls in the table) equals the cut model's assess (float64 on both sides, 1e-6 relative); and the cut
    changes the log joint (by more than 1e-3 nats) for the beam model, so the test can tell the two models apart."""
    with enable_x64():
        grid, params, angles, _, y, table, _ = cut_scene(beam_model, 4, geometry, wall_pass_prob)
        uncut = replace_params(params, cut_past_reading=math.inf)
        rng = np.random.default_rng(1)
        for density in (0.2, 0.5):
            walls = (rng.random(grid.shape) < density).astype(np.float64)
            chords = table.wall_chords(walls, PASS_WALLS if wall_pass_prob else 1)
            p = params.prior_wall_prob
            prior = walls.sum() * math.log(p) + (walls.size - walls.sum()) * math.log1p(-p)
            got = prior + float(jnp.sum(walls_log_likelihood(jnp.asarray(y.reshape(-1)), jnp.asarray(chords), params)))
            want = float(log_joint_scans(walls, y, POSES, params, angles))
            assert got == pytest.approx(want, rel=1e-6, abs=1e-6)
            if beam_model == "beam":
                assert abs(want - float(log_joint_scans(walls, y, POSES, uncut, angles))) > 1e-3


@pytest.mark.parametrize("beam_model, geometry", [("normal", "entry"), ("beam", "entry"), ("beam", "chord")])
def test_cellwise_conditionals_match_assess(beam_model, geometry):
    """The whole-log sampler on the cut table: every cell's conditional log-odds equals the difference of the cut
    model's assess with the cell set to 1 and to 0 (1e-4 as tests/inference/test_cellwise.py, float64)."""
    with enable_x64():
        grid, params, angles, _, y, table, _ = cut_scene(beam_model, 7, geometry)
        sampler = CellwiseGibbs(table, y.reshape(-1), params)
        brute = assess_cell_differences(grid, params, angles, y)
        rng = np.random.default_rng(3)
        for density in (0.15, 0.35, 0.6):
            walls = (rng.random(grid.shape) < density).astype(np.float64)
            want = np.asarray(brute(jnp.asarray(walls)))
            np.testing.assert_allclose(np.asarray(sampler.cell_log_odds(walls)), want, atol=1e-4, rtol=0)
            assert np.ptp(want - prior_log_odds(params.prior_wall_prob)) > 2.0


def test_sampler_matches_exact_enumeration_of_the_cut_model():
    """On the 3 x 4 enumeration scene (beam model, sensor noise 0.4 m, 2 poses x 6 beams) cut 0.2 m past each
    reading: 64 chains x 300 sweeps of the cut table's sampler against the 4,096 maps enumerated with the cut model's
    assess. Tolerance 0.06 as tests/inference/test_cellwise.py::test_sampler_matches_exact_enumeration (Monte Carlo
    standard error <= 0.014); a cut this short (half the noise) moves some exact marginal by more than 0.15 from the
    uncut model's (0.24), so the test tells the two models apart."""
    full, y, uncut_params, uncut_exact = beam_enumeration_scene()
    params = replace_params(uncut_params, cut_past_reading=0.2)
    exact = enumerated_marginals(full.origins[::6], params, full.beam_angles.reshape(2, 6), y)
    assert np.abs(exact - uncut_exact).max() > 0.15
    table = build_ray_table(full.grid, full.origins, full.beam_angles, params.max_range,
                            ray_limits=ray_limits(y.reshape(-1), params))
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    result = run_chains(jax.random.key(3), sampler.algorithm, jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.samples[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.06, (est, exact)


def test_a_table_that_does_not_match_the_cut_is_refused():
    """A sampler refuses a full table for a cut model, and a cut table for an uncut model (each by name)."""
    grid, params, angles, _, y, table, full = cut_scene("beam", 2)
    with pytest.raises(BayesmapError, match="ray limits differ"):
        CellwiseGibbs(full, y.reshape(-1), params)
    with pytest.raises(BayesmapError, match="cut past the readings but the model is not"):
        CellwiseGibbs(table, y.reshape(-1), replace_params(params, cut_past_reading=math.inf))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "far"])
def test_bad_cut_is_refused(bad):
    with pytest.raises(BayesmapError, match="cut_past_reading"):
        make_params(cut_past_reading=bad)


@pytest.mark.parametrize("block_size", [1, 2])
def test_fast_block_weights_match_assess(block_size):
    """The level-based sampler (FastGibbs) on the cut table, beam model: every block's log-weights over its
    configurations equal the cut model's assess differences (1e-4 as tests/model/test_multiscan.py, float64)."""
    with enable_x64():
        grid, params, angles, _, y, table, _ = cut_scene("beam", 7)
        fast = FastGibbs(table, y.reshape(-1), params, block_size=block_size)
        assert_block_weights_match_assess(fast, grid, params, angles, y)
