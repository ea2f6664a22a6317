"""The cap on glibc's heaps (bayesmap.memory.limit_malloc_arenas), counted from glibc's own report."""

import os
import subprocess
import sys
import textwrap

import pytest

from bayesmap.memory import drop_compiled_programs, keep_compiled_programs, limit_malloc_arenas

GLIBC = "CS_GNU_LIBC_VERSION" in os.confstr_names and bool(os.confstr("CS_GNU_LIBC_VERSION"))

# The order of the bayesmap command (bayesmap.__main__): the cap, then numpy and JAX, whose threads compute; then
# eight threads allocate at once; glibc's malloc_info then lists one <heap> per arena.
PROGRAM = textwrap.dedent("""
    import ctypes, ctypes.util, sys, tempfile, threading
    from bayesmap.memory import limit_malloc_arenas
    print(limit_malloc_arenas(int(sys.argv[1])) if sys.argv[1] != "none" else None)
    import numpy as np
    import jax.numpy as jnp
    a = np.ones((512, 512))
    float((a @ a).sum() + jnp.sum(jnp.ones((512, 512)) @ jnp.ones((512, 512))))
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.fopen.restype = ctypes.c_void_p
    libc.malloc.restype = ctypes.c_void_p
    barrier = threading.Barrier(8)
    def work():
        barrier.wait()
        blocks = [libc.malloc(4096) for _ in range(200)]
        barrier.wait()
        for b in blocks:
            libc.free(ctypes.c_void_p(b))
    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads: t.start()
    for t in threads: t.join()
    with tempfile.NamedTemporaryFile("r") as f:
        fp = libc.fopen(f.name.encode(), b"w")
        libc.malloc_info(0, ctypes.c_void_p(fp))
        libc.fclose(ctypes.c_void_p(fp))
        print(f.read().count("<heap nr="))
""")


def heaps(arenas: str, env_cap=None) -> tuple[str, int]:
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    if env_cap is not None:
        env["MALLOC_ARENA_MAX"] = env_cap
    out = subprocess.run([sys.executable, "-c", PROGRAM, arenas], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(not GLIBC, reason="glibc's allocator only")
def test_arenas_capped_unless_the_environment_sets_them():
    assert heaps("none")[1] > 2  # glibc's default: a heap per allocating thread, up to eight per core
    assert heaps("2") == ("True", 2)
    assert heaps("1") == ("True", 1)
    assert heaps("2", env_cap="3") == ("False", 3)  # the user's setting rules


def test_arenas_below_one_refused():
    with pytest.raises(ValueError, match="at least 1, got 0"):
        limit_malloc_arenas(0)


def test_compiled_programs_dropped_unless_kept():
    """Inside keep_compiled_programs a jitted function keeps its compiled program through drop_compiled_programs;
    outside it, and after the context, the program is dropped and the next call compiles again. Checked on a thread
    of its own: a thread starts outside every context (this module's tests run inside one: tests/conftest.py), and
    the test's own context still keeps."""
    import threading

    import jax
    import jax.numpy as jnp

    f = jax.jit(lambda x: x * 2 + 1)
    sizes = []

    def check():
        f(jnp.ones(3))
        sizes.append(f._cache_size())
        with keep_compiled_programs():
            with keep_compiled_programs():  # nested: leaving the inner one still keeps
                pass
            drop_compiled_programs()
            sizes.append(f._cache_size())
        drop_compiled_programs()
        sizes.append(f._cache_size())
        sizes.append(float(f(jnp.ones(3))[0]))

    thread = threading.Thread(target=check)
    thread.start()
    thread.join()
    assert sizes == [1, 1, 0, 3.0]
    f(jnp.ones(3))
    drop_compiled_programs()  # this test's context keeps (the module fixture's)
    assert f._cache_size() == 1
