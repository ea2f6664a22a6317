"""Tests for bayesmap.inference.logodds: hand-made corridors with exact log-odds, OctoMap's per-scan rules, and the
tutorial scene."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.logodds import LogOddsParams, beam_hits_and_misses, logit, logodds_map, occupancy

HIT = math.log(0.7 / 0.3)  # default p_hit 0.7
MISS = math.log(0.4 / 0.6)  # default p_miss 0.4
EPS = 1e-12  # float64 rounding of the log-odds sums (a few ulps of numbers below 40)
CORRIDOR = Grid((10, 3))  # unit cells centered at integer (i, j)


def corridor_table(origins, angles, max_distance=20.0):
    return build_ray_table(CORRIDOR, origins, np.asarray(angles, float), max_distance)


def test_single_beam_along_corridor():
    # sensor at the center of cell (0, 1), beam along +x; cell (i, 1) is entered at i - 0.5 for i >= 1
    table = corridor_table([0.0, 1.0], [0.0])
    logodds = logodds_map(table, [5.0])
    expected = np.zeros((10, 3))
    expected[0:5, 1] = MISS  # the sensor's cell and cells 1-4: crossed before the endpoint
    expected[5, 1] = HIT  # x = 5.0 lies in cell 5, entered at 4.5
    # beyond the endpoint and off the beam: untouched (0)
    np.testing.assert_allclose(logodds, expected, rtol=0, atol=EPS)


def test_reading_on_a_cell_edge_hits_the_cell_entered_there():
    table = corridor_table([0.0, 1.0], [0.0])
    logodds = logodds_map(table, [4.5])  # exactly where cell 5 is entered
    assert logodds[5, 1] == pytest.approx(HIT, abs=EPS)
    assert logodds[4, 1] == pytest.approx(MISS, abs=EPS)
    assert logodds[6, 1] == 0.0


def test_a_reading_just_short_of_a_cell_edge_does_not_enter_the_cell():
    # readings are float64, table distances float32: one float64 ulp short of 4.5 (where cell 5 is entered; the
    # reading rounds to 4.5 in float32) the beam ends in cell 4
    table = corridor_table([0.0, 1.0], [0.0])
    assert table.pair_dists.dtype == np.float32
    logodds = logodds_map(table, [np.nextafter(4.5, 0.0)])
    assert logodds[4, 1] == pytest.approx(HIT, abs=EPS)
    assert logodds[3, 1] == pytest.approx(MISS, abs=EPS)
    assert logodds[5, 1] == 0.0


@pytest.mark.parametrize("reading, hit_cell", [(0.3, 9), (0.6, 8)])
def test_sensor_cell_counts_as_entered_at_zero(reading, hit_cell):
    # beam along -x from cell (9, 1): the sensor's cell and cell 8 share the table distance 0.5 (the sensor's cell
    # is listed with its exit distance); a reading inside the sensor's cell hits it, one past 0.5 hits cell 8
    table = corridor_table([9.0, 1.0], [math.pi])
    logodds = logodds_map(table, [reading])
    assert logodds[hit_cell, 1] == pytest.approx(HIT, abs=EPS)
    assert (logodds > 0).sum() == 1
    if hit_cell == 8:
        assert logodds[9, 1] == pytest.approx(MISS, abs=EPS) and (logodds < 0).sum() == 1
    else:
        assert (logodds < 0).sum() == 0


def test_max_range_beam_is_all_misses_up_to_its_reading():
    table = corridor_table([0.0, 1.0], [0.0])
    logodds = logodds_map(table, [5.0], max_range_mask=np.array([True]))
    expected = np.zeros((10, 3))
    expected[0:6, 1] = MISS  # cells entered by 5.0 m: 0-5, none a hit
    np.testing.assert_allclose(logodds, expected, rtol=0, atol=EPS)


def test_reading_beyond_the_grid_or_the_max_distance_has_no_hit():
    # the corridor ends at x = 9.5: a 12 m reading ends outside the grid, so no cell of the grid is its endpoint
    table = corridor_table([0.0, 1.0], [0.0], max_distance=20.0)
    logodds = logodds_map(table, [12.0])
    assert np.allclose(logodds[:, 1], MISS, rtol=0, atol=EPS) and (logodds > 0).sum() == 0
    # a reading equal to the table's max distance (the tutorial's "no wall") is no hit either
    table = corridor_table([0.0, 1.0], [0.0], max_distance=6.0)
    logodds = logodds_map(table, [6.0])
    assert np.allclose(logodds[0:7, 1], MISS, rtol=0, atol=EPS) and (logodds > 0).sum() == 0


def test_clamping_stops_exactly_at_the_bounds():
    params = LogOddsParams()
    scans = 40  # 40 hits would reach 40 * 0.847 = 33.9 without clamping; 40 misses -16.2
    origins = np.tile([[0.0, 1.0]], (scans, 1))
    table = corridor_table(origins, np.zeros(scans))
    logodds = logodds_map(table, np.full(scans, 5.0), scan_of_ray=np.arange(scans), params=params)
    lo, hi = params.clamp_bounds
    assert logodds[5, 1] == hi == logit(0.97)
    assert logodds[2, 1] == lo == logit(0.12)
    # below the bounds nothing is clamped: 4 hits = 3.39 < logit(0.97) = 3.48, 4 misses = -1.62 > logit(0.12) = -1.99
    # (a fifth would pass either bound); scans 3-39 merged into one scan count once
    few = logodds_map(table, np.full(scans, 5.0), scan_of_ray=np.minimum(np.arange(scans), 3))
    assert few[5, 1] == pytest.approx(4 * HIT, abs=EPS) and few[2, 1] == pytest.approx(4 * MISS, abs=EPS)
    # clamping makes the map change again quickly: after saturating, one opposite reading moves it off the bound
    table2 = corridor_table(np.tile([[0.0, 1.0]], (scans + 1, 1)), np.zeros(scans + 1))
    readings = np.r_[np.full(scans, 5.0), 8.0]  # the last scan sees through cell 5
    again = logodds_map(table2, readings, scan_of_ray=np.arange(scans + 1))
    assert again[5, 1] == pytest.approx(hi + MISS, abs=EPS)


def test_hit_wins_over_miss_within_a_scan_and_each_cell_updates_once():
    # two beams along the corridor in one scan: one ends in cell 3, the other crosses it to end in cell 7
    table = corridor_table([[0.0, 1.0], [0.0, 1.0]], [0.0, 0.0])
    one_scan = logodds_map(table, [3.0, 7.0])
    assert one_scan[3, 1] == pytest.approx(HIT, abs=EPS)  # hit wins, and not HIT + MISS
    assert one_scan[1, 1] == pytest.approx(MISS, abs=EPS)  # crossed by both beams, updated once
    assert one_scan[7, 1] == pytest.approx(HIT, abs=EPS)
    # as two scans, the updates add up
    two_scans = logodds_map(table, [3.0, 7.0], scan_of_ray=np.array([0, 1]))
    assert two_scans[3, 1] == pytest.approx(HIT + MISS, abs=EPS)
    assert two_scans[1, 1] == pytest.approx(2 * MISS, abs=EPS)
    # scan ids need not be sorted or contiguous: order of application is by id
    table3 = corridor_table(np.tile([[0.0, 1.0]], (3, 1)), np.zeros(3))
    a = logodds_map(table3, [7.0, 3.0, 7.0], scan_of_ray=np.array([5, 2, 5]))
    b = logodds_map(table3, [3.0, 7.0, 7.0], scan_of_ray=np.array([0, 1, 1]))
    np.testing.assert_array_equal(a, b)


def test_prior_shifts_start_and_updates():
    params = LogOddsParams(prior=0.3, p_miss=0.2, clamp_min=0.01, clamp_max=0.99)
    table = corridor_table([0.0, 1.0], [0.0])
    logodds = logodds_map(table, [5.0], params=params)
    l0 = logit(0.3)
    assert logodds[8, 1] == pytest.approx(l0, abs=EPS)  # untouched
    assert logodds[5, 1] == pytest.approx(logit(0.7), abs=EPS)  # Table 9.1: l0 + (logit(p_hit) - l0)
    assert logodds[2, 1] == pytest.approx(logit(0.2), abs=EPS)


def test_tutorial_scene():
    from bayesmap.scenes import tutorial_problem

    pb = tutorial_problem()
    walls = pb.truth > 0.5
    # exact readings (distance to the first wall): the hit cells are exactly the first walls seen, the miss cells
    # exactly the free cells seen
    exact = logodds_map(pb.table, pb.table.first_wall_distances(pb.truth))
    np.testing.assert_array_equal(exact > 0, pb.visible & walls)
    np.testing.assert_array_equal(exact < 0, pb.visible & ~walls)
    # the tutorial's noisy readings (sd 0.2 on 1 m cells): a reading short of the wall's near edge (half of them)
    # puts the endpoint in the free cell just before the wall. Measured: 28 of the 52 positive cells are walls
    # (0.54; 0.45-0.58 over seeds 0-4), 50 of 52 (0.96) are walls or 4-neighbours of one, all 154 negative cells
    # are free.
    noisy = logodds_map(pb.table, pb.readings)
    positive, negative = noisy > 0, noisy < 0
    assert 40 <= positive.sum() <= 70
    assert walls[positive].mean() >= 0.45
    padded = np.pad(walls, 1)
    near_wall = walls | padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:]
    assert near_wall[positive].mean() >= 0.9
    assert (~walls[negative]).mean() >= 0.98 and negative.sum() >= 120


def test_hits_and_misses_are_disjoint_with_one_hit_per_beam():
    from bayesmap.scenes import tutorial_problem

    pb = tutorial_problem()
    hit, miss = beam_hits_and_misses(pb.table, pb.readings)
    assert not (hit & miss).any()
    per_ray = np.bincount(pb.table.pair_rays[hit], minlength=pb.table.num_rays)
    assert per_ray.max() == 1
    # along each ray, the misses are exactly the cells before the hit
    for r in range(pb.table.num_rays):
        sl = slice(pb.table.offsets[r], pb.table.offsets[r + 1])
        if hit[sl].any():
            k = int(np.flatnonzero(hit[sl])[0])
            assert miss[sl][:k].all() and not miss[sl][k:].any()


def test_occupancy():
    np.testing.assert_allclose(occupancy([0.0, math.log(3.0), -math.log(3.0)]), [0.5, 0.75, 0.25], rtol=1e-15)
    assert occupancy(1000.0) == 1.0 and occupancy(-1000.0) == 0.0  # no overflow
    np.testing.assert_allclose(occupancy(logit(0.97)), 0.97, rtol=1e-14)
    with pytest.raises(BayesmapError, match="NaN"):
        occupancy([np.nan])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"p_hit": 1.0}, "p_hit must be in"),
        ({"p_miss": 0.0}, "p_miss must be in"),
        ({"p_hit": 0.45}, "p_miss < prior < p_hit"),
        ({"p_miss": 0.6}, "p_miss < prior < p_hit"),
        ({"clamp_max": 0.4}, "clamp_min <= prior <= clamp_max"),
        ({"clamp_min": "0.1"}, "clamp_min must be a probability"),
        ({"prior": True}, "prior must be a probability"),
    ],
)
def test_params_validation(kwargs, message):
    with pytest.raises(BayesmapError, match=message):
        LogOddsParams(**kwargs)


def test_bad_arguments():
    table = corridor_table([[0.0, 1.0], [0.0, 1.0]], [0.0, 0.0])
    with pytest.raises(BayesmapError, match="expected 2 readings"):
        logodds_map(table, [1.0])
    with pytest.raises(BayesmapError, match="reading 1 is -1.0"):
        logodds_map(table, [1.0, -1.0])
    with pytest.raises(BayesmapError, match="max_range_mask"):
        logodds_map(table, [1.0, 2.0], max_range_mask=np.array([1, 0]))
    with pytest.raises(BayesmapError, match="scan_of_ray must be an integer"):
        logodds_map(table, [1.0, 2.0], scan_of_ray=np.array([0.0, 1.0]))
    with pytest.raises(BayesmapError, match="scan_of_ray must be >= 0, got -1"):
        logodds_map(table, [1.0, 2.0], scan_of_ray=np.array([0, -1]))
    with pytest.raises(BayesmapError, match="params"):
        logodds_map(table, [1.0, 2.0], params=(0.7, 0.4))
