"""Scenes: observations and poses, the multi-scan Problem, the scene defaults, scans of a log, scan selections."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.inference.driver import run_logodds
from bayesmap.model.generative import log_joint_scans
from bayesmap.problem import Observations, Problem
from bayesmap.runs.inputs import parse_scans
from bayesmap.scenes import log_problem, scan_problem
from bayesmap.slam.problem import log_slam_problem
from helpers import room_scans


@pytest.mark.parametrize("beam_model", ["normal", "beam"])
def test_table_log_joint_equals_assess_of_the_multi_scan_model(beam_model):
    pb = room_scans(beam_model)
    rng = np.random.default_rng(1)
    for walls in [pb.truth, np.zeros_like(pb.truth), (rng.random(pb.truth.shape) < 0.3).astype(np.float32)]:
        dense = float(log_joint_scans(walls, pb.readings, pb.pos, pb.params, pb.beam_angles))
        # the model's prior term is float32 (TFP); the table's is float64: agree to float32 rounding of ~1e2 terms
        assert pb.table_log_joint(walls) == pytest.approx(dense, rel=1e-5, abs=1e-3)
        assert pb.log_joint(walls) == pytest.approx(dense, rel=1e-6)  # small problem: assess itself


def test_multi_scan_problem_layout():
    pb = room_scans("beam")
    assert pb.multi_scan and pb.num_scans == 3 and pb.table.num_rays == 72
    assert np.array_equal(pb.scan_of_ray, np.repeat([0, 1, 2], 24))
    assert np.array_equal(pb.ray_origins[24], pb.pos[1]) and pb.ray_angles[25] == pb.beam_angles[1, 1]
    assert pb.poses.shape == (3, 3) and pb.observations.readings.shape == (3, 24)
    with pytest.raises(BayesmapError, match="take one scan; this problem has 3"):
        pb.single_scan()


def test_tutorial_is_one_scan_at_heading_zero(tutorial):
    assert not tutorial.multi_scan and tutorial.num_scans == 1
    assert np.array_equal(tutorial.poses, [[10.0, 10.0, 0.0]])
    assert tutorial.pos.shape == (2,) and tutorial.readings.shape == tutorial.beam_angles.shape == (100,)
    assert np.array_equal(tutorial.beam_angles, tutorial.observations.beam_angles[0])  # theta 0: frames agree
    readings, pos, _, angles = tutorial.single_scan()
    assert np.array_equal(readings, tutorial.readings) and np.array_equal(pos, [10.0, 10.0])
    assert np.array_equal(angles, tutorial.beam_angles)


def test_log_scenes_keep_the_logs_world_angles_bit_for_bit(small_log):
    """The ray table (and so every number) sees exactly the angles io/carmen computed; the sensor-frame angles are
    the log's beam offsets (up to the rounding of theta + offset - theta)."""
    from bayesmap.io.carmen import beam_offsets, read_carmen

    log = read_carmen(small_log)
    pb = log_problem(log, [2, 5, 7], resolution=0.2)
    assert np.array_equal(pb.beam_angles, log.angles[[2, 5, 7]])
    assert np.array_equal(pb.ray_angles, log.angles[[2, 5, 7]].reshape(-1))
    assert np.array_equal(pb.poses, log.poses[[2, 5, 7]]) and np.array_equal(pb.pos, log.poses[[2, 5, 7], :2])
    np.testing.assert_allclose(pb.observations.beam_angles, np.broadcast_to(beam_offsets(180), (3, 180)),
                               rtol=0, atol=1e-12)
    one = scan_problem(log, 5, resolution=0.2)
    assert not one.multi_scan and np.array_equal(one.beam_angles, log.angles[5]) and one.pos.shape == (2,)


def test_returned_endpoints_are_the_logs_endpoints_of_the_readings_that_returned(small_log):
    """Problem.returned_endpoints (what a figure's crop follows) holds the log's own endpoints of every returned
    beam of the chosen scans, in scan order, and none of a max-range beam."""
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(small_log)
    chosen = [2, 5, 7]
    expected = np.vstack([log.endpoints(i)[~log.is_max_range[i]] for i in chosen])
    assert 0 < len(expected) < 3 * 180  # some beams of these scans returned nothing
    np.testing.assert_allclose(log_problem(log, chosen, resolution=0.2).returned_endpoints, expected, rtol=0,
                               atol=1e-9)


def test_scan_and_log_scenes_share_max_range_and_grid(small_log):
    """One helper fits both: a single scan gets the same max-range readings and covering grid either way."""
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(small_log)
    one, many = scan_problem(log, 4, resolution=0.2), log_problem(log, [4], resolution=0.2)
    assert one.grid == many.grid and one.params.max_range == many.params.max_range == log.max_range
    assert np.array_equal(one.readings, many.readings[0]) and np.array_equal(one.max_range_mask, many.max_range_mask[0])
    assert one.max_range_mask.any() and np.all(one.readings[one.max_range_mask] == log.max_range)
    assert one.extra["pose"] == list(log.poses[4]) and one.observations.max_range == log.max_range
    for bad in (-1, 12, 2.0):
        with pytest.raises(BayesmapError, match="scan index"):
            scan_problem(log, bad)
    with pytest.raises(BayesmapError, match="scan index 12 is out of range"):
        log_problem(log, [0, 12])
    with pytest.raises(BayesmapError, match="no scan selected"):
        log_problem(log, [])


def test_log_defaults_come_from_the_scene_defaults(small_log, monkeypatch):
    from bayesmap import scenes
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(small_log)
    pb = log_problem(log, resolution=0.2)
    assert (pb.params.prior_wall_prob == pytest.approx(scenes.LOG_STRUCTURED_PRIOR)
            and pb.params.beam_model == scenes.LOG_BEAM_MODEL)
    # the prior wall probability follows the prior: the structured prior's (given balanced neighbours) by default,
    # the independent prior's with no coupling, and a given value whatever the coupling
    # (the cross-validation made the two defaults equal, so give them distinct values to tell the branches apart)
    assert pb.params.coupling > 0
    monkeypatch.setattr(scenes, "LOG_STRUCTURED_PRIOR", 0.37)
    monkeypatch.setattr(scenes, "LOG_PRIOR", 0.13)
    assert log_problem(log, resolution=0.2).params.prior_wall_prob == pytest.approx(0.37)
    assert log_problem(log, resolution=0.2, coupling=0.0).params.prior_wall_prob == pytest.approx(0.13)
    monkeypatch.undo()
    assert log_problem(log, resolution=0.2, prior_wall_prob=0.2).params.prior_wall_prob == pytest.approx(0.2)
    # every map default of a log is in meters (or a probability), the same at every resolution
    for res in (0.1, 0.2):
        pb = log_problem(log, resolution=res)
        assert pb.params.sensor_noise == pytest.approx(scenes.LOG_SENSOR_NOISE)
        assert pb.range_offset == 0.0 and pb.params.geometry == scenes.LOG_GEOMETRY == "chord"
        per_cell = scenes.endpoints_per_cell(_returned_endpoints(log), pb.grid)
        assert pb.likelihood_power == pytest.approx(scenes.log_likelihood_power(per_cell)) and pb.likelihood_power < 1
        assert pb.params.coupling == pytest.approx(scenes.log_coupling(res)) == pytest.approx(
            math.log(scenes.LOG_RUN_LENGTH / res - 1) if scenes.LOG_RUN_LENGTH >= 2 * res else 0.0)
        assert pb.extra["coupling"] == pytest.approx(pb.params.coupling)
    assert log_problem(log, resolution=0.2, coupling=0.0).params.coupling == 0.0
    # runs shorter than two cells are the independent prior's; a bad resolution is named
    assert scenes.log_coupling(0.2, run_length=0.3) == 0.0 and scenes.log_coupling(0.1, run_length=0.0) == 0.0
    with pytest.raises(BayesmapError, match="resolution"):
        scenes.log_coupling(0.0)


def test_slam_problem_keeps_the_slam_map_model(small_log):
    """``bayesmap slam --log`` keeps the map model its defaults were cross-validated with (0.05 m noise, power 0.1,
    independent prior), whatever the map defaults of logs are, in the chord geometry with no range offset."""
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(small_log)
    slam = log_slam_problem(log, resolution=0.2)
    assert slam.params.geometry == "chord" and slam.range_offset == 0.0
    assert slam.params.sensor_noise == pytest.approx(0.05) and slam.likelihood_power == pytest.approx(0.1)
    assert slam.params.coupling == 0.0
    given = log_slam_problem(log, resolution=0.2, range_offset=0.1, likelihood_power=1.0, sensor_noise=0.02)
    assert given.range_offset == 0.1 and given.likelihood_power == 1.0 and given.params.sensor_noise == 0.02


def test_slam_problem_final_map_is_the_log_map_model(small_log):
    """The final map of ``slam --log`` (run_log_slam's stage 6) is drawn in exactly the map model ``infer --log``
    uses at known poses (log_problem's defaults), on the SLAM problem's grid and beam model."""
    from bayesmap import scenes
    from bayesmap.io.carmen import read_carmen
    from bayesmap.slam.pipeline import final_map_power, scan_data

    log = read_carmen(small_log)
    for resolution in (0.1, 0.2):
        slam = log_slam_problem(log, resolution=resolution)
        known = scenes.log_problem(log, resolution=resolution)
        final = slam.final_map_params
        for name in ("sensor_noise", "coupling", "wall_pass_prob", "geometry", "neighbourhood", "prior_wall_prob",
                     "beam_model", "z_hit", "z_short", "z_max", "z_rand", "lambda_short", "max_range"):
            assert getattr(final, name) == pytest.approx(getattr(known.params, name)), name
        assert final.grid == slam.params.grid and final.wall_pass_prob > 0 and final.coupling > 0
        # the final map's power follows the readings' density at the path: at the same poses, the known-pose map's
        assert slam.final_map_power is None
        assert final_map_power(slam, scan_data(slam), slam.odometry, final.grid) == pytest.approx(
            known.likelihood_power)


def test_with_poses_moves_the_rays_and_keeps_the_observations():
    pb = room_scans("normal")
    moved = pb.poses.copy()
    moved[1] += [0.5, -0.25, 0.3]
    other = pb.with_poses(moved)
    assert other.observations is pb.observations and other.params is pb.params and other.truth is pb.truth
    assert np.array_equal(other.moved_scans(pb.poses), [1]) and len(pb.moved_scans(pb.poses)) == 0
    # world angles = theta + sensor-frame angles; only scan 1's rays change
    np.testing.assert_allclose(other.beam_angles[1], pb.beam_angles[1] + 0.3, rtol=0, atol=1e-12)
    assert np.array_equal(other.beam_angles[[0, 2]], pb.beam_angles[[0, 2]])
    np.testing.assert_allclose(other.ray_origins[24:48], np.repeat([pb.pos[1] + [0.5, -0.25]], 24, axis=0))
    rows = pb.rays_of_scans([1])
    assert np.array_equal(rows, np.arange(24, 48))
    assert np.array_equal(pb.rays_of_scans([2, 0]), np.r_[48:72, 0:24])
    # the table is rebuilt for the new poses: scan 1's first-wall distances change, the others' do not
    d_old, d_new = pb.table.first_wall_distances(pb.truth), other.table.first_wall_distances(pb.truth)
    assert not np.allclose(d_old[rows], d_new[rows])
    np.testing.assert_array_equal(np.delete(d_old, rows), np.delete(d_new, rows))
    assert np.array_equal(pb.with_poses(pb.poses).table.first_wall_distances(pb.truth), d_old)
    with pytest.raises(BayesmapError, match=r"poses must be finite numbers of shape \(3, 3\)"):
        pb.with_poses(moved[:2])
    with pytest.raises(BayesmapError, match="outside"):
        pb.with_poses(moved + [100.0, 0.0, 0.0])
    with pytest.raises(BayesmapError, match=r"scan indices must lie in 0..2, got 0..3"):
        pb.rays_of_scans([0, 3])


def test_observations_and_problem_refuse_shapes_that_do_not_match():
    pb = room_scans("normal")
    with pytest.raises(BayesmapError, match=r"one shape \(S, K\), got \(3, 24\) and \(3, 23\)"):
        Observations(pb.observations.beam_angles, pb.observations.readings[:, :23])
    with pytest.raises(BayesmapError, match=r"max_range_mask has shape \(3,\)"):
        Observations(pb.observations.beam_angles, pb.observations.readings, max_range_mask=np.zeros(3, bool))
    with pytest.raises(BayesmapError, match=r"poses must have shape \(3, 3\)"):
        Problem(params=pb.params, observations=pb.observations, poses=pb.poses[:, :2])
    with pytest.raises(BayesmapError, match="single-scan problem has one scan, got 3"):
        Problem(params=pb.params, observations=pb.observations, poses=pb.poses, multi_scan=False)
    with pytest.raises(BayesmapError, match="world_angles must equal"):
        Problem(params=pb.params, observations=pb.observations, poses=pb.poses, world_angles=pb.beam_angles + 0.1)
    with pytest.raises(BayesmapError, match="ray_table has 72 rays, the scans 48"):
        Problem(params=pb.params, observations=Observations(pb.observations.beam_angles[:2], pb.readings[:2]),
                poses=pb.poses[:2], ray_table=pb.table)
    assert Observations(pb.observations.beam_angles, pb.readings).max_range == math.inf


@pytest.mark.parametrize("spec, expected", [
    (None, list(range(10))), ("all", list(range(10))), ("3", [3]), ("-1", [9]), ("2:5", [2, 3, 4]),
    ("::4", [0, 4, 8]), ("1:8:3, 9", [1, 4, 7, 9]), ("8:", [8, 9]),
])
def test_parse_scans(spec, expected):
    assert list(parse_scans(spec, 10)) == expected


@pytest.mark.parametrize("spec, match", [("10", "scan 10 is out of range"), ("a", "bad scan selection 'a'"),
                                         ("1:2:0", "bad scan selection"), ("5:2", "selects no scan"),
                                         ("1:2:3:4", "bad scan selection")])
def test_parse_scans_errors(spec, match):
    with pytest.raises(BayesmapError, match=match):
        parse_scans(spec, 10)


def test_range_offset_shifts_only_returned_readings_the_model_scores(small_log):
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(small_log)
    pb = log_problem(log, resolution=0.2, range_offset=0.2, geometry="entry")
    assert pb.range_offset == 0.2 and pb.extra["range_offset"] == 0.2
    raw, model, is_max = pb.ray_readings, pb.model_ray_readings, pb.ray_max_range
    assert is_max.any() and (~is_max).any()
    np.testing.assert_array_equal(model[is_max], raw[is_max])  # max-range readings keep the max range
    np.testing.assert_allclose(model[~is_max], np.maximum(raw[~is_max] - 0.2, 0.0))
    # the model's log joint scores the shifted readings; the figures and log-odds keep the measured ones
    walls = np.zeros(pb.grid.shape)
    unshifted = log_problem(log, resolution=0.2, geometry="entry")  # no offset by default
    assert unshifted.range_offset == 0.0 and np.array_equal(unshifted.model_ray_readings, raw)
    assert pb.table_log_joint(walls) != unshifted.table_log_joint(walls)
    np.testing.assert_array_equal(run_logodds(pb).posterior, run_logodds(unshifted).posterior)
    for bad in (-0.1, float("nan"), 1e6):
        with pytest.raises(BayesmapError, match="range_offset"):
            log_problem(log, resolution=0.2, range_offset=bad)
    # the chord geometry models where in the cell the surface lies: the log default, with no offset
    chord = log_problem(log, resolution=0.2)
    assert chord.params.geometry == "chord" and chord.range_offset == 0.0 and chord.extra["geometry"] == "chord"
    with pytest.raises(BayesmapError, match="'inside'"):
        log_problem(log, resolution=0.2, geometry="inside")


def _returned_endpoints(log) -> np.ndarray:
    """``(N, 2)`` world endpoints of every returned beam of ``log`` (the reader's own, scan by scan)."""
    return np.concatenate([log.endpoints(i)[~log.is_max_range[i]] for i in range(len(log))])


def test_likelihood_power_default_for_logs_and_bad_powers(small_log):
    """Logs default to a tempered target whose power follows the data's density (log_likelihood_power): the same
    scans twice halve it, cells of twice the side hold more endpoints each and get a lower one; a given power wins;
    bad powers are refused with the value named."""
    from bayesmap.io.carmen import read_carmen
    from bayesmap.scenes import LOG_READINGS_PER_CELL, endpoints_per_cell, log_likelihood_power

    log = read_carmen(small_log)
    pb = log_problem(log, resolution=0.2)
    per_cell = endpoints_per_cell(_returned_endpoints(log), pb.grid)
    assert pb.likelihood_power == pytest.approx(LOG_READINGS_PER_CELL / per_cell) and pb.likelihood_power < 1
    scans = np.arange(len(log))
    twice = log_problem(log, np.concatenate([scans, scans]), resolution=0.2)
    assert twice.likelihood_power == pytest.approx(pb.likelihood_power / 2)
    assert log_problem(log, resolution=0.1).likelihood_power > pb.likelihood_power
    assert log_problem(log, resolution=0.2, readings_per_cell=2 * LOG_READINGS_PER_CELL).likelihood_power == (
        pytest.approx(2 * pb.likelihood_power))
    assert log_problem(log, resolution=0.2, likelihood_power=1).likelihood_power == 1.0
    for bad in (0, -0.5, 2, "x"):
        with pytest.raises(BayesmapError, match="likelihood_power"):
            log_problem(log, resolution=0.2, likelihood_power=bad)
    with pytest.raises(BayesmapError, match="readings_per_cell must be a finite number > 0, got -1"):
        log_likelihood_power(3.0, -1)


def test_endpoints_per_cell_counts_returned_endpoints_inside_the_grid():
    """Hand-made: 3 endpoints in one cell and 1 in another (4 over 2 cells), an endpoint outside the grid not
    counted; the power is readings_per_cell over that mean, at most 1."""
    from bayesmap.geometry.grid import Grid
    from bayesmap.scenes import endpoints_per_cell, log_likelihood_power

    grid = Grid((4, 4), resolution=1.0, origin=(0.0, 0.0))
    ends = np.array([[2.6, 0.5], [2.7, 0.5], [2.8, 0.5], [0.5, 2.5], [9.5, 0.5]])  # 3 in (2, 0), 1 in (0, 2), outside
    assert endpoints_per_cell(ends, grid) == pytest.approx(2.0)
    assert endpoints_per_cell(ends[4:], grid) == 0.0 and endpoints_per_cell(np.zeros((0, 2)), grid) == 0.0
    assert log_likelihood_power(2.0, 1.0) == pytest.approx(0.5) and log_likelihood_power(0.5, 1.0) == 1.0
    assert log_likelihood_power(0.0) == 1.0
