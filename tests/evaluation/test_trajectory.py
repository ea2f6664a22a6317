"""Tests for bayesmap.evaluation.trajectory: hand-made trajectories with known answers, the project's SLAM files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.evaluation.trajectory import (
    absolute_trajectory_error,
    align_rigid_2d,
    coverage_rank,
    ellipse_coverage,
    frame_of,
    relative_pose_error,
    sample_coverages,
    score_trajectory,
    similarity_scale,
)
from bayesmap.io.tum import read_tum

SLAM = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "slam"


def rotation(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def moved(poses, angle, t):
    """The poses moved rigidly: rotated by ``angle`` about the origin, then translated by ``t``."""
    poses = np.asarray(poses, dtype=float)
    return np.column_stack([poses[:, :2] @ rotation(angle).T + t, poses[:, 2] + angle])


def random_walk(rng, n=200):
    heading = np.cumsum(rng.normal(0, 0.2, n))
    steps = rng.uniform(0.1, 0.5, n)[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    return np.column_stack([np.cumsum(steps, axis=0), heading])


def circle(radii, n, theta=0.0):
    """``n`` poses on a circle about the origin at evenly spaced angles, radius ``radii`` (scalar or ``(n,)``)."""
    a = 2 * np.pi * np.arange(n) / n
    r = np.broadcast_to(radii, (n,))
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.full(n, theta)])


def test_align_recovers_a_rigid_motion():
    truth = random_walk(np.random.default_rng(1))
    estimate = moved(truth, -2.5, [30.0, -4.0])  # truth = the inverse motion applied to the estimate
    rot, t = align_rigid_2d(estimate[:, :2], truth[:, :2])
    np.testing.assert_allclose(rot, rotation(2.5), atol=1e-12)
    np.testing.assert_allclose(estimate[:, :2] @ rot.T + t, truth[:, :2], atol=1e-10)
    assert absolute_trajectory_error(estimate, truth)["max_m"] < 1e-10


def test_align_never_reflects():
    truth = random_walk(np.random.default_rng(2))
    mirror = truth * [1, -1, -1]  # the mirror image fits only with a reflection, which is not allowed
    rot, _ = align_rigid_2d(mirror[:, :2], truth[:, :2])
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(rot.T @ rot, np.eye(2), atol=1e-12)
    assert absolute_trajectory_error(mirror, truth)["rmse_m"] > 1.0


def test_align_degenerate_points_give_identity():
    rot, t = align_rigid_2d([[1.0, 2.0]], [[4.0, 6.0]])
    np.testing.assert_array_equal(rot, np.eye(2))
    np.testing.assert_allclose(t, [3.0, 4.0])


def test_ate_zero_for_a_rigidly_moved_trajectory():
    truth = random_walk(np.random.default_rng(3))
    ate = absolute_trajectory_error(moved(truth, 1.0, [-7.0, 12.0]), truth)
    assert set(ate) == {"rmse_m", "mean_m", "median_m", "max_m"}
    assert max(ate.values()) < 1e-10


@pytest.mark.parametrize("angle, t", [(0.0, [0.0, 0.0]), (0.8, [5.0, -3.0])])
def test_ate_known_offsets(angle, t):
    # truth on a circle of radius 10, estimate on concentric radii 10.1 / 10.3 alternating: by symmetry the best
    # alignment is the identity (in the estimate's own frame), leaving errors 0.1, 0.3, 0.1, 0.3, ...
    truth = circle(10.0, 8)
    estimate = moved(circle(np.tile([10.1, 10.3], 4), 8), angle, t)
    ate = absolute_trajectory_error(estimate, truth)
    assert ate["rmse_m"] == pytest.approx(math.sqrt((0.1**2 + 0.3**2) / 2), abs=1e-12)
    assert ate["mean_m"] == pytest.approx(0.2, abs=1e-12)
    assert ate["median_m"] == pytest.approx(0.2, abs=1e-12)
    assert ate["max_m"] == pytest.approx(0.3, abs=1e-12)
    # a constant offset of every position is removed by the alignment
    ring = absolute_trajectory_error(moved(circle(10.2, 8), angle, t), truth)
    assert all(v == pytest.approx(0.2, abs=1e-12) for v in ring.values())
    shifted = truth + [0.4, -0.2, 0.0]
    assert absolute_trajectory_error(shifted, truth)["max_m"] < 1e-12


def bent_line(n, k, phi):
    """A straight line of ``n`` poses 1 m apart heading along x, and the same with an extra turn ``phi`` at scan
    ``k``: poses ``k, k+1, ...`` rotated by ``phi`` about pose ``k``."""
    truth = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    estimate = truth.copy()
    estimate[k:] = moved(truth[k:] - [k, 0, 0], phi, [k, 0.0])
    return estimate, truth


def test_rpe_of_one_extra_rotation():
    n, k, phi = 30, 12, 0.3
    estimate, truth = bent_line(n, k, phi)
    rpe1 = relative_pose_error(estimate, truth, 1)
    # one pair (k-1, k) has rotation error phi and no translation error; every other pair is exact
    assert rpe1["pairs"] == n - 1
    assert rpe1["trans_rmse_m"] == pytest.approx(0.0, abs=1e-12)
    assert rpe1["rot_rmse_deg"] == pytest.approx(math.degrees(phi) / math.sqrt(n - 1), rel=1e-12)
    rpe2 = relative_pose_error(estimate, truth, 2)
    # pairs (k-2, k) and (k-1, k+1) turn by phi; (k-1, k+1) also ends 2 sin(phi/2) away from the true end
    assert rpe2["pairs"] == n - 2
    assert rpe2["rot_rmse_deg"] == pytest.approx(math.degrees(phi) * math.sqrt(2 / (n - 2)), rel=1e-12)
    assert rpe2["trans_rmse_m"] == pytest.approx(2 * math.sin(phi / 2) / math.sqrt(n - 2), rel=1e-12)


def test_rpe_is_frame_free_and_wraps_angles():
    truth = random_walk(np.random.default_rng(4))
    estimate = moved(truth, 2.0, [100.0, 50.0])
    estimate[::3, 2] += 2 * np.pi  # the same headings
    for delta in (1, 7):
        rpe = relative_pose_error(estimate, truth, delta)
        assert rpe["trans_rmse_m"] < 1e-10 and rpe["rot_rmse_deg"] < 1e-10


def test_rpe_translation_error_in_the_first_pose_frame():
    # the estimate drives 1 m forward where the truth drives 1 m to its left: error sqrt(2) whatever the heading
    truth = np.array([[0.0, 0.0, 1.0], [-math.sin(1.0), math.cos(1.0), 1.0]])
    estimate = np.array([[5.0, 5.0, -2.0], [5.0 + math.cos(-2.0), 5.0 + math.sin(-2.0), -2.0]])
    rpe = relative_pose_error(estimate, truth, 1)
    assert rpe["trans_rmse_m"] == pytest.approx(math.sqrt(2), rel=1e-12)
    assert rpe["rot_rmse_deg"] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("delta", [0, -1, 5, 6, 1.0, True, "1"])
def test_rpe_refuses_bad_delta(delta):
    poses = np.zeros((5, 3))
    with pytest.raises(BayesmapError, match=r"delta must be an integer in \[1, 4\] \(the trajectories have 5 poses\)"):
        relative_pose_error(poses, poses, delta)


@pytest.mark.parametrize("estimate, truth, message", [
    (np.zeros((3, 2)), np.zeros((3, 3)), r"estimate must have shape \(S, 3\) with S >= 1, got \(3, 2\)"),
    (np.zeros((0, 3)), np.zeros((0, 3)), r"estimate must have shape \(S, 3\) with S >= 1, got \(0, 3\)"),
    (np.zeros((3, 3)), np.zeros(3), r"truth must have shape \(S, 3\) with S >= 1, got \(3,\)"),
    (np.zeros((3, 3)), np.zeros((4, 3)), r"estimate has 3 poses but truth has 4"),
    (np.zeros((3, 3)), [[0, 0, 0], [0, 0, 0], [0, np.nan, 0]], r"truth\[2, 1\] is nan, not a finite number"),
])
def test_bad_trajectories(estimate, truth, message):
    with pytest.raises(BayesmapError, match=message):
        absolute_trajectory_error(estimate, truth)


def test_coverage_radius_is_the_chi_square_quantile():
    # every true position 1 m from its estimate (the alignment is the identity by symmetry); the 95 % ellipse of
    # an isotropic sigma has radius sigma * sqrt(-2 ln 0.05) = 2.4477 sigma
    truth, estimate = circle(10.0, 12), circle(11.0, 12)
    cov = np.zeros((12, 3, 3))
    for sigma, expected in ((1 / 2.44, 1.0), (1 / 2.45, 0.0)):
        cov[:, :2, :2] = sigma**2 * np.eye(2)
        assert ellipse_coverage(estimate, cov, truth) == expected
    cov[:, :2, :2] = np.eye(2) / 1.17**2  # radius 1.17 sigma at level 0.5 (sqrt(2 ln 2) = 1.1774)
    assert ellipse_coverage(estimate, cov, truth, level=0.5) == 1.0
    cov[:, :2, :2] = np.eye(2) / 1.18**2
    assert ellipse_coverage(estimate, cov, truth, level=0.5) == 0.0


def correlated_covariances(rng, n):
    """``(n, 3, 3)`` random covariances with elongated, tilted (x, y) blocks (std about 1.7 m along x, 0.17 m
    along y)."""
    a = rng.normal(size=(n, 3, 3)) * [[[1.0], [0.1], [0.05]]]
    cov = a @ a.transpose(0, 2, 1)
    return cov + 1e-4 * np.eye(3)


@pytest.mark.parametrize("level", [0.95, 0.5])
def test_coverage_of_samples_from_the_stated_gaussian(level):
    rng = np.random.default_rng(5)
    n = 4000
    estimate = random_walk(rng, n)
    cov = correlated_covariances(rng, n)
    noise = np.einsum("sij,sj->si", np.linalg.cholesky(cov[:, :2, :2]), rng.normal(size=(n, 2)))
    truth_here = estimate + np.column_stack([noise, np.zeros(n)])
    # the truth in another frame (rotated 1.3 rad): the alignment must bring it back before the ellipses apply
    truth = moved(truth_here, 1.3, [-20.0, 8.0])
    coverage = ellipse_coverage(estimate, cov, truth, level)
    se = math.sqrt(level * (1 - level) / n)  # binomial standard error: 0.0034 at 0.95, 0.0079 at 0.5
    assert abs(coverage - level) < 4 * se
    # the truth's frame does not matter (here the alignment is close to the identity)
    assert ellipse_coverage(estimate, cov, truth_here, level) == pytest.approx(coverage, abs=1e-3)
    wrong = cov.copy()
    wrong[:, :2, :2] = cov[:, :2, :2].transpose(0, 2, 1)[:, ::-1, ::-1]  # x and y variances swapped
    assert ellipse_coverage(estimate, wrong, truth, level) < level - 10 * se


def test_coverage_with_zero_covariance():
    truth = circle(5.0, 6)
    cov = np.zeros((6, 3, 3))
    assert ellipse_coverage(truth, cov, truth) == 1.0  # coinciding: inside a point-sized ellipse
    assert ellipse_coverage(circle(5.5, 6), cov, truth) == 0.0
    cov[:, 0, 0] = 1.0  # zero variance along y only: the radial offsets at 0 and 180 degrees lie along x
    assert ellipse_coverage(circle(5.5, 6), cov, truth) == pytest.approx(2 / 6)


@pytest.mark.parametrize("cov, level, message", [
    (np.zeros((3, 2, 2)), 0.95, r"pose_cov must have shape \(3, 3, 3\) to match the poses, got \(3, 2, 2\)"),
    (np.full((3, 3, 3), np.inf), 0.95, r"pose_cov\[0, 0, 0\] is inf, not finite"),
    (np.array([[[1, 0.5, 0], [0.4, 1, 0], [0, 0, 1]]] * 3), 0.95,
     r"pose_cov\[0\] is not symmetric: \(x, y\) entry 0.5, \(y, x\) 0.4"),
    (np.array([[[1, 2, 0], [2, 1, 0], [0, 0, 1]]] * 3), 0.95,
     r"pose_cov\[0\] is not a covariance: its \(x, y\) block has eigenvalue -1.0 < 0"),
    (np.array([np.eye(3)] * 3), 1.0, r"level must be a probability in \(0, 1\), got 1.0"),
    (np.array([np.eye(3)] * 3), 0, r"level must be a probability in \(0, 1\), got 0"),
    (np.array([np.eye(3)] * 3), "0.9", r"level must be a probability in \(0, 1\), got '0.9'"),
])
def test_coverage_refuses_bad_input(cov, level, message):
    poses = circle(1.0, 3)
    with pytest.raises(BayesmapError, match=message):
        ellipse_coverage(poses, cov, poses, level)


def test_score_trajectory_collects_the_scores():
    rng = np.random.default_rng(6)
    truth = random_walk(rng, 50)
    estimate = truth + rng.normal(0, 0.1, truth.shape)
    cov = np.array([np.diag([0.01, 0.01, 0.01])] * 50)
    scores = score_trajectory(estimate, truth, cov)
    ate = absolute_trajectory_error(estimate, truth)
    assert scores["poses"] == 50
    assert {k: scores[f"ate_{k}"] for k in ate} == ate
    for delta in (1, 10):
        rpe = relative_pose_error(estimate, truth, delta)
        assert scores[f"rpe{delta}_trans_rmse_m"] == rpe["trans_rmse_m"]
        assert scores[f"rpe{delta}_rot_rmse_deg"] == rpe["rot_rmse_deg"]
    assert scores["coverage"] == ellipse_coverage(estimate, cov, truth)
    assert scores["coverage_level"] == 0.95
    short = score_trajectory(estimate[:10], truth[:10])
    assert short["coverage"] is None
    assert "rpe1_trans_rmse_m" in short and "rpe10_trans_rmse_m" not in short  # delta 10 needs 11 poses
    with pytest.raises(BayesmapError, match="level must be a probability"):
        score_trajectory(estimate, truth, level=1.5)


# evo 1.38.1 (a scratch virtualenv, not a dependency): APE with align=True, RPE in frames with all_pairs=True, on
# X-odom.odom.tum (estimate) against X-odom.truth.tum (reference)
EVO = {
    "intel": (13.045543679524485, 11.595772081377484, 11.836891708681259, 25.121042629608283,
              0.04531329033907024, 4.757523269157393, 0.6560773957326954, 13.878053771265154),
    "aces": (16.069457780773117, 14.062096774839848, 11.768384094472346, 38.14641440620265,
             0.04961890303854711, 3.566916279668271, 0.7572224430477524, 11.339068406563051),
    "csail": (7.474510403313791, 6.490441934929532, 5.523809195516286, 15.649990431437695,
              0.05888191511131038, 2.4290190041568627, 0.6538999237488485, 7.9806445974508025),
}
README_ATE = {"intel": 13.0, "aces": 16.1, "csail": 7.5}  # data/README.md: the odometry's ATE, meters


@pytest.mark.parametrize("name", ["intel", "aces", "csail"])
def test_odometry_scores_on_the_project_data(name):
    if not SLAM.is_dir():
        pytest.skip(f"{SLAM} not present")
    _, truth = read_tum(SLAM / f"{name}-odom.truth.tum")
    _, odom = read_tum(SLAM / f"{name}-odom.odom.tum")
    scores = score_trajectory(odom, truth)
    assert scores["ate_rmse_m"] == pytest.approx(README_ATE[name], abs=0.1)
    keys = ("ate_rmse_m", "ate_mean_m", "ate_median_m", "ate_max_m", "rpe1_trans_rmse_m", "rpe1_rot_rmse_deg",
            "rpe10_trans_rmse_m", "rpe10_rot_rmse_deg")
    np.testing.assert_allclose([scores[k] for k in keys], EVO[name], rtol=1e-9)
    assert score_trajectory(truth, truth)["ate_max_m"] < 1e-9


def test_frame_of_inverts_the_alignment():
    """The true poses carried into the estimate's frame are the estimate itself when the truth is the estimate moved
    rigidly (0.7 rad, (3, -2) m): positions to 1e-9 m, headings to 1e-9 rad, wrapped to [-pi, pi). This is how a
    held-out scan's true pose lands on a SLAM map (:mod:`bayesmap.evaluation.slammap`)."""
    estimate = random_walk(np.random.default_rng(3), 50)
    truth = moved(estimate, 0.7, np.array([3.0, -2.0]))
    carried = frame_of(estimate, truth, truth[::7])
    assert np.allclose(carried[:, :2], estimate[::7, :2], atol=1e-9)
    wrapped = np.angle(np.exp(1j * estimate[::7, 2]))
    assert np.allclose(np.angle(np.exp(1j * (carried[:, 2] - wrapped))), 0.0, atol=1e-9)
    assert np.all((carried[:, 2] >= -np.pi) & (carried[:, 2] < np.pi))


def drift_posterior(rng, n, sd):
    """A path of ``n`` poses and the joint Gaussian of a posterior whose positions drift as a random walk from the
    fixed first pose (steps of ``sd`` m per axis): ``(mean (n, 3), marginal covariances (n, 3, 3), a sampler)``."""
    mean = random_walk(rng, n)
    var = sd**2 * np.arange(n)  # a random walk's variance, zero at the fixed first pose
    cov = np.zeros((n, 3, 3))
    cov[:, 0, 0] = cov[:, 1, 1] = var
    cov[:, 2, 2] = 1e-6

    def draw(k, scale=1.0):
        walk = np.cumsum(rng.normal(0.0, scale * sd, (k, n - 1, 2)), axis=1)
        out = np.repeat(mean[None], k, axis=0)
        out[:, 1:, :2] += walk
        return out

    return mean, cov, draw


def test_coverage_rank_is_uniform_for_a_calibrated_posterior_and_low_for_an_overconfident_one():
    """Truth and samples from the same drifting posterior: the truth's rank among 19 samples is uniform over runs
    (mean 0.5; 400 runs, Monte Carlo sd 0.289 / sqrt(400) = 0.014, tolerance 4 sd). A truth drifting twice as fast
    ranks low (the ellipses are too narrow)."""
    rng = np.random.default_rng(11)
    mean, cov, draw = drift_posterior(rng, 40, 0.05)
    calibrated = [coverage_rank(mean, cov, draw(1)[0], draw(19))["coverage_rank"] for _ in range(400)]
    assert abs(np.mean(calibrated) - 0.5) < 4 * 0.289 / math.sqrt(400)
    assert np.mean(np.array(calibrated) < 0.1) < 0.2  # not piled at either end: about 0.1 of them
    wide = [coverage_rank(mean, cov, draw(1, scale=2.0)[0], draw(19))["coverage_rank"] for _ in range(100)]
    assert np.mean(wide) < 0.2
    result = coverage_rank(mean, cov, draw(1)[0], draw(50))
    assert result["samples"] == 50
    assert result["samples_coverage_min"] <= result["samples_coverage_median"] <= result["samples_coverage_max"]


def test_coverage_rank_by_hand():
    """Two samples, one on the path (coverage 1) and one the truth itself (the truth's coverage): the truth ties
    one and scores below the other, rank (0 + 0.5) / 2."""
    poses = circle(1.0, 8)
    cov = np.array([np.diag([0.01, 0.01, 0.01])] * 8)
    truth = poses.copy()
    truth[::2, :2] *= 1.5  # half the poses 0.5 m off: outside an ellipse of 0.1 m sd
    result = coverage_rank(poses, cov, truth, np.stack([poses, truth]))
    assert result["coverage"] == pytest.approx(ellipse_coverage(poses, cov, truth))
    assert result["samples_coverage_max"] == 1.0 and result["samples_coverage_min"] == result["coverage"]
    assert result["coverage_rank"] == 0.25
    assert list(sample_coverages(poses, cov, np.stack([poses, truth]))) == [1.0, result["coverage"]]
    scores = score_trajectory(poses, truth, cov, samples=np.stack([poses, truth]))
    assert {k: scores[k] for k in result} == result
    assert "coverage_rank" not in score_trajectory(poses, truth, cov)


@pytest.mark.parametrize("samples, message", [
    (np.zeros((2, 7, 3)), r"samples must have shape \(N, 8, 3\)"),
    (np.zeros((0, 8, 3)), r"with N >= 1"),
    (np.full((1, 8, 3), np.nan), r"samples\[0, 0, 0\] is nan"),
])
def test_coverage_rank_refuses_bad_samples(samples, message):
    poses = circle(1.0, 8)
    cov = np.array([np.eye(3) * 0.01] * 8)
    with pytest.raises(BayesmapError, match=message):
        coverage_rank(poses, cov, poses, samples)


def test_similarity_scale_of_a_shrunk_and_moved_path():
    """A path that is the truth shrunk by 0.5 % about a point, then turned and moved: the truth is 1 / 0.995 times
    as large, whatever the motion; the same path unscaled gives 1; all positions equal give 1 (no spread to scale)."""
    truth = random_walk(np.random.default_rng(8), 80)
    shrunk = moved(np.column_stack([0.995 * (truth[:, :2] - [2.0, 1.0]), truth[:, 2]]), 1.1, [7.0, -3.0])
    assert similarity_scale(shrunk[:, :2], truth[:, :2]) == pytest.approx(1 / 0.995, rel=1e-12)
    assert similarity_scale(moved(truth, -0.3, [1.0, 2.0])[:, :2], truth[:, :2]) == pytest.approx(1.0, rel=1e-12)
    assert similarity_scale(np.ones((5, 2)), truth[:5, :2]) == 1.0
    scores = score_trajectory(shrunk, truth)
    assert scores["scale_pct"] == pytest.approx(100 * (1 / 0.995 - 1), rel=1e-9)
    with pytest.raises(BayesmapError, match="estimate has 80 poses but truth has 4"):
        similarity_scale(truth[:, :2], truth[:4, :2])
