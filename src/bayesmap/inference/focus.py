"""A cellwise chain that sweeps the cells in doubt more often than the settled ones.

On a whole log most cells are settled after a few sweeps: their conditional wall probability stays below 10^-4 or
above 1 - 10^-4 sweep after sweep, yet every sweep scores them, and their rays are most of the sweep's work (on the
Intel log at known poses the cells in doubt are about 10 % of the crossed cells and 13 % of the (beam, cell) pairs).
:func:`focused_chain` runs:

1. :data:`FOCUS_START` sweeps of every cell (the chain of :func:`bayesmap.inference.chains.run_chain`, the same
   keys and draws);
2. then picks the cells in doubt: those whose conditional wall probability ``p`` had ``min(p, 1 - p) >``
   :data:`FOCUS_DOUBT` in one of the sweeps of the second half of step 1 (:func:`cells_in_doubt`);
3. then repeats, to the end of the chain: one sweep of every cell, followed by ``FOCUS_EVERY - 1`` sweeps of the
   cells in doubt only (the other cells keep their values).

Why the chain still samples the posterior: a sweep of the cells in doubt draws each of them from its full
conditional given all the others (the same update as in a whole sweep; the cells it skips are held fixed), so it
leaves the posterior invariant; so does a whole sweep; so does their composition (Tierney 1994, sec. 2.4), and the
whole sweep every ``FOCUS_EVERY`` sweeps keeps the chain irreducible wherever the plain chain is. Which cells are
in doubt is chosen once, from the chain's own first sweeps, and then fixed: from there on the chain is a
time-homogeneous Markov chain with that (valid) kernel, started from the state the first sweeps reached, which the
burn-in discards as it discards any start (adapting only before a fixed point and then freezing the kernel keeps an
adaptive sampler valid; Gilks, Roberts & Sahu 1998; Andrieu & Thoms 2008, sec. 2). The cells' order within a sweep
changes at step 2 (the cells in doubt first within each width group, :meth:`bayesmap.inference.cellwise.
CellwiseKernel.focus`, which reorders the kernel given in place): any fixed order is a valid sweep.

The records: each sweep's map is the chain's state; a skipped cell's conditional wall probability in a sweep that
skips it is the one it had when it was last drawn (the last whole sweep), so the mean over the kept sweeps weights
each of its draws by the sweeps until the next, a fixed schedule, and stays an unbiased Rao-Blackwellized estimate at
stationarity.

The three settings change the Monte Carlo error, not the target: how they were chosen (held-out scores within the
seed-to-seed spread of the plain chain, at the least time) is on the validation page (docs/validation/
defaults.md#focus_every).
"""

from __future__ import annotations

import jax
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.base import kernel_algorithm
from bayesmap.inference.cellwise import CellwiseKernel
from bayesmap.inference.chains import ChainResult, run_sweeps
from bayesmap.progress import ProgressCallback

FOCUS_START = 10
"""Sweeps of every cell before the cells in doubt are chosen (from the records of the last half of them); a chain
of at most this many sweeps sweeps every cell every time. Set, not cross-validated: a tenth of the default 100
sweeps, and more than the SLAM pipeline's map blocks (4 sweeps, left as they were); docs/validation/
defaults.md#focus_every."""

FOCUS_DOUBT = 1e-4
"""A cell is in doubt when its conditional wall probability ``p`` had ``min(p, 1 - p)`` above this in one of the
sweeps it is chosen from (:func:`cells_in_doubt`); a probability, no unit. Chosen with :data:`FOCUS_EVERY` by
leave-one-log-out cross-validation over 10^-3 and 10^-4 (``benchmarks/focus_cv.py``; docs/validation/
defaults.md#focus_every)."""

FOCUS_EVERY = 10
"""After the cells in doubt are chosen, one sweep in this many visits every cell, the others only the cells in
doubt (>= 1; 1: every sweep visits every cell). Chosen with :data:`FOCUS_DOUBT` by leave-one-log-out
cross-validation over 5 and 10: the fastest setting whose held-out NLL is within the plain chain's seed-to-seed
spread (``benchmarks/focus_cv.py``; docs/validation/defaults.md#focus_every)."""


def cells_in_doubt(wall_probs, doubt: float = FOCUS_DOUBT) -> np.ndarray:
    """The cells whose conditional wall probability ``p`` had ``min(p, 1 - p) > doubt`` in at least one sweep.

    Args:
        wall_probs: ``(sweeps, nx, ny)`` float, each sweep's conditional wall probabilities, ``sweeps >= 1``.
        doubt: the threshold, ``0 <= doubt < 0.5``.

    Returns:
        ``(nx, ny)`` bool.

    Raises:
        BayesmapError: on no sweeps or a ``doubt`` outside ``[0, 0.5)``.
    """
    _check_doubt(doubt)
    probs = np.asarray(wall_probs)
    if probs.ndim != 3 or len(probs) == 0:
        raise BayesmapError(f"wall_probs must be (sweeps, nx, ny) with sweeps >= 1, got shape {probs.shape}")
    return (np.minimum(probs, 1 - probs) > doubt).any(axis=0)


def _check_doubt(doubt) -> None:
    if isinstance(doubt, bool) or not isinstance(doubt, (int, float)) or not 0 <= doubt < 0.5:
        raise BayesmapError(f"doubt must be a probability in [0, 0.5), got {doubt!r}")


def focused_chain(key, kernel: CellwiseKernel, initial_walls, num_sweeps: int,
                  progress: ProgressCallback | None = None, stage: str = "sweeps", start: int = FOCUS_START,
                  every: int = FOCUS_EVERY, doubt: float = FOCUS_DOUBT) -> ChainResult:
    """``num_sweeps`` sweeps of the cellwise ``kernel`` from ``initial_walls``, the later ones mostly of the cells in
    doubt (module docstring). Sweep ``t`` uses key ``t`` of ``jax.random.split(key, num_sweeps)``: the first
    ``start`` sweeps are those of :func:`bayesmap.inference.chains.run_chain` with ``key``, bit for bit. One
    compiled sweep per call, shared by the whole and the focused sweeps.

    Args:
        key: a JAX PRNG key.
        kernel: the sampler's kernel (:attr:`bayesmap.inference.cellwise.CellwiseGibbs.kernel`); after ``start``
            sweeps its cells are reordered in place (:meth:`~bayesmap.inference.cellwise.CellwiseKernel.focus`).
        initial_walls: ``(nx, ny)`` the starting map (0/1).
        num_sweeps: sweeps, >= 1.
        progress: gets ``Progress(stage, done, num_sweeps, "sweep")`` before the first sweep and after each.
        stage: the stage the reports name.
        start: :data:`FOCUS_START`, >= 1.
        every: :data:`FOCUS_EVERY`, >= 1.
        doubt: :data:`FOCUS_DOUBT`, in ``[0, 0.5)``.

    Returns:
        :class:`bayesmap.inference.chains.ChainResult` of numpy records: ``samples`` ``(num_sweeps, nx, ny)``
        bool, the final state, ``wall_probs`` ``(num_sweeps, nx, ny)`` float32 (module docstring).

    Raises:
        BayesmapError: on ``num_sweeps``, ``start`` or ``every`` not an integer >= 1, or a bad ``doubt``.
    """
    for name, value in (("number of sweeps", num_sweeps), ("start", start), ("every", every)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise BayesmapError(f"{name} must be an integer >= 1, got {value!r}")
    _check_doubt(doubt)
    num_sweeps = int(num_sweeps)
    keys = jax.random.split(key, num_sweeps)
    algorithm = kernel_algorithm(kernel)
    state = algorithm.init(initial_walls)
    first = run_sweeps(keys[:min(start, num_sweeps)], state, algorithm, progress, stage, 0, num_sweeps)
    if start >= num_sweeps:
        return first
    samples = np.empty((num_sweeps,) + first.samples.shape[1:], first.samples.dtype)
    probs = np.empty((num_sweeps,) + first.wall_probs.shape[1:], first.wall_probs.dtype)
    samples[:start], probs[:start] = first.samples, first.wall_probs
    settled = ~cells_in_doubt(first.wall_probs[start // 2:], doubt)
    state = first.final_state
    del first
    focused = kernel_algorithm(kernel.focus(~settled))  # (kernel reordered in place: its whole sweeps in a new order)
    whole = algorithm
    t = start
    while t < num_sweeps:  # a whole sweep, then up to every - 1 sweeps of the cells in doubt
        for algorithm, end in ((whole, t + 1), (focused, min(t + every, num_sweeps))):
            if end <= t:
                continue
            piece = run_sweeps(keys[t:end], state, algorithm, progress, stage, t, num_sweeps)
            samples[t:end], probs[t:end] = piece.samples, piece.wall_probs
            if algorithm is focused:  # the settled cells keep the probability of their last draw
                probs[t:end, settled] = probs[t - 1, settled]
            state, t = piece.final_state, end
    return ChainResult(samples, state, probs)
