"""Single-site Gibbs over the walls given the poses, for small grids, with the ray-cell distances computed in JAX.

The samplers of :mod:`bayesmap.inference.fast` and :mod:`bayesmap.inference.cellwise` read a sparse ray-cell table
built on the host (numpy) for fixed poses: moving a pose changes the table's shapes and compiles the sweep anew.
A SLAM chain moves the poses every sweep (:mod:`bayesmap.slam.joint`), so this kernel keeps a *dense* table
instead, computed from the poses inside the compiled code: for every ray ``r`` (``R = S K`` rays: ``K`` beams of
each of ``S`` scans) and every cell ``c`` (``N = nx ny`` cells), ``D[r, c]`` is the distance (meters) at which the
ray would stop if ``c`` were its first wall: :func:`bayesmap.geometry.raycast.cell_hit_distance` (the arithmetic of
:func:`~bayesmap.geometry.raycast.first_hit_distances`, hence of the model's ``assess``), capped at the max range
``params.max_range``, and ``inf`` where the ray misses the cell. Its shapes depend only on ``S``, ``K`` and the grid,
never on the poses' values, so a chain that moves poses never recompiles.

Memory: ``D`` holds ``R * N`` floats (of the default float dtype), e.g. 8 scans of 100 beams on the tutorial's
21 x 21 grid: 352,800 floats, 1.4 MB in float32. Problems with more than :data:`MAX_DENSE_ENTRIES` entries are
refused (use the sparse samplers for whole logs).

The sweep (:func:`dense_gibbs`) visits the cells in raster order (flat index ``i * ny + j``) in a ``lax.scan`` and
draws each from its full conditional (Geman & Geman 1984, systematic-scan Gibbs). A cell's conditional log-odds is
(derived in ``docs/fast-conditional.md``)

    log-odds(c) = prior log-odds + eta * sum over rays r of [log p(y_r | min(D[r, c], d_r)) - log p(y_r | d_r)]

with ``d_r`` the distance of ray ``r``'s first wall *other than c* (the max range if there is none): the state keeps,
per ray, the distances of its first and second wall (the two smallest ``D[r, c]`` over the wall cells, with
multiplicity), so ``d_r`` is the second one when ``c`` is a wall at the first one's distance, the first otherwise.
Terms with ``D[r, c] >= d_r`` (the ray stops before the cell, or misses it) vanish. After the draw, a new wall is
inserted into each ray's two minima; a removed wall that was some ray's first or second wall makes the sweep
recompute the two minima from ``D`` and the map (for every ray at once: one vectorized pass over ``D``, equal to
the old values on the rays the wall was not first or second on). The sensor model is
:func:`bayesmap.model.generative.reading_log_likelihood`, tempered by :func:`bayesmap.model.likelihood.tempered`,
and the prior part is :func:`bayesmap.model.generative.prior_log_odds`, plus, with the structured prior
(:mod:`bayesmap.model.prior`, ``params.coupling > 0``), ``J (n_wall - n_free)`` over the cell's 4-neighbours in the
current map (the raster sweep updates one cell at a time, so no two neighbours are drawn at once).

Each cell is drawn with ``jax.random.categorical`` over its two values ``(free, wall)`` with one key of
``jax.random.split(key, N)``, as the reference raster sweep (:func:`bayesmap.inference.reference.reference_gibbs`)
draws its cells, so with the same key both sweeps make the same draws (up to float rounding of the conditionals).
Each sweep reports ``p(cell is a wall | rest)`` in :attr:`bayesmap.inference.base.GibbsInfo.wall_prob`
(Rao-Blackwellization, Gelfand & Smith 1990, sec. 2.3).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.geometry.raycast import cell_hit_distance, unit_dir
from bayesmap.inference.base import GibbsInfo, SamplingAlgorithm
from bayesmap.model.generative import (
    ModelParams,
    check_entry_geometry,
    check_likelihood_power,
    prior_log_odds,
    reading_log_likelihood,
)
from bayesmap.model.likelihood import tempered
from bayesmap.model.prior import neighbour_indices

MAX_DENSE_ENTRIES = 1 << 24
"""The largest dense table (``R * N`` rays times cells, 64 MB in float32) :func:`dense_gibbs` accepts."""


class DenseState(NamedTuple):
    """State of a :func:`dense_gibbs` chain.

    Attributes:
        walls: ``(nx, ny)`` float32 map of 0.0 / 1.0.
        poses: ``(S, 3)`` the poses the map is conditioned on (x m, y m, theta rad).
        distances: ``(R, N)`` float, :func:`ray_cell_distances` at ``poses`` (meters, ``inf`` where a ray misses a
            cell), ``R = S K`` rays in scan-major order, ``N = nx ny`` cells in flat order.
        first: ``(R,)`` float, each ray's distance to its first wall (meters; the max range if there is none).
        second: ``(R,)`` float, to its second wall (the max range if there is none; equal to ``first`` on a tie).
    """

    walls: jax.Array
    poses: jax.Array
    distances: jax.Array
    first: jax.Array
    second: jax.Array


def ray_cell_distances(poses, sensor_angles, params: ModelParams):
    """The dense ray-cell table: where every ray would stop in every cell.

    Args:
        poses: ``(S, 3)`` poses (x m, y m, theta rad).
        sensor_angles: ``(S, K)`` beam angles relative to the heading, radians (world angle ``theta + angle``).
        params: the model parameters (grid and max range).

    Returns:
        ``(S K, nx ny)`` float (the poses' dtype, at least float32): ``D[s K + k, i ny + j]`` is the distance in
        meters from pose ``s`` along beam ``k`` to the boundary of cell ``(i, j)``
        (:func:`bayesmap.geometry.raycast.cell_hit_distance`), capped at ``params.max_range``, ``inf`` where the ray
        misses the cell. With the walls' minimum over a row taken (the max range for no wall), this is exactly the
        distance :func:`bayesmap.geometry.raycast.first_hit_distances` computes. Never raises; jittable.
    """
    grid = params.grid
    poses = jnp.asarray(poses)
    ii, jj = jnp.meshgrid(jnp.arange(grid.shape[0]), jnp.arange(grid.shape[1]), indexing="ij")
    cells = jnp.stack([ii.ravel(), jj.ravel()], axis=-1)
    max_cells = params.max_range / grid.resolution

    def one_ray(p, angle):
        d = cell_hit_distance(p, unit_dir(angle)[None, :], cells)
        return jnp.where(jnp.isfinite(d), jnp.minimum(d, max_cells) * grid.resolution, jnp.inf)

    def one_scan(pose, rel_angles):
        p = grid.to_cell_coords(pose[:2])
        return jax.vmap(lambda a: one_ray(p, a))(pose[2] + rel_angles)

    table = jax.vmap(one_scan)(poses, jnp.asarray(sensor_angles, dtype=poses.dtype))
    return table.reshape(-1, cells.shape[0])


def _no_wall_distance(params: ModelParams, dtype):
    """The distance of a ray with no wall, meters: the capped distance as :func:`first_hit_distances` computes it."""
    return jnp.minimum(jnp.asarray(jnp.inf, dtype), params.max_range / params.grid.resolution) * params.grid.resolution


def two_nearest_walls(distances, walls, no_wall):
    """Each ray's distances to its first and second wall: ``(first (R,), second (R,))``, the two smallest
    ``distances[r, c]`` over wall cells ``c`` (``walls`` ``(nx, ny)``, > 0 is a wall), with multiplicity, each
    replaced by ``no_wall`` (the max range) where there is no such wall."""
    masked = jnp.where(walls.reshape(1, -1) > 0, distances, jnp.inf)
    two = -jax.lax.top_k(-masked, 2)[0] if masked.shape[1] >= 2 else jnp.concatenate(
        [masked, jnp.full_like(masked, jnp.inf)], axis=1)
    two = jnp.minimum(two, no_wall)
    return two[:, 0], two[:, 1]


def dense_state(walls, poses, sensor_angles, params: ModelParams) -> DenseState:
    """The :class:`DenseState` of the map ``walls`` ``(nx, ny)`` at ``poses`` ``(S, 3)`` (distances and each ray's
    two nearest walls computed from them). Jittable; never raises."""
    poses = jnp.asarray(poses, dtype=jnp.result_type(float))
    walls = (jnp.asarray(walls) > 0).astype(jnp.float32)
    distances = ray_cell_distances(poses, sensor_angles, params)
    first, second = two_nearest_walls(distances, walls, _no_wall_distance(params, distances.dtype))
    return DenseState(walls=walls, poses=poses, distances=distances, first=first, second=second)


def cell_log_odds(state: DenseState, cell, readings, params: ModelParams, eta, prior_lo):
    """The conditional log-odds ``log p(cell = wall | rest) - log p(cell = free | rest)`` of one cell (flat index,
    traced or not) in ``state``, ``readings`` ``(R,)`` meters, likelihood power ``eta``, prior log-odds
    ``prior_lo`` (:func:`bayesmap.model.generative.prior_log_odds`; see the module docstring), plus the structured
    prior's neighbour term when ``params.structured``. Returns a scalar float."""
    d = state.distances[:, cell]
    is_wall = state.walls.reshape(-1)[cell] > 0
    other = jnp.where(is_wall & (d == state.first), state.second, state.first)
    with_wall = jnp.minimum(d, other)
    diff = reading_log_likelihood(readings, with_wall, params) - reading_log_likelihood(readings, other, params)
    diff = jnp.where(d < other, diff, 0.0)
    log_odds = prior_lo + jnp.sum(tempered(diff, eta))
    if params.structured:  # the structured prior's neighbour term, J (n_wall - n_free)
        neighbours = jnp.asarray(neighbour_indices(params.grid.shape))[cell]
        values = state.walls.reshape(-1)[jnp.maximum(neighbours, 0)]
        log_odds = log_odds + params.coupling * jnp.sum(jnp.where(neighbours >= 0, 2.0 * values - 1.0, 0.0))
    return log_odds


def _set_cell(state: DenseState, cell, value, no_wall) -> DenseState:
    """``state`` with the cell set to ``value`` (0/1) and each ray's two nearest walls updated."""
    was = state.walls.reshape(-1)[cell] > 0
    now = value > 0
    walls = state.walls.reshape(-1).at[cell].set(value.astype(jnp.float32)).reshape(state.walls.shape)
    d = state.distances[:, cell]
    inserted_first = jnp.minimum(state.first, d)
    inserted_second = jnp.where(d < state.first, state.first, jnp.minimum(state.second, d))
    first = jnp.where(now & ~was, inserted_first, state.first)
    second = jnp.where(now & ~was, inserted_second, state.second)
    removed = was & ~now & jnp.any((d == state.first) | (d == state.second))
    first, second = jax.lax.cond(removed, lambda: two_nearest_walls(state.distances, walls, no_wall),
                                 lambda: (first, second))
    return state._replace(walls=walls, first=first, second=second)


def dense_sweep(key, state: DenseState, readings, params: ModelParams, eta,
                prior_lo) -> tuple[DenseState, GibbsInfo]:
    """One raster-order single-site Gibbs sweep of ``state`` (see the module docstring): ``readings`` ``(R,)``
    meters, likelihood power ``eta``, prior log-odds ``prior_lo`` (a float: the prior's
    :func:`bayesmap.model.generative.prior_log_odds`). Returns ``(state, GibbsInfo(wall_prob (nx, ny) float32))``.
    Jittable."""
    num_cells = state.walls.size
    keys = jax.random.split(key, num_cells)
    no_wall = _no_wall_distance(params, state.distances.dtype)

    def body(st, inputs):
        cell, k = inputs
        lo = cell_log_odds(st, cell, readings, params, eta, prior_lo)
        value = jax.random.categorical(k, jnp.stack([jnp.zeros_like(lo), lo]))
        return _set_cell(st, cell, value, no_wall), jax.nn.sigmoid(lo).astype(jnp.float32)

    state, prob = jax.lax.scan(body, state, (jnp.arange(num_cells), keys))
    return state, GibbsInfo(wall_prob=prob.reshape(state.walls.shape))


def check_dense_size(num_rays: int, num_cells: int) -> None:
    """Refuse a dense table larger than :data:`MAX_DENSE_ENTRIES`.

    Raises:
        BayesmapError: if ``num_rays * num_cells`` exceeds it (the message names both).
    """
    if num_rays * num_cells > MAX_DENSE_ENTRIES:
        raise BayesmapError(f"the dense ray-cell table would hold {num_rays:,} rays x {num_cells:,} cells = "
                            f"{num_rays * num_cells:,} floats, more than MAX_DENSE_ENTRIES = {MAX_DENSE_ENTRIES:,}; "
                            "use a sparse sampler (bayesmap.inference.fast or cellwise)")


def dense_readings(sensor_angles, readings, params: ModelParams) -> tuple[jax.Array, jax.Array]:
    """Check the sensor angles ``(S, K)`` and readings ``(S, K)`` (meters) and return them as JAX arrays of the
    default float dtype, the readings flattened to ``(S K,)`` (the rays' order in :func:`ray_cell_distances`).

    Raises:
        BayesmapError: if the angles are not ``(S, K)`` with ``S, K >= 1``, the readings not of that shape, a value
            is not finite, a reading is negative, the table is too large (:func:`check_dense_size`), or
            ``params.geometry`` is not ``"entry"`` (the dense table has entry distances only).
    """
    check_entry_geometry(params, "the dense sweep")
    angles = np.asarray(sensor_angles, dtype=np.float64)
    y = np.asarray(readings, dtype=np.float64)
    if angles.ndim != 2 or min(angles.shape) < 1:
        raise BayesmapError(f"sensor_angles must have shape (S, K) with S, K >= 1, got {angles.shape}")
    if y.shape != angles.shape:
        raise BayesmapError(f"readings must have shape {angles.shape} (S, K), got {y.shape}")
    if not (np.all(np.isfinite(angles)) and np.all(np.isfinite(y))):
        raise BayesmapError("sensor_angles and readings must be finite")
    if np.any(y < 0):
        raise BayesmapError(f"readings must be >= 0 meters, got {float(y.min())!r}")
    check_dense_size(angles.size, int(np.prod(params.grid.shape)))
    dtype = jnp.result_type(float)
    return jnp.asarray(angles, dtype=dtype), jnp.asarray(y.reshape(-1), dtype=dtype)


def dense_gibbs(poses, sensor_angles, readings, params: ModelParams,
                likelihood_power: float = 1.0) -> SamplingAlgorithm:
    """Single-site Gibbs over the walls at fixed poses with the dense, JAX-computed ray-cell table.

    Args:
        poses: ``(S, 3)`` poses (x m, y m, theta rad).
        sensor_angles: ``(S, K)`` beam angles relative to the heading, radians.
        readings: ``(S, K)`` range readings, meters.
        params: the model parameters.
        likelihood_power: ``eta`` in (0, 1].

    Returns:
        A :class:`~bayesmap.inference.base.SamplingAlgorithm`: ``init(walls (nx, ny)) -> DenseState`` at ``poses``,
        ``step(key, DenseState) -> (DenseState, GibbsInfo)`` one raster sweep (:func:`dense_sweep`). A state's poses
        can be changed with :func:`dense_state` (same shapes: the compiled sweep is reused).

    Raises:
        BayesmapError: on bad shapes or values (:func:`dense_readings`), ``poses`` not ``(S, 3)``, a bad likelihood
            power, or a table larger than :data:`MAX_DENSE_ENTRIES`.
    """
    eta = check_likelihood_power(likelihood_power)
    prior_lo = prior_log_odds(params.prior_wall_prob)
    angles, y = dense_readings(sensor_angles, readings, params)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape != (angles.shape[0], 3) or not np.all(np.isfinite(poses)):
        raise BayesmapError(f"poses must be finite with shape (S, 3) = ({angles.shape[0]}, 3), got {poses.shape}")

    def init(walls):
        return dense_state(walls, poses, angles, params)

    def step(key, state: DenseState):
        return dense_sweep(key, state, y, params, eta, prior_lo)

    return SamplingAlgorithm(init=init, step=step)
