"""Giving freed memory back to the operating system between the stages of a long run.

numpy's and XLA's large temporaries (a ray-cell table being sorted into a sampler's lanes, a piece of a log's table)
are freed when a stage ends, but glibc's allocator keeps freed blocks below its dynamic mmap threshold (up to 32 MB
each) in its heap, so the process's resident memory stays at the stage's high-water mark and the next stage's
temporaries come on top. :func:`release_freed_memory` asks the allocator to return those pages (glibc's
``malloc_trim``), which the peak of the next stage then does not count. What it saves, and why the allocator's
thresholds are left as they are: docs/validation/scale.md, "Known poses in tiles".

glibc also gives each thread that allocates under contention its own heap ("arena"), up to eight per core, and an
arena keeps its freed blocks for its own thread. XLA's thread pool has a thread per core, so on a machine of many
cores the freed memory of many arenas counts in the process's resident memory: :func:`limit_malloc_arenas` caps the
arenas at :data:`MALLOC_ARENAS` (glibc's ``mallopt(M_ARENA_MAX)``, the setting ``MALLOC_ARENA_MAX`` makes), called by
the ``bayesmap`` command (:mod:`bayesmap.__main__`) before it imports numpy or JAX.

Compiled programs hold memory too (a whole log's front end and loop closure about 250 MB on Intel, a tile's sweep
its own): :func:`drop_compiled_programs` drops them between the stages of a long run, unless the caller keeps them
(:func:`keep_compiled_programs`, for a program that runs many small problems in one process).
"""

from __future__ import annotations

import contextlib
import contextvars
import ctypes
import ctypes.util
import functools
import os

MALLOC_ARENAS = 2
"""The most heaps (arenas) glibc's allocator keeps, where the environment does not set ``MALLOC_ARENA_MAX``
(glibc's default: eight per core). On a 16-core machine the first 1,000 scans of Freiburg 079 (``bayesmap slam
--log``) peaked at 1,593 MB with 2 heaps against 1,963-1,992 MB with glibc's default, and the whole log at 2,186 MB
against 4,429 MB. Only 2 was measured against the default (one heap would make every thread wait for one lock); the
runs and their times: [validation](../validation/scale.md#memory-on-a-machine-of-many-cores)."""

_M_ARENA_MAX = -8  # glibc's malloc.h


@functools.cache
def _libc_function(name: str):
    """glibc's function ``name`` or None (another C library, another system)."""
    library = ctypes.util.find_library("c")
    try:
        return getattr(ctypes.CDLL(library), name) if library else None
    except (OSError, AttributeError):
        return None


def release_freed_memory() -> None:
    """Return the heap's free pages to the operating system (glibc's ``malloc_trim(0)``); nothing where the C
    library has no such call. Takes a few milliseconds; changes no value."""
    trim = _libc_function("malloc_trim")
    if trim is not None:
        trim(0)


def limit_malloc_arenas(arenas: int = MALLOC_ARENAS) -> bool:
    """Cap glibc's allocator at ``arenas`` heaps (``mallopt(M_ARENA_MAX, arenas)``) unless the environment sets
    ``MALLOC_ARENA_MAX``, which then rules. Call it before any other thread allocates (before importing numpy,
    whose BLAS starts a thread per core): glibc fixes its limit once more than eight heaps exist, and heaps made
    before stay.

    Returns:
        True where the cap was set; False where the environment sets it or the C library is not glibc.

    Raises:
        ValueError: ``arenas`` below 1.
    """
    if arenas < 1:
        raise ValueError(f"arenas must be at least 1, got {arenas}")
    mallopt = _libc_function("mallopt")
    if mallopt is None or "MALLOC_ARENA_MAX" in os.environ:
        return False
    return bool(mallopt(_M_ARENA_MAX, int(arenas)))


_KEEP_COMPILED = contextvars.ContextVar("bayesmap_keep_compiled", default=False)


def drop_compiled_programs() -> None:
    """Drop every program JAX has compiled in this process, and what the programs hold (``jax.clear_caches``), unless
    called inside :func:`keep_compiled_programs`. Called between the stages of a whole-log run
    (:mod:`bayesmap.slam.pipeline`: after the loop closure and before the final map; :mod:`bayesmap.inference.tiled`:
    after each tile whose sweep no other tile shares), whose next stage compiles programs of its own: on 300 scans of
    Intel the final map's peak was 929 MB with it against 1,286 MB without. JAX's caches hold every compiled function of
    the process, the caller's too: the next call of any of them compiles again. Never raises."""
    if not _KEEP_COMPILED.get():
        import jax  # (not at the top: the command imports this module before numpy and JAX, limit_malloc_arenas)

        jax.clear_caches()


@contextlib.contextmanager
def keep_compiled_programs():
    """A context in which :func:`drop_compiled_programs` keeps JAX's compiled programs: for a program that runs
    many small problems in one process (a notebook, a test suite, a sweep over settings), where compiling again
    costs more than the memory the programs hold. The memory then grows with the programs compiled: leaving the
    context frees nothing by itself (the next :func:`drop_compiled_programs` outside it does, or
    ``jax.clear_caches()``). Contexts nest; each thread and task has its own."""
    token = _KEEP_COMPILED.set(True)
    try:
        yield
    finally:
        _KEEP_COMPILED.reset(token)
