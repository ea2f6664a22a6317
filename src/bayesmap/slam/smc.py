"""Sequential Monte Carlo over the path and the map together, for small problems: resample-move SMC on the SLAM
model's data-tempered targets.

The chain of :mod:`bayesmap.slam.joint` moves one state about; where the readings leave two paths (and their maps)
about equally probable, it visits one and then, much later if ever, the other. A population of particles, each a
whole path and a whole map, weighted by the model, keeps both. The targets are the SLAM model's
(:data:`bayesmap.model.slam.slam_model`) with the readings of scan ``s`` counted at a power ``lambda_{k,s}``:

    pi_k(poses, walls)  ~  p(poses | odometry) p(walls) prod_s p(readings_s | walls, pose_s) ** lambda_{k,s},

the scans added one at a time (``lambda`` 0 for a scan not yet added, ``eta`` once it is): by the rows of a fixed
schedule (:func:`scan_schedule`; ``substeps`` rows per scan raise its power in equal steps), or adaptively, each stage
raising the current scan's power as far as leaves half the particles' effective sample size (:func:`slam_smc`).
``pi_{-1}`` is the prior and the last row the posterior (``eta = 1``) or the tempered posterior. A stage
(:func:`slam_smc`'s ``step``) goes from ``pi_{k-1}`` to ``pi_k``:

1. *reweight*: each particle's log-weight gains ``sum_s (lambda_{k,s} - lambda_{k-1,s}) log p(readings_s | walls,
   pose_s)``, the ratio ``pi_k / pi_{k-1}`` at the particle (no proposal: the poses of scans not yet added are already
   in the particle, distributed as the motion model says given the earlier ones, since ``pi_{k-1}`` does not look at
   their readings);
2. *resample* (systematic) when the effective sample size ``1 / sum_i W_i^2`` falls below ``resample_ess`` times the
   number of particles;
3. *move* every particle by a kernel that leaves ``pi_k`` invariant, ``num_moves`` times: the joint kernel of
   :func:`bayesmap.slam.joint.slam_kernel` at the powers ``lambda_k`` (its pose kernel draws each pose from its exact
   conditional, its map sweep each cell; a scan at power 0 enters neither).

This is the resample-move algorithm (Gilks & Berzuini 2001) on data-tempered targets (Chopin 2002, "A sequential
particle filter method for static models"), in the framework of Del Moral, Doucet & Jasra 2006. It is exact in the
sense of every SMC sampler: the weighted particles' averages converge to ``pi_k``'s expectations as the number of
particles grows, and with a fixed schedule the product of the stages' mean incremental weights, ``exp(log_evidence)``,
is an unbiased estimate of the normalizing constant ``p(readings)`` of the last target (of ``Z_k / Z_{-1}`` with
``Z_{-1}`` the prior's mass under the initial particles' weights), as is ``exp(log_evidence) sum_i W_i f(particle_i)``
of ``Z_k E_{pi_k}[f]`` (Del Moral 2004; for adaptive resampling, Whiteley, Lee & Heine 2016). The tests check both
against exact enumeration of a tiny problem.

The particles are ``vmap``-ed: memory is the number of particles times one path and one map (and the joint kernel's
dense ray-cell table). Starting from the prior, a scan whose beams are precise needs many stages: on the tutorial
scene (100 beams of 0.2 m noise a scan) the adaptive schedule had raised the first scan's power to 0.10 after 30
stages, so a building, or even the tutorial scene, is beyond it (docs/slam.md, "Several hypotheses").
"""

from __future__ import annotations

import functools
import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.base import SamplingAlgorithm
from bayesmap.inference.importance import effective_sample_size
from bayesmap.model.generative import check_likelihood_power
from bayesmap.model.motion import sample_path
from bayesmap.slam.particles import systematic_resample
from bayesmap.slam.poses import SlamData, scans_log_likelihood

TARGET_ESS = 0.5
"""The adaptive schedule's effective sample size after each stage's reweighting, as a fraction of the particles
(half: the usual choice of adaptive tempering, e.g. BlackJAX's ``adaptive_tempered_smc`` examples)."""

RESAMPLE_ESS = 0.5
"""Resample when the effective sample size falls below this fraction of the particles (Doucet & Johansen 2009,
sec. 3.5: the usual rule; resampling at every stage also leaves the estimates consistent, with more variance)."""


class SmcState(NamedTuple):
    """The particle population after ``stage`` stages.

    Attributes:
        stage: int32 scalar, the stages done (0 after ``init``: the particles target the prior).
        powers: ``(S,)`` float, the per-scan powers ``lambda`` of the target the particles are weighted for.
        poses: ``(N, S, 3)`` every particle's path (x m, y m, theta rad; pose 0 fixed).
        walls: ``(N, nx, ny)`` float32 of 0.0 / 1.0, every particle's map.
        log_weights: ``(N,)`` normalized log-weights (their ``logsumexp`` is 0).
        log_evidence: float scalar, the log of the estimate of ``Z_stage / Z_{-1}`` (module docstring).
        done: bool scalar, the powers are the last target's.
    """

    stage: jax.Array
    powers: jax.Array
    poses: jax.Array
    walls: jax.Array
    log_weights: jax.Array
    log_evidence: jax.Array
    done: jax.Array


class SmcInfo(NamedTuple):
    """What a stage reports: ``ess`` (float scalar, the effective sample size after reweighting, before resampling),
    ``resampled`` (bool scalar), ``log_increment`` (float scalar, the log of the stage's mean incremental weight)
    and ``acceptance`` (float scalar, the pose kernel's mean acceptance over the particles' moves)."""

    ess: jax.Array
    resampled: jax.Array
    log_increment: jax.Array
    acceptance: jax.Array


def scan_schedule(num_scans: int, likelihood_power: float = 1.0, substeps: int = 1) -> np.ndarray:
    """The per-scan powers of the data-tempered targets that add the scans one at a time.

    Args:
        num_scans: ``S >= 1``.
        likelihood_power: ``eta`` in (0, 1], the last target's power of every scan (1: the posterior).
        substeps: ``>= 1`` rows per scan: scan ``t``'s power rises ``eta / substeps`` a row.

    Returns:
        ``(S substeps, S)`` float64: row ``k`` the powers ``lambda_k`` of target ``pi_k``; scan ``t`` at 0 before its
        rows, at ``eta`` after; the last row ``eta`` everywhere.

    Raises:
        BayesmapError: on ``num_scans < 1``, ``substeps < 1`` or a bad ``likelihood_power``.
    """
    eta = check_likelihood_power(likelihood_power)
    if int(num_scans) != num_scans or num_scans < 1 or int(substeps) != substeps or substeps < 1:
        raise BayesmapError(f"scan_schedule needs num_scans >= 1 and substeps >= 1, got {num_scans!r}, {substeps!r}")
    rows = []
    for t in range(int(num_scans)):
        for j in range(1, int(substeps) + 1):
            row = np.where(np.arange(num_scans) < t, eta, 0.0)
            row[t] = eta * j / substeps
            rows.append(row)
    return np.asarray(rows, np.float64)


def prior_particles(key, first_pose, data: SlamData, num: int) -> tuple[jax.Array, jax.Array]:
    """``num`` exact draws from the SLAM model's prior: each path from the motion model
    (:func:`bayesmap.model.motion.sample_path` from ``first_pose`` ``(3,)``), each map's cells independent walls with
    the prior wall probability. The start of :func:`slam_smc` for poses that take continuous values (log-weights 0).

    Returns:
        ``(poses (num, S, 3), walls (num, nx, ny) float32)``.

    Raises:
        BayesmapError: on ``num < 1``, or a structured prior (whose draws are not independent cells).
    """
    if int(num) != num or num < 1:
        raise BayesmapError(f"need at least one particle, got {num!r}")
    params = data.params
    if params.structured:
        raise BayesmapError("prior_particles draws the independent prior only; got a structured prior "
                            f"(coupling {params.coupling!r})")
    k_path, k_walls = jax.random.split(key)
    poses = jax.vmap(lambda k: sample_path(k, first_pose, data.increments, data.covs))(
        jax.random.split(k_path, int(num)))
    walls = jax.random.bernoulli(k_walls, params.prior_wall_prob, (int(num), *params.grid.shape))
    return poses, walls.astype(jnp.float32)


def slam_smc(data: SlamData, move: Callable[[jax.Array], SamplingAlgorithm], schedule=None,
             likelihood_power: float = 1.0, target_ess: float = TARGET_ESS, num_moves: int = 1,
             resample_ess: float = RESAMPLE_ESS) -> SamplingAlgorithm:
    """Resample-move SMC over paths and maps (the module docstring).

    Args:
        data: the odometry, sensor angles ``(S, K)``, readings ``(S, K)`` and parameters
            (:func:`bayesmap.slam.poses.slam_data`).
        move: ``move(powers (S,)) -> SamplingAlgorithm`` over :class:`bayesmap.slam.joint.SlamState`, a kernel that
            leaves the target at those per-scan powers invariant; called inside ``jit`` with traced powers. For
            example ``lambda powers: slam_kernel(data, discrete_pose_gibbs(data, candidates, powers), powers)``.
        schedule: ``(K, S)`` per-scan powers, row ``k`` the target after stage ``k`` (:func:`scan_schedule`); each
            row at least the one before it, entries in [0, 1]. None: adaptive, the scans added in order, each
            stage raising the current scan's power by as much as leaves ``target_ess`` of the particles' effective
            sample size (found by bisection; Jasra, Stephens, Doucet & Tsagaris 2011), up to ``likelihood_power``.
            A fixed schedule keeps ``exp(log_evidence)`` unbiased; the adaptive one is consistent, with a bias that
            vanishes as the particles grow, and needs no schedule to be tuned to how informative the scans are.
        likelihood_power: ``eta`` in (0, 1], the adaptive schedule's final power of every scan.
        target_ess: in (0, 1), the adaptive schedule's effective sample size per stage, as a fraction of the
            particles.
        num_moves: ``>= 0`` kernel steps per particle per stage.
        resample_ess: in [0, 1]: resample when the effective sample size is below this fraction of the particles
            (1: every stage; 0: never).

    Returns:
        A :class:`bayesmap.inference.base.SamplingAlgorithm`: ``init(poses (N, S, 3), walls (N, nx, ny),
        log_weights (N,) or None) -> SmcState`` (``log_weights``: the particles' importance weights for the prior,
        ``log p(path) + log p(walls) - log q`` for draws from ``q``; None: exact prior draws,
        :func:`prior_particles`) and ``step(key, SmcState) -> (SmcState, SmcInfo)`` (one stage; pure and jittable;
        a stage after the last target reweights nothing and only moves the particles). :func:`run_smc` runs the
        stages to the last target.

    Raises:
        BayesmapError: on a schedule that is not ``(K, S)``, not in [0, 1] or decreasing down a column, a bad
            ``likelihood_power`` or ``target_ess``, a negative ``num_moves``, a ``resample_ess`` outside [0, 1] or,
            adaptive, below ``target_ess``.
    """
    num_scans = data.sensor_angles.shape[0]
    dtype = jnp.result_type(float)
    if schedule is None:
        eta = check_likelihood_power(likelihood_power)
        if not 0.0 < float(target_ess) < 1.0:
            raise BayesmapError(f"target_ess must be in (0, 1), got {target_ess!r}")
        if float(resample_ess) < float(target_ess):  # else a stage could start below the target and never advance
            raise BayesmapError(f"the adaptive schedule needs resample_ess >= target_ess, got {resample_ess!r} < "
                                f"{target_ess!r}")
        final = np.full(num_scans, eta)
        advance = functools.partial(_adaptive_powers, jnp.asarray(final, dtype), float(target_ess))
    else:
        table = np.asarray(schedule, np.float64)
        if table.ndim != 2 or table.shape[1] != num_scans or table.shape[0] < 1:
            raise BayesmapError(f"schedule must be (K, S) = (K, {num_scans}) with K >= 1, got shape {table.shape}")
        if (not np.all(np.isfinite(table)) or table.min() < 0 or table.max() > 1
                or np.any(np.diff(table, axis=0) < 0)):
            raise BayesmapError("schedule must hold powers in [0, 1] that never decrease from one row to the next")
        final = table[-1]
        advance = functools.partial(_scheduled_powers, jnp.asarray(table, dtype))
    if int(num_moves) != num_moves or num_moves < 0:
        raise BayesmapError(f"num_moves must be an integer >= 0, got {num_moves!r}")
    if not 0.0 <= float(resample_ess) <= 1.0:
        raise BayesmapError(f"resample_ess must be in [0, 1], got {resample_ess!r}")
    # closures, not pytrees: ``move`` is a Python function, and the arrays are constants of the compiled stage
    step = functools.partial(_step, data, move, advance, jnp.asarray(final, dtype), int(num_moves),
                             float(resample_ess))
    return SamplingAlgorithm(init=functools.partial(_init, num_scans), step=step)


def _init(num_scans, poses, walls, log_weights=None) -> SmcState:
    poses = jnp.asarray(poses, jnp.result_type(float))
    num = poses.shape[0]
    lw = jnp.zeros(num, poses.dtype) if log_weights is None else jnp.asarray(log_weights, poses.dtype)
    total = jax.nn.logsumexp(lw)
    return SmcState(stage=jnp.int32(0), powers=jnp.zeros(num_scans, poses.dtype), poses=poses,
                    walls=(jnp.asarray(walls) > 0).astype(jnp.float32), log_weights=lw - total,
                    log_evidence=total - math.log(num), done=jnp.bool_(False))


def _scheduled_powers(table, state: SmcState, like):
    """The fixed schedule's next row (its last once past it)."""
    return table[jnp.minimum(state.stage, table.shape[0] - 1)]


def _adaptive_powers(final, target_ess, state: SmcState, like, iterations: int = 40):
    """The adaptive schedule's next powers: the first scan below its final power raised by the largest step (at
    most to its final power) whose reweighting leaves ``target_ess`` of the particles' effective sample size, by
    bisection on the step (the ESS falls as the step grows)."""
    num = state.log_weights.shape[0]
    below = state.powers < final
    t = jnp.argmax(below)
    room = jnp.where(jnp.any(below), final[t] - state.powers[t], 0.0)
    scan_like = like[:, t]

    def ess_fraction(step):
        return effective_sample_size(state.log_weights + jnp.where(step > 0, step * scan_like, 0.0)) / num

    def bisect(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        ok = ess_fraction(mid) >= target_ess
        return jnp.where(ok, mid, lo), jnp.where(ok, hi, mid)

    lo, _ = jax.lax.fori_loop(0, iterations, bisect, (jnp.zeros_like(room), room))
    whole = ess_fraction(room) >= target_ess
    raised = jnp.where(whole, final[t], state.powers[t] + jnp.maximum(lo, room * 2.0**-iterations))  # final exactly
    return state.powers.at[t].set(jnp.where(room > 0, raised, state.powers[t]))


def _step(data, move, advance, final, num_moves, resample_ess, key, state: SmcState) -> tuple[SmcState, SmcInfo]:
    """:func:`slam_smc`'s stage ``state.stage`` -> ``state.stage + 1``: reweight, resample, move."""
    num = state.log_weights.shape[0]
    params = data.params
    like = jax.vmap(lambda poses, walls: scans_log_likelihood(walls, poses, data.sensor_angles, data.readings,
                                                              params))(state.poses, state.walls)  # (N, S)
    now = advance(state, like)
    delta = now - state.powers
    # the added powers times each scan's log-likelihood; 0 where a power is unchanged
    increment = jnp.sum(jnp.where(delta > 0, delta * like, 0.0), axis=1)
    log_weights = state.log_weights + increment
    gained = jax.nn.logsumexp(log_weights)  # log sum_i W_i exp(increment_i): the stage's mean incremental weight
    ess = effective_sample_size(log_weights)
    log_weights = log_weights - gained
    k_resample, k_move = jax.random.split(key)
    resampled = ess < resample_ess * num

    def resample(carried):
        ancestors = systematic_resample(k_resample, carried[2])
        return carried[0][ancestors], carried[1][ancestors], jnp.full(num, -math.log(num), log_weights.dtype)

    poses, walls, log_weights = jax.lax.cond(resampled, resample, lambda carried: carried,
                                             (state.poses, state.walls, log_weights))
    kernel = move(now)

    def move_one(k, poses, walls):
        def body(st, k):
            st, info = kernel.step(k, st)
            return st, jnp.mean(info.accepted.astype(poses.dtype))

        st, accepted = jax.lax.scan(body, kernel.init(poses, walls), jax.random.split(k, num_moves))
        return st.poses, st.walls, jnp.mean(accepted) if num_moves else jnp.asarray(1.0, poses.dtype)

    poses, walls, accepted = jax.vmap(move_one)(jax.random.split(k_move, num), poses, walls)
    state = SmcState(stage=state.stage + 1, powers=now, poses=poses, walls=walls, log_weights=log_weights,
                     log_evidence=state.log_evidence + gained, done=jnp.all(now >= final))
    return state, SmcInfo(ess=ess, resampled=resampled, log_increment=gained, acceptance=jnp.mean(accepted))


def run_smc(key, algorithm: SamplingAlgorithm, initial: SmcState, max_stages: int) -> tuple[SmcState, SmcInfo]:
    """Stages of ``algorithm`` (:func:`slam_smc`) from ``initial`` until the particles target the last target, at
    most ``max_stages`` (a ``lax.while_loop``: jittable and ``vmap``-able; stage ``k``'s key ``fold_in(key, k)``).
    A fixed schedule takes its row count; an adaptive one as many as the scans need (check ``state.done``).

    Returns:
        ``(the last SmcState, SmcInfo of every stage)``, each info field with a leading ``(max_stages,)`` axis whose
        entries past ``state.stage`` are zeros.
    """
    max_stages = int(max_stages)
    if max_stages < 1:
        raise BayesmapError(f"max_stages must be at least 1, got {max_stages!r}")
    _, shapes = jax.eval_shape(algorithm.step, key, initial)
    infos = jax.tree_util.tree_map(lambda a: jnp.zeros((max_stages, *a.shape), a.dtype), shapes)

    def more(carry):
        state, _ = carry
        return (state.stage < max_stages) & ~state.done

    def body(carry):
        state, infos = carry
        k = state.stage
        state, info = algorithm.step(jax.random.fold_in(key, k), state)
        return state, jax.tree_util.tree_map(lambda buf, v: buf.at[k].set(v), infos, info)

    return jax.lax.while_loop(more, body, (initial, infos))
