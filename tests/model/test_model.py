import jax
import jax.numpy as jnp
import numpy as np
import pytest
from genjax import ChoiceMapBuilder as C

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles, sensor_distances
from bayesmap.io.ascii import tutorial_map
from bayesmap.model.generative import full_model, log_joint, make_params, model_args, simulate, simulate_readings


def manual_log_joint(walls, readings, pos, params, beam_angles):
    p = params.prior_wall_prob
    prior = np.sum(np.where(walls > 0, np.log(p), np.log1p(-p)))
    d = np.asarray(sensor_distances(walls, pos, beam_angles, grid=params.grid, max_distance=params.max_range), float)
    s = params.sensor_noise
    lik = np.sum(-0.5 * ((np.asarray(readings) - d) / s) ** 2 - np.log(s) - 0.5 * np.log(2 * np.pi))
    return prior + lik


def test_tutorial_readings_and_log_joint(tutorial):
    # the tutorial's readings (key 0): cell (4, 1)'s ray reads 10.83 with the cell at 10.51 (tutorial-baseline.md)
    table = tutorial.table
    rays = np.unique(table.pair_rays[table.pair_cells == 4 * 21 + 1])
    assert 65 in rays
    assert tutorial.readings[65] == pytest.approx(10.83, abs=0.005)
    cells, dists = table.ray(65)
    assert dists[cells == 4 * 21 + 1][0] == pytest.approx(10.51, abs=0.005)
    low = make_params(prior_wall_prob=0.05)
    assert float(log_joint(tutorial.truth, tutorial.readings, tutorial.pos, low)) == pytest.approx(-164.7, abs=0.05)


@pytest.mark.parametrize("seed", range(4))
def test_log_joint_is_assess_and_the_formula(seed):
    rng = np.random.default_rng(seed)
    grid = Grid((int(rng.integers(3, 9)), int(rng.integers(3, 9))), resolution=float(rng.choice([1.0, 0.2])))
    params = make_params(float(rng.uniform(0.02, 0.9)), float(rng.uniform(0.05, 1)), int(rng.integers(1, 30)), grid)
    xmin, xmax, ymin, ymax = grid.extent
    pos = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
    walls = (rng.random(grid.shape) < 0.4).astype(np.float32)
    readings = rng.uniform(0, 5, params.num_angles)
    args = model_args(pos, params)
    assess = full_model.assess(C["walls"].set(jnp.asarray(walls))
                               | C["readings"].set(jnp.asarray(readings, jnp.float32)), args)[0]
    lj = log_joint(walls, readings, pos, params)
    assert float(lj) == pytest.approx(float(assess), rel=1e-6)
    assert float(lj) == pytest.approx(manual_log_joint(walls, readings, pos, params, np.asarray(args[2])),
                                      rel=1e-4, abs=1e-3)


def test_simulate_readings_are_normal_around_the_exact_distances():
    walls = tutorial_map()
    params = make_params(sensor_noise=0.3)
    keys = jax.random.split(jax.random.key(7), 400)
    # 200 draws, one per key, vmapped and jitted (200 un-jitted calls took 11 s; the same draws to float32 rounding)
    draws = np.asarray(jax.jit(jax.vmap(lambda k: simulate_readings(k, walls, [10, 10], params)))(keys[:200]))
    exact = np.asarray(sensor_distances(walls, [10, 10], angles(100)))
    z = (draws.mean(0) - exact) / (0.3 / np.sqrt(200))
    assert np.abs(z).max() < 4.5  # 100 standard normals: |z| > 4.5 has probability < 1e-3
    assert draws.std(0).mean() == pytest.approx(0.3, rel=0.05)


def test_simulate_draws_from_the_prior():
    params = make_params(prior_wall_prob=0.2)
    walls, readings = simulate(jax.random.key(3), [10, 10], params)
    assert walls.shape == (21, 21) and readings.shape == (100,)
    assert abs(float(np.mean(walls)) - 0.2) < 4 * np.sqrt(0.2 * 0.8 / 441)


@pytest.mark.parametrize("kwargs, match", [
    (dict(prior_wall_prob=0.0), "prior_wall_prob"),
    (dict(prior_wall_prob=1.5), "prior_wall_prob"),
    (dict(sensor_noise=0.0), "sensor_noise"),
    (dict(sensor_noise=-1.0), "sensor_noise"),
    (dict(num_angles=0), "num_angles"),
    (dict(max_distance=-3), "max_distance"),
])
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(BayesmapError, match=match):
        make_params(**kwargs)
