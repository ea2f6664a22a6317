"""The kernel contract shared by every sampler, in the style of BlackJAX.

A sampler is a :class:`SamplingAlgorithm`: a pure ``init(walls) -> state`` and a pure ``step(key, state) -> (state,
info)`` kernel that performs one sweep. A state is a small NamedTuple whose ``walls`` field is the current map;
``info`` is a :class:`GibbsInfo` holding what the sweep records for estimates besides the map (the conditional wall
probabilities of a Rao-Blackwellized sampler, or None). Keys are passed explicitly; there is no global state.
:mod:`bayesmap.inference.chains` runs chains of any such sampler with ``jax.lax.scan``.

The fast samplers (:mod:`bayesmap.inference.fast`, :mod:`bayesmap.inference.cellwise`) keep their sweep's arrays and
code in a pytree kernel (a :class:`KernelFields`), built by a :class:`KernelSampler` that forwards ``init``,
``step`` and exposes the pair as its :attr:`KernelSampler.algorithm`.

Source: the BlackJAX interface (Cabezas, Corenflos, Lao, Louf et al., "BlackJAX: Composable Bayesian inference in
JAX", 2024): ``init`` and ``step(rng_key, state) -> (state, info)``.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax


class SamplingAlgorithm(NamedTuple):
    """A Gibbs sampler: ``init(walls (nx, ny)) -> state`` and ``step(key, state) -> (state, GibbsInfo)`` (one
    sweep); both pure and jittable."""

    init: Callable
    step: Callable


class GibbsState(NamedTuple):
    """The state of a Gibbs chain that keeps nothing but the map: ``walls`` ``(nx, ny)`` float32 of 0.0 / 1.0."""

    walls: jax.Array


class GibbsInfo(NamedTuple):
    """What a sweep reports besides the new state.

    Attributes:
        wall_prob: ``(nx, ny)`` float32, the conditional probability ``p(cell is a wall | rest)`` each cell was drawn
            with in this sweep, for samplers that record it (their mean over sweeps is the Rao-Blackwellized estimate
            of the posterior marginals; Gelfand & Smith 1990, sec. 2.3); None for samplers that do not.
    """

    wall_prob: jax.Array | None = None


class KernelFields:
    """Base of a sampler's kernel as a pytree: the attributes named in ``_ARRAYS`` are its leaves (arguments of a
    compiled chain, so that problems differing only in array values share one compilation), those in ``_STATIC``
    its static metadata (sizes, flags, names). Subclasses set both tuples, define ``init(walls) -> state`` and
    ``step(key, state) -> (state, GibbsInfo)``, are built with keyword arguments, and are registered with
    ``jax.tree_util.register_pytree_node_class``.

    Raises:
        KeyError: when built without one of the named fields.
    """

    _ARRAYS: tuple[str, ...] = ()
    _STATIC: tuple[str, ...] = ()

    def __init__(self, **fields):
        for name in self._ARRAYS + self._STATIC:
            setattr(self, name, fields[name])

    def tree_flatten(self):
        return tuple(getattr(self, n) for n in self._ARRAYS), tuple(getattr(self, n) for n in self._STATIC)

    @classmethod
    def tree_unflatten(cls, static, arrays):
        return cls(**dict(zip(cls._ARRAYS, arrays)), **dict(zip(cls._STATIC, static)))


class KernelSampler:
    """Base of a sampler built for one problem around a pytree kernel: a subclass builds its
    :class:`KernelFields` kernel and stores it as ``self.kernel``; this base forwards :meth:`init` and :meth:`step`
    to it and packs both as :attr:`algorithm`."""

    kernel: KernelFields

    @property
    def algorithm(self) -> SamplingAlgorithm:
        """The :class:`SamplingAlgorithm` of the kernel (:func:`kernel_algorithm`)."""
        return kernel_algorithm(self.kernel)

    def init(self, walls):
        """The kernel's state for the map ``walls`` ``(nx, ny)`` (see the subclass's kernel)."""
        return self.kernel.init(walls)

    def step(self, key, state):
        """One sweep of the kernel: ``(state, GibbsInfo)`` (see the subclass's kernel)."""
        return self.kernel.step(key, state)


def kernel_algorithm(kernel: KernelFields) -> SamplingAlgorithm:
    """The :class:`SamplingAlgorithm` of a pytree kernel: ``init`` and ``step`` are ``jax.tree_util.Partial`` of the
    kernel, so a compiled chain takes the kernel's arrays as arguments and is reused by any problem of the same
    static metadata (geometry, schedule, sensor model name)."""
    kind = type(kernel)
    return SamplingAlgorithm(init=jax.tree_util.Partial(kind.init, kernel),
                             step=jax.tree_util.Partial(kind.step, kernel))
