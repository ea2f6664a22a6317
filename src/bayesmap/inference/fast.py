"""Fast exact Gibbs: block conditionals from the ray-cell table instead of re-running the model.

For a block of cells (one cell for single-site Gibbs), only the rays through the block depend on its values.
For such a ray, let ``m_out`` be the distance of its first wall *outside* the block (or the max distance). With the
block in configuration ``c``, the ray's expected distance is ``min(m_out, min over block walls of t)``, where ``t``
is the table's stopping distance of each block cell on that ray. The block's conditional log-weights are then

    log w(c) = sum over block cells of log prior(c_cell) + sum over rays through the block of log N(y_r; d_r(c), s)

up to a constant that does not depend on ``c`` (``shared/DESIGN.md``, "The fast conditional"; for one cell it is
the prior log-odds plus, per ray, ``log N(y | d1) - log N(y | d0)``).

A sweep runs the levels of a schedule (:mod:`bayesmap.inference.schedules`): all blocks of a level share no cell
and no ray, so their conditionals are computed and sampled at once, each exactly as if sampled alone. With
``schedule="sequential"`` the levels come from :func:`dependency_levels`, which makes one sweep the *same
transition kernel* as the reference sweep in the same order; ``"chromatic"`` runs colour classes instead.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError
from bayesmap.inference.chains import GibbsState, SamplingAlgorithm
from bayesmap.inference.schedules import block_configurations, chromatic_levels, dependency_levels, make_blocks
from bayesmap.model import ModelParams
from bayesmap.raycast import RayTable, check_readings

SCHEDULES = ("sequential", "chromatic")


def _normal_logpdf(y, mean, scale):
    z = (y - mean) / scale
    return -0.5 * z * z - jnp.log(scale) - 0.5 * jnp.log(2 * jnp.pi)


class FastGibbs:
    """The fast Gibbs sampler for one problem (table, readings, parameters) and one schedule.

    Args:
        table: the ray-cell table of the scene (its rows are the rays, in the order of ``readings``).
        readings: ``(R,)`` observed ranges, meters.
        params: model parameters (``prior_wall_prob`` and ``sensor_noise`` are used; geometry comes from the table).
        order: ``"raster"`` or ``"outward"`` (block anchors' order).
        block_size: 1 for single-site, k for k x k blocks.
        schedule: ``"sequential"`` (same kernel as the reference sweep) or ``"chromatic"``.
        pos: ``(2,)`` sensor position, meters (for the outward order; default: the first ray's origin).

    Attributes:
        blocks: ``(NB, B)`` int flat cell indices, sweep order.
        levels: ``(num_levels, width)`` int32 block indices (padding ``NB``).
        algorithm: the :class:`SamplingAlgorithm` (``init``, ``step``).

    Raises:
        BayesmapError: on readings that do not match the table's rays, an unknown schedule or order, or a bad
            block size.
    """

    def __init__(self, table: RayTable, readings, params: ModelParams, order: str = "raster", block_size: int = 1,
                 schedule: str = "sequential", pos=None):
        if schedule not in SCHEDULES:
            raise BayesmapError(f"unknown schedule {schedule!r}; choose one of {', '.join(SCHEDULES)}")
        self.table = table
        self.grid = table.grid
        readings = check_readings(readings, table.num_rays)
        if pos is None:
            pos = table.origins[0]
        self.blocks = make_blocks(self.grid, block_size, order, pos)
        make_levels = dependency_levels if schedule == "sequential" else chromatic_levels
        self.levels = make_levels(self.blocks, table.cells, table.num_cells)
        num_cells = table.num_cells
        dtype = jnp.result_type(float)
        self._num_cells = num_cells
        self._ray_cells = jnp.asarray(table.cells)
        self._dists = jnp.asarray(table.dists, dtype=dtype)
        self._readings = jnp.asarray(readings, dtype=dtype)
        self._max_distance = jnp.asarray(table.max_distance, dtype=dtype)
        self._blocks_ext = jnp.asarray(np.vstack([self.blocks, np.full((1, self.blocks.shape[1]), num_cells)]), dtype=jnp.int32)
        self._bits = jnp.asarray(block_configurations(self.blocks.shape[1]), dtype=dtype)
        self._levels = jnp.asarray(self.levels)
        p = jnp.asarray(params.prior_wall_prob, dtype=dtype)
        self._log_prior = jnp.stack([jnp.log1p(-p), jnp.log(p)])
        self._noise = jnp.asarray(params.sensor_noise, dtype=dtype)
        self.algorithm = SamplingAlgorithm(init=self.init, step=self.step)

    @property
    def num_configurations(self) -> int:
        return int(self._bits.shape[0])

    def init(self, walls) -> GibbsState:
        """State for the map ``walls`` ``(nx, ny)``."""
        return GibbsState(walls=jnp.asarray(walls, dtype=jnp.float32))

    def log_weights(self, walls_ext, block_ids):
        """Conditional log-weights of the blocks ``block_ids`` ``(A,)`` (pairwise non-conflicting; ``NB`` for
        none) given the rest of ``walls_ext`` ``(num_cells + 1,)`` (last entry 0): ``(A, 2**B)``, each row up to
        an additive constant; configurations of :func:`block_configurations`; ``-inf`` for configurations that
        set cells a clipped or padded block does not have."""
        n = self._num_cells
        cells = self._blocks_ext[block_ids]  # (A, B)
        num_blocks, size = cells.shape
        flat = cells.reshape(-1)
        local = jnp.full(n + 1, -1, jnp.int32).at[flat].set(jnp.tile(jnp.arange(size, dtype=jnp.int32), num_blocks)).at[n].set(-1)
        slot = jnp.full(n + 1, num_blocks, jnp.int32).at[flat].set(jnp.repeat(jnp.arange(num_blocks, dtype=jnp.int32), size)).at[n].set(num_blocks)
        pair_local = local[self._ray_cells]  # (R, L)
        pair_wall = walls_ext[self._ray_cells] > 0
        m_out = jnp.min(jnp.where(pair_wall & (pair_local < 0), self._dists, self._max_distance), axis=1)  # (R,)
        t_local = jnp.stack([jnp.min(jnp.where(pair_local == j, self._dists, jnp.inf), axis=1) for j in range(size)])
        d = jnp.min(jnp.where(self._bits[:, :, None] > 0, t_local[None], jnp.inf), axis=1)  # (C, R)
        d = jnp.minimum(d, m_out[None, :])
        ll = _normal_logpdf(self._readings[None, :], d, self._noise)  # (C, R)
        ray_slot = jnp.min(slot[self._ray_cells], axis=1)  # (R,), num_blocks where no block
        weights = jnp.zeros((num_blocks + 1, ll.shape[0]), ll.dtype).at[ray_slot].add(ll.T)[:num_blocks]
        exists = cells < n  # (A, B)
        bits = self._bits > 0
        prior = jnp.where(bits[None], self._log_prior[1], self._log_prior[0])  # (1, C, B)
        prior = jnp.sum(jnp.where(exists[:, None, :], prior, 0.0), axis=-1)  # (A, C)
        invalid = jnp.any(bits[None] & ~exists[:, None, :], axis=-1)
        return jnp.where(invalid, -jnp.inf, weights + prior)

    def step(self, key, state: GibbsState) -> GibbsState:
        """One sweep: every level in order, all its blocks sampled at once."""
        shape = state.walls.shape
        walls_ext = jnp.append(state.walls.reshape(-1), 0.0)
        num_levels, width = self._levels.shape
        gumbels = jax.random.gumbel(key, (num_levels, width, self.num_configurations), dtype=self._dists.dtype)

        def level(l, walls_ext):
            block_ids = self._levels[l]
            choice = jnp.argmax(self.log_weights(walls_ext, block_ids) + gumbels[l], axis=-1)
            values = self._bits[choice].astype(walls_ext.dtype)  # (A, B)
            return walls_ext.at[self._blocks_ext[block_ids]].set(values).at[self._num_cells].set(0.0)

        walls_ext = jax.lax.fori_loop(0, num_levels, level, walls_ext)
        return GibbsState(walls=walls_ext[:-1].reshape(shape))


def fast_gibbs(table: RayTable, readings, params: ModelParams, order: str = "raster", block_size: int = 1,
               schedule: str = "sequential", pos=None) -> SamplingAlgorithm:
    """The fast exact Gibbs sampler as a :class:`SamplingAlgorithm`; see :class:`FastGibbs` for the arguments."""
    return FastGibbs(table, readings, params, order, block_size, schedule, pos).algorithm
