"""Seconds per cellwise sweep of a whole log, by map model (issue 16's cost target: the structured prior at most 1.5x
the independent prior's sweep).

For each setting, the log's problem is built at ``--resolution``, the cellwise sampler is started from the log-odds
map and a chain of ``--sweeps`` sweeps is compiled (``bayesmap.inference.chains.compile_chain``); the figure is the
best of ``--repeats`` timed runs of the compiled chain, divided by its sweeps (compilation and table building
excluded, as ``bayesmap bench`` times its samplers). Settings:

* ``entry``: the tutorial's entry geometry, a 0.1 m range offset, power 0.1, the independent prior (the log
  defaults before issue 16);
* ``chord``: the chord geometry, no offset, the default power, the independent prior;
* ``opaque``: the log defaults with wall cells that stop every beam (``wall_pass_prob`` 0: each ray's first two
  walls in the rows, as before passable walls);
* ``default``: the log defaults of ``bayesmap.scenes`` (chord geometry, the structured prior and passable walls).

Usage: PYTHONPATH=src python benchmarks/sweep_cost.py [--log intel] [--resolution 0.1] [--sweeps 20] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from seeded_logs import CORRECTED_LOGS

from bayesmap import scenes
from bayesmap.inference.chains import compile_chain
from bayesmap.inference.driver import run_logodds
from bayesmap.inference.registry import make_sampler
from bayesmap.io.carmen import read_carmen

SETTINGS = {
    "entry": dict(geometry="entry", range_offset=0.1, likelihood_power=0.1, coupling=0.0, wall_pass_prob=0.0),
    "chord": dict(coupling=0.0, wall_pass_prob=0.0),
    "opaque": dict(wall_pass_prob=0.0),
    "default": {},
}


def seconds_per_sweep(problem, sweeps: int, repeats: int) -> float:
    """Best of ``repeats`` runs of a compiled ``sweeps``-sweep cellwise chain, per sweep."""
    algorithm = make_sampler(problem, "cellwise")
    state = algorithm.init(np.asarray(run_logodds(problem).posterior) > 0.5)
    key = jax.random.key(0)
    run = compile_chain(key, state, algorithm, sweeps)
    jax.block_until_ready(run(key, state))
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(run(key, state))
        best = min(best, time.perf_counter() - start)
    return best / sweeps


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", default="intel")
    parser.add_argument("--resolution", type=float, default=scenes.RESOLUTION)
    parser.add_argument("--sweeps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    log = read_carmen(CORRECTED_LOGS[args.log])
    print("| setting | coupling J | seconds per sweep | ratio to entry |\n|---|---|---|---|")
    base = None
    for name, kwargs in SETTINGS.items():
        problem = scenes.log_problem(log, resolution=args.resolution, **kwargs)
        cost = seconds_per_sweep(problem, args.sweeps, args.repeats)
        base = cost if base is None else base
        print(f"| {name} | {problem.params.coupling:.3f} | {cost:.3f} | {cost / base:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
