"""The fast samplers sample exactly the reference conditionals."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.chains import run_chains
from bayesmap.inference.fast import FastGibbs
from bayesmap.inference.reference import block_log_weights, reference_gibbs
from bayesmap.inference.schedules import cell_rays
from bayesmap.model.generative import log_joint, make_params, model_args, simulate_readings
from helpers import sweeps_keep_ray_bits


def scene(rng, prior, shape=None, num_angles=None):
    shape = shape or (int(rng.integers(4, 8)), int(rng.integers(4, 8)))
    grid = Grid(shape)
    params = make_params(prior_wall_prob=prior, sensor_noise=0.3, num_angles=num_angles or int(rng.integers(5, 30)),
                         grid=grid)
    pos = np.array([rng.uniform(0, shape[0] - 1), rng.uniform(0, shape[1] - 1)])
    truth = (rng.random(shape) < 0.3).astype(np.float32)
    i, j = np.floor(pos + 0.5).astype(int)
    truth[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2] = 0  # keep readings positive
    for k in range(100):
        y = np.asarray(simulate_readings(jax.random.key(k), truth, pos, params), float)
        if (y >= 0).all():
            break
    args = model_args(pos, params)
    table = build_ray_table(grid, pos, np.asarray(args[2]), params.max_range)
    return params, pos, y, args, table


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("block_size", [1, 2])
def test_fast_log_odds_equal_assess_reference(seed, block_size):
    """Log-odds of every cell / block configuration vs the assess reference, in float64, to 1e-4."""
    with jax.experimental.enable_x64():
        rng = np.random.default_rng(seed)
        params, pos, y, args, table = scene(rng, prior=[0.5, 0.05][seed % 2])
        fast = FastGibbs(table, y, params, block_size=block_size, pos=pos)
        reference_weights = jax.jit(block_log_weights)
        for trial in range(2):
            walls = (rng.random(params.grid.shape) < 0.4).astype(np.float64)
            got_all = np.asarray(fast.block_log_weights(walls))
            assert got_all.shape == (len(fast.blocks), 2 ** block_size ** 2)
            for b, cells in enumerate(fast.blocks):
                got = got_all[b]
                want = np.asarray(reference_weights(jnp.asarray(walls), jnp.asarray(cells), jnp.asarray(y), args))
                assert np.allclose(got - got[0], want - want[0], atol=1e-4, rtol=0)


def conflicts(blocks, table):
    rays_of = cell_rays(table)
    rays = [set(np.concatenate([rays_of[c] for c in b]).tolist()) for b in blocks]
    cells = [set(b.tolist()) for b in blocks]
    return lambda a, b: bool(rays[a] & rays[b]) or bool(cells[a] & cells[b])


@pytest.mark.parametrize("schedule", ["sequential", "chromatic"])
@pytest.mark.parametrize("block_size", [1, 2])
def test_levels_are_valid_schedules(schedule, block_size):
    rng = np.random.default_rng(3)
    params, pos, y, args, table = scene(rng, 0.5, shape=(7, 6), num_angles=25)
    fast = FastGibbs(table, y, params, block_size=block_size, schedule=schedule, pos=pos)
    nb = len(fast.blocks)
    level_of = {}
    for lv, row in enumerate(fast.levels):
        for b in row[row < nb]:
            assert b not in level_of
            level_of[int(b)] = lv
    assert sorted(level_of) == list(range(nb))  # every block exactly once per sweep
    conflict = conflicts(fast.blocks, table)
    for a, b in itertools.combinations(range(nb), 2):
        if conflict(a, b):
            assert level_of[a] != level_of[b]  # a level holds only conditionally independent blocks
            if schedule == "sequential":
                assert level_of[a] < level_of[b]  # conflicting updates keep the sweep's order


def exact_marginals(params, pos, y, beam_angles=None):
    nx, ny = params.grid.shape
    maps = np.array(list(itertools.product([0.0, 1.0], repeat=nx * ny)), dtype=np.float32).reshape(-1, nx, ny)
    lj = jax.jit(jax.vmap(lambda w: log_joint(w, y, pos, params, beam_angles)))(jnp.asarray(maps))
    w = np.exp(np.asarray(lj, float) - np.max(np.asarray(lj, float)))
    w /= w.sum()
    return np.tensordot(w, maps, axes=1)


@pytest.mark.parametrize("sampler, prior, pos", [
    ("raster", 0.5, (1.3, 0.6)),
    ("outward", 0.2, (0.4, 2.2)),
    ("chromatic", 0.5, (2.0, 1.5)),
    ("block", 0.1, (1.3, 0.6)),
    ("chromatic-block", 0.5, (0.7, 1.1)),
])
def test_marginals_match_exact_enumeration(sampler, prior, pos):
    """3 x 4 grid (4,096 maps), 7 rays, sensor off center: enumerate the posterior; run 64 chains x 300 sweeps.

    Tolerance: each marginal estimate averages 64 independent chains of 250 kept sweeps; its Monte Carlo standard
    error is at most sqrt(0.25 / n_eff) with n_eff >= 64 * 20 even for slowly mixing cells (autocorrelation time
    <= 12), i.e. <= 0.014; we allow 0.06 (above 4 standard errors) for all 12 cells at once."""
    from bayesmap.problem import Problem

    grid = Grid((3, 4))
    params = make_params(prior_wall_prob=prior, sensor_noise=0.4, num_angles=7, grid=grid)
    truth = np.zeros((3, 4), np.float32)
    truth[2, 3] = truth[0, 3] = truth[2, 0] = 1
    pos = np.array(pos)
    y = np.abs(np.asarray(simulate_readings(jax.random.key(5), truth, pos, params), float))
    exact = exact_marginals(params, pos, y)
    from bayesmap.geometry.raycast import angles
    from bayesmap.inference.registry import make_sampler

    problem = Problem.from_world_frame(params, pos, np.asarray(angles(7), float), y, truth=truth)
    result = run_chains(jax.random.key(11), make_sampler(problem, sampler), jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.samples[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.06, (est, exact)
    assert np.abs(exact - 0.5).max() > 0.3  # the data are informative: the test can fail


def test_reference_sampler_matches_exact_enumeration():
    """The assess-based reference passes the same check (smaller run: 16 chains x 150 sweeps, tolerance 0.1)."""
    grid = Grid((3, 3))
    params = make_params(prior_wall_prob=0.3, sensor_noise=0.4, num_angles=6, grid=grid)
    truth = np.zeros((3, 3), np.float32)
    truth[2, 2] = truth[0, 2] = 1
    pos = np.array([0.8, 0.3])
    y = np.abs(np.asarray(simulate_readings(jax.random.key(2), truth, pos, params), float))
    exact = exact_marginals(params, pos, y)
    result = run_chains(jax.random.key(4), reference_gibbs(y, pos, params, block_size=1), jnp.zeros((3, 3)), 150, 16)
    est = np.asarray(result.samples[:, 30:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.1, (est, exact)


@pytest.mark.parametrize("schedule", ["sequential", "chromatic"])
@pytest.mark.parametrize("block_size", [1, 2])
@pytest.mark.parametrize("capacity", [1, 3, None])
def test_sweep_keeps_ray_bits_consistent(schedule, block_size, capacity):
    """The sweep reads every ray's walls from where the ray's previous update wrote them (never from the map):
    after each sweep the state's bit strings must equal those recomputed from the new map. Small level
    capacities force split levels and blocks drawn over several steps (chunks of their rays)."""
    rng = np.random.default_rng(7)
    params, pos, y, args, table = scene(rng, 0.3, shape=(6, 7), num_angles=40)
    fast = FastGibbs(table, y, params, block_size=block_size, schedule=schedule, pos=pos, level_capacity=capacity)
    if capacity == 1:
        assert not np.all(np.asarray(fast._steps.commit))  # blocks drawn over several steps are exercised
    state = fast.init(jnp.asarray(rng.random(params.grid.shape) < 0.5, jnp.float32))
    assert sweeps_keep_ray_bits(fast, state, 5) > 0  # the chain moves


@pytest.mark.parametrize("block_size, prior", [(1, 0.5), (2, 0.2)])
def test_split_levels_sample_the_exact_posterior(block_size, prior):
    """Enumeration check (as above) with level capacity 1: every level with more than one (block, ray) entry is
    split, and blocks crossed by several rays are drawn over several steps; the kernel must stay the same."""
    grid = Grid((3, 4))
    params = make_params(prior_wall_prob=prior, sensor_noise=0.4, num_angles=7, grid=grid)
    truth = np.zeros((3, 4), np.float32)
    truth[2, 3] = truth[0, 3] = truth[2, 0] = 1
    pos = np.array([1.3, 0.6])
    y = np.abs(np.asarray(simulate_readings(jax.random.key(5), truth, pos, params), float))
    exact = exact_marginals(params, pos, y)
    table = build_ray_table(grid, pos, np.asarray(model_args(pos, params)[2]), params.max_range)
    fast = FastGibbs(table, y, params, block_size=block_size, pos=pos, level_capacity=1)
    assert not np.all(np.asarray(fast._steps.commit))
    result = run_chains(jax.random.key(3), fast.algorithm, jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.samples[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.06, (est, exact)  # tolerance: see test_marginals_match_exact_enumeration


def test_fast_conditionals_with_several_poses():
    """One table for rays from three poses (a multi-scan problem): every cell's log-odds equal the brute-force
    difference of log joints, computed from each ray's first wall (itself tested against ``sensor_distances``)."""
    with jax.experimental.enable_x64():
        rng = np.random.default_rng(11)
        grid = Grid((6, 7))
        params = make_params(prior_wall_prob=0.3, sensor_noise=0.4, num_angles=12, grid=grid)
        poses = np.array([[1.2, 1.1], [4.3, 5.2], [2.6, 3.9]])
        beam = np.asarray(model_args(poses[0], params)[2], float)
        origins = np.repeat(poses, len(beam), axis=0)
        table = build_ray_table(grid, origins, np.tile(beam, len(poses)), params.max_range)
        y = rng.uniform(0.3, 6.0, table.num_rays)
        fast = FastGibbs(table, y, params, block_size=1)
        s, p = params.sensor_noise, params.prior_wall_prob

        def log_joint_np(walls):
            d = table.first_wall_distances(walls).astype(float)
            prior = np.sum(np.where(walls > 0, np.log(p), np.log1p(-p)))
            return prior + np.sum(-0.5 * ((y - d) / s) ** 2)

        walls = (rng.random(grid.shape) < 0.35).astype(float)
        got = np.asarray(fast.block_log_weights(walls))
        for b, (cell,) in enumerate(fast.blocks):
            on, off = walls.copy().reshape(-1), walls.copy().reshape(-1)
            on[cell], off[cell] = 1, 0
            want = log_joint_np(on.reshape(grid.shape)) - log_joint_np(off.reshape(grid.shape))
            assert got[b, 1] - got[b, 0] == pytest.approx(want, abs=1e-4)


@pytest.mark.parametrize("schedule", ["chromatic", "sequential"])
@pytest.mark.parametrize("block_size", [1, 2])
def test_blocks_of_a_level_get_their_own_conditionals(schedule, block_size):
    """Computed together in one level, every block's conditional equals the one it gets alone (the sweep's levels
    hold only blocks that share no cell and no ray): the same conditionals as a one-block-at-a-time sweep."""
    with jax.experimental.enable_x64():
        rng = np.random.default_rng(5)
        params, pos, y, args, table = scene(rng, 0.3, shape=(6, 7), num_angles=30)
        fast = FastGibbs(table, y, params, block_size=block_size, schedule=schedule, pos=pos)
        walls = (rng.random(params.grid.shape) < 0.4).astype(float)
        alone = np.asarray(fast.block_log_weights(walls))
        count = np.bincount(fast._entries[0], minlength=len(fast.blocks))
        largest = max(int(count[row[row < len(fast.blocks)]].sum()) for row in fast.levels)
        together = fast._pack(fast.levels, largest, chained=False)[0]  # one step per level, reading the map
        ray_bits = fast.ray_bits(walls)
        scores = np.asarray(jax.vmap(lambda lv: fast.kernel._level_scores(ray_bits[lv.src], lv)[0])(together))
        checked = 0
        for lv, row in enumerate(fast.levels):
            for slot, b in enumerate(row):
                if b < len(fast.blocks):
                    got = scores[lv, slot]
                    got = np.array([0.0, got]) if got.ndim == 0 else got - got[0]
                    assert np.allclose(got, alone[b] - alone[b, 0], atol=1e-6)
                    checked += 1
        assert checked == len(fast.blocks)
        assert (fast.levels < len(fast.blocks)).sum(axis=1).max() > 1  # levels do hold several blocks
