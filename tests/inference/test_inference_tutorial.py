"""What the tutorial reports, on the tutorial map with its readings (key 0)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesmap.inference.chains import posterior_mean, run_chain
from bayesmap.inference.importance import importance_sampling, resample
from bayesmap.inference.registry import make_sampler

pytestmark = pytest.mark.compute_bound  # (pyproject.toml, Makefile: run at XLA's default optimization)

REFERENCE = ["reference-raster", "reference-incremental", "reference-outward", "reference-block"]
FAST = ["raster", "outward", "chromatic", "block", "chromatic-block"]
REFERENCE_BLOCK_SWEEPS = 16
"""Sweeps of the tutorial's own 2x2 block sampler (16 assess calls per block, 0.6 s a sweep, 30 times the fast
block's): its chain is right from sweep 7 on at both priors, so the mean over sweeps 8-16 is the converged one
(1 wrong visible cell at both priors with key 0; the fast samplers keep their 30 and 40 sweeps)."""


def wrong_after(problem, sampler, sweeps, seed=0):
    chain = run_chain(jax.random.key(seed), make_sampler(problem, sampler), jnp.zeros((21, 21)), sweeps)
    return problem.wrong_visible_cells(posterior_mean(chain.samples, sweeps // 2)), chain


def test_importance_sampling_collapses(tutorial):
    result = importance_sampling(jax.random.key(0), tutorial.readings, tutorial.pos, tutorial.params, 2000,
                                 batch_size=500)
    assert result.walls.shape == (2000, 21, 21)
    assert float(jax.scipy.special.logsumexp(result.log_weights)) == pytest.approx(0.0, abs=1e-4)
    assert float(result.ess) < 1.5
    idx = np.asarray(resample(jax.random.key(1), result.log_weights, 100))
    assert len(set(idx.tolist())) == 1  # all resampled indices identical
    best = np.asarray(result.walls[idx[0]])
    assert np.sum(best != (tutorial.truth > 0)) > 150  # the best particle is a bad map


@pytest.mark.parametrize("sampler", REFERENCE + FAST)
def test_every_gibbs_variant_converges_at_prior_half(tutorial, sampler):
    wrong, _ = wrong_after(tutorial, sampler, REFERENCE_BLOCK_SWEEPS if sampler == "reference-block" else 30)
    assert wrong <= 2


@pytest.mark.parametrize("sampler", ["reference-raster", "reference-outward", "raster", "outward"])
def test_single_site_gibbs_is_stuck_at_low_prior(tutorial_low_prior, sampler):
    wrong, _ = wrong_after(tutorial_low_prior, sampler, 100)
    assert wrong >= 10


@pytest.mark.parametrize("sampler", ["reference-block", "block"])
def test_block_gibbs_recovers_at_low_prior(tutorial_low_prior, sampler):
    # the tutorial's block chain is right from sweep 7 on
    wrong, _ = wrong_after(tutorial_low_prior, sampler, REFERENCE_BLOCK_SWEEPS if sampler == "reference-block" else 40)
    assert wrong <= 2


def test_chain_samples_and_mean(tutorial):
    _, chain = wrong_after(tutorial, "block", 6)
    samples = np.asarray(chain.samples)
    assert samples.shape == (6, 21, 21) and samples.dtype == bool
    assert np.allclose(posterior_mean(samples, 2), samples[2:].mean(0))
    # same key, same chain
    _, again = wrong_after(tutorial, "block", 6)
    assert np.array_equal(samples, np.asarray(again.samples))
