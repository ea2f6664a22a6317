"""Many chains and per-cell diagnostics (split R-hat, effective sample size)."""

import json

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.inference.chains import cell_diagnostics
from bayesmap.inference.driver import run_inference


def test_diagnostics_of_independent_draws():
    """4 chains x 400 iid Bernoulli(0.3) draws per cell: R-hat is 1 and the ESS the number of draws, within the
    estimators' sampling error (a few percent for 1,600 iid draws; we allow 2 % on R-hat and 25 % on ESS)."""
    rng = np.random.default_rng(0)
    draws = rng.random((4, 400, 2, 3)) < 0.3
    diag = cell_diagnostics(draws)
    assert diag["r_hat"].shape == diag["ess"].shape == (2, 3)
    assert np.all(np.abs(diag["r_hat"] - 1) < 0.02)
    assert np.all((diag["ess"] > 0.75 * 1600) & (diag["ess"] < 1.25 * 1600))


def test_diagnostics_flag_chains_that_disagree_and_constant_cells():
    rng = np.random.default_rng(1)
    p = np.array([0.05, 0.95, 0.05, 0.95])[:, None, None, None]
    draws = rng.random((4, 200, 1, 2)) < p  # chains stuck in different modes
    draws[:, :, 0, 1] = True  # a cell that never changes
    diag = cell_diagnostics(draws)
    assert diag["r_hat"][0, 0] > 1.5 and diag["ess"][0, 0] < 100
    assert np.isnan(diag["r_hat"][0, 1])


def test_diagnostics_need_two_chains():
    with pytest.raises(BayesmapError, match="chains >= 2"):
        cell_diagnostics(np.zeros((1, 50, 2, 2)))


def test_tutorial_chains_agree(tutorial):
    """4 chains of fast 2x2 block Gibbs (100 sweeps, 50 kept) on the tutorial scene: every cell that changes has
    split R-hat below 1.1 (the usual threshold; Vehtari et al. 2021 recommend 1.01 for final results, which
    needs longer chains), and the chains' joint posterior mean is as accurate as one chain's."""
    result = run_inference(tutorial, "block", sweeps=100, chains=4, progress=False)
    assert result.samples.shape == (4, 100, 21, 21)
    assert result.summary["r_hat_max"] < 1.1
    assert result.summary["ess_min"] > 20
    assert result.summary["wrong_visible_cells"] <= 2


def test_cli_chains_write_diagnostics(tmp_path, monkeypatch, capsys):
    from helpers import run_cli

    code, out, err = run_cli(monkeypatch, capsys, "infer", "--sweeps", 12, "--chains", 3, "--sampler", "outward",
                             "--out", tmp_path / "out")
    assert code in (0, None), err
    with np.load(tmp_path / "out" / "diagnostics.npz") as diag:
        assert diag["r_hat"].shape == diag["ess"].shape == (21, 21)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["chains"] == 3 and summary["r_hat_max"] >= 1.0
    assert "R-hat" in out
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--sweeps", 5, "--chains", 2, "--out", tmp_path / "o2")
    assert code == 2 and "at least 4 sweeps" in err and not (tmp_path / "o2").exists()


def test_new_readings_prior_and_noise_reuse_the_compiled_sweep():
    """A sampler's arrays are arguments of the compiled chain: a problem with the same geometry but other readings,
    prior or noise runs without compiling again (what the app needs); another sensor position compiles anew."""
    import jax
    import jax.numpy as jnp

    from bayesmap.inference.chains import compiled_chain_count, run_chain_from
    from bayesmap.inference.registry import make_sampler
    from bayesmap.scenes import tutorial_problem

    def run(problem):
        algorithm = make_sampler(problem, "block")
        samples, _, _ = run_chain_from(jax.random.key(0), algorithm.init(jnp.zeros(problem.grid.shape)), algorithm, 7)
        return np.asarray(samples)

    first = run(tutorial_problem(seed=3))
    size = compiled_chain_count()
    second = run(tutorial_problem(seed=4, prior_wall_prob=0.2, sensor_noise=0.3))
    assert compiled_chain_count() == size  # no new compilation
    assert not np.array_equal(first, second)  # and the new data were used
    run(tutorial_problem(seed=3, pos=(6.0, 12.0)))
    assert compiled_chain_count() == size + 1
