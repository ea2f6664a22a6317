"""The structured prior over walls: a pairwise Markov random field in which walls come in connected runs.

The tutorial's prior makes every cell a wall independently with probability ``prior_wall_prob``; the tutorial
itself proposes a prior in which "wall pixels are likely connected". This module gives it as an Ising model on
the 4-neighbourhood of the grid (Geman & Geman 1984, sec. IV; Besag 1974; Li, *Markov Random Field Modeling in
Image Analysis*, 3rd ed. 2009, sec. 1.2.4):

    log p(w) = h * sum_c w_c + J * sum_{c ~ c'} [w_c == w_c'] + const

over the cells ``c`` and the unordered pairs ``c ~ c'`` of 4-neighbours (cells that share an edge), with

* ``h = log(pi / (1 - pi))``, ``pi = prior_wall_prob``;
* ``J = coupling >= 0`` (nats per pair of neighbours that agree). ``J = 0`` is the tutorial's independent prior,
  exactly.

**What** ``prior_wall_prob`` **means once J > 0.** The MRF's conditional log-odds of a wall given the rest of the
map is (the derivation is in ``docs/structured-prior.md``)

    log p(w_c = 1 | w_-c) - log p(w_c = 0 | w_-c) = h + J (n_wall(c) - n_free(c)),

where ``n_wall`` and ``n_free`` count the cell's 4-neighbours (inside the grid) that are walls and free. So
``prior_wall_prob`` is the probability that a cell is a wall *given that as many of its neighbours are walls as
are free* (for example a cell between a wall run's end and free space), not the fraction of wall cells a map
from the prior has: with ``J > 0`` and ``pi < 0.5`` the marginal is smaller than ``pi``; it is computed by a
chain on the prior (:func:`sample_prior`) when needed.

**The coupling's default and its meaning in meters.** The default is ``J = 0`` (:data:`DEFAULT_COUPLING`): the
tutorial's prior, every existing number unchanged. A coupling is set either directly (nats) or from a length in
meters with :func:`coupling_for_run_length`: in a chain of cells (one row of the grid) with ``h = 0``, neighbours
differ with probability ``1 / (1 + e^J)``, so runs of equal cells are geometric with mean ``1 + e^J`` cells;
``J = log(L / resolution - 1)`` makes that mean ``L`` meters at any resolution. The coupling then *depends on the
resolution* (finer cells need a stronger coupling for the same run in meters): the rule is stated in meters, never
as a count of cells. The maps of logs default to ``L =`` :data:`bayesmap.scenes.LOG_RUN_LENGTH` meters
(:func:`bayesmap.scenes.log_coupling`), chosen by leave-one-log-out cross-validation
([validation](../validation/defaults.md#log_run_length)); every other scene keeps ``J = 0``.

**In the GenJAX model, exactly.** The MRF's normalizing constant is intractable, so the model does not sample the
MRF directly. It keeps the independent prior at ``"walls"`` and adds an *observed* auxiliary choice at
``"connections"`` (:data:`connections`): for each pair of 4-neighbours ``(c, c')`` a bit with

    p(connection = 1 | w) = exp(J ([w_c == w_c'] - 1))

(1 for neighbours that agree, ``e^-J`` for neighbours that differ; a "Swendsen-Wang"-style bond, Swendsen & Wang
1987, Edwards & Sokal 1988). Conditioning on every connection being 1 multiplies the independent prior by
``exp(J sum ([w_c == w_c'] - 1))``, i.e. gives the MRF above: ``assess`` of a choice map whose connections are all
1 (:func:`observed_connections`) is ``log p_MRF(w) + log p(readings | w)`` up to a constant that does not depend on
the walls, and ``simulate`` stays a valid sampler of the augmented model. The address holds a ``(2, nx, ny)`` bool
array: ``[0, i, j]`` is the pair ``((i, j), (i + 1, j))``, ``[1, i, j]`` the pair ``((i, j), (i, j + 1))``; entries
past the grid's edge pair a cell with itself (always agreeing: probability 1, log-probability 0 whatever ``J``).

The neighbourhood is static: ``ModelParams.neighbourhood`` is 0 (the independent prior: the model has no
``"connections"`` address, the tutorial's model unchanged) or 4. ``make_params(coupling=J)`` sets 4 when ``J > 0``.
"""

from __future__ import annotations

import math

import genjax
import jax
import jax.numpy as jnp
import numpy as np

from bayesmap.errors import BayesmapError

NEIGHBOURHOODS = (0, 4)
"""Supported neighbourhoods: 0 (independent cells, the tutorial's prior) and 4 (pairs of cells sharing an edge)."""

DEFAULT_COUPLING = 0.0
"""Default coupling ``J`` (nats per agreeing pair of neighbours): 0, the tutorial's independent prior."""

MAX_COUPLING = 20.0
"""Largest coupling accepted: ``e^-20`` for a pair of neighbours that differ is already 2e-9."""


def check_coupling(value) -> float:
    """Validate a coupling ``J`` (nats per agreeing pair of 4-neighbours) and return it as a float.

    Raises:
        BayesmapError: unless ``0 <= J <= MAX_COUPLING`` (the message names the value).
    """
    try:
        coupling = float(value)
    except (TypeError, ValueError):
        raise BayesmapError(f"coupling must be a number, got {value!r}") from None
    if not (math.isfinite(coupling) and 0.0 <= coupling <= MAX_COUPLING):
        raise BayesmapError(f"coupling must be between 0 and {MAX_COUPLING:g} (nats per pair of neighbours), "
                            f"got {value!r}")
    return coupling


def coupling_for_run_length(run_length: float, resolution: float) -> float:
    """The coupling ``J = log(run_length / resolution - 1)`` whose runs of equal cells along a row have a mean
    length of ``run_length`` meters in a chain of cells with zero field (see the module docstring).

    Args:
        run_length: mean run length, meters; at least two cells (``J = 0`` gives runs of two cells on average).
        resolution: meters per cell, > 0.

    Returns:
        ``J`` in nats, >= 0.

    Raises:
        BayesmapError: if ``resolution`` is not finite and > 0, or ``run_length`` is shorter than two cells or not
            finite (the message names the value).
    """
    res = float(resolution)
    if not (math.isfinite(res) and res > 0):
        raise BayesmapError(f"resolution must be a finite number > 0 (meters), got {resolution!r}")
    length = float(run_length)
    if not (math.isfinite(length) and length >= 2 * res):
        raise BayesmapError(f"run_length must be at least two cells ({2 * res:g} m at {res:g} m per cell), "
                            f"got {run_length!r}")
    return check_coupling(math.log(length / res - 1.0))


def check_neighbourhood(value) -> int:
    """Return ``value`` as an int if it is a supported neighbourhood (:data:`NEIGHBOURHOODS`).

    Raises:
        BayesmapError: otherwise, naming it.
    """
    if value not in NEIGHBOURHOODS:
        raise BayesmapError(f"neighbourhood must be one of {', '.join(map(str, NEIGHBOURHOODS))}, got {value!r}")
    return int(value)


# -- the pairs of neighbours --------------------------------------------------------------------------------------


def agreements(walls) -> jax.Array:
    """``(2, nx, ny)`` bool: whether each cell agrees with its neighbour along x (``[0]``) and along y (``[1]``) of
    the map ``walls`` ``(nx, ny)`` (> 0 is a wall); True past the grid's edge (a cell paired with itself). Works on
    numpy or JAX input, under ``jit``."""
    w = jnp.asarray(walls) > 0
    next_x = jnp.concatenate([w[1:], w[-1:]], axis=0)
    next_y = jnp.concatenate([w[:, 1:], w[:, -1:]], axis=1)
    return jnp.stack([w == next_x, w == next_y])


def disagreeing_pairs(walls) -> jax.Array:
    """Number of pairs of 4-neighbours of ``walls`` ``(nx, ny)`` that differ (one wall, one free): a scalar int."""
    return jnp.sum(~agreements(walls))


def neighbour_field(walls) -> jax.Array:
    """``(nx, ny)`` float32 ``n_wall - n_free`` of each cell: its 4-neighbours inside the grid that are walls minus
    those that are free, for ``walls`` ``(nx, ny)`` (> 0 is a wall). Times ``J``, the MRF's part of a cell's
    conditional log-odds (see the module docstring)."""
    s = 2.0 * (jnp.asarray(walls) > 0).astype(jnp.float32) - 1.0
    zx = jnp.zeros((1, s.shape[1]), s.dtype)
    zy = jnp.zeros((s.shape[0], 1), s.dtype)
    return (jnp.concatenate([s[1:], zx], 0) + jnp.concatenate([zx, s[:-1]], 0)
            + jnp.concatenate([s[:, 1:], zy], 1) + jnp.concatenate([zy, s[:, :-1]], 1))


def neighbour_indices(shape: tuple[int, int]) -> np.ndarray:
    """``(nx * ny, 4)`` int64 flat indices ``i * ny + j`` of each cell's 4-neighbours ``(i - 1, j), (i + 1, j),
    (i, j - 1), (i, j + 1)``, ``-1`` where the neighbour is outside the grid."""
    nx, ny = shape
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    out = []
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        a, b = i + di, j + dj
        inside = (a >= 0) & (a < nx) & (b >= 0) & (b < ny)
        out.append(np.where(inside, a * ny + b, -1).reshape(-1))
    return np.stack(out, axis=1).astype(np.int64)


def internal_agreements(block_shape: tuple[int, int], configurations: np.ndarray) -> np.ndarray:
    """``(C,)`` float64: for each configuration ``(C, B)`` (0/1) of a block of ``block_shape`` cells (row-major, as
    :func:`bayesmap.inference.schedules.make_blocks`), the number of its pairs of 4-neighbours *inside the block*
    that agree. Times ``J``, the block's internal part of its MRF log-weight."""
    kx, ky = block_shape
    config = np.asarray(configurations) > 0
    cells = config.reshape(len(config), kx, ky)
    same_x = (cells[:, 1:, :] == cells[:, :-1, :]).sum(axis=(1, 2))
    same_y = (cells[:, :, 1:] == cells[:, :, :-1]).sum(axis=(1, 2))
    return (same_x + same_y).astype(np.float64)


def log_prior(walls, prior_wall_prob, coupling) -> jax.Array:
    """The structured prior's unnormalized log-probability of ``walls`` ``(nx, ny)``: the independent prior's
    ``sum_c [w_c log pi + (1 - w_c) log(1 - pi)]`` plus ``-J`` times the number of differing pairs of 4-neighbours
    (:func:`disagreeing_pairs`). Equal, up to a constant that does not depend on the walls, to the MRF's ``log p(w)``;
    equal to the GenJAX model's ``"walls"`` plus ``"connections"`` scores (all connections observed). A scalar
    float32 (float64 under x64)."""
    w = (jnp.asarray(walls) > 0)
    p = jnp.asarray(prior_wall_prob, dtype=jnp.result_type(float))
    independent = jnp.sum(jnp.where(w, jnp.log(p), jnp.log1p(-p)))
    return independent - jnp.asarray(coupling, p.dtype) * disagreeing_pairs(w).astype(p.dtype)


# -- the GenJAX distribution of the connections ------------------------------------------------------------------


def connection_log_prob(walls, coupling) -> jax.Array:
    """``(2, nx, ny)`` ``log p(connection = 1 | walls)``: 0 for agreeing neighbours (and past the edge), ``-J`` for
    differing ones."""
    j = jnp.asarray(coupling, dtype=jnp.result_type(float))
    return jnp.where(agreements(walls), jnp.zeros((), j.dtype), -j)


def connections_sample(key, walls, coupling) -> jax.Array:
    """Draw the ``(2, nx, ny)`` bool connections given ``walls`` ``(nx, ny)``: each 1 with probability
    ``exp(J ([agree] - 1))``. Never raises."""
    return jax.random.uniform(key, (2,) + tuple(jnp.shape(walls))) < jnp.exp(connection_log_prob(walls, coupling))


def connections_logpdf(value, walls, coupling) -> jax.Array:
    """``log p(connections = value | walls)``: the sum over pairs of ``log p`` of each bit, ``J ([agree] - 1)`` for a
    1 and ``log(1 - exp(J ([agree] - 1)))`` for a 0 (``-inf`` where the pair agrees). ``value`` ``(2, nx, ny)``
    bool. A scalar float."""
    lp = connection_log_prob(walls, coupling)
    log_one_minus = jnp.log(-jnp.expm1(jnp.minimum(lp, 0.0)))
    return jnp.sum(jnp.where(jnp.asarray(value) > 0, lp, log_one_minus))


connections = genjax.exact_density(connections_sample, connections_logpdf, name="connections")
"""GenJAX distribution of the observed connections, arguments ``(walls (nx, ny), coupling)``; see the module
docstring."""


def observed_connections(shape: tuple[int, int]) -> jax.Array:
    """The observed value of the ``"connections"`` address: ``(2, nx, ny)`` bool, all True."""
    return jnp.ones((2,) + tuple(shape), dtype=bool)


# -- samples from the prior --------------------------------------------------------------------------------------


def checkerboard_sweep(key, walls, prior_log_odds, coupling):
    """One Gibbs sweep of the structured prior alone over ``walls`` ``(nx, ny)`` float32 0/1: the cells with
    ``i + j`` even, all at once, then those with ``i + j`` odd. Cells of one colour share no pair of 4-neighbours,
    so given the other colour they are independent and each is drawn from its exact conditional, log-odds
    ``prior_log_odds + J (n_wall - n_free)`` (chromatic Gibbs on the two-colouring of the grid: Geman & Geman 1984,
    sec. XI; Gonzalez et al. 2011). Returns the new map. Jittable."""
    nx, ny = walls.shape
    even = (np.add.outer(np.arange(nx), np.arange(ny)) % 2 == 0)
    u = jax.random.uniform(key, (2, nx, ny))
    for colour, mask in enumerate((even, ~even)):
        logit = prior_log_odds + coupling * neighbour_field(walls)
        draw = (u[colour] < jax.nn.sigmoid(logit)).astype(walls.dtype)
        walls = jnp.where(mask, draw, walls)
    return walls


def sample_prior(key, shape: tuple[int, int], prior_wall_prob: float, coupling: float, sweeps: int = 500,
                 num_samples: int = 1) -> jax.Array:
    """Maps drawn from the structured prior by a chain on the prior alone: ``sweeps`` checkerboard Gibbs sweeps
    (:func:`checkerboard_sweep`) from independent draws of ``prior_wall_prob``, one chain per sample.

    With ``coupling = 0`` the sweeps draw every cell independently (the tutorial's prior exactly). With ``J > 0``
    the chain's samples approach the MRF's law as ``sweeps`` grows; near the Ising model's critical coupling
    (``J`` about 0.88 with ``h = 0``) mixing slows down (critical slowing down), so use many sweeps.

    Args:
        key: PRNG key.
        shape: ``(nx, ny)``.
        prior_wall_prob: ``pi`` in (0, 1).
        coupling: ``J`` >= 0.
        sweeps: >= 1.
        num_samples: independent chains, >= 1.

    Returns:
        ``(num_samples, nx, ny)`` float32 of 0.0 / 1.0.

    Raises:
        BayesmapError: on a bad probability, coupling, number of sweeps or samples.
    """
    p = float(prior_wall_prob)
    if not 0.0 < p < 1.0:
        raise BayesmapError(f"prior_wall_prob must be strictly between 0 and 1, got {prior_wall_prob!r}")
    j = check_coupling(coupling)
    for name, value in (("sweeps", sweeps), ("num_samples", num_samples)):
        if int(value) != value or value < 1:
            raise BayesmapError(f"{name} must be an integer >= 1, got {value!r}")
    logit = math.log(p) - math.log1p(-p)

    @jax.jit
    def chain(k):
        k0, k1 = jax.random.split(k)
        start = (jax.random.uniform(k0, tuple(shape)) < p).astype(jnp.float32)
        def sweep(t, w):
            return checkerboard_sweep(jax.random.fold_in(k1, t), w, logit, j)

        return jax.lax.fori_loop(0, int(sweeps), sweep, start)

    return jnp.stack([chain(k) for k in jax.random.split(key, int(num_samples))])
