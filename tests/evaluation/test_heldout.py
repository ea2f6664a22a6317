"""Held-out and floor-plan scores (bayesmap.evaluation.heldout) on hand-made cases with known answers."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.heldout import (
    heldout_split,
    occupancy_auc,
    predictive_log_density_independent,
    predictive_log_density_samples,
    truth_scores,
)
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table

CORRIDOR = Grid((6, 1))  # unit cells centered at (0, 0) .. (5, 0)
SIGMA = 0.3


def normal_logpdf(y, d):
    y, d = np.asarray(y, float), np.asarray(d, float)
    return -0.5 * ((y - d) / SIGMA) ** 2 - math.log(SIGMA * math.sqrt(2 * math.pi))


def corridor(readings):
    """Beams from (0, 0) along +x; the sensor cell (0, 0) is left at 0.5, cell k entered at k - 0.5."""
    return build_ray_table(CORRIDOR, (0.0, 0.0), np.zeros(len(readings)), max_distance=10.0)


def test_heldout_split_holds_out_every_kth_scan():
    train, test = heldout_split(25, 10)
    assert list(test) == [9, 19] and len(train) == 23 and not set(train) & set(test)
    for bad in (1, 2.5):
        with pytest.raises(BayesmapError, match="integer >= 2"):
            heldout_split(25, bad)
    with pytest.raises(BayesmapError, match="no scan to test"):
        heldout_split(5, 10)


def test_auc_endpoint_cells_are_positives_crossed_cells_negatives():
    table = corridor([3.2])
    # the beam ends in cell 3 (entered at 2.5); cells 0 (sensor), 1 and 2 are crossed before it
    perfect = np.array([[0.1], [0.2], [0.3], [0.9], [0.0], [0.0]])
    assert occupancy_auc(table, [3.2], perfect) == 1.0
    assert occupancy_auc(table, [3.2], 1 - perfect) == 0.0
    # the endpoint scored like one crossed cell, above the other two: (2 + 0.5) / 3
    tied = np.array([[0.1], [0.2], [0.9], [0.9], [0.0], [0.0]])
    assert occupancy_auc(table, [3.2], tied) == pytest.approx(2.5 / 3)
    # a max-range beam gives no positive: no AUC from it alone
    with pytest.raises(BayesmapError):
        occupancy_auc(table, [3.2], perfect, max_range_mask=np.array([True]))


def test_independent_predictive_matches_enumeration_of_maps():
    table = corridor([2.7, 4.1, 9.0])
    readings = np.array([2.7, 4.1, 9.0])
    q = np.array([[0.0], [0.2], [0.5], [0.7], [0.1], [0.95]])
    got = predictive_log_density_independent(table, readings, q, normal_logpdf)
    # brute force: every map of the 5 cells that can be walls (the sensor cell has q = 0)
    dists = {k: k - 0.5 for k in range(1, 6)}
    expected = np.zeros(3)
    for bits in itertools.product([0, 1], repeat=5):
        walls = dict(zip(range(1, 6), bits))
        weight = np.prod([q[k, 0] if walls[k] else 1 - q[k, 0] for k in range(1, 6)])
        first = next((dists[k] for k in range(1, 6) if walls[k]), 10.0)
        expected += weight * np.exp(normal_logpdf(readings, first))
    np.testing.assert_allclose(got, np.log(expected), rtol=1e-9)


def test_sample_predictive_averages_densities_over_samples():
    table = corridor([2.6])
    a = np.zeros((6, 1))
    a[3] = 1  # first wall entered at 2.5
    b = np.zeros((6, 1))
    b[5] = 1  # first wall entered at 4.5
    got = predictive_log_density_samples(table, [2.6], np.stack([a, b, b]), normal_logpdf)
    want = np.log((np.exp(normal_logpdf(2.6, 2.5)) + 2 * np.exp(normal_logpdf(2.6, 4.5))) / 3)
    np.testing.assert_allclose(got, [want], rtol=1e-12)
    # a deterministic map: samples and independent probabilities agree
    np.testing.assert_allclose(predictive_log_density_independent(table, [2.6], a, normal_logpdf),
                               predictive_log_density_samples(table, [2.6], a[None], normal_logpdf), rtol=1e-12)
    # no wall on the beam: the density at the max distance
    empty = np.zeros((1, 6, 1))
    np.testing.assert_allclose(predictive_log_density_samples(table, [2.6], empty, normal_logpdf),
                               [normal_logpdf(2.6, 10.0)])
    with pytest.raises(BayesmapError, match="shape"):
        predictive_log_density_samples(table, [2.6], np.zeros((2, 5, 1)), normal_logpdf)


def test_truth_scores_on_a_hand_made_map():
    truth = np.array([[1, 0], [0, 1]])
    prob = np.array([[0.9, 0.4], [0.6, 0.8]])
    scores = truth_scores(prob, truth)
    assert scores["accuracy"] == 0.75  # (1, 0) is wrong at threshold 0.5
    assert scores["auc"] == 1.0  # both walls score above both free cells
    assert scores["brier"] == pytest.approx((0.01 + 0.16 + 0.36 + 0.04) / 4)
    known = np.array([[True, False], [True, True]])
    assert truth_scores(prob, truth, known)["cells"] == 3
    with pytest.raises(BayesmapError, match="no known cell"):
        truth_scores(prob, truth, np.zeros((2, 2), bool))
