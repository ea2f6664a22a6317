"""The likelihood side of the fast samplers' conditionals (bayesmap.model.likelihood and the prior log-odds of
bayesmap.model.generative): the per-pair tables against the sensor model, the max-range rule, tempering."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.cellwise import CellwiseGibbs
from bayesmap.inference.fast import FastGibbs
from bayesmap.model.generative import make_params, prior_log_odds
from bayesmap.model.likelihood import (
    PAIR_CHUNK,
    check_max_range,
    chunked_log_likelihoods,
    likelihood_inputs,
    log_likelihood_table,
    padded_length,
    pair_log_likelihoods,
    tempered,
)
from bayesmap.model.sensor import reading_logpdf


@pytest.mark.parametrize("x64", [False, True])
@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_pair_log_likelihoods_are_the_sensor_model(beam_model, x64):
    """likelihood.pair_log_likelihoods (the per-pair table of the fast and cellwise samplers, which computes the beam
    model's point mass only for the pairs of max-range readings) equals reading_logpdf at each pair's reading and
    stopping distance, element by element, then zeros up to its padded length; with max-range readings (at and
    beyond the max range),
    readings just below it on rays whose last cells are near the max range, readings of 0, and stopping distances
    near 0 (sensors just inside a cell edge), in float32 and float64. Tolerance: a few units of rounding (the same
    operations in one jitted call; in practice the bits are equal)."""
    with enable_x64(x64):
        grid = Grid((12, 12))
        params = make_params(0.3, 0.05, 16, grid, 6.0, beam_model=beam_model)
        poses = np.array([[3.4999, 5.0], [6.0, 6.5001], [8.2, 3.3]])
        rng = np.random.default_rng(0)
        angles = rng.uniform(-np.pi, np.pi, (3, 16))
        angles[:, :4] = [0.0, np.pi / 2, np.pi, -np.pi / 2]  # straight out of the cell whose edge is 1e-4 away
        table = build_ray_table(grid, np.repeat(poses, 16, axis=0), angles.reshape(-1), params.max_range)
        m = params.max_range
        y = rng.uniform(0.0, m, table.num_rays)
        y[::5], y[1::7], y[2::6], y[3::9] = m, 2 * m, m - 0.01, 0.0
        dtype = jnp.result_type(float)
        sensor_args = tuple(jnp.asarray(a, dtype) for a in params.sensor_args)
        got = np.asarray(pair_log_likelihoods(table, y, beam_model, sensor_args))
        want = np.asarray(reading_logpdf(beam_model, jnp.asarray(y[table.pair_rays], dtype),
                                         jnp.asarray(table.pair_dists, dtype), sensor_args))
        num_pairs = table.num_pairs
        assert got.shape == (PAIR_CHUNK,) and got.dtype == dtype and not got[num_pairs:].any()
        tol = 8 * np.finfo(dtype).eps
        np.testing.assert_allclose(got[:num_pairs], want, rtol=tol, atol=tol)
        # the scene has what the test is about
        at_max = y[table.pair_rays] >= m
        assert at_max.any() and (~at_max).any() and np.isfinite(want).all()
        assert table.pair_dists.min() < 1e-3 and table.pair_dists[~at_max].max() > m - 0.3


@pytest.mark.parametrize("chord", [False, True])
def test_chunked_tables_are_the_table_across_chunk_edges(chord):
    """Eight chunks and a bit of random readings (max-range ones too) and distances (some inf: no wall): computed
    a chunk at a time they are log_likelihood_table of the whole arrays, bit for bit (the same elementwise
    operations); the rest up to the padded length is 0, and the length is a padded number of chunks."""
    grid = Grid((12, 12))
    params = make_params(0.3, 0.05, 16, grid, 6.0, beam_model="beam")
    rng = np.random.default_rng(1)
    n = 8 * PAIR_CHUNK + 5
    y = rng.uniform(0.0, 7.0, n).astype(np.float32)
    y[rng.random(n) < 0.2] = params.max_range
    d = rng.uniform(0.0, 6.0, n).astype(np.float32)
    d[rng.random(n) < 0.1] = np.inf
    exits = (d + rng.uniform(0.0, 0.3, n)).astype(np.float32) if chord else None
    sensor_args = tuple(jnp.asarray(a, jnp.float32) for a in params.sensor_args)
    got = np.asarray(chunked_log_likelihoods("beam", sensor_args, y, d, exits))
    want = np.asarray(log_likelihood_table("beam", sensor_args, y, d, exits))
    assert got.shape == (PAIR_CHUNK * padded_length(9),) and padded_length(9) == 10  # a zero chunk appended
    np.testing.assert_array_equal(got[:n], want)
    assert not got[n:].any() and np.isfinite(want).all() and (want == 0).any() and (y[d < np.inf] >= 6.0).any()


def test_padded_lengths_are_few_and_close():
    """padded_length(n) >= n, within 25 % of n (n itself below 8), never decreasing, and it takes 4 values per
    doubling: from 1,000 to 1,000,000 the 999,001 lengths share 41 compilations."""
    n = np.arange(0, 1_000_001)
    got = np.array([padded_length(int(k)) for k in n])
    assert (got >= n).all() and (got[8:] <= 1.25 * n[8:]).all() and (got[:8] == n[:8]).all()
    assert (np.diff(got) >= 0).all()
    assert len(np.unique(got[1000:])) == 41
    assert padded_length(1 << 20) == 1 << 20 and padded_length((1 << 20) + 1) == 5 << 18
    with pytest.raises(ValueError, match="-1"):
        padded_length(-1)


@pytest.mark.parametrize("p", [0.5, 0.1, 0.3, 0.9, 1e-6, 1 - 1e-6])
def test_prior_log_odds_is_the_logit_of_the_prior(p):
    """prior_log_odds(p) = log(p / (1 - p)) (to float64 rounding, relative 1e-12 or 1e-15 absolute), 0 for 0.5,
    antisymmetric under p -> 1 - p, and the sigmoid of it gives p back."""
    lo = prior_log_odds(p)
    assert isinstance(lo, float)
    assert lo == pytest.approx(np.log(p / (1 - p)), rel=1e-12, abs=1e-15)
    assert lo == pytest.approx(-prior_log_odds(1 - p), rel=1e-9, abs=1e-15)
    assert 1 / (1 + math.exp(-lo)) == pytest.approx(p, rel=1e-12)
    assert prior_log_odds(0.5) == 0.0


def test_tempered_multiplies_each_log_likelihood_and_leaves_eta_one_exact():
    """Tempering multiplies every log p(y | d) by eta; eta = 1 returns the same bits (float32 and float64)."""
    ll = jnp.asarray([-3.25, 0.0, 7.1, -1e-8], jnp.float32)
    np.testing.assert_array_equal(np.asarray(tempered(ll, 1.0)), np.asarray(ll))
    np.testing.assert_array_equal(np.asarray(tempered(ll, jnp.float32(1.0))), np.asarray(ll))
    np.testing.assert_allclose(np.asarray(tempered(ll, 0.25)), 0.25 * np.asarray(ll), rtol=1e-7)
    assert tempered(ll, 0.25).dtype == jnp.float32
    assert tempered(np.array([2.0, -4.0]), 0.5).tolist() == [1.0, -2.0]


def test_log_likelihood_table_is_zero_where_no_wall_stops_the_ray():
    """log_likelihood_table is the sensor model where d is finite and 0 where d is inf (a block configuration that
    does not stop the ray), broadcasting y (2, 1) against d (2, 3)."""
    params = make_params(0.3, 0.2, 4, Grid((5, 5)), 4.0, beam_model="beam")
    sensor_args = tuple(jnp.asarray(a, jnp.float32) for a in params.sensor_args)
    y = jnp.asarray([[1.0], [4.0]], jnp.float32)
    d = jnp.asarray([[0.5, 1.0, np.inf], [2.0, 4.0, np.inf]], jnp.float32)
    got = np.asarray(log_likelihood_table("beam", sensor_args, y, d))
    want = np.asarray(reading_logpdf("beam", y, jnp.where(jnp.isfinite(d), d, 1.0), sensor_args))
    assert got.shape == (2, 3)
    np.testing.assert_array_equal(got[:, 2], 0.0)
    np.testing.assert_allclose(got[:, :2], want[:, :2], rtol=1e-6)
    assert np.isfinite(got).all() and got[0, 1] > got[0, 0]  # a hit at the reading is likelier than a short one


def test_max_range_rule_and_inputs():
    """The beam model needs the table's max distance to be the model's max range (both named in the error), for
    check_max_range and both fast samplers; the Normal takes any table. likelihood_inputs casts the sensor
    arguments to the kernel dtype and checks the readings and the likelihood power."""
    grid = Grid((6, 6))
    origins, angles = np.array([[1.5, 1.5]] * 4), np.linspace(0.0, 6.0, 4)
    table = build_ray_table(grid, origins, angles, 5.0)
    y = np.full(4, 2.0)
    beam = make_params(0.3, 0.2, 4, grid, 4.0, beam_model="beam")
    normal = make_params(0.3, 0.2, 4, grid, 4.0)
    for build in (check_max_range, lambda t, p: FastGibbs(t, y, p), lambda t, p: CellwiseGibbs(t, y, p)):
        with pytest.raises(BayesmapError, match=r"max distance 5\.0 m is not the model's max range .* 4\.0 m"):
            build(table, beam)
    check_max_range(table, normal)
    check_max_range(build_ray_table(grid, origins, angles, 4.0), beam)
    inputs = likelihood_inputs(table, y, normal, 0.5)
    assert inputs.beam_model == "normal" and inputs.likelihood_power == 0.5
    assert inputs.readings.dtype == np.float64 and inputs.readings.tolist() == y.tolist()
    assert ([a.dtype for a in inputs.sensor_args] == [inputs.dtype]
            and float(inputs.sensor_args[0]) == pytest.approx(0.2))
    with pytest.raises(BayesmapError, match="likelihood_power"):
        likelihood_inputs(table, y, normal, 1.5)
    with pytest.raises(BayesmapError, match="readings"):
        likelihood_inputs(table, y[:3], normal)


def test_chunked_length_is_the_length_of_the_chunked_table():
    """``chunked_length(n)``, the length arrays are padded to so that one compilation serves every ``n`` of it, is
    the length ``chunked_log_likelihoods`` returns for ``n`` entries (one, two and four chunks, at their edges), and
    grows in whole chunks."""
    from bayesmap.model.likelihood import chunked_length

    params = make_params()
    args = tuple(jnp.asarray(a, jnp.float32) for a in params.sensor_args)
    for n in (0, 1, PAIR_CHUNK - 1, PAIR_CHUNK, 2 * PAIR_CHUNK + 3, 3 * PAIR_CHUNK):
        y = np.full(n, 2.0, np.float32)
        got = chunked_log_likelihoods(params.beam_model, args, y, np.full(n, 1.0, np.float32))
        assert len(got) == chunked_length(n) > n and chunked_length(n) % PAIR_CHUNK == 0
    assert chunked_length(3 * PAIR_CHUNK) == 4 * PAIR_CHUNK
    with pytest.raises(ValueError, match="-1"):
        chunked_length(-1)
