"""Helpers shared by several test modules: scenes, checks and a CLI runner (not tests themselves)."""

import dataclasses
import os
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.cli import main
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raytable import build_ray_table
from bayesmap.model import motion
from bayesmap.model.generative import choices, make_params, multi_scan_model, scan_args, simulate_scan_readings

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
"""The read-only data beside the checkout (``../shared/data``): real logs and a floor plan."""


def random_scene(rng, max_side=8, metric=False):
    """A random small grid, position inside it, map and beam angles (numpy)."""
    shape = (int(rng.integers(3, max_side + 1)), int(rng.integers(3, max_side + 1)))
    if metric:
        grid = Grid(shape, resolution=float(rng.choice([0.1, 0.25, 0.7])), origin=tuple(rng.normal(0, 3, 2)))
    else:
        grid = Grid(shape)
    xmin, xmax, ymin, ymax = grid.extent
    pos = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
    walls = (rng.random(shape) < rng.uniform(0.1, 0.6)).astype(np.float32)
    beam_angles = rng.uniform(-np.pi, 3 * np.pi, int(rng.integers(1, 60)))
    return grid, pos, walls, beam_angles


POSES = np.array([[1.2, 1.1], [4.3, 5.2], [2.6, 3.9]])  # three scans inside a 6 x 7 grid, meters


def scenes(beam_model, seed, max_distance=6.0, num_beams=10, geometry="entry"):
    """Grid, params, poses (3, 2), world-frame angles (3, K) (each scan its own headings), truth map, readings
    (3, K) simulated from the model with about a quarter set to exactly the max range, and the ray table."""
    rng = np.random.default_rng(seed)
    grid = Grid((6, 7))
    params = make_params(0.3, 0.4, num_beams, grid, max_distance, beam_model=beam_model, geometry=geometry)
    angles = rng.uniform(-np.pi, np.pi, (len(POSES), num_beams))
    truth = (rng.random(grid.shape) < 0.25).astype(np.float32)
    y = np.asarray(simulate_scan_readings(jax.random.key(seed), truth, POSES, params, angles), np.float64)
    y = np.maximum(y, 0.0)  # the Normal can go below 0 next to a wall; a real sensor cannot (as in problem.py)
    y[rng.random(y.shape) < 0.25] = params.max_range  # max-range readings, exactly at the max range
    table = build_ray_table(grid, np.repeat(POSES, num_beams, axis=0), angles.reshape(-1), params.max_range)
    return grid, params, angles, truth, y, table


def enumerated_marginals(poses, params, angles, y):
    """Exact posterior wall marginals ``(nx, ny)`` of the multi-scan model (scans at ``poses`` ``(S, 2)``, beam
    angles ``(S, K)``, readings ``(S, K)``), by enumerating every map of ``params.grid`` (at most 16 cells) with the
    model's assess."""
    import itertools

    shape = params.grid.shape
    maps = np.array(list(itertools.product([0.0, 1.0], repeat=shape[0] * shape[1])), np.float32).reshape(-1, *shape)
    args = scan_args(poses, params, angles)
    lj = np.asarray(jax.jit(jax.vmap(lambda w: multi_scan_model.assess(choices(w, jnp.asarray(y)), args)[0]))(
        jnp.asarray(maps)), np.float64)
    w = np.exp(lj - lj.max())
    return np.tensordot(w / w.sum(), maps, axes=1)


def beam_enumeration_scene(**model):
    """Two scans on a 3 x 4 grid with the beam model (max range 4 m): 2 poses x 6 beams, readings simulated from a
    3-wall map with two set to exactly the max range and one short (0.3 m). Returns ``(table, readings (2, 6),
    params, exact posterior marginals (3, 4))``, the marginals by enumerating all 4,096 maps with the model's
    assess. ``model``: more keywords of ``make_params`` (e.g. ``wall_pass_prob``)."""

    grid = Grid((3, 4))
    params = make_params(0.3, 0.4, 6, grid, 4.0, beam_model="beam", **model)
    poses = np.array([[0.2, 0.4], [1.8, 2.6]])
    angles = np.stack([np.linspace(0, 2 * np.pi, 6, endpoint=False) + 0.1 * s for s in range(2)])
    truth = np.zeros((3, 4), np.float32)
    truth[2, 3] = truth[0, 3] = truth[2, 0] = 1
    y = np.asarray(simulate_scan_readings(jax.random.key(5), truth, poses, params, angles), np.float64)
    y[0, 1] = y[1, 4] = params.max_range  # max-range readings
    y[1, 2] = 0.3  # a short reading
    exact = enumerated_marginals(poses, params, angles, y)
    table = build_ray_table(grid, np.repeat(poses, 6, axis=0), angles.reshape(-1), params.max_range)
    return table, y, params, exact


def mrf_enumeration_scene(coupling):
    """3 x 4 grid (4,096 maps), one scan of 7 beams, J = ``coupling``: the problem and its exact marginals by
    enumerating every map with the model's assess (connections observed)."""
    import itertools

    from bayesmap.geometry.raycast import angles as tutorial_angles
    from bayesmap.model.generative import log_joint, simulate_readings
    from bayesmap.problem import Problem

    grid = Grid((3, 4))
    params = make_params(prior_wall_prob=0.3, sensor_noise=0.4, num_angles=7, grid=grid, coupling=coupling)
    truth = np.zeros((3, 4), np.float32)
    truth[2, 3] = truth[0, 3] = truth[2, 0] = 1
    pos = np.array([1.3, 0.6])
    y = np.abs(np.asarray(simulate_readings(jax.random.key(5), truth, pos, params), float))
    maps = np.array(list(itertools.product([0.0, 1.0], repeat=12)), np.float32).reshape(-1, 3, 4)
    lj = np.asarray(jax.jit(jax.vmap(lambda w: log_joint(w, y, pos, params)))(jnp.asarray(maps)), float)
    w = np.exp(lj - lj.max())
    exact = np.tensordot(w / w.sum(), maps, axes=1)
    problem = Problem.from_world_frame(params, pos, np.asarray(tutorial_angles(7), float), y, truth=truth)
    return problem, exact


def sweeps_keep_ray_rows(sampler, table, grid, walls_kept: int, num_sweeps: int) -> int:
    """Run ``num_sweeps`` sweeps of ``sampler`` (a CellwiseGibbs) from a random half-full map (keys 0, 1, ...),
    asserting after each that the state's rows equal those recomputed from its map (``sampler.ray_walls``) and that
    their first ``walls_kept`` columns are the positions of each ray's first walls found in plain numpy; returns how
    many cells changed in all."""
    from bayesmap.inference.cellwise import NO_WALL

    step = jax.jit(sampler.step)
    state = sampler.init(jnp.asarray(np.random.default_rng(0).random(grid.shape) < 0.5, jnp.float32))
    changed = 0
    for k in range(num_sweeps):
        new, _ = step(jax.random.key(k), state)
        changed += int(jnp.sum(new.walls != state.walls))
        state = new
        rows = np.asarray(state.ray_walls)
        on = np.asarray(state.walls).reshape(-1)[table.pair_cells] > 0
        want = np.full((table.num_rays, walls_kept), NO_WALL)
        for r in range(table.num_rays):
            pos = np.nonzero(on[table.offsets[r]:table.offsets[r + 1]])[0][:walls_kept]
            want[r, :len(pos)] = pos
        np.testing.assert_array_equal(rows[:-1, :walls_kept], want)
        np.testing.assert_allclose(rows, np.asarray(sampler.ray_walls(state.walls)), rtol=0, atol=0)
    return changed


def sweeps_keep_ray_bits(fast, state, num_sweeps: int) -> int:
    """Run ``num_sweeps`` sweeps of ``fast`` (a FastGibbs) from ``state`` (keys 0, 1, ...), asserting after each that
    the state's ray bits equal those recomputed from its map; returns how many cells changed in all."""
    step = jax.jit(fast.step)
    changed = 0
    for k in range(num_sweeps):
        new, _ = step(jax.random.key(k), state)
        changed += int(jnp.sum(new.walls != state.walls))
        state = new
        assert np.array_equal(np.asarray(state.ray_bits), np.asarray(fast.ray_bits(state.walls)))
    return changed


def run_main(*args) -> int:
    """Run the ``bayesmap`` command line in-process with ``args`` (any objects, made strings) and return its exit
    code; ``sys.argv`` is restored afterwards (for module-scoped fixtures, where ``monkeypatch`` is not available)."""
    old = sys.argv
    sys.argv = ["bayesmap", *map(str, args)]
    try:
        main()
    except SystemExit as exc:
        return 0 if exc.code is None else exc.code
    finally:
        sys.argv = old
    return 0


def run_cli(monkeypatch, capsys, *args):
    monkeypatch.setattr(sys, "argv", ["bayesmap", *map(str, args)])
    code = 0
    try:
        main()
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def room_scans(beam_model: str, seed: int = 0):
    """A 12 x 9 unit-cell room with an inner wall, seen by 3 scans of 24 beams from different positions: a
    :class:`bayesmap.problem.Problem` with the true map and readings simulated from the model (max distance 15 m)."""
    from bayesmap.problem import Problem

    walls = np.zeros((12, 9), np.float32)
    walls[0, :] = walls[-1, :] = walls[:, 0] = walls[:, -1] = 1
    walls[6, 3:7] = 1
    grid = Grid((12, 9))
    poses = np.array([[2.3, 2.1], [9.2, 6.4], [3.7, 6.6]])
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)[None] + np.array([[0.0], [0.1], [0.2]])
    params = make_params(0.3, 0.25, 24, grid, max_distance=15.0, beam_model=beam_model)
    readings = np.asarray(simulate_scan_readings(jax.random.key(seed), walls, poses, params, angles), np.float64)
    readings = np.clip(readings, 0.0, 15.0)
    return Problem.from_world_frame(params, poses, angles, readings, truth=walls, max_range_mask=readings >= 15.0)


# -- figures (tests/viz) ---------------------------------------------------------------------------------------

POS = np.array([10.0, 10.0])  # the tutorial's sensor position (cells of its unit grid)


def blurred(walls):
    """A fake posterior: the true map blurred with a 3 x 3 binomial kernel, squeezed into [0.1, 0.9]."""
    out = np.asarray(walls, dtype=np.float64)
    kernel = np.array([1.0, 2.0, 1.0]) / 4
    for axis in (0, 1):
        out = np.apply_along_axis(lambda v: np.convolve(np.pad(v, 1, mode="edge"), kernel, mode="valid"), axis, out)
    return 0.1 + 0.8 * out


def by_gid(ax, gid):
    """The one artist of ``ax`` with this gid (fails the test if there is none or more than one)."""
    found = [a for a in ax.get_children() if a.get_gid() == gid]
    assert len(found) == 1, f"expected one artist with gid {gid!r}, found {len(found)}"
    return found[0]


TINY_SLAM_GRID = Grid((2, 3))  # 6 unit cells: 64 maps
TINY_SLAM_ODOMETRY = np.array([[0.0, 0.0, 0.0], [0.2, 1.0, 1.2], [0.0, 2.0, 2.0]])
TINY_SLAM_OFFSETS = np.array([[0.0, 0.0, 0.0], [-0.12, 0.1, -0.1], [0.1, 0.12, 0.15]])  # 3 candidates per pose


def tiny_slam_problem():
    """Three scans of 4 beams on a 2 x 3 grid, poses 1 and 2 restricted to 3 candidates each; readings simulated
    at candidates (1, 2) with one wall: ``(params, increments, covs, candidates (3, 3, 3), angles (3, 4), readings
    (3, 4))``."""
    params = make_params(0.35, 0.5, 1, TINY_SLAM_GRID, 1.6)
    inc, cov = motion.odometry_controls(TINY_SLAM_ODOMETRY,
                                        motion.make_motion_params((0.2, 0.1, 0.2, 0.1), 0.2, 0.2))
    candidates = TINY_SLAM_ODOMETRY[:, None, :] + TINY_SLAM_OFFSETS[None]
    candidates[0] = TINY_SLAM_ODOMETRY[0]
    angles = np.tile(np.array([-2.8, -1.0, 0.3, 1.7]), (3, 1))
    truth_path = np.stack([candidates[0, 0], candidates[1, 1], candidates[2, 2]])
    truth = np.array([[0, 0, 0], [0, 1, 0]], np.float32)
    y = np.abs(np.asarray(simulate_scan_readings(jax.random.key(3), truth, truth_path[:, :2], params,
                                                 truth_path[:, 2:3] + angles), np.float64))
    return params, inc, cov, candidates, angles, y


def exact_slam_log_joint(params, inc, cov, candidates, angles, y):
    """Every joint state of a tiny SLAM problem whose poses 1 and 2 take 3 candidate values each (``candidates``
    ``(3, 3, 3)``, pose 0 fixed at ``candidates[0, 0]``) and whose grid has 6 cells, scored by the model's assess:
    ``(log p(poses, walls, readings) (3, 3, 64), the 64 maps (64, nx, ny))``, axis 0 pose 1's candidate, axis 1
    pose 2's."""
    import itertools

    from bayesmap.model.slam import slam_args, slam_choices, slam_model

    args = slam_args(candidates[0, 0], inc, cov, params, angles)
    maps = np.array(list(itertools.product([0.0, 1.0], repeat=6))).reshape((-1,) + params.grid.shape)
    assess = jax.jit(jax.vmap(lambda p, w: slam_model.assess(slam_choices(p, w, y), args)[0], in_axes=(None, 0)))
    logp = np.zeros((3, 3, len(maps)))
    for i, j in itertools.product(range(3), range(3)):
        path = jnp.asarray(np.stack([candidates[0, 0], candidates[1, i], candidates[2, j]]))
        logp[i, j] = np.asarray(assess(path, jnp.asarray(maps)))
    return logp, maps


def exact_slam_marginals(params, inc, cov, candidates, angles, y):
    """Exact marginals of the tiny SLAM problem of :func:`exact_slam_log_joint`: ``P(pose_1 = c)`` (3,),
    ``P(pose_2 = c)`` (3,) and ``P(wall)`` (grid shape), from all 3 * 3 * 64 = 576 joint states."""
    logp, maps = exact_slam_log_joint(params, inc, cov, candidates, angles, y)
    prob = np.exp(logp - logp.max())
    prob /= prob.sum()
    return prob.sum(axis=(1, 2)), prob.sum(axis=(0, 2)), np.tensordot(prob.sum(axis=(0, 1)), maps, axes=1)


def assess_cell_differences(grid, params, angles, y):
    """A jitted ``brute(walls) -> (nx, ny)``: for every cell, the multi-scan model's ``assess`` (scans at
    :data:`POSES`, beam angles ``angles``, readings ``y``) with the cell set to 1 minus with it set to 0, the exact
    conditional log-odds the fast paths must reproduce."""
    args = scan_args(POSES, params, angles)
    readings = jnp.asarray(y)

    @jax.jit
    def brute(walls):
        flat = walls.reshape(-1)

        def diff(c):
            on = multi_scan_model.assess(choices(flat.at[c].set(1.0).reshape(grid.shape), readings), args)[0]
            off = multi_scan_model.assess(choices(flat.at[c].set(0.0).reshape(grid.shape), readings), args)[0]
            return on - off

        return jax.vmap(diff)(jnp.arange(flat.size)).reshape(grid.shape)

    return brute


def assess_block_log_joints(grid, params, angles, y, blocks, configs):
    """A jitted ``brute(walls) -> (NB, C)``: the multi-scan model's ``assess`` (scans at :data:`POSES`) with each
    block of ``blocks`` ``(NB, B)`` (flat cell indices) set to each configuration of ``configs`` ``(C, B)``."""
    args = scan_args(POSES, params, angles)
    readings = jnp.asarray(y)

    @jax.jit
    def brute(walls):
        flat = walls.reshape(-1)

        def one(cells, config):
            return multi_scan_model.assess(choices(flat.at[cells].set(config).reshape(grid.shape), readings),
                                           args)[0]

        per_block = jax.vmap(lambda cells: jax.vmap(lambda c: one(cells, c))(jnp.asarray(configs, flat.dtype)))
        return per_block(jnp.asarray(blocks))

    return brute


def assert_block_weights_match_assess(fast, grid, params, angles, y):
    """A level-based sampler's (``FastGibbs``) block log-weights, over every configuration of each block, equal the
    multi-scan model's ``assess`` differences (:func:`assess_block_log_joints`) to 1e-4 on maps of wall density
    0.15, 0.35 and 0.6, and the data are informative (the weights of some block span more than 1 nat)."""
    from bayesmap.inference.schedules import block_configurations

    configs = block_configurations(fast.blocks.shape[1])
    brute = assess_block_log_joints(grid, params, angles, y, fast.blocks, configs)  # (NB, C)
    rng = np.random.default_rng(3)
    for density in (0.15, 0.35, 0.6):
        walls = (rng.random(grid.shape) < density).astype(np.float64)
        got = np.asarray(fast.block_log_weights(walls))
        want = np.asarray(brute(jnp.asarray(walls)))
        np.testing.assert_allclose(got - got[:, :1], want - want[:, :1], atol=1e-4, rtol=0)
        assert np.ptp(want - want[:, :1]) > 1.0


def replay_one_at_a_time(log_odds, shape, walls, u, order, probs):
    """Replay a sweep cell by cell: for each flat cell of ``order``, its wall probability from ``log_odds(walls)``
    at the current map, then the draw ``u[c] < p``. ``walls`` ``(nx * ny,)`` float32 and ``probs`` are updated in
    place; returns how many cells changed."""
    changed = 0
    for c in order:
        probs[c] = np.asarray(jax.nn.sigmoid(log_odds(walls.reshape(shape)))).reshape(-1)[c]
        new = np.float32(u[c] < probs[c])
        changed += int(new != walls[c])
        walls[c] = new
    return changed


def replayed_sweeps(step, log_odds, state, shape, order, free, prior: float, sweeps: int = 4):
    """Run ``sweeps`` sweeps of ``step`` (keys 0, 1, ...) from ``state``, replaying each one cell at a time over
    ``order`` (:func:`replay_one_at_a_time`, each with the sweep's uniform) and then drawing the ``free`` cells
    ``(nx * ny,)`` bool from the ``prior``; yields ``(state, info, before, walls, probs, changed)`` after each sweep:
    the sweep's state and info, and the replay's map before and after, probabilities and number of changed cells."""
    walls = np.asarray(state.walls).reshape(-1).copy()
    for k in range(sweeps):
        key = jax.random.key(k)
        state, info = step(key, state)
        u = np.asarray(jax.random.uniform(key, walls.shape))
        probs = np.full(walls.shape, prior, np.float32)
        before = walls.copy()
        changed = replay_one_at_a_time(log_odds, shape, walls, u, order, probs)
        walls[free] = u[free] < prior
        yield state, info, before, walls, probs, changed


def four_cpu_devices_env() -> dict:
    """The environment of a fresh process with four CPU devices: ``JAX_PLATFORMS=cpu`` and this process's
    ``XLA_FLAGS`` plus ``--xla_force_host_platform_device_count=4``, so that the child compiles as this process does
    (``make test`` runs most tests at another XLA optimization level, whose floats may differ in the last bit)."""
    flags = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4").strip()
    return dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")


def random_slam_scene(seed, beam_model="normal", num_scans=4, geometry="entry"):
    """A random small grid and map (:func:`random_scene`), a path of ``num_scans`` poses near its position,
    odometry near the path, readings simulated at the path (some set to the max range)."""
    rng = np.random.default_rng(seed)
    grid, pos, walls, beam_angles = random_scene(rng, metric=bool(seed % 2))
    params = make_params(0.3, 0.3, 1, grid, beam_model=beam_model)
    step = 0.5 * grid.resolution
    path = np.concatenate([np.tile(pos, (num_scans, 1)) + rng.normal(0, step, (num_scans, 2)),
                           rng.uniform(-np.pi, np.pi, (num_scans, 1))], axis=1)
    path[0, :2] = pos
    odometry = path + rng.normal(0, [step, step, 0.1], path.shape)
    odometry[0] = path[0]
    inc, cov = motion.odometry_controls(odometry, motion.make_motion_params((0.2, 0.1, 0.2, 0.1), step, 0.1))
    sensor_angles = np.tile(beam_angles[:12], (num_scans, 1)) - path[:, 2:3]
    y = np.asarray(simulate_scan_readings(jax.random.key(seed), walls, path[:, :2], params,
                                          path[:, 2:3] + sensor_angles), np.float64)
    y = np.maximum(y, 0.0)
    y[rng.random(y.shape) < 0.2] = params.max_range
    # the readings are simulated in the entry geometry whatever ``geometry`` (any readings are data to condition on)
    return dataclasses.replace(params, geometry=geometry), path, walls, inc, cov, sensor_angles, y, step
