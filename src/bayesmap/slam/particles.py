"""Sequential Monte Carlo over the front end's path: several hypotheses where one scan match is ambiguous.

The single-track front end (:func:`bayesmap.slam.scanmatch.correlative_path`) keeps one path: a scan matched into
the wrong basin of its score, or one odometry step far outside the motion model, and the path is wrong for good.
:func:`particle_path` keeps ``N`` particles instead, each a front end with its own path and its own local map (the
likelihood fields and stamps of its own last :data:`~bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE` meters of scans),
and weighs them by the front end's tempered target: per scan ``t`` and particle ``k``

* the search (:func:`bayesmap.slam.scanmatch.search`, the motion model's log-density in its score) starts from the
  particle's odometry prediction (even ``k``) or from a draw of the motion model around it (odd ``k``), so that
  particles look into different basins of the score;
* the particle's pose is its match (the default, ``draw=False``), or, with ``draw=True``, a draw from the step's
  tempered posterior ``exp(p S(x)) p(x | x_{t-1}, u_t)`` on the step lattice around its match
  (:func:`bayesmap.slam.scanmatch.step_logits`: a node by its probability, then uniformly within the node's cell);
* its log weight grows by the log of that density's integral over the lattice, the evidence of the step (the weight
  update of the improved proposal of Grisetti, Stachniss & Burgard 2007, "Improved techniques for grid mapping with
  Rao-Blackwellized particle filters", IEEE T-RO 23(1));
* a particle whose match puts fewer than ``min_hit_fraction`` of the scan's endpoints on its local map takes the
  odometry's prediction instead, as the single track does (with ``draw=True``: a draw from the motion model), and
  is weighed by ``p S`` there (the bootstrap filter's update: the proposal is the prior);
* when the effective sample size ``1 / sum w_k^2`` falls below half the particles, they are resampled
  systematically (Doucet & Johansen 2009, "A tutorial on particle filtering and smoothing"), paths, local maps and
  step covariances together.

Where it is an approximation: the target is the front end's (the tempered likelihood-field score against each
particle's local map, with the motion model), not the SLAM model's posterior with the whole map; the proposal's
normalizer is a quadrature on the step lattice (:data:`~bayesmap.slam.scanmatch.STEP_POSTERIOR_NODES`, +-0.3 m and
+-0.05 rad around the match), a particle that takes its match is weighed as if it had drawn its pose, and the weight
of a particle whose search started from a draw does not divide by that draw's density (the search is a
deterministic map of it). The loop closure then works on the heaviest particle's path. One particle that takes its
matches is the single-track front end, to the bit (a test holds it).

The kernel follows BlackJAX's conventions: :func:`init` builds a :class:`ParticleState`, :func:`step` advances it by
one scan, ``step(key, state, context) -> (state, info)``, pure and jittable; the scans and settings are the
:class:`ParticleContext`. :func:`particle_path` runs it over a log in one jitted ``lax.fori_loop`` (blocks of scans
with a progress callback, the same result).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.importance import effective_sample_size
from bayesmap.model.motion import MotionParams, compose, tailed_motion_logpdf
from bayesmap.progress import ProgressCallback
from bayesmap.slam.scanmatch import (
    FIELD_SEED,
    LOCAL_MAP_DISTANCE,
    MATCH_GRID_HALF_WIDTH,
    MATCH_LEVELS,
    MATCHER_COMPILER_OPTIONS,
    MIN_HIT_FRACTION,
    MOTION_TAIL_WEIGHT,
    FrontEndSetup,
    Lattices,
    MatchedPath,
    ScanData,
    add_matched,
    front_end_setup,
    hit_fraction,
    lattice_scores,
    lattices,
    local_map,
    moved_window,
    recentred,
    run_in_blocks,
    search,
    start_window,
    step_cell_widths,
    step_covariance,
    step_lattice,
    step_logits,
)

RESAMPLE_ESS = 0.5
"""Resample when the effective sample size falls below this fraction of the particles (Doucet & Johansen 2009's
usual threshold)."""

HYPOTHESIS_WEIGHT = 0.01
"""A distinct final path counts as a hypothesis in :func:`hypotheses` when its particles' weights sum to at least
this (the same 1 % as the loop closure's hypotheses in summary.json, ``loop_hypotheses.above_1_percent``)."""

HYPOTHESIS_DISTANCE = 0.5
"""Meters: two particles' paths are the same hypothesis when their final positions lie within this of each other
(a path that slipped once differs from the rest by decimeters to meters from then on)."""


class ParticleContext(NamedTuple):
    """The scans and settings :func:`step` reads (a pytree; ``grid``, ``half_width``, ``draw`` and ``field_seed`` are
    static in :func:`particle_path`'s jitted loop).

    Attributes:
        setup: :class:`bayesmap.slam.scanmatch.FrontEndSetup` (the scans, the frame, the grid, the local map's span,
            the likelihood power, the least hit fraction).
        levels: the search's lattices (:func:`bayesmap.slam.scanmatch.lattices`).
        lattice: the step lattice (:func:`bayesmap.slam.scanmatch.step_lattice`).
        widths: ``(A B, 3)`` its cells' widths (:func:`bayesmap.slam.scanmatch.step_cell_widths`).
        half_width: meters, the fields' half width.
        draw: True: draw each pose from the step's lattice density; False: take the match.
        field_seed: the search's (:func:`bayesmap.slam.scanmatch.search`, :data:`bayesmap.slam.scanmatch.FIELD_SEED`).
    """

    setup: FrontEndSetup
    levels: Lattices
    lattice: tuple
    widths: jax.Array
    half_width: float
    draw: bool
    field_seed: bool = FIELD_SEED


class ParticleState(NamedTuple):
    """The particles after scan ``t - 1`` (a pytree).

    Attributes:
        t: int32, the next scan to match.
        paths: ``(N, S, 3)`` each particle's path in world coordinates (rows ``>= t`` zero).
        fields: per likelihood field ``(N, n, n)`` float32, each particle's local map.
        stamps: ``(N, n, n)`` the path length of the last scan that reached each cell.
        offset: ``(2,)`` int32, the fields' window (shared by the particles: it follows the heaviest).
        log_weights: ``(N,)`` normalized log weights.
        step_cov: ``(N, S, 3, 3)`` each particle's steps' posterior covariances, row ``t`` the step to scan ``t``.
        resamples: int32, how many times the particles were resampled.
        log_evidence: the log of the target's normalizing constant as the filter estimates it so far, ``sum_t log
            sum_k w_k exp(increment_k)`` with the weights before each scan's update (the sequential Monte Carlo
            estimate of the marginal likelihood; Doucet & Johansen 2009, sec. 3.5).
    """

    t: jax.Array
    paths: jax.Array
    fields: tuple
    stamps: jax.Array
    offset: jax.Array
    log_weights: jax.Array
    step_cov: jax.Array
    resamples: jax.Array
    log_evidence: jax.Array


class ParticleInfo(NamedTuple):
    """What one :func:`step` did: ``ess`` the effective sample size before resampling, ``resampled`` bool,
    ``evidence`` ``(N,)`` each particle's log-weight increment, ``trusted`` ``(N,)`` bool, whose match was kept."""

    ess: jax.Array
    resampled: jax.Array
    evidence: jax.Array
    trusted: jax.Array


def init(context: ParticleContext, num: int) -> ParticleState:
    """``num`` identical particles at the first pose, with the local map of scan 0, equal weights. Jittable."""
    setup = context.setup
    path, fields, stamps, offset, step_cov = start_window(setup.first_pose, setup.scans, setup.frame, setup.grid)

    def tile(a):
        return jnp.broadcast_to(a, (num, *a.shape))

    return ParticleState(t=jnp.asarray(1, jnp.int32), paths=tile(path), fields=tuple(map(tile, fields)),
                         stamps=tile(stamps), offset=offset,
                         log_weights=jnp.full(num, -math.log(num), path.dtype), step_cov=tile(step_cov),
                         resamples=jnp.asarray(0, jnp.int32), log_evidence=jnp.zeros((), path.dtype))


def _move(context: ParticleContext, key, k, t, prev, fields, stamps, shift):
    """One particle's pose ``(3,)`` in the frame for scan ``t`` from its previous pose ``prev``, its log-weight
    increment, its step covariance and whether its match was trusted (the module docstring)."""
    setup = context.setup
    d, grid = setup.scans, setup.grid
    u, cov = d.increments[t - 1], d.covs[t - 1]
    start_key, node_key, cell_key, motion_key = jax.random.split(key, 4)
    deterministic = jnp.all(cov == 0)
    chol = jnp.linalg.cholesky(jnp.where(deterministic, jnp.eye(3, dtype=cov.dtype), cov))

    def motion_draw(key):
        return compose(prev, u + jnp.where(deterministic, 0.0, chol @ jax.random.normal(key, (3,), cov.dtype)))

    predicted = compose(prev, u)
    start = jnp.where(k % 2 == 0, predicted, motion_draw(start_key))
    seen = local_map(fields, stamps, d.travelled[t] - setup.span)
    scan = (d.sensor_angles[t], d.readings[t], d.returned[t])

    def log_prior(cands):
        return setup.prior_weight * tailed_motion_logpdf(prev, cands, u, cov, setup.tail_weight, setup.tail_cov)

    best, _ = search(seen, grid, start, *scan, context.levels, log_prior, shift=shift, field_seed=context.field_seed)
    trusted = hit_fraction(seen, grid, best, *scan, shift=shift) >= setup.min_hit
    cands, logits = step_logits(seen, grid, best, prev, u, cov, *scan, setup.power, context.lattice, shift=shift,
                                tail=(setup.tail_weight, setup.tail_cov))
    if context.draw:
        node = jax.random.categorical(node_key, logits)
        jitter = jax.random.uniform(cell_key, (3,), cands.dtype, -0.5, 0.5)
        matched = cands[node] + context.widths[node] * jnp.where(deterministic, 0.0, jitter)
    else:
        matched = best
    drawn = motion_draw(motion_key) if context.draw else predicted
    at_drawn = lattice_scores(seen[0], grid, drawn, jnp.zeros((1, 2), drawn.dtype), jnp.zeros(1, drawn.dtype),
                              *scan, interpolate=True, shift=shift)[0]
    floor = context.lattice[-1]
    step_cov = jnp.where(trusted, step_covariance(cands, logits, prev, cov, floor), cov + floor)
    evidence = jnp.where(trusted, jax.nn.logsumexp(logits), setup.power * at_drawn)
    return jnp.where(trusted, matched, drawn), evidence, step_cov, trusted


def systematic_resample(key, log_weights) -> jax.Array:
    """``(N,)`` int32 ancestor indices by systematic resampling of normalized ``log_weights`` ``(N,)`` (one uniform
    draw, ``N`` evenly spaced points through the weights' cumulative sum; Doucet & Johansen 2009, sec. 3.4).
    Jittable."""
    num = log_weights.shape[0]
    points = (jax.random.uniform(key, (), log_weights.dtype) + jnp.arange(num, dtype=log_weights.dtype)) / num
    return jnp.clip(jnp.searchsorted(jnp.cumsum(jnp.exp(log_weights)), points), 0, num - 1).astype(jnp.int32)


def step(key, state: ParticleState, context: ParticleContext) -> tuple[ParticleState, ParticleInfo]:
    """Match scan ``state.t`` in every particle, reweigh, and resample when the effective sample size falls below
    :data:`RESAMPLE_ESS` of the particles (the module docstring). Pure and jittable."""
    setup = context.setup
    d, grid, frame, t = setup.scans, setup.grid, setup.frame, state.t
    num = state.log_weights.shape[0]
    prev = state.paths[:, t - 1] - frame
    lead = jnp.argmax(state.log_weights)
    far, moved = recentred(compose(prev[lead], d.increments[t - 1]), state.offset, grid, context.half_width)

    def move_all():
        return jax.vmap(lambda path, fields, stamps: moved_window(d, grid, frame, path, t, fields, stamps,
                                                                  state.offset, moved))(
            state.paths, state.fields, state.stamps)

    fields, stamps = jax.lax.cond(far, move_all, lambda: (state.fields, state.stamps))
    move_key, resample_key = jax.random.split(key)
    keys = jax.random.split(move_key, num)
    poses, evidence, covs, trusted = jax.vmap(
        lambda key, k, prev, fields, stamps: _move(context, key, k, t, prev, fields, stamps, moved))(
        keys, jnp.arange(num), prev, fields, stamps)
    world = poses + frame
    fields, stamps = jax.vmap(lambda pose, fields, stamps: add_matched(d, grid, frame, pose, t, moved,
                                                                       (fields, stamps)))(world, fields, stamps)
    paths = state.paths.at[:, t].set(world)
    step_cov = state.step_cov.at[:, t].set(covs)
    log_weights = state.log_weights + evidence
    gained = jax.nn.logsumexp(log_weights)
    ess = effective_sample_size(log_weights)
    log_weights = log_weights - gained
    resampled = ess < RESAMPLE_ESS * num

    def resample(carried):  # copies every particle's local map: only when resampling
        ancestors = systematic_resample(resample_key, log_weights)
        return jax.tree_util.tree_map(lambda a: a[ancestors], carried), jnp.full(num, -math.log(num), gained.dtype)

    (paths, fields, stamps, step_cov), log_weights = jax.lax.cond(
        resampled, resample, lambda carried: (carried, log_weights), (paths, fields, stamps, step_cov))
    state = ParticleState(t=t + 1, paths=paths, fields=fields, stamps=stamps, offset=moved, log_weights=log_weights,
                          step_cov=step_cov, resamples=state.resamples + resampled.astype(jnp.int32),
                          log_evidence=state.log_evidence + gained)
    return state, ParticleInfo(ess=ess, resampled=resampled, evidence=evidence, trusted=trusted)


@functools.partial(jax.jit, donate_argnames=("state",), static_argnames=("grid", "half_width", "draw", "field_seed"),
                   compiler_options=MATCHER_COMPILER_OPTIONS)
def _steps(state, lo, hi, key, setup_arrays, grid, levels, lattice, widths, half_width, draw, field_seed):
    """:func:`step` over the scans ``lo <= t < hi`` from ``state`` (whose ``t`` is ``lo``), the key of scan ``t``
    ``fold_in(key, t)``."""
    setup = FrontEndSetup(*setup_arrays[:3], grid, *setup_arrays[3:])
    context = ParticleContext(setup, levels, lattice, widths, half_width, draw, field_seed)

    def body(t, state):
        return step(jax.random.fold_in(key, t), state, context)[0]

    return jax.lax.fori_loop(lo, hi, body, state)


class ParticlePath(NamedTuple):
    """:func:`particle_path`'s result.

    Attributes:
        matched: the heaviest particle's path and step covariances, as the single-track front end returns them
            (:class:`bayesmap.slam.scanmatch.MatchedPath`).
        paths: ``(N, S, 3)`` float64, every particle's path (its ancestors' before each resampling).
        log_weights: ``(N,)`` float64, their normalized log weights.
        resamples: how many times the particles were resampled.
        log_evidence: the filter's estimate of the log of its target's normalizing constant
            (:class:`ParticleState`).
    """

    matched: MatchedPath
    paths: np.ndarray
    log_weights: np.ndarray
    resamples: int
    log_evidence: float


def particle_path(first_pose, data: ScanData, resolution: float, particles: int, seed: int = 0,
                  draw: bool = False, levels=MATCH_LEVELS, window: float | None = LOCAL_MAP_DISTANCE,
                  half_width: float = MATCH_GRID_HALF_WIDTH, likelihood_power: float = 1.0,
                  min_hit_fraction: float = MIN_HIT_FRACTION,
                  progress: ProgressCallback | None = None, motion_tail: float = MOTION_TAIL_WEIGHT,
                  motion: MotionParams | None = None, field_seed: bool = FIELD_SEED) -> ParticlePath:
    """Sequential Monte Carlo over the front end's path (the module docstring) with ``particles`` particles.

    Args:
        first_pose: ``(3,)`` the fixed first pose (x m, y m, theta rad).
        data: the scans and odometry (:class:`bayesmap.slam.scanmatch.ScanData`).
        resolution: the fields' cell size, meters.
        particles: ``N >= 1``; memory grows by about 30 MB a particle (a particle's fields on a 0.05 m grid of
            +-40 m), time about linearly on a CPU.
        seed: the random seed (``jax.random.key(seed)``; scan ``t``'s key is ``fold_in(key, t)``).
        draw: True: each pose a draw from the step's lattice density; False (the default): the match itself, the
            particles then differing by the basins their searches found (on every other scan of ACES and CSAIL,
            odometry seeds 0-4, the start path's ATE was lower with False on 7 of 10 runs;
            [validation](../validation/slam.md#several-hypotheses-in-the-front-end)).
        levels: the coarse-to-fine search (:data:`bayesmap.slam.scanmatch.MATCH_LEVELS`).
        window: meters of travel of each particle's local map (:data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE`;
            None: every earlier scan).
        half_width: meters, the fields' half width (:data:`bayesmap.slam.scanmatch.MATCH_GRID_HALF_WIDTH`).
        likelihood_power: ``p`` in (0, 1], the field score's power against the motion model.
        min_hit_fraction: a match that puts fewer of the scan's endpoints on the particle's local map is not
            trusted (:data:`bayesmap.slam.scanmatch.MIN_HIT_FRACTION`).
        progress: called with ``Progress("front end", done, S - 1, "scan")`` as blocks of scans are matched (the
            same result); None: one call.
        motion_tail: the weight of the motion density's broad component, as
            :func:`bayesmap.slam.scanmatch.correlative_path` (:data:`bayesmap.slam.scanmatch.MOTION_TAIL_WEIGHT`).
        motion: the motion noise that sets that component's covariance, as there.
        field_seed: the search's, as there (:data:`bayesmap.slam.scanmatch.FIELD_SEED`).

    Returns:
        A :class:`ParticlePath`.

    Raises:
        BayesmapError: as :func:`bayesmap.slam.scanmatch.correlative_path`, or if ``particles`` is not an integer
            >= 1.
    """
    if isinstance(particles, bool) or not isinstance(particles, (int, np.integer)) or particles < 1:
        raise BayesmapError(f"particles must be an integer >= 1, got {particles!r}")
    setup = front_end_setup(first_pose, data, resolution, window, half_width, likelihood_power, min_hit_fraction,
                            motion_tail, motion)
    context = ParticleContext(setup, lattices(levels), step_lattice(), step_cell_widths(), float(half_width),
                              bool(draw), bool(field_seed))
    count = data.readings.shape[0]
    key = jax.random.key(seed)
    arrays = (*setup[:3], *setup[4:])
    run = functools.partial(_steps, key=key, setup_arrays=arrays, grid=setup.grid, levels=context.levels,
                            lattice=context.lattice, widths=context.widths, half_width=context.half_width,
                            draw=context.draw, field_seed=context.field_seed)

    def start():
        return jax.tree_util.tree_map(jnp.array, init(context, int(particles)))  # its own buffers: the loop donates

    state = run_in_blocks(run, start, count, progress)
    log_weights = np.asarray(state.log_weights, np.float64)
    paths = np.asarray(state.paths, np.float64)
    best = int(np.argmax(log_weights))
    matched = MatchedPath(paths[best], np.asarray(state.step_cov[best], np.float64)[1:],
                          hypotheses(paths, log_weights))
    return ParticlePath(matched, paths, log_weights, int(state.resamples), float(state.log_evidence))


def hypotheses(paths, log_weights, distance: float = HYPOTHESIS_DISTANCE,
               min_weight: float = HYPOTHESIS_WEIGHT) -> int:
    """How many distinct paths of ``paths`` ``(N, S, 3)`` carry at least ``min_weight`` of the weight
    (``log_weights`` ``(N,)`` normalized): the particles grouped greedily, heaviest first, by final positions within
    ``distance`` meters of the group's first (:data:`HYPOTHESIS_DISTANCE`, :data:`HYPOTHESIS_WEIGHT`)."""
    ends = np.asarray(paths)[:, -1, :2]
    weights = np.exp(np.asarray(log_weights, np.float64))
    left = list(np.argsort(-weights))
    count = 0
    while left:
        head = left[0]
        group = [k for k in left if np.hypot(*(ends[k] - ends[head])) <= distance]
        count += int(weights[group].sum() >= min_weight)
        left = [k for k in left if k not in group]
    return count
