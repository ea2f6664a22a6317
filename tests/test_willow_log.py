"""``benchmarks/willow_log.py``: the SLAM problem simulated in a building no default was chosen on."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import willow_log  # noqa: E402

from bayesmap.io.carmen import read_carmen  # noqa: E402


def test_a_beam_reads_the_distance_to_the_first_wall_pixel_within_its_noise():
    # a 10 x 10 m room of 0.1 m pixels, walls on its border and one pixel column at x = 7.0-7.1 m
    walls = np.zeros((100, 100), dtype=bool)
    walls[[0, -1], :] = walls[:, [0, -1]] = True
    walls[70, :] = True
    poses = np.array([[2.05, 5.05, 0.0], [2.05, 5.05, math.pi / 2]])
    ranges = willow_log.simulate_ranges(walls, 0.1, poses, np.random.default_rng(0))
    assert ranges.shape == (2, willow_log.NUM_BEAMS)
    ahead = willow_log.NUM_BEAMS // 2  # beam offset 0 (even count: -pi/2 + k pi/n)
    # straight ahead the first wall pixel starts at x = 7.0 m: 4.95 m, to the march step (0.01 m) and 4 sd of noise
    assert abs(ranges[0, ahead] - 4.95) < 0.01 + 4 * willow_log.RANGE_NOISE
    # pointing +y from y = 5.05 the border pixel starts at y = 9.9 m: 4.85 m
    assert abs(ranges[1, ahead] - 4.85) < 0.01 + 4 * willow_log.RANGE_NOISE
    # every beam inside a closed room returns
    assert np.all(ranges < willow_log.MAX_RANGE)


def test_a_beam_that_meets_no_wall_reads_the_maximum_range():
    walls = np.zeros((50, 50), dtype=bool)
    ranges = willow_log.simulate_ranges(walls, 0.1, np.array([[2.5, 2.5, 0.0]]), np.random.default_rng(0))
    assert np.all(ranges == willow_log.MAX_RANGE)


@pytest.mark.skipif(not willow_log.WILLOW_PLAN.exists(), reason="shared data not present")
def test_the_willow_tour_stays_in_free_space_and_the_log_reads_back(tmp_path):
    walls, free, resolution = willow_log.plan_cells()
    path = tmp_path / "willow.log.gz"
    poses = willow_log.write_willow_log(path)
    cells = np.floor(poses[:, :2] / resolution).astype(int)
    assert free[cells[:, 0], cells[:, 1]].all()  # no pose on a wall or in the unknown
    steps = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    # each step is the chord of 0.7 m of the tour: at most 0.7 m, shorter on a bend or where the tour turns back
    assert steps.max() <= willow_log.SCAN_SPACING + 1e-9 and np.median(steps) > willow_log.SCAN_SPACING - 0.01
    log = read_carmen(path)
    assert len(log) == len(poses) and log.ranges.shape[1] == willow_log.NUM_BEAMS
    assert np.allclose(np.asarray(log.poses), poses, atol=1e-5)
    assert log.max_range == pytest.approx(willow_log.MAX_RANGE)
    # the same log on every run
    again = willow_log.write_willow_log(tmp_path / "again.log.gz")
    assert np.array_equal(again, poses)
    assert np.array_equal(np.asarray(read_carmen(tmp_path / "again.log.gz").ranges), np.asarray(log.ranges))


def test_the_seeded_benchmarks_know_willow_but_never_choose_it_by_default(tmp_path):
    import argparse

    import seeded_logs

    from bayesmap.errors import BayesmapError

    parser = argparse.ArgumentParser()
    seeded_logs.add_log_seed_options(parser)
    args = parser.parse_args([])
    assert seeded_logs.chosen_logs(parser, args.logs) == ["intel", "aces", "csail"]
    assert seeded_logs.chosen_logs(parser, "willow,aces") == ["willow", "aces"]
    with pytest.raises(SystemExit):
        seeded_logs.chosen_logs(parser, "wilow")
    with pytest.raises(BayesmapError, match="wilow"):
        seeded_logs.corrected_log("wilow", tmp_path)
    assert seeded_logs.corrected_log("aces", tmp_path) == seeded_logs.CORRECTED_LOGS["aces"]
