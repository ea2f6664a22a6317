"""bayesmap: Bayesian occupancy-grid mapping from range scans, with honest uncertainty.

The public API, in data-flow order (a notebook needs only ``import bayesmap as bm``)::

    walls = bm.tutorial_map()                        # or bm.load_map("room.txt"), bm.read_rosmap("map.yaml")
    problem = bm.tutorial_problem(walls)             # or bm.log_problem(bm.read_carmen("intel.log.gz"))
    result = bm.run_inference(problem, "block")      # posterior marginals, samples, summary
    fig = bm.plot_posterior(problem.grid, result.posterior, ...)
    bm.save_figure(fig, "posterior.png")

Names are loaded on first use (PEP 562): ``import bayesmap`` itself imports neither JAX, GenJAX nor matplotlib.
Each name is documented in its module; ``__all__`` lists them and ``API`` says which module each comes from.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

API: dict[str, str] = {
    # errors
    "BayesmapError": "bayesmap.errors",
    # io: readers and writers
    "tutorial_map": "bayesmap.io.ascii",
    "load_map": "bayesmap.io.ascii",
    "save_map": "bayesmap.io.ascii",
    "parse_map": "bayesmap.io.ascii",
    "format_map": "bayesmap.io.ascii",
    "read_carmen": "bayesmap.io.carmen",
    "read_rosmap": "bayesmap.io.rosmap",
    "write_rosmap": "bayesmap.io.rosmap",
    "read_bag": "bayesmap.io.rosbag",
    "write_log_bag": "bayesmap.io.rosbag",
    "read_tum": "bayesmap.io.tum",
    "write_tum": "bayesmap.io.tum",
    # geometry
    "Grid": "bayesmap.geometry.grid",
    "sensor_distances": "bayesmap.geometry.raycast",
    "build_ray_table": "bayesmap.geometry.raytable",
    "RayTable": "bayesmap.geometry.raytable",
    # model
    "ModelParams": "bayesmap.model.generative",
    "make_params": "bayesmap.model.generative",
    "full_model": "bayesmap.model.generative",
    "multi_scan_model": "bayesmap.model.generative",
    "log_joint": "bayesmap.model.generative",
    "simulate": "bayesmap.model.generative",
    "simulate_readings": "bayesmap.model.generative",
    "slam_model": "bayesmap.model.slam",
    "log_joint_slam": "bayesmap.model.slam",
    "simulate_slam": "bayesmap.model.slam",
    "MotionParams": "bayesmap.model.motion",
    "make_motion_params": "bayesmap.model.motion",
    "walls_prior": "bayesmap.model.generative",
    "sample_prior": "bayesmap.model.prior",
    "coupling_for_run_length": "bayesmap.model.prior",
    # scenes
    "Problem": "bayesmap.problem",
    "Observations": "bayesmap.problem",
    "tutorial_problem": "bayesmap.scenes",
    "scan_problem": "bayesmap.scenes",
    "log_problem": "bayesmap.scenes",
    # inference
    "SAMPLERS": "bayesmap.inference.registry",
    "make_sampler": "bayesmap.inference.registry",
    "run_inference": "bayesmap.inference.driver",
    "run_logodds": "bayesmap.inference.driver",
    "InferenceResult": "bayesmap.inference.driver",
    "run_chain": "bayesmap.inference.chains",
    "run_chains": "bayesmap.inference.chains",
    "run_chain_from": "bayesmap.inference.chains",
    "posterior_mean": "bayesmap.inference.chains",
    "cell_diagnostics": "bayesmap.inference.chains",
    "importance_sampling": "bayesmap.inference.importance",
    "resample": "bayesmap.inference.importance",
    "chain_log_joints": "bayesmap.inference.traces",
    "chain_wrong_cells": "bayesmap.inference.traces",
    # evaluation
    "evaluate_log": "bayesmap.evaluation.heldout",
    "evaluate_truth": "bayesmap.evaluation.heldout",
    "score_trajectory": "bayesmap.evaluation.trajectory",
    # visualisation
    "plot_map": "bayesmap.viz.maps",
    "plot_posterior": "bayesmap.viz.maps",
    "plot_prior_samples": "bayesmap.viz.maps",
    "plot_convergence": "bayesmap.viz.diagnostics",
    "plot_importance": "bayesmap.viz.diagnostics",
    "save_figure": "bayesmap.viz.common",
    "figure_bytes": "bayesmap.viz.common",
    "chain_gif": "bayesmap.viz.animation",
    "build_report": "bayesmap.viz.report",
}

__all__ = sorted(API)


def __getattr__(name: str):
    """Import the module of a public name on first use and return the name (``AttributeError`` for others)."""
    module = API.get(name)
    if module is None:
        raise AttributeError(f"module 'bayesmap' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(API))
