"""Branch points and the weights of path hypotheses (bayesmap.slam.branches)."""

import numpy as np
import pytest
from scipy.stats import chi2

from bayesmap.errors import BayesmapError
from bayesmap.io.rosbag import compose_poses
from bayesmap.model.motion import make_motion_params, odometry_controls
from bayesmap.slam.branches import BRANCH_GATE, branch_points, hypothesis_weights, step_disagreement


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
