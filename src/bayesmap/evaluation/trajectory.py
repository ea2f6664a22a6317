"""Scores of an estimated planar trajectory against the true one (numpy, vectorized).

Poses are rows ``(x, y, theta)``: meters, meters, radians (heading, counter-clockwise from the x axis), one per
scan, estimate and truth in the same scan order (``(S, 3)`` float arrays).

* :func:`absolute_trajectory_error` (ATE): the position error after the best rigid 2-D alignment of the estimate
  onto the truth (:func:`align_rigid_2d`), as in Sturm et al. 2012, "A benchmark for the evaluation of RGB-D SLAM
  systems" (IROS), Section VI-B, restricted to the plane.
* :func:`relative_pose_error` (RPE): the error of the relative motion between scans ``i`` and ``i + delta``
  (Sturm et al. 2012, Section VI-A; Kümmerle et al. 2009, "On measuring the accuracy of SLAM algorithms",
  Autonomous Robots 27(4)); it needs no alignment.
* :func:`similarity_scale`: how much larger the truth is than the estimate, by the best similarity alignment.
* :func:`frame_of`: true poses carried into the estimate's frame by the inverse of that alignment (where the truth
  lands on a SLAM map).
* :func:`ellipse_coverage`: how often the truth lies inside the estimate's confidence ellipse: a calibration check
  of a posterior's pose covariance.
* :func:`sample_coverages`, :func:`coverage_rank`: the same coverage scored by paths drawn from the posterior, and
  where the truth's falls among them: what coverage a calibrated posterior would give on this path (the probability
  integral transform of the coverage; Dawid 1984, "Statistical theory: the prequential approach", J. R. Statist.
  Soc. A 147(2)).

These are the few lines evo (the standard package) computes, written here for SE(2): evo aligns with 3-D
Umeyama (SE(3)/Sim(3)), which on planar trajectories may pick a rotation by pi about an axis in the plane, a mirror
image within the plane, and it would add about a dozen dependencies (rosbags, seaborn, apsw, lz4, ...). On the
project's data (the odometry of ``data/slam/*-odom.odom.tum`` against ``*-odom.truth.tum``) every ATE statistic and
the RPE at delta 1 and 10 equal evo 1.38.1's ``APE`` (``align=True``) and ``RPE`` (frames, ``all_pairs=True``) to
1e-12 (ATE RMSE: Intel 13.05 m, ACES 16.07 m, CSAIL 7.47 m).
"""

from __future__ import annotations

import math

import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.model.motion import wrap_angle


def _check_poses(estimate, truth, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Estimate and truth as float64 ``(S, columns)``, one shape, finite, ``S >= 1``."""
    e = np.asarray(estimate, dtype=np.float64)
    g = np.asarray(truth, dtype=np.float64)
    for name, a in (("estimate", e), ("truth", g)):
        if a.ndim != 2 or a.shape[1] != columns or a.shape[0] == 0:
            raise BayesmapError(f"{name} must have shape (S, {columns}) with S >= 1, got {a.shape}")
        bad = np.argwhere(~np.isfinite(a))
        if len(bad):
            i, j = (int(v) for v in bad[0])
            raise BayesmapError(f"{name}[{i}, {j}] is {a[i, j]!r}, not a finite number")
    if e.shape != g.shape:
        raise BayesmapError(f"estimate has {e.shape[0]} poses but truth has {g.shape[0]}: they must match scan "
                            "for scan")
    return e, g


def align_rigid_2d(estimate, truth) -> tuple[np.ndarray, np.ndarray]:
    """The rigid 2-D motion that best maps the estimated positions onto the true ones (least squares, no scale).

    Minimizes ``sum_i |R @ estimate[i] + t - truth[i]|^2`` over rotations ``R`` (det +1, no reflection) and
    translations ``t``: Umeyama 1991 ("Least-squares estimation of transformation parameters between two point
    patterns", IEEE PAMI 13(4)) / Horn 1987 restricted to SE(2), where it has a closed form: with the centred
    points ``e'``, ``g'``, the angle is ``atan2(sum(e'_x g'_y - e'_y g'_x), sum(e'_x g'_x + e'_y g'_y))`` and
    ``t = mean(g) - R @ mean(e)``. If the points do not fix the angle (a single point, or every position the
    same), ``R`` is the identity.

    Args:
        estimate: ``(S, 2)`` estimated positions, meters.
        truth: ``(S, 2)`` true positions, meters, same order.

    Returns:
        ``(R, t)``: ``(2, 2)`` float64 rotation and ``(2,)`` float64 translation (meters).

    Raises:
        BayesmapError: if the shapes differ or are not ``(S, 2)`` with ``S >= 1``, or a value is not finite.
    """
    e, g = _check_poses(estimate, truth, 2)
    me, mg = e.mean(axis=0), g.mean(axis=0)
    cross, dot = _centred_products(e - me, g - mg)
    angle = math.atan2(cross, dot)
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    return rot, mg - rot @ me


def _centred_products(ec: np.ndarray, gc: np.ndarray) -> tuple[float, float]:
    """``(sum of e' x g', sum of e' . g')`` of centred ``(S, 2)`` positions: the sine and cosine parts of the best
    rotation (Umeyama 1991 in the plane)."""
    cross = float(np.sum(ec[:, 0] * gc[:, 1] - ec[:, 1] * gc[:, 0]))
    dot = float(np.sum(ec[:, 0] * gc[:, 0] + ec[:, 1] * gc[:, 1]))
    return cross, dot


def similarity_scale(estimate, truth) -> float:
    """The scale of the least-squares similarity (rotation, translation and scale) that maps the estimated positions
    onto the true ones: Umeyama 1991 restricted to the plane, ``s = sqrt(C^2 + D^2) / sum_i |e'_i|^2`` with ``C`` and
    ``D`` the centred points' summed cross and dot products (the rotation is :func:`align_rigid_2d`'s). Above 1: the
    truth is larger than the estimate (a path shrunk by a range or odometry bias, which no loop closure sees, since a
    scaled map agrees with itself). The ATE does not fit it.

    Args:
        estimate: ``(S, 2)`` estimated positions, meters.
        truth: ``(S, 2)`` true positions, meters, same order.

    Returns:
        The scale (float, dimensionless); 1.0 if the estimated positions are all the same.

    Raises:
        BayesmapError: as :func:`align_rigid_2d`.
    """
    e, g = _check_poses(estimate, truth, 2)
    ec, gc = e - e.mean(axis=0), g - g.mean(axis=0)
    spread = float(np.sum(ec**2))
    if spread == 0.0:
        return 1.0
    return math.hypot(*_centred_products(ec, gc)) / spread


def frame_of(estimate, truth, poses) -> np.ndarray:
    """``poses`` ``(M, 3)`` of the truth's frame carried into the frame of ``estimate``: the inverse of the rigid 2-D
    alignment of ``estimate`` ``(S, 3)`` onto ``truth`` ``(S, 3)`` (:func:`align_rigid_2d`): positions ``R^T (p - t)``,
    headings minus the alignment's angle, wrapped to ``[-pi, pi)``. Meters and radians.

    Raises:
        BayesmapError: as :func:`align_rigid_2d`.
    """
    rot, t = align_rigid_2d(np.asarray(estimate, np.float64)[:, :2], np.asarray(truth, np.float64)[:, :2])
    poses = np.asarray(poses, np.float64)
    theta = wrap_angle(poses[:, 2] - math.atan2(rot[1, 0], rot[0, 0]))
    return np.column_stack([(poses[:, :2] - t) @ rot, theta])  # rows R^T (p - t)


def absolute_trajectory_error(estimate, truth) -> dict[str, float]:
    """Absolute trajectory error: the position error after aligning the estimate onto the truth.

    The estimate's positions are moved by :func:`align_rigid_2d` (the alignment uses every scan) and compared with
    the true ones, scan by scan (Sturm et al. 2012, Section VI-B). Headings are not scored (:func:`relative_pose_error`
    does).

    Args:
        estimate: ``(S, 3)`` estimated poses ``(x, y, theta)``: meters, meters, radians.
        truth: ``(S, 3)`` true poses, same order.

    Returns:
        ``{"rmse_m", "mean_m", "median_m", "max_m"}``: the root mean square, mean, median and largest position
        error, meters.

    Raises:
        BayesmapError: if the shapes differ or are not ``(S, 3)`` with ``S >= 1``, or a value is not finite.
    """
    e, g = _check_poses(estimate, truth, 3)
    rot, t = align_rigid_2d(e[:, :2], g[:, :2])
    err = np.linalg.norm(e[:, :2] @ rot.T + t - g[:, :2], axis=1)
    return {"rmse_m": float(np.sqrt(np.mean(err**2))), "mean_m": float(np.mean(err)),
            "median_m": float(np.median(err)), "max_m": float(np.max(err))}


def _relative_motion(poses: np.ndarray, delta: int) -> np.ndarray:
    """``(S - delta, 3)``: pose ``i + delta`` in the frame of pose ``i`` (``P_i^-1 P_{i+delta}`` in SE(2))."""
    a, b = poses[:-delta], poses[delta:]
    d = b[:, :2] - a[:, :2]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap_angle(b[:, 2] - a[:, 2])], axis=1)


def relative_pose_error(estimate, truth, delta: int) -> dict[str, float]:
    """Relative pose error over ``delta`` scans: the error of each estimated motion from scan ``i`` to ``i + delta``.

    With ``Q_i`` the true and ``P_i`` the estimated pose (as SE(2) transforms), the error of pair ``i`` is
    ``E_i = (Q_i^-1 Q_{i+delta})^-1 (P_i^-1 P_{i+delta})`` (Sturm et al. 2012, Section VI-A, eq. 1; Kümmerle et al.
    2009): its translation length and its rotation angle (wrapped to ``[-pi, pi)``) are scored over all the
    ``S - delta`` overlapping pairs ``i = 0, 1, ..., S - delta - 1`` (Sturm's definition; evo's ``--all_pairs``,
    where evo's default takes only every ``delta``-th pair). It needs no alignment and does not depend on the
    frame of either trajectory.

    Args:
        estimate: ``(S, 3)`` estimated poses ``(x, y, theta)``: meters, meters, radians.
        truth: ``(S, 3)`` true poses, same order.
        delta: the scan gap, ``1 <= delta < S``.

    Returns:
        ``{"trans_rmse_m", "rot_rmse_deg", "pairs"}``: the root mean square translation error (meters), rotation
        error (degrees), and the number of pairs scored (``S - delta``).

    Raises:
        BayesmapError: if the shapes differ or are not ``(S, 3)``, a value is not finite, or ``delta`` is not an
            integer in ``[1, S - 1]``.
    """
    e, g = _check_poses(estimate, truth, 3)
    if isinstance(delta, bool) or not isinstance(delta, (int, np.integer)) or not 1 <= delta < len(e):
        raise BayesmapError(f"delta must be an integer in [1, {len(e) - 1}] (the trajectories have {len(e)} "
                            f"poses), got {delta!r}")
    delta = int(delta)
    rel_e, rel_g = _relative_motion(e, delta), _relative_motion(g, delta)
    # E = rel_g^-1 rel_e: rel_e's translation minus rel_g's, in rel_g's frame (its length is frame-free)
    trans = np.linalg.norm(rel_e[:, :2] - rel_g[:, :2], axis=1)
    rot = wrap_angle(rel_e[:, 2] - rel_g[:, 2])
    return {"trans_rmse_m": float(np.sqrt(np.mean(trans**2))),
            "rot_rmse_deg": float(np.degrees(np.sqrt(np.mean(rot**2)))), "pairs": len(trans)}


def _check_covariances(pose_cov, count: int) -> np.ndarray:
    """``(S, 2, 2)`` position marginals of ``(S, 3, 3)`` pose covariances, checked symmetric and PSD."""
    cov = np.asarray(pose_cov, dtype=np.float64)
    if cov.shape != (count, 3, 3):
        raise BayesmapError(f"pose_cov must have shape ({count}, 3, 3) to match the poses, got {cov.shape}")
    bad = np.argwhere(~np.isfinite(cov))
    if len(bad):
        raise BayesmapError(f"pose_cov{list(int(v) for v in bad[0])} is {cov[tuple(bad[0])]!r}, not finite")
    xy = cov[:, :2, :2]
    scale = np.maximum(np.abs(xy).max(axis=(1, 2)), np.finfo(np.float64).tiny)
    asym = np.flatnonzero(np.abs(xy[:, 0, 1] - xy[:, 1, 0]) > 1e-9 * scale)
    if len(asym):
        i = int(asym[0])
        raise BayesmapError(f"pose_cov[{i}] is not symmetric: (x, y) entry {xy[i, 0, 1]!r}, (y, x) {xy[i, 1, 0]!r}")
    low = np.linalg.eigvalsh(xy)[:, 0]
    neg = np.flatnonzero(low < -1e-9 * scale)
    if len(neg):
        i = int(neg[0])
        raise BayesmapError(f"pose_cov[{i}] is not a covariance: its (x, y) block has eigenvalue {low[i]!r} < 0")
    return xy


ZERO_VARIANCE_SLACK = 1e-9
"""Meters: the largest offset along a zero-variance direction that :func:`ellipse_coverage` counts as none."""


def _mahalanobis_sq(diff: np.ndarray, eig: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``(S,)`` squared Mahalanobis lengths of ``(S, 2)`` vectors under ``(S, 2, 2)`` PSD covariances given by their
    ``numpy.linalg.eigh`` ``eig`` (computed once for every path scored against them).

    A direction of zero variance (eigenvalue at most 1e-12 of the largest, or all zero) admits no offset beyond
    :data:`ZERO_VARIANCE_SLACK` (rounding): a larger component along it gives ``inf``, so a pose with zero
    covariance covers the truth only where they coincide.
    """
    vals, vecs = eig
    comp = np.einsum("sij,si->sj", vecs, diff)  # components along the eigenvectors
    flat = vals <= 1e-12 * np.maximum(vals[:, -1:], 0.0)
    fixed = np.where(np.abs(comp) <= ZERO_VARIANCE_SLACK, 0.0, np.inf)
    terms = np.where(flat, fixed, comp**2 / np.where(flat, 1.0, vals))
    return terms.sum(axis=1)


def _check_level(level) -> float:
    if isinstance(level, bool) or not isinstance(level, (int, float, np.floating)) or not 0.0 < level < 1.0:
        raise BayesmapError(f"level must be a probability in (0, 1), got {level!r}")
    return float(level)


def ellipse_coverage(estimate, pose_cov, truth, level: float = 0.95) -> float:
    """Fraction of true positions inside the estimate's ``level`` confidence ellipse.

    The ellipse of scan ``i`` is that of the (x, y) marginal of ``N(estimate[i], pose_cov[i])``: the positions
    ``p`` with ``(p - mu)^T Sigma^-1 (p - mu) <= r^2``, ``r^2 = -2 ln(1 - level)`` (the chi-square quantile with 2
    degrees of freedom). The truth is first moved into the estimate's frame by the inverse of the alignment
    :func:`absolute_trajectory_error` uses (:func:`align_rigid_2d` of the estimate onto the truth): ``p =
    R^T (truth - t)``; this is the same as aligning the estimate and rotating each covariance to ``R Sigma R^T``.
    For a calibrated posterior the result is about ``level``. A zero-variance direction (a pose held fixed, such as
    the first pose of a SLAM run) covers the truth only where they coincide along that direction (to within
    :data:`ZERO_VARIANCE_SLACK`); the alignment usually moves such a pose's truth off it.

    Args:
        estimate: ``(S, 3)`` estimated (posterior mean) poses ``(x, y, theta)``: meters, meters, radians.
        pose_cov: ``(S, 3, 3)`` pose covariances (m^2, m rad, rad^2); only the (x, y) block is used.
        truth: ``(S, 3)`` true poses, same order.
        level: the ellipse's probability, in ``(0, 1)``.

    Returns:
        The fraction (float in ``[0, 1]``) of scans whose true position lies inside (or on) the ellipse.

    Raises:
        BayesmapError: if the shapes do not match, a value is not finite, a covariance's (x, y) block is not
            symmetric or has a negative eigenvalue (beyond 1e-9 of its largest entry), or ``level`` is not in
            ``(0, 1)``.
    """
    e, g = _check_poses(estimate, truth, 3)
    level = _check_level(level)
    cov = _check_covariances(pose_cov, len(e))
    return _inside_fraction(e, np.linalg.eigh(cov), g, level)


def _inside_fraction(e: np.ndarray, eig, g: np.ndarray, level: float) -> float:
    """:func:`ellipse_coverage` of checked poses ``e`` and ``g`` ``(S, 3)``, the ellipses' covariances given by their
    eigen-decomposition ``eig`` (:func:`_mahalanobis_sq`)."""
    truth_in_estimate_frame = frame_of(e, g, g)[:, :2]
    r2 = -2.0 * math.log1p(-level)
    return float(np.mean(_mahalanobis_sq(truth_in_estimate_frame - e[:, :2], eig) <= r2))


def sample_coverages(estimate, pose_cov, samples, level: float = 0.95) -> np.ndarray:
    """The :func:`ellipse_coverage` of each path drawn from the posterior, scored in the truth's place.

    Each sample is aligned onto ``estimate`` by the best rigid motion, then its positions are counted inside or
    outside the ellipses of ``pose_cov``, exactly as the truth is.

    Args:
        estimate: ``(S, 3)`` estimated (posterior mean) poses ``(x, y, theta)``: meters, meters, radians.
        pose_cov: ``(S, 3, 3)`` pose covariances (m^2, m rad, rad^2); only the (x, y) block is used.
        samples: ``(N, S, 3)`` paths drawn from the posterior (``trajectory_samples.npy``), ``N >= 1``.
        level: the ellipse's probability, in ``(0, 1)``.

    Returns:
        ``(N,)`` float64 fractions in ``[0, 1]``.

    Raises:
        BayesmapError: as :func:`ellipse_coverage`, or if ``samples`` is not ``(N, S, 3)`` with ``N >= 1`` or holds a
            value that is not finite.
    """
    e = np.asarray(estimate, dtype=np.float64)
    draws = np.asarray(samples, dtype=np.float64)
    if draws.ndim != 3 or draws.shape[1:] != e.shape or draws.shape[0] == 0:
        raise BayesmapError(f"samples must have shape (N, {e.shape[0]}, 3) with N >= 1 to match the poses, got "
                            f"{draws.shape}")
    bad = np.argwhere(~np.isfinite(draws))
    if len(bad):
        raise BayesmapError(f"samples{list(int(v) for v in bad[0])} is {draws[tuple(bad[0])]!r}, not a finite "
                            "number")
    e, _ = _check_poses(estimate, draws[0], 3)
    level = _check_level(level)
    eig = np.linalg.eigh(_check_covariances(pose_cov, len(e)))  # once for all the samples
    return np.array([_inside_fraction(e, eig, d, level) for d in draws])


def coverage_rank(estimate, pose_cov, truth, samples, level: float = 0.95) -> dict[str, float | int]:
    """The truth's :func:`ellipse_coverage` beside the coverage that paths drawn from the posterior score.

    Each sample path is scored exactly as the truth is (:func:`sample_coverages`). For a calibrated posterior the
    truth is one more draw, so its coverage is one more value of the samples' distribution: its rank among them (the
    fraction of samples scoring less, ties counted half) is uniform over runs (the probability integral transform;
    Dawid 1984). The samples' coverages also say what coverage to expect: with the first pose held fixed the
    ellipses grow along the path, the alignment takes the path's rigid drift out, and a calibrated posterior's
    coverage is then often above ``level``.

    Args:
        estimate: ``(S, 3)`` estimated (posterior mean) poses ``(x, y, theta)``: meters, meters, radians.
        pose_cov: ``(S, 3, 3)`` pose covariances (m^2, m rad, rad^2); only the (x, y) block is used.
        truth: ``(S, 3)`` true poses, same order.
        samples: ``(N, S, 3)`` paths drawn from the posterior (``trajectory_samples.npy``), ``N >= 1``.
        level: the ellipse's probability, in ``(0, 1)``.

    Returns:
        ``{"coverage", "samples_coverage_min", "samples_coverage_median", "samples_coverage_max", "coverage_rank",
        "samples"}``: the truth's coverage, the samples' smallest, median and largest (fractions in ``[0, 1]``), the
        truth's rank in ``[0, 1]`` and ``N``.

    Raises:
        BayesmapError: as :func:`ellipse_coverage` and :func:`sample_coverages`.
    """
    observed = ellipse_coverage(estimate, pose_cov, truth, level)
    drawn = sample_coverages(estimate, pose_cov, samples, level)
    rank = float(np.mean(drawn < observed) + 0.5 * np.mean(drawn == observed))
    return {"coverage": observed, "samples_coverage_min": float(drawn.min()),
            "samples_coverage_median": float(np.median(drawn)), "samples_coverage_max": float(drawn.max()),
            "coverage_rank": rank, "samples": len(drawn)}


RPE_DELTAS = (1, 10)
"""The scan gaps :func:`score_trajectory` reports the relative pose error at."""


def score_trajectory(estimate, truth, pose_cov=None, level: float = 0.95,
                     samples=None) -> dict[str, float | int | None]:
    """All trajectory scores of an estimate, in one flat dict (ready for JSON or a table).

    Args:
        estimate: ``(S, 3)`` estimated poses ``(x, y, theta)``: meters, meters, radians.
        truth: ``(S, 3)`` true poses, same order.
        pose_cov: optional ``(S, 3, 3)`` pose covariances for :func:`ellipse_coverage`.
        level: the coverage ellipse's probability.
        samples: optional ``(N, S, 3)`` paths drawn from the posterior, with ``pose_cov``: the keys of
            :func:`coverage_rank` as well.

    Returns:
        ``ate_rmse_m``, ``ate_mean_m``, ``ate_median_m``, ``ate_max_m`` (:func:`absolute_trajectory_error`);
        ``scale_pct``, :func:`similarity_scale` less 1 in percent (above 0: the estimate is smaller than the truth);
        for each ``delta`` in :data:`RPE_DELTAS` smaller than ``S``: ``rpe{delta}_trans_rmse_m`` and
        ``rpe{delta}_rot_rmse_deg`` (:func:`relative_pose_error`); ``poses`` (``S``); ``coverage`` (the
        :func:`ellipse_coverage` fraction, None without ``pose_cov``) and ``coverage_level``; with ``samples``
        and ``pose_cov``, ``samples_coverage_min``, ``samples_coverage_median``, ``samples_coverage_max``,
        ``coverage_rank`` and ``samples`` (:func:`coverage_rank`).

    Raises:
        BayesmapError: as the functions it calls.
    """
    e, g = _check_poses(estimate, truth, 3)
    level = _check_level(level)
    scores: dict[str, float | int | None] = {"poses": len(e)}
    scores.update({f"ate_{k}": v for k, v in absolute_trajectory_error(e, g).items()})
    scores["scale_pct"] = 100.0 * (similarity_scale(e[:, :2], g[:, :2]) - 1.0)
    for delta in RPE_DELTAS:
        if delta < len(e):
            rpe = relative_pose_error(e, g, delta)
            scores[f"rpe{delta}_trans_rmse_m"] = rpe["trans_rmse_m"]
            scores[f"rpe{delta}_rot_rmse_deg"] = rpe["rot_rmse_deg"]
    if pose_cov is not None and samples is not None:  # the truth's coverage with the samples'
        scores.update(coverage_rank(e, pose_cov, g, samples, level))
    else:
        scores["coverage"] = None if pose_cov is None else ellipse_coverage(e, pose_cov, g, level)
    scores["coverage_level"] = level
    return scores
