"""Giving freed memory back to the operating system between the stages of a long run.

numpy's and XLA's large temporaries (a ray-cell table being sorted into a sampler's lanes, a piece of a log's table)
are freed when a stage ends, but glibc's allocator keeps freed blocks below its dynamic mmap threshold (up to 32 MB
each) in its heap, so the process's resident memory stays at the stage's high-water mark and the next stage's
temporaries come on top. :func:`release_freed_memory` asks the allocator to return those pages (glibc's
``malloc_trim``), which the peak of the next stage then does not count. What it saves, and why the allocator's
thresholds are left as they are: docs/validation/scale.md, "Known poses in tiles".
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim`` or None (another C library, another system)."""
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):
        return None


def release_freed_memory() -> None:
    """Return the heap's free pages to the operating system (glibc's ``malloc_trim(0)``); nothing where the C
    library has no such call. Takes a few milliseconds; changes no value."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)
