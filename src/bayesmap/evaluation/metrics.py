"""Scores of an inferred occupancy grid against a true map (numpy, vectorized).

Every function takes arrays of any (equal) shape, typically ``(nx, ny)`` maps, and an optional boolean ``mask`` of
the same shape selecting the cells to score (for instance the cells a ray saw). Truth labels are occupied = 1 /
True, free = 0 / False.
"""

from __future__ import annotations

import numpy as np

from bayesmap.errors import BayesmapError


def _as_mask(mask, shape: tuple[int, ...]) -> np.ndarray | None:
    if mask is None:
        return None
    m = np.asarray(mask)
    if m.dtype != bool:
        raise BayesmapError(f"mask must be a boolean array, got dtype {m.dtype}")
    if m.shape != shape:
        raise BayesmapError(f"mask has shape {m.shape}, but the scored arrays have shape {shape}")
    return m


def _select(arrays: dict[str, object], mask) -> list[np.ndarray]:
    """Arrays as float64, checked to have one shape, restricted to ``mask`` and flattened; raises if empty."""
    out = {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}
    names = list(out)
    shape = out[names[0]].shape
    for k in names[1:]:
        if out[k].shape != shape:
            raise BayesmapError(f"{k} has shape {out[k].shape}, but {names[0]} has shape {shape}")
    m = _as_mask(mask, shape)
    flat = [out[k][m] if m is not None else out[k].reshape(-1) for k in names]
    if flat[0].size == 0:
        extra = " or the mask selects no cell" if m is not None else ""
        raise BayesmapError(f"nothing to score: the arrays are empty{extra}")
    return flat


def _check_labels(truth: np.ndarray, name: str) -> np.ndarray:
    bad = np.flatnonzero((truth != 0) & (truth != 1))
    if len(bad):
        raise BayesmapError(
            f"{name} must be 0/1 (or bool), got {truth[bad[0]]!r} at (flattened, masked) index {bad[0]}"
        )
    return truth == 1


def _check_probabilities(prob: np.ndarray, name: str) -> None:
    bad = np.flatnonzero(~((prob >= 0) & (prob <= 1)))
    if len(bad):
        raise BayesmapError(
            f"{name} must be probabilities in [0, 1], got {prob[bad[0]]!r} at (flattened, masked) index {bad[0]}"
        )


def roc_auc(scores, labels, mask=None) -> float:
    """Area under the ROC curve of ``scores`` as a predictor of ``labels``.

    Computed as the Mann-Whitney U statistic over the two classes, with average ranks for tied scores: the
    fraction of (occupied, free) pairs in which the occupied cell has the higher score, a tie counting 1/2
    (Hanley & McNeil, Radiology 143(1), 1982; Fawcett, "An introduction to ROC analysis", Pattern Recognition
    Letters 27(8), 2006, sec. 6). Exact, including ties; O(n log n).

    Args:
        scores: any shape, finite numbers (e.g. a ``(nx, ny)`` float posterior probability of occupied).
        labels: the same shape, 0/1 or bool (1 = occupied, the positive class).
        mask: optional bool array of the same shape, the cells to score.

    Returns:
        The AUC in ``[0, 1]``: 1.0 for a perfect ranking, 0.0 for a reversed one, 0.5 when all scores tie.

    Raises:
        BayesmapError: if the shapes differ, a score is NaN or infinite, a label is not 0/1, the mask is not a bool
            array of the same shape, or (after masking) one class is empty (the AUC is undefined).
    """
    s, y = _select({"scores": scores, "labels": labels}, mask)
    if not np.all(np.isfinite(s)):
        bad = np.flatnonzero(~np.isfinite(s))[0]
        raise BayesmapError(f"scores must be finite, got {s[bad]!r} at (flattened, masked) index {bad}")
    pos = _check_labels(y, "labels")
    n1 = int(pos.sum())
    n0 = pos.size - n1
    if n1 == 0 or n0 == 0:
        raise BayesmapError(
            f"ROC AUC needs both classes, got {n1} positive (occupied) and {n0} negative (free) labels"
        )
    order = np.argsort(s, kind="stable")
    sorted_s = s[order]
    starts = np.flatnonzero(np.r_[True, sorted_s[1:] != sorted_s[:-1]])
    counts = np.diff(np.r_[starts, s.size])
    avg_rank = starts + (counts + 1) / 2.0  # 1-based average rank of each group of tied scores
    ranks = np.empty(s.size)
    ranks[order] = np.repeat(avg_rank, counts)
    u = ranks[pos].sum() - n1 * (n1 + 1) / 2.0
    return float(u / (n1 * n0))


def brier_score(prob, truth, mask=None) -> float:
    """Brier score: the mean squared difference between the probability of occupied and the true 0/1 state
    (Brier, Monthly Weather Review 78(1), 1950). Lower is better; 0 is perfect, 0.25 is a constant 0.5.

    Args:
        prob: any shape, probabilities of occupied in ``[0, 1]``.
        truth: the same shape, 0/1 or bool.
        mask: optional bool array of the same shape, the cells to score.

    Returns:
        The mean of ``(prob - truth) ** 2`` over the (masked) cells, a float in ``[0, 1]``.

    Raises:
        BayesmapError: if the shapes differ, a probability is outside ``[0, 1]`` or NaN, a truth value is not 0/1,
            the mask is not a bool array of the same shape, or no cell is selected.
    """
    p, t = _select({"prob": prob, "truth": truth}, mask)
    _check_probabilities(p, "prob")
    t = _check_labels(t, "truth")
    return float(np.mean((p - t) ** 2))


def accuracy(prob, truth, threshold: float = 0.5, mask=None) -> float:
    """Fraction of cells classified correctly, a cell being called occupied when ``prob > threshold``.

    Args:
        prob: any shape, probabilities of occupied in ``[0, 1]``.
        truth: the same shape, 0/1 or bool.
        threshold: decision threshold in ``[0, 1]``; ``prob == threshold`` counts as free.
        mask: optional bool array of the same shape, the cells to score.

    Returns:
        A float in ``[0, 1]``.

    Raises:
        BayesmapError: as :func:`brier_score`, or if ``threshold`` is not a number in ``[0, 1]``.
    """
    if isinstance(threshold, (bool, np.bool_)) or not isinstance(threshold, (int, float, np.integer, np.floating)) \
            or not 0.0 <= float(threshold) <= 1.0:
        raise BayesmapError(f"threshold must be a number in [0, 1], got {threshold!r}")
    p, t = _select({"prob": prob, "truth": truth}, mask)
    _check_probabilities(p, "prob")
    t = _check_labels(t, "truth")
    return float(np.mean((p > threshold) == t))


def mean_nll(log_densities, mask=None) -> float:
    """Mean negative log-likelihood: ``-mean(log_densities)`` (natural log, nats per item).

    Args:
        log_densities: any shape, log densities or log probabilities (``-inf`` allowed: the result is then
            ``inf``).
        mask: optional bool array of the same shape, the entries to average.

    Returns:
        The negative mean, a float.

    Raises:
        BayesmapError: if the array is empty or the mask selects nothing, a value is NaN or ``+inf``, or the mask
            is not a bool array of the same shape.
    """
    (x,) = _select({"log_densities": log_densities}, mask)
    bad = np.flatnonzero(np.isnan(x) | (x == np.inf))
    if len(bad):
        raise BayesmapError(
            f"log_densities must not be NaN or +inf, got {x[bad[0]]!r} at (flattened, masked) index {bad[0]}"
        )
    return float(-np.mean(x))
