import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import (
    angles,
    first_hit_chords,
    first_hit_distances,
    march_first_chord,
    march_first_hit,
    march_ray_chords,
    sensor_distances,
)
from bayesmap.geometry.raytable import build_ray_table, check_readings, visible_cells
from bayesmap.io.ascii import tutorial_map
from bayesmap.model.generative import cut_chords, make_params
from helpers import random_scene


def slab_distances(walls, pos, beam_angles, grid, max_distance):
    """Independent float64 reference: ray-box (slab) intersection with every wall cell.

    The tutorial's distance to a cell is where the ray first meets the cell's boundary: the entry distance if the
    sensor is outside the cell, the exit distance if it is inside."""
    out = []
    p = (np.asarray(pos, float) - np.asarray(grid.origin)) / grid.resolution  # corner frame: cell (i, j) = [i, i+1]
    for a in beam_angles:
        u = np.array([math.cos(a), math.sin(a)])
        best = max_distance / grid.resolution
        for i, j in zip(*np.nonzero(walls > 0)):
            lo, hi = np.array([i, j], float), np.array([i + 1, j + 1], float)
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (lo - p) / u, (hi - p) / u
            t_enter = np.max(np.minimum(t1, t2))
            t_exit = np.min(np.maximum(t1, t2))
            if t_exit < max(t_enter, 0):
                continue
            best = min(best, t_enter if t_enter >= 0 else t_exit)
        out.append(best * grid.resolution)
    return np.array(out)


def test_analytic_cases():
    walls = np.zeros((21, 21), np.float32)
    walls[15, 10] = 1  # straight ahead along +x: near edge at x = 14.5
    walls[12, 12] = 1  # on the diagonal: corner (11.5, 11.5)
    d = np.asarray(sensor_distances(walls, [10, 10], jnp.array([0.0, math.pi / 4, math.pi])))
    assert d == pytest.approx([4.5, 1.5 * math.sqrt(2), 42.0], abs=1e-5)


def test_sensor_inside_a_wall_cell_sees_its_far_edge():
    walls = np.zeros((5, 5), np.float32)
    walls[2, 2] = 1
    d = np.asarray(sensor_distances(walls, [2.25, 2.0], jnp.array([0.0, math.pi])))
    assert d == pytest.approx([0.25, 0.75], abs=1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_sensor_distances_match_an_independent_implementation(seed):
    rng = np.random.default_rng(seed)
    grid, pos, walls, beam_angles = random_scene(rng, max_side=12, metric=seed % 2 == 1)
    got = np.asarray(sensor_distances(walls, pos, beam_angles, grid=grid))
    want = slab_distances(walls, pos, beam_angles, grid, grid.default_max_distance)
    assert got == pytest.approx(want, abs=1e-5 * max(1.0, grid.resolution * 10))


def test_tutorial_scene_matches_independent_implementation():
    walls = tutorial_map()
    a = np.asarray(angles(100))
    got = np.asarray(sensor_distances(walls, [10, 10], a))
    assert got == pytest.approx(slab_distances(walls, [10, 10], a, Grid((21, 21)), 42.0), abs=1e-5)


def test_sensor_distances_jit_and_vmap():
    walls = jnp.asarray(tutorial_map())
    positions = jnp.array([[10.0, 10.0], [3.3, 17.2], [15.5, 9.25]])
    batched = jax.jit(jax.vmap(lambda p: sensor_distances(walls, p, angles(16))))(positions)
    for k in range(3):
        assert np.asarray(batched[k]) == pytest.approx(np.asarray(sensor_distances(walls, positions[k], angles(16))),
                                                       abs=1e-6)


@pytest.mark.parametrize("seed", range(8))
def test_ray_table_first_wall_equals_sensor_distances(seed):
    rng = np.random.default_rng(100 + seed)
    grid, pos, walls, beam_angles = random_scene(rng, max_side=25, metric=seed % 2 == 0)
    table = build_ray_table(grid, pos, beam_angles)
    for _ in range(3):
        walls = (rng.random(grid.shape) < rng.uniform(0.05, 0.7)).astype(np.float32)
        want = np.asarray(sensor_distances(walls, pos, beam_angles, grid=grid))
        assert table.first_wall_distances(walls) == pytest.approx(want, abs=1e-5 * max(1, grid.resolution * 10))


def test_ray_table_many_poses_and_sparsity():
    grid = Grid((21, 21))
    poses = np.array([[10.0, 10.0], [3.0, 4.5], [17.2, 15.9]])
    a = np.asarray(angles(50))
    origins = np.repeat(poses, len(a), axis=0)
    table = build_ray_table(grid, origins, np.tile(a, 3))
    walls = tutorial_map()
    for s, p in enumerate(poses):
        want = np.asarray(sensor_distances(walls, p, a))
        assert table.first_wall_distances(walls)[s * 50:(s + 1) * 50] == pytest.approx(want, abs=1e-5)
    # each ray's pairs sorted by distance; storage is the real pairs only, far fewer than rays x cells
    same_ray = np.diff(table.pair_rays) == 0
    assert np.all(np.diff(table.pair_dists)[same_ray] >= 0)
    assert table.pair_cells.shape == table.pair_dists.shape == (table.num_pairs,)
    assert table.num_pairs < 0.2 * table.num_rays * table.num_cells


def test_pairs_by_cell():
    """RayTable.pairs_by_cell is numpy's stable argsort of the pairs by cell (or by a rank per cell, with ties kept in
    pair order)."""
    grid = Grid((21, 21))
    poses = np.array([[10.0, 10.0], [3.0, 4.5], [17.2, 15.9]])
    a = np.asarray(angles(50))
    table = build_ray_table(grid, np.repeat(poses, len(a), axis=0), np.tile(a, 3))
    np.testing.assert_array_equal(table.pairs_by_cell(), np.argsort(table.pair_cells, kind="stable"))
    rank = np.random.default_rng(0).integers(0, 5, table.num_cells)  # many cells per rank
    np.testing.assert_array_equal(table.pairs_by_cell(rank), np.argsort(rank[table.pair_cells], kind="stable"))
    assert table.pairs_by_cell(rank).dtype == np.int64
    with pytest.raises(BayesmapError, match="cell ranks"):
        table.pairs_by_cell(rank - 1)


def test_tutorial_scene_table_and_visible_cells():
    table = build_ray_table(Grid((21, 21)), [10, 10], np.asarray(angles(100)))
    assert 1500 <= table.num_pairs <= 1700  # "about 1,600 (ray, cell) pairs"
    assert visible_cells(table, tutorial_map()).sum() == 217  # the tutorial's measured figure


def test_position_outside_grid_is_an_error():
    with pytest.raises(BayesmapError, match="outside the grid"):
        build_ray_table(Grid((21, 21)), [21.0, 3.0], [0.0])


@pytest.mark.parametrize("readings, match", [
    ([1.0, 2.0], "expected 3 readings, got 2"),
    ([1.0, float("nan"), 2.0], "reading 1 is nan"),
    ([1.0, 2.0, float("inf")], "reading 2 is inf"),
    ([1.0, -0.5, 2.0], "reading 1 is -0.5"),
])
def test_bad_readings(readings, match):
    with pytest.raises(BayesmapError, match=match):
        check_readings(readings, 3)


@pytest.mark.parametrize("seed", range(4))
def test_march_first_hit_equals_the_all_cells_ray_cast(seed):
    """Grid traversal against the all-cells edge test on a random grid per seed (1, 0.1 or 0.05 m cells, random
    origin), wall densities 2-30 %, eight sensors inside and outside the grid (up to half the grid away), 300 random
    angles plus the eight axis and diagonal directions, a max distance shorter or longer than the grid: equal to
    1e-5 relative (the same float32 edge arithmetic; only a ray within rounding of a grid vertex may differ, and
    random angles do not hit one). A traversal that starts in the wrong cell, steps on the wrong axis or ignores a
    sensor outside the grid misses walls by whole cells. march_first_chord: its entries are march_first_hit's and
    its chords first_hit_chords' (the same cell, the same exit arithmetic), to the same tolerance."""
    rng = np.random.default_rng(seed)
    nx, ny = (int(v) for v in rng.integers(3, 30, 2))
    grid = Grid(shape=(nx, ny), resolution=float([1.0, 0.1, 0.05, 0.1][seed]),
                origin=tuple(float(v) for v in rng.normal(size=2)))
    max_distance = float([5.0, 1000.0][seed % 2]) * grid.resolution
    longest = 0.0
    for _ in range(8):
        walls = (rng.random((nx, ny)) < rng.choice([0.02, 0.1, 0.3])).astype(np.float32)
        pos = np.asarray(grid.origin) + rng.uniform(-0.5, 1.5, 2) * np.array([nx, ny]) * grid.resolution
        beams = np.concatenate([np.arange(8) * np.pi / 4, rng.uniform(-np.pi, np.pi, 300)])
        want = np.asarray(first_hit_distances(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(beams), grid,
                                              max_distance))
        got = np.asarray(march_first_hit(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(beams), grid,
                                         max_distance))
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
        # the chord of the first wall cell (entry and exit): the same cell, so the same exit arithmetic
        chords = np.asarray(march_first_chord(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(beams), grid,
                                              max_distance))
        np.testing.assert_array_equal(chords[:, 0], got)
        np.testing.assert_allclose(chords, first_hit_chords(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(beams),
                                                            grid, max_distance), rtol=1e-5, atol=1e-6)
        longest = max(longest, float(np.max(chords[:, 1] - chords[:, 0])))
    assert longest > 0.1 * grid.resolution  # real chords, not entry = exit


@pytest.mark.parametrize("seed", range(3))
def test_a_march_stopped_past_the_cut_equals_the_whole_march_cut(seed):
    """Beams cut past their readings (cut_chords): a traversal that stops one cell past each beam's cut
    (``stops = y + cut + resolution``) gives the chords of the whole traversal once both are cut, bit for bit, on a
    random grid (1, 0.1 or 0.05 m cells) with 30 % walls, readings anywhere from 0 to past the max range and cuts of
    0.3-2 cells. The stops change the uncut result of some beams (walls past the cut no longer reached), so the
    test sees the stops at work; stopping at ``y + cut - resolution`` instead changes cut chords."""
    rng = np.random.default_rng(100 + seed)
    nx, ny = (int(v) for v in rng.integers(20, 40, 2))
    grid = Grid(shape=(nx, ny), resolution=float([1.0, 0.1, 0.05][seed]), origin=(0.0, 0.0))
    max_distance = 30.0 * grid.resolution
    params = make_params(0.3, 0.3, 1, grid, max_distance,
                         cut_past_reading=float(rng.uniform(0.3, 2.0)) * grid.resolution)
    changed = early = 0
    for _ in range(6):
        walls = jnp.asarray((rng.random((nx, ny)) < 0.3).astype(np.float32))
        pos = jnp.asarray(rng.uniform(0, 1, 2) * np.array([nx, ny]) * grid.resolution)
        beams = jnp.asarray(rng.uniform(-np.pi, np.pi, 200))
        y = jnp.asarray(rng.uniform(0, 1.1 * max_distance, 200))
        whole = march_first_chord(walls, pos, beams, grid, max_distance)
        stops = y + params.cut_past_reading + grid.resolution
        stopped = march_first_chord(walls, pos, beams, grid, max_distance, stops)
        np.testing.assert_array_equal(cut_chords(y, stopped[:, None], params), cut_chords(y, whole[:, None], params))
        np.testing.assert_array_equal(march_first_hit(walls, pos, beams, grid, max_distance, stops), stopped[:, 0])
        changed += int(np.sum(np.asarray(whole) != np.asarray(stopped)))
        short = march_first_chord(walls, pos, beams, grid, max_distance, stops - 2 * grid.resolution)
        early += int(np.sum(np.asarray(cut_chords(y, short[:, None], params))
                            != np.asarray(cut_chords(y, whole[:, None], params))))
    assert changed > 0 and early > 0


@pytest.mark.parametrize("lanes", [1, 7, 64, 4096])
def test_march_ray_chords_equals_march_first_chord_scan_by_scan(lanes):
    """Rays of five scans from five origins (inside and outside the grid, on a random grid of 0.1 m cells, 15 % walls,
    60 beams each with stops for half the scans) traversed ``lanes`` at a time: bit for bit the chords of
    march_first_chord one scan at a time, whatever the lanes (1: one ray after another; 4,096: more lanes than
    rays)."""
    rng = np.random.default_rng(lanes)
    grid = Grid(shape=(25, 31), resolution=0.1, origin=(-1.0, 0.5))
    walls = jnp.asarray((rng.random(grid.shape) < 0.15).astype(np.float32))
    origins = np.asarray(grid.origin) + rng.uniform(-0.3, 1.3, (5, 2)) * np.array(grid.shape) * grid.resolution
    beams = rng.uniform(-np.pi, np.pi, (5, 60))
    stops = rng.uniform(0.0, 4.0, (5, 60))
    stops[::2] = np.inf
    want = np.stack([march_first_chord(walls, jnp.asarray(origins[m]), jnp.asarray(beams[m]), grid, 3.0,
                                       jnp.asarray(stops[m])) for m in range(5)])
    got = march_ray_chords(walls, jnp.asarray(np.repeat(origins, 60, axis=0)), jnp.asarray(beams.reshape(-1)), grid,
                           3.0, jnp.asarray(stops.reshape(-1)), lanes=lanes)
    np.testing.assert_array_equal(np.asarray(got).reshape(5, 60, 2), want)
    assert np.sum(want[..., 0] < 3.0) > 50  # walls found, not only misses


@pytest.mark.parametrize("seed", range(3))
def test_a_sensor_inside_a_wall_cell_marches_to_the_all_cells_first_wall(seed):
    """Sensors inside wall cells (40 % walls, 0.1 m cells), 300 random angles each: the traversal's chords equal the
    all-cells cast's (first_hit_chords: the smallest distance, ties by flat index), 1e-5 relative, for
    march_first_chord and march_ray_chords. Where the ray leaves the sensor's cell into another wall cell the two
    cells tie, and the all-cells cast takes the one of smaller flat index, whose exit differs: a traversal that
    always stopped at the sensor's own cell gives exit = entry there (checked: some chords are longer than 0)."""
    rng = np.random.default_rng(200 + seed)
    grid = Grid(shape=(12, 9), resolution=0.1, origin=(0.3, -0.2))
    walls = (rng.random(grid.shape) < 0.4).astype(np.float32)
    inner = np.argwhere(walls[1:-1, 1:-1] > 0) + 1
    longest = 0.0
    for i, j in inner[rng.choice(len(inner), 6, replace=False)]:
        pos = np.asarray(grid.origin) + (np.array([i, j]) + rng.uniform(0.05, 0.95, 2)) * grid.resolution
        beams = rng.uniform(-np.pi, np.pi, 300)
        want = np.asarray(first_hit_chords(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(beams), grid, 2.0))
        got = np.asarray(march_first_chord(jnp.asarray(walls), jnp.asarray(pos), jnp.asarray(beams), grid, 2.0))
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
        lanes = march_ray_chords(jnp.asarray(walls), jnp.asarray(np.tile(pos, (300, 1))), jnp.asarray(beams), grid,
                                 2.0, lanes=16)
        np.testing.assert_array_equal(np.asarray(lanes), got)
        longest = max(longest, float(np.max(want[:, 1] - want[:, 0])))
    assert longest > 0.01
