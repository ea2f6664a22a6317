"""Path hypotheses where the scan and the odometry disagree, weighed by the SLAM target with the walls integrated out.

A single-track front end keeps, at every scan, the match it scores best against the last meters' local map. Where
that match is far from the odometry's step (an aliased corridor, a scan that sees little), the other hypothesis, that
the odometry was right and the match slipped, is lost for good: the chain that follows moves poses by centimeters.
Here both are kept, at the few steps where they differ most, and the whole log decides between them:

1. **Branch points** (:func:`branch_points`): the steps whose match lies farther from the odometry's step than
   :data:`BRANCH_GATE` (squared Mahalanobis distance under the motion model's covariance of the step,
   :func:`step_disagreement`), at most :data:`BRANCHES` of them, the farthest first.
2. **Branches**: for each, the front end again from that scan with that step taken from the odometry
   (:func:`bayesmap.slam.scanmatch.correlative_path`'s ``odometry_steps``, resumed from the single track's poses
   before it), until it rejoins the single track (:func:`rejoin_scan`): once its steps have agreed with the single
   track's, within their posteriors, over a whole local map's travel, its local map is the single track's moved
   rigidly, and the rest of the branch is the single track's later steps (:func:`spliced`). Then the loop closure.
3. **Weights** (:func:`hypothesis_weights`): each closed path's evidence, the SLAM target's lower bound with the
   walls integrated out (:func:`bayesmap.slam.evidence.path_evidence`), normalized over the hypotheses. The chain
   starts from the heaviest.

This is a discrete search over start paths weighed by the target's own marginal, not a sampler of the path: the
weights are those of the hypotheses found, each at one path, and the bound's draw adds Monte Carlo noise of tens of
nats (docs/slam.md; [validation](../validation/slam.md#hypotheses-where-scan-and-odometry-disagree)).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.io.rosbag import compose_poses
from bayesmap.model.motion import wrap_angle
from bayesmap.slam.posegraph import CONSISTENCY_GATE, relative
from bayesmap.slam.scanmatch import LOCAL_MAP_DISTANCE, MatchedPath

BRANCH_GATE = CONSISTENCY_GATE
"""Squared Mahalanobis distance (under the motion model's covariance of the step) beyond which a step's match and
the odometry are two hypotheses: 16.27, the 99.9 % quantile of the chi-square distribution with 3 degrees of freedom,
the loop closure's consistency gate. A quantile of the motion model, not fitted to any log: a true step that follows
the motion model lies beyond it once in a thousand steps."""

BRANCHES = 3
"""The most branch points weighed per run. Each costs a front end from its scan until it rejoins the single track
(:func:`rejoin_scan`: about 10 m of travel where it does), a loop closure and a 4-sweep map chain: the whole
stage 9-24 s on CSAIL's 203-406 keyframes and 45-86 s on Freiburg 079's 1,389 (one to three branch points, two
cores), nothing where a log has none. With them the whole `slam --log` takes 1.21-1.48 times 685e56c's on CSAIL's
seeds 0-4 at both scan rates, and 1.07-1.32 times on Freiburg 079's seeds 0, 2 and 3
(seed 3 1.14) ([validation](../validation/slam.md#time-against-the-pipeline-at-685e56c)). A compute budget, not a model
setting: any value searches the same target, more of its branches. Where CSAIL every other scan had three branch
points, the one chosen was the third farthest on seed 0 and the second on seeds 3, 4 and 10."""

EVIDENCE_SWEEPS = 4
"""Cellwise sweeps of the map drawn at each hypothesis for its evidence (:func:`bayesmap.slam.evidence.
path_evidence`): the wall probabilities of the last two. Twelve sweeps raised every hypothesis's bound by 870-1,090
nats on CSAIL every other scan seeds 0 and 10 (five hypotheses each) and chose the same branch on both; four are the
joint chain's own map block (:data:`bayesmap.slam.pipeline.MAP_SWEEPS`), so that the chosen start's draw is the
chain's first block ([validation](../validation/slam.md#hypotheses-where-scan-and-odometry-disagree))."""

WEIGHT_FLOOR = 0.01
"""A hypothesis with at least this weight counts as a distinct one in summaries (as the loop closure's and the
front end's hypotheses)."""


class PathHypotheses(NamedTuple):
    """The start paths weighed (:mod:`bayesmap.slam.branches`).

    Attributes:
        odometry_steps: ``(H,)`` int64: for each hypothesis the scan whose step it took from the odometry; 0 for
            the front end's own path (row 0).
        disagreement: ``(H,)`` float64: the squared Mahalanobis distance of that step's match from the odometry
            (:func:`step_disagreement`; 0 for row 0).
        evidence: ``(H,)`` float64: each closed path's evidence lower bound, nats
            (:func:`bayesmap.slam.evidence.path_evidence`).
        weights: ``(H,)`` float64, summing to 1 (:func:`hypothesis_weights`).
        chosen: the row the chain starts from (the heaviest).
        rejoined: ``(H,)`` int64: for each branch the scan after which its steps are the single track's
            (:func:`rejoin_scan`), -1 where it never rejoined (its front end ran to the last scan); 0 for row 0.
    """

    odometry_steps: np.ndarray
    disagreement: np.ndarray
    evidence: np.ndarray
    weights: np.ndarray
    chosen: int
    rejoined: np.ndarray

    @property
    def distinct(self) -> int:
        """How many hypotheses carry at least :data:`WEIGHT_FLOOR` of the weight."""
        return int(np.sum(self.weights >= WEIGHT_FLOOR))


def step_disagreement(path, increments, covs) -> np.ndarray:
    """``(S - 1,)`` float64: for each step of ``path`` ``(S, 3)`` (x m, y m, theta rad), the squared Mahalanobis
    distance of the path's step (in the frame of the pose before) from the odometry's ``increments`` ``(S - 1, 3)``
    under the motion model's covariances ``covs`` ``(S - 1, 3, 3)``, the heading's difference wrapped to
    ``(-pi, pi]``.

    Raises:
        BayesmapError: if the shapes disagree.
    """
    path, increments, covs = (np.asarray(a, np.float64) for a in (path, increments, covs))
    if path.ndim != 2 or path.shape[1] != 3 or increments.shape != (len(path) - 1, 3) or covs.shape != (
            len(path) - 1, 3, 3):
        raise BayesmapError(f"shapes disagree: path {path.shape}, increments {increments.shape}, covs {covs.shape}")
    delta = relative(path[:-1], path[1:]) - increments
    delta[:, 2] = wrap_angle(delta[:, 2])
    return np.einsum("ei,ei->e", delta, np.linalg.solve(covs, delta[..., None])[..., 0])


def branch_points(distance, gate: float = BRANCH_GATE, most: int = BRANCHES) -> np.ndarray:
    """``(B,)`` int64, ``B <= most``: the scans ``t`` (in ``1 .. S - 1``) whose step into them from ``t - 1``
    disagrees with the odometry by more than ``gate``, by ``distance`` ``(S - 1,)`` (:func:`step_disagreement`), the
    largest disagreement first.

    Raises:
        BayesmapError: if ``most`` is not an integer >= 0 or ``gate`` is not a number >= 0.
    """
    if isinstance(most, bool) or not isinstance(most, (int, np.integer)) or most < 0:
        raise BayesmapError(f"most must be an integer >= 0, got {most!r}")
    if isinstance(gate, bool) or not isinstance(gate, (int, float)) or not gate >= 0:
        raise BayesmapError(f"gate must be a number >= 0, got {gate!r}")
    distance = np.asarray(distance, np.float64)
    order = np.argsort(-distance, kind="stable")
    return (order[distance[order] > gate][:most] + 1).astype(np.int64)


def hypothesis_weights(evidence) -> np.ndarray:
    """``(H,)`` float64 weights summing to 1: ``exp(evidence)`` normalized (``evidence`` ``(H,)`` nats, finite).

    Raises:
        BayesmapError: if ``evidence`` is empty or not finite.
    """
    evidence = np.asarray(evidence, np.float64)
    if evidence.ndim != 1 or not len(evidence) or not np.all(np.isfinite(evidence)):
        raise BayesmapError(f"evidence must be a non-empty vector of finite nats, got {evidence!r}")
    w = np.exp(evidence - evidence.max())
    return w / w.sum()


def steps_apart(path, step_cov, other, other_cov) -> np.ndarray:
    """``(n - 1,)`` float64: for each step into scans ``1 .. n - 1`` of two paths of the same scans, ``path`` and
    ``other`` ``(n, 3)`` (at least ``n`` poses each; x m, y m, theta rad), the squared Mahalanobis distance between
    their steps (each in the frame of its pose before) under the sum of their covariances ``step_cov`` and
    ``other_cov`` (``(n - 1, 3, 3)``, at least; the front end's step posteriors,
    :class:`bayesmap.slam.scanmatch.MatchedPath`): two matches of the same scan, each with its own error.

    Raises:
        BayesmapError: if the shapes disagree.
    """
    n = min(len(path), len(other))
    if n < 1 or len(step_cov) < n - 1 or len(other_cov) < n - 1:
        raise BayesmapError(f"shapes disagree: paths {np.shape(path)} and {np.shape(other)}, step covariances "
                            f"{np.shape(step_cov)} and {np.shape(other_cov)}")
    other = np.asarray(other, np.float64)[:n]
    covs = np.asarray(step_cov, np.float64)[:n - 1] + np.asarray(other_cov, np.float64)[:n - 1]
    return step_disagreement(np.asarray(path, np.float64)[:n], relative(other[:-1], other[1:]), covs)


def rejoin_scan(distance, travelled, point: int, window: float = LOCAL_MAP_DISTANCE,
                gate: float = BRANCH_GATE) -> int | None:
    """The scan at which a branch from ``point`` rejoins the single track: the first scan ``j > point`` such that
    every step after the branch's last step into a scan ``u`` (``point <= u <= j``) that disagrees with the single
    track's by more than ``gate`` (``distance`` ``(n - 1,)``, :func:`steps_apart` of the two paths' first ``n``
    poses; the step into ``point`` itself, the odometry's, counts as disagreeing) agrees, and the robot travelled
    more than ``window`` meters from ``u`` to ``j`` (``travelled`` ``(S,)``, the odometry's path length,
    :func:`bayesmap.slam.scanmatch.path_length`); None if no ``j < n`` is.

    From there the branch's front end would match against a local map (the scans of the last ``window`` meters,
    :data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE`) whose scans lie as the single track's do, moved rigidly, up
    to the steps' posteriors: it would repeat the single track's matches, up to the same, and the single track's
    later steps are taken instead (:func:`spliced`). ``gate`` is a chi-square quantile
    (:data:`BRANCH_GATE`) and ``window`` the local map's own span: nothing here is fitted to a log.

    Raises:
        BayesmapError: if ``point`` is not a scan index in ``1 .. S - 1`` or ``window`` is not a number >= 0.
    """
    travelled = np.asarray(travelled, np.float64)
    distance = np.asarray(distance, np.float64)
    if isinstance(point, bool) or not isinstance(point, (int, np.integer)) or not 1 <= point < len(travelled):
        raise BayesmapError(f"branch point {point!r} is not a scan index in 1..{len(travelled) - 1}")
    if isinstance(window, bool) or not isinstance(window, (int, float)) or not window >= 0:
        raise BayesmapError(f"window must be a number of meters >= 0, got {window!r}")
    last = point
    for j in range(point + 1, min(len(distance) + 1, len(travelled))):
        if distance[j - 1] > gate:
            last = j
        elif travelled[j] - travelled[last] > window:
            return j
    return None


def spliced(branch: MatchedPath, single: MatchedPath) -> MatchedPath:
    """The branch ``branch`` (poses ``0 .. j``, :func:`rejoin_scan`'s scan ``j`` its last) continued by the single
    track ``single``'s later steps: poses ``u > j`` at ``branch``'s pose ``j`` composed with ``single``'s pose ``u``
    in the frame of its pose ``j`` (the single track moved rigidly; the heading not wrapped), and ``single``'s
    steps' covariances after ``j``. A branch of every scan is returned as it is.

    Raises:
        BayesmapError: if ``branch`` has more poses than ``single``.
    """
    j = len(branch.path) - 1
    if j >= len(single.path):
        raise BayesmapError(f"a branch of {j + 1} poses is longer than the single track's {len(single.path)}")
    rest = relative(single.path[j], single.path[j + 1:])
    later = compose_poses(branch.path[j], rest)
    later[:, 2] = branch.path[j, 2] + (single.path[j + 1:, 2] - single.path[j, 2])
    return MatchedPath(np.vstack([branch.path, later]), np.concatenate([branch.step_cov, single.step_cov[j:]]),
                       branch.hypotheses)
