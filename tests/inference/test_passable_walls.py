"""Wall cells a beam can pass (``wall_pass_prob``): the GenJAX model's mixture over a ray's first two walls, the
cellwise sampler's conditionals, rows and marginals against it, the held-out predictive densities, and the samplers
that refuse it."""

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.heldout import (
    predictive_log_density_independent,
    predictive_log_density_samples,
    predictive_log_density_walls,
    sensor_logpdf,
)
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import wall_hit_chords
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference import cellwise
from bayesmap.inference.cellwise import CellwiseGibbs
from bayesmap.inference.chains import run_chains
from bayesmap.inference.fast import fast_gibbs
from bayesmap.model.generative import (
    log_joint_scans,
    make_params,
    prior_log_odds,
    reading_log_likelihood,
    simulate_scan_readings,
    walls_log_likelihood,
)
from bayesmap.model.passable import check_wall_pass_prob
from helpers import POSES, assess_cell_differences, beam_enumeration_scene, scenes, sweeps_keep_ray_rows

PASS = 0.3


def passable(params, pass_prob=PASS):
    return dataclasses.replace(params, wall_pass_prob=pass_prob)


@pytest.mark.parametrize("geometry, beam_model", [("chord", "beam")])
def test_the_model_scores_the_mixture_over_the_first_two_walls(geometry, beam_model):
    """assess minus the prior is, per beam, log((1 - pi) p(y | w1) + pi (1 - pi) p(y | w2) + pi^2 p(y | none)) with
    each part the one-wall sensor model at the ray's first wall, its second, and the max distance; the chords of the
    two walls from the all-cells cast equal the table's. With pi = 0 the model is the one-wall model, and pi changes
    the score by far more than rounding. (The entry geometry's draws are checked below; the mixture's code is the
    same for both geometries.)"""
    grid, params, angles, truth, y, table = scenes(beam_model, 4, geometry=geometry)
    model = passable(params)
    chords = np.stack([np.asarray(wall_hit_chords(truth, pos, a, grid, params.max_range, 2))
                       for pos, a in zip(POSES, angles)])  # (S, K, 2, 2)
    np.testing.assert_allclose(chords.reshape(-1, 2, 2), table.wall_chords(truth, 2), atol=1e-5)
    one = dataclasses.replace(params, wall_pass_prob=0.0)
    exits = (lambda k: chords[..., k, 1]) if geometry == "chord" else (lambda k: None)
    parts = [reading_log_likelihood(y, chords[..., k, 0], one, exits(k)) for k in range(2)]
    none = np.full(y.shape, params.max_range)
    parts.append(reading_log_likelihood(y, none, one, none if geometry == "chord" else None))
    pi = PASS
    want = np.log((1 - pi) * np.exp(parts[0]) + pi * (1 - pi) * np.exp(parts[1]) + pi**2 * np.exp(parts[2]))
    prior = float(np.sum(np.where(truth > 0, np.log(0.3), np.log(0.7))))
    got = float(log_joint_scans(truth, y, POSES, model, angles)) - prior
    np.testing.assert_allclose(got, want.sum(), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(walls_log_likelihood(y, chords, model)), want, rtol=1e-5, atol=1e-5)
    opaque = float(log_joint_scans(truth, y, POSES, one, angles)) - prior
    np.testing.assert_allclose(opaque, np.sum(parts[0]), rtol=1e-5)
    assert abs(got - opaque) > 1.0


def test_simulated_readings_come_from_each_wall_with_the_mixtures_weights():
    """One beam along a row with walls at cells 3 and 6 (entry 2.5 m and 5.5 m), max distance 9.5 m, noise 0.05 m:
    4,000 simulated readings fall near 2.5, 5.5 and 9.5 m in the proportions 1 - pi, pi (1 - pi), pi^2 (0.7, 0.21,
    0.09). Binomial standard errors are at most 0.008; tolerance 0.03."""
    grid = Grid((10, 1))
    params = make_params(0.3, 0.05, 1, grid, 9.5, wall_pass_prob=PASS)
    walls = np.zeros((10, 1), np.float32)
    walls[3] = walls[6] = 1
    keys = jax.random.split(jax.random.key(0), 4000)
    y = np.asarray(jax.vmap(lambda k: simulate_scan_readings(k, walls, [[0.0, 0.0]], params, [[0.0]]))(keys))
    y = y.reshape(-1)
    fractions = [np.mean(np.abs(y - d) < 0.3) for d in (2.5, 5.5, 9.5)]
    np.testing.assert_allclose(fractions, [1 - PASS, PASS * (1 - PASS), PASS**2], atol=0.03)
    assert sum(fractions) > 0.99


@pytest.mark.parametrize("geometry", ["chord"])
def test_cellwise_conditionals_equal_assess_differences(geometry):
    """Every cell's log-odds from the cellwise scoring with passable walls equals the multi-scan model's assess with
    the cell set to 1 minus set to 0 (likelihood power 1), and the prior's log-odds plus eta times the rest at power
    0.3: the mixture is tempered as a whole. Tolerance 1e-4 as the one-wall test (float64 both sides); the five
    cases of the docstring differ by far more, and the data are informative (spread of the log-odds > 2)."""
    with enable_x64():
        grid, params, angles, _, y, table = scenes("beam", 7, geometry=geometry)
        model = passable(params)
        brute = assess_cell_differences(grid, model, angles, y)
        logit = prior_log_odds(model.prior_wall_prob)
        samplers = {eta: CellwiseGibbs(table, y.reshape(-1), model, likelihood_power=eta) for eta in (1.0, 0.3)}
        rng = np.random.default_rng(3)
        for density in (0.2, 0.5):
            walls = (rng.random(grid.shape) < density).astype(np.float64)
            differences = np.asarray(brute(jnp.asarray(walls)))
            for eta, sampler in samplers.items():
                got = np.asarray(sampler.cell_log_odds(walls))
                np.testing.assert_allclose(got, logit + eta * (differences - logit), atol=1e-4, rtol=0)
            assert np.ptp(differences) > 2.0


def test_sweeps_keep_three_walls_per_ray(monkeypatch):
    """With passable walls each row keeps a ray's first three walls: after each sweep they (and their
    log-likelihoods, the no-wall one and the mixtures of them) equal those recomputed from the new map, including
    the walk to a ray's next wall after its third when one of the three is removed (one ray rewritten per batch, so
    that a cell's rewrites take several batches)."""
    monkeypatch.setattr(cellwise, "SEARCH_BATCH", 1)
    grid, params, angles, _, y, table = scenes("beam", 11, num_beams=30, geometry="chord")
    sampler = CellwiseGibbs(table, y.reshape(-1), passable(params), likelihood_power=0.5)
    assert sampler.init(jnp.zeros(grid.shape)).ray_walls.shape == (table.num_rays + 1, 12)
    assert sweeps_keep_ray_rows(sampler, table, grid, 3, 12) > 20


def test_cellwise_marginals_match_exact_enumeration():
    """The two-scan beam scene with pi = 0.3 (4,096 maps enumerated with the model's assess): the Rao-Blackwellized
    marginals of 64 chains x 250 kept sweeps are within 0.03 of the exact ones (as the one-wall test: standard error
    <= 0.014), and the pass probability moves some exact marginal by more than 0.05 (the test sees the difference)."""
    table, y, model, exact = beam_enumeration_scene(wall_pass_prob=PASS)
    opaque = beam_enumeration_scene()[3]
    sampler = CellwiseGibbs(table, y.reshape(-1), model)
    result = run_chains(jax.random.key(3), sampler.algorithm, jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.wall_probs)[:, 50:].astype(float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.03, (est, exact)
    assert np.abs(exact - opaque).max() > 0.05


@pytest.mark.parametrize("geometry", ["chord"])
def test_predictive_densities_with_passable_walls(geometry):
    """Independent wall probabilities: the closed form (probabilities of no wall, one wall, a first and a second)
    equals the average of the model's density over all 64 maps of a 3 x 2 grid weighted by their probabilities.
    Samples: the predictive averages each sample's density, and with pi = 0 it is the one-wall one."""
    grid = Grid((3, 2))
    params = make_params(0.3, 0.3, 3, grid, max_distance=6.0, geometry=geometry, beam_model="beam",
                         wall_pass_prob=PASS)
    table = build_ray_table(grid, np.array([[-0.4, 0.2], [-0.3, 1.1], [2.4, 1.2]]), np.array([0.3, -0.2, 3.5]), 6.0)
    y = np.array([1.7, 3.1, 6.0])
    q = np.random.default_rng(3).uniform(0.05, 0.95, grid.shape)
    got = predictive_log_density_independent(table, y, q, sensor_logpdf(params), chords=geometry == "chord",
                                             pass_prob=PASS)
    maps = np.array(list(itertools.product([0.0, 1.0], repeat=6))).reshape(-1, 3, 2)
    weights = np.prod(np.where(maps > 0, q, 1 - q), axis=(1, 2))
    chords = np.stack([table.wall_chords(m, 2) for m in maps])  # (64, R, 2, 2)
    dens = np.exp(np.asarray(walls_log_likelihood(np.broadcast_to(y, (64, 3)), chords, params), np.float64))
    np.testing.assert_allclose(got, np.log(weights @ dens), rtol=1e-5)
    np.testing.assert_allclose(predictive_log_density_walls(table, y, maps[[3, 40]], params),
                               np.log(dens[[3, 40]].mean(axis=0)), rtol=1e-5)
    opaque = dataclasses.replace(params, wall_pass_prob=0.0)
    np.testing.assert_allclose(predictive_log_density_walls(table, y, maps[5:9], opaque),
                               predictive_log_density_samples(table, y, maps[5:9], sensor_logpdf(opaque),
                                                              chords=geometry == "chord"), rtol=1e-5)


def test_passable_predictive_density_of_a_ray_does_not_depend_on_the_other_rays():
    """Each ray's density with passable walls is its own: thousands of earlier rays through cells of probability 1
    (odds 1e9 at the cap) leave a later ray's value equal to that ray scored alone, to float64 rounding (a running
    sum over the whole table lost 0.003 nats and could turn a zero sum negative, a NaN NLL)."""
    grid = Grid((6, 3))
    params = make_params(0.3, 0.3, 3, grid, max_distance=8.0, geometry="chord", beam_model="beam", wall_pass_prob=PASS)
    q = np.zeros(grid.shape)
    q[2:, :2] = 1.0
    q[1, 0], q[3, 2] = 0.3, 0.6
    rng = np.random.default_rng(0)
    n = 3000
    origins = np.column_stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.4, 2.4, n)])
    thetas = rng.uniform(-0.6, 0.6, n)
    table = build_ray_table(grid, origins, thetas, 8.0)
    assert len(set(np.diff(table.offsets))) > 3  # rays of several lengths
    y = rng.uniform(0.2, 8.0, n)
    logpdf = sensor_logpdf(params)
    got = predictive_log_density_independent(table, y, q, logpdf, chords=True, pass_prob=PASS)
    assert np.all(np.isfinite(got))
    for r in rng.choice(n, 8, replace=False):
        alone = build_ray_table(grid, origins[r:r + 1], thetas[r:r + 1], 8.0)
        want = predictive_log_density_independent(alone, y[r:r + 1], q, logpdf, chords=True, pass_prob=PASS)
        np.testing.assert_allclose(got[r], want[0], rtol=0, atol=1e-12)


def test_samplers_without_a_second_wall_refuse_passable_walls():
    """The level-based samplers, the one-wall likelihood (pose moves, dense sweeps) and bad values refuse with the
    name and value."""
    grid, params, angles, _, y, table = scenes("beam", 2)
    with pytest.raises(BayesmapError, match="wall_pass_prob = 0.3"):
        fast_gibbs(table, y.reshape(-1), passable(params))
    with pytest.raises(BayesmapError, match="wall_pass_prob"):
        reading_log_likelihood(y, y, passable(params))
    for bad in (1.0, -0.1, float("nan"), "x"):
        with pytest.raises(BayesmapError, match="wall_pass_prob"):
            make_params(wall_pass_prob=bad)
    assert check_wall_pass_prob(0) == 0.0
