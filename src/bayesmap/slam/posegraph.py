"""Loop closure and pose-graph optimization: the back end that turns the front end's drifting path into a globally
consistent start for the joint chain (graph SLAM: Lu & Milios 1997, "Globally consistent range scan alignment";
*Probabilistic Robotics* ch. 11; Karto's design, Konolige et al. 2010, "Efficient sparse pose adjustment").

* **Edges.** Each consecutive pair of the front end's path gives a sequential edge (the relative pose between
  them). A scan ``t`` whose estimate lies within :data:`LOOP_RADIUS` meters of an older scan ``s``
  (``t - s >= LOOP_GAP``) is matched (correlative scan matching, :func:`bayesmap.slam.scanmatch.search`, with
  the wide window :data:`LOOP_LEVELS`) against a local map of the scans ``s - LOOP_NEIGHBOURS .. s +
  LOOP_NEIGHBOURS`` within :data:`LOOP_MAP_TRAVEL` meters of travel at their estimates
  (:func:`local_map_neighbours`); if at least :data:`LOOP_MIN_HIT_FRACTION` of its returned beams land on that
  map, the match gives a loop edge ``s -> t``. In the first round, before any loop ties the path, the window and the
  radius grow with the drift the sequential edges allow between ``s`` and ``t`` (:func:`loop_candidates`,
  :func:`chain_covariances`, :data:`LOOP_WINDOWS`).
* **Optimization.** The path minimizing ``sum rho(f^2)`` over the components ``f`` of the whitened residuals ``W
  (relative(x_i, x_j) - z_ij)`` of every edge, with the first pose fixed, ``W`` the edge's square-root information
  and ``rho`` the Cauchy loss (a false loop closure costs a bounded amount), by Levenberg-Marquardt on iteratively
  reweighted least squares with the analytic sparse Jacobian (:func:`optimize_pose_graph`).
* Detection and optimization alternate :data:`ROUNDS` times: each round's path finds the loops the previous one's
  drift hid.
* **Uncertainty.** The graph is also the Laplace approximation of the path's posterior with the map marginalized
  (Lu & Milios 1997; *Probabilistic Robotics* sec. 11.4): the whitened edge Jacobian ``J`` gives the information
  ``H = J^T J`` of the poses after the first, :func:`marginal_covariances` its inverse's ``3 x 3`` diagonal blocks
  and :func:`sample_deviations` draws ``N(0, H^-1)`` by perturb-and-solve (``H d = J^T eps``, ``eps ~ N(0, I)``;
  Papandreou & Yuille 2010), both by a sparse LU of ``H`` (docs/slam.md). Given :class:`LocalMaps`, each sequential
  edge's scan information is tied to the scans of the front end's local map it was matched against, its motion
  model's to the pose before.

The optimized path is a start for the joint chain only; the chain's target does not depend on it.
"""

from __future__ import annotations

import functools
import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.rosbag import compose_poses, invert_pose
from bayesmap.model.generative import check_likelihood_power
from bayesmap.model.motion import wrap_angle
from bayesmap.progress import ProgressCallback, report
from bayesmap.slam.scanmatch import (
    MATCHER_COMPILER_OPTIONS,
    Lattices,
    ScanData,
    add_to_fields,
    bound_span,
    empty_fields,
    hit_fraction,
    lattice_covariance,
    lattices,
    log_field,
    scan_logits,
    search,
    step_lattice,
)

LOOP_GAP = 30
"""Fewest scans between the two ends of a loop edge (closer scans are the sequential edges' business)."""

LOOP_RADIUS = 4.0
"""Meters: an older scan whose estimate is this close to scan ``t``'s is a loop candidate."""

LOOP_NEIGHBOURS = 10
"""Scans on each side of ``s`` that make the local map a loop candidate is matched against (every other one:
:data:`LOCAL_MAP_STEP`)."""

LOCAL_MAP_STEP = 2
"""Take every this many scans of ``s - LOOP_NEIGHBOURS .. s + LOOP_NEIGHBOURS`` into the local map (neighbouring
scans overlap almost entirely; half of them cost half as much)."""

LOOP_MAP_TRAVEL = 10.0
"""Meters of travel (the odometry's path length) on each side of ``s`` that a loop candidate's local map may span:
where the :data:`LOOP_NEIGHBOURS` scans on one side reach farther, that side's scans are spread over those within it
(:func:`local_map_neighbours`), since the front end's path is not rigid over more than its own local map's
:data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE`. ``inf``: no limit. Chosen among 5, 10, 20 m and no limit by
leave-one-log-out cross-validation of the start path's ATE, Intel, ACES and CSAIL, every scan's keyframes and every
other scan, seeds 0-4 ([validation](../validation/defaults.md#loop_map_travel))."""

LOOP_STRIDE = 3
"""Match only every this many scans ``t`` as loop candidates: a robot coming back stays near the old path for
several scans, each of which would give almost the same edge."""

LOOP_LEVELS = ((0.1, 0.03, 15, 7, 1), (0.03, 0.01, 3, 3, 0), (0.01, 0.0033, 2, 2, 0), (0.003, 0.001, 2, 2, 0))
"""The loop search (as :data:`bayesmap.slam.scanmatch.MATCH_LEVELS`): +-1.5 m and +-0.21 rad (12 degrees)
around the current estimate, down to 3 mm and 0.06 degrees."""

LOOP_WINDOWS = (1.5, 3.0, 6.0)
"""Meters: the half widths the first round's loop search can take (:func:`loop_levels`, :func:`loop_candidates`):
:data:`LOOP_LEVELS`' 1.5 m, or wider where the drift since the older scan may be larger. Doubling steps, so that a
few compiled searches serve every candidate; the widest bounds the search's time (its first lattice, 61 x 61
positions of 0.2 m, has 3.9 times the candidates of the other two, 31 x 31 positions of 0.1 or 0.2 m; the headings
are the same)."""

LOOP_WINDOW_SIGMAS = 2.5
"""How many standard deviations of a candidate's drift (:func:`chain_covariances`, the largest of its position's)
the first round's search window covers: the smallest of :data:`LOOP_WINDOWS` that is at least this many, else the
widest. Chosen among 0 (every window 1.5 m), 2.5 and 4 by leave-one-log-out cross-validation of the start path's ATE
over Intel, ACES and CSAIL, odometry seeds 0-4, every scan and every other scan (``benchmarks/front_end_cv.py
--parameter loop_window_sigmas``): two of the three folds choose 4, which gives the same path as 2.5 on all 30 runs,
and the smaller windows cost less search; [validation](../validation/defaults.md#loop_window_sigmas)."""

LOOP_MIN_HIT_FRACTION = 0.6
"""Least fraction of a candidate's returned beams that must land on the local map for a loop edge."""

LOCAL_MAP_HALF_WIDTH = 16.0
"""Half the side of a local map's square grid, meters (a laser sees about this far indoors)."""

LOCAL_MAP_RESOLUTION = 0.05
"""Cell size of the local maps, meters."""

SEQUENTIAL_STD = (0.03, 0.03, 0.01)
"""Standard deviations of a sequential edge (x m, y m, theta rad) where the front end's step posteriors are not
given (:func:`sequential_edges`; :func:`close_loops` without ``step_cov``): a typical error of the front end per
scan."""

LOOP_STD = (0.1, 0.1, 0.04)
"""Standard deviations of a loop edge (x m, y m, theta rad): twice (0.05 m, 0.05 m, 0.02 rad), chosen among 1, 2 and 4
times that by leave-one-log-out cross-validation of the start path's ATE after loop closure over Intel, ACES and
CSAIL (``benchmarks/loop_std_cv.py``; [validation](../validation/defaults.md#loop_std)). For the optimization and the
choice of loop edges; the path's uncertainty gives each loop edge its match's posterior instead
(:func:`loop_posteriors`)."""

CAUCHY_SCALE = 30.0
"""The Cauchy loss's scale, in standard deviations: residuals beyond it count less and less. Large, because a true
loop edge may disagree with the drifted path by meters (tens of standard deviations) before the optimization;
the loss only bounds what a gross false match can do."""

ROUNDS = 3
"""Rounds of loop detection and optimization."""

LOOP_GATE = 5.0
"""Standard deviations: after the robust optimization, a loop edge whose whitened residual norm exceeds this is
dropped and the graph optimized again without it (a false match: a corridor matched a metre along its axis fits
no consistent path). Five sigma of a 3-dimensional residual is far out (chi-square with 3 degrees of freedom
exceeds 25 with probability 1e-5), so true loops are kept."""

CONSISTENCY_GATE = 16.27
"""Squared Mahalanobis norm up to which two loop edges are consistent (:func:`pairwise_consistency`): the 99.9 %
quantile of the chi-square distribution with 3 degrees of freedom. Chosen among the 95, 99 and 99.9 % quantiles (7.81,
11.34, 16.27) by leave-one-log-out cross-validation of the start path's ATE over Intel, ACES and CSAIL, odometry seeds
0-4, every scan and every other scan (``benchmarks/front_end_cv.py --parameter consistency_gate``); the three agree
to 0.002 m in the mean; [validation](../validation/defaults.md#consistency_gate)."""

MAX_LOOP_SETS = 1000
"""Most maximal consistent sets of loop edges enumerated (:func:`consistent_sets`); past it the largest set found so
far stands for the largest, and the hypotheses are weighed among the sets found: a bound on the enumeration's time.
Intel, ACES and CSAIL have at most 16; Freiburg 079's keyframes (167 loop edges) reach it, in under 1 s a round."""

WEIGHED_LOOP_SETS = 16
"""The largest maximal consistent sets weighed as hypotheses (:func:`loop_hypotheses`), besides the empty set."""

MAX_ITERATIONS = 100
"""Most Levenberg-Marquardt iterations of one optimization (:func:`optimize_pose_graph`; the shared logs' graphs
converge in 4-6)."""

COST_TOLERANCE = 1e-10
"""An optimization stops when an iteration lowers the robust cost by less than this fraction of it."""

SOLVE_COLUMNS = 384
"""Right-hand sides per sparse solve in :func:`marginal_covariances` (bounds its memory to ``3 S x 384``)."""


SYMMETRIC_ORDERING = "MMD_AT_PLUS_A"
"""SuperLU's column ordering for the information matrix's LU in :func:`marginal_covariances` and
:func:`sample_deviations`: minimum degree on ``H + H^T``, suited to a symmetric matrix. With the sequential edges tied
to the front end's local maps (:class:`LocalMaps`) the marginals took 0.67 s against 1.27 s with SuperLU's default
(COLAMD) on Intel's 910 scans (odometry seed 1, the start path), 0.13 against 0.19 s on ACES's 440 and 0.16 against
0.10 s on CSAIL's 406 (the best of three, the machine otherwise idle)."""


class Edges(NamedTuple):
    """Edges of a pose graph: ``i``, ``j`` ``(E,)`` int node indices, ``z`` ``(E, 3)`` measured pose of ``j`` in
    ``i``'s frame (m, m, rad), ``std`` ``(E, 3)`` its standard deviations, ``whitening`` None (independent
    components: the square-root information is ``diag(1 / std)``) or ``(E, 3, 3)`` each edge's square-root
    information ``W``, ``W^T W = Sigma^-1`` for a full covariance ``Sigma`` (:func:`with_covariances`; ``std`` then
    the square roots of its diagonal)."""

    i: np.ndarray
    j: np.ndarray
    z: np.ndarray
    std: np.ndarray
    whitening: np.ndarray | None = None

    def take(self, index) -> Edges:
        """The edges ``index`` (an int array or a boolean mask over the edges)."""
        return Edges(*(None if a is None else np.asarray(a)[index] for a in self))


def whitening_matrices(edges: Edges) -> np.ndarray:
    """``(E, 3, 3)`` float64: each edge's square-root information ``W`` (``edges.whitening``, or ``diag(1 / std)``)."""
    if edges.whitening is not None:
        return np.asarray(edges.whitening, np.float64)
    std = np.asarray(edges.std, np.float64)
    return np.eye(3) / std[:, :, None] if std.size else np.zeros((0, 3, 3))


def with_covariances(edges: Edges, cov) -> Edges:
    """``edges`` with full covariances ``cov`` ``(E, 3, 3)`` (m^2, m rad, rad^2; each symmetric positive definite):
    ``W = L^-1`` for the Cholesky factor ``Sigma = L L^T``, ``std`` the square roots of the diagonal.

    Raises:
        BayesmapError: if ``cov`` is not ``(E, 3, 3)`` or a covariance is not finite and positive definite (the
            message names the first such edge).
    """
    cov = np.asarray(cov, np.float64)
    if cov.shape != (len(edges.i), 3, 3):
        raise BayesmapError(f"cov must have shape ({len(edges.i)}, 3, 3), got {cov.shape}")
    bad = ~np.isfinite(cov).all(axis=(1, 2))
    if bad.any():
        raise BayesmapError(f"edge {int(np.flatnonzero(bad)[0])}'s covariance is not finite")
    cov = (cov + np.swapaxes(cov, 1, 2)) / 2
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        first = int(np.argmin(np.linalg.eigvalsh(cov)[:, 0]))  # the least definite
        raise BayesmapError(f"edge {first}'s covariance is not positive definite") from None
    whitening = np.linalg.solve(chol, np.broadcast_to(np.eye(3), cov.shape))
    return edges._replace(std=np.sqrt(np.diagonal(cov, axis1=1, axis2=2)), whitening=whitening)


class LoopHypotheses(NamedTuple):
    """Hypotheses about which loop edges are true matches (:func:`loop_hypotheses`).

    Attributes:
        sets: the weighed hypotheses, each an ``(n,)`` int array of indices into the loop edges (sorted), the most
            probable first; the empty set (every loop edge a false match) is always among them.
        weights: ``(H,)`` float64 their posterior probabilities, normalized over ``sets`` (descending).
        enumerated: how many maximal consistent sets the consistency graph has (at most :data:`MAX_LOOP_SETS`).
        loops: the loop edges the sets index (:class:`Edges`).
    """

    sets: list
    weights: np.ndarray
    enumerated: int
    loops: Edges


class LocalMaps(NamedTuple):
    """What the front end matched each step's scan against, for the graph's uncertainty (:func:`marginal_covariances`,
    :func:`sample_deviations`; docs/slam.md, "The path's uncertainty").

    A step's posterior (:func:`bayesmap.slam.scanmatch.step_posterior`) is scan ``t``'s pose given its local map,
    the scans of the last :data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE` meters of travel at their poses, times
    the motion model from pose ``t - 1``. Its information is the
    motion model's plus the scan's; the motion model's ties pose ``t`` to pose ``t - 1``, the scan's to the scans of
    the local map: moving them moves the field it was matched in. So the graph splits each sequential edge's
    information in two: the motion model's (the inverse of ``motion_cov``, capped in every direction at the step's)
    on the step from pose ``t - 1``, and the rest on ``pose_t - sum_s w_ts pose_s`` to first order, each local-map
    scan ``s`` carrying pose ``t`` with it by its ``shares`` ``w_ts``. The two sum to the step's information; with
    every share on scan ``t - 1`` this is the plain sequential edge.

    Attributes:
        shares: ``(S - 1, S)`` scipy sparse, row ``t - 1`` the shares of step ``t``'s local-map scans, summing to 1
            (:func:`bayesmap.slam.scanmatch.local_map_shares`), each in a column ``< t``.
        motion_cov: ``(S - 1, 3, 3)`` the motion model's covariance of each step in the previous pose's frame
            (:attr:`bayesmap.slam.scanmatch.ScanData.covs`; m^2, m rad, rad^2); one that is not positive definite
            (a step the odometry fixes) adds no motion information.
    """

    shares: scipy.sparse.spmatrix
    motion_cov: np.ndarray


def relative(a, b) -> np.ndarray:
    """Pose ``b`` ``(..., 3)`` in the frame of pose ``a`` ``(..., 3)`` (numpy; theta wrapped to ``[-pi, pi)``)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    d = b[..., :2] - a[..., :2]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1],
                     wrap_angle(b[..., 2] - a[..., 2])], axis=-1)


def sequential_edges(path) -> Edges:
    """The edges ``t - 1 -> t`` of ``path`` ``(S, 3)`` with :data:`SEQUENTIAL_STD`."""
    path = np.asarray(path, np.float64)
    n = len(path) - 1
    return Edges(np.arange(n), np.arange(1, n + 1), relative(path[:-1], path[1:]),
                 np.tile(np.asarray(SEQUENTIAL_STD), (n, 1)))


def loop_levels(half_width: float) -> tuple:
    """The loop search's levels (as :data:`LOOP_LEVELS`) for a window of +-``half_width`` meters (one of
    :data:`LOOP_WINDOWS`): :data:`LOOP_LEVELS` for 1.5 m; wider, a first lattice of 0.2 m steps on the broad field
    (whose 0.2 m standard deviation spans them) and the same headings, then 0.1 m steps over +-0.2 m, then
    :data:`LOOP_LEVELS`' finer levels.

    Raises:
        BayesmapError: if ``half_width`` is not one of :data:`LOOP_WINDOWS`.
    """
    if half_width not in LOOP_WINDOWS:
        raise BayesmapError(f"half_width must be one of LOOP_WINDOWS {LOOP_WINDOWS}, got {half_width!r}")
    if half_width == LOOP_WINDOWS[0]:
        return LOOP_LEVELS
    _, theta, _, theta_steps, field = LOOP_LEVELS[0]
    return ((0.2, theta, int(round(half_width / 0.2)), theta_steps, field), (0.1, theta, 2, 1, field),
            *LOOP_LEVELS[1:])


def loop_candidates(path, sequential: Edges | None = None,
                    sigmas: float = LOOP_WINDOW_SIGMAS) -> tuple[np.ndarray, np.ndarray]:
    """The loop candidates of ``path`` ``(S, 3)`` and the half width of each one's search.

    For every :data:`LOOP_STRIDE`-th scan ``t``, the nearest scan ``s <= t - LOOP_GAP`` in ``path``. Without
    ``sequential``, it is a candidate within :data:`LOOP_RADIUS` meters, searched over +-1.5 m
    (:data:`LOOP_LEVELS`). With the graph's ``sequential`` edges (the first round, when nothing but the chain ties
    ``t`` to ``s``) and ``sigmas > 0``, the window is the smallest of :data:`LOOP_WINDOWS` that covers ``sigmas``
    standard deviations of ``t``'s position given ``s``'s (its drift: the square root of the largest eigenvalue of the
    position block of :func:`chain_covariances`; the widest window if none covers it), and ``s`` is a candidate within
    :data:`LOOP_RADIUS` plus that drift (at most the widest window): a long loop's drift can exceed 1.5 m, where the
    standard window would miss the place the scan was taken.

    Returns:
        ``(pairs (P, 2) int64, half_widths (P,) float64)``: the pairs ``(s, t)`` and each one's window (meters).

    Raises:
        BayesmapError: as :func:`chain_covariances`.
    """
    xy = np.asarray(path, np.float64)[:, :2]
    pairs, distances = [], []
    for t in range(LOOP_GAP, len(xy), LOOP_STRIDE):
        d = np.hypot(*(xy[: t - LOOP_GAP + 1] - xy[t]).T)
        s = int(np.argmin(d))
        pairs.append((s, t))
        distances.append(d[s])
    pairs, distances = np.asarray(pairs, np.int64).reshape(-1, 2), np.asarray(distances)
    drift = np.zeros(len(pairs))
    if sequential is not None and sigmas > 0 and len(pairs):
        cov = chain_covariances(sequential, pairs)
        drift = sigmas * np.sqrt(np.linalg.eigvalsh(cov[:, :2, :2])[:, -1])
    windows = np.asarray(LOOP_WINDOWS)
    fits = windows[None, :] >= drift[:, None]
    half_widths = np.where(fits.any(axis=1), windows[np.argmax(fits, axis=1)], windows[-1])
    near = distances < LOOP_RADIUS + np.minimum(drift, windows[-1])
    return pairs[near], half_widths[near]


def local_map_grid() -> Grid:
    """The square grid of a local map (:func:`match_to_local_maps`): +-:data:`LOCAL_MAP_HALF_WIDTH` meters around
    its center (the origin), cells of :data:`LOCAL_MAP_RESOLUTION`."""
    n = int(round(2 * LOCAL_MAP_HALF_WIDTH / LOCAL_MAP_RESOLUTION))
    return Grid(shape=(n, n), resolution=LOCAL_MAP_RESOLUTION, origin=(-LOCAL_MAP_HALF_WIDTH, -LOCAL_MAP_HALF_WIDTH))


class LoopMatches:
    """The loop matches one path's loop closure made, kept so that another path's loop closure of the same scans
    takes those whose every input is the same to the bit instead of searching again: the matched scan, its window,
    the local map's scans and their poses, and the search's start and center (:func:`match_loops`). A match is a
    deterministic function of those inputs, so a loop closure that reads them gives the same path as one that
    searches (tested). The start's other hypotheses (:func:`bayesmap.slam.pipeline.branched_start`) share the path
    before their branch point with the single track, and with it the first round's matches among those scans.

    Attributes:
        found: how many matches were taken from the memo, counted across every loop closure that read it.
    """

    def __init__(self):
        self._matches: dict = {}
        self.found = 0

    def __len__(self) -> int:
        return len(self._matches)

    @staticmethod
    def key(t: int, width: float, neighbours, path, start, center) -> tuple:
        """The inputs of one match, as bytes (:func:`match_loops`)."""
        return (int(t), float(width), np.asarray(neighbours, np.int64).tobytes(),
                np.asarray(path, np.float64)[np.asarray(neighbours)].tobytes(),
                np.asarray(start, np.float64).tobytes(), np.asarray(center, np.float64).tobytes())

    def get(self, key: tuple):
        """The ``(pose (3,), hit fraction)`` kept at ``key``, or None."""
        found = self._matches.get(key)
        self.found += found is not None
        return found

    def put(self, key: tuple, pose, quality: float) -> None:
        """Keep one match's ``pose`` ``(3,)`` and hit fraction at ``key``."""
        self._matches[key] = (np.array(pose, np.float64), float(quality))


def match_loops(path, data: ScanData, pairs, progress: ProgressCallback | None = None,
                stage: str = "loop closure", half_widths=None,
                matches: LoopMatches | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Match scan ``t`` against the local map around scan ``s`` for each pair of ``pairs`` ``(P, 2)``
    (:func:`match_to_local_maps` with :func:`loop_levels` of the pair's entry of ``half_widths`` ``(P,)``, default
    1.5 m for every pair, from ``t``'s estimate, the local map of the scans :func:`local_map_neighbours` gives
    ``s``, centered on ``s``), reporting ``Progress(stage, done, P, "scan")`` before the first match and after
    each. With ``matches`` (a :class:`LoopMatches`), a pair whose inputs it holds takes the kept match instead of a
    search, and every match searched is kept in it.

    Returns:
        ``(poses (P, 3), hit_fraction (P,))``: scan ``t``'s matched world pose and its match quality
        (:func:`bayesmap.slam.scanmatch.hit_fraction`).

    Raises:
        BayesmapError: as :func:`loop_levels` and :func:`match_to_local_maps`.
    """
    path = np.asarray(path, np.float64)
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    half_widths = (np.full(len(pairs), LOOP_WINDOWS[0]) if half_widths is None
                   else np.asarray(half_widths, np.float64).reshape(-1))
    if len(half_widths) != len(pairs):
        raise BayesmapError(f"half_widths {half_widths.shape} must have one entry per pair {pairs.shape}")
    neighbours = local_map_neighbours(pairs[:, 0], data.increments)
    poses, quality = np.zeros((len(pairs), 3)), np.zeros(len(pairs))
    done = 0
    for width in np.unique(half_widths):  # one compiled search per window
        rows = np.flatnonzero(half_widths == width)

        def shifted(p, offset=done):  # this window's reports as part of every candidate's count
            if p.done > 0 or offset == 0:
                report(progress, stage, offset + p.done, len(pairs), p.unit)

        keys = [None if matches is None else LoopMatches.key(pairs[r, 1], width, neighbours[r], path,
                                                             path[pairs[r, 1]], path[pairs[r, 0], :2]) for r in rows]
        kept = [None if key is None else matches.get(key) for key in keys]
        for r, found in zip(rows, kept):
            if found is not None:
                poses[r], quality[r] = found
        todo = rows[[found is None for found in kept]]
        poses[todo], quality[todo] = match_to_local_maps(
            path, data, pairs[todo, 1], neighbours[todo], path[pairs[todo, 1]], path[pairs[todo, 0], :2],
            levels=loop_levels(float(width)), progress=None if progress is None else shifted, stage=stage)
        if matches is not None:
            for r, key, found in zip(rows, keys, kept):
                if found is None:
                    matches.put(key, poses[r], quality[r])
        done += len(rows)
        if progress is not None and len(todo) < len(rows):  # the kept ones count as matched
            report(progress, stage, done, len(pairs), "scan")
    return poses, quality


def local_map_neighbours(centers, increments, travel: float | None = None) -> np.ndarray:
    """The scans of each loop candidate's local map: for each scan ``s`` of ``centers`` ``(P,)``, the scans ``s -
    LOOP_NEIGHBOURS .. s + LOOP_NEIGHBOURS``, every :data:`LOCAL_MAP_STEP`-th (clipped to the log: a scan near an end
    repeats the first or last scan, which adds nothing to a local map), except on a side whose farthest scan lies
    more than ``travel`` meters of the odometry's path length from ``s``: there the same number of scans spread
    evenly (rounded) over the scans within ``travel`` (repeats where they are fewer).

    Args:
        centers: ``(P,)`` int scan indices.
        increments: ``(S - 1, 3)`` the odometry's steps (dx m, dy m, dtheta rad; only their lengths are read).
        travel: meters (> 0, or ``inf``); None: :data:`LOOP_MAP_TRAVEL`, read at the call.

    Returns:
        ``(P, 2 (LOOP_NEIGHBOURS // LOCAL_MAP_STEP) + 1)`` int64, ``s`` in the middle column.

    Raises:
        BayesmapError: if ``travel`` is not a number > 0 or a center is outside ``0 .. S - 1``.
    """
    travel = LOOP_MAP_TRAVEL if travel is None else travel
    if isinstance(travel, bool) or not isinstance(travel, (int, float, np.floating)) or not travel > 0:
        raise BayesmapError(f"travel must be a number of meters > 0 (or inf), got {travel!r}")
    steps = np.asarray(increments, np.float64).reshape(-1, 3)
    along = np.concatenate([[0.0], np.cumsum(np.hypot(steps[:, 0], steps[:, 1]))])
    centers = np.asarray(centers, np.int64).reshape(-1)
    last = len(along) - 1
    if centers.size and (centers.min() < 0 or centers.max() > last):
        raise BayesmapError(f"centers must be scan indices in 0..{last}, got {centers.min()}..{centers.max()}")
    reach, per_side = LOOP_NEIGHBOURS, LOOP_NEIGHBOURS // LOCAL_MAP_STEP
    full = np.arange(LOCAL_MAP_STEP, reach + 1, LOCAL_MAP_STEP)  # one side's offsets, unlimited
    rows = np.zeros((len(centers), 2 * per_side + 1), np.int64)
    for k, s in enumerate(centers):
        sides = []
        for sign in (-1, 1):
            ends = np.clip(s + sign * np.arange(reach + 1), 0, last)
            within = np.abs(along[ends] - along[s]) <= travel
            if within.all():
                sides.append(sign * full)
            else:
                m = int(np.argmin(within)) - 1  # the farthest scan within travel, in steps from s
                sides.append(sign * np.rint(np.linspace(0, m, per_side + 1)[1:]).astype(np.int64))
        rows[k] = np.clip(s + np.concatenate([sides[0][::-1], [0], sides[1]]), 0, last)
    return rows


def match_to_local_maps(path, data: ScanData, scans, neighbours, starts, centers=None, levels=LOOP_LEVELS,
                        progress: ProgressCallback | None = None,
                        stage: str = "scan matches") -> tuple[np.ndarray, np.ndarray]:
    """Match each scan of ``scans`` against the local map of its ``neighbours`` at their poses in ``path``.

    The local map of scan ``scans[k]`` is the likelihood fields (:func:`bayesmap.slam.scanmatch.add_to_fields`)
    of the scans ``neighbours[k]`` at ``path[neighbours[k]]``, on a square grid of +-:data:`LOCAL_MAP_HALF_WIDTH`
    meters around ``centers[k]``; the scan is searched (:func:`bayesmap.slam.scanmatch.search`, no prior) from
    ``starts[k]`` over ``levels``. The loop closure's matcher (:func:`match_loops`), and what
    :mod:`bayesmap.evaluation.slammap` registers a held-out scan into a map's frame with.

    Args:
        path: ``(S, 3)`` poses of the scans of ``data`` (x m, y m, theta rad); only the neighbours' rows are read.
        data: the scans (:class:`bayesmap.slam.scanmatch.ScanData`; its odometry is not used).
        scans: ``(P,)`` int indices into ``data`` of the scans to match.
        neighbours: ``(P, N)`` int indices into ``data`` of each one's local map (a scan may be its own neighbour
            only if the caller wants it to).
        starts: ``(P, 3)`` where each search starts (world frame).
        centers: ``(P, 2)`` the local maps' centers (meters); default the starts' positions.
        levels: the coarse-to-fine search (as :data:`bayesmap.slam.scanmatch.MATCH_LEVELS`).
        progress: called with ``Progress(stage, done, P, "scan")`` before the first match and after each (nothing
            when ``P`` is 0); None: no reports.
        stage: the stage the reports name.

    Returns:
        ``(poses (P, 3), hit_fraction (P,))`` float64: each scan's matched world pose and the fraction of its returned
        beams that land on the local map (:func:`bayesmap.slam.scanmatch.hit_fraction`).

    Raises:
        BayesmapError: if the shapes disagree or an index is outside ``data``.
    """
    path = np.asarray(path, np.float64)
    scans = np.asarray(scans, np.int64).reshape(-1)
    neighbours = np.asarray(neighbours, np.int64)
    starts = np.asarray(starts, np.float64).reshape(-1, 3)
    centers = starts[:, :2] if centers is None else np.asarray(centers, np.float64).reshape(-1, 2)
    count = np.asarray(data.readings).shape[0]
    if path.shape != (count, 3):
        raise BayesmapError(f"path must be ({count}, 3), one pose per scan of the data, got shape {path.shape}")
    if neighbours.ndim != 2 or not (len(neighbours) == len(scans) == len(starts) == len(centers)):
        raise BayesmapError(f"scans {scans.shape}, neighbours {neighbours.shape}, starts {starts.shape} and centers "
                            f"{centers.shape} must have one row per matched scan")
    for name, index in (("scans", scans), ("neighbours", neighbours)):
        if index.size and (index.min() < 0 or index.max() >= count):
            raise BayesmapError(f"{name} must index the {count} scans of the data, got {index.min()}..{index.max()}")
    grid = local_map_grid()
    steps = lattices(levels)
    span = None if levels[0][4] == 0 else bound_span(levels[0][0], grid.resolution)  # (nearest-cell first level)
    angles, readings, returned = (jnp.asarray(np.asarray(a)) for a in (data.sensor_angles, data.readings,
                                                                       data.returned))
    poses, quality = np.zeros((len(scans), 3)), np.zeros(len(scans))
    if len(scans):
        report(progress, stage, 0, len(scans), "scan")
    for k, t in enumerate(scans):
        shift = np.array([centers[k, 0], centers[k, 1], 0.0])  # local frame: the center at the origin
        best, q = _match_one(jnp.asarray(neighbours[k]), int(t), jnp.asarray(path[neighbours[k]] - shift),
                             jnp.asarray(starts[k] - shift), angles, readings, returned, steps, grid, span)
        poses[k], quality[k] = np.asarray(best, np.float64) + shift, float(q)
        report(progress, stage, k + 1, len(scans), "scan")
    return poses, quality


def _match_one(neighbours, t, local_poses, center, angles, readings, returned, steps: Lattices, grid: Grid,
               span: int | None):
    """One match of :func:`match_to_local_maps`: scan ``t`` searched from ``center`` against the fields of the scans
    ``neighbours`` at ``local_poses``. Two compiled calls (module level, so that every run with these shapes shares
    them): the local map, then the search, which reads the coarse field's logarithm as an argument
    (:func:`bayesmap.slam.scanmatch.log_field`), its first level by branch and bound where ``span`` is given
    (:func:`bayesmap.slam.scanmatch.search`'s ``bound_span``: the same match as scoring every candidate)."""
    fields, logs = _local_map(neighbours, local_poses, angles, readings, returned, grid)
    return _search_local_map(fields, logs, center, angles[t], readings[t], returned[t], steps, grid, span)


@functools.partial(jax.jit, static_argnames=("grid",), compiler_options=MATCHER_COMPILER_OPTIONS)
def _local_map(neighbours, local_poses, angles, readings, returned, grid: Grid):
    """The fields of the scans ``neighbours`` at ``local_poses``, and the log of each but the fine one."""
    fields = add_to_fields(empty_fields(grid), grid, local_poses, angles[neighbours], readings[neighbours],
                           returned[neighbours])
    return fields, (None,) + tuple(log_field(f) for f in fields[1:])


@functools.partial(jax.jit, static_argnames=("grid", "span"), compiler_options=MATCHER_COMPILER_OPTIONS)
def _search_local_map(fields, logs, center, angles, readings, returned, steps: Lattices, grid: Grid,
                      span: int | None = None):
    """:func:`bayesmap.slam.scanmatch.search` from ``center`` (``span`` its ``bound_span``) and the match's hit
    fraction."""
    best, _ = search(fields, grid, center, angles, readings, returned, steps, log_fields=logs, bound_span=span)
    return best, hit_fraction(fields, grid, best, angles, readings, returned)


def loop_posteriors(path, data: ScanData, loops: Edges, power: float,
                    progress: ProgressCallback | None = None) -> np.ndarray:
    """Each loop edge's match posterior: the covariance ``(L, 3, 3)`` in the frame of its first pose (the edge's
    frame; m^2, m rad, rad^2) of scan ``j``'s pose given the local map of scan ``i``'s neighbours at ``path``
    (:func:`local_map_neighbours`, :func:`local_map_grid`: the loop closure's matcher's), ``exp(power S(x))``
    integrated on the front end's step lattice (:func:`bayesmap.slam.scanmatch.step_lattice`, its floor added)
    around the edge's placement ``path[i]`` composed with ``z``; no motion term, as a loop match has none. The
    covariance of a correlative match's response (Olson 2009, sec. IV-B) with the likelihood tempered as the target
    tempers it, as the front end's steps' (:func:`bayesmap.slam.scanmatch.step_posterior`); where the scan leaves a
    direction free (a corridor's axis) the lattice's reach, 0.3 m and 0.05 rad, bounds it.

    Args:
        path: ``(S, 3)`` poses of the scans of ``data`` (x m, y m, theta rad).
        data: the scans (:class:`bayesmap.slam.scanmatch.ScanData`).
        loops: the loop edges (:class:`Edges`; ``z`` each one's measured pose of ``j`` in ``i``'s frame).
        power: the likelihood power in (0, 1] (the problem's).
        progress: called with ``Progress("path uncertainty", done, L, "loop edge")`` before the first edge and
            after each (nothing without loop edges); None: no reports.

    Raises:
        BayesmapError: if ``path`` is not one pose per scan of ``data``, or ``power`` is not in (0, 1].
    """
    path = np.asarray(path, np.float64)
    count = np.asarray(data.readings).shape[0]
    if path.shape != (count, 3):
        raise BayesmapError(f"path must be ({count}, 3), one pose per scan of the data, got shape {path.shape}")
    power = check_likelihood_power(power)
    i, j = np.asarray(loops.i, np.int64), np.asarray(loops.j, np.int64)
    cov = np.zeros((len(i), 3, 3))
    if not len(i):
        return cov
    neighbours = local_map_neighbours(i, data.increments)
    placed = compose_poses(path[i], np.asarray(loops.z, np.float64))
    grid, lattice = local_map_grid(), step_lattice()
    angles, readings, returned = (jnp.asarray(np.asarray(a)) for a in (data.sensor_angles, data.readings,
                                                                       data.returned))
    report(progress, "path uncertainty", 0, len(i), "loop edge")
    for k in range(len(i)):
        shift = np.array([path[i[k], 0], path[i[k], 1], 0.0])  # local frame: the first pose's position at the origin
        cov[k] = np.asarray(_match_posterior(jnp.asarray(neighbours[k]), jnp.asarray(path[neighbours[k]] - shift),
                                             int(j[k]), jnp.asarray(placed[k] - shift),
                                             jnp.asarray(path[i[k]] - shift), angles, readings, returned, power,
                                             lattice, grid))
        report(progress, "path uncertainty", k + 1, len(i), "loop edge")
    return cov


@functools.partial(jax.jit, static_argnames=("grid",))
def _match_posterior(neighbours, local_poses, t, center, frame, angles, readings, returned, power, lattice,
                     grid: Grid):
    """:func:`loop_posteriors`' covariance of scan ``t``'s match against the local map of the scans ``neighbours``
    at ``local_poses``, in the frame of ``frame``: one compiled call, the local map's fields built as
    :func:`_local_map` builds them."""
    fields = add_to_fields(empty_fields(grid), grid, local_poses, angles[neighbours], readings[neighbours],
                           returned[neighbours])
    cands, logits = scan_logits(fields, grid, center, angles[t], readings[t], returned[t], power, lattice)
    return lattice_covariance(cands, logits, frame, lattice[-1])


def loop_edges(path, data: ScanData, progress: ProgressCallback | None = None, stage: str = "loop closure",
               sequential: Edges | None = None, sigmas: float = LOOP_WINDOW_SIGMAS,
               matches: LoopMatches | None = None) -> tuple[Edges, np.ndarray]:
    """The accepted loop edges of ``path`` (:func:`loop_candidates`, the windows sized by ``sequential`` and
    ``sigmas`` if ``sequential`` is given; :func:`match_loops`, with ``matches`` as there; quality at least
    :data:`LOOP_MIN_HIT_FRACTION`), with :data:`LOOP_STD`; ``progress`` gets ``Progress(stage, done, P, "scan")``
    per candidate matched.

    Returns:
        ``(edges, half_widths (L,))``: the edges and the half width (meters) each one's search covered.
    """
    pairs, half_widths = loop_candidates(path, sequential, sigmas)
    if len(pairs) == 0:
        return Edges(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))), np.zeros(0)
    poses, quality = match_loops(path, data, pairs, progress, stage, half_widths, matches)
    ok = quality >= LOOP_MIN_HIT_FRACTION
    s, t = pairs[ok, 0], pairs[ok, 1]
    return (Edges(s, t, relative(np.asarray(path)[s], poses[ok]), np.tile(np.asarray(LOOP_STD), (int(ok.sum()), 1))),
            half_widths[ok])


def with_step_covariances(edges: Edges, step_cov) -> Edges:
    """The graph ``edges`` (its ``S - 1`` sequential edges first, as :func:`close_loops` returns it) with the
    sequential edges' covariances ``step_cov`` ``(S - 1, 3, 3)`` (:func:`with_covariances`; the front end's step
    posteriors, :class:`bayesmap.slam.scanmatch.MatchedPath`), the loop edges as they are.

    Raises:
        BayesmapError: as :func:`with_covariances`.
    """
    count = len(np.asarray(step_cov))
    return concat_edges(with_covariances(edges.take(slice(0, count)), step_cov), edges.take(slice(count, None)))


def concat_edges(*edges: Edges) -> Edges:
    """All edges of several :class:`Edges` in one (with full square-root informations if any has them)."""
    joined = Edges(*(np.concatenate(parts) for parts in zip(*(e[:4] for e in edges))))
    if all(e.whitening is None for e in edges):
        return joined
    return joined._replace(whitening=np.concatenate([whitening_matrices(e) for e in edges]))


def edge_residuals(path, edges: Edges) -> np.ndarray:
    """``(E, 3)`` whitened residuals ``W (relative(x_i, x_j) - z_ij)`` of ``edges`` at ``path`` ``(S, 3)`` (the angle
    difference wrapped to ``[-pi, pi)`` first; ``W`` :func:`whitening_matrices`, ``diag(1 / std)`` by default)."""
    path = np.asarray(path, np.float64)
    e = relative(path[edges.i], path[edges.j]) - edges.z
    e[:, 2] = wrap_angle(e[:, 2])
    if edges.whitening is None:
        return e / edges.std
    return np.einsum("eij,ej->ei", whitening_matrices(edges), e)


def robust_cost(path, edges: Edges, scale: float = CAUCHY_SCALE) -> float:
    """The graph's robust cost at ``path`` ``(S, 3)``: ``sum rho(f^2) / 2`` over the whitened residuals' components
    ``f`` (:func:`edge_residuals`), ``rho(z) = c^2 log(1 + z / c^2)`` the Cauchy loss at ``c = scale`` standard
    deviations (``scipy.optimize.least_squares``'s ``loss="cauchy"``)."""
    f = edge_residuals(path, edges).reshape(-1)
    return float(0.5 * scale**2 * np.sum(np.log1p((f / scale) ** 2)))


def optimize_pose_graph(path, edges: Edges, scale: float = CAUCHY_SCALE) -> np.ndarray:
    """The path ``(S, 3)`` float64 minimizing the robust edge cost (:func:`robust_cost`, the Cauchy loss at ``scale``
    standard deviations), pose 0 fixed at ``path[0]``, started at ``path``.

    Levenberg-Marquardt (Levenberg 1944, Marquardt 1963) on iteratively reweighted least squares: each iteration
    weighs every residual component by the loss's slope ``rho'(f^2) = 1 / (1 + f^2 / c^2)`` (Holland & Welsch 1977),
    solves the damped normal equations ``(J^T W J + lambda diag(J^T W J)) d = -J^T W f`` with the analytic sparse
    Jacobian (:func:`edge_jacobians`) by a sparse LU, and keeps the step only if the robust cost falls (else
    ``lambda`` grows tenfold), the scheme of g2o and Ceres for pose graphs. Stops when an iteration lowers the cost by
    less than :data:`COST_TOLERANCE` of it, or after :data:`MAX_ITERATIONS`."""
    x = np.array(path, np.float64)
    n = len(x)
    damping, cost = 1e-4, robust_cost(x, edges, scale)
    for _ in range(MAX_ITERATIONS):
        f = edge_residuals(x, edges).reshape(-1)
        weight = 1.0 / (1.0 + (f / scale) ** 2)
        jacobian = _whitened_jacobian(x, edges).tocsr()
        weighted = scipy.sparse.diags(weight) @ jacobian
        hessian = (jacobian.T @ weighted).tocsc()
        gradient = jacobian.T @ (weight * f)
        diagonal = np.maximum(hessian.diagonal(), 1e-12)
        while True:
            step = scipy.sparse.linalg.spsolve((hessian + scipy.sparse.diags(damping * diagonal)).tocsc(), -gradient)
            trial = x.copy()
            trial[1:] += step.reshape(n - 1, 3)
            new = robust_cost(trial, edges, scale)
            if new < cost:
                damping = max(damping / 10, 1e-12)
                break
            damping *= 10
            if damping > 1e8:  # no step lowers the cost: a minimum to rounding
                return x
        converged = cost - new < COST_TOLERANCE * cost
        x, cost = trial, new
        if converged:
            break
    return x


def odometry_path(sequential: Edges) -> np.ndarray:
    """The path ``(S, 3)`` float64 that the sequential edges ``t - 1 -> t`` chain, from the origin
    (:func:`bayesmap.io.rosbag.compose_poses`, headings summed, not wrapped): the front end's path up to one rigid
    motion.

    Raises:
        BayesmapError: if the edges are not ``0 -> 1, 1 -> 2, ...`` in order.
    """
    i, j = np.asarray(sequential.i), np.asarray(sequential.j)
    if not (np.array_equal(i, np.arange(len(i))) and np.array_equal(j, i + 1)):
        raise BayesmapError("sequential edges must be 0 -> 1, 1 -> 2, ... in order")
    path = np.zeros((len(i) + 1, 3))
    for k, z in enumerate(np.asarray(sequential.z, np.float64)):
        path[k + 1] = compose_poses(path[k], z)
    return path


def _pivot_covariance(xy_var, theta_var, lever) -> np.ndarray:
    """``(..., 3, 3)``: a relative pose's noise (``xy_var`` on each position component, ``theta_var`` on its angle)
    carried to the end of a chain whose rest turns about the pose it ends at, ``lever`` ``(..., 2)`` the vector from
    there to the end: ``xy_var I + theta_var g g^T``, ``g = (-lever_y, lever_x, 1)``."""
    g = np.concatenate([-lever[..., 1:2], lever[..., 0:1], np.ones(lever.shape[:-1] + (1,))], axis=-1)
    out = np.asarray(theta_var)[..., None, None] * g[..., :, None] * g[..., None, :]
    out[..., 0, 0] += xy_var
    out[..., 1, 1] += xy_var
    return out


def rotation3(theta) -> np.ndarray:
    """``(..., 3, 3)`` float64: the rotation of a pose's frame by ``theta`` ``(...)`` (radians), acting on ``(x, y)``
    and leaving the heading: what turns a covariance in a pose's frame into the world's, ``R Sigma R^T``."""
    c, s = np.cos(theta), np.sin(theta)
    r = np.zeros(np.shape(theta) + (3, 3))
    r[..., 0, 0], r[..., 0, 1], r[..., 1, 0], r[..., 1, 1], r[..., 2, 2] = c, -s, s, c, 1.0
    return r


def _isotropic(edges: Edges, name: str) -> np.ndarray:
    std = np.asarray(edges.std, np.float64)
    if edges.whitening is not None:
        raise BayesmapError(f"{name} edges must have independent components (no whitening) for the consistency test")
    if not np.allclose(std[:, 0], std[:, 1]):
        raise BayesmapError(f"{name} edges must have equal x and y standard deviations for the consistency test")
    return std


def edge_covariances(edges: Edges) -> np.ndarray:
    """``(E, 3, 3)`` float64: each edge's covariance in the frame of its first pose (m^2, m rad, rad^2):
    ``diag(std^2)``, or ``(W^T W)^-1`` for an edge with a square-root information ``W``."""
    if edges.whitening is None:
        std = np.asarray(edges.std, np.float64)
        return std[:, :, None] ** 2 * np.eye(3) if std.size else np.zeros((0, 3, 3))
    whitening = whitening_matrices(edges)
    return np.linalg.inv(np.swapaxes(whitening, 1, 2) @ whitening)


def _lever_matrix(point) -> np.ndarray:
    """``(..., 3, 3)``: ``[[0, 0, -y], [0, 0, x], [0, 0, 0]]`` for ``point`` ``(..., 2)``: a heading change
    ``dtheta`` at the origin moves ``point`` by ``(-y, x) dtheta``."""
    out = np.zeros(np.shape(point)[:-1] + (3, 3))
    out[..., 0, 2], out[..., 1, 2] = -point[..., 1], point[..., 0]
    return out


class _Chain:
    """Prefix sums over the sequential edges of the moments that the covariance of a stretch of them needs
    (:func:`pairwise_consistency`, :func:`chain_covariances`). Edge ``k`` (pose ``k - 1`` to ``k``) has covariance
    ``C_k`` in the chain's frame (its own turned by pose ``k - 1``'s heading) and turns what follows about pose
    ``k``'s position ``p_k``, so at an anchor ``a`` it adds ``G C_k G^T`` with ``G = M(a) - N(p_k)``, ``M(a) = I +
    lever(a)`` and ``N(p) = lever(p)`` (:func:`_lever_matrix`): the sums of ``C_k``, ``C_k N_k^T`` and ``N_k C_k
    N_k^T`` give any stretch."""

    def __init__(self, sequential: Edges):
        self.path = odometry_path(sequential)
        rotation = rotation3(self.path[:-1, 2])
        cov = rotation @ edge_covariances(sequential) @ np.swapaxes(rotation, 1, 2)
        lever = _lever_matrix(self.path[1:, :2])  # sequential edge k - 1 ends at pose k
        cross = cov @ np.swapaxes(lever, 1, 2)
        self.sums = tuple(np.concatenate([np.zeros((1, 3, 3)), np.cumsum(v, axis=0)])
                          for v in (cov, cross, lever @ cross))

    def covariance(self, start, stop, anchor) -> np.ndarray:
        """``(P, 3, 3)``: the noise of the sequential edges between poses ``start`` and ``stop`` ``(P,)`` (either
        order) carried to ``anchor`` ``(P, 2)`` (the odometry path's frame): ``sum_k G_k C_k G_k^T``, ``G_k`` the
        rigid turn about edge ``k``'s end pose seen at ``anchor``."""
        low, high = np.minimum(start, stop), np.maximum(start, stop)
        cov, cross, second = (s[high] - s[low] for s in self.sums)
        move = np.eye(3) + _lever_matrix(np.asarray(anchor, np.float64))
        first = move @ cross
        return move @ cov @ np.swapaxes(move, 1, 2) - first - np.swapaxes(first, 1, 2) + second


def chain_covariances(sequential: Edges, pairs) -> np.ndarray:
    """How far pose ``t`` can be from its estimate if pose ``s`` is where the estimate puts it and only the
    sequential edges between them tie the two: for each pair ``(s, t)`` of ``pairs`` ``(P, 2)``, the covariance of
    pose ``t`` given pose ``s`` along the chain of ``sequential`` (:func:`sequential_edges`, independent components
    or full covariances, :func:`with_covariances`), to first order: ``sum_k G_k C_k G_k^T`` over the edges
    between them, ``C_k`` edge ``k``'s covariance turned into the chain's frame and ``G_k = [[1, 0, -l_y], [0, 1,
    l_x], [0, 0, 1]]``, ``l`` the lever from edge ``k``'s end to pose ``t`` (a heading error at ``k`` swings
    everything after it; for independent components with equal x and y deviations, ``xy_var_k I + theta_var_k g_k
    g_k^T``, ``g_k = (-l_y, l_x, 1)``).

    Returns:
        ``(P, 3, 3)`` float64 (m^2, m rad, rad^2), in the frame of the chain's path (:func:`odometry_path`, which
        starts at the origin: the world's turned by the first pose's heading; the position block's eigenvalues are
        the same in either).

    Raises:
        BayesmapError: on sequential edges out of order, a pair outside the chain or one with ``s > t``.
    """
    chain = _Chain(sequential)
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    if pairs.size and (pairs.min() < 0 or pairs.max() >= len(chain.path)):
        raise BayesmapError(f"pairs must index the chain's {len(chain.path)} poses, got {pairs.min()}..{pairs.max()}")
    if np.any(pairs[:, 0] > pairs[:, 1]):
        raise BayesmapError(f"each pair (s, t) must have s <= t, got {pairs[np.argmax(pairs[:, 0] > pairs[:, 1])]}")
    return chain.covariance(pairs[:, 0], pairs[:, 1], chain.path[pairs[:, 1], :2])


def pairwise_consistency(sequential: Edges, loops: Edges) -> np.ndarray:
    """How far each pair of loop edges is from agreeing, given the odometry between them (Mangelson et al. 2018,
    "Pairwise consistency maximization for robust multi-robot map merging"): for loop edges ``a`` (``i_a -> j_a``)
    and ``b`` (``i_b -> j_b``), the cycle ``i_a -> j_a`` (edge ``a``), ``j_a -> j_b`` (the sequential edges),
    ``j_b -> i_b`` (edge ``b`` backwards), ``i_b -> i_a`` (the sequential edges) composes to the identity if both
    are true; its error ``e`` (a pose in ``i_a``'s frame) has, to first order in the edges' noise, the covariance
    ``Sigma = sum_k J_k Sigma_k J_k^T`` over the cycle's edges, and the result is ``e^T Sigma^-1 e``.

    A noise ``(dx, dy, dtheta)`` on an edge moves the part of the cycle beyond the edge by ``(dx, dy)`` turned into
    the cycle's frame and turns it by ``dtheta`` about the edge's pose ``j``, whichever way the cycle runs through
    the edge, so each edge adds ``G C G^T``, ``C`` its covariance in the cycle's frame and ``G = [[1, 0, -l_y], [0,
    1, l_x], [0, 0, 1]]``, ``l`` the lever from that pose to the cycle's end (for a loop edge, whose x and y
    deviations are equal, ``sigma_xy^2 I + sigma_theta^2 g g^T``, ``g = (-l_y, l_x, 1)``); the sums over a stretch
    of sequential edges are differences of prefix sums (:func:`chain_covariances`, docs/slam.md). Checked against
    the covariance of Monte Carlo cycles (tests).

    Args:
        sequential: the sequential edges ``0 -> 1, 1 -> 2, ...`` (:func:`sequential_edges`, possibly with full
            covariances, :func:`with_covariances`), whose chain (:func:`odometry_path`) is the odometry between
            the loop edges' ends.
        loops: ``L`` loop edges of the same graph.

    Returns:
        ``(L, L)`` float64 squared Mahalanobis norms, zero on the diagonal.

    Raises:
        BayesmapError: on sequential edges out of order, or a loop edge whose x and y standard deviations differ
            or that has a full covariance.
    """
    chain = _Chain(sequential)
    path, loop_std = chain.path, _isotropic(loops, "loop")
    count = len(loops.i)
    if count == 0:
        return np.zeros((0, 0))

    def stretch(start, stop, frame, end):
        """The covariance at the cycle's ``end`` of the sequential edges between poses ``start`` and ``stop``,
        ``frame`` the transform from the odometry path's frame to the cycle's."""
        anchor = compose_poses(invert_pose(frame), end)[..., :2]  # the cycle's end in the odometry path's frame
        rotation = rotation3(frame[:, 2])
        return rotation @ chain.covariance(start, stop, anchor) @ np.swapaxes(rotation, -1, -2)

    a, b = (k.ravel() for k in np.meshgrid(np.arange(count), np.arange(count), indexing="ij"))
    i, j, z = np.asarray(loops.i), np.asarray(loops.j), np.asarray(loops.z, np.float64)
    at_ja = z[a]
    at_jb = compose_poses(at_ja, relative(path[j[a]], path[j[b]]))
    at_ib = compose_poses(at_jb, invert_pose(z[b]))
    end = compose_poses(at_ib, relative(path[i[b]], path[i[a]]))
    end[:, 2] = wrap_angle(end[:, 2])  # the cycle's error: its heading in [-pi, pi)
    cov = (_pivot_covariance(loop_std[a, 0] ** 2, loop_std[a, 2] ** 2, end[:, :2] - at_ja[:, :2])
           + _pivot_covariance(loop_std[b, 0] ** 2, loop_std[b, 2] ** 2, end[:, :2] - at_jb[:, :2])
           + stretch(j[a], j[b], compose_poses(at_ja, invert_pose(path[j[a]])), end)
           + stretch(i[b], i[a], compose_poses(at_ib, invert_pose(path[i[b]])), end))
    norms = np.einsum("ni,ni->n", end, np.linalg.solve(cov, end[:, :, None])[:, :, 0]).reshape(count, count)
    np.fill_diagonal(norms, 0.0)
    return norms


def consistent_sets(norms, gate: float = CONSISTENCY_GATE, limit: int = MAX_LOOP_SETS) -> tuple[list, int]:
    """The maximal sets of loop edges that are pairwise consistent (``norms <= gate`` for every pair in the set,
    :func:`pairwise_consistency`): the maximal cliques of the consistency graph (Bron & Kerbosch 1973, with Tomita
    et al.'s pivot, ``networkx.find_cliques``), at most ``limit`` of them.

    Args:
        norms: ``(L, L)`` squared norms (symmetrized by their larger value).
        gate: the squared norm up to which a pair is consistent (:data:`CONSISTENCY_GATE`).
        limit: the most sets enumerated, ``>= 1``.

    Returns:
        ``(sets, count)``: the sets (sorted ``(n,)`` int64 index arrays), largest first (ties in index order), and
        how many were enumerated (``count == limit`` means there may be more). No loop edges: ``([], 0)``.
    """
    import networkx as nx  # the consistency graph's cliques; imported where used (the CLI's start time)

    norms = np.asarray(norms, np.float64)
    graph = nx.Graph()
    graph.add_nodes_from(range(len(norms)))
    first, second = np.nonzero(np.triu(np.maximum(norms, norms.T) <= gate, 1))
    graph.add_edges_from(zip(first.tolist(), second.tolist()))
    sets = [np.sort(np.asarray(c, np.int64)) for c in itertools.islice(nx.find_cliques(graph), limit)]
    sets.sort(key=lambda c: (-len(c), c.tolist()))
    return sets, len(sets)


def window_volumes(half_widths) -> np.ndarray:
    """``(L,)`` float64: the volume (m^2 rad) of the first lattice of each loop search of ``half_widths`` ``(L,)``
    (:func:`loop_levels`): where a false match can land.

    Raises:
        BayesmapError: as :func:`loop_levels`.
    """
    firsts = [loop_levels(float(w))[0] for w in np.asarray(half_widths).reshape(-1)]
    return np.array([((2 * steps + 1) * xy) ** 2 * (2 * theta_steps + 1) * theta
                     for xy, theta, steps, theta_steps, _ in firsts], np.float64).reshape(-1)


def log_evidence(path, sequential: Edges, loops: Edges, chosen, half_widths=None) -> float:
    """The log-probability of the loop edges' measurements if the edges ``chosen`` are true matches and the others
    false ones, up to a constant shared by every choice: the chosen edges Gaussian about the graph's prediction
    (their standard deviations), each other edge uniform over its search's window (the first lattice of
    :func:`loop_levels` of its entry of ``half_widths`` ``(L,)``, default 1.5 m for every edge: a false match lands
    anywhere in it, :func:`window_volumes`), the poses integrated out by the Laplace approximation of the graph
    of ``sequential`` and the chosen edges (a flat prior on the poses after the first; Olson & Agarwal 2013 for the
    mixture of a Gaussian and a broad component). The graph's minimum is one Gauss-Newton step from ``path``
    ``(S, 3)``: exact for the graph linearized there.

    ``log p = -chi2_min / 2 - log det H / 2 + sum_{chosen} (-3/2 log 2 pi + log det W) - sum_{others} log V`` (``W``
    an edge's square-root information, ``diag(1 / std)`` by default)

    Raises:
        BayesmapError: as :func:`marginal_covariances` for a graph with an untied pose.
    """
    chosen = np.asarray(chosen, np.int64)
    loops_in = loops.take(chosen)
    edges = concat_edges(sequential, loops_in)
    path = _check_graph(path, edges)
    jacobian, lu = _information_lu(path, edges)
    residual = edge_residuals(path, edges).reshape(-1)
    gradient = jacobian.T @ residual
    chi2 = float(residual @ residual - gradient @ lu.solve(gradient))
    log_det = float(np.sum(np.log(np.abs(lu.U.diagonal()))))
    log_det_w = np.linalg.slogdet(whitening_matrices(loops_in))[1] if len(chosen) else np.zeros(0)
    normalizers = float(np.sum(-1.5 * np.log(2 * np.pi) + log_det_w))
    volumes = window_volumes(np.full(len(loops.i), LOOP_WINDOWS[0]) if half_widths is None else half_widths)
    others = np.ones(len(loops.i), bool)
    others[chosen] = False
    return -0.5 * chi2 - 0.5 * log_det + normalizers - float(np.sum(np.log(volumes[others])))


def loop_hypotheses(path, sequential: Edges, loops: Edges, sets: tuple | None = None,
                    weighed: int = WEIGHED_LOOP_SETS, half_widths=None) -> LoopHypotheses:
    """Which loop edges are true: the empty set and the ``weighed`` largest maximal pairwise-consistent sets
    (``sets``, the output of :func:`consistent_sets`; by default of :func:`pairwise_consistency` at the defaults),
    weighed by :func:`log_evidence` (the edges' search windows ``half_widths``, as there) with equal prior odds of a
    true and a false match, and normalized over them. The sets are weighed at ``path`` ``(S, 3)``, the empty set at
    the sequential edges' own chain from ``path[0]`` (:func:`odometry_path`), where it fits with zero residuals and
    its Laplace approximation is exact."""
    sets, count = consistent_sets(pairwise_consistency(sequential, loops)) if sets is None else sets
    sets = [np.zeros(0, np.int64), *sets[:weighed]]
    odometry = compose_poses(np.asarray(path, np.float64)[0], odometry_path(sequential))
    logs = np.array([log_evidence(path if len(c) else odometry, sequential, loops, c, half_widths) for c in sets])
    order = np.argsort(-logs, kind="stable")
    weights = np.exp(logs[order] - logs.max())
    return LoopHypotheses([sets[k] for k in order], weights / weights.sum(), count, loops)


def optimize_with_loop_gate(path, sequential: Edges, loops: Edges, consistency_gate: float = CONSISTENCY_GATE,
                            half_widths=None) -> tuple[np.ndarray, Edges, LoopHypotheses]:
    """Keep the loop edges of the most probable hypothesis (:func:`loop_hypotheses` of the sets consistent at
    ``consistency_gate``, weighed at the graph's optimum with the largest of them, each edge's search window
    ``half_widths`` as there), optimize the graph of ``sequential`` and those edges from ``path`` ``(S, 3)``
    (:func:`optimize_pose_graph`), then drop every kept loop edge whose whitened residual norm exceeds
    :data:`LOOP_GATE` and optimize again without them.

    Returns:
        ``(path (S, 3) float64, the loop edges kept, the hypotheses)``.
    """
    subset = loops.take

    sets = consistent_sets(pairwise_consistency(sequential, loops), consistency_gate)
    largest = sets[0][0] if sets[0] else np.zeros(0, np.int64)
    path = optimize_pose_graph(path, concat_edges(sequential, subset(largest)))
    hypotheses = loop_hypotheses(path, sequential, loops, sets, half_widths=half_widths)
    chosen = hypotheses.sets[0]
    if not np.array_equal(chosen, largest):
        path = optimize_pose_graph(path, concat_edges(sequential, subset(chosen)))
    kept = subset(chosen)
    keep = np.linalg.norm(edge_residuals(path, kept), axis=1) <= LOOP_GATE
    if keep.all():
        return path, kept, hypotheses
    kept = kept.take(keep)
    return optimize_pose_graph(path, concat_edges(sequential, kept)), kept, hypotheses


class LoopClosure(NamedTuple):
    """The back end's result (:func:`close_loops`): ``path`` ``(S, 3)`` float64, ``edges`` the graph (the
    sequential edges, then the loop edges kept in the last round), ``hypotheses`` the last round's
    :class:`LoopHypotheses` (None if no round found a loop edge)."""

    path: np.ndarray
    edges: Edges
    hypotheses: LoopHypotheses | None


def close_loops(path, data: ScanData, rounds: int = ROUNDS, progress: ProgressCallback | None = None,
                consistency_gate: float = CONSISTENCY_GATE, window_sigmas: float = LOOP_WINDOW_SIGMAS,
                step_cov=None, matches: LoopMatches | None = None) -> LoopClosure:
    """Alternate loop detection (:func:`loop_edges`) and the choice of loop edges with pose-graph optimization
    (:func:`optimize_with_loop_gate` at ``consistency_gate``) ``rounds`` times from the front end's ``path`` (fewer
    if a round finds no loop edge). ``progress`` gets ``Progress("loop closure r/rounds", done, P, "scan")`` per
    loop candidate matched in round ``r`` (``P`` its candidates; nothing for a round without any).

    The first round sizes each candidate's search window by its drift along the chain, ``window_sigmas`` standard
    deviations (:func:`loop_candidates`; 0: every window 1.5 m): before any loop is closed, a long loop's end can be
    meters from where the front end puts it. Later rounds search +-1.5 m around the path the kept loops corrected
    ([validation](../validation/slam.md#the-loop-searchs-reach)).

    ``step_cov`` ``(S - 1, 3, 3)`` (or None): the sequential edges' covariances, each in the frame of the pose
    before it (the front end's step posteriors, :attr:`bayesmap.slam.scanmatch.MatchedPath.step_cov`): the windows,
    the consistency test, the hypotheses' weights and the optimization all read them, so a step the front end could
    not pin down (a corridor, a match that was not trusted) is where a loop bends the path. None: every step at
    :data:`SEQUENTIAL_STD` ([validation](../validation/slam.md#the-steps-uncertainty-in-the-loop-closure)).

    ``matches`` (a :class:`LoopMatches`, or None): the matches of another loop closure of the same scans, taken where
    a candidate's inputs are the same to the bit (:func:`match_loops`; the same result as searching), and this one's
    kept in it.

    Returns:
        A :class:`LoopClosure`: the optimized path, the graph's edges (the sequential edges of the front end's
        ``path``, :func:`sequential_edges`, with ``step_cov`` if given, followed by the loop edges kept in the last
        round) and the last round's hypotheses.

    Raises:
        BayesmapError: as :func:`with_covariances` for a bad ``step_cov``.
    """
    path = np.asarray(path, np.float64)
    sequential = sequential_edges(path) if step_cov is None else with_covariances(sequential_edges(path), step_cov)
    kept = Edges(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    hypotheses = None
    for r in range(rounds):
        loops, half_widths = loop_edges(path, data, progress, f"loop closure {r + 1}/{rounds}",
                                        sequential if r == 0 else None, window_sigmas, matches)
        if len(loops.i) == 0:
            break
        path, kept, hypotheses = optimize_with_loop_gate(path, sequential, loops, consistency_gate, half_widths)
    return LoopClosure(path, concat_edges(sequential, kept), hypotheses)


def edge_jacobians(path, edges: Edges) -> tuple[np.ndarray, np.ndarray]:
    """The whitened residuals' Jacobians ``(E, 3, 3)`` float64 with respect to the edges' first and second poses,
    ``(d r_e / d x_i, d r_e / d x_j)``, at ``path`` ``(S, 3)`` (:func:`edge_residuals`). For ``relative(a, b) =
    (R(a_theta)^T (b_xy - a_xy), b_theta - a_theta)`` the derivative in ``a_theta`` of the position part is
    ``(rel_y, -rel_x)`` (docs/slam.md)."""
    path = np.asarray(path, np.float64)
    a = path[edges.i]
    rel = relative(a, path[edges.j])
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    rotation_t = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], axis=1)  # (E, 2, 2): R^T
    first, second = np.zeros((len(a), 3, 3)), np.zeros((len(a), 3, 3))
    second[:, :2, :2], first[:, :2, :2] = rotation_t, -rotation_t
    first[:, 0, 2], first[:, 1, 2] = rel[:, 1], -rel[:, 0]
    first[:, 2, 2], second[:, 2, 2] = -1.0, 1.0
    if edges.whitening is None:
        weight = 1.0 / np.asarray(edges.std, np.float64)[:, :, None]
        return first * weight, second * weight
    whitening = whitening_matrices(edges)
    return whitening @ first, whitening @ second


def _edge_matrix(blocks, edges: Edges, count: int) -> scipy.sparse.coo_matrix:
    """The sparse ``(3 E, 3 (count - 1))`` matrix whose rows ``3 e .. 3 e + 2`` hold edge ``e``'s ``(3, 6)`` block
    ``blocks[e]`` (derivatives in pose ``i``, then in pose ``j``) in the columns of those poses; pose 0 is fixed, so
    its columns are dropped."""
    i, j = np.asarray(edges.i), np.asarray(edges.j)
    rows = np.broadcast_to(3 * np.arange(len(i))[:, None, None] + np.arange(3)[None, :, None], (len(i), 3, 6))
    node_cols = np.concatenate([3 * (i - 1)[:, None] + np.arange(3), 3 * (j - 1)[:, None] + np.arange(3)], axis=1)
    cols = np.broadcast_to(node_cols[:, None, :], (len(i), 3, 6))
    keep = cols >= 0
    return scipy.sparse.coo_matrix((np.asarray(blocks)[keep], (rows[keep], cols[keep])),
                                   shape=(3 * len(i), 3 * (count - 1)))


def _whitened_jacobian(path, edges: Edges, local_maps: LocalMaps | None = None) -> scipy.sparse.csc_matrix:
    """The sparse ``(3 E, 3 (S - 1))`` whitened Jacobian in the poses after the first (pose 0 is fixed); with
    ``local_maps``, the ``S - 1`` sequential edges' rows are :func:`_local_map_rows`' (``3 (S - 1)`` more rows)."""
    count = len(np.asarray(path))
    if local_maps is None:
        first, second = edge_jacobians(path, edges)
        return _edge_matrix(np.concatenate([first, second], axis=2), edges, count).tocsc()
    loops = edges.take(slice(count - 1, None))
    first, second = edge_jacobians(path, loops)
    return scipy.sparse.vstack([_local_map_rows(path, edges.take(slice(0, count - 1)), local_maps),
                                _edge_matrix(np.concatenate([first, second], axis=2), loops, count)]).tocsc()


def _local_map_rows(path, sequential: Edges, local_maps: LocalMaps) -> scipy.sparse.coo_matrix:
    """The whitened rows ``(6 (S - 1), 3 (S - 1))`` of the sequential edges split as :class:`LocalMaps` says: the
    motion model's edges ``t - 1 -> t`` (:func:`edge_jacobians`), then each step's scan information on ``pose_t -
    sum_s w_ts pose_s``: in pose ``t`` the plain edge's block ``diag(R^T, 1)``, in each local-map scan ``s`` ``w_ts``
    times the plain edge's block in its first pose with the lever from ``s`` (``R`` the heading of pose ``t - 1``,
    the frame of the step's covariance)."""
    path = np.asarray(path, np.float64)
    count = len(path)
    if not (np.array_equal(sequential.i, np.arange(count - 1)) and np.array_equal(sequential.j, np.arange(1, count))):
        raise BayesmapError("the graph's first S - 1 edges must be the sequential edges t - 1 -> t")
    shares = scipy.sparse.coo_matrix(local_maps.shares)
    motion_cov = np.asarray(local_maps.motion_cov, np.float64)
    if shares.shape != (count - 1, count) or motion_cov.shape != (count - 1, 3, 3):
        raise BayesmapError(f"local maps' shares {shares.shape} and motion covariances {motion_cov.shape} must be "
                            f"({count - 1}, {count}) and ({count - 1}, 3, 3)")
    if shares.nnz and np.any(shares.col >= shares.row + 1):
        raise BayesmapError("a step's local map may hold only the scans before it")
    whitening = whitening_matrices(sequential)  # W, W^T W the step posterior's information
    definite = np.all(np.linalg.eigvalsh((motion_cov + np.swapaxes(motion_cov, 1, 2)) / 2) > 0, axis=1)
    motion_info = np.zeros_like(motion_cov)
    motion_info[definite] = np.linalg.inv(motion_cov[definite])
    # the motion model's information in the step's whitened frame, at most the step's in every direction (the
    # lattice's floor and the motion density's broad component can leave the step wider than the motion model)
    inverse = np.linalg.inv(whitening)
    value, vector = np.linalg.eigh(np.swapaxes(inverse, 1, 2) @ motion_info @ inverse)
    value = np.clip(value, 0.0, 1.0)
    motion_w = (np.sqrt(value)[:, :, None] * np.swapaxes(vector, 1, 2)) @ whitening
    motion = _whitened_jacobian(path, sequential._replace(whitening=motion_w))
    scan_w = (np.sqrt(1.0 - value)[:, :, None] * np.swapaxes(vector, 1, 2)) @ whitening  # (S - 1, 3, 3)
    c, s = np.cos(path[:-1, 2]), np.sin(path[:-1, 2])
    rotation_t = np.zeros((count - 1, 3, 3))
    rotation_t[:, 0, 0], rotation_t[:, 0, 1], rotation_t[:, 1, 0], rotation_t[:, 1, 1] = c, s, -s, c
    rotation_t[:, 2, 2] = 1.0
    step, scan = shares.row, shares.col  # step t = row + 1
    lever = path[step + 1, :2] - path[scan, :2]
    block = -rotation_t[step].copy()  # d/d pose_s of -(R^T (p_t - p_s) moved by s), as edge_jacobians' first
    block[:, :2, 2] = -np.einsum("nij,nj->ni", rotation_t[step, :2, :2], np.stack([-lever[:, 1], lever[:, 0]], -1))
    blocks = np.concatenate([scan_w @ rotation_t, scan_w[step] @ (shares.data[:, None, None] * block)])
    nodes = np.concatenate([np.arange(1, count), scan])
    rows = np.concatenate([np.arange(count - 1), step])
    r = np.broadcast_to(3 * rows[:, None, None] + np.arange(3)[None, :, None], blocks.shape)
    k = np.broadcast_to(3 * (nodes - 1)[:, None, None] + np.arange(3)[None, None, :], blocks.shape)
    keep = k >= 0
    scans = scipy.sparse.coo_matrix((blocks[keep], (r[keep], k[keep])), shape=(3 * (count - 1), 3 * (count - 1)))
    return scipy.sparse.vstack([motion, scans]).tocoo()


def _check_graph(path, edges: Edges) -> np.ndarray:
    path = np.asarray(path, np.float64)
    if path.ndim != 2 or path.shape[1] != 3 or len(path) < 2:
        raise BayesmapError(f"path must have shape (S, 3) with S >= 2, got {path.shape}")
    std = np.asarray(edges.std, np.float64)
    if std.size and not (np.isfinite(std).all() and (std > 0).all()):
        raise BayesmapError(f"edge standard deviations must be positive and finite, got minimum {std.min()!r}")
    if edges.whitening is not None and not np.isfinite(edges.whitening).all():
        raise BayesmapError("edge square-root informations (whitening) must be finite")
    touched = np.zeros(len(path), bool)
    touched[np.asarray(edges.i)], touched[np.asarray(edges.j)] = True, True
    if not touched[1:].all():
        raise BayesmapError(f"pose {int(np.flatnonzero(~touched[1:])[0]) + 1} has no edge: its covariance is "
                            "unbounded")
    return path


def _information_lu(path, edges: Edges, local_maps: LocalMaps | None = None, ordering: str = "COLAMD"):
    """The whitened Jacobian and a sparse LU of ``H = J^T J`` with SuperLU's column ``ordering`` (the loop
    hypotheses' evidence keeps SuperLU's default; the marginals and draws take :data:`SYMMETRIC_ORDERING`)."""
    jacobian = _whitened_jacobian(path, edges, local_maps)
    try:
        return jacobian, scipy.sparse.linalg.splu((jacobian.T @ jacobian).tocsc(), permc_spec=ordering)
    except RuntimeError as err:  # SuperLU: "Factor is exactly singular"
        raise BayesmapError("the pose graph does not tie every pose to pose 0 (its information matrix is "
                            f"singular: {err})") from None


def marginal_covariances(path, edges: Edges, local_maps: LocalMaps | None = None) -> np.ndarray:
    """The Laplace approximation's pose covariances: the ``3 x 3`` diagonal blocks of ``H^-1`` (module docstring).

    Args:
        path: ``(S, 3)`` poses (x m, y m, theta rad) to linearize at, ``S >= 2``; pose 0 is held fixed.
        edges: the graph (every pose after the first on at least one edge; the graph connected).
        local_maps: None, or what the front end matched each step against (:class:`LocalMaps`): each sequential
            edge (the first ``S - 1`` of ``edges``, ``t - 1 -> t``) then ties its scan's information to the
            scans of its local map, its motion model's to pose ``t - 1``.

    Returns:
        ``(S, 3, 3)`` float64 covariances (m^2, m rad, rad^2), zeros for pose 0.

    Raises:
        BayesmapError: on a bad ``path`` shape, a non-positive edge standard deviation, a pose without edges or a
            graph in pieces (some poses not tied to pose 0), or ``local_maps`` that do not fit the graph (named).
    """
    path = _check_graph(path, edges)
    _, lu = _information_lu(path, edges, local_maps, SYMMETRIC_ORDERING)
    size = 3 * (len(path) - 1)
    cov = np.zeros((len(path), 3, 3))
    for start in range(0, size, SOLVE_COLUMNS):
        stop = min(start + SOLVE_COLUMNS, size)
        rhs = np.zeros((size, stop - start))
        rhs[np.arange(start, stop), np.arange(stop - start)] = 1.0
        cols = lu.solve(rhs)  # columns start..stop of H^-1
        nodes = np.arange(start // 3, stop // 3)  # SOLVE_COLUMNS is a multiple of 3: whole poses per chunk
        k = np.arange(3)
        cov[nodes + 1] = cols[(3 * nodes)[:, None, None] + k[None, :, None], (3 * nodes - start)[:, None, None] + k]
    return cov


def sample_deviations(seed: int, path, edges: Edges, num: int, local_maps: LocalMaps | None = None) -> np.ndarray:
    """``num`` draws ``(num, S, 3)`` float64 of ``N(0, H^-1)`` (module docstring), pose 0's deviation zero: the
    graph's correlated uncertainty of the whole path at ``path`` ``(S, 3)``, by perturb-and-solve with
    ``numpy.random.default_rng(seed)``; ``local_maps`` as :func:`marginal_covariances`.

    Raises:
        BayesmapError: as :func:`marginal_covariances`, or if ``num < 1``.
    """
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 1:
        raise BayesmapError(f"num must be a positive integer, got {num!r}")
    path = _check_graph(path, edges)
    jacobian, lu = _information_lu(path, edges, local_maps, SYMMETRIC_ORDERING)
    eps = np.random.default_rng(seed).standard_normal((jacobian.shape[0], int(num)))
    draws = lu.solve(np.asarray(jacobian.T @ eps))
    return np.concatenate([np.zeros((int(num), 1, 3)), draws.T.reshape(int(num), len(path) - 1, 3)], axis=1)
