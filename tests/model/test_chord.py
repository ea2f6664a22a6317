"""The chord geometry: the sensor's hit averaged over the beam's chord through the first wall cell.

Its densities are probability measures (quadrature, with the beam mixture's atom at the max range), tend to the
entry geometry as the chord shrinks, stay finite far in the tails; its GenJAX distributions sample what they score;
the model's chords equal the ray-cell table's; and every fast path (cellwise, the block samplers, the held-out
scores, the table's log joint) equals the GenJAX model's ``assess`` in the chord geometry.

Numbers run in float64 (``enable_x64``) unless a test checks float32 on purpose."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64
from scipy import integrate, stats

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import first_hit_chords, first_hit_distances
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.cellwise import CellwiseGibbs
from bayesmap.inference.fast import FastGibbs
from bayesmap.model import sensor
from bayesmap.model.generative import (
    log_joint_scans,
    make_params,
    prior_log_odds,
)
from helpers import (
    POSES,
    assert_block_weights_match_assess,
    assess_cell_differences,
    random_scene,
    scenes,
)

SIGMA, MAX = 0.05, 8.0
BEAM = (SIGMA, 0.8, 0.05, 0.05, 0.1, 0.1, MAX)
# chords: ordinary, degenerate, shorter than CHORD_MIN_WIDTH sigmas, just above it, at the sensor, at the max range,
# the no-wall chord
CHORDS = [(1.0, 1.1), (1.0, 1.0), (1.0, 1.0 + 1e-5), (1.0, 1.0 + 2e-4), (0.0, 0.07), (0.01, 0.03), (7.95, 8.0),
          (7.9, 7.99), (MAX, MAX)]


# the densities under quadrature, jitted: scipy's adaptive quadrature calls them point by point (hundreds of times per
# integral), and the un-jitted functions dispatch each of their ~100 operations separately (45 ms a call, against
# 0.2 ms jitted; the same operations, the same values to rounding). Called with float64 scalars inside enable_x64.
_chord_normal_logpdf = jax.jit(sensor.chord_normal_logpdf)
_chord_beam_logpdf = jax.jit(sensor.chord_beam_logpdf)


def _quad(f, lo, hi, points):
    """Adaptive quadrature of ``f`` on [lo, hi] with breakpoints (absolute error estimate below 1e-10 here)."""
    points = sorted({p for p in points if lo < p < hi})
    value, error = integrate.quad(f, lo, hi, points=points or None, limit=400, epsabs=1e-12, epsrel=1e-12)
    assert error < 1e-9
    return value


@pytest.mark.parametrize("a,b", CHORDS)
def test_chord_normal_is_a_density_and_the_average_of_the_normal(a, b):
    """The chord Normal integrates to 1 (tolerance 1e-8: quadrature error < 1e-10) and equals the average of
    ``N(y; x, sigma)`` over ``x`` in [a, b] by quadrature at a few readings (relative 1e-6: the midpoint rule for
    chords below CHORD_MIN_WIDTH sigmas errs by < 1e-7; the closed form by float64 rounding)."""
    with enable_x64():
        def f(y):
            return float(np.exp(_chord_normal_logpdf(y, a, b, SIGMA)))

        total = _quad(f, a - 20 * SIGMA, b + 20 * SIGMA, [a, b])
        assert total == pytest.approx(1.0, abs=1e-8)
        for y in (a - 0.1, a, 0.5 * (a + b), b + 0.02):
            if b > a:
                want = _quad(lambda x: stats.norm.pdf(y, x, SIGMA), a, b, []) / (b - a)
            else:
                want = stats.norm.pdf(y, a, SIGMA)
            assert f(y) == pytest.approx(want, rel=1e-6)


@pytest.mark.parametrize("a,b", CHORDS)
def test_chord_beam_mixture_is_a_probability_measure(a, b):
    """Density on [0, M) plus the atom at M is 1 (tolerance 1e-8), for chords anywhere in [0, M], degenerate ones
    and the no-wall chord [M, M]. A chord at 0 keeps the short component on [0, MIN_SHORT_DISTANCE] (its mass z_short
    lies in a micrometre, integrated apart). A wrong normalizer of the hit's truncation at 0 (1/2 at a = 0) or of its
    censoring at M (half the hit at a = M) would be off by >= 0.05."""
    with enable_x64():
        def f(y):
            return float(np.exp(_chord_beam_logpdf(y, a, b, *BEAM)))

        d_short = max(a, sensor.MIN_SHORT_DISTANCE)
        total = _quad(f, 0.0, d_short, []) + _quad(f, d_short, MAX, [a, b, a - 0.5, b + 0.5])
        atom = float(np.exp(sensor.chord_beam_logpdf(MAX, a, b, *BEAM)))
        assert total + atom == pytest.approx(1.0, abs=1e-8)


def test_short_chords_tend_to_the_entry_geometry_and_tails_stay_finite():
    """As b -> a the chord's densities and atom tend to the entry geometry's: at a width of 1e-3 sigma (the switch
    to the midpoint) both sides of the switch agree with the entry geometry at the chord's midpoint to 1e-5 in log
    (the midpoint's error is (w / sigma)^2 (1 + z^2) / 24 < 1e-6 here); readings 40
    sigmas away and chords far below the max range give finite log-densities in float32 and float64 (no -inf, no
    NaN), within 1e-3 relative of float64."""
    a = 2.0
    with enable_x64():
        for width in (0.0, 0.999e-3 * SIGMA, 1.001e-3 * SIGMA):
            mid = a + 0.5 * width
            for y in (a - 0.1, a, a + 0.03):
                np.testing.assert_allclose(sensor.chord_normal_logpdf(y, a, a + width, SIGMA),
                                           sensor.normal_logpdf(y, mid, SIGMA), atol=1e-5)
                np.testing.assert_allclose(sensor.chord_beam_logpdf(y, a, a + width, *BEAM),
                                           sensor.beam_logpdf(y, mid, *BEAM), atol=1e-5)
            np.testing.assert_allclose(sensor.chord_beam_log_max_mass(a, a + width, *BEAM),
                                       sensor.beam_log_max_mass(mid, *BEAM), atol=1e-5)
        y = np.array([a - 40 * SIGMA, a + 40 * SIGMA, 0.0])
        ref = np.asarray(sensor.chord_normal_logpdf(y, a, a + 0.1, SIGMA))
        censored = np.asarray(sensor.chord_beam_log_max_mass(np.array([0.5, 7.0]), np.array([0.6, 7.1]), *BEAM))
    f32 = np.asarray(sensor.chord_normal_logpdf(jnp.asarray(y, jnp.float32), jnp.float32(a), jnp.float32(a + 0.1),
                                                jnp.float32(SIGMA)))
    assert np.all(np.isfinite(ref)) and np.all(np.isfinite(f32))
    np.testing.assert_allclose(f32, ref, rtol=1e-3)
    assert np.all(np.isfinite(censored))


def test_log_normal_partial_expectation():
    """``log G(t)``, ``G(t) = t Phi(t) + phi(t) = int_{-inf}^t Phi``, against a float64 reference that does not
    cancel (``G(t) = phi(t) (1 - |t| R(|t|))`` for ``t < 0`` with the Mills ratio ``R`` from scipy's ``erfcx``:
    rounding below 1e-12): 1e-9 where the direct formula is used (t >= -10), 1e-5 beyond (the series'
    truncation); continuous at the switch (1e-5); ``G(t) - G(-t) = t``; and ``G' = Phi`` (a difference quotient,
    1e-6)."""
    from scipy.special import erfcx

    def reference(t):
        if t >= 0:
            return math.log(t * stats.norm.cdf(t) + stats.norm.pdf(t))
        mills = math.sqrt(math.pi / 2) * float(erfcx(-t / math.sqrt(2)))
        return float(stats.norm.logpdf(t)) + math.log1p(t * mills)

    with enable_x64():
        for t in (-30.0, -12.0, -10.5, -9.0, -3.0, -0.5, 0.0, 2.0, 7.0):
            got = float(sensor.log_normal_partial_expectation(t))
            assert got == pytest.approx(reference(t), abs=1e-5 if t < -10 else 1e-9), t
        left = float(sensor.log_normal_partial_expectation(-10.0 - 1e-9))
        right = float(sensor.log_normal_partial_expectation(-10.0))
        assert left == pytest.approx(right, abs=1e-5)
        g = np.exp(sensor.log_normal_partial_expectation(np.array([0.3, -0.3, 1.0 + 1e-6, 1.0 - 1e-6])))
        assert g[0] - g[1] == pytest.approx(0.3, abs=1e-12)
        assert (g[2] - g[3]) / 2e-6 == pytest.approx(stats.norm.cdf(1.0), abs=1e-6)


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_chord_distributions_sample_what_they_score(beam_model):
    """20,000 draws of the GenJAX distribution: the fraction at the max range and the mean and the probability of
    the first half of the chord's neighbourhood below M match quadrature of the scored density within 5 Monte Carlo
    standard errors (a sampler that ignored the chord, drawing at a, is off by > 30 of them), plus 1e-8 for the
    quadrature (its error estimate is below 1e-9, _quad). The binomial variance ``p (1 - p)`` is clipped at 0: for
    the Normal the neighbourhood holds all but 2e-23 of the mass, and the quadrature's ``p`` can come out a rounding
    error above 1 (then the tolerance is the quadrature's, and every draw must fall in the neighbourhood)."""
    a, b = 3.0, 3.2
    args = (a, b) + ((SIGMA,) if beam_model == "normal" else BEAM)
    dist = sensor.reading_distribution(beam_model, "chord")
    quad_tol = 1e-8

    def tolerance(p, n):
        return 5 * math.sqrt(max(p * (1 - p), 0.0) / n) + quad_tol

    with enable_x64():
        keys = jax.random.split(jax.random.key(0), 20_000)
        draws = np.asarray(jax.jit(jax.vmap(lambda k: dist.simulate(k, args).get_retval()))(keys))
        logpdf = _chord_normal_logpdf if beam_model == "normal" else _chord_beam_logpdf

        def f(y):
            return float(np.exp(logpdf(y, *args)))

        lo = a - 10 * SIGMA
        inside = _quad(f, lo, b + 10 * SIGMA, [a, b])
        mean = _quad(lambda y: y * f(y), lo, b + 10 * SIGMA, [a, b]) / inside
        below = _quad(f, lo, 0.5 * (a + b), [a]) / inside
        atom = float(np.exp(logpdf(MAX, *args))) if beam_model == "beam" else 0.0
    near = (draws > lo) & (draws < b + 10 * SIGMA)
    assert near.mean() == pytest.approx(inside, abs=tolerance(inside, len(draws)))
    if beam_model == "beam":
        assert np.mean(draws >= MAX) == pytest.approx(atom, abs=tolerance(atom, len(draws)))
    sd = (b - a) / math.sqrt(12) + SIGMA
    assert draws[near].mean() == pytest.approx(mean, abs=5 * sd / math.sqrt(near.sum()) + quad_tol)
    frac = np.mean(draws[near] < 0.5 * (a + b))
    assert frac == pytest.approx(below, abs=tolerance(below, near.sum()))


def test_model_chords_equal_the_tables():
    """On random scenes (metric grids, any origin): the model's entry distances (column 0 of first_hit_chords) are
    exactly first_hit_distances, and the table's first-wall chords equal the model's (entry exactly as the tables
    are tested, 1e-5 relative + 1e-5 cells; exit likewise); exits lie in [entry, max distance]."""
    rng = np.random.default_rng(11)
    for _ in range(6):
        grid, pos, walls, angles = random_scene(rng, metric=True)
        max_d = float(grid.default_max_distance) * 0.6
        chords = np.asarray(first_hit_chords(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(angles), grid, max_d))
        entry = np.asarray(first_hit_distances(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(angles), grid, max_d))
        np.testing.assert_array_equal(chords[:, 0], entry)
        assert np.all(chords[:, 1] >= chords[:, 0]) and np.all(chords[:, 1] <= max_d * (1 + 1e-6))
        table = build_ray_table(grid, pos, angles, max_d)
        tol = 1e-5 * grid.resolution
        np.testing.assert_allclose(table.first_wall_chords(walls), chords, rtol=1e-5, atol=tol)
        assert np.all(table.pair_exits >= table.pair_dists)
        # a chord is at most a cell's diagonal
        assert np.all(table.pair_exits - table.pair_dists <= math.sqrt(2) * grid.resolution * (1 + 1e-5))
        # the exits of some pairs (wall_chords computes only its walls') are the table's, to the bit
        some = np.random.default_rng(0).integers(0, table.num_pairs, 50)
        np.testing.assert_array_equal(table.exits_of_pairs(some), table.pair_exits[some])
        two = table.wall_chords(walls, 2)  # (R, 2, 2): each ray's first two wall pairs, in order along it
        for r in range(table.num_rays):
            cells, _ = table.ray(r)
            wall_pairs = table.offsets[r] + np.flatnonzero(np.asarray(walls).reshape(-1)[cells] > 0)
            for k in range(2):
                want = ((table.pair_dists[wall_pairs[k]], table.pair_exits[wall_pairs[k]]) if k < len(wall_pairs)
                        else (table.max_distance, table.max_distance))
                np.testing.assert_array_equal(two[r, k], np.asarray(want, table.pair_dists.dtype))


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_cellwise_conditionals_match_the_model_in_the_chord_geometry(beam_model):
    """As tests/inference/test_cellwise.py::test_conditionals_match_the_multi_scan_model, in the chord geometry:
    every cell's log-odds from the sweep's tables equals the difference of assess with the cell set to 1 and 0
    (tempered: likelihood powers 1 and, for the beam model, 0.3, against the one assess reference), tolerance 1e-4
    (the model's float32 prior; the exits of model and table differ by float rounding, < 1e-6 here). The entry
    geometry's log-odds differ from the chord's by > 0.5 somewhere: the test can fail."""
    with enable_x64():
        grid, params, angles, _, y, table = scenes(beam_model, 7, geometry="chord")
        entry_params = make_params(0.3, 0.4, 10, grid, 6.0, beam_model=beam_model)
        powers = (1.0, 0.3) if beam_model == "beam" else (1.0,)
        samplers = {eta: (CellwiseGibbs(table, y.reshape(-1), params, likelihood_power=eta),
                          CellwiseGibbs(table, y.reshape(-1), entry_params, likelihood_power=eta)) for eta in powers}
        brute = assess_cell_differences(grid, params, angles, y)
        rng = np.random.default_rng(3)
        logit = prior_log_odds(params.prior_wall_prob)
        for density in (0.15, 0.35, 0.6):
            walls = (rng.random(grid.shape) < density).astype(np.float64)
            differences = np.asarray(brute(jnp.asarray(walls)))
            for likelihood_power, (sampler, entry) in samplers.items():
                got = np.asarray(sampler.cell_log_odds(walls))
                want = logit + likelihood_power * (differences - logit)
                np.testing.assert_allclose(got, want, atol=1e-4, rtol=0)
                assert np.ptp(want) > 2.0
                assert np.abs(np.asarray(entry.cell_log_odds(walls)) - got).max() > 0.5


@pytest.mark.parametrize("beam_model,block_size", [("normal", 1), ("normal", 2), ("beam", 2)])
def test_block_samplers_match_the_model_in_the_chord_geometry(beam_model, block_size):
    """The block samplers' conditional log-weights (every configuration of every block, relative to all-free)
    equal assess's in the chord geometry, tolerance 1e-4 as tests/model/test_multiscan.py."""
    with enable_x64():
        grid, params, angles, _, y, table = scenes(beam_model, 7, geometry="chord")
        fast = FastGibbs(table, y.reshape(-1), params, block_size=block_size)
        assert_block_weights_match_assess(fast, grid, params, angles, y)


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_table_log_joint_and_heldout_density_in_the_chord_geometry(beam_model):
    """The table's log joint (bayesmap.problem.Problem.table_log_joint) equals the model's assess in the chord geometry
    (1e-6 relative), and the held-out predictive density of a map with certain cells (0/1 probabilities) equals the
    model's per-beam density in both of the held-out evaluator's forms (1e-9)."""
    from bayesmap.evaluation.heldout import (
        predictive_log_density_independent,
        predictive_log_density_samples,
        sensor_logpdf,
    )
    from bayesmap.problem import Problem

    with enable_x64():
        grid, params, angles, truth, y, table = scenes(beam_model, 5, geometry="chord")
        problem = Problem.from_world_frame(params, POSES, angles, y)
        for walls in (truth, np.zeros_like(truth)):
            want = float(log_joint_scans(walls, y, POSES, params, angles))
            assert problem.table_log_joint(walls) == pytest.approx(want, rel=1e-6)
        logpdf = sensor_logpdf(params)
        chords = table.first_wall_chords(truth)
        per_beam = logpdf(y.reshape(-1), chords[:, 0], chords[:, 1])
        np.testing.assert_allclose(predictive_log_density_samples(table, y.reshape(-1), truth[None], logpdf,
                                                                  chords=True), per_beam, atol=1e-9)
        np.testing.assert_allclose(predictive_log_density_independent(table, y.reshape(-1), truth, logpdf,
                                                                      chords=True), per_beam, atol=1e-9)


def test_geometry_defaults_and_errors():
    """The tutorial's parameters keep the entry geometry; an unknown geometry is refused naming it."""
    assert make_params().geometry == "entry"
    with pytest.raises(BayesmapError, match="'middle'"):
        make_params(geometry="middle")
    with pytest.raises(BayesmapError, match="'middle'"):
        sensor.reading_distribution("normal", "middle")
    with pytest.raises(BayesmapError, match="exit distances"):
        from bayesmap.model.generative import reading_log_likelihood

        reading_log_likelihood([1.0], [1.0], make_params(geometry="chord", grid=Grid((3, 3))))
