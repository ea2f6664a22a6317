"""Tests for bayesmap.inference.traces: the per-sweep log joints and wrong cells, and the importance-sampling run,
that the report draws."""

from __future__ import annotations

from types import SimpleNamespace

import jax
import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.inference.importance import importance_sampling
from bayesmap.inference.traces import IMPORTANCE_PARTICLES, chain_log_joints, chain_traces, chain_wrong_cells
from bayesmap.io.ascii import parse_map
from bayesmap.scenes import tutorial_problem

ROOM = """
XXXXXXX
X.....X
X..X..X
X.....X
XXXXXXX
"""


@pytest.fixture(scope="module")
def problem():
    walls = parse_map(ROOM)
    return tutorial_problem(walls, pos=(1.0, 1.0), num_angles=24, source="room")


@pytest.fixture(scope="module")
def samples(problem):
    """Two chains of three sweeps: the true map, no walls, every cell a wall (chain 0), and the reverse (chain 1)."""
    truth = np.asarray(problem.truth) > 0.5
    maps = np.stack([truth, np.zeros_like(truth), np.ones_like(truth)])
    return np.stack([maps, maps[::-1]])


def test_log_joints_are_the_model_scores(problem, samples):
    got = chain_log_joints(problem, samples)
    assert got.shape == (2, 3) and got.dtype == np.float64
    expected = [[problem.log_joint(w) for w in chain] for chain in samples]
    # float32 model, scores of order 10^2: agree to 1e-4 relative
    np.testing.assert_allclose(got, expected, rtol=1e-4)
    np.testing.assert_array_equal(got[1], got[0][::-1])
    assert got[0, 0] > got[0, 1] and got[0, 0] > got[0, 2]  # the true map explains the readings best
    np.testing.assert_allclose(chain_log_joints(problem, samples[0]), got[0], rtol=1e-6)  # one chain: (T,)


def test_wrong_cells_count_the_visible_cells(problem, samples):
    wrong = chain_wrong_cells(problem, samples)
    visible = np.asarray(problem.visible)
    truth = np.asarray(problem.truth) > 0.5
    assert wrong.shape == (2, 3)
    assert wrong[0, 0] == 0
    assert wrong[0, 1] == int((truth & visible).sum())  # no walls: every visible wall is wrong
    assert wrong[0, 2] == int((~truth & visible).sum())  # all walls: every visible free cell is wrong
    assert wrong[0, 1] == problem.wrong_visible_cells(np.zeros_like(truth, dtype=float))
    np.testing.assert_array_equal(wrong[1], wrong[0][::-1])
    assert chain_wrong_cells(SimpleNamespace(truth=None), samples) is None


def test_chain_traces_runs_importance_sampling_on_small_grids(problem, samples):
    result = SimpleNamespace(samples=samples)
    traces = chain_traces(problem, result, seed=3)
    np.testing.assert_array_equal(traces.log_joints, chain_log_joints(problem, samples))
    np.testing.assert_array_equal(traces.wrong_cells, chain_wrong_cells(problem, samples))
    assert traces.importance.log_weights.shape == (IMPORTANCE_PARTICLES,)
    same = importance_sampling(jax.random.key(3), problem.model_readings, problem.pos, problem.params,
                               IMPORTANCE_PARTICLES, problem.beam_angles)
    np.testing.assert_array_equal(np.asarray(traces.importance.log_weights), np.asarray(same.log_weights))
    assert 1.0 <= float(traces.importance.ess) <= IMPORTANCE_PARTICLES
    assert chain_traces(problem, result, importance=False).importance is None


def test_chain_traces_refuses_importance_on_several_scans():
    problem = SimpleNamespace(multi_scan=True)
    with pytest.raises(BayesmapError, match="importance=True needs a single-scan problem"):
        chain_traces(problem, SimpleNamespace(samples=np.zeros((2, 3, 3), bool)), importance=True)
