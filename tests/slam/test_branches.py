"""Branch points and the weights of path hypotheses (bayesmap.slam.branches)."""

import numpy as np
import pytest
from scipy.stats import chi2

from bayesmap.errors import BayesmapError
from bayesmap.io.rosbag import compose_poses
from bayesmap.model.motion import make_motion_params, odometry_controls
from bayesmap.slam.branches import (
    BRANCH_GATE,
    branch_points,
    hypothesis_weights,
    rejoin_scan,
    spliced,
    step_disagreement,
    steps_apart,
)
from bayesmap.slam.posegraph import relative
from bayesmap.slam.scanmatch import MatchedPath


def test_the_gate_is_the_motion_models_999_per_mille_quantile():
    assert BRANCH_GATE == pytest.approx(chi2.ppf(0.999, 3), abs=5e-3)


def odometry_and_path():
    """A 10-pose odometry path and a path whose steps into poses 3 and 7 differ from it by a known step (in the
    frame of the pose before): ``(odometry, path, increments, covs, deviations)``."""
    rng = np.random.default_rng(2)
    odometry = np.cumsum(np.column_stack([rng.uniform(0.2, 0.4, 10), rng.uniform(-0.1, 0.1, 10),
                                          rng.uniform(-0.3, 0.3, 10)]), axis=0)
    increments, covs = (np.asarray(a, np.float64) for a in
                        odometry_controls(odometry, make_motion_params((0.1, 0.05, 0.1, 0.05))))
    deviations = {3: np.array([0.3, -0.1, 0.2]), 7: np.array([0.0, 0.05, -0.1])}
    path = [odometry[0]]
    for t in range(1, 10):
        step = increments[t - 1] + deviations.get(t, 0.0)
        path.append(compose_poses(path[-1], step))
    return odometry, np.array(path), increments, covs, deviations


def test_step_disagreement_is_the_mahalanobis_distance_of_each_step_from_the_odometrys():
    """Zero where the path takes the odometry's step; the deviation's ``d^T Sigma^-1 d`` where it does not (the
    step in the frame of the pose before, so the same deviation gives the same distance anywhere); a heading that
    differs by 2 pi is the same step."""
    _, path, increments, covs, deviations = odometry_and_path()
    distance = step_disagreement(path, increments, covs)
    for t in range(1, 10):
        d = deviations.get(t, np.zeros(3))
        assert distance[t - 1] == pytest.approx(d @ np.linalg.solve(covs[t - 1], d), rel=1e-6, abs=1e-9), t
    turned = path.copy()
    turned[5:, 2] += 2 * np.pi
    np.testing.assert_allclose(step_disagreement(turned, increments, covs), distance, atol=1e-9)
    with pytest.raises(BayesmapError, match="shapes disagree"):
        step_disagreement(path[:-1], increments, covs)


def test_branch_points_are_the_steps_beyond_the_gate_largest_first():
    _, path, increments, covs, _ = odometry_and_path()
    distance = step_disagreement(path, increments, covs)
    assert distance[2] > distance[6] > 0 and distance[6] > BRANCH_GATE  # both steps beyond the gate
    np.testing.assert_array_equal(branch_points(distance), [3, 7])
    np.testing.assert_array_equal(branch_points(distance, most=1), [3])
    np.testing.assert_array_equal(branch_points(distance, gate=distance[6]), [3])
    assert branch_points(distance, most=0).size == 0
    for bad, match in ((dict(most=-1), "most must be"), (dict(most=1.5), "most must be"),
                       (dict(gate=float("nan")), "gate must be"), (dict(gate=-1.0), "gate must be")):
        with pytest.raises(BayesmapError, match=match):
            branch_points(distance, **bad)


def test_hypothesis_weights_normalize_the_evidence():
    """``exp(evidence)`` normalized, stable for evidence of thousands of nats; refused when empty or not finite."""
    weights = hypothesis_weights([-15000.0, -15000.0 + np.log(3.0), -16000.0])
    np.testing.assert_allclose(weights, [0.25, 0.75, 0.0], atol=1e-12)
    for bad in ([], [0.0, np.nan], [np.inf]):
        with pytest.raises(BayesmapError, match="evidence must be"):
            hypothesis_weights(bad)


def test_steps_apart_is_the_mahalanobis_distance_between_two_paths_steps():
    """Two matches of the same steps: zero where they agree, ``d^T (C1 + C2)^-1 d`` where one step differs by ``d``
    (in the frame of the pose before: the same deviation gives the same distance wherever it is), whichever path
    is the longer (only the common poses count); a heading 2 pi apart is the same step."""
    odometry, path, increments, covs, deviations = odometry_and_path()
    other_covs = covs[::-1].copy()
    distance = steps_apart(path, covs, odometry, other_covs)
    for t in range(1, 10):
        d = deviations.get(t, np.zeros(3))
        assert distance[t - 1] == pytest.approx(d @ np.linalg.solve(covs[t - 1] + other_covs[t - 1], d), rel=1e-6,
                                                abs=1e-9), t
    turned = odometry.copy()
    turned[4:, 2] -= 2 * np.pi
    np.testing.assert_allclose(steps_apart(path, covs, turned, other_covs), distance, atol=1e-9)
    np.testing.assert_allclose(steps_apart(path, covs, odometry[:6], other_covs[:5]), distance[:5], atol=1e-12)
    with pytest.raises(BayesmapError, match="shapes disagree"):
        steps_apart(path, covs[:3], odometry, other_covs)


def test_a_branch_rejoins_once_its_steps_agree_over_a_local_maps_travel():
    """1 m a step, a window of 3.5 m, the branch at scan 2: with every later step agreeing it rejoins at scan 6 (4 m
    from scan 2, the first beyond 3.5 m); a disagreeing step into scan 5 starts the count again (scan 9); a step
    exactly at the gate agrees; a path that ends first never rejoins. An index outside the scans and a negative
    window are named."""
    travelled = np.arange(12.0)
    agree = np.zeros(11)
    assert rejoin_scan(agree, travelled, 2, window=3.5) == 6
    assert rejoin_scan(agree, travelled, 2, window=0.0) == 3
    late = agree.copy()
    late[4] = BRANCH_GATE + 1e-9  # the step into scan 5
    assert rejoin_scan(late, travelled, 2, window=3.5) == 9
    late[4] = BRANCH_GATE
    assert rejoin_scan(late, travelled, 2, window=3.5) == 6
    assert rejoin_scan(agree[:5], travelled, 2, window=3.5) is None  # poses 0..5 matched so far
    stopped = np.concatenate([np.arange(4.0), [3.0] * 4, np.arange(4.0, 8.0)])  # still from scan 3 to 7
    assert rejoin_scan(agree, stopped, 2, window=3.5) == 10  # travel, not scans, counts
    for point in (0, 12, 2.0):
        with pytest.raises(BayesmapError, match=f"branch point {point!r}"):
            rejoin_scan(agree, travelled, point)
    with pytest.raises(BayesmapError, match="window must be"):
        rejoin_scan(agree, travelled, 2, window=-1.0)


def test_a_spliced_branch_takes_the_single_tracks_later_steps():
    """Poses ``0 .. j`` the branch's, every later step the single track's (in the frame of the pose before, so the
    rest of the single track moved rigidly onto the branch's pose ``j``), the headings not wrapped, and the step
    covariances the branch's up to ``j`` and the single track's after; a branch of every scan is itself; one
    longer than the single track is refused."""
    odometry, path, increments, covs, _ = odometry_and_path()
    single = MatchedPath(odometry, covs)
    branch = MatchedPath(path[:5], covs[:4] * 2)
    joined = spliced(branch, single)
    np.testing.assert_array_equal(joined.path[:5], path[:5])
    np.testing.assert_allclose(relative(joined.path[4:-1], joined.path[5:]), relative(odometry[4:-1], odometry[5:]),
                               atol=1e-12)
    np.testing.assert_allclose(np.diff(joined.path[4:, 2]), np.diff(odometry[4:, 2]), atol=1e-12)
    np.testing.assert_array_equal(joined.step_cov, np.concatenate([covs[:4] * 2, covs[4:]]))
    whole = MatchedPath(path, covs * 2)
    np.testing.assert_array_equal(spliced(whole, single).path, path)
    with pytest.raises(BayesmapError, match="longer than"):
        spliced(MatchedPath(np.vstack([path, path[-1:]]), covs), single)
