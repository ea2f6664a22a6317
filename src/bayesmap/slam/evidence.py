"""The SLAM target at a path with the walls integrated out: how strongly the model prefers one whole path to another.

The SLAM target (:data:`bayesmap.model.slam.slam_model`, the readings tempered by the problem's likelihood power
``p``; docs/slam.md) is ``log p(x | u) + log p(w) + p log p(y | w, x)`` for a path ``x`` and walls ``w``. Two paths
are weighed by the target's marginal over the walls, ``log sum_w exp(target)``, which no one can sum over ``2^cells``
maps. :func:`path_evidence` bounds it from below (the evidence lower bound, Jordan et al. 1999):

    ``log p(x, y) >= E_q[log p(x | u) + log p(w) + p log p(y | w, x)] + H(q)``

with ``q`` the independent cells at the wall probabilities of a short cellwise Gibbs chain at ``x``
(:func:`drawn_walls`), the readings' expectation under ``q`` estimated by the chain's last draw
(:func:`map_entropy_bound`). The target at one drawn map alone does not weigh two paths: a path whose map is less
certain draws a map of lower density, which the map's entropy makes up for
([validation](../validation/slam.md#the-targets-own-preference-the-truth-or-the-start-path)).

The bound needs the chain's map model, the independent prior (``coupling`` 0).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.cellwise import SweepShapes
from bayesmap.inference.tiled import TILE_PAIRS, TiledChain, tiled_map_chain
from bayesmap.model.motion import path_logpdf
from bayesmap.model.prior import log_prior
from bayesmap.problem import Problem
from bayesmap.progress import ProgressCallback

_path_logpdf = jax.jit(path_logpdf)  # (one compilation, where the operations one by one compile each its own)
_log_prior = jax.jit(log_prior)


def scans_at(problem, params, path) -> tuple[np.ndarray, Problem]:
    """``(path (S, 3), scans)``: ``path`` with its headings unwrapped (the motion model's heading is a real number)
    and the scans of ``problem`` (a :class:`bayesmap.slam.problem.SlamProblem`) at it as a known-pose
    :class:`bayesmap.problem.Problem` on ``params``' grid (their world-frame rays, which the map's draws and its
    score both read)."""
    path = _unwrapped(path)
    angles = path[:, 2:3] + problem.sensor_angles
    return path, Problem.from_world_frame(params, path[:, :2], angles, problem.readings)


def _unwrapped(path) -> np.ndarray:
    path = np.array(path, np.float64)
    path[:, 2] = np.unwrap(path[:, 2])
    return path


def target_log_density(problem, params, path, walls) -> tuple[float, float, float]:
    """``(target, motion, p readings)``: the target's log-density (nats) at ``path`` ``(S, 3)`` (x m, y m,
    theta rad) and ``walls`` ``(nx, ny)`` on ``params``' grid: the motion model's log-density of the path, the
    prior's of the walls and the problem's power ``p`` times the readings' (at ``p = 1``, the SLAM model's
    ``assess``)."""
    path, scans = scans_at(problem, params, path)
    motion, prior = _motion_and_prior(problem, params, path, walls)
    readings = problem.likelihood_power * (scans.table_log_joint(walls) - prior)
    return motion + prior + readings, motion, readings


def _motion_and_prior(problem, params, path, walls) -> tuple[float, float]:
    """The motion model's log-density of ``path`` ``(S, 3)`` (headings unwrapped) and the prior's of ``walls``."""
    increments, covs = problem.motion_steps()
    motion = float(_path_logpdf(jnp.asarray(path), jnp.asarray(path[0]), jnp.asarray(increments), jnp.asarray(covs)))
    return motion, float(_log_prior(np.asarray(walls), params.prior_wall_prob, params.coupling))


def drawn_map(problem, params, path, key, sweeps: int, tile_pairs: int = TILE_PAIRS,
              shapes: SweepShapes | None = None, headroom: float = 0.0,
              progress: ProgressCallback | None = None) -> TiledChain:
    """The walls drawn by ``sweeps`` cellwise sweeps from an empty map at ``path`` ``(S, 3)`` (x m, y m, theta rad)
    with the chain's map model (``params``' grid, the problem's power; in tiles of at most ``tile_pairs`` pairs,
    :func:`bayesmap.inference.tiled.tiled_map_chain`, whose ``shapes`` and ``headroom`` let draws at other paths
    share one compiled sweep), random key ``key``: the joint chain's first map block at that path
    (:func:`bayesmap.slam.pipeline.run_log_slam` takes the chosen start's draw as its own). Returns the chain
    (:class:`bayesmap.inference.tiled.TiledChain`: its last walls ``(nx, ny)`` float32, each sweep's wall
    probabilities ``(sweeps, nx, ny)``, the sizes its sweep was compiled for). ``progress`` gets
    ``Progress("evidence", done, sweeps, "sweep")``; the sweeps then run one per compiled call, as a chain's that
    reports (the same draw, bit for bit).

    Raises:
        BayesmapError: as :func:`bayesmap.inference.tiled.tiled_map_chain` (``sweeps`` < 1, ``tile_pairs`` < 1).
    """
    _, scans = scans_at(problem, params, path)
    return tiled_map_chain(key, params, scans.ray_origins, scans.ray_angles, scans.ray_readings,
                           jnp.zeros(params.grid.shape, jnp.float32), sweeps, problem.likelihood_power,
                           max_pairs=tile_pairs, shapes=shapes, headroom=headroom, progress=progress,
                           stage="evidence")


def drawn_walls(problem, params, path, key, sweeps: int, tile_pairs: int = TILE_PAIRS,
                shapes: SweepShapes | None = None, headroom: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``(walls (nx, ny), probabilities (nx, ny) float64)`` of :func:`drawn_map` (the same arguments): the last
    walls, and each cell's wall probability averaged over the second half of the sweeps (its conditional
    probability at each)."""
    chain = drawn_map(problem, params, path, key, sweeps, tile_pairs, shapes, headroom)
    return _walls_and_probabilities(chain)


def _walls_and_probabilities(chain: TiledChain) -> tuple[np.ndarray, np.ndarray]:
    sweeps = len(chain.wall_probs)
    return np.asarray(chain.walls), np.asarray(chain.wall_probs, np.float64)[sweeps // 2:].mean(axis=0)


def map_entropy_bound(params, probabilities, target: float, walls) -> float:
    """The evidence lower bound of ``log p(path, readings)`` (tempered) with the walls integrated out under the
    factorized ``q`` of each cell's wall ``probabilities`` ``(nx, ny)``: ``target`` (:func:`target_log_density` at
    the drawn ``walls``) with the prior's log-probability of the draw replaced by its expectation under ``q``, plus
    ``q``'s entropy (nats). The readings' term stays that of the one draw. A cell that no beam reaches has ``q`` at
    the prior and adds nothing, so the bound does not depend on how far the grid reaches past the beams."""
    q = np.clip(np.asarray(probabilities, np.float64), 1e-9, 1 - 1e-9)
    pi = params.prior_wall_prob
    drawn = float(_log_prior(np.asarray(walls), pi, 0.0))
    expected = float(np.sum(q * np.log(pi) + (1 - q) * np.log1p(-pi)))
    entropy = float(-np.sum(q * np.log(q) + (1 - q) * np.log1p(-q)))
    return target - drawn + expected + entropy


def path_evidence(key, problem, params, path, sweeps: int, tile_pairs: int = TILE_PAIRS,
                  shapes: SweepShapes | None = None, headroom: float = 0.0) -> tuple[float, SweepShapes | None]:
    """The lower bound (nats) of the target's log-marginal at ``path`` ``(S, 3)`` (x m, y m, theta rad) with the
    walls integrated out (module docstring): ``sweeps`` cellwise sweeps from an empty map on ``params``' grid
    (:func:`drawn_map`, random key ``key``; ``tile_pairs``, ``shapes`` and ``headroom`` as there), scored by
    :func:`draw_evidence`. Two paths of the same scans compare by it on any grids that hold their beams.

    Returns:
        ``(bound, shapes)``: the bound and the sizes its sweep was compiled for (to pass to the next path's; with
        tiles, the last tile's).

    Raises:
        BayesmapError: if ``params`` has a coupled prior (the bound is for independent cells) or ``sweeps`` < 2.
    """
    check_evidence_arguments(params, sweeps)
    chain = drawn_map(problem, params, path, key, int(sweeps), tile_pairs, shapes, headroom)
    return draw_evidence(problem, params, path, chain), chain.shapes


def check_evidence_arguments(params, sweeps) -> None:
    """Raise :class:`~bayesmap.errors.BayesmapError` naming the value if ``params`` has a coupled prior (the bound
    of :func:`path_evidence` is for independent cells) or ``sweeps`` is not an integer >= 2."""
    if params.coupling:
        raise BayesmapError(f"the path's evidence needs the independent prior, got coupling {params.coupling!r}")
    if isinstance(sweeps, bool) or not isinstance(sweeps, (int, np.integer)) or sweeps < 2:
        raise BayesmapError(f"the path's evidence needs sweeps >= 2, got {sweeps!r}")


def draw_evidence(problem, params, path, chain: TiledChain) -> float:
    """:func:`path_evidence`'s bound (nats) from ``chain``, a :func:`drawn_map` of at least 2 sweeps at ``path``
    ``(S, 3)`` on ``params``' grid: :func:`map_entropy_bound` of its wall probabilities averaged over the second
    half of its sweeps and the target at its last walls (:func:`target_log_density`; its readings' term the one
    the chain's sweep computed, :attr:`bayesmap.inference.tiled.TiledChain.readings_log_lik`, where it has one: no
    second table, the same to the kernel's float precision)."""
    walls, probabilities = _walls_and_probabilities(chain)
    if chain.readings_log_lik is None:
        target, _, _ = target_log_density(problem, params, path, walls)
    else:
        motion, prior = _motion_and_prior(problem, params, _unwrapped(path), walls)
        target = motion + prior + chain.readings_log_lik
    return map_entropy_bound(params, probabilities, target, walls)
