"""What a run's report shows besides the posterior: the log joint and the wrong visible cells of every sweep's sample,
and (on small single-scan problems) an importance-sampling run for comparison.

:func:`chain_traces` computes them once; :func:`bayesmap.viz.report.build_report` only renders them.

Sources: the log joint is GenJAX ``assess`` of the model (:func:`bayesmap.model.generative.log_joint`); importance
sampling with the prior as proposal is :func:`bayesmap.inference.importance.importance_sampling`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.importance import ImportanceResult, importance_sampling
from bayesmap.model.generative import log_joint

__all__ = ["ChainTraces", "chain_log_joints", "chain_traces", "chain_wrong_cells"]

# grids up to this many cells get the importance-sampling run (it runs the full model once per particle)
IMPORTANCE_MAX_CELLS = 2500
IMPORTANCE_PARTICLES = 1000
# samples scored per call of the jitted, vmapped log joint
LOG_JOINT_BATCH = 25


class ChainTraces(NamedTuple):
    """Per-sweep traces of a run and the optional importance-sampling comparison (what the report draws).

    Attributes:
        log_joints: ``(T,)`` or ``(C, T)`` float64 (one or ``C`` chains of ``T`` sweeps): natural-log
            ``log p(walls, readings)`` of the sample after each sweep.
        wrong_cells: same shape, int: visible cells each sample gets wrong; None without a true map.
        importance: an :class:`~bayesmap.inference.importance.ImportanceResult` of
            :data:`IMPORTANCE_PARTICLES` particles, or None when not run.
    """

    log_joints: np.ndarray
    wrong_cells: np.ndarray | None
    importance: ImportanceResult | None


def chain_log_joints(problem, samples) -> np.ndarray:
    """Log joint (GenJAX ``assess``) of every sample: ``samples`` ``(T, nx, ny)`` or ``(C, T, nx, ny)`` ->
    ``(T,)`` or ``(C, T)`` float64. For several scans: :meth:`~bayesmap.problem.Problem.log_joints` (``assess``, or
    the ray-cell table's equal sum on large problems, the table read once for all samples)."""
    arr = np.asarray(samples, dtype=np.float32)
    flat = arr.reshape((-1,) + arr.shape[-2:])
    if problem.multi_scan:
        return problem.log_joints(flat).reshape(arr.shape[:-2])
    score = jax.jit(jax.vmap(lambda w: log_joint(w, problem.model_readings, problem.pos, problem.params,
                                                 problem.beam_angles)))
    out = np.concatenate([np.asarray(score(flat[i:i + LOG_JOINT_BATCH]), dtype=np.float64)
                          for i in range(0, len(flat), LOG_JOINT_BATCH)])
    return out.reshape(arr.shape[:-2])


def chain_wrong_cells(problem, samples) -> np.ndarray | None:
    """Visible cells each sample gets wrong (``(T,)`` or ``(C, T)`` int), or None without a true map."""
    if problem.truth is None:
        return None
    visible = problem.visible
    truth = np.asarray(problem.truth) > 0
    arr = np.asarray(samples) > 0
    return np.sum((arr != truth) & visible, axis=(-2, -1))


def chain_traces(problem, result, *, seed: int = 0, importance: bool | None = None) -> ChainTraces:
    """The traces of ``result`` (an :class:`~bayesmap.inference.driver.InferenceResult` of ``problem``) for its
    report.

    Args:
        problem: the :class:`~bayesmap.problem.Problem` that was solved.
        result: its inference result (``samples`` ``(T, nx, ny)`` or ``(C, T, nx, ny)``).
        seed: key of the importance-sampling run (``jax.random.key(seed)``).
        importance: run importance sampling with :data:`IMPORTANCE_PARTICLES` particles; default: for grids of at
            most :data:`IMPORTANCE_MAX_CELLS` cells and a single scan.

    Raises:
        BayesmapError: if importance sampling is asked for on a problem of several scans (the model of
            :func:`~bayesmap.inference.importance.importance_sampling` has one scan).
    """
    samples = np.asarray(result.samples)
    if importance is None:
        importance = problem.grid.num_cells <= IMPORTANCE_MAX_CELLS and not problem.multi_scan
    elif importance and problem.multi_scan:
        raise BayesmapError("importance=True needs a single-scan problem: importance sampling runs the one-scan model")
    imp = None
    if importance:
        imp = importance_sampling(jax.random.key(seed), problem.model_readings, problem.pos, problem.params,
                                  IMPORTANCE_PARTICLES, problem.beam_angles)
    return ChainTraces(chain_log_joints(problem, samples), chain_wrong_cells(problem, samples), imp)
