"""The ``bayesmap`` command (and ``python -m bayesmap``): caps glibc's heaps and turns JAX's persistent compilation
cache off, then runs :func:`bayesmap.cli.main`.

* The cap (:func:`bayesmap.memory.limit_malloc_arenas`) must come before numpy, JAX and XLA start their threads:
  glibc fixes its number of heaps once enough threads have allocated, so this module imports nothing else first.
* JAX's persistent compilation cache (``JAX_COMPILATION_CACHE_DIR``) hands bayesmap's samplers wrong compiled code
  under the pinned JAX 0.5.3: two jitted steps of samplers that differ only in the arrays they close over (two tables
  of the same shapes) get the same cache entry, so the second runs with the first's arrays (the sweeps' draws and the
  SLAM path then differ from the same run without the cache: in the test suite a path 1.36 m off instead of
  0.04 m). The command sets ``JAX_ENABLE_COMPILATION_CACHE=false`` before JAX reads its settings; a program using
  the library must leave the cache off itself. Found and measured: docs/validation/tried.md, "Speed".
"""

from __future__ import annotations

import os

from bayesmap.memory import limit_malloc_arenas


def main() -> None:
    """Cap glibc's heaps, turn JAX's persistent compilation cache off, then run :func:`bayesmap.cli.main` (which ends
    the process with its exit code)."""
    limit_malloc_arenas()
    os.environ["JAX_ENABLE_COMPILATION_CACHE"] = "false"
    from bayesmap.cli import main as cli_main  # numpy, JAX and the rest only now

    cli_main()


if __name__ == "__main__":
    main()
