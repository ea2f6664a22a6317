"""The dense map kernel (bayesmap.inference.dense) against assess, exact enumeration and the reference sweep."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import first_hit_distances
from bayesmap.inference.chains import run_chains
from bayesmap.inference.dense import (
    MAX_DENSE_ENTRIES,
    cell_log_odds,
    dense_gibbs,
    dense_state,
    two_nearest_walls,
)
from bayesmap.inference.reference import reference_gibbs
from bayesmap.model.generative import log_joint_scans, make_params, prior_log_odds, simulate_scan_readings


def random_poses_scene(seed, shape=(5, 6), num_scans=3, num_beams=9, prior=0.3, max_distance=None):
    """A random map on a small metric grid, ``num_scans`` poses inside it with random headings, readings simulated
    from the model (clipped at 0)."""
    rng = np.random.default_rng(seed)
    grid = Grid(shape, resolution=0.5, origin=(-1.0, 0.5))
    params = make_params(prior, 0.3, 1, grid, max_distance)
    walls = (rng.random(shape) < 0.35).astype(np.float32)
    lo = np.asarray(grid.origin) + 0.2
    hi = lo + np.asarray(shape) * grid.resolution - 0.4
    poses = np.concatenate([rng.uniform(lo, hi, (num_scans, 2)), rng.uniform(-np.pi, np.pi, (num_scans, 1))], 1)
    angles = np.sort(rng.uniform(-np.pi, np.pi, (num_scans, num_beams)), axis=1)
    y = np.asarray(simulate_scan_readings(jax.random.key(seed), walls, poses[:, :2], params, poses[:, 2:3] + angles))
    return params, walls, poses, angles, np.maximum(y, 0.0)


@pytest.mark.parametrize("seed", range(3))
def test_distances_give_the_exact_ray_cast(seed):
    """Each ray's first wall distance from the dense table equals first_hit_distances (the model's ray cast), in
    float64 to 1e-12 m (the same arithmetic; only XLA's fusion may round differently)."""
    with enable_x64():
        params, walls, poses, angles, y = random_poses_scene(seed, max_distance=2.0 if seed == 2 else None)
        state = dense_state(walls, poses, angles, params)
        want = np.concatenate([np.asarray(first_hit_distances(jnp.asarray(walls), p[:2], p[2] + a, params.grid,
                                                              params.max_range)) for p, a in zip(poses, angles)])
        assert np.allclose(np.asarray(state.first), want, rtol=0, atol=1e-12)
        assert np.any(want == params.max_range) and np.any(want < params.max_range)
        assert np.all(np.asarray(state.second) >= np.asarray(state.first))


@pytest.mark.parametrize("seed", range(3))
def test_cell_conditionals_equal_assess_differences(seed):
    """For every cell and two maps, the conditional log-odds equals assess(cell wall) - assess(cell free) under the
    multi-scan model, float64, 1e-6 (the same arithmetic up to summation order, ~1e-12)."""
    with enable_x64():
        params, walls, poses, angles, y = random_poses_scene(seed, prior=[0.3, 0.5, 0.05][seed])
        prior_lo = prior_log_odds(params.prior_wall_prob)
        rng = np.random.default_rng(seed + 10)
        odds = jax.jit(lambda st, c: cell_log_odds(st, c, jnp.asarray(y.reshape(-1)), params, 1.0, prior_lo))
        for current in (walls, (rng.random(walls.shape) < 0.6).astype(np.float32)):
            state = dense_state(current, poses, angles, params)
            for c in range(current.size):
                scores = []
                for v in (0.0, 1.0):
                    w = current.reshape(-1).copy()
                    w[c] = v
                    scores.append(float(log_joint_scans(w.reshape(current.shape), y, poses[:, :2], params,
                                                        poses[:, 2:3] + angles)))
                assert abs(float(odds(state, c)) - (scores[1] - scores[0])) < 1e-6, c


def test_sweeps_keep_the_two_nearest_walls():
    """After every sweep the state's per-ray first and second wall distances equal those recomputed from the map
    (the incremental insert/remove rules are right), and the chain moves."""
    params, walls, poses, angles, y = random_poses_scene(4, shape=(6, 6), num_scans=4, num_beams=12)
    kernel = dense_gibbs(poses, angles, y, params)
    state = kernel.init(jnp.zeros(walls.shape))
    step = jax.jit(kernel.step)
    changed = 0
    for k in range(6):
        old = state.walls
        state, info = step(jax.random.key(k), state)
        changed += int(jnp.sum(old != state.walls))
        first, second = two_nearest_walls(state.distances, state.walls, params.max_range)
        assert np.array_equal(np.asarray(first), np.asarray(state.first))
        assert np.array_equal(np.asarray(second), np.asarray(state.second))
        prob = np.asarray(info.wall_prob)
        assert prob.shape == walls.shape and np.all((prob >= 0) & (prob <= 1))
    assert changed > 0


def test_marginals_match_exact_enumeration():
    """3 x 4 grid (4,096 maps), two scans of 6 beams: 64 chains x 300 sweeps against the enumerated marginals.
    Tolerance 0.06 as tests/inference/test_fast_exact.py (above 4 Monte Carlo standard errors, <= 0.014 each)."""
    grid = Grid((3, 4))
    params = make_params(0.4, 0.4, 1, grid)
    truth = np.zeros((3, 4), np.float32)
    truth[2, 3] = truth[0, 3] = truth[2, 0] = 1
    poses = np.array([[1.3, 0.6, 0.2], [0.4, 2.2, -1.0]])
    angles = np.tile(np.linspace(-np.pi, np.pi, 6, endpoint=False), (2, 1))
    y = np.abs(np.asarray(simulate_scan_readings(jax.random.key(5), truth, poses[:, :2], params,
                                                 poses[:, 2:3] + angles), float))
    maps = np.array(list(itertools.product([0.0, 1.0], repeat=12)), np.float32).reshape(-1, 3, 4)
    lj = np.array([float(log_joint_scans(m, y, poses[:, :2], params, poses[:, 2:3] + angles)) for m in maps])
    w = np.exp(lj - lj.max())
    exact = np.tensordot(w / w.sum(), maps, axes=1)
    assert np.abs(exact - 0.5).max() > 0.3  # informative data: the test can fail
    result = run_chains(jax.random.key(11), dense_gibbs(poses, angles, y, params), jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.samples[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.06, (est, exact)
    rb = np.asarray(result.wall_probs[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(rb - exact).max() < 0.06, (rb, exact)


def test_sweep_equals_the_reference_raster_sweep(tutorial):
    """On the tutorial scene (one scan), with the same keys, dense sweeps make the same draws as the assess-based
    reference raster sweep (both draw each cell with categorical over (free, wall) from split keys): 4 sweeps from
    an empty map, in float64, where the two conditionals agree to ~1e-12 (in float32 assess's totals, ~1e3, round at
    ~1e-4 and about one draw in a thousand lands on the other side of its threshold)."""
    from bayesmap.geometry.raycast import angles as tutorial_angles

    with enable_x64():
        pos, readings, params = np.asarray(tutorial.pos), np.asarray(tutorial.readings), tutorial.params
        beams = np.asarray(tutorial_angles(params.num_angles), float)
        dense = dense_gibbs(np.array([[pos[0], pos[1], 0.0]]), beams[None], readings[None], params)
        reference = reference_gibbs(readings, pos, params)
        d_state, r_state = dense.init(jnp.zeros(params.grid.shape)), reference.init(jnp.zeros(params.grid.shape))
        d_step, r_step = jax.jit(dense.step), jax.jit(reference.step)
        for k in range(4):
            d_state, _ = d_step(jax.random.key(k), d_state)
            r_state, _ = r_step(jax.random.key(k), r_state)
            assert np.array_equal(np.asarray(d_state.walls), np.asarray(r_state.walls)), k
        assert 20 < float(jnp.sum(d_state.walls)) < 400


def test_bad_arguments_are_errors():
    params, walls, poses, angles, y = random_poses_scene(0)
    with pytest.raises(BayesmapError, match="readings"):
        dense_gibbs(poses, angles, y[:, :3], params)
    with pytest.raises(BayesmapError, match="poses"):
        dense_gibbs(poses[:2], angles, y, params)
    with pytest.raises(BayesmapError, match="likelihood_power"):
        dense_gibbs(poses, angles, y, params, likelihood_power=0.0)
    with pytest.raises(BayesmapError, match="readings must be >= 0"):
        dense_gibbs(poses, angles, -y, params)
    big = make_params(0.3, 0.3, 1, Grid((512, 512)))
    rays = MAX_DENSE_ENTRIES // (512 * 512) + 1
    with pytest.raises(BayesmapError, match="MAX_DENSE_ENTRIES"):
        dense_gibbs(np.zeros((1, 3)), np.zeros((1, rays)), np.ones((1, rays)), big)


def test_moving_the_poses_does_not_recompile():
    """The dense state and sweep at other poses (same S, K, grid) reuse the compiled code: one cache entry."""
    from bayesmap.inference.dense import dense_sweep

    params, walls, poses, angles, y = random_poses_scene(1)
    lo = prior_log_odds(params.prior_wall_prob)
    flat_y = jnp.asarray(y.reshape(-1), jnp.float32)

    @jax.jit
    def sweep(key, p, w):
        return dense_sweep(key, dense_state(w, p, angles, params), flat_y, params, 1.0, lo)[0].walls

    first = sweep(jax.random.key(0), poses, walls)
    moved = poses + np.array([0.1, -0.05, 0.3])
    second = sweep(jax.random.key(0), moved, walls)
    assert sweep._cache_size() == 1
    assert not np.array_equal(np.asarray(dense_state(walls, moved, angles, params).distances),
                              np.asarray(dense_state(walls, poses, angles, params).distances))
    assert first.shape == second.shape == walls.shape
