"""The sensor models of :mod:`bayesmap.model.sensor`: the beam mixture is a probability measure on [0, max range], its
GenJAX distribution scores and samples it, and bad parameters are refused.

Everything numeric runs in float64 (``enable_x64``) so that tolerances measure the model, not float32 rounding."""

import inspect
import math

import genjax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from genjax import ChoiceMapBuilder as C
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.model import sensor
from bayesmap.model.generative import PARAMS_FIELDS, make_params, replace_params

DEFAULT = dict(sigma=0.2, **{k: v for k, v in sensor.BEAM_DEFAULTS.items()}, max_range=42.0)
# a second setting where the short and random parts carry real mass and the max range is short
HEAVY = dict(sigma=0.5, z_hit=0.6, z_short=0.2, z_max=0.1, z_rand=0.1, lambda_short=2.0, max_range=8.0)
ORDER = ("sigma", "z_hit", "z_short", "z_max", "z_rand", "lambda_short", "max_range")


def args_of(p):
    return tuple(p[k] for k in ORDER)


def logpdf(y, d, p):
    return np.asarray(sensor.beam_logpdf(jnp.asarray(y, jnp.float64), jnp.asarray(d, jnp.float64), *args_of(p)))


def pieces(d, p, upper):
    """Breakpoints of the density on [0, upper] (upper <= max): its jumps (0, the end of the short part, max) and
    the hit's peak."""
    s = p["sigma"]
    points = {0.0, upper, min(max(d, sensor.MIN_SHORT_DISTANCE), upper)}
    points |= {min(max(d + k * s, 0.0), upper) for k in (-12, 0, 12)}
    return np.array(sorted(points))


def integrate(f, d, p, upper=None):
    """Composite 16-point Gauss-Legendre of ``f`` over [0, upper) (default [0, max)), panels no wider than
    sigma / 2 between the breakpoints: exact to ~1e-13 for these smooth pieces (the Normal varies on the scale
    sigma, the exponential on 1 / lambda >= sigma here)."""
    upper = p["max_range"] if upper is None else upper
    panel = p["sigma"] / 2
    x, w = np.polynomial.legendre.leggauss(16)
    nodes, weights = [], []
    edges = pieces(d, p, upper)
    for a, b in zip(edges[:-1], edges[1:]):
        if b <= a:
            continue
        n = max(1, math.ceil((b - a) / panel))
        edges = np.linspace(a, b, n + 1)
        half = np.diff(edges)[:, None] / 2
        nodes.append((edges[:-1, None] + half + half * x[None]).ravel())
        weights.append((half * w[None]).ravel())
    nodes, weights = np.concatenate(nodes), np.concatenate(weights)
    return float(np.sum(weights * f(nodes)))


@pytest.mark.parametrize("p", [DEFAULT, HEAVY], ids=["default", "heavy"])
@pytest.mark.parametrize("frac", [0.0, 1e-7, 1e-4, 0.3, "max-2sigma", "max-1e-3", 1.0])
def test_beam_mixture_is_a_probability_measure(p, frac):
    """Density on [0, max) by quadrature plus the point mass at max must be 1 for every d in [0, max], including
    d = 0 (short part on [0, MIN_SHORT_DISTANCE]), d below that, and d = max (no wall within range).

    Tolerance 1e-9: the quadrature is exact to ~1e-13 and float64 rounding over 10^4 nodes is ~1e-13; any slip in a
    normalizer (PR's eta = 1 / Phi(d / sigma) is 2 at d = 0; the censored tail is half the hit at d = max) is
    >= 1e-3."""
    with enable_x64():
        m, s = p["max_range"], p["sigma"]
        d = {"max-2sigma": m - 2 * s, "max-1e-3": m - 1e-3}.get(frac, None)
        d = frac * m if d is None else d
        continuous = integrate(lambda y: np.exp(logpdf(y, d, p)), d, p)
        point = float(np.exp(logpdf(m, d, p)))
        assert continuous + point == pytest.approx(1.0, abs=1e-9)
        # and the parts are where the convention puts them: everything but z_max and the hit's censored tail is
        # continuous (tail = P(Normal(d, s) >= max) / P(Normal(d, s) >= 0))
        tail = 0.5 * math.erfc((m - d) / (s * math.sqrt(2))) / (1 - 0.5 * math.erfc(d / (s * math.sqrt(2))))
        assert point == pytest.approx(p["z_max"] + p["z_hit"] * tail, rel=1e-12)


def reference_density(y, d, p):
    """PR eqs. 6.4-6.12 (hit censored at max), written out with math.erf: an independent implementation."""
    s, m, lam = p["sigma"], p["max_range"], p["lambda_short"]

    def Phi(x):
        return 0.5 * (1 + math.erf(x / math.sqrt(2)))

    eta = 1 / Phi(d / s)
    if y < 0:
        return 0.0
    if y >= m:
        return p["z_max"] + p["z_hit"] * eta * (1 - Phi((m - d) / s))
    hit = eta * math.exp(-0.5 * ((y - d) / s) ** 2) / (s * math.sqrt(2 * math.pi))
    ds = max(d, sensor.MIN_SHORT_DISTANCE)
    short = lam * math.exp(-lam * y) / (1 - math.exp(-lam * ds)) if y <= ds else 0.0
    return p["z_hit"] * hit + p["z_short"] * short + p["z_rand"] / m


@pytest.mark.parametrize("p", [DEFAULT, HEAVY], ids=["default", "heavy"])
def test_beam_logpdf_is_the_formula(p):
    """Against a plain-Python transcription of the formulas (relative 1e-10: float64, the same formula computed in
    another order; values span ~10 orders of magnitude, so only a relative tolerance is meaningful)."""
    with enable_x64():
        rng = np.random.default_rng(0)
        m = p["max_range"]
        ds = np.concatenate([[0.0, 1e-8, m], rng.uniform(0, m, 20)])
        for d in ds:
            ys = np.concatenate([[0.0, d, max(d - 1e-3, 0.0), m, m + 1.0, -0.5], rng.uniform(0, m, 6),
                                 d + rng.normal(0, p["sigma"], 4)])
            got = logpdf(ys, np.full_like(ys, d), p)
            for y, g in zip(ys, got):
                want = reference_density(y, d, p)
                if want == 0.0:
                    assert g == -np.inf
                else:
                    assert g == pytest.approx(math.log(want), rel=1e-10, abs=1e-12), (y, d)


def test_normal_model_is_genjax_normal():
    """The "normal" sensor model is genjax.normal itself (the tutorial's model is unchanged) and normal_logpdf is its
    density (float64: equal to 1e-12; the two differ only in the order of the same operations)."""
    assert sensor.reading_distribution("normal") is genjax.normal
    with enable_x64():
        rng = np.random.default_rng(1)
        for y, d, s in zip(rng.uniform(-1, 10, 20), rng.uniform(0, 10, 20), rng.uniform(0.05, 2, 20)):
            want = float(genjax.normal.assess(C.v(jnp.float64(y)), (jnp.float64(d), jnp.float64(s)))[0])
            assert float(sensor.normal_logpdf(y, d, s)) == pytest.approx(want, abs=1e-12)
            assert float(sensor.reading_logpdf("normal", y, d, (s,))) == float(sensor.normal_logpdf(y, d, s))


@pytest.mark.parametrize("p", [DEFAULT, HEAVY], ids=["default", "heavy"])
def test_beam_distribution_assess_is_beam_logpdf(p):
    """GenJAX's assess of beam_reading scores a reading with beam_logpdf (same function; 1e-12 allows for jit)."""
    with enable_x64():
        rng = np.random.default_rng(2)
        m = p["max_range"]
        score = jax.jit(lambda y, d: sensor.beam_reading.assess(C.v(y), (d,) + args_of(p))[0])
        for d in np.concatenate([[0.0, m], rng.uniform(0, m, 8)]):
            for y in np.concatenate([[0.0, m, m + 2.0, d], rng.uniform(0, m, 4)]):
                want = float(logpdf(y, d, p))
                assert float(score(jnp.float64(y), jnp.float64(d))) == pytest.approx(want, rel=1e-12, abs=1e-12)
        assert sensor.reading_distribution("beam") is sensor.beam_reading


@pytest.mark.parametrize("p, d", [(DEFAULT, 3.0), (DEFAULT, 42.0), (HEAVY, 1.0), (HEAVY, 7.2)],
                         ids=["wall", "no-wall", "heavy-near", "heavy-far"])
def test_beam_distribution_simulate_samples_the_mixture(p, d):
    """20,000 draws of beam_reading.simulate: the fraction of max-range readings, the mean and the CDF at five
    points match the measure computed by quadrature.

    Tolerance: 4.5 Monte Carlo standard errors for each of the 7 statistics (binomial sqrt(q (1 - q) / N) for
    fractions, sample std / sqrt(N) for the mean); a false alarm has probability < 7 * 7e-6. A wrong component
    weight of 0.05 moves the max-range fraction or the CDF by >= 0.05 >> 4.5 SE (<= 0.016)."""
    n = 20_000
    with enable_x64():
        m = p["max_range"]
        args = (jnp.float64(d),) + tuple(jnp.float64(v) for v in args_of(p))
        keys = jax.random.split(jax.random.key(123), n)
        y = np.asarray(jax.jit(jax.vmap(lambda k: sensor.beam_reading.simulate(k, args).get_retval()))(keys))
        assert y.shape == (n,) and np.all((y >= 0) & (y <= m))

        def density(t):
            return np.exp(logpdf(t, d, p))

        point = float(np.exp(logpdf(m, d, p)))

        def check_fraction(got, want):
            se = math.sqrt(max(want * (1 - want), 1e-12) / n)
            assert abs(got - want) <= 4.5 * se + 1e-12, (got, want, se)

        check_fraction(np.mean(y >= m), point)
        mean = integrate(lambda t: t * density(t), d, p) + m * point
        assert abs(y.mean() - mean) <= 4.5 * y.std() / math.sqrt(n), (y.mean(), mean)
        for t in (0.5 * d, d - p["sigma"], d, d + p["sigma"], 0.5 * (d + m)):
            t = min(max(t, 1e-3), m - 1e-3)
            check_fraction(np.mean(y <= t), integrate(density, d, p, upper=t))


@pytest.mark.parametrize("kwargs, match", [
    (dict(beam_model="gaussian"), "beam_model"),
    (dict(z_hit=0.0, z_rand=0.9), "z_hit"),
    (dict(z_short=-0.05, z_rand=0.2), "z_short"),
    (dict(z_rand=float("nan")), "z_rand"),
    (dict(z_max=float("inf")), "z_max"),
    (dict(z_max=0.15), "sum to 1"),
    (dict(z_hit="lots"), "z_hit"),
    (dict(lambda_short=0.0), "lambda_short"),
    (dict(lambda_short=-1.0), "lambda_short"),
    (dict(lambda_short=float("inf")), "lambda_short"),
])
def test_bad_sensor_parameters_are_named(kwargs, match):
    with pytest.raises(BayesmapError, match=match):
        make_params(**kwargs)


def test_make_params_keeps_its_positional_signature_and_carries_the_sensor():
    grid = Grid((5, 6))
    params = make_params(0.3, 0.25, 12, grid, 4.0)
    assert ((params.prior_wall_prob, params.sensor_noise, params.num_angles, params.grid, params.max_range)
            == (0.3, 0.25, 12, grid, 4.0))
    assert params.beam_model == "normal" and params.sensor_args == (0.25,)
    beam = make_params(0.3, 0.25, 12, grid, 4.0, beam_model="beam", z_hit=0.7, z_short=0.1, z_max=0.1, z_rand=0.1,
                       lambda_short=0.5)
    assert beam.sensor_args == (0.25, 0.7, 0.1, 0.1, 0.1, 0.5, 4.0)
    with pytest.raises(BayesmapError, match="takes 7 parameters"):
        sensor.reading_logpdf("beam", 1.0, 1.0, (0.2,))


def test_replace_params_changes_only_what_it_is_given_and_checks_it():
    """Every field is kept but those given; the new values are checked as make_params checks them; a coupling given
    with ``neighbourhood=None`` gets the 4-neighbourhood; a name that is no field is refused by name."""
    params = make_params(0.3, 0.25, 12, Grid((5, 6)), 4.0, beam_model="beam", z_rand=0.2, z_hit=0.7,
                         geometry="chord")
    other = replace_params(params, sensor_noise=0.1, coupling=1.5, neighbourhood=None, wall_pass_prob=0.5)
    changed = {"sensor_noise": 0.1, "coupling": 1.5, "neighbourhood": 4, "wall_pass_prob": 0.5}
    assert PARAMS_FIELDS == tuple(inspect.signature(make_params).parameters)  # every field, and make_params takes it
    for name in PARAMS_FIELDS:
        assert getattr(other, name) == changed.get(name, getattr(params, name)), name
    with pytest.raises(BayesmapError, match="sensor_noise"):
        replace_params(params, sensor_noise=-1.0)
    with pytest.raises(BayesmapError, match="neighbourhood 4"):
        replace_params(params, coupling=1.5)  # the kept neighbourhood 0 cannot carry a coupling
    with pytest.raises(BayesmapError, match="not a model parameter: noise"):
        replace_params(params, noise=0.1)
