"""Scoring maps: on held-out beams of a log, and against a known floor plan.

Held-out beams (a map built without them predicts them):

* **occupancy AUC**: for each held-out beam, its endpoint cell (not for max-range readings) is a positive and
  every cell it crosses before the endpoint a negative (:func:`bayesmap.inference.logodds.beam_hits_and_misses`
  decides which cells those are); the score of a cell is its wall probability; ties count one half
  (:func:`bayesmap.metrics.roc_auc`). A cell crossed by several beams counts once per beam.
* **predictive NLL**: the mean over held-out beams of ``-log p(y)`` where ``p(y)`` is the posterior predictive
  density of the reading under the sensor model: for posterior samples ``m_1..m_N``,
  ``p(y) = (1/N) sum_n p(y | d(m_n))`` with ``d(m)`` the beam's first-wall distance in map ``m``
  (:func:`predictive_log_density_samples`); for a map of independent wall probabilities ``q`` (log-odds mapping),
  ``p(y) = sum_k P(first wall is the k-th cell) p(y | t_k) + P(no wall) p(y | max distance)`` with
  ``P(first wall is the k-th cell) = q_k prod_{j<k} (1 - q_j)`` (:func:`predictive_log_density_independent`).
  Both use the same sensor model, so the two maps are scored alike.

Against a floor plan: cell-wise accuracy, AUC and Brier score of the wall probabilities over the known cells
(:func:`truth_scores`).
"""

from __future__ import annotations

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.logodds import beam_hits_and_misses
from bayesmap.metrics import accuracy, brier_score, roc_auc
from bayesmap.raycast import RayTable, check_readings


def heldout_split(num_scans: int, every: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(train, test)`` of scans ``0..num_scans-1``: every ``every``-th scan (``every-1, 2*every-1, ...``)
    is held out, the rest is for mapping.

    Raises:
        BayesmapError: if ``every`` is not an integer >= 2 or no scan would be held out or kept.
    """
    if int(every) != every or every < 2:
        raise BayesmapError(f"hold-out stride must be an integer >= 2, got {every!r}")
    scans = np.arange(int(num_scans))
    test = (scans % int(every)) == int(every) - 1
    if not test.any() or test.all():
        raise BayesmapError(f"holding out every {every}-th of {num_scans} scans leaves no scan to "
                            f"{'test' if not test.any() else 'map'} with")
    return scans[~test], scans[test]


def occupancy_auc(table: RayTable, readings, prob, max_range_mask=None) -> float:
    """Occupancy classification AUC of the wall probabilities ``prob`` ``(nx, ny)`` on the beams of ``table``
    (readings ``(R,)`` meters; ``max_range_mask`` ``(R,)`` bool): endpoint cells are positives, cells crossed before
    the endpoint negatives (see the module docstring).

    Raises:
        BayesmapError: on shapes that do not match, or if the beams give no positive or no negative.
    """
    prob = np.asarray(prob, dtype=np.float64)
    if prob.shape != table.grid.shape:
        raise BayesmapError(f"wall probabilities have shape {prob.shape}, the grid is {table.grid.shape}")
    hit, miss = beam_hits_and_misses(table, readings, max_range_mask)
    scores = prob.reshape(-1)[table.pair_cells]
    touched = hit | miss
    return roc_auc(scores[touched], hit[touched])


def _first_wall_positions(table: RayTable, walls_flat: np.ndarray) -> np.ndarray:
    """``(R,)`` index into the table's pairs of each ray's first wall, or ``num_pairs`` (the max distance) if none."""
    is_wall = walls_flat[table.pair_cells] > 0.5
    idx = np.flatnonzero(is_wall)
    rays = table.pair_rays[idx]
    first = np.full(table.num_rays, table.num_pairs, dtype=np.int64)
    # pairs are sorted along each ray: the first wall pair of a ray is its smallest index
    np.minimum.at(first, rays, idx)
    return first


def predictive_log_density_samples(table: RayTable, readings, samples, logpdf) -> np.ndarray:
    """``(R,)`` log posterior predictive density of each beam's reading: ``log (1/N) sum_n p(y | d(m_n))``.

    Args:
        table: the ray-cell table of the scored beams (R rays).
        readings: ``(R,)`` meters.
        samples: ``(N, nx, ny)`` posterior samples (0/1).
        logpdf: ``logpdf(y (R,), d (R,)) -> (R,)`` log-density of a reading given the first-wall distance (the
            sensor model, e.g. :func:`bayesmap.sensor.reading_logpdf` with the problem's parameters).

    Raises:
        BayesmapError: on shapes that do not match.
    """
    y = check_readings(readings, table.num_rays)
    samples = np.asarray(samples)
    if samples.ndim != 3 or samples.shape[1:] != table.grid.shape:
        raise BayesmapError(f"samples must have shape (N, {table.grid.shape[0]}, {table.grid.shape[1]}), got {samples.shape}")
    dists = np.append(table.pair_dists.astype(np.float64), table.max_distance)
    logs = np.stack([np.asarray(logpdf(y, dists[_first_wall_positions(table, s.reshape(-1))]), dtype=np.float64)
                     for s in samples])
    top = logs.max(axis=0)
    return top + np.log(np.mean(np.exp(logs - top), axis=0))


def predictive_log_density_independent(table: RayTable, readings, prob, logpdf, chunk: int = 1 << 22) -> np.ndarray:
    """``(R,)`` log predictive density of each beam's reading when cells are walls independently with probability
    ``prob`` ``(nx, ny)``: ``log(sum_k q_k prod_{j<k}(1 - q_j) p(y | t_k) + prod_j (1 - q_j) p(y | max))`` over the
    ray's cells ``k`` in order (see the module docstring). ``logpdf`` as in
    :func:`predictive_log_density_samples`. Computed in log space over the table's pairs, ``chunk`` rays' pairs at a
    time.

    Raises:
        BayesmapError: on shapes that do not match, or probabilities outside [0, 1].
    """
    y = check_readings(readings, table.num_rays)
    q = np.asarray(prob, dtype=np.float64)
    if q.shape != table.grid.shape:
        raise BayesmapError(f"wall probabilities have shape {q.shape}, the grid is {table.grid.shape}")
    if not np.all((q >= 0) & (q <= 1)):
        raise BayesmapError("wall probabilities must lie in [0, 1]")
    qp = q.reshape(-1)[table.pair_cells]
    rays = table.pair_rays
    starts, ends = table.offsets[:-1], table.offsets[1:]
    # log prod_{j<k} (1 - q_j) within each ray, from cumulative sums over the whole table minus each ray's start;
    # cells with q = 1 are counted apart (their log(1 - q) is -inf, which a running sum cannot carry)
    certain = qp >= 1.0
    log_free = np.log1p(-np.where(certain, 0.0, qp))
    csum, ccount = np.cumsum(log_free), np.cumsum(certain)

    def before(cumulative):
        return np.where(starts > 0, cumulative[np.maximum(starts - 1, 0)], 0)

    inclusive = csum - before(csum)[rays]
    inclusive_count = ccount - before(ccount)[rays]
    exclusive = np.where(inclusive_count - certain > 0, -np.inf, inclusive - log_free)
    with np.errstate(divide="ignore"):
        log_q = np.log(qp)
    log_ll = np.asarray(logpdf(y[rays], table.pair_dists.astype(np.float64)), dtype=np.float64)
    terms = log_q + exclusive + log_ll
    # the "no wall on the ray" term
    last = np.maximum(ends - 1, 0)
    empty = ends == starts
    none = np.where(empty, 0.0, np.where(inclusive_count[last] > 0, -np.inf, inclusive[last]))
    none_term = none + np.asarray(logpdf(y, np.full(table.num_rays, table.max_distance)), dtype=np.float64)
    # per-ray logsumexp of its terms and the no-wall term
    top = none_term.copy()
    np.maximum.at(top, rays, terms)
    top = np.where(np.isfinite(top), top, 0.0)
    total = np.exp(none_term - top)
    np.add.at(total, rays, np.exp(terms - top[rays]))
    with np.errstate(divide="ignore"):
        return top + np.log(total)


def truth_scores(prob, truth, known=None) -> dict[str, float]:
    """Cell-wise scores of wall probabilities ``prob`` ``(nx, ny)`` against a floor plan ``truth`` ``(nx, ny)``
    (0/1) over the ``known`` cells (``(nx, ny)`` bool; default all): ``{"accuracy", "auc", "brier", "cells"}``
    (accuracy at threshold 0.5; :mod:`bayesmap.metrics`).

    Raises:
        BayesmapError: on shapes that do not match or no known cell.
    """
    prob = np.asarray(prob, dtype=np.float64)
    truth = np.asarray(truth)
    if prob.shape != truth.shape:
        raise BayesmapError(f"wall probabilities have shape {prob.shape}, the floor plan {truth.shape}")
    mask = np.ones(prob.shape, bool) if known is None else np.asarray(known, bool)
    if not mask.any():
        raise BayesmapError("no known cell to score")
    labels = truth > 0.5
    return {"accuracy": accuracy(prob, labels, mask=mask), "auc": roc_auc(prob[mask], labels[mask]),
            "brier": brier_score(prob, labels, mask=mask), "cells": int(mask.sum())}
