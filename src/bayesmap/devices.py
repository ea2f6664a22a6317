"""Where the Gibbs sweeps run: on the host's CPU devices, whatever JAX's default device is.

A Gibbs sweep over a map (:mod:`bayesmap.inference.cellwise`) or a path (:mod:`bayesmap.slam.poses`) is a long loop of
small steps, each depending on the last: a step scores a few cells or one pose, and on a GPU each step is a kernel
launch that waits for the one before. The scan matching of SLAM (front end, loop closure, placing the scans between
keyframes) is the opposite, thousands of candidate poses scored at once. Measured on one machine with an NVIDIA H100
and 16 CPU cores, the first 1,000 scans of Freiburg 079 (``bayesmap slam --log``): everything on the GPU took 180 s,
everything on the CPU 66 s; on the GPU the front end and the loop closure took 2.9 s and 3.2 s against 11.0 s and
3.7 s on the CPU, the final map's sweeps 67 s against 16 s. So the sweeps run on the CPU devices and everything else
on the default device (a GPU where JAX has one): :func:`on_sweep_devices` around the sweeps. On a machine without an
accelerator both are the CPU and nothing changes. The figures and the command: docs/validation/scale.md, "On a GPU".
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import jax


def sweep_devices() -> tuple:
    """The devices Gibbs sweeps run on: JAX's CPU devices, ``jax.devices("cpu")`` (one, or ``N`` under
    ``XLA_FLAGS=--xla_force_host_platform_device_count=N``), in JAX's order. Chains of the cellwise sampler are split
    over them (:func:`bayesmap.inference.chains.run_chains_on_devices`)."""
    return tuple(jax.devices("cpu"))


@contextmanager
def on_sweep_devices() -> Iterator[None]:
    """Within the block, arrays made from host data and the computations on them go to the first of
    :func:`sweep_devices` (``jax.default_device``), instead of JAX's default device. Arrays already placed on
    another device keep their place: pass host (numpy) data into the block, or its own arrays."""
    with jax.default_device(sweep_devices()[0]):
        yield
