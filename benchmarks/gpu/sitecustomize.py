"""Runs bayesmap's pinned genjax 0.10.3 (and TensorFlow Probability's JAX substrate) on a newer JAX, for measuring
on a lent GPU machine whose image holds JAX 0.11 with CUDA 13 (JAX 0.5.3's CUDA 12 build and its CUDA libraries are
about 2 GB, more than such a machine can be sent). Not part of bayesmap: ``benchmarks/gpu/setup.sh`` puts this folder
first on ``PYTHONPATH`` there, so Python imports it at start-up. It restores four names newer JAX releases removed,
each only where it is missing: ``jax.util``, ``jax.interpreters.xla.pytype_aval_mappings`` and
``canonicalize_dtype_handlers``, ``jax.core.get_aval`` and ``raise_to_shaped``. With it, ``bayesmap slam --log``
on 200 Intel scans under JAX 0.11.2 on a CPU gave a path within 0.04 m of JAX 0.5.3's (docs/validation/scale.md,
"On a GPU")."""
# ruff: noqa: PLC2701  (the removed names live in jax._src now: restoring them is the point)

import sys

import jax
import jax._src.core as _core
import jax._src.util as _util
import jax.interpreters.xla as _xla

if not hasattr(jax, "util"):
    jax.util = _util
    sys.modules.setdefault("jax.util", _util)
if not hasattr(_xla, "pytype_aval_mappings"):
    _xla.pytype_aval_mappings = _core.pytype_aval_mappings
if not hasattr(_xla, "canonicalize_dtype_handlers"):
    from jax._src import dtypes as _dtypes

    _xla.canonicalize_dtype_handlers = getattr(_dtypes, "canonicalize_dtype_handlers", {})
if not hasattr(_core, "get_aval"):
    _core.get_aval = _core.typeof if hasattr(_core, "typeof") else _core.shaped_abstractify
if not hasattr(_core, "raise_to_shaped"):
    _core.raise_to_shaped = lambda aval, weak_type=None: aval
