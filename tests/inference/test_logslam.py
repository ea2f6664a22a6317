"""run_log_slam's final map (stage 6): drawn after the joint chain without changing it, in the log's map model at
the mean path, and refused counts named."""

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.inference.logslam import run_log_slam
from bayesmap.io.carmen import read_carmen


@pytest.fixture(scope="module")
def slam_problem(small_log):
    from bayesmap.scenes import log_slam_problem

    return log_slam_problem(read_carmen(small_log), resolution=0.2)


RUN = {"rounds": 1, "burn_in": 0, "map_sweeps": 2, "pose_sweeps": 2, "seed": 5}


def test_final_map_leaves_the_chain_alone_and_differs_from_its_map(slam_problem):
    """Same seed with and without the final map: the same path samples and the same chain map (the final map's key
    is none of the chain's), and the reported map is another one, in the log's model (walls a beam can pass, 0.1 m
    noise, the structured prior), with the walls of the chain's map where the chain is sure of them."""
    without = run_log_slam(slam_problem, final_map_sweeps=0, **RUN)
    # 20 sweeps (10 kept): at this slice's power (0.06, 12 scans from nearly one place) 6 sweeps left 3 of the
    # chain's 30 sure walls below 0.5, 20 none (at power 0.1: 1 and none)
    with_final = run_log_slam(slam_problem, final_map_sweeps=20, **RUN)
    assert without.chain_posterior is None
    np.testing.assert_array_equal(with_final.pose_samples, without.pose_samples)
    np.testing.assert_array_equal(with_final.chain_posterior, without.posterior)
    final = with_final.posterior
    assert final.shape == without.posterior.shape and final.min() >= 0 and final.max() <= 1
    assert not np.allclose(final, without.posterior, atol=0.05)
    # the same readings at nearly the same poses: cells the chain holds for sure walls / sure free stay so
    sure_wall, sure_free = without.posterior > 0.99, without.posterior < 0.01
    assert sure_wall.sum() > 20 and sure_free.sum() > 100
    assert np.mean(final[sure_wall] > 0.5) > 0.9 and np.mean(final[sure_free] < 0.5) > 0.9


@pytest.mark.parametrize("bad", [1, -2, 2.5, True])
def test_bad_final_map_sweeps_refused_by_name(slam_problem, bad):
    with pytest.raises(BayesmapError, match="final_map_sweeps"):
        run_log_slam(slam_problem, final_map_sweeps=bad, **RUN)
