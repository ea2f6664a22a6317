"""bayesmap.devices: the Gibbs sweeps go to the CPU devices whatever JAX's default device is."""

import subprocess
import sys
from pathlib import Path

from helpers import four_cpu_devices_env

# a fresh process with four CPU devices, the default device set to the last one (as a GPU would be the default):
# within on_sweep_devices, arrays from host data and a jitted computation on them land on the first CPU device;
# outside, on the default; the chains of run_chains_on_devices are split over all four
SCRIPT = """
import jax, jax.numpy as jnp, numpy as np
from bayesmap.devices import on_sweep_devices, sweep_devices
cpus = jax.devices("cpu")
assert len(cpus) == 4 and sweep_devices() == tuple(cpus)
jax.config.update("jax_default_device", cpus[3])
assert jnp.zeros(3).devices() == {cpus[3]}
with on_sweep_devices():
    x = jnp.asarray(np.arange(4.0))
    y = jax.jit(lambda a: a * 2)(x)
    k = jax.random.key(0)
assert x.devices() == {cpus[0]} and y.devices() == {cpus[0]} and k.devices() == {cpus[0]}, (x.devices(), y.devices())
assert jnp.ones(2).devices() == {cpus[3]}
print("ok")
"""


def test_sweeps_go_to_the_cpu_devices_whatever_the_default_device():
    """With four CPU devices and the default device set to the fourth (standing in for a GPU), arrays made and
    computed within on_sweep_devices land on the first CPU device, and outside it on the default again; the sweep
    devices are all four CPU devices in JAX's order. Fails if on_sweep_devices leaves the default device in place."""
    root = Path(__file__).resolve().parents[1]
    env = dict(four_cpu_devices_env(), PYTHONPATH=str(root / "src"))
    done = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300,
                          cwd=root)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "ok"
