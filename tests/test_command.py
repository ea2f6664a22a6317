"""The ``bayesmap`` command's entry (bayesmap.__main__): glibc's heaps capped before numpy or JAX is imported, and
JAX's persistent compilation cache off (it hands the samplers wrong compiled code under JAX 0.5.3)."""

import os
import subprocess
import sys


def test_the_command_imports_nothing_before_the_cap():
    probe = "import sys, bayesmap.__main__; print(sorted({'numpy', 'jax'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_command_writes_no_compilation_cache(tmp_path):
    """A user's JAX_COMPILATION_CACHE_DIR, with every compilation worth keeping: the run writes nothing there (the
    same run without the command's setting writes about 75 entries)."""
    cache = tmp_path / "cache"
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(cache), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    env.pop("JAX_ENABLE_COMPILATION_CACHE", None)
    run = subprocess.run([sys.executable, "-m", "bayesmap", "infer", "--sweeps", "2", "--burn-in", "0", "--out",
                          tmp_path / "out"], env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "out" / "summary.json").exists()
    assert not cache.exists() or not any(cache.iterdir())
