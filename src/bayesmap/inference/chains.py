"""Running Markov chains: ``lax.scan`` chains, many chains, and per-cell diagnostics.

Every sampler is a :class:`~bayesmap.inference.base.SamplingAlgorithm` in the style of BlackJAX
(:mod:`bayesmap.inference.base`): a pure ``init(walls) -> state`` and a ``step(key, state) -> (state, info)`` kernel
that performs one sweep; a state exposes the current map as ``state.walls``, and ``info`` (a
:class:`~bayesmap.inference.base.GibbsInfo`) the conditional wall probabilities of the sweep as ``info.wall_prob`` if
the sampler records them (for Rao-Blackwellized posterior marginals). Keys are passed explicitly; there is no global
state.

A chain given a progress callback (:mod:`bayesmap.progress`) runs one compiled sweep per call over the keys the
whole chain would use, reporting after each (:func:`run_recorded_chains`): the same samples, bit for bit, as one
compiled loop.
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental.shard_map import shard_map
from jax.sharding import Mesh, PartitionSpec

from bayesmap.devices import sweep_devices
from bayesmap.errors import BayesmapError
from bayesmap.inference.base import SamplingAlgorithm
from bayesmap.progress import ProgressCallback, report


class ChainResult(NamedTuple):
    """Samples of one chain.

    Attributes:
        samples: ``(num_sweeps, nx, ny)`` bool, the map after each sweep.
        final_state: the sampler's state after the last sweep.
        wall_probs: ``(num_sweeps, nx, ny)`` float32, each sweep's conditional wall probabilities, for samplers that
            report them (``info.wall_prob`` of :class:`~bayesmap.inference.base.GibbsInfo`); else None.
    """

    samples: jax.Array
    final_state: object
    wall_probs: jax.Array | None = None


def _split(algorithm):
    """``algorithm`` -> (its array leaves, the hashable rest): arrays become arguments of the compiled chain, so
    that samplers whose arrays differ only in value (new readings, prior, noise) share one compilation; functions,
    sizes and flags are static."""
    leaves, treedef = jax.tree_util.tree_flatten(algorithm)
    is_array = [isinstance(x, (jax.Array, np.ndarray)) for x in leaves]
    arrays = [x for x, a in zip(leaves, is_array) if a]
    static = (treedef, tuple(None if a else x for x, a in zip(leaves, is_array)))
    return arrays, static


def _join(arrays, static):
    treedef, rest = static
    it = iter(arrays)
    return jax.tree_util.tree_unflatten(treedef, [next(it) if x is None else x for x in rest])


def scan_chain(key, initial_state, algorithm: SamplingAlgorithm, num_sweeps: int, record):
    """``num_sweeps`` steps of ``algorithm`` from ``initial_state`` by ``jax.lax.scan``, one key per sweep split
    from ``key`` (:func:`scan_sweeps` of ``jax.random.split(key, num_sweeps)``); ``record(state, info)`` picks what
    each sweep keeps (a pytree). Pure and jittable; the loop every chain of bayesmap runs (the map chains here, the
    joint chain of :mod:`bayesmap.slam.joint`).

    Returns:
        ``(final_state, records)``, each leaf of ``records`` with a leading ``(num_sweeps,)`` axis.
    """
    return scan_sweeps(jax.random.split(key, num_sweeps), initial_state, algorithm, record)


def scan_sweeps(sweep_keys, initial_state, algorithm: SamplingAlgorithm, record):
    """One step of ``algorithm`` per key of ``sweep_keys`` ``(n,)`` from ``initial_state``, by ``jax.lax.scan``:
    :func:`scan_chain` with its keys given, so that a chain can run in pieces (the keys ``[a:b]`` continue from the
    state after the keys ``[:a]``). Pure and jittable.

    Returns:
        ``(final_state, records)``, each leaf of ``records`` with a leading ``(n,)`` axis.
    """

    def body(state, k):
        state, info = algorithm.step(k, state)
        return state, record(state, info)

    return jax.lax.scan(body, initial_state, sweep_keys)


def _map_record(state, info):
    """What a map chain keeps per sweep: the map as bool and the conditional wall probabilities (or None)."""
    return state.walls > 0, info.wall_prob


@partial(jax.jit, static_argnames=("static", "num_sweeps", "record", "batch"))
def _run_jit(key, initial_state, arrays, static, num_sweeps: int, record, batch):
    """The one compiled chain of this module: :func:`scan_chain` of the algorithm ``_join(arrays, static)``.
    ``batch`` None: one chain; ``"keys"``: one chain per key of ``key`` ``(C,)`` from the shared ``initial_state``;
    ``"states"``: one per key and per state (``initial_state`` batched on a leading ``(C,)`` axis). Returns
    ``(final_state, records)`` (batched likewise)."""
    algorithm = _join(arrays, static)

    def one(k, state):
        return scan_chain(k, state, algorithm, num_sweeps, record)

    if batch is None:
        return one(key, initial_state)
    return jax.vmap(one, in_axes=(0, 0 if batch == "states" else None))(key, initial_state)


@partial(jax.jit, static_argnames=("static", "record", "batch"))
def _sweeps_jit(sweep_keys, initial_state, arrays, static, record, batch):
    """:func:`scan_sweeps` of the algorithm ``_join(arrays, static)`` over ``sweep_keys`` ``(n,)`` (``(C, n)``
    with ``batch``, as :func:`_run_jit`): one piece of a chain run in pieces."""
    algorithm = _join(arrays, static)

    def one(keys, state):
        return scan_sweeps(keys, state, algorithm, record)

    if batch is None:
        return one(sweep_keys, initial_state)
    return jax.vmap(one, in_axes=(0, 0 if batch == "states" else None))(sweep_keys, initial_state)


def _run(key, initial_state, arrays, static, num_sweeps: int, record, batch, progress: ProgressCallback | None,
         stage: str):
    """``_run_jit(key, initial_state, arrays, static, num_sweeps, record, batch)``; with ``progress``, the same
    numbers one sweep per compiled call (:func:`_sweeps_jit` over the keys ``_run_jit`` splits, one compilation
    whatever ``num_sweeps``), reporting ``Progress(stage, done, num_sweeps, "sweep")`` before the first sweep and
    after each; the records are then numpy arrays, each sweep's written into them while the next sweep runs (no
    second copy)."""
    num_sweeps = int(num_sweeps)
    if progress is None or num_sweeps < 1:
        return _run_jit(key, initial_state, arrays, static, num_sweeps, record, batch)
    if batch is None:
        sweep_keys = jax.random.split(key, num_sweeps)
    else:  # (C, num_sweeps): chain c's keys, as scan_chain splits them under vmap
        sweep_keys = jax.vmap(lambda k: jax.random.split(k, num_sweeps))(key)
    return _run_keys(sweep_keys, initial_state, arrays, static, record, batch, progress, stage)


def _on_device(arrays) -> list:
    """``arrays`` as the one-sweep program takes them: numpy arrays copied to the device once, not once per sweep;
    JAX arrays as they are (``jnp.asarray`` of one took 0.14 ms, two thirds of a small sampler's sweep)."""
    return [a if isinstance(a, jax.Array) else jnp.asarray(a) for a in arrays]


def _run_keys(sweep_keys, initial_state, arrays, static, record, batch, progress: ProgressCallback | None,
              stage: str, done: int = 0, total: int | None = None):
    """One compiled sweep per key of ``sweep_keys`` (``(n,)``; ``(C, n)`` with ``batch``) from ``initial_state``,
    reporting ``Progress(stage, done + t, total, "sweep")`` (``total`` default ``done + n``) before the first sweep
    and after each sweep ``t``; returns ``(final_state, records)``, the records numpy arrays, each sweep's written
    into them while the next sweep runs (no second copy)."""
    num_sweeps = int(sweep_keys.shape[-1])
    total = done + num_sweeps if total is None else total
    arrays = _on_device(arrays)
    state, out, pending = initial_state, None, None
    axis = 0 if batch is None else 1

    def write(t, records):  # sweep t's records into the numpy arrays (waits for the sweep), then its report
        at = (slice(None),) * axis + (slice(t, t + 1),)
        jax.tree.map(lambda o, r: o.__setitem__(at, np.asarray(r)), out, records)
        report(progress, stage, done + t + 1, total)

    report(progress, stage, done, total)
    for t in range(num_sweeps):
        keys = sweep_keys[t:t + 1] if batch is None else sweep_keys[:, t:t + 1]
        state, records = _sweeps_jit(keys, state, arrays, static, record, batch)
        batch = "states" if batch == "keys" else batch  # the chains' states part after their first sweep
        if out is None:
            out = jax.tree.map(lambda r: np.empty(r.shape[:axis] + (num_sweeps,) + r.shape[axis + 1:], r.dtype),
                               records)
        if pending is not None:  # the sweep before, copied while this one runs (JAX dispatches asynchronously)
            write(*pending)
        pending = (t, records)
    write(*pending)
    return state, out


def _map_chain(arrays, static, key, initial_state, num_sweeps: int, batch, progress: ProgressCallback | None = None,
               stage: str = "sweeps") -> ChainResult:
    final, (samples, wall_probs) = _run(key, initial_state, arrays, static, num_sweeps, _map_record, batch, progress,
                                        stage)
    return ChainResult(samples, final, wall_probs)


def run_recorded_chains(key, initial_state, algorithm: SamplingAlgorithm, num_sweeps: int, record,
                        num_chains: int | None = None, progress: ProgressCallback | None = None,
                        stage: str = "sweeps"):
    """Run a chain of ``num_sweeps`` steps of any kernel (:func:`scan_chain`) and return what ``record(state, info)``
    keeps per step; with ``num_chains``, that many independent chains from the same state (``key`` split into
    ``num_chains`` keys, ``vmap``). Compiled once per static part of ``algorithm``, shape of the state, ``record``
    (a module-level function, compared by identity), ``num_sweeps`` and ``num_chains``: an algorithm whose ``init``
    and ``step`` are pytrees (``jax.tree_util.Partial`` of module functions and arrays, as the pose and joint kernels
    are) reuses the compiled chain when only its arrays' values change; an algorithm of closures compiles anew.

    With ``progress`` (:mod:`bayesmap.progress`), the chain runs one sweep per compiled call over the same keys
    (the same records, bit for bit; one compilation for every ``num_sweeps``) and reports
    ``Progress(stage, done, num_sweeps, "sweep")`` before the first sweep and after each.

    Returns:
        ``record``'s pytree, each leaf with a leading ``(num_sweeps,)`` axis (``(num_chains, num_sweeps)`` with
        ``num_chains``).
    """
    arrays, static = _split(algorithm)
    if num_chains is None:
        return _run(key, initial_state, arrays, static, num_sweeps, record, None, progress, stage)[1]
    keys = jax.random.split(key, int(num_chains))
    return _run(keys, initial_state, arrays, static, num_sweeps, record, "keys", progress, stage)[1]


def compile_recorded_chain(key, initial_state, algorithm: SamplingAlgorithm, num_sweeps: int, record,
                           reported: bool) -> None:
    """Compile ahead of time the program :func:`run_recorded_chains` (one chain) runs with these arguments: with
    ``reported`` (a ``progress`` callback given) its one-sweep program, else its chain of ``num_sweeps`` sweeps.
    JAX keeps the executable, so that the first such call does not compile again: compile on another thread while
    this one works. ``initial_state`` may hold ``jax.ShapeDtypeStruct``s (``jax.eval_shape`` of ``init``)."""
    arrays, static = _split(algorithm)
    if reported:
        keys = jax.eval_shape(lambda k: jax.random.split(k, 1), key)  # one sweep's keys, as _run_keys slices them
        arrays = _on_device(arrays)  # (as _run_keys passes them)
        _sweeps_jit.lower(keys, initial_state, arrays, static, record, None).compile()
    else:
        _run_jit.lower(key, initial_state, arrays, static, int(num_sweeps), record, None).compile()


def compiled_chain_count() -> int:
    """How many chains are compiled and kept so far (by :func:`run_chain_from`, :func:`run_chains_from`,
    :func:`compile_chain` and :func:`run_recorded_chains`, whole or one sweep per call): one per distinct static part
    of a sampler (geometry, schedule, sensor model name), shape of the state, record function, number of sweeps (a
    chain run with progress: one) and of chains. Samplers that differ only in array values (readings, prior, noise;
    for the pose and joint kernels also the odometry) share a compiled chain, so running them does not change this
    count."""
    return int(_run_jit._cache_size()) + int(_sweeps_jit._cache_size())


def run_chain_from(key, initial_state, algorithm: SamplingAlgorithm, num_sweeps: int,
                   progress: ProgressCallback | None = None, stage: str = "sweeps") -> ChainResult:
    """Run ``num_sweeps`` sweeps of ``algorithm`` from a sampler state (``algorithm.init(walls)``, or the
    ``final_state`` of an earlier run, to continue a chain), compiled with ``jax.lax.scan``.

    Args:
        key: a JAX PRNG key (split into one key per sweep).
        initial_state: the sampler's state.
        algorithm: the sampler.
        num_sweeps: number of sweeps (an int >= 1; not checked here, see :func:`run_chain`).
        progress: called with ``Progress(stage, done, num_sweeps, "sweep")`` before the first sweep and after each
            (the chain then runs one sweep per compiled call, with the same keys: the same samples, bit for bit);
            None: one compiled loop, no reports.
        stage: the stage the reports name.

    Returns:
        :class:`ChainResult`: ``samples`` ``(num_sweeps, nx, ny)`` bool, the final state, and ``wall_probs``
        ``(num_sweeps, nx, ny)`` float32 or None.
    """
    arrays, static = _split(algorithm)
    return _map_chain(arrays, static, key, initial_state, num_sweeps, None, progress, stage)


def run_sweeps(sweep_keys, initial_state, algorithm: SamplingAlgorithm, progress: ProgressCallback | None = None,
               stage: str = "sweeps", done: int = 0, total: int | None = None) -> ChainResult:
    """One sweep of ``algorithm`` per key of ``sweep_keys`` ``(n,)``, ``n >= 1``, from a sampler state, one compiled
    sweep per call (one compilation whatever ``n``, shared by every algorithm of the same static part and array
    shapes): a piece of a chain whose pieces may use different algorithms of one compilation
    (:func:`bayesmap.inference.focus.focused_chain`). The keys ``jax.random.split(key, N)[a:b]`` continue, from the
    state after the keys ``[:a]``, the chain :func:`run_chain_from` runs with ``key``, bit for bit.

    Args:
        sweep_keys: ``(n,)`` JAX PRNG keys, one per sweep.
        initial_state: the sampler's state.
        algorithm: the sampler.
        progress: called with ``Progress(stage, done + t, total, "sweep")`` before the first sweep (``t = 0``) and
            after each; None: no reports.
        stage: the stage the reports name.
        done: the chain's sweeps before this piece (for the reports).
        total: the chain's sweeps in all (for the reports); default ``done + n``.

    Returns:
        :class:`ChainResult` of numpy records: ``samples`` ``(n, nx, ny)`` bool, the final state, ``wall_probs``
        ``(n, nx, ny)`` float32 or None.
    """
    arrays, static = _split(algorithm)
    final, (samples, wall_probs) = _run_keys(jnp.asarray(sweep_keys), initial_state, arrays, static, _map_record,
                                             None, progress, stage, done, total)
    return ChainResult(samples, final, wall_probs)


def compile_chain(key, initial_state, algorithm: SamplingAlgorithm, num_sweeps: int, num_chains: int | None = None):
    """Compile a chain of ``num_sweeps`` sweeps (``num_chains`` at once with ``vmap`` if given; ``key`` is then
    ``(num_chains,)`` keys and the state batched) ahead of time; returns ``run(key, initial_state) ->
    (samples, final_state, wall_probs)``. ``key`` and ``initial_state`` may be ``jax.ShapeDtypeStruct``s. For
    timing compilation apart from running, or to compile on another thread: JAX keeps the executable, so that the
    first :func:`run_chain_from` (:func:`run_chains_from`) with such arguments does not compile again."""
    arrays, static = _split(algorithm)
    batch = None if num_chains is None else "states"
    compiled = _run_jit.lower(key, initial_state, arrays, static, int(num_sweeps), _map_record, batch).compile()

    def run(k, s):
        final, (samples, wall_probs) = compiled(k, s, arrays)
        return samples, final, wall_probs

    return run


def run_chain(key, algorithm: SamplingAlgorithm, initial_walls, num_sweeps: int,
              progress: ProgressCallback | None = None, stage: str = "sweeps") -> ChainResult:
    """Run ``num_sweeps`` sweeps of ``algorithm`` from ``initial_walls`` with ``jax.lax.scan``.

    Args:
        key: a JAX PRNG key.
        algorithm: the sampler.
        initial_walls: ``(nx, ny)`` starting map (the tutorial starts from all free).
        num_sweeps: number of sweeps (>= 1).
        progress: as :func:`run_chain_from`.
        stage: as :func:`run_chain_from`.

    Returns:
        :class:`ChainResult` with ``samples[t]`` the map after sweep ``t + 1``. (The tutorial's chain records the
        map *before* each sweep, so its first sample is the initial map; here every sample is a draw of the
        chain.)

    Raises:
        BayesmapError: if ``num_sweeps`` < 1.
    """
    if int(num_sweeps) != num_sweeps or num_sweeps < 1:
        raise BayesmapError(f"number of sweeps must be an integer >= 1, got {num_sweeps!r}")
    state = algorithm.init(jnp.asarray(initial_walls, dtype=jnp.float32))
    return run_chain_from(key, state, algorithm, int(num_sweeps), progress, stage)


@partial(jax.jit, static_argnames=("static", "devices"))
def _sweeps_on_devices(sweep_keys, states, arrays, static, devices: tuple):
    """One sweep of each chain, the chains split over ``devices`` (``shard_map``; ``sweep_keys`` ``(C,)`` and the
    states' leading ``(C,)`` axis split, the algorithm's arrays replicated): each device runs its chains one after
    another (``lax.map``, not ``vmap``, which would turn a kernel's conditional writes into always-run selects)."""
    def local(keys, states, arrays):
        algorithm = _join(arrays, static)
        return jax.lax.map(lambda ks: scan_sweeps(ks[0][None], ks[1], algorithm, _map_record), (keys, states))

    mesh = Mesh(np.asarray(devices), ("chains",))
    split = PartitionSpec("chains")
    return shard_map(local, mesh, in_specs=(split, split, PartitionSpec()), out_specs=split,
                     check_rep=False)(sweep_keys, states, arrays)


def run_chains_on_devices(keys, initial_state, algorithm: SamplingAlgorithm, num_sweeps: int,
                          progress: ProgressCallback | None = None, stage: str = "sweeps",
                          devices=None) -> ChainResult:
    """``C`` chains of ``algorithm`` from one state, split over the devices (``jax.sharding`` / ``shard_map``: one
    CPU core, several CPU devices, a GPU or several GPUs run the same code): chain ``c`` runs on device ``c % D``'s
    share, the chains of one device one after another, so a kernel written for one chain (the cellwise sampler)
    runs as it does alone. Chain ``c`` gets the sweep keys :func:`run_chain` splits from ``keys[c]``, so its records
    equal those of ``run_chain(keys[c], ...)`` (tested on four CPU devices). One compiled sweep per call, reporting
    ``Progress(stage, done, num_sweeps, "sweep")`` before the first and after each.

    Args:
        keys: ``(C,)`` PRNG keys, one per chain.
        initial_state: the chains' shared first state (``algorithm.init(walls)``).
        algorithm: the sampler.
        num_sweeps: sweeps per chain, >= 1.
        progress: the callback (None: no reports).
        stage: the stage the reports name.
        devices: the devices to split the chains over; default :func:`bayesmap.devices.sweep_devices` (the CPU
            devices), at most ``C``.

    Returns:
        :class:`ChainResult` with ``samples`` ``(C, num_sweeps, nx, ny)`` bool and ``wall_probs`` alike (numpy), and
        the chains' final states (a leading ``(C,)`` axis).
    """
    num_chains, num_sweeps = len(keys), int(num_sweeps)
    devices = tuple(sweep_devices() if devices is None else devices)[:max(num_chains, 1)]
    padded = -(-num_chains // len(devices)) * len(devices)  # a whole number of chains per device
    keys = jnp.concatenate([keys, jnp.broadcast_to(keys[:1], (padded - num_chains,))]) if padded > num_chains \
        else keys
    sweep_keys = jax.vmap(lambda k: jax.random.split(k, num_sweeps))(keys)  # (C, num_sweeps), as run_chain's
    states = jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, (padded,) + jnp.shape(leaf)), initial_state)
    arrays, static = _split(algorithm)
    arrays = [jnp.asarray(a) for a in arrays]
    samples = probs = None
    report(progress, stage, 0, num_sweeps)
    for t in range(num_sweeps):
        states, (walls, wall_prob) = _sweeps_on_devices(sweep_keys[:, t], states, arrays, static, devices)
        if samples is None:
            samples = np.empty((num_chains, num_sweeps) + walls.shape[2:], bool)
            probs = None if wall_prob is None else np.empty((num_chains, num_sweeps) + wall_prob.shape[2:],
                                                            wall_prob.dtype)
        samples[:, t] = np.asarray(walls)[:num_chains, 0]
        if probs is not None:
            probs[:, t] = np.asarray(wall_prob)[:num_chains, 0]
        report(progress, stage, t + 1, num_sweeps)
    final = jax.tree.map(lambda leaf: leaf[:num_chains], states)
    return ChainResult(samples, final, probs)


def run_chains_from(keys, initial_states, algorithm: SamplingAlgorithm, num_sweeps: int) -> ChainResult:
    """``C`` chains at once (``vmap``) from their states: ``keys`` ``(C,)``, states batched on a leading ``(C,)``
    axis; as :func:`run_chain_from` with a leading ``(C,)`` axis on every output."""
    arrays, static = _split(algorithm)
    return _map_chain(arrays, static, keys, initial_states, num_sweeps, "states")


def run_chains(key, algorithm: SamplingAlgorithm, initial_walls, num_sweeps: int, num_chains: int) -> ChainResult:
    """Run ``num_chains`` independent chains at once (``vmap`` over chains, independent keys).

    Args:
        initial_walls: ``(nx, ny)`` shared starting map, or ``(num_chains, nx, ny)`` one per chain.

    Returns:
        :class:`ChainResult` with ``samples`` ``(num_chains, num_sweeps, nx, ny)`` bool (and ``wall_probs`` alike).
    """
    if int(num_chains) != num_chains or num_chains < 1:
        raise BayesmapError(f"number of chains must be an integer >= 1, got {num_chains!r}")
    if int(num_sweeps) != num_sweeps or num_sweeps < 1:
        raise BayesmapError(f"number of sweeps must be an integer >= 1, got {num_sweeps!r}")
    walls = jnp.asarray(initial_walls, dtype=jnp.float32)
    if walls.ndim == 2:
        walls = jnp.broadcast_to(walls, (num_chains,) + walls.shape)
    states = jax.vmap(algorithm.init)(walls)
    return run_chains_from(jax.random.split(key, num_chains), states, algorithm, int(num_sweeps))


def posterior_mean(samples, burn_in: int = 0) -> np.ndarray:
    """Posterior wall probability per cell: the mean of ``samples[..., burn_in:, :, :]`` over sweeps (and chains).

    Args:
        samples: ``(num_sweeps, nx, ny)`` or ``(num_chains, num_sweeps, nx, ny)``.
        burn_in: number of leading sweeps to drop.

    Returns:
        ``(nx, ny)`` float64 in [0, 1].

    Raises:
        BayesmapError: if no sweep is left after the burn-in.
    """
    arr = np.asarray(samples)
    num_sweeps = arr.shape[-3]
    if not (0 <= burn_in < num_sweeps):
        raise BayesmapError(f"burn-in must be between 0 and {num_sweeps - 1} (number of sweeps - 1), got {burn_in!r}")
    kept = arr[..., burn_in:, :, :].astype(np.float64)
    return kept.reshape((-1,) + arr.shape[-2:]).mean(axis=0)


def cell_diagnostics(samples, burn_in: int = 0) -> dict[str, np.ndarray]:
    """Per-cell split R-hat and bulk effective sample size of the wall indicators, with ArviZ.

    Args:
        samples: ``(num_chains, num_sweeps, nx, ny)``, at least 2 chains and 4 kept sweeps.
        burn_in: leading sweeps to drop.

    Returns:
        ``{"r_hat": (nx, ny), "ess": (nx, ny)}`` float64; cells that never change in any chain have R-hat NaN
        and ESS NaN (ArviZ's convention for constant draws).

    Source: rank-normalized split R-hat and bulk ESS of Vehtari, Gelman, Simpson, Carpenter, Bürkner,
    "Rank-normalization, folding, and localization: an improved R-hat", Bayesian Analysis 16(2), 2021, as
    implemented in ArviZ.
    """
    import arviz  # imported here: it takes a second and most commands do not need it

    arr = np.asarray(samples, dtype=np.float64)[:, burn_in:]
    if arr.ndim != 4 or arr.shape[0] < 2 or arr.shape[1] < 4:
        raise BayesmapError(f"diagnostics need samples (chains >= 2, sweeps >= 4, nx, ny), got shape {arr.shape}")
    data = arviz.convert_to_dataset({"walls": arr})
    with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # constant cells: 0 / 0, reported as NaN
        r_hat = arviz.rhat(data)["walls"].values
        ess = arviz.ess(data)["walls"].values
    return {"r_hat": np.asarray(r_hat), "ess": np.asarray(ess)}
