"""The closed-form ray-cell table builder (``build_ray_table``) against the reference builder
(``build_ray_table_reference``, the original candidate-and-sort algorithm) and against the definition itself (every
cell's tutorial distance, ``cell_hit_distance``, on small grids).

Tolerance: offsets and cells (hence the order along each ray) must be identical; distances must agree to 1e-5
relative + 1e-5 cells absolute (``assert_same_table``). The builder actually reproduces the distances to the last bit
(same two float roundings as the edge arithmetic); ``test_distances_are_bit_identical`` checks that on the tutorial
scene and the Intel scans. ``RayTable.replace_rays`` (moving some scans or rays) must give exactly, field for field,
the table built from scratch at the new poses (``assert_identical_tables``).
"""

import dataclasses
import logging
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles, cell_hit_distance, sensor_distances, unit_dir
from bayesmap.geometry.raytable import RayTable, build_ray_table
from bayesmap.geometry.reference import build_ray_table_reference
from bayesmap.io.ascii import tutorial_map
from helpers import random_scene

RTOL = 1e-5
ATOL_CELLS = 1e-5


def assert_same_table(got: RayTable, want: RayTable):
    """Identical offsets and cells; distances within RTOL + ATOL_CELLS (meters: times the resolution)."""
    assert got.offsets.dtype == np.int64 and got.pair_cells.dtype == np.int32
    assert got.pair_dists.dtype == want.pair_dists.dtype
    np.testing.assert_array_equal(got.offsets, want.offsets, err_msg="pairs per ray differ")
    np.testing.assert_array_equal(got.pair_cells, want.pair_cells, err_msg="cells or their order differ")
    np.testing.assert_allclose(got.pair_dists, want.pair_dists, rtol=RTOL, atol=ATOL_CELLS * got.grid.resolution)
    assert got.max_distance == want.max_distance
    np.testing.assert_array_equal(got.origins, want.origins)
    np.testing.assert_array_equal(got.beam_angles, want.beam_angles)


@jax.jit
def _hit(p, u, cells):
    return cell_hit_distance(p, u, cells)


def brute_table(grid, origins, beam_angles, max_distance=None) -> RayTable:
    """The definition: for every ray and every cell of the grid the tutorial's distance (``cell_hit_distance`` in
    JAX's default dtype, from the same cell-frame origin and direction the model uses); keep it if below the max
    distance; sort by distance, ties by flat index. Small grids only (rays x cells evaluations)."""
    beam_angles = np.asarray(beam_angles, dtype=np.float64).reshape(-1)
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), (len(beam_angles), 2))
    max_distance = grid.default_max_distance if max_distance is None else float(max_distance)
    cap = max_distance / grid.resolution
    dtype = jnp.result_type(float)
    p = np.asarray(grid.to_cell_coords(jnp.asarray(origins, dtype=dtype)))
    u = np.asarray(unit_dir(jnp.asarray(beam_angles, dtype=dtype)))
    nx, ny = grid.shape
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    cells = np.stack([ii.ravel(), jj.ravel()], axis=-1).astype(dtype)
    rays, pairs, dists, counts = np.arange(len(beam_angles)), [], [], []
    r_all = np.repeat(rays, grid.num_cells)
    c_all = np.tile(np.arange(grid.num_cells), len(rays))
    n = len(r_all)
    size = max(256, 1 << max(n - 1, 1).bit_length())  # pad: few compiled sizes
    pad = np.zeros(size - n, dtype=np.int64)
    ridx, cidx = np.concatenate([r_all, pad]), np.concatenate([c_all, pad])
    d = np.asarray(_hit(p[ridx], u[ridx], cells[cidx]))[:n].reshape(len(rays), grid.num_cells)
    for r in rays:
        keep = np.flatnonzero(d[r] < cap)
        order = np.lexsort((keep, d[r][keep]))
        pairs.append(keep[order])
        dists.append(d[r][keep[order]])
        counts.append(len(keep))
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    dist = np.concatenate(dists) if dists else np.zeros(0, dtype=dtype)
    return RayTable(grid=grid, offsets=offsets,
                    pair_cells=(np.concatenate(pairs) if pairs else np.zeros(0)).astype(np.int32),
                    pair_dists=dist * dist.dtype.type(grid.resolution), origins=np.array(origins),
                    beam_angles=beam_angles, max_distance=max_distance)


def check_all(grid, origins, beam_angles, max_distance=None, brute=True):
    """The fast table equals the reference builder's and (small grids) the definition's."""
    table = build_ray_table(grid, origins, beam_angles, max_distance)
    assert_same_table(table, build_ray_table_reference(grid, origins, beam_angles, max_distance))
    if brute:
        assert_same_table(table, brute_table(grid, origins, beam_angles, max_distance))
    return table


def test_the_comparison_can_fail():
    grid = Grid((21, 21))
    table = build_ray_table(grid, [10.3, 9.6], np.asarray(angles(20)))
    ref = build_ray_table_reference(grid, [10.3, 9.6], np.asarray(angles(20)))
    swapped = ref.pair_cells.copy()
    swapped[[3, 4]] = swapped[[4, 3]]
    with pytest.raises(AssertionError):
        assert_same_table(table, dataclasses.replace(ref, pair_cells=swapped))
    nudged = ref.pair_dists.copy()
    nudged[5] += 1e-3
    with pytest.raises(AssertionError):
        assert_same_table(table, dataclasses.replace(ref, pair_dists=nudged))
    with pytest.raises(AssertionError):
        assert_same_table(table, build_ray_table_reference(grid, [10.3, 9.6], np.asarray(angles(20)), 5.0))


def test_tutorial_scene():
    a = np.asarray(angles(100))
    table = check_all(Grid((21, 21)), [10, 10], a)
    assert 1500 <= table.num_pairs <= 1700
    # the sensor's own cell is listed where the ray leaves it: half a cell along +x
    cells, dists = table.ray(0)
    assert 10 * 21 + 10 in cells[:2] and dists[0] == pytest.approx(0.5)
    walls = tutorial_map()
    want = np.asarray(sensor_distances(walls, [10, 10], a))
    assert table.first_wall_distances(walls) == pytest.approx(want, abs=1e-5)


def test_distances_are_bit_identical():
    rng = np.random.default_rng(5)
    for args in [(Grid((21, 21)), [10, 10], np.asarray(angles(100))),
                 (Grid((40, 30), 0.05, (3.3, -1.7)), [4.0, -0.9], rng.uniform(-4, 4, 300))]:
        np.testing.assert_array_equal(build_ray_table(*args).pair_dists, build_ray_table_reference(*args).pair_dists)


def test_distances_are_bit_identical_on_intel(intel_log):
    args = intel_scans(intel_log, 3)
    np.testing.assert_array_equal(build_ray_table(*args).pair_dists, build_ray_table_reference(*args).pair_dists)


@st.composite
def scenes(draw):
    nx, ny = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    res = draw(st.sampled_from([1.0, 0.1, 0.25, 0.7])) if draw(st.booleans()) else draw(st.floats(0.01, 3.0))
    origin = (draw(st.floats(-50, 50)), draw(st.floats(-50, 50)))
    grid = Grid((nx, ny), res, origin)
    xmin, xmax, ymin, ymax = grid.extent
    n = draw(st.integers(1, 12))
    fx = draw(st.lists(st.floats(0, 1), min_size=n, max_size=n))
    fy = draw(st.lists(st.floats(0, 1), min_size=n, max_size=n))
    pos = np.stack([xmin + np.array(fx) * (xmax - xmin), ymin + np.array(fy) * (ymax - ymin)], axis=-1)
    pos = np.clip(pos, [xmin, ymin], [xmax, ymax])
    beams = np.array(draw(st.lists(st.floats(-2 * math.pi, 4 * math.pi), min_size=n, max_size=n)))
    md = draw(st.none() | st.floats(0.0, 3.0 * max(nx, ny) * res))
    return grid, pos, beams, md


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes())
def test_random_scenes(scene):
    check_all(*scene)


def test_several_poses_at_once():
    grid = Grid((21, 21))
    poses = np.array([[10.0, 10.0], [3.0, 4.5], [17.2, 15.9], [0.1, 20.4], [-0.5, -0.5]])
    a = np.asarray(angles(50))
    origins = np.repeat(poses, len(a), axis=0)
    table = check_all(grid, origins, np.tile(a, len(poses)))
    # each scan's rays equal a table of that scan alone
    for s, p in enumerate(poses):
        alone = build_ray_table(grid, p, a)
        lo, hi = table.offsets[s * 50], table.offsets[(s + 1) * 50]
        np.testing.assert_array_equal(table.pair_cells[lo:hi], alone.pair_cells)
        np.testing.assert_array_equal(table.offsets[s * 50:(s + 1) * 50 + 1] - lo, alone.offsets)


def _corner_and_edge_positions(grid, rng, n):
    """World positions on cell corners (interior and border), edge midpoints and other points of edges."""
    nx, ny = grid.shape
    ox, oy = grid.origin
    i = rng.integers(0, nx + 1, n).astype(float)
    j = rng.integers(0, ny + 1, n).astype(float)
    kind = rng.integers(0, 3, n)
    i = np.where(kind == 1, np.minimum(i + rng.choice([0.5, 0.25, 0.8], n), nx), i)
    j = np.where(kind == 2, np.minimum(j + rng.choice([0.5, 1 / 3], n), ny), j)
    return np.stack([ox + i * grid.resolution, oy + j * grid.resolution], axis=-1)


@pytest.mark.parametrize("res, origin", [(1.0, (-0.5, -0.5)), (0.1, (-2.3, 7.1)), (0.25, (0.0, 0.0)),
                                         (0.7, (-1000.35, 512.0))])
def test_sensors_on_corners_and_edges_axis_aligned_and_diagonal_rays(res, origin):
    rng = np.random.default_rng(int(res * 100))
    grid = Grid((9, 7), res, origin)
    pos = _corner_and_edge_positions(grid, rng, 40)
    special = np.arange(-8, 17) * math.pi / 4  # axis-aligned and 45-degree rays, several turns
    origins = np.repeat(pos, len(special), axis=0)
    check_all(grid, origins, np.tile(special, len(pos)))
    # lines through grid vertices at other slopes (2:1, 1:3, ...), and the same rays nudged by an ulp or so
    slopes = np.arctan2(*np.array([[1, 2], [2, 1], [1, 3], [-3, 1], [-2, -1], [3, -2]]).T)
    nudged = np.concatenate([slopes, slopes + 1e-7, slopes - 1e-9, special + 3e-8])
    origins = np.repeat(pos[:12], len(nudged), axis=0)
    check_all(grid, origins, np.tile(nudged, 12))


def test_tutorial_corners_and_cell_centers():
    grid = Grid((21, 21))
    pos = np.array([[9.5, 9.5], [10.0, 9.5], [9.5, 10.0], [-0.5, -0.5], [20.5, 20.5], [20.5, 3.0], [3.0, -0.5],
                    [0.0, 0.0], [20.0, 20.0]])
    a = np.concatenate([np.asarray(angles(100)), np.arange(8) * math.pi / 4])
    check_all(grid, np.repeat(pos, len(a), axis=0), np.tile(a, len(pos)))


def test_rays_along_the_grid_border():
    # the reference builder used to drop these (0 / 0 in its exit distance): compare with the definition too
    grid = Grid((9, 10), 0.1, (-1.185, -2.638))
    xmin, xmax, ymin, ymax = grid.extent
    pos = np.array([[xmin, ymin], [xmin + 0.4, ymax], [xmax, ymin + 0.3], [xmax, ymax], [xmin, ymin + 0.5]])
    a = np.arange(8) * math.pi / 2
    table = check_all(grid, np.repeat(pos, len(a), axis=0), np.tile(a, len(pos)))
    cells, _ = table.ray(1 * len(a) + 0)  # from the top border along +x: the border row's cells, to the end
    assert len(cells) >= 5 and np.all(cells % grid.shape[1] == grid.shape[1] - 1)


@pytest.mark.parametrize("max_distance", [0.0, 0.5, 1.0, 2.5, 3.0, 3.5, 4.2426406871, 7.77, 30.0])
def test_max_distance_ending_inside_the_grid(max_distance):
    grid = Grid((15, 12))
    rng = np.random.default_rng(7)
    pos = np.concatenate([rng.uniform(0, 11, (6, 2)), [[7.0, 5.0], [6.5, 4.5], [7.0, 4.5]]])
    a = np.concatenate([rng.uniform(0, 2 * math.pi, 30), np.arange(8) * math.pi / 4])
    table = check_all(grid, np.repeat(pos, len(a), axis=0), np.tile(a, len(pos)), max_distance)
    assert np.all(table.pair_dists < max_distance) if table.num_pairs else True


def test_degenerate_inputs():
    check_all(Grid((1, 1)), [0.0, 0.0], [0.3])
    check_all(Grid((1, 5), 0.5), [[-0.3, 1.2], [-0.25, -0.25]], [math.pi / 2, 1.0])
    empty = build_ray_table(Grid((4, 4)), np.zeros((0, 2)), [])
    assert empty.num_rays == 0 and empty.num_pairs == 0 and empty.offsets.tolist() == [0]
    zero = check_all(Grid((4, 4)), [1.2, 2.3], angles(8), 0.0)
    assert zero.num_pairs == 0


def test_chunk_size_does_not_change_the_table():
    grid = Grid((30, 20), 0.2, (1.0, -3.0))
    rng = np.random.default_rng(3)
    xmin, xmax, ymin, ymax = grid.extent
    pos = np.stack([rng.uniform(xmin, xmax, 200), rng.uniform(ymin, ymax, 200)], axis=-1)
    a = rng.uniform(0, 2 * math.pi, 200)
    want = build_ray_table(grid, pos, a)
    for chunk in (1, 37, 1000):
        got = build_ray_table(grid, pos, a, chunk=chunk)
        np.testing.assert_array_equal(got.offsets, want.offsets)
        np.testing.assert_array_equal(got.pair_cells, want.pair_cells)
        np.testing.assert_array_equal(got.pair_dists, want.pair_dists)
    assert_same_table(want, build_ray_table_reference(grid, pos, a))


def intel_scans(path, num_scans, resolution=0.1):
    """Rays of the first ``num_scans`` scans of the Intel log, on the grid covering them (as ``scan_problem``)."""
    from bayesmap.io.carmen import read_carmen

    log = read_carmen(path)
    idx = np.arange(num_scans)
    ends = np.concatenate([log.endpoints(i)[~log.is_max_range[i]] for i in idx])
    grid = Grid.covering(np.vstack([ends, log.poses[idx, :2]]), resolution=resolution, margin=1.0)
    origins = np.repeat(log.poses[idx, :2], log.angles.shape[1], axis=0)
    return grid, origins, log.angles[idx].reshape(-1), float(log.max_range)


def test_intel_log_three_scans(intel_log):
    grid, origins, beams, max_range = intel_scans(intel_log, 3)
    table = check_all(grid, origins, beams, max_range, brute=False)
    assert table.num_rays == 3 * 180 and table.num_pairs > 30_000


def test_bad_inputs():
    grid = Grid((5, 5))
    with pytest.raises(BayesmapError, match="outside the grid"):
        build_ray_table(grid, [[1.0, 1.0], [5.0, 1.0]], [0.0, 1.0])
    with pytest.raises(BayesmapError, match="finite numbers"):
        build_ray_table(grid, [[1.0, float("nan")]], [0.0])
    with pytest.raises(BayesmapError, match="beam angle 1 is nan"):
        build_ray_table(grid, [1.0, 1.0], [0.0, float("nan")])
    with pytest.raises(BayesmapError, match=r"got shape \(3,\)"):
        build_ray_table(grid, [1.0, 1.0, 1.0], [0.0, 1.0])
    for bad in (-1.0, float("inf"), float("nan")):
        with pytest.raises(BayesmapError, match="max distance"):
            build_ray_table(grid, [1.0, 1.0], [0.0], bad)


def assert_identical_tables(got: RayTable, want: RayTable):
    """Every field equal: arrays with np.array_equal (same dtype, same bits), the rest with ==."""
    for field in dataclasses.fields(RayTable):
        a, b = getattr(got, field.name), getattr(want, field.name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype, field.name
            np.testing.assert_array_equal(a, b, err_msg=field.name)
        else:
            assert a == b, field.name


def _positions_inside(grid, rng, n):
    xmin, xmax, ymin, ymax = grid.extent
    return np.stack([rng.uniform(xmin, xmax, n), rng.uniform(ymin, ymax, n)], axis=-1)


@pytest.mark.parametrize("seed", range(12))
def test_replace_rays_equals_a_rebuild(seed):
    """Scans at random poses (some on cell corners and edges, with axis-aligned and diagonal beams); moving some
    whole scans and some single rays gives exactly the table built from scratch at the new poses, cached per-pair
    views included, and leaves the original table as it was."""
    rng = np.random.default_rng(seed)
    grid, _, _, beam_angles = random_scene(rng, max_side=12, metric=seed % 2 == 1)
    beam_angles = np.concatenate([beam_angles, np.arange(8) * math.pi / 4])
    num_beams, num_scans = len(beam_angles), int(rng.integers(2, 6))

    def poses(n):
        special = _corner_and_edge_positions(grid, rng, n)
        return np.where(rng.random((n, 1)) < 0.5, special, _positions_inside(grid, rng, n))

    origins = np.repeat(poses(num_scans), num_beams, axis=0)
    headings = np.repeat(rng.choice([0.0, math.pi / 2, rng.uniform(-math.pi, math.pi)], num_scans), num_beams)
    ray_angles = np.tile(beam_angles, num_scans) + headings
    table = build_ray_table(grid, origins, ray_angles)
    if seed % 3:  # views computed before the replacement are spliced, the others computed afresh
        table.pair_rays, table.pair_positions
    saved = {name: np.copy(getattr(table, name)) for name in ("offsets", "pair_cells", "pair_dists", "origins",
                                                               "beam_angles")}
    moved = rng.choice(num_scans, int(rng.integers(1, num_scans + 1)), replace=False)
    rays = np.concatenate([s * num_beams + np.arange(num_beams) for s in moved]
                          + [rng.choice(num_scans * num_beams, 3, replace=False)])
    rays = rng.permutation(np.unique(rays))  # any order
    new_origins, new_angles = origins.copy(), ray_angles.copy()
    new_origins[rays] = np.repeat(poses(len(rays) // num_beams + 1), num_beams, axis=0)[:len(rays)]
    new_angles[rays] += rng.choice([0.0, math.pi / 4, rng.uniform(-math.pi, math.pi)])
    got = table.replace_rays(rays, new_origins[rays], new_angles[rays], chunk=int(rng.choice([1, 50, 1 << 18])))
    want = build_ray_table(grid, new_origins, new_angles)
    assert_identical_tables(got, want)
    for view in ("lengths", "pair_rays", "pair_positions"):
        np.testing.assert_array_equal(getattr(got, view), getattr(want, view), err_msg=view)
    assert not (np.array_equal(got.offsets, table.offsets) and np.array_equal(got.pair_cells, table.pair_cells))
    for name, values in saved.items():
        np.testing.assert_array_equal(getattr(table, name), values, err_msg=name)


def test_replace_rays_of_intel_scans(intel_log):
    """Moving two scans of a real log (pose shifted by 0.37 m and turned by 0.2 rad) equals a rebuild."""
    grid, origins, beams, max_range = intel_scans(intel_log, 6)
    table = build_ray_table(grid, origins, beams, max_range)
    table.pair_rays
    rays = np.concatenate([np.arange(180, 360), np.arange(4 * 180, 5 * 180)])
    new_origins, new_angles = origins.copy(), beams.copy()
    new_origins[rays] += [0.37, -0.21]
    new_angles[rays] += 0.2
    got = table.replace_rays(rays, new_origins[rays], new_angles[rays])
    want = build_ray_table(grid, new_origins, new_angles, max_range)
    assert_identical_tables(got, want)
    np.testing.assert_array_equal(got.pair_rays, want.pair_rays)
    assert not np.array_equal(got.offsets, table.offsets)


def test_replace_no_rays_or_all_rays():
    grid = Grid((9, 7), 0.25, (1.0, -2.0))
    rng = np.random.default_rng(4)
    origins, a = _positions_inside(grid, rng, 30), rng.uniform(0, 2 * math.pi, 30)
    table = build_ray_table(grid, origins, a)
    assert_identical_tables(table.replace_rays([], np.zeros((0, 2)), []), table)
    new_origins, new_a = _positions_inside(grid, rng, 30), rng.uniform(0, 2 * math.pi, 30)
    assert_identical_tables(table.replace_rays(np.arange(30)[::-1], new_origins[::-1], new_a[::-1]),
                            build_ray_table(grid, new_origins, new_a))
    # one origin for all replaced rays
    want_origins = origins.copy()
    want_origins[[3, 4]] = [1.5, -1.0]
    assert_identical_tables(table.replace_rays([4, 3], [1.5, -1.0], a[[4, 3]]),
                            build_ray_table(grid, want_origins, a))


def test_replace_rays_bad_inputs():
    grid = Grid((5, 5))
    table = build_ray_table(grid, [[1.0, 1.0], [2.0, 3.0], [4.0, 0.5]], [0.0, 1.0, 2.0])
    with pytest.raises(BayesmapError, match="ray 1 is listed twice"):
        table.replace_rays([1, 2, 1], [2.0, 2.0], [0.0, 0.1, 0.2])
    with pytest.raises(BayesmapError, match=r"ray index 3 is outside \[0, 3\)"):
        table.replace_rays([0, 3], [2.0, 2.0], [0.0, 0.1])
    with pytest.raises(BayesmapError, match="ray index -1"):
        table.replace_rays([-1], [2.0, 2.0], [0.0])
    with pytest.raises(BayesmapError, match="must be integers"):
        table.replace_rays([0.5], [2.0, 2.0], [0.0])
    with pytest.raises(BayesmapError, match="2 rays to replace but 1 beam angles"):
        table.replace_rays([0, 1], [2.0, 2.0], [0.0])
    with pytest.raises(BayesmapError, match=r"shape \(2, 2\) or \(2,\).*got shape \(3, 2\)"):
        table.replace_rays([0, 1], np.ones((3, 2)), [0.0, 1.0])
    with pytest.raises(BayesmapError, match="outside the grid"):
        table.replace_rays([0], [7.0, 1.0], [0.0])
    with pytest.raises(BayesmapError, match="beam angle 0 is nan"):
        table.replace_rays([0], [2.0, 1.0], [float("nan")])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_rays_of_a_range_of_pairs_are_those_of_each_pair(seed, a, b):
    """``rays_of_range(start, stop)`` is ``pair_rays[start:stop]`` for any range, on tables with rays of no pairs
    (a ray limit of 0) among the others; and the exits computed with it are those of ``exits_of_pairs`` (a binary
    search a pair), to the bit."""
    grid = Grid((12, 9), 0.25, (-1.0, 0.5))
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = grid.extent
    pos = np.stack([rng.uniform(xmin, xmax, 60), rng.uniform(ymin, ymax, 60)], axis=-1)
    limits = np.where(rng.uniform(size=60) < 0.3, 0.0, 4.0)
    table = build_ray_table(grid, pos, rng.uniform(0, 2 * math.pi, 60), max_distance=4.0, ray_limits=limits)
    assert np.all(table.lengths[limits == 0] == 0) and table.num_pairs > 0
    start, stop = sorted(int(x * table.num_pairs) for x in (a, b))
    stop = max(stop, start + 1) if start < table.num_pairs else table.num_pairs
    start = min(start, stop - 1)
    np.testing.assert_array_equal(table.rays_of_range(start, stop), table.pair_rays[start:stop])
    np.testing.assert_array_equal(table.pair_exits, table.exits_of_pairs(np.arange(table.num_pairs)))


def test_cell_frame_pads_the_rays_to_a_few_lengths_and_gives_the_same_numbers(caplog):
    """``cell_frame`` runs JAX's operations on the rays padded to ``power_of_two_length`` (the next power of two, at
    least 64): each ray's numbers are those of the operations on the rays alone, bit for bit, and a batch of another
    length within the same power of two compiles no new program (without the padding, every length of a whole log's
    tiles and chunks stayed compiled: hundreds of MB on Freiburg 079's map draws)."""
    from bayesmap.geometry.traversal import cell_frame, power_of_two_length

    assert [power_of_two_length(n, 64) for n in (0, 1, 64, 65, 1000, 1024, 1025)] == [64, 64, 64, 128, 1024, 1024,
                                                                                       2048]
    assert [power_of_two_length(n, 1024) for n in (1, 1000, 1025)] == [1024, 1024, 2048]
    grid = Grid((40, 30), resolution=0.05, origin=(-1.0, 0.5))
    rng = np.random.default_rng(4)
    origins, angles_ = rng.uniform([-0.9, 0.6], [0.9, 1.9], (700, 2)), rng.uniform(-np.pi, np.pi, 700)
    p, u = cell_frame(grid, origins, angles_)
    dtype = jnp.result_type(float)
    np.testing.assert_array_equal(p, np.asarray(grid.to_cell_coords(jnp.asarray(origins, dtype))))
    np.testing.assert_array_equal(u, np.asarray(unit_dir(jnp.asarray(angles_, dtype))))
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        caplog.clear()
        p_part, u_part = cell_frame(grid, origins[:600], angles_[:600])
    assert not [r.getMessage() for r in caplog.records if "XLA compilation" in r.getMessage()]
    np.testing.assert_array_equal(p_part, p[:600])
    np.testing.assert_array_equal(u_part, u[:600])
