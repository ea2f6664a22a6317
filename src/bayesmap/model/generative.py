"""The tutorial's generative model in GenJAX: the source of truth for every sampler.

* prior: each cell is a wall with probability ``prior_wall_prob``, independently (``genjax.flip`` repeated over
  the grid) at address ``"walls"``; with a coupling ``J > 0`` (``params.coupling``, ``params.neighbourhood`` 4) the
  structured prior of :mod:`bayesmap.model.prior`, a 4-neighbour Markov random field, through the observed
  auxiliary address ``"connections"`` (after ``"readings"``; :func:`choices` sets it to all 1), exactly;
* sensor model: each beam's range reading given the exact distance to the first wall (``genjax`` distribution
  vmapped over beams) at address ``"readings"``. ``params.beam_model`` picks it (:mod:`bayesmap.model.sensor`):
  ``"normal"`` (default) is the tutorial's ``Normal(exact distance, sensor_noise)`` (``genjax.normal``, unchanged);
  ``"beam"`` is the robust beam mixture of *Probabilistic Robotics* sec. 6.3 with a point mass at the max range.
  ``params.geometry`` says where a wall cell's reading is expected: ``"entry"`` (default, the tutorial's) at the
  face where the beam enters the first wall cell; ``"chord"`` anywhere on the beam's chord through that cell (the
  sensor model's hit averaged over the chord, :mod:`bayesmap.model.sensor`; the readings' distribution then takes
  the entry and exit distances from :func:`bayesmap.geometry.raycast.first_hit_chords`).
  ``params.wall_pass_prob`` ``pi`` (default 0: every wall cell stops the beam, the tutorial's model) lets a beam pass
  through a wall cell: the reading comes from the ray's first wall cell with probability ``1 - pi``, from its second
  with ``pi (1 - pi)``, and is read as if there were no wall with ``pi^2``
  (:func:`bayesmap.model.passable.pass_reading`, the two walls from :func:`bayesmap.geometry.raycast.wall_hit_chords`).
  ``params.cut_past_reading`` ``c`` (default ``inf``: the whole beam) cuts each beam ``c`` meters past its reading:
  a wall it enters at or beyond ``y + c`` counts as no wall (:func:`cut_chords`, :func:`cut_reading`). That is an
  approximation of the likelihood, not a way readings are made: ``assess`` scores the cut likelihood, ``simulate``
  draws from the uncut sensor model; it lets a ray-cell table stop at the cut (:func:`ray_limits`). Derivation and
  measured effect: ``docs/sensor.md``, "Beams cut past their readings".

:data:`full_model` is the tutorial's single scan; its arguments are ``(pos, params, beam_angles)``: the sensor
position (world meters; the tutorial's unit cells by default), the :class:`ModelParams` and the beam angles
(radians; the tutorial's ``angles(num_angles)`` unless given). :func:`model_args` builds them.

:data:`multi_scan_model` is the same map seen by ``S`` scans, each from its own pose with its own ``K`` beam angles:
arguments ``(poses (S, 2), params, beam_angles (S, K))``, readings ``(S, K)`` at ``"readings"``. A pose here is
a position and the scan's *world-frame* beam angles: the heading ``theta`` is already added to the angles (CARMEN
logs give world-frame angles; otherwise pass ``theta + angles_in_sensor_frame``). Every scan has the same number
of beams ``K``; scans with different numbers of beams are not supported (resample them to a common ``K``).
:func:`scan_args` builds and checks the arguments. The max distance ``params.max_range`` is also the sensor's max range.

:data:`bayesmap.model.slam.slam_model` adds the robot's poses as random choices (:mod:`bayesmap.model.slam`).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import genjax
import jax
import jax.numpy as jnp
import numpy as np
from genjax import ChoiceMapBuilder as C
from genjax import Pytree

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import angles, first_hit_chords, first_hit_distances, wall_hit_chords
from bayesmap.model import passable, prior, sensor


@Pytree.dataclass
class ModelParams(Pytree):
    """Parameters of the tutorial's model (a JAX pytree).

    Attributes:
        prior_wall_prob: prior probability that a cell is a wall, in (0, 1) (dynamic: changing it does not
            recompile).
        sensor_noise: standard deviation of a range reading in meters, > 0 (dynamic); for the beam model the hit
            component's ``sigma_hit``.
        num_angles: number of beams for the tutorial's equally spaced angles (static).
        grid: the grid geometry (static); default: the tutorial's 21 x 21 unit cells.
        max_distance: the max range in meters (static; :attr:`max_range` resolves the default); default: twice the
            grid's larger side (42 m for the tutorial). It is also the sensor's max range (the beam model's point
            mass sits there).
        beam_model: the sensor model, ``"normal"`` (the tutorial's) or ``"beam"`` (the robust mixture), static:
            see :mod:`bayesmap.model.sensor`.
        z_hit, z_short, z_max, z_rand: the beam mixture's weights (dynamic; >= 0, sum 1; PR eq. 6.12); unused by
            ``"normal"``. Defaults :data:`bayesmap.model.sensor.BEAM_DEFAULTS` (0.8, 0.05, 0.05, 0.1).
        lambda_short: rate of the beam model's short component, 1/m (dynamic; PR eq. 6.7); default 0.1.
        geometry: ``"entry"`` (the tutorial's: a wall cell's reading is expected where the beam enters it) or
            ``"chord"`` (the hit averaged over the beam's chord through the cell), static: see
            :mod:`bayesmap.model.sensor`.
        coupling: the structured prior's ``J`` >= 0, nats per pair of 4-neighbours that agree (dynamic; see
            :mod:`bayesmap.model.prior`); default 0, the tutorial's independent prior.
        neighbourhood: 0 (independent cells: the model has no ``"connections"`` address) or 4 (the Markov random
            field on pairs of cells sharing an edge), static; :func:`make_params` sets 4 when ``coupling > 0``. With
            4, ``prior_wall_prob`` is the conditional wall probability of a cell with as many wall as free
            neighbours, not the marginal (:mod:`bayesmap.model.prior`).
        wall_pass_prob: the probability ``pi`` in ``[0, 1)`` that a beam passes through a wall cell it meets
            (static); default 0, every wall cell stops the beam (the tutorial's model). With ``pi > 0`` a reading
            comes from the ray's first wall cell, its second, or no wall (module docstring;
            :func:`bayesmap.model.passable.pass_reading`).
        cut_past_reading: meters past its reading beyond which a beam does not look at the map (static; default
            ``inf``, the whole beam, the tutorial's model): a wall cell the beam enters at or beyond ``y +
            cut_past_reading`` counts as no wall for the reading ``y`` (:func:`cut_chords`; the module docstring
            says what this approximates; [derivation](../sensor.md#beams-cut-past-their-readings)).
    """

    prior_wall_prob: float = 0.5
    sensor_noise: float = 0.2
    num_angles: int = Pytree.static(default=100)
    grid: Grid = Pytree.static(default=Grid(shape=(21, 21)))
    max_distance: float | None = Pytree.static(default=None)
    beam_model: str = Pytree.static(default="normal")
    z_hit: float = sensor.BEAM_DEFAULTS["z_hit"]
    z_short: float = sensor.BEAM_DEFAULTS["z_short"]
    z_max: float = sensor.BEAM_DEFAULTS["z_max"]
    z_rand: float = sensor.BEAM_DEFAULTS["z_rand"]
    lambda_short: float = sensor.BEAM_DEFAULTS["lambda_short"]
    geometry: str = Pytree.static(default="entry")
    coupling: float = prior.DEFAULT_COUPLING
    neighbourhood: int = Pytree.static(default=0)
    wall_pass_prob: float = Pytree.static(default=0.0)
    cut_past_reading: float = Pytree.static(default=math.inf)

    @property
    def cut(self) -> bool:
        """True when a beam's walls are cut past its reading (``cut_past_reading`` finite, :func:`cut_chords`)."""
        return math.isfinite(self.cut_past_reading)

    @property
    def penetrable(self) -> bool:
        """True when a beam can pass through a wall cell (``wall_pass_prob > 0``): a reading then depends on its
        ray's first two wall cells, not the first alone."""
        return self.wall_pass_prob > 0

    @property
    def structured(self) -> bool:
        """True when the prior is the Markov random field (``neighbourhood > 0``): the model has a
        ``"connections"`` address and every sampler's conditional a neighbour term."""
        return self.neighbourhood > 0

    @property
    def max_range(self) -> float:
        """The model's max range in meters: ``max_distance`` if given, else the grid's default. Distances to the
        first wall are capped at it, and it is the sensor's max range (the beam model's point mass sits there)."""
        return self.grid.default_max_distance if self.max_distance is None else float(self.max_distance)

    @property
    def sensor_args(self) -> tuple:
        """The sensor model's parameters after the exact distance (see :func:`bayesmap.model.sensor.reading_logpdf`):
        ``(sensor_noise,)`` for ``"normal"``; ``(sensor_noise, z_hit, z_short, z_max, z_rand, lambda_short, max_range)``
        for ``"beam"`` (meters, 1/m). Pytree leaves stay traced under jit; ``max_range`` is a Python float."""
        if self.beam_model == "normal":
            return (self.sensor_noise,)
        return (self.sensor_noise, self.z_hit, self.z_short, self.z_max, self.z_rand, self.lambda_short, self.max_range)


def check_likelihood_power(value) -> float:
    """Validate the power ``eta`` of a tempered likelihood and return it as a float.

    A sampler run with ``eta`` targets ``p(walls) p(readings | walls) ** eta`` (a power, or "generalized",
    posterior: Gruenwald 2012, "The safe Bayesian"; Holmes & Walker 2017; Miller & Dunson 2019, "Robust Bayesian
    inference via coarsening"); ``eta = 1`` is the model's own posterior. The model (:data:`full_model`,
    :data:`multi_scan_model`) is unchanged: the tempered target's log density is the prior's log-probability plus
    ``eta`` times the rest of ``assess``'s score.

    Raises:
        BayesmapError: unless ``0 < eta <= 1`` (the message names the value).
    """
    try:
        eta = float(value)
    except (TypeError, ValueError):
        raise BayesmapError(f"likelihood_power must be a number, got {value!r}") from None
    if not (math.isfinite(eta) and 0.0 < eta <= 1.0):
        raise BayesmapError(f"likelihood_power must be in (0, 1] (1: the posterior), got {value!r}")
    return eta


def check_scan_powers(value, num_scans: int):
    """Validate the likelihood power of a SLAM kernel: one ``eta`` for every scan (returned as a float, as
    :func:`check_likelihood_power`), or one power per scan, ``(num_scans,)`` in ``[0, 1]`` (returned as a JAX
    array), the target then ``p(poses) p(walls) prod_s p(readings_s | walls, pose_s) ** eta_s``. A power of 0 leaves a
    scan out of the target: the data-tempered targets of sequential Monte Carlo that add a log's scans one at a time
    (Chopin 2002; :mod:`bayesmap.slam.smc`). Traced arrays (inside ``jit``) are passed through unchecked.

    Raises:
        BayesmapError: on a scalar outside (0, 1], or an array that is not ``(num_scans,)``, not finite or outside
            [0, 1] (the message names it).
    """
    if isinstance(value, jax.core.Tracer):
        return value
    if np.ndim(value) == 0:
        return check_likelihood_power(value)
    powers = np.asarray(value, dtype=np.float64)
    if powers.shape != (num_scans,) or not np.all(np.isfinite(powers)) or powers.min() < 0 or powers.max() > 1:
        raise BayesmapError(f"per-scan likelihood powers must be ({num_scans},) values in [0, 1], got "
                            f"shape {powers.shape} and values {np.array2string(powers, precision=3, threshold=8)}")
    return jnp.asarray(powers, dtype=jnp.result_type(float))


def scan_power(eta, t):
    """The power of scan ``t`` (a possibly traced index) under ``eta``, a float or ``(S,)`` per-scan powers
    (:func:`check_scan_powers`)."""
    return eta if jnp.ndim(eta) == 0 else eta[t]


def make_params(
    prior_wall_prob: float = 0.5,
    sensor_noise: float = 0.2,
    num_angles: int = 100,
    grid: Grid | None = None,
    max_distance: float | None = None,
    *,
    beam_model: str = "normal",
    z_hit: float = sensor.BEAM_DEFAULTS["z_hit"],
    z_short: float = sensor.BEAM_DEFAULTS["z_short"],
    z_max: float = sensor.BEAM_DEFAULTS["z_max"],
    z_rand: float = sensor.BEAM_DEFAULTS["z_rand"],
    lambda_short: float = sensor.BEAM_DEFAULTS["lambda_short"],
    geometry: str = "entry",
    coupling: float = prior.DEFAULT_COUPLING,
    neighbourhood: int | None = None,
    wall_pass_prob: float = 0.0,
    cut_past_reading: float = math.inf,
) -> ModelParams:
    """Build :class:`ModelParams` after checking every value.

    The first five arguments keep their positions; the sensor model's are keyword-only: ``beam_model``
    (``"normal"`` or ``"beam"``), the mixture weights ``z_hit, z_short, z_max, z_rand`` and ``lambda_short`` (1/m),
    see :mod:`bayesmap.model.sensor` (checked for either model), and the wall ``geometry`` (``"entry"`` or
    ``"chord"``); the structured prior's ``coupling`` ``J`` (nats per agreeing pair of 4-neighbours,
    :mod:`bayesmap.model.prior`) and ``neighbourhood`` (default: 4 if ``coupling > 0``, else 0, the tutorial's
    independent prior and model); ``wall_pass_prob``, the probability that a beam passes through a wall cell
    (default 0, the tutorial's: :class:`ModelParams`); ``cut_past_reading``, meters past its reading beyond which a
    beam does not look at the map (default ``inf``: :class:`ModelParams`).

    Raises:
        BayesmapError: if ``prior_wall_prob`` is not in (0, 1), ``sensor_noise`` is not finite and > 0,
            ``num_angles`` is not an integer >= 1, ``max_distance`` is not finite and > 0, ``beam_model`` is
            unknown, ``geometry`` is unknown, the mixture parameters are bad
            (:func:`bayesmap.model.sensor.check_sensor_params`), the coupling is not in ``[0, MAX_COUPLING]`` or the
            neighbourhood not 0 or 4 (0 with a coupling > 0), ``wall_pass_prob`` is not in ``[0, 1)``, or
            ``cut_past_reading`` is not a number > 0 (``inf`` allowed); the message names the bad value.
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
    weights = sensor.check_sensor_params(beam_model, z_hit, z_short, z_max, z_rand, lambda_short)
    sensor.check_geometry(geometry)
    wall_pass_prob = passable.check_wall_pass_prob(wall_pass_prob)
    cut = _check_cut(cut_past_reading)
    coupling = prior.check_coupling(coupling)
    neighbourhood = (4 if coupling > 0 else 0) if neighbourhood is None else prior.check_neighbourhood(neighbourhood)
    if coupling > 0 and neighbourhood == 0:
        raise BayesmapError(f"a coupling of {coupling!r} needs neighbourhood 4, got neighbourhood 0")
    return ModelParams(
        prior_wall_prob=p,
        sensor_noise=noise,
        num_angles=int(num_angles),
        grid=grid or Grid(shape=(21, 21)),
        max_distance=None if max_distance is None else float(max_distance),
        beam_model=beam_model,
        geometry=geometry,
        **dict(zip(("z_hit", "z_short", "z_max", "z_rand", "lambda_short"), weights)),
        coupling=coupling,
        neighbourhood=neighbourhood,
        wall_pass_prob=wall_pass_prob,
        cut_past_reading=cut,
    )


def _check_cut(value) -> float:
    try:
        cut = float(value)
    except (TypeError, ValueError):
        raise BayesmapError(f"cut_past_reading must be a number (meters), got {value!r}") from None
    if not cut > 0:  # (NaN fails too)
        raise BayesmapError(f"cut_past_reading must be > 0 (meters; inf: the whole beam), got {value!r}")
    return cut


PARAMS_FIELDS = tuple(field.name for field in dataclasses.fields(ModelParams))
"""The fields of :class:`ModelParams`, each an argument of :func:`make_params` of the same name (tested)."""


def replace_params(params: ModelParams, **changes) -> ModelParams:
    """``params`` with the fields named in ``changes`` replaced, every value checked again by :func:`make_params`
    (``neighbourhood=None`` derives it from the coupling again; ``max_distance`` keeps ``params.max_distance``,
    ``None`` included, unless given).

    Raises:
        BayesmapError: as :func:`make_params`, or if a name in ``changes`` is not one of :data:`PARAMS_FIELDS`.
    """
    unknown = sorted(set(changes) - set(PARAMS_FIELDS))
    if unknown:
        raise BayesmapError(f"not a model parameter: {', '.join(unknown)} (the fields: {', '.join(PARAMS_FIELDS)})")
    return make_params(**{name: getattr(params, name) for name in PARAMS_FIELDS} | changes)


def walls_prior(shape: tuple[int, int]):
    """The prior over walls as a generative function of ``prior_wall_prob``: ``(nx, ny)`` independent flips."""
    return genjax.flip.repeat(n=shape[1]).repeat(n=shape[0])


def _beam_chords(walls, pos, angle, params: ModelParams):
    """``(3, 2)`` the chords of a beam's first two wall cells and no wall (wall cells a beam can pass), else
    ``(1, 2)`` its first wall cell's (meters)."""
    if params.penetrable:
        walls2 = wall_hit_chords(walls, pos, angle[None], params.grid, params.max_range, passable.PASS_WALLS)[0]
        return jnp.concatenate([walls2, jnp.full((1, 2), params.max_range, walls2.dtype)])
    return first_hit_chords(walls, pos, angle[None], params.grid, params.max_range)


@genjax.gen
def sensor_model_single(pos, walls, params: ModelParams, angle):
    """One beam, a scalar reading (meters) at address ``()`` given the first wall: in the ``"entry"`` geometry its
    exact distance ``d`` (capped at ``params.max_range``), ``Normal(d, sensor_noise)`` for ``beam_model="normal"``
    (the tutorial's, through ``genjax.normal`` exactly as before) or the beam mixture
    :data:`bayesmap.model.sensor.beam_reading` for ``"beam"``; in the ``"chord"`` geometry the entry and exit
    distances ``(a, b)`` of the first wall cell (:func:`bayesmap.geometry.raycast.first_hit_chords`) and
    :data:`~bayesmap.model.sensor.chord_normal_reading` or :data:`~bayesmap.model.sensor.chord_beam_reading`.
    With ``params.wall_pass_prob > 0``, the chords of the first two wall cells and no wall
    (:func:`bayesmap.geometry.raycast.wall_hit_chords`) and :func:`~bayesmap.model.passable.pass_reading`."""
    if params.cut:
        reading = cut_reading(params.beam_model, params.geometry, params.penetrable, params.cut_past_reading,
                              params.max_range)
        return reading(_beam_chords(walls, pos, angle, params), params.wall_pass_prob, *params.sensor_args) @ ()
    if params.penetrable:
        chords = _beam_chords(walls, pos, angle, params)
        reading = passable.pass_reading(params.beam_model, params.geometry)
        return reading(chords, params.wall_pass_prob, *params.sensor_args) @ ()
    if params.geometry == "chord":
        chord = first_hit_chords(walls, pos, angle[None], params.grid, params.max_range)[0]
        reading = sensor.reading_distribution(params.beam_model, "chord")
        return reading(chord[0], chord[1], *params.sensor_args) @ ()
    exact = first_hit_distances(walls, pos, angle[None], params.grid, params.max_range)[0]
    if params.beam_model == "normal":
        return genjax.normal(exact, params.sensor_noise) @ ()
    return sensor.reading_distribution(params.beam_model)(exact, *params.sensor_args) @ ()


sensor_model = sensor_model_single.vmap(in_axes=(None, None, None, 0))
"""All beams of a scan: arguments ``(pos, walls, params, beam_angles (K,))``, readings ``(K,)``."""


@genjax.gen
def full_model(pos, params: ModelParams, beam_angles):
    """The tutorial's full model: walls from the prior at ``"walls"``, readings at ``"readings"``.

    Returns ``(walls, readings)``: ``(nx, ny)`` bool and ``(K,)`` float (meters).
    """
    walls = walls_prior(params.grid.shape)(params.prior_wall_prob) @ "walls"
    readings = sensor_model(pos, walls, params, beam_angles) @ "readings"
    if params.structured:  # the structured prior's observed connections (bayesmap.model.prior); last: the keys of
        prior.connections(walls, params.coupling) @ "connections"  # "walls" and "readings" stay the same
    return walls, readings


scan_sensor_model = sensor_model.vmap(in_axes=(0, None, None, 0))
"""All beams of ``S`` scans: arguments ``(poses (S, 2), walls, params, beam_angles (S, K))``, readings ``(S, K)``."""


@genjax.gen
def multi_scan_model(poses, params: ModelParams, beam_angles):
    """One map seen by ``S`` scans: walls from the prior at ``"walls"``, readings ``(S, K)`` at ``"readings"``.

    Args (see :func:`scan_args`):
        poses: ``(S, 2)`` sensor positions, world meters.
        params: the model parameters (the sensor model is ``params.beam_model``).
        beam_angles: ``(S, K)`` world-frame beam angles, radians (heading included).

    Returns ``(walls, readings)``: ``(nx, ny)`` bool and ``(S, K)`` float (meters). Given the walls, scans and beams
    are independent, so its log joint is the prior plus the sum over scans of :data:`sensor_model`'s score.
    """
    walls = walls_prior(params.grid.shape)(params.prior_wall_prob) @ "walls"
    readings = scan_sensor_model(poses, walls, params, beam_angles) @ "readings"
    if params.structured:  # as in full_model
        prior.connections(walls, params.coupling) @ "connections"
    return walls, readings


def scan_args(poses, params: ModelParams, beam_angles) -> tuple:
    """The argument tuple of :data:`multi_scan_model`: ``(poses (S, 2), params, beam_angles (S, K))`` as JAX arrays
    of the default float dtype.

    Args:
        poses: ``(S, 2)`` sensor positions, world meters (``(2,)`` is one scan). Only the position: fold the
            heading into ``beam_angles``.
        params: the model parameters.
        beam_angles: ``(S, K)`` world-frame beam angles, radians (``(K,)`` is one scan).

    Raises:
        BayesmapError: if ``poses`` is not ``(S, 2)``, ``beam_angles`` not ``(S, K)`` with the same ``S`` and
            ``K >= 1``, or a value is not finite.
    """
    poses = np.asarray(poses, dtype=np.float64)
    beam_angles = np.asarray(beam_angles, dtype=np.float64)
    if poses.ndim == 1:
        poses = poses[None]
    if beam_angles.ndim == 1:
        beam_angles = beam_angles[None]
    if poses.ndim != 2 or poses.shape[1] != 2 or poses.shape[0] < 1:
        raise BayesmapError(f"poses must have shape (S, 2) (positions in meters), got {poses.shape}")
    if beam_angles.ndim != 2 or beam_angles.shape[0] != poses.shape[0] or beam_angles.shape[1] < 1:
        raise BayesmapError(f"beam_angles must have shape (S, K) = ({poses.shape[0]}, K) with K >= 1, "
                            f"got {beam_angles.shape}")
    if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(beam_angles))):
        raise BayesmapError("poses and beam angles must be finite")
    dtype = jnp.result_type(float)
    return jnp.asarray(poses, dtype=dtype), params, jnp.asarray(beam_angles, dtype=dtype)


@jax.jit
def _assess_scans(walls, readings, args):
    return multi_scan_model.assess(choices(walls, readings, args[1]), args)[0]


def log_joint_scans(walls, readings, poses, params: ModelParams, beam_angles):
    """``log p(walls, readings)`` under :data:`multi_scan_model`: exactly its ``assess`` score.

    Args:
        walls: ``(nx, ny)`` array of 0/1 (float or bool).
        readings: ``(S, K)`` range readings in meters (max-range readings equal to ``params.max_range``).
        poses: ``(S, 2)`` sensor positions, world meters.
        params: the model parameters.
        beam_angles: ``(S, K)`` world-frame beam angles, radians.

    Returns:
        A scalar JAX float.

    Raises:
        BayesmapError: on shapes that do not match (:func:`scan_args`) or readings not ``(S, K)``.
    """
    args = scan_args(poses, params, beam_angles)
    readings = jnp.asarray(readings)
    if readings.shape != args[2].shape:
        raise BayesmapError(f"readings must have shape {tuple(args[2].shape)} (S, K), got {tuple(readings.shape)}")
    return _assess_scans(jnp.asarray(walls, dtype=jnp.float32), readings, args)


def simulate_scan_readings(key, walls, poses, params: ModelParams, beam_angles):
    """Range readings ``(S, K)`` (meters) for the map ``walls`` ``(nx, ny)`` from ``S`` scans, simulated from the
    sensor model (:data:`scan_sensor_model`) with ``key``; see :func:`scan_args` for the shapes.

    Raises:
        BayesmapError: on shapes that do not match.
    """
    poses, params, beam_angles = scan_args(poses, params, beam_angles)
    return _simulate_scans(key, (poses, jnp.asarray(walls), params, beam_angles))


@jax.jit
def _simulate_scans(key, args):
    """:data:`scan_sensor_model`'s simulated readings, compiled once per shape (run eagerly, each of the model's
    operations would compile on its own)."""
    return scan_sensor_model.simulate(key, args).get_retval()


def reading_log_likelihood(readings, distances, params: ModelParams, exit_distances=None):
    """Per-beam log-likelihood ``log p(y | d)`` of readings ``y`` given the first wall's entry distances ``d``
    (meters, same shape) under ``params.beam_model``: :func:`bayesmap.model.sensor.reading_logpdf` with
    ``params.sensor_args``; in the ``"chord"`` geometry with the first wall cell's exit distances
    ``exit_distances`` (meters, same shape).

    Raises:
        BayesmapError: if ``params.geometry`` is ``"chord"`` and ``exit_distances`` is None, or if wall cells can
            be passed (``params.wall_pass_prob > 0``: the reading depends on the second wall too; use
            :func:`walls_log_likelihood`).
    """
    check_opaque_walls(params, "a first-wall log-likelihood")
    if params.geometry == "chord":
        if exit_distances is None:
            raise BayesmapError("the chord geometry needs the first wall cells' exit distances")
        exit_distances = jnp.asarray(exit_distances)
    else:
        exit_distances = None
    y, distances = jnp.asarray(readings), jnp.asarray(distances)
    if params.cut:
        exits = distances if exit_distances is None else exit_distances
        chord = cut_chords(y, jnp.stack([distances, exits.astype(distances.dtype)], axis=-1)[..., None, :], params)
        distances, exit_distances = chord[..., 0, 0], None if exit_distances is None else chord[..., 0, 1]
    return sensor.reading_logpdf(params.beam_model, y, distances, params.sensor_args, exit_distances)


def walls_log_likelihood(readings, chords, params: ModelParams):
    """Per-beam log-likelihood of readings ``y`` ``(...,)`` given the chords ``(..., 2, 2)`` (meters: entry and exit
    distance) of each ray's first and second wall cell (both the max distance for a wall that does not exist), for
    any ``params``: the first wall's :func:`reading_log_likelihood` when every wall cell stops the beam, the
    mixture :func:`bayesmap.model.passable.pass_mixture` over the first wall, the second and no wall when
    ``params.wall_pass_prob > 0`` (what the model's ``assess`` scores per beam). The entry geometry ignores the
    exits. Never raises for matching shapes."""
    y, chords = jnp.asarray(readings), cut_chords(readings, chords, params)
    exits = chords[..., 1] if params.geometry == "chord" else None
    if not params.penetrable:
        return reading_log_likelihood(y, chords[..., 0, 0], params, None if exits is None else exits[..., 0])
    none = jnp.full(y.shape, params.max_range, chords.dtype)
    parts = [sensor.reading_logpdf(params.beam_model, y, a, params.sensor_args, b)
             for a, b in ((chords[..., 0, 0], None if exits is None else exits[..., 0]),
                          (chords[..., 1, 0], None if exits is None else exits[..., 1]),
                          (none, None if exits is None else none))]
    return passable.pass_mixture(*parts, params.wall_pass_prob)


def cut_chords(readings, chords, params: ModelParams):
    """The chords ``(..., n, 2)`` (entry and exit distance, meters, of a beam's first ``n`` wall cells in order)
    of beams with readings ``(...,)`` (meters), cut past the readings: a wall entered at or beyond ``y +
    params.cut_past_reading`` becomes no wall, ``(M, M)`` with ``M = params.max_range``, and so do the walls after
    it. The chords unchanged when ``params.cut`` is False. Computed in the chords' dtype; never raises."""
    chords = jnp.asarray(chords)
    if not params.cut:
        return chords
    return _cut(readings, chords, params.cut_past_reading, params.max_range)


def _cut(readings, chords, cut: float, max_range: float):
    limit = jnp.asarray(readings, chords.dtype) + jnp.asarray(cut, chords.dtype)
    beyond = chords[..., :1] >= limit[..., None, None]
    return jnp.where(beyond, jnp.asarray(max_range, chords.dtype), chords)


@functools.cache
def cut_reading(beam_model: str, geometry: str, penetrable: bool, cut: float, max_range: float):
    """The GenJAX distribution of a reading whose beam is cut ``cut`` meters past it (:func:`cut_chords`), for
    ``beam_model`` in ``geometry`` with wall cells a beam can pass (``penetrable``) or not; ``max_range`` is the
    model's (meters). Arguments ``(chords (n, 2), pass_prob, *sensor_args)``: the entry and exit distances of the
    beam's first wall cell (``n = 1``), or of its first two and no wall (``n = 3``, as
    :func:`bayesmap.model.passable.pass_reading` takes them). ``assess`` scores the sensor model at the cut chords;
    ``simulate`` draws from the sensor model at the chords as given (the cut is a likelihood's approximation, not a
    way readings are made: module docstring).

    Raises:
        BayesmapError: on an unknown model or geometry name.
    """
    inner = (passable.pass_reading(beam_model, geometry) if penetrable
             else sensor.reading_distribution(beam_model, geometry))

    def inner_args(chords, pass_prob, sensor_args):
        if penetrable:
            return (chords, pass_prob, *sensor_args)
        if geometry == "chord":
            return (chords[0, 0], chords[0, 1], *sensor_args)
        return (chords[0, 0], *sensor_args)

    def logpdf(y, chords, pass_prob, *sensor_args):
        return inner.logpdf(y, *inner_args(_cut(y, chords, cut, max_range), pass_prob, sensor_args))

    def sample(key, chords, pass_prob, *sensor_args):
        return inner.sample(key, *inner_args(chords, pass_prob, sensor_args))

    return genjax.exact_density(sample, logpdf, name=f"cut_{geometry}_{beam_model}_reading")


def ray_limits(readings, params: ModelParams, dtype=None) -> np.ndarray | None:
    """``(R,)`` each beam's own max distance for a ray-cell table (meters, ``dtype``, default JAX's default float):
    ``min(y + cut_past_reading, max_range)`` computed as :func:`cut_chords` computes the cut, so the table lists
    exactly the cells the cut model looks at (:attr:`bayesmap.geometry.raytable.RayTable.ray_limits`); None when
    ``params.cut`` is False."""
    if not params.cut:
        return None
    dtype = np.dtype(jnp.result_type(float) if dtype is None else dtype)
    y = np.asarray(readings, dtype=np.float64).reshape(-1).astype(dtype)
    return np.minimum(y + dtype.type(params.cut_past_reading), dtype.type(params.max_range))


def beam_lengths(readings, params: ModelParams):
    """Each beam's length in a ray-cell table, meters: :func:`ray_limits` ``(R,)`` float64 where the model cuts
    beams past their readings, else ``params.max_range`` (a float, the same for every beam)."""
    limits = ray_limits(readings, params)
    return float(params.max_range) if limits is None else limits.astype(np.float64)


def check_opaque_walls(params: ModelParams, what: str) -> None:
    """Refuse wall cells a beam can pass through where only the first wall is computed (``what`` names the caller:
    the level-based fast samplers, the dense sweeps and the pose moves keep one wall per ray).

    Raises:
        BayesmapError: if ``params.wall_pass_prob > 0``, naming it and ``what``.
    """
    if params.penetrable:
        raise BayesmapError(f"{what} supports only wall_pass_prob 0 (every wall cell stops the beam), got "
                            f"wall_pass_prob = {params.wall_pass_prob!r}; the cellwise sampler supports it")


def check_entry_geometry(params: ModelParams, what: str) -> None:
    """Refuse the chord geometry where only the tutorial's entry geometry is implemented (``what`` names the caller:
    the dense map sweep of the tutorial-scale SLAM chain computes only entry distances).

    Raises:
        BayesmapError: if ``params.geometry`` is not ``"entry"``, naming it and ``what``.
    """
    if params.geometry != "entry":
        raise BayesmapError(f"{what} supports only geometry 'entry', got params.geometry = {params.geometry!r}")


def model_args(pos, params: ModelParams, beam_angles=None) -> tuple:
    """The argument tuple of :data:`full_model`: ``(pos (2,), params, beam_angles (K,))``; the beam angles
    default to the tutorial's ``angles(params.num_angles)``."""
    if beam_angles is None:
        beam_angles = angles(params.num_angles)
    return (jnp.asarray(pos, dtype=jnp.result_type(float)), params, jnp.asarray(beam_angles))


def choices(walls, readings, params: ModelParams | None = None):
    """The choice map ``{"walls": walls, "readings": readings}``; with ``params`` of a structured prior
    (``params.structured``) also the observed ``"connections"``, all 1
    (:func:`bayesmap.model.prior.observed_connections`), so that ``assess`` scores the Markov random field's
    unnormalized prior."""
    chm = C["walls"].set(jnp.asarray(walls)) | C["readings"].set(jnp.asarray(readings))
    if params is not None and params.structured:
        chm = chm | C["connections"].set(prior.observed_connections(jnp.shape(walls)))
    return chm


@jax.jit
def _assess(walls, readings, args):
    return full_model.assess(choices(walls, readings, args[1]), args)[0]


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
    return _simulate_scan(key, (pos, jnp.asarray(walls), params, beam_angles))


@jax.jit
def _simulate_scan(key, args):
    """:data:`sensor_model`'s simulated readings, compiled once per shape."""
    return sensor_model.simulate(key, args).get_retval()


def simulate(key, pos, params: ModelParams, beam_angles=None):
    """Sample ``(walls (nx, ny) bool, readings (K,))`` from the full model's prior predictive."""
    trace = full_model.simulate(key, model_args(pos, params, beam_angles))
    return trace.get_retval()


def prior_log_odds(prior_wall_prob: float) -> float:
    """The prior log-odds of a wall, ``log(p / (1 - p))`` of the prior wall probability ``p`` (a float in (0, 1),
    ``params.prior_wall_prob``), computed in float64 as ``log(p) - log1p(-p)``: the prior's part of every cell's
    Gibbs conditional log-odds (and, times the number of walls, of a block configuration's log-weight relative to
    the all-free configuration). The one place the samplers compute it."""
    p = float(prior_wall_prob)
    return math.log(p) - math.log1p(-p)


def as_numpy_walls(walls) -> np.ndarray:
    """``walls`` as a float32 numpy array of 0.0 / 1.0."""
    return (np.asarray(walls) > 0).astype(np.float32)
