"""The samplers by name: what ``--sampler`` takes, and the limits that decide which fits a problem."""

from __future__ import annotations

from bayesmap.errors import BayesmapError
from bayesmap.inference.cellwise import cellwise_gibbs
from bayesmap.inference.chains import SamplingAlgorithm
from bayesmap.inference.fast import fast_gibbs
from bayesmap.inference.reference import reference_gibbs, reference_incremental_gibbs
from bayesmap.problem import Problem

MAX_FAST_PAIRS = 8_000_000
"""Most (beam, cell) pairs the level-based fast samplers (:data:`LEVEL_SAMPLERS`) take: they need about 1.9 KB per
pair (measured on CSAIL), so a whole log at 0.1 m (Intel: 42 million pairs) would exhaust memory. The ``cellwise``
sampler needs about 22 bytes per pair and has no limit ([validation](../validation/defaults.md#max_fast_pairs))."""

LEVEL_SAMPLERS = ("block", "raster", "outward", "chromatic", "chromatic-block")
"""The samplers of :mod:`bayesmap.inference.fast` (levels of blocks updated at once)."""

SEQUENTIAL_CHAINS = ("cellwise",)
"""Samplers whose chains run one after another rather than at once under ``vmap`` (which would turn their
conditional writes into selects that always run)."""

def _fast(order: str, block_size: int, schedule: str):
    """Factory of a :func:`~bayesmap.inference.fast.fast_gibbs` sampler for a problem (its table, readings,
    parameters, first sensor position and likelihood power)."""
    return lambda problem: fast_gibbs(problem.table, problem.model_ray_readings, problem.params, order, block_size,
                                      schedule, problem.ray_origins[0], problem.likelihood_power)


# name -> (description, factory(problem) -> SamplingAlgorithm)
SAMPLERS: dict[str, tuple[str, object]] = {
    "block": ("2x2 block Gibbs, fast (ray-cell table), raster order", _fast("raster", 2, "sequential")),
    "raster": ("single-site Gibbs, fast, raster order", _fast("raster", 1, "sequential")),
    "outward": ("single-site Gibbs, fast, sensor-outward order", _fast("outward", 1, "sequential")),
    "chromatic": ("single-site Gibbs, fast, chromatic (colour classes updated in parallel)",
                  _fast("raster", 1, "chromatic")),
    "chromatic-block": ("2x2 block Gibbs, fast, chromatic", _fast("raster", 2, "chromatic")),
    "cellwise": ("single-site Gibbs, one cell at a time, each ray's first two walls in the state (whole logs)",
                 lambda problem: cellwise_gibbs(problem.table, problem.model_ray_readings, problem.params,
                                                problem.likelihood_power)),
    "reference-raster": ("the tutorial's single-site Gibbs with assess, raster order",
                         lambda problem: reference_gibbs(*problem.single_scan(), "raster", 1)),
    "reference-incremental": ("the tutorial's single-site Gibbs with incremental trace edit",
                              lambda problem: reference_incremental_gibbs(*problem.single_scan())),
    "reference-outward": ("the tutorial's single-site Gibbs with assess, sensor-outward order",
                          lambda problem: reference_gibbs(*problem.single_scan(), "outward", 1)),
    "reference-block": ("the tutorial's 2x2 block Gibbs with assess",
                        lambda problem: reference_gibbs(*problem.single_scan(), "raster", 2)),
}


def make_sampler(problem: Problem, name: str) -> SamplingAlgorithm:
    """The sampler ``name`` (a key of :data:`SAMPLERS`) for ``problem``.

    Raises:
        BayesmapError: on an unknown name, a fast sampler on more than :data:`MAX_FAST_PAIRS` pairs, or a reference
            sampler on a tempered problem (``likelihood_power`` < 1).
    """
    if name not in SAMPLERS:
        raise BayesmapError(f"unknown sampler {name!r}; choose one of {', '.join(SAMPLERS)}")
    if name.startswith("reference-") and problem.likelihood_power != 1.0:
        raise BayesmapError(f"the sampler {name!r} samples the posterior itself (likelihood power 1), not a tempered "
                            f"one (likelihood power {problem.likelihood_power!r}); use a fast sampler or cellwise")
    if name in LEVEL_SAMPLERS and problem.table.num_pairs > MAX_FAST_PAIRS:
        pairs = problem.table.num_pairs
        raise BayesmapError(
            f"{problem.source or 'this problem'} has {pairs:,} (beam, cell) pairs; the sampler {name!r} takes at most "
            f"{MAX_FAST_PAIRS:,} (about 1.9 KB each, {pairs * 1.9e-6:.0f} GB here): use --sampler cellwise (about "
            "22 bytes per pair), map fewer scans (--scans ::k) or use coarser cells (--resolution)")
    return SAMPLERS[name][1](problem)
