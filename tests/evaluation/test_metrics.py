"""Tests for bayesmap.evaluation.metrics: hand-computed answers and a property test of the AUC against a pairwise
count."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.metrics import accuracy, brier_score, mean_nll, roc_auc


def brute_force_auc(scores, labels):
    """Fraction of (positive, negative) pairs ranked correctly, ties counted 1/2: the definition."""
    s = np.asarray(scores, float)
    y = np.asarray(labels, bool)
    pos, neg = s[y], s[~y]
    wins = sum((p > n) + 0.5 * (p == n) for p in pos for n in neg)
    return wins / (len(pos) * len(neg))


def test_auc_known_answers():
    assert roc_auc([0.1, 0.2, 0.8, 0.9], [0, 0, 1, 1]) == 1.0
    assert roc_auc([0.9, 0.8, 0.2, 0.1], [0, 0, 1, 1]) == 0.0
    assert roc_auc(np.full(6, 0.3), [0, 1, 0, 1, 1, 0]) == 0.5
    # positives 0.35, 0.8 vs negatives 0.1, 0.4: 3 of 4 pairs ordered right
    assert roc_auc([0.1, 0.4, 0.35, 0.8], [0, 0, 1, 1]) == 0.75
    # a tie across the classes: pairs (0.5 > 0.2), (0.5 = 0.5 -> 1/2), (0.9 > 0.2), (0.9 > 0.5) -> 3.5 / 4
    assert roc_auc([0.2, 0.5, 0.5, 0.9], [0, 1, 0, 1]) == 0.875
    # ties within a class do not matter
    assert roc_auc([0.1, 0.1, 0.7, 0.7, 0.7], [False, False, True, True, True]) == 1.0


def test_auc_on_maps_with_mask():
    scores = np.array([[0.9, 0.1], [0.2, 0.95]])
    labels = np.array([[1, 0], [1, 0]])
    # unmasked: positives 0.9, 0.2 vs negatives 0.1, 0.95 -> (0.9>0.1), (0.2>0.1) right, 2 of 4
    assert roc_auc(scores, labels) == 0.5
    mask = np.array([[True, True], [False, True]])  # drop the 0.2 positive
    assert roc_auc(scores, labels, mask=mask) == 0.5  # 0.9 vs {0.1, 0.95}
    mask = np.array([[True, True], [True, False]])  # drop the 0.95 negative
    assert roc_auc(scores, labels, mask=mask) == 1.0


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from([0.0, 0.25, 0.5, 0.75, 1.0, -3.0, 7.5]) | st.floats(-10, 10), st.booleans()),
        min_size=2,
        max_size=40,
    )
)
def test_auc_matches_pairwise_count(pairs):
    # few distinct values drawn often, so ties within and across classes are common
    scores = np.array([p[0] for p in pairs])
    labels = np.array([p[1] for p in pairs])
    if labels.all() or not labels.any():
        with pytest.raises(BayesmapError, match="both classes"):
            roc_auc(scores, labels)
        return
    assert roc_auc(scores, labels) == pytest.approx(brute_force_auc(scores, labels), abs=1e-12)


@pytest.mark.parametrize(
    "scores, labels, mask, message",
    [
        ([0.1, 0.2], [1, 1], None, "both classes"),
        ([0.1, 0.2], [0, 0], None, "both classes"),
        ([0.1, 0.2, 0.3], [0, 1], None, "shape"),
        ([0.1, np.nan], [0, 1], None, "finite"),
        ([0.1, 0.2], [0, 2], None, "0/1"),
        ([0.1, 0.2], [0, 1], [1, 1], "boolean"),
        ([0.1, 0.2], [0, 1], [True, False], "both classes"),
        ([0.1, 0.2], [0, 1], [False, False], "selects no cell"),
    ],
)
def test_auc_bad_input(scores, labels, mask, message):
    with pytest.raises(BayesmapError, match=message):
        roc_auc(scores, labels, mask=None if mask is None else np.array(mask))


def test_brier_known_answers():
    assert brier_score([1.0, 0.0], [1, 0]) == 0.0
    assert brier_score([0.5, 0.5, 0.5], [1, 0, 1]) == 0.25
    # (0.2 - 1)^2 = 0.64, (0.3 - 0)^2 = 0.09 -> mean 0.365
    assert brier_score([0.2, 0.3], [True, False]) == pytest.approx(0.365, abs=1e-15)
    assert brier_score([0.2, 0.3], [1, 0], mask=np.array([False, True])) == pytest.approx(0.09, abs=1e-15)
    with pytest.raises(BayesmapError, match="1.5"):
        brier_score([1.5], [1])
    with pytest.raises(BayesmapError, match="truth"):
        brier_score([0.5], [0.5])
    with pytest.raises(BayesmapError, match="empty"):
        brier_score([], [])


def test_accuracy_known_answers():
    prob = np.array([0.9, 0.5, 0.51, 0.2])
    truth = np.array([1, 0, 1, 1])
    assert accuracy(prob, truth) == 0.75  # 0.5 is not above the threshold: called free, correctly
    assert accuracy(prob, truth, threshold=0.1) == 0.75  # now 0.5 is called occupied (wrong), 0.2 right
    assert accuracy(prob, truth, mask=np.array([False, False, False, True])) == 0.0
    with pytest.raises(BayesmapError, match="threshold"):
        accuracy(prob, truth, threshold=2.0)
    with pytest.raises(BayesmapError, match="shape"):
        accuracy(prob, truth[:3])


def test_mean_nll():
    assert mean_nll([-1.0, -3.0]) == 2.0
    assert mean_nll(np.array([[-1.0, -3.0], [-10.0, -4.0]]), mask=np.array([[True, False], [False, True]])) == 2.5
    assert mean_nll([-1.0, -np.inf]) == np.inf
    with pytest.raises(BayesmapError, match="empty"):
        mean_nll([])
    with pytest.raises(BayesmapError, match="NaN"):
        mean_nll([np.nan])
