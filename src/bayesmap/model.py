"""The tutorial's generative model in GenJAX: the source of truth for every sampler.

* prior: each cell is a wall with probability ``prior_wall_prob``, independently (``genjax.flip`` repeated over
  the grid) at address ``"walls"``;
* sensor model: each beam's range reading is ``Normal(exact distance to the first wall, sensor_noise)``
  (``genjax.normal`` vmapped over beams) at address ``"readings"``.

The model's arguments are ``(pos, params, beam_angles)``: the sensor position (world meters; the tutorial's unit
cells by default), the :class:`ModelParams` and the beam angles (radians; the tutorial's
``angles(num_angles)`` unless given). :func:`model_args` builds them.
"""

from __future__ import annotations

import math

import genjax
import jax
import jax.numpy as jnp
import numpy as np
from genjax import ChoiceMapBuilder as C
from genjax import Pytree

from bayesmap.errors import BayesmapError
from bayesmap.grid import Grid
from bayesmap.raycast import _sensor_distances, angles


@Pytree.dataclass
class ModelParams(Pytree):
    """Parameters of the tutorial's model (a JAX pytree).

    Attributes:
        prior_wall_prob: prior probability that a cell is a wall, in (0, 1) (dynamic: changing it does not
            recompile).
        sensor_noise: standard deviation of a range reading in meters, > 0 (dynamic).
        num_angles: number of beams for the tutorial's equally spaced angles (static).
        grid: the grid geometry (static); default: the tutorial's 21 x 21 unit cells.
        max_distance: cap on distances in meters (static); default: twice the grid's larger side (42 m for the
            tutorial).
    """

    prior_wall_prob: float = 0.5
    sensor_noise: float = 0.2
    num_angles: int = Pytree.static(default=100)
    grid: Grid = Pytree.static(default=Grid(shape=(21, 21)))
    max_distance: float | None = Pytree.static(default=None)

    @property
    def cap(self) -> float:
        """The max distance in meters (``max_distance`` or the grid's default)."""
        return self.grid.default_max_distance if self.max_distance is None else float(self.max_distance)


def make_params(
    prior_wall_prob: float = 0.5,
    sensor_noise: float = 0.2,
    num_angles: int = 100,
    grid: Grid | None = None,
    max_distance: float | None = None,
) -> ModelParams:
    """Build :class:`ModelParams` after checking every value.

    Raises:
        BayesmapError: if ``prior_wall_prob`` is not in (0, 1), ``sensor_noise`` is not finite and > 0,
            ``num_angles`` is not an integer >= 1, or ``max_distance`` is not finite and > 0.
    """
    p = float(prior_wall_prob)
    if not (0.0 < p < 1.0):
        raise BayesmapError(f"prior_wall_prob must be strictly between 0 and 1, got {prior_wall_prob!r}")
    noise = float(sensor_noise)
    if not (math.isfinite(noise) and noise > 0):
        raise BayesmapError(f"sensor_noise must be a finite number > 0 (meters), got {sensor_noise!r}")
    if int(num_angles) != num_angles or num_angles < 1:
        raise BayesmapError(f"num_angles must be an integer >= 1, got {num_angles!r}")
    if max_distance is not None and not (math.isfinite(float(max_distance)) and float(max_distance) > 0):
        raise BayesmapError(f"max_distance must be a finite number > 0 (meters), got {max_distance!r}")
    return ModelParams(
        prior_wall_prob=p,
        sensor_noise=noise,
        num_angles=int(num_angles),
        grid=grid or Grid(shape=(21, 21)),
        max_distance=None if max_distance is None else float(max_distance),
    )


def walls_prior(shape: tuple[int, int]):
    """The prior over walls as a generative function of ``prior_wall_prob``: ``(nx, ny)`` independent flips."""
    return genjax.flip.repeat(n=shape[1]).repeat(n=shape[0])


@genjax.gen
def sensor_model_single(pos, walls, params: ModelParams, angle):
    """One beam: ``Normal(exact distance to the first wall, sensor_noise)``, a scalar at address ``()``."""
    exact = _sensor_distances(walls, pos, angle[None], params.grid, params.cap)[0]
    return genjax.normal(exact, params.sensor_noise) @ ()


sensor_model = sensor_model_single.vmap(in_axes=(None, None, None, 0))
"""All beams of a scan: arguments ``(pos, walls, params, beam_angles (K,))``, readings ``(K,)``."""


@genjax.gen
def full_model(pos, params: ModelParams, beam_angles):
    """The tutorial's full model: walls from the prior at ``"walls"``, readings at ``"readings"``.

    Returns ``(walls, readings)``: ``(nx, ny)`` bool and ``(K,)`` float (meters).
    """
    walls = walls_prior(params.grid.shape)(params.prior_wall_prob) @ "walls"
    readings = sensor_model(pos, walls, params, beam_angles) @ "readings"
    return walls, readings


def model_args(pos, params: ModelParams, beam_angles=None) -> tuple:
    """The argument tuple of :data:`full_model`: ``(pos (2,), params, beam_angles (K,))``; the beam angles
    default to the tutorial's ``angles(params.num_angles)``."""
    if beam_angles is None:
        beam_angles = angles(params.num_angles)
    return (jnp.asarray(pos, dtype=jnp.result_type(float)), params, jnp.asarray(beam_angles))


def choices(walls, readings):
    """The choice map ``{"walls": walls, "readings": readings}``."""
    return C["walls"].set(jnp.asarray(walls)) | C["readings"].set(jnp.asarray(readings))


@jax.jit
def _assess(walls, readings, args):
    return full_model.assess(choices(walls, readings), args)[0]


def log_joint(walls, readings, pos, params: ModelParams, beam_angles=None):
    """``log p(walls, readings)`` under the full model: exactly ``full_model.assess``'s score.

    Args:
        walls: ``(nx, ny)`` array of 0/1 (float or bool).
        readings: ``(K,)`` range readings in meters.
        pos: ``(2,)`` sensor position, world meters.
        params: the model parameters.
        beam_angles: ``(K,)`` radians; default the tutorial's ``angles(params.num_angles)``.

    Returns:
        A scalar JAX float.
    """
    return _assess(jnp.asarray(walls, dtype=jnp.float32), jnp.asarray(readings), model_args(pos, params, beam_angles))


def simulate_readings(key, walls, pos, params: ModelParams, beam_angles=None):
    """Noisy range readings ``(K,)`` (meters) for the map ``walls`` ``(nx, ny)``, simulated from the sensor model
    with ``key`` (the tutorial's ``sensor_model.simulate``: with key 0 on the tutorial map, the tutorial's
    readings)."""
    pos, params, beam_angles = model_args(pos, params, beam_angles)
    trace = sensor_model.simulate(key, (pos, jnp.asarray(walls), params, beam_angles))
    return trace.get_retval()


def simulate(key, pos, params: ModelParams, beam_angles=None):
    """Sample ``(walls (nx, ny) bool, readings (K,))`` from the full model's prior predictive."""
    trace = full_model.simulate(key, model_args(pos, params, beam_angles))
    return trace.get_retval()


def prior_log_odds(params: ModelParams):
    """``log(p / (1 - p))`` of the prior wall probability."""
    p = jnp.asarray(params.prior_wall_prob)
    return jnp.log(p) - jnp.log1p(-p)


def as_numpy_walls(walls) -> np.ndarray:
    """``walls`` as a float32 numpy array of 0.0 / 1.0."""
    return (np.asarray(walls) > 0).astype(np.float32)
