"""Scoring maps: on held-out beams of a log, and against a known floor plan.

Held-out beams (a map built without them predicts them):

* **occupancy AUC**: for each held-out beam, its endpoint cell (not for max-range readings) is a positive and
  every cell it crosses before the endpoint a negative (:func:`bayesmap.inference.logodds.beam_hits_and_misses`
  decides which cells those are); the score of a cell is its wall probability; ties count one half
  (:func:`bayesmap.evaluation.metrics.roc_auc`). A cell crossed by several beams counts once per beam.
* **predictive NLL**: the mean over held-out beams of ``-log p(y)`` where ``p(y)`` is the posterior predictive
  density of the reading under the sensor model: for posterior samples ``m_1..m_N``,
  ``p(y) = (1/N) sum_n p(y | d(m_n))`` with ``d(m)`` the beam's first-wall distance in map ``m``
  (:func:`predictive_log_density_samples`); for a map of independent wall probabilities ``q`` (log-odds mapping),
  ``p(y) = sum_k P(first wall is the k-th cell) p(y | t_k) + P(no wall) p(y | max distance)`` with
  ``P(first wall is the k-th cell) = q_k prod_{j<k} (1 - q_j)`` (:func:`predictive_log_density_independent`).
  Both use the same sensor model, so the two maps are scored alike. When a beam can pass a wall cell
  (``wall_pass_prob`` ``pi > 0``), a reading depends on the ray's first two walls
  (:func:`bayesmap.model.generative.walls_log_likelihood`): with samples, each sample's first two walls
  (:func:`predictive_log_density_walls`); with independent cells, the probabilities of no wall, of exactly one (at
  ``k``) and of a first and second wall (:func:`predictive_log_density_independent`, ``pass_prob``).

Against a floor plan: cell-wise accuracy, AUC and Brier score of the wall probabilities over the known cells
(:func:`truth_scores`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.metrics import accuracy, brier_score, roc_auc
from bayesmap.geometry.raytable import RayTable, build_ray_table, check_readings, visible_cells
from bayesmap.inference.driver import run_inference, run_logodds
from bayesmap.inference.logodds import beam_hits_and_misses
from bayesmap.io.rosmap import read_rosmap
from bayesmap.model.generative import make_params, reading_log_likelihood, walls_log_likelihood
from bayesmap.model.passable import PASS_WALLS
from bayesmap.model.prior import DEFAULT_COUPLING
from bayesmap.model.sensor import beam_sample
from bayesmap.progress import ProgressCallback
from bayesmap.scenes import (
    LOG_BEAM_MODEL,
    LOG_CUT_PAST_READING,
    LOG_GEOMETRY,
    LOG_KEYFRAME_DISTANCE,
    LOG_KEYFRAME_TURN,
    LOG_PRIOR,
    RESOLUTION,
    SIMULATED_CLEARANCE,
    SIMULATED_MAX_RANGE,
    SIMULATED_NUM_ANGLES,
    SIMULATED_NUM_POSES,
    SIMULATED_SENSOR_NOISE,
    Observations,
    Problem,
    log_problem,
    log_wall_pass_prob,
)
from bayesmap.slam.keyframes import select_keyframes


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
    return _auc(table, beam_hits_and_misses(table, readings, max_range_mask), prob)


def _auc(table: RayTable, hits_and_misses: tuple[np.ndarray, np.ndarray], prob) -> float:
    """:func:`occupancy_auc` from the beams' ``(hit, miss)`` pairs (:func:`beam_hits_and_misses`)."""
    prob = np.asarray(prob, dtype=np.float64)
    if prob.shape != table.grid.shape:
        raise BayesmapError(f"wall probabilities have shape {prob.shape}, the grid is {table.grid.shape}")
    hit, miss = hits_and_misses
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


def predictive_log_density_samples(table: RayTable, readings, samples, logpdf, chords: bool = False) -> np.ndarray:
    """``(R,)`` log posterior predictive density of each beam's reading: ``log (1/N) sum_n p(y | d(m_n))``.

    Args:
        table: the ray-cell table of the scored beams (R rays).
        readings: ``(R,)`` meters.
        samples: ``(N, nx, ny)`` posterior samples (0/1).
        logpdf: ``logpdf(y (R,), d (R,)) -> (R,)`` log-density of a reading given the first-wall distance (the
            sensor model, e.g. :func:`bayesmap.model.sensor.reading_logpdf` with the problem's parameters); with
            ``chords``, ``logpdf(y, a, b)`` of the first wall cell's entry and exit distances ``a``, ``b`` (the chord
            geometry, :attr:`~bayesmap.geometry.raytable.RayTable.pair_exits`).

    Raises:
        BayesmapError: on shapes that do not match.
    """
    y, samples = _check_samples(table, readings, samples)
    dists = np.append(table.pair_dists.astype(np.float64), table.max_distance)
    exits = np.append(table.pair_exits.astype(np.float64), table.max_distance) if chords else None

    def one(sample):
        first = _first_wall_positions(table, sample.reshape(-1))
        args = (dists[first], exits[first]) if chords else (dists[first],)
        return np.asarray(logpdf(y, *args), dtype=np.float64)

    return _log_mean_exp(np.stack([one(s) for s in samples]))


def _check_samples(table: RayTable, readings, samples) -> tuple[np.ndarray, np.ndarray]:
    """``(readings (R,), samples (N, nx, ny))`` checked against ``table``."""
    y = check_readings(readings, table.num_rays)
    samples = np.asarray(samples)
    if samples.ndim != 3 or samples.shape[1:] != table.grid.shape:
        raise BayesmapError(f"samples must have shape (N, {table.grid.shape[0]}, {table.grid.shape[1]}), "
                            f"got {samples.shape}")
    return y, samples


def _log_mean_exp(logs: np.ndarray) -> np.ndarray:
    """``log mean exp`` of ``logs`` ``(N, R)`` over its first axis, without overflow."""
    top = logs.max(axis=0)
    return top + np.log(np.mean(np.exp(logs - top), axis=0))


def predictive_log_density_walls(table: RayTable, readings, samples, params) -> np.ndarray:
    """``(R,)`` log posterior predictive density of each beam's reading, ``log (1/N) sum_n p(y | m_n)``, under the
    model ``params`` (a :class:`~bayesmap.model.generative.ModelParams`): each sample's first two walls per ray
    (:meth:`~bayesmap.geometry.raytable.RayTable.wall_chords`) scored by
    :func:`bayesmap.model.generative.walls_log_likelihood`, for any ``wall_pass_prob``. ``samples`` ``(N, nx, ny)``.

    Raises:
        BayesmapError: on shapes that do not match.
    """
    y, samples = _check_samples(table, readings, samples)
    dtype = jnp.result_type(float)
    return _log_mean_exp(np.stack([np.asarray(walls_log_likelihood(jnp.asarray(y, dtype), jnp.asarray(
        table.wall_chords(s, PASS_WALLS), dtype), params), dtype=np.float64) for s in samples]))


def predictive_log_density_independent(table: RayTable, readings, prob, logpdf, chunk: int = 1 << 22,
                                      chords: bool = False, pass_prob: float = 0.0) -> np.ndarray:
    """``(R,)`` log predictive density of each beam's reading when cells are walls independently with probability
    ``prob`` ``(nx, ny)``: ``log(sum_k q_k prod_{j<k}(1 - q_j) p(y | t_k) + prod_j (1 - q_j) p(y | max))`` over the
    ray's cells ``k`` in order (see the module docstring). ``logpdf`` and ``chords`` as in
    :func:`predictive_log_density_samples`. Computed in log space over the table's pairs, ``chunk`` rays' pairs at a
    time.

    With ``pass_prob`` ``pi > 0`` (a beam passes a wall cell with probability ``pi``; ``logpdf`` the sensor model at
    one wall) the reading depends on the first two walls: ``p(y) = (1 - pi) sum_k P(first = k) p(y | t_k) +
    pi (1 - pi) sum_l P(second = l) p(y | t_l) + (P(none) + pi P(one) + pi^2 P(two or more)) p(y | max)``, with
    ``P(second = l) = q_l prod_{j<l} (1 - q_j) sum_{k<l} q_k / (1 - q_k)`` and ``P(one) = P(none) sum_k q_k / (1 -
    q_k)``; there ``q`` is capped at ``1 - 1e-9`` (log-odds maps are clamped far below it).

    Raises:
        BayesmapError: on shapes that do not match, or probabilities outside [0, 1].
    """
    y = check_readings(readings, table.num_rays)
    q = np.asarray(prob, dtype=np.float64)
    if q.shape != table.grid.shape:
        raise BayesmapError(f"wall probabilities have shape {q.shape}, the grid is {table.grid.shape}")
    if not np.all((q >= 0) & (q <= 1)):
        raise BayesmapError("wall probabilities must lie in [0, 1]")
    if pass_prob > 0:
        return _independent_passable(table, y, q, logpdf, chords, float(pass_prob))
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
    pair_args = (table.pair_dists.astype(np.float64),) + ((table.pair_exits.astype(np.float64),) if chords else ())
    log_ll = np.asarray(logpdf(y[rays], *pair_args), dtype=np.float64)
    terms = log_q + exclusive + log_ll
    # the "no wall on the ray" term
    last = np.maximum(ends - 1, 0)
    empty = ends == starts
    none = np.where(empty, 0.0, np.where(inclusive_count[last] > 0, -np.inf, inclusive[last]))
    no_wall = (np.full(table.num_rays, table.max_distance),) * (2 if chords else 1)
    none_term = none + np.asarray(logpdf(y, *no_wall), dtype=np.float64)
    # per-ray logsumexp of its terms and the no-wall term
    top = none_term.copy()
    np.maximum.at(top, rays, terms)
    top = np.where(np.isfinite(top), top, 0.0)
    total = np.exp(none_term - top)
    np.add.at(total, rays, np.exp(terms - top[rays]))
    with np.errstate(divide="ignore"):
        return top + np.log(total)


def _independent_passable(table: RayTable, y, q, logpdf, chords: bool, pi: float) -> np.ndarray:
    """:func:`predictive_log_density_independent` with ``pass_prob`` ``pi > 0`` (its docstring's formula)."""
    qp = np.minimum(q.reshape(-1)[table.pair_cells], 1.0 - 1e-9)
    rays = table.pair_rays
    starts = table.offsets[:-1]
    lengths = table.offsets[1:] - starts
    by_length = np.argsort(-lengths, kind="stable")  # the rays still running at position k: by_length[:count[k]]
    count = np.searchsorted(-lengths[by_length], -np.arange(lengths.max(initial=0)), side="left")
    log_free = np.log1p(-qp)
    with np.errstate(divide="ignore"):
        log_q = np.log(qp)
    odds = qp / (1.0 - qp)

    def exclusive_sum(values):
        """Per pair, the sum of ``values`` ``(P, ...)`` over the earlier pairs of its ray, accumulated ray by ray
        along the rays' positions: a running sum over the whole table minus each ray's start would lose a ray's
        small sums to the rounding of every earlier ray's (a cell of probability ``1 - 1e-9`` adds ``1e9`` to the
        odds)."""
        out = np.empty_like(values)
        acc = np.zeros((table.num_rays,) + values.shape[1:])
        for k, n in enumerate(count):
            live = by_length[:n]
            at = starts[live] + k
            out[at] = acc[live]
            acc[live] += values[at]
        return out

    # log prod_{j<k} (1 - q_j) and sum_{j<k} q_j / (1 - q_j), in one pass
    before_free, before_odds = exclusive_sum(np.stack([log_free, odds], axis=1)).T
    pair_args = (table.pair_dists.astype(np.float64),) + ((table.pair_exits.astype(np.float64),) if chords else ())
    log_ll = np.asarray(logpdf(y[rays], *pair_args), dtype=np.float64)
    with np.errstate(divide="ignore"):
        first = np.log1p(-pi) + log_q + before_free + log_ll
        second = np.log(pi) + np.log1p(-pi) + log_q + before_free + np.log(before_odds) + log_ll
    all_free = np.zeros(table.num_rays)
    np.add.at(all_free, rays, log_free)
    total_odds = np.zeros(table.num_rays)
    np.add.at(total_odds, rays, odds)
    p_none = np.exp(all_free)
    p_one = p_none * total_odds
    no_wall_weight = p_none + pi * p_one + pi**2 * np.maximum(1.0 - p_none - p_one, 0.0)
    no_wall = (np.full(table.num_rays, table.max_distance),) * (2 if chords else 1)
    with np.errstate(divide="ignore"):
        none_term = np.log(no_wall_weight) + np.asarray(logpdf(y, *no_wall), dtype=np.float64)
    top = none_term.copy()
    np.maximum.at(top, rays, np.maximum(first, second))
    top = np.where(np.isfinite(top), top, 0.0)
    total = np.exp(none_term - top)
    np.add.at(total, rays, np.exp(first - top[rays]) + np.exp(second - top[rays]))
    with np.errstate(divide="ignore"):
        return top + np.log(total)


def truth_scores(prob, truth, known=None) -> dict[str, float]:
    """Cell-wise scores of wall probabilities ``prob`` ``(nx, ny)`` against a floor plan ``truth`` ``(nx, ny)``
    (0/1) over the ``known`` cells (``(nx, ny)`` bool; default all): ``{"accuracy", "auc", "brier", "cells"}``
    (accuracy at threshold 0.5; :mod:`bayesmap.evaluation.metrics`).

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


# -- drivers: a log with held-out scans, a floor plan with synthetic scans ------------------------------------------


def sensor_logpdf(params):
    """``logpdf(y, d)`` (``logpdf(y, a, b)`` in the chord geometry) of the problem's sensor model at one wall, numpy
    in and out (:func:`bayesmap.model.generative.reading_log_likelihood`; a beam passing wall cells is the caller's
    mixture)."""

    params = dataclasses.replace(params, wall_pass_prob=0.0)  # one wall's density (the mixture is the caller's)

    def logpdf(y, d, exits=None):
        return np.asarray(reading_log_likelihood(np.asarray(y), np.asarray(d), params,
                                                 None if exits is None else np.asarray(exits)), dtype=np.float64)

    return logpdf


def score_maps(test, maps: dict, max_samples: int = 50) -> dict[str, dict[str, float]]:
    """Score maps on the beams of ``test`` (a :class:`~bayesmap.problem.Problem` on the maps' grid).

    Args:
        test: the held-out beams.
        maps: name -> ``(prob (nx, ny), samples (N, nx, ny) or None)``; with samples the predictive density averages
            over (at most ``max_samples``, evenly thinned) samples, without it cells are independent with ``prob``.

    Returns:
        name -> ``{"auc", "nll", "beams", "positives", "negatives"}``.
    """
    # endpoints (AUC) from the measured ranges; densities (NLL) of the readings the model scores (the same shift for
    # every map, so the comparison is fair)
    table, y, mask = test.table, test.ray_readings, test.ray_max_range
    y_model = test.model_ray_readings
    logpdf = sensor_logpdf(test.params)
    chords = test.params.geometry == "chord"
    hit, miss = beam_hits_and_misses(table, y, mask)
    out = {}
    for name, (prob, samples) in maps.items():
        if samples is not None and len(samples):
            keep = samples[np.unique(np.linspace(0, len(samples) - 1, min(max_samples, len(samples))).astype(int))]
            if test.params.penetrable:
                logp = predictive_log_density_walls(table, y_model, keep, test.params)
            else:
                logp = predictive_log_density_samples(table, y_model, keep, logpdf, chords=chords)
        else:
            logp = predictive_log_density_independent(table, y_model, prob, logpdf, chords=chords,
                                                      pass_prob=test.params.wall_pass_prob)
        out[name] = {"auc": _auc(table, (hit, miss), prob), "nll": float(-np.mean(logp)),
                     "beams": int(table.num_rays), "positives": int(hit.sum()), "negatives": int(miss.sum())}
    return out


def evaluate_log(log, scans=None, every: int = 10, resolution: float = RESOLUTION, sampler: str = "cellwise",
                 sweeps: int = 100, seed: int = 0, prior_wall_prob: float | None = None,
                 sensor_noise: float | None = None, beam_model: str = LOG_BEAM_MODEL,
                 progress: ProgressCallback | None = None,
                 range_offset: float | None = None, sensor_params: dict | None = None,
                 likelihood_power: float | None = None, geometry: str = LOG_GEOMETRY,
                 coupling: float | None = None, wall_pass_prob: float | None = None,
                 readings_per_cell: float | None = None, cut_past_reading: float = LOG_CUT_PAST_READING,
                 keyframe_distance: float = LOG_KEYFRAME_DISTANCE, keyframe_turn: float = LOG_KEYFRAME_TURN) -> dict:
    """Held-out evaluation on a log: hold out every ``every``-th of the chosen scans, map the rest with bayesmap
    (``sampler``, ``sweeps``; kept samples after a burn-in of half) and with log-odds mapping, and score both on the
    held-out beams (see the module docstring). ``sensor_noise``, ``range_offset``, ``sensor_params``,
    ``likelihood_power`` (None: the log default, which follows the training scans' density,
    :func:`bayesmap.scenes.log_likelihood_power`), ``geometry``, ``coupling`` (the structured prior's; None: the log
    default at ``resolution``), ``prior_wall_prob`` (None: :func:`bayesmap.scenes.log_prior_wall_prob` of the
    coupling), ``wall_pass_prob`` (None: :func:`bayesmap.scenes.log_wall_pass_prob` of ``sampler``) and
    ``readings_per_cell`` (None: :data:`bayesmap.scenes.LOG_READINGS_PER_CELL`): see
    :func:`bayesmap.scenes.log_problem` (log-odds mapping always uses the measured ranges); the other defaults are
    the scene defaults of :mod:`bayesmap.scenes`. ``cut_past_reading`` (meters, default
    :data:`bayesmap.scenes.LOG_CUT_PAST_READING`) cuts the training beams past their readings
    (:class:`bayesmap.model.generative.ModelParams`); the held-out beams are always scored with whole beams, so that
    scores with and without a cut compare. ``keyframe_distance`` (meters) and ``keyframe_turn`` (radians; defaults
    :data:`bayesmap.scenes.LOG_KEYFRAME_DISTANCE` and ``LOG_KEYFRAME_TURN``) map only the training scans that are
    keyframes among them (:func:`bayesmap.slam.keyframes.select_keyframes` of their poses; 0: every training scan),
    as ``bayesmap infer`` does; log-odds mapping always maps every training scan, and the held-out scans are the
    same. ``progress`` gets the chain's sweeps (:func:`bayesmap.inference.driver.run_inference`).

    Returns:
        ``{"bayesmap": {...}, "logodds": {...}, "setup": {...}}`` (JSON-serializable).

    Raises:
        BayesmapError: on bad arguments (see :func:`heldout_split`, :func:`bayesmap.scenes.log_problem`).
    """
    import time


    scans = np.arange(len(log)) if scans is None else np.asarray(scans)
    train_pos, test_pos = heldout_split(len(scans), every)
    train, test = scans[train_pos], scans[test_pos]
    wall_pass_prob = log_wall_pass_prob(sampler) if wall_pass_prob is None else wall_pass_prob
    grid = log_problem(log, scans, resolution=resolution).grid  # covers all chosen scans, held-out ones too
    kwargs = dict(resolution=resolution, prior_wall_prob=prior_wall_prob, sensor_noise=sensor_noise,
                  beam_model=beam_model, grid=grid, range_offset=range_offset, sensor_params=sensor_params,
                  likelihood_power=likelihood_power, geometry=geometry, coupling=coupling,
                  wall_pass_prob=wall_pass_prob, readings_per_cell=readings_per_cell)
    keyframes = train[select_keyframes(log.poses[train], keyframe_distance, keyframe_turn)]
    train_problem = log_problem(log, keyframes, **kwargs, cut_past_reading=cut_past_reading)
    test_problem = log_problem(log, test, **kwargs)
    start = time.perf_counter()
    gibbs = run_inference(train_problem, sampler, sweeps, seed=seed, progress=progress)
    gibbs_s = time.perf_counter() - start
    logodds = run_logodds(train_problem if len(keyframes) == len(train) else log_problem(log, train, **kwargs))
    kept = gibbs.samples[gibbs.summary["burn_in"]:]
    scores = score_maps(test_problem, {"bayesmap": (gibbs.posterior, kept), "logodds": (logodds.posterior, None)})
    scores["bayesmap"]["runtime_s"] = round(gibbs_s, 3)
    scores["logodds"]["runtime_s"] = round(logodds.runtime_s, 3)
    scores["setup"] = {
        "log": str(log.path), "scans": int(len(scans)), "train_scans": int(len(train)),
        "keyframes": int(len(keyframes)), "test_scans": int(len(test)),
        "every": int(every), "resolution": float(resolution), "grid": list(grid.shape), "sampler": sampler,
        "sweeps": int(sweeps), "beam_model": beam_model, "sensor_noise": float(train_problem.params.sensor_noise),
        "prior_wall_prob": float(train_problem.params.prior_wall_prob),
        "train_pairs": int(train_problem.table.num_pairs),
        "range_offset": float(train_problem.range_offset), "likelihood_power": float(train_problem.likelihood_power),
        "geometry": geometry,
        "coupling": float(train_problem.params.coupling),
        "wall_pass_prob": float(train_problem.params.wall_pass_prob),
        "cut_past_reading": train_problem.params.cut_past_reading if train_problem.params.cut else None,
    }
    return scores


KNOWN_FREE = 0.1
"""A floor-plan cell counts as known free when its occupancy (map_server's ``(255 - pixel) / 255``) is at most this:
white. Willow's unknown grey is pixel 206 (occupancy 0.192), which map_server's default ``free_thresh`` 0.196 would
call free."""


def simulate_readings_from_table(key, table: RayTable, walls, params) -> np.ndarray:
    """``(R,)`` range readings (meters) of the table's beams in the map ``walls`` ``(nx, ny)``, drawn from the sensor
    model of ``params`` (``params.beam_model``) at each beam's first-wall distance. Memory grows with the table's
    pairs, not beams x cells. Normal readings are clipped at 0 (as :func:`bayesmap.scenes.tutorial_problem`) and at
    the max distance."""


    d = jnp.asarray(table.first_wall_distances(walls), dtype=jnp.result_type(float))
    if params.beam_model == "normal":
        y = d + params.sensor_noise * jax.random.normal(key, d.shape, d.dtype)
    else:
        keys = jax.random.split(key, d.shape[0])
        y = jax.vmap(lambda k, dist: beam_sample(k, dist, *params.sensor_args))(keys, d)
    return np.clip(np.asarray(y, dtype=np.float64), 0.0, table.max_distance)


def evaluate_truth(path, resolution: float = RESOLUTION, num_poses: int = SIMULATED_NUM_POSES,
                   num_angles: int = SIMULATED_NUM_ANGLES, max_range: float = SIMULATED_MAX_RANGE,
                   sampler: str = "cellwise", sweeps: int = 100, seed: int = 0, sensor_noise: float | None = None,
                   beam_model: str = LOG_BEAM_MODEL, prior_wall_prob: float | None = None,
                   clearance: float = SIMULATED_CLEARANCE, sensor_params: dict | None = None,
                   coupling: float | None = None, progress: ProgressCallback | None = None) -> dict:
    """Map synthetic scans of a known floor plan and score the maps against it.

    ``num_poses`` positions are drawn (seed ``seed``) uniformly among the known-free cells at least ``clearance``
    meters from any wall or unknown cell; from each, ``num_angles`` beams over 360 degrees (random heading) are
    ray-cast in the floor plan and readings drawn from the sensor model (:func:`simulate_readings_from_table`;
    max-range readings where no wall is within ``max_range``). bayesmap (``sampler``, ``sweeps``) and log-odds
    mapping both map them; :func:`truth_scores` scores each over the known cells that some beam reached (cells
    no beam saw are the prior in both, and would only measure coverage).

    Args:
        path: the floor plan, a ROS map (``.yaml``, or a bare ``.pgm`` with ``resolution`` meters per pixel).
        sensor_noise: meters, the simulated sensor's and the model's; default
            :data:`bayesmap.scenes.SIMULATED_SENSOR_NOISE`.
        coupling: the structured prior's ``J`` (:mod:`bayesmap.model.prior`); None: 0.
        prior_wall_prob: None: :data:`bayesmap.scenes.LOG_PRIOR`, whatever the coupling (the floor plan's prior
            was not cross-validated). The other defaults are the scene defaults of :mod:`bayesmap.scenes`.
        progress: gets the chain's sweeps (:func:`bayesmap.inference.driver.run_inference`); None: no reports.

    Returns:
        ``{"bayesmap": {"accuracy", "auc", "brier", "cells"}, "logodds": {...}, "setup": {...}}``.

    Raises:
        BayesmapError: on an unreadable map, or too few free cells for the poses.
    """
    import time
    from pathlib import Path



    bare_pgm = Path(path).suffix.lower() == ".pgm"
    plan = read_rosmap(path, resolution=resolution if bare_pgm else None)
    grid = plan.grid
    walls = plan.occupancy > plan.occupied_thresh
    free = plan.occupancy <= KNOWN_FREE
    known = walls | free
    # poses: free cells with `clearance` of known free space around them (a square of cells, by shifting)
    r = int(np.ceil(clearance / grid.resolution))
    ok = free.copy()
    padded = np.pad(free, r, constant_values=False)
    for di in range(-r, r + 1):
        for dj in range(-r, r + 1):
            ok &= padded[r + di: r + di + free.shape[0], r + dj: r + dj + free.shape[1]]
    candidates = np.argwhere(ok)
    if len(candidates) < num_poses:
        raise BayesmapError(f"{path}: only {len(candidates)} free cells with {clearance} m of clearance "
                            f"for {num_poses} poses")
    rng = np.random.default_rng(seed)
    cells = candidates[rng.choice(len(candidates), size=num_poses, replace=False)]
    centers = grid.cell_centers()[cells[:, 0], cells[:, 1]]
    positions = centers + rng.uniform(-0.5, 0.5, size=centers.shape) * grid.resolution
    headings = rng.uniform(0, 2 * np.pi, size=num_poses)
    poses = np.column_stack([positions, headings])
    relative = np.broadcast_to(np.linspace(0, 2 * np.pi, num_angles, endpoint=False), (num_poses, num_angles))
    noise = SIMULATED_SENSOR_NOISE if sensor_noise is None else sensor_noise
    coupling = DEFAULT_COUPLING if coupling is None else coupling
    prior_wall_prob = LOG_PRIOR if prior_wall_prob is None else prior_wall_prob
    params = make_params(prior_wall_prob, noise, num_angles, grid, max_distance=max_range, beam_model=beam_model,
                         **(sensor_params or {}), coupling=coupling)
    world = poses[:, 2:3] + relative  # (the world-frame angles the Problem derives from the poses)
    table = build_ray_table(grid, np.repeat(positions, num_angles, axis=0), world.reshape(-1), max_range)
    readings = simulate_readings_from_table(jax.random.key(seed), table, walls, params).reshape(num_poses, num_angles)
    observations = Observations(beam_angles=relative, readings=readings, max_range_mask=readings >= max_range,
                                max_range=max_range)
    # the table was built above to simulate the readings: the problem takes it instead of building it again
    problem = Problem(params=params, observations=observations, poses=poses, ray_table=table,
                      source=f"{path} ({num_poses} simulated scans)")
    start = time.perf_counter()
    gibbs = run_inference(problem, sampler, sweeps, seed=seed, progress=progress)
    gibbs_s = time.perf_counter() - start
    logodds = run_logodds(problem)
    seen = visible_cells(table, walls) & known
    scores = {"bayesmap": truth_scores(gibbs.posterior, walls, seen),
              "logodds": truth_scores(logodds.posterior, walls, seen)}
    scores["bayesmap"]["runtime_s"] = round(gibbs_s, 3)
    scores["logodds"]["runtime_s"] = round(logodds.runtime_s, 3)
    scores["setup"] = {"truth": str(path), "grid": list(grid.shape), "resolution": grid.resolution,
                       "num_poses": int(num_poses), "num_angles": int(num_angles), "max_range": float(max_range),
                       "sampler": sampler, "sweeps": int(sweeps), "beam_model": beam_model,
                       "sensor_noise": float(noise), "cells_scored": int(seen.sum()), "known_cells": int(known.sum()),
                       "pairs": int(table.num_pairs), "coupling": float(coupling)}
    return scores
