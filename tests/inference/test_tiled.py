"""Tiles of a map chain (bayesmap.geometry.tiles, bayesmap.inference.tiled): a tile's table gives each of its cells
exactly the conditional it has in the whole table, the frozen cells stay as they are, the tiles cover the grid once
within the budget, and a chain whose rays fit the budget is the whole table's chain."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.geometry.tiles import crossing_rays, ray_cells, rays_per_cell, split_tiles, tile_table
from bayesmap.inference.cellwise import CellwiseGibbs, cellwise_gibbs
from bayesmap.inference.chains import run_chain
from bayesmap.inference.tiled import map_chains, tiled_map_chain
from bayesmap.model.generative import make_params, ray_limits
from helpers import POSES, assess_cell_differences, four_cpu_devices_env, scenes


def _rays(seed: int, num_rays: int = 400):
    """A 24 x 30 grid of 0.2 m cells, ``num_rays`` rays from random positions inside it at random angles."""
    rng = np.random.default_rng(seed)
    grid = Grid((24, 30), resolution=0.2)
    origins = rng.uniform([0.5, 0.5], [4.3, 5.5], (num_rays, 2))
    angles = rng.uniform(-np.pi, np.pi, num_rays)
    return rng, grid, origins, angles


def _model(grid, num_rays, rng, **model):
    params = make_params(0.3, 0.3, num_rays, grid, 6.0, beam_model="beam", geometry="chord", **model)
    y = rng.uniform(0.1, 6.0, num_rays)
    y[rng.random(num_rays) < 0.2] = params.max_range  # no-return beams, exactly at the max range
    return params, y, ray_limits(y, params)


@pytest.mark.parametrize("model", [
    {},
    {"cut_past_reading": 0.5, "coupling": 0.5},
    {"wall_pass_prob": 0.2, "coupling": 0.4, "cut_past_reading": 0.6},  # every option, passable walls among them
])
def test_a_tiles_conditionals_are_the_whole_tables(model):
    """For random maps of two densities, every cell of every tile gets from its tile's table (the rest frozen)
    the conditional log-odds it gets from the whole log's table. Both are float32 sums of the same terms in another
    order: 1e-4 nats is far above their rounding (~1e-6 seen) and far below any term a wrong cut of a ray would
    drop or add (a beam's term is of order 1 nat here; the check below makes sure the maps are informative). The
    tiles' samplers are padded to the sizes of the samplers before them, as a joint chain's map blocks are (one
    compilation serves them all)."""
    rng, grid, origins, angles = _rays(1)
    params, y, limits = _model(grid, len(angles), rng, **model)
    whole = build_ray_table(grid, origins, angles, params.max_range, ray_limits=limits)
    full = CellwiseGibbs(whole, y, params)
    tiles = split_tiles(rays_per_cell(grid, origins, angles, params.max_range, limits), whole.num_pairs // 4)
    assert len(tiles) >= 4
    kept = 3 if params.penetrable else 2
    shapes = full.kernel.shapes  # every tile's arrays padded to the whole table's sizes: one compilation for all
    for density in (0.1, 0.4):
        walls = (rng.random(grid.shape) < density).astype(np.float32)
        want = np.asarray(full.cell_log_odds(walls))
        assert np.ptp(want) > 2.0
        for tile in tiles:
            table, rays = tile_table(grid, origins, angles, params.max_range, limits, walls, tile, kept, slots=2000)
            assert table.num_pairs < whole.num_pairs
            inside = tile.mask(grid.shape)
            gibbs = CellwiseGibbs(table, y[rays], params, frozen=~inside, shapes=shapes)
            shapes = gibbs.kernel.shapes
            got = np.asarray(gibbs.cell_log_odds(walls))
            np.testing.assert_allclose(got[inside], want[inside], atol=1e-4, rtol=0)


@pytest.mark.parametrize("beam_model, geometry", [("beam", "chord"), ("normal", "entry")])
def test_a_tiles_conditionals_match_the_multi_scan_models_assess(beam_model, geometry):
    """On the 3-scan scene of the cellwise tests, each tile's conditional log-odds (its own table, the rest frozen)
    equal the GenJAX model's assess with the cell set to 1 minus set to 0, for random maps: the tile's sampler draws
    from the model's exact conditional. Tolerance 1e-4 as the cellwise sampler's own test (float64 on both sides)."""
    with enable_x64():
        grid, params, angles, _, y, table = scenes(beam_model, 11, num_beams=30, geometry=geometry)
        brute = assess_cell_differences(grid, params, angles, y)
        origins = np.repeat(POSES, angles.shape[1], axis=0)
        tiles = split_tiles(table.rays_per_cell().reshape(grid.shape), table.num_pairs // 4)
        assert len(tiles) >= 4
        rng = np.random.default_rng(4)
        shapes = None  # each tile padded to the sizes of the tiles before it (one compilation for most)
        for density in (0.2, 0.5):
            walls = (rng.random(grid.shape) < density).astype(np.float64)
            want = np.asarray(brute(jnp.asarray(walls)))
            assert np.ptp(want) > 2.0
            for tile in tiles:
                sub, rays = tile_table(grid, origins, angles.reshape(-1), params.max_range, None, walls, tile, 2)
                inside = tile.mask(grid.shape)
                gibbs = CellwiseGibbs(sub, y.reshape(-1)[rays], params, frozen=~inside, shapes=shapes, headroom=0.5)
                shapes = gibbs.kernel.shapes
                got = np.asarray(gibbs.cell_log_odds(walls))
                np.testing.assert_allclose(got[inside], want[inside], atol=1e-4, rtol=0)


def test_rays_per_cell_streams_the_whole_tables_counts():
    """Counted a few hundred traced pairs at a time, the rays per cell are the whole table's, exactly."""
    rng, grid, origins, angles = _rays(2)
    params, y, limits = _model(grid, len(angles), rng, cut_past_reading=0.5)
    whole = build_ray_table(grid, origins, angles, params.max_range, ray_limits=limits)
    counts = rays_per_cell(grid, origins, angles, params.max_range, limits, slots=300)
    np.testing.assert_array_equal(counts.reshape(-1), whole.rays_per_cell())


@pytest.mark.parametrize("budget", [1, 50, 1_000, 10**9])
def test_tiles_cover_the_grid_once_within_the_budget(budget):
    """Every cell lies in exactly one tile, each tile's pairs are its cells' counts, and a tile over the budget is
    a single cell."""
    rng = np.random.default_rng(3)
    counts = rng.integers(0, 40, (13, 9)) * (rng.random((13, 9)) < 0.7)
    tiles = split_tiles(counts, budget)
    cover = np.zeros(counts.shape, int)
    for tile in tiles:
        cover += tile.mask(counts.shape)
        assert tile.pairs == counts[tile.i0:tile.i1, tile.j0:tile.j1].sum()
        assert tile.pairs <= budget or tile.num_cells == 1
    np.testing.assert_array_equal(cover, 1)
    if budget >= counts.sum():
        assert len(tiles) == 1
    with pytest.raises(ValueError, match="max_pairs"):
        split_tiles(counts, 0)


def test_crossing_rays_lists_every_ray_with_a_pair_in_the_tile():
    """Every ray with a pair inside a tile is listed (the slab test may list more, never fewer)."""
    rng, grid, origins, angles = _rays(4)
    params, y, limits = _model(grid, len(angles), rng, cut_past_reading=0.5)
    whole = build_ray_table(grid, origins, angles, params.max_range, ray_limits=limits)
    i, j = np.divmod(whole.pair_cells, grid.shape[1])
    for tile in split_tiles(whole.rays_per_cell().reshape(grid.shape), whole.num_pairs // 6):
        inside = (i >= tile.i0) & (i < tile.i1) & (j >= tile.j0) & (j < tile.j1)
        listed = crossing_rays(grid, origins, angles, limits, tile)
        assert set(np.unique(whole.pair_rays[inside])) <= set(listed)


def test_a_frozen_sweep_keeps_the_frozen_cells():
    """Sweeps with most of the grid frozen change none of its cells (and report their values), and do change the
    others; a frozen mask of another shape is refused."""
    rng, grid, origins, angles = _rays(5)
    params, y, limits = _model(grid, len(angles), rng)
    table = build_ray_table(grid, origins, angles, params.max_range, ray_limits=limits)
    frozen = np.ones(grid.shape, bool)
    frozen[5:15, 8:20] = False
    walls = (rng.random(grid.shape) < 0.3).astype(np.float32)
    chain = run_chain(jax.random.key(0), cellwise_gibbs(table, y, params, frozen=frozen), walls, 5)
    samples = np.asarray(chain.samples)
    assert (samples[:, frozen] == (walls[frozen] > 0)).all()
    np.testing.assert_array_equal(np.asarray(chain.wall_probs)[:, frozen],
                                  np.broadcast_to(walls[frozen], (5, frozen.sum())))
    assert (samples[:, ~frozen] != (walls[~frozen] > 0)).any()
    with pytest.raises(BayesmapError, match="frozen"):
        CellwiseGibbs(table, y, params, frozen=frozen[:-1])


def test_a_chain_within_the_budget_is_the_whole_tables_chain():
    """Rays whose pairs fit the budget: the same keys give the whole table's chain, bit for bit."""
    rng, grid, origins, angles = _rays(6)
    params, y, limits = _model(grid, len(angles), rng, cut_past_reading=0.5)
    walls = np.zeros(grid.shape, np.float32)
    key = jax.random.key(7)
    got = tiled_map_chain(key, params, origins, angles, y, walls, 4, max_pairs=10**9)
    table = build_ray_table(grid, origins, angles, params.max_range, ray_limits=limits)
    want = run_chain(key, cellwise_gibbs(table, y, params), walls, 4)
    assert len(got.tiles) == 1
    np.testing.assert_array_equal(got.wall_probs, np.asarray(want.wall_probs))
    np.testing.assert_array_equal(np.asarray(got.walls), np.asarray(want.samples[-1], np.float32))
    assert ray_cells(grid, origins, angles, limits).sum() >= table.num_pairs  # (the budget's estimate: above)


@pytest.mark.parametrize("margin, passes, agrees", [(0.6, 1, True), (0.6, 2, True), (0.0, 1, False)])
def test_a_tiled_chain_targets_the_same_posterior(margin, passes, agrees):
    """Two chains, one of four tiles and one of the whole table (different keys), 60 sweeps from an empty map:
    their Rao-Blackwellized marginals over the last 40 sweeps agree when the tiles are swept with a band of their
    neighbours (0.6 m, three cells). Two whole-table chains of other keys differ by up to 0.21 on a cell (0.014 on
    average) on this scene; 0.35 and 0.03 leave room for that Monte Carlo spread. Without the band a cell on a
    tile's edge takes the wall of beams that end just beyond it while the neighbour is still empty, and keeps it
    (a marginal near 1 where the whole chain's is near 0): the same check fails (measured: largest difference 1.0,
    mean 0.039; with the band 0.27 and 0.011). Two passes over the tiles (30 sweeps each) agree too (0.20, 0.013),
    and report their progress as one stage of 60 sweeps that never goes back."""
    rng, grid, origins, angles = _rays(8, num_rays=600)
    truth = rng.random(grid.shape) < 0.15
    params, _, _ = _model(grid, len(angles), rng, cut_past_reading=0.5)
    whole = build_ray_table(grid, origins, angles, params.max_range)
    ray = whole.per_pair(np.arange(whole.num_rays))  # each ray's first wall in the truth, else the max range
    dists = np.where(truth.reshape(-1)[whole.pair_cells], whole.pair_dists, np.inf)
    y = np.full(whole.num_rays, params.max_range)
    np.minimum.at(y, ray, dists)
    y = np.minimum(y + rng.normal(0, 0.05, y.shape), params.max_range).clip(0.0)
    walls = np.zeros(grid.shape, np.float32)
    budget = int(ray_cells(grid, origins, angles, ray_limits(y, params)).sum()) // 3  # four tiles
    reports = []
    tiled = tiled_map_chain(jax.random.key(1), params, origins, angles, y, walls, 60, max_pairs=budget,
                            margin=margin, passes=passes, progress=reports.append if passes > 1 else None)
    if passes > 1:
        done = [r.done for r in reports]
        assert {(r.stage, r.total) for r in reports} == {("sweeps", 60)}
        assert done[0] == 0 and done[-1] == 60 and np.all(np.diff(done) >= 0)
    plain = tiled_map_chain(jax.random.key(2), params, origins, angles, y, walls, 60, max_pairs=10**9)
    assert len(tiled.tiles) >= 4 and len(plain.tiles) == 1
    a, b = tiled.wall_probs[20:].mean(0), plain.wall_probs[20:].mean(0)
    assert (np.abs(a - b).max() < 0.35 and np.abs(a - b).mean() < 0.03) == agrees
    assert b[truth].mean() > 0.5 > b[~truth].mean()


def test_a_tile_no_beam_crosses_draws_from_the_prior():
    """A tile no beam reaches has an empty table: its cells are drawn from the prior (0.3 here, independent cells),
    and the frozen rest of the map stays as it was."""
    grid = Grid((20, 20), resolution=0.2)
    params = make_params(0.3, 0.3, 10, grid, 6.0, beam_model="beam", geometry="chord")
    origins, angles = np.tile([[0.5, 0.5]], (10, 1)), np.linspace(0.0, 0.3, 10)
    tile = split_tiles(np.ones(grid.shape), 25)[-1]  # the last 5 x 5 tile, far from the beams
    assert (tile.i0, tile.j0) == (15, 15)
    walls = np.zeros(grid.shape, np.float32)
    table, rays = tile_table(grid, origins, angles, params.max_range, None, walls, tile, 2)
    assert table.num_rays == table.num_pairs == 0 and len(rays) == 0
    inside = tile.mask(grid.shape)
    chain = run_chain(jax.random.key(0), cellwise_gibbs(table, np.full(10, 1.0)[rays], params, frozen=~inside),
                      walls, 3)
    np.testing.assert_allclose(np.asarray(chain.wall_probs)[:, inside], 0.3, rtol=1e-6)
    assert not np.asarray(chain.samples)[:, ~inside].any()


MAP_CHAINS_ON_DEVICES = """
import sys
import numpy as np
import jax
sys.path[:0] = sys.argv[2:]
from tests.inference.test_tiled import map_chains_of_a_scene
assert len(jax.devices()) == 4, jax.devices()
walls, probs = map_chains_of_a_scene(5)
np.savez(sys.argv[1], walls=walls, probs=probs)
"""


def map_chains_of_a_scene(num_chains: int):
    """``(walls, probs)`` of :func:`map_chains` on a small scene: each chain's last map and conditional wall
    probabilities, ``num_chains`` chains of 5 sweeps (keys split from 11)."""
    rng, grid, origins, angles = _rays(9, num_rays=300)
    params, y, _ = _model(grid, len(angles), rng, wall_pass_prob=0.2, coupling=0.4, cut_past_reading=0.6)
    keys = jax.random.split(jax.random.key(11), num_chains)
    runs = map_chains(keys, params, origins, angles, y, np.zeros(grid.shape, np.float32), 5, max_pairs=10**9)
    return np.stack([np.asarray(r.walls) for r in runs]), np.stack([r.wall_probs for r in runs])


def test_map_chains_split_over_four_devices_are_the_chains_one_at_a_time(tmp_path):
    """Five chains of the whole table split over four CPU devices (``shard_map``,
    ``XLA_FLAGS=--xla_force_host_platform_device_count=4`` in a fresh process; the chains of one device one after
    another) give, chain by chain, the maps and conditional probabilities of :func:`tiled_map_chain` with the same
    keys on one device, bit for bit (each device runs the same sweep on the same numbers)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    env = four_cpu_devices_env()
    out = tmp_path / "chains.npz"
    subprocess.run([sys.executable, "-c", MAP_CHAINS_ON_DEVICES, str(out), str(root), str(root / "tests")], env=env,
                   check=True, cwd=root, timeout=600)
    rng, grid, origins, angles = _rays(9, num_rays=300)
    params, y, _ = _model(grid, len(angles), rng, wall_pass_prob=0.2, coupling=0.4, cut_past_reading=0.6)
    got = np.load(out)
    for c, key in enumerate(jax.random.split(jax.random.key(11), 5)):
        one = tiled_map_chain(key, params, origins, angles, y, np.zeros(grid.shape, np.float32), 5, max_pairs=10**9)
        np.testing.assert_array_equal(got["walls"][c], np.asarray(one.walls))
        np.testing.assert_array_equal(got["probs"][c], one.wall_probs)
    assert not np.array_equal(got["probs"][0], got["probs"][1])


def test_tiles_share_one_compiled_sweep_and_pad_no_draw():
    """A chain in four tiles pads each tile's sweep to the sizes of the tile before (with a headroom of 0.5): the
    tiles compile fewer sweeps than there are tiles, and a second chain given the first's ``shapes`` compiles none,
    while its draws are those of the same chain unpadded (``shapes`` None, no headroom), bit for bit. Without the
    padding (each tile at its own sizes) every tile of this scene compiles a sweep of its own."""
    from bayesmap.inference.chains import compiled_chain_count

    rng, grid, origins, angles = _rays(8, num_rays=600)
    params, y, limits = _model(grid, len(angles), rng, cut_past_reading=0.5)
    walls = np.zeros(grid.shape, np.float32)
    budget = int(ray_cells(grid, origins, angles, limits).sum()) // 3  # four tiles

    def chain(key, shapes=None, headroom=0.0):
        return tiled_map_chain(jax.random.key(key), params, origins, angles, y, walls, 3, max_pairs=budget,
                               shapes=shapes, headroom=headroom)

    before = compiled_chain_count()
    first = chain(1, headroom=0.5)
    compiled = compiled_chain_count() - before
    assert len(first.tiles) >= 4 and 1 <= compiled < len(first.tiles)
    before = compiled_chain_count()
    padded = chain(2, first.shapes, 0.5)
    assert compiled_chain_count() == before
    plain = chain(2)
    np.testing.assert_array_equal(padded.wall_probs, plain.wall_probs)
    np.testing.assert_array_equal(padded.samples, plain.samples)
    np.testing.assert_array_equal(np.asarray(padded.walls), np.asarray(plain.walls))
