"""The structured prior (bayesmap.model.prior): the GenJAX model's assess, every sampler's
conditional against assess differences, sampler marginals against exact enumeration, and the schedules."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import enable_x64

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.inference.cellwise import CellwiseGibbs
from bayesmap.inference.chains import run_chains
from bayesmap.inference.dense import cell_log_odds, dense_gibbs, dense_state
from bayesmap.inference.fast import FastGibbs
from bayesmap.inference.reference import block_log_weights, reference_gibbs, reference_incremental_gibbs
from bayesmap.inference.schedules import chromatic_levels, dependency_levels
from bayesmap.model.generative import (
    choices,
    full_model,
    log_joint,
    make_params,
    model_args,
    multi_scan_model,
    prior_log_odds,
    scan_args,
    simulate,
    simulate_readings,
    simulate_scan_readings,
)
from bayesmap.model.prior import (
    coupling_for_run_length,
    disagreeing_pairs,
    internal_agreements,
    log_prior,
    neighbour_field,
    neighbour_indices,
    sample_prior,
)
from helpers import POSES, mrf_enumeration_scene, replay_one_at_a_time, run_cli, scenes

COUPLING = 0.8


def brute_field(walls):
    """n_wall - n_free over the in-grid 4-neighbours, by loops."""
    nx, ny = walls.shape
    out = np.zeros((nx, ny))
    for i, j in itertools.product(range(nx), range(ny)):
        for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)):
            if 0 <= a < nx and 0 <= b < ny:
                out[i, j] += 1 if walls[a, b] > 0 else -1
    return out


def test_prior_helpers():
    rng = np.random.default_rng(0)
    walls = (rng.random((5, 7)) < 0.4).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(neighbour_field(walls)), brute_field(walls))
    pairs = sum(walls[i, j] != walls[i + 1, j] for i in range(4) for j in range(7)) + sum(
        walls[i, j] != walls[i, j + 1] for i in range(5) for j in range(6))
    assert int(disagreeing_pairs(walls)) == pairs
    near = neighbour_indices((5, 7))
    assert near.shape == (35, 4) and set(near[0]) == {-1, 7, 1} and sorted(near[8]) == [1, 7, 9, 15]
    configs = np.array(list(itertools.product([0, 1], repeat=4)))
    agree = internal_agreements((2, 2), configs)
    assert agree[0] == agree[-1] == 4 and agree[0b0110] == 0 and agree[0b0011] == 2
    assert coupling_for_run_length(0.5, 0.1) == pytest.approx(np.log(4.0))
    assert coupling_for_run_length(0.2, 0.1) == 0.0
    for bad in (0.15, float("nan")):
        with pytest.raises(BayesmapError, match="run_length"):
            coupling_for_run_length(bad, 0.1)
    for bad in (-0.1, float("inf"), "x", 25.0):
        with pytest.raises(BayesmapError, match="coupling"):
            make_params(coupling=bad)
    with pytest.raises(BayesmapError, match="neighbourhood"):
        make_params(coupling=0.5, neighbourhood=0)


def test_zero_coupling_leaves_the_model_unchanged(tutorial):
    """J = 0: no "connections" address, the same simulated walls and readings, the same assess."""
    params = make_params(0.2)
    assert not params.structured and make_params(0.2, coupling=0.0) == params
    trace = full_model.simulate(jax.random.key(3), model_args([10, 10], params))
    assert trace.get_choices().get_submap("connections").static_is_empty()
    structured_trace = full_model.simulate(jax.random.key(3), model_args([10, 10], make_params(0.2, coupling=0.5)))
    assert not structured_trace.get_choices().get_submap("connections").static_is_empty()
    structured = make_params(0.2, coupling=COUPLING)
    a, b = simulate(jax.random.key(3), [10, 10], params), simulate(jax.random.key(3), [10, 10], structured)
    np.testing.assert_array_equal(np.asarray(a[0]), np.asarray(b[0]))  # the connections come last: same keys
    np.testing.assert_array_equal(np.asarray(a[1]), np.asarray(b[1]))
    assert float(log_joint(tutorial.truth, tutorial.readings, tutorial.pos, make_params(prior_wall_prob=0.05))) \
        == pytest.approx(-164.7, abs=0.05)


@pytest.mark.parametrize("seed", range(3))
def test_assess_is_the_mrf_up_to_a_constant(seed):
    """assess(walls, readings, connections = 1) = the independent model's assess - J * (differing pairs); flipping
    one cell changes it by the independent difference plus J (n_wall - n_free)."""
    with enable_x64():
        rng = np.random.default_rng(seed)
        grid = Grid((4, 5))
        plain = make_params(0.3, 0.4, 9, grid)
        params = make_params(0.3, 0.4, 9, grid, coupling=[0.4, 1.3, 3.0][seed])
        pos, y = np.array([1.3, 2.2]), rng.uniform(0.2, 4, 9)
        walls = (rng.random(grid.shape) < 0.5).astype(np.float64)
        got = float(log_joint(walls, y, pos, params))
        want = float(log_joint(walls, y, pos, plain)) - params.coupling * int(disagreeing_pairs(walls))
        assert got == pytest.approx(want, abs=1e-9)
        lp = float(log_prior(walls, 0.3, params.coupling))
        independent = np.sum(np.where(walls > 0, np.log(0.3), np.log(0.7)))
        assert lp == pytest.approx(independent - params.coupling * int(disagreeing_pairs(walls)), abs=1e-9)
        for c in range(walls.size):
            on, off = walls.reshape(-1).copy(), walls.reshape(-1).copy()
            on[c], off[c] = 1, 0
            on, off = on.reshape(grid.shape), off.reshape(grid.shape)
            diff = float(log_joint(on, y, pos, params)) - float(log_joint(off, y, pos, params))
            base = float(log_joint(on, y, pos, plain)) - float(log_joint(off, y, pos, plain))
            assert diff == pytest.approx(base + params.coupling * brute_field(walls).reshape(-1)[c], abs=1e-9)


def test_simulated_connections_follow_their_law():
    """simulate draws each connection with probability exp(J ([agree] - 1)): about e^-J of differing pairs are 1."""
    params = make_params(0.5, 0.4, 4, Grid((30, 30)), coupling=1.0)
    args = model_args([15, 15], params)

    @jax.jit  # the same draws as un-jitted simulate (checked: identical for these keys), 3x faster
    def draw(key):
        chm = full_model.simulate(key, args).get_choices()
        return chm["walls"], chm["connections"]

    agree_on, differ_on, differ = 0, 0, 0
    for k in range(4):
        walls, c = draw(jax.random.key(k))
        walls, c = np.asarray(walls) > 0, np.asarray(c)
        w = np.asarray(walls)
        same = np.stack([w == np.concatenate([w[1:], w[-1:]]), w == np.concatenate([w[:, 1:], w[:, -1:]], 1)])
        agree_on += int((~c[same]).sum())
        differ_on += int(c[~same].sum())
        differ += int((~same).sum())
    assert agree_on == 0
    rate = differ_on / differ
    assert abs(rate - np.exp(-1.0)) < 4 * np.sqrt(np.exp(-1) * (1 - np.exp(-1)) / differ)


def single_scan_scene(seed, coupling=COUPLING, shape=(5, 6), num_angles=20):
    rng = np.random.default_rng(seed)
    grid = Grid(shape)
    params = make_params(0.3, 0.3, num_angles, grid, coupling=coupling)
    pos = np.array([rng.uniform(1, shape[0] - 2), rng.uniform(1, shape[1] - 2)])
    truth = (rng.random(shape) < 0.3).astype(np.float32)
    i, j = np.floor(pos + 0.5).astype(int)
    truth[i - 1:i + 2, j - 1:j + 2] = 0
    y = np.abs(np.asarray(simulate_readings(jax.random.key(seed), truth, pos, params), float))
    args = model_args(pos, params)
    table = build_ray_table(grid, pos, np.asarray(args[2]), params.max_range)
    return params, pos, y, args, table


@pytest.mark.parametrize("schedule", ["sequential", "chromatic"])
@pytest.mark.parametrize("block_size", [1, 2])
def test_fast_conditionals_equal_assess(schedule, block_size):
    """Every block's log-weights (each configuration) against the assess reference, float64, 1e-6."""
    with enable_x64():
        params, pos, y, args, table = single_scan_scene(1)
        fast = FastGibbs(table, y, params, block_size=block_size, schedule=schedule, pos=pos)
        reference = jax.jit(block_log_weights)
        rng = np.random.default_rng(2)
        for _ in range(2):
            walls = (rng.random(params.grid.shape) < 0.45).astype(np.float64)
            got_all = np.asarray(fast.block_log_weights(walls))
            for b, cells in enumerate(fast.blocks):
                want = np.asarray(reference(jnp.asarray(walls), jnp.asarray(cells), jnp.asarray(y), args))
                np.testing.assert_allclose(got_all[b] - got_all[b, 0], want - want[0], atol=1e-6, rtol=0)


@pytest.mark.parametrize("schedule", ["sequential", "chromatic"])
@pytest.mark.parametrize("block_size", [1, 2])
def test_levels_hold_no_neighbouring_blocks(schedule, block_size):
    """With the structured prior no level holds two blocks with cells that share an edge (their conditionals read
    each other), and the sequential levels keep the order of every such pair."""
    params, pos, y, args, table = single_scan_scene(3, shape=(6, 7))
    fast = FastGibbs(table, y, params, block_size=block_size, schedule=schedule, pos=pos)
    near = neighbour_indices(params.grid.shape)
    level_of = {int(b): lv for lv, row in enumerate(fast.levels) for b in row[row < len(fast.blocks)]}
    touching = 0
    for a, b in itertools.combinations(range(len(fast.blocks)), 2):
        if set(near[fast.blocks[a]].reshape(-1)) & set(fast.blocks[b]):
            touching += 1
            assert level_of[a] != level_of[b]
            if schedule == "sequential":
                assert level_of[a] < level_of[b]
    assert touching > 0
    # without neighbours the same blocks can share a level
    plain = dependency_levels(fast.blocks, table) if schedule == "sequential" else chromatic_levels(fast.blocks, table)
    assert len(plain) <= len(fast.levels)


def test_cellwise_and_dense_conditionals_equal_assess():
    """The cellwise sampler's (three scans, beam model, likelihood power 1 and 0.3) and the dense kernel's cell
    log-odds against assess differences with the cell set to 1 and to 0, float64, 1e-4 (as test_cellwise)."""
    with enable_x64():
        grid, plain, angles, _, y, table = scenes("beam", 7)
        params = make_params(0.3, 0.4, 10, grid, 6.0, beam_model="beam", coupling=COUPLING)
        readings = jnp.asarray(y)

        def differences(p):
            args = scan_args(POSES, p, angles)

            @jax.jit
            def brute(walls):
                flat = walls.reshape(-1)

                def diff(c):
                    on = multi_scan_model.assess(choices(flat.at[c].set(1.0).reshape(grid.shape), readings, p), args)
                    off = multi_scan_model.assess(choices(flat.at[c].set(0.0).reshape(grid.shape), readings, p), args)
                    return on[0] - off[0]

                return jax.vmap(diff)(jnp.arange(flat.size)).reshape(grid.shape)

            return brute

        brute, brute_plain = differences(params), differences(plain)
        logit = prior_log_odds(0.3)
        samplers = {eta: CellwiseGibbs(table, y.reshape(-1), params, likelihood_power=eta) for eta in (1.0, 0.3)}
        rng = np.random.default_rng(3)
        for density in (0.2, 0.6):
            walls = (rng.random(grid.shape) < density).astype(np.float64)
            total = np.asarray(brute(jnp.asarray(walls)))
            likelihood = np.asarray(brute_plain(jnp.asarray(walls))) - logit
            assert np.abs(total - likelihood - logit).max() > 1.0  # the neighbour term matters here
            for eta, sampler in samplers.items():
                got = np.asarray(sampler.cell_log_odds(walls))
                np.testing.assert_allclose(got, total - (1 - eta) * likelihood, atol=1e-4, rtol=0)
        poses = np.column_stack([POSES, np.zeros(3)])
        dense_params = make_params(0.3, 0.4, 10, grid, 6.0, coupling=COUPLING)
        y_dense = np.abs(np.asarray(simulate_scan_readings(jax.random.key(1), walls, POSES, dense_params, angles)))
        readings = jnp.asarray(y_dense)
        brute_dense = differences(dense_params)
        state = dense_state(walls, poses, angles, dense_params)
        odds = jax.jit(lambda c: cell_log_odds(state, c, jnp.asarray(y_dense.reshape(-1)), dense_params, 1.0, logit))
        want = np.asarray(brute_dense(jnp.asarray(walls))).reshape(-1)
        got = np.array([float(odds(c)) for c in range(walls.size)])
        np.testing.assert_allclose(got, want, atol=1e-6, rtol=0)


@pytest.fixture(scope="module")
def enumerated():
    return mrf_enumeration_scene(COUPLING)


@pytest.mark.parametrize("sampler", ["raster", "chromatic", "block", "chromatic-block", "cellwise", "split",
                                     "dense"])
def test_marginals_match_exact_enumeration(enumerated, sampler):
    """64 chains x 300 sweeps against the enumerated marginals of the MRF posterior. Tolerance 0.06 as
    tests/inference/test_fast_exact.py (each marginal averages 64 x 250 kept sweeps: Monte Carlo standard error
    <= 0.014). "split": 2x2 blocks with level capacity 1 (blocks drawn over several steps)."""
    from bayesmap.inference.registry import make_sampler

    problem, exact = enumerated
    if sampler == "split":
        fast = FastGibbs(problem.table, problem.model_ray_readings, problem.params, block_size=2,
                         pos=problem.pos, level_capacity=1)
        assert not np.all(np.asarray(fast._steps.commit))
        algorithm = fast.algorithm
    elif sampler == "dense":
        pose = np.array([[problem.pos[0], problem.pos[1], 0.0]])
        algorithm = dense_gibbs(pose, problem.beam_angles[None], problem.readings[None], problem.params)
    else:
        algorithm = make_sampler(problem, sampler)
    result = run_chains(jax.random.key(11), algorithm, jnp.zeros((3, 4)), 300, 64)
    est = np.asarray(result.samples[:, 50:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.06, (est, exact)
    assert np.abs(exact - 0.5).max() > 0.3


def test_the_prior_matters_in_the_enumeration(enumerated):
    """The MRF's exact marginals differ from the independent prior's by more than the tolerance: the enumeration
    tests above can fail when a sampler drops the neighbour term."""
    import dataclasses

    problem, exact = enumerated
    params = make_params(0.3, 0.4, 7, problem.grid)
    plain = dataclasses.replace(problem, params=params)
    maps = np.array(list(itertools.product([0.0, 1.0], repeat=12)), np.float32).reshape(-1, 3, 4)
    lj = np.asarray(jax.jit(jax.vmap(lambda w: log_joint(w, plain.readings, plain.pos, params)))(
        jnp.asarray(maps)), float)
    w = np.exp(lj - lj.max())
    independent = np.tensordot(w / w.sum(), maps, axes=1)
    assert np.abs(independent - exact).max() > 0.15


@pytest.mark.parametrize("incremental", [False, True])
def test_reference_samplers_match_exact_enumeration(enumerated, incremental):
    """The assess-based reference sweeps (and the tutorial's incremental trace.edit variant) sample the MRF
    posterior: 16 chains x 150 sweeps, tolerance 0.1 as tests/inference/test_fast_exact.py (standard error
    <= 0.025)."""
    problem, exact = enumerated
    args = problem.single_scan()
    algorithm = reference_incremental_gibbs(*args) if incremental else reference_gibbs(*args, block_size=1)
    result = run_chains(jax.random.key(4), algorithm, jnp.zeros((3, 4)), 150, 16)
    est = np.asarray(result.samples[:, 30:], float).mean(axis=(0, 1))
    assert np.abs(est - exact).max() < 0.1, (est, exact)


def test_cellwise_sweep_is_the_one_cell_at_a_time_sweep():
    """With J > 0 the cellwise sweep (speculative scoring, checkerboard order, uncrossed cells by colour) makes the
    draws of updating one cell at a time: the crossed cells in the visiting order, then the uncrossed cells of
    colour even, then odd, each drawn with its uniform from its conditional on the current map; its rows stay
    consistent."""
    grid = Grid((9, 8))
    params = make_params(0.3, 0.3, 8, grid, 5.0, beam_model="beam", coupling=COUPLING)
    poses = np.array([[3.0, 3.5], [6.2, 4.1]])
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)[None] + np.array([[0.0], [0.3]])
    y = np.full((2, 8), 2.0)
    y[0, :3], y[1, 2] = 1.1, 5.0
    table = build_ray_table(grid, np.repeat(poses, 8, axis=0), angles.reshape(-1), params.max_range)
    sampler = CellwiseGibbs(table, y.reshape(-1), params)
    free = np.asarray(sampler.kernel._free)
    assert free.sum() > 5
    crossed = np.concatenate([np.asarray(lanes.cells) for lanes in sampler.kernel._lanes])
    even = (np.add.outer(np.arange(9), np.arange(8)) % 2 == 0).reshape(-1)
    order = list(crossed) + list(np.flatnonzero(free & even)) + list(np.flatnonzero(free & ~even))
    step, log_odds = jax.jit(sampler.step), jax.jit(sampler.cell_log_odds)
    state = sampler.init(jnp.asarray(np.random.default_rng(1).random(grid.shape) < 0.5, jnp.float32))
    walls = np.asarray(state.walls).reshape(-1).copy()
    changed = 0
    for k in range(4):
        key = jax.random.key(k)
        state, info = step(key, state)
        u = np.asarray(jax.random.uniform(key, walls.shape))
        probs = np.zeros(walls.shape)
        changed += replay_one_at_a_time(log_odds, grid.shape, walls, u, order, probs)
        np.testing.assert_array_equal(np.asarray(state.walls).reshape(-1), walls)
        np.testing.assert_allclose(np.asarray(info.wall_prob).reshape(-1), probs, rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(np.asarray(state.ray_walls), np.asarray(sampler.ray_walls(state.walls)))
    assert changed > 20


def test_prior_samples():
    """J = 0: the checkerboard chain draws independent cells (wall fraction within 5 standard errors of pi); J > 0:
    far fewer differing neighbours than independent cells with the same wall fraction would have."""
    flat = np.asarray(sample_prior(jax.random.key(0), (40, 40), 0.3, 0.0, sweeps=3, num_samples=4))
    assert abs(flat.mean() - 0.3) < 5 * np.sqrt(0.21 / flat.size)
    maps = np.asarray(sample_prior(jax.random.key(1), (40, 40), 0.5, 0.8, sweeps=200, num_samples=2))
    frac = maps.mean()
    differ = np.mean([int(disagreeing_pairs(m)) for m in maps]) / (2 * 40 * 39)
    assert differ < 0.5 * 2 * frac * (1 - frac)
    with pytest.raises(BayesmapError, match="sweeps"):
        sample_prior(jax.random.key(0), (4, 4), 0.3, 0.5, sweeps=0)


def test_cli_coupling(monkeypatch, capsys, tmp_path):
    """--coupling reaches the model (summary.json), bad values and --coupling with --run-length are one-line errors
    with exit code 2."""
    import json

    code, out, err = run_cli(monkeypatch, capsys, "infer", "--coupling", "0.7", "--sweeps", "3", "--out",
                             tmp_path / "o")
    assert code == 0, err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["coupling"] == pytest.approx(0.7) and summary["neighbourhood"] == 4
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--coupling", "-1", "--out", tmp_path / "p")
    assert code == 2 and "coupling" in err and len(err.strip().splitlines()) == 1
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--coupling", "1", "--run-length", "0.5", "--out",
                             tmp_path / "q")
    assert code == 2 and "--run-length" in err
