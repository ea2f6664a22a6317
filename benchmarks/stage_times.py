"""`slam --log`'s time by stage on seeded logs, for this checkout's package or another commit's.

    PYTHONPATH=src .venv/bin/python benchmarks/stage_times.py --logs csail --seeds 0 --every 1,2
    git worktree add /tmp/base 685e56c
    PYTHONPATH=src .venv/bin/python benchmarks/stage_times.py --src /tmp/base/src --logs csail --seeds 0

Each run makes the log with ``noisy_odometry.py --seed N`` (:mod:`seeded_logs`, as ``karto_peer.py``), runs
``bayesmap.runs.slam.log_slam`` on every ``--every``-th scan without the final map (as ``karto_peer.py`` runs it), and
prints one JSON line: the package's source directory, log, seed, every, wall seconds, ATE (m), the peak resident
memory (MB), and the seconds and peak resident memory of each stage (``bayesmap.progress.StageRecorder``). ``--src``
imports the package from another source tree (a ``git worktree`` of an older commit: the same scans and odometry,
its own pipeline); ``--option branches=N`` sets ``run_log_slam``'s ``branches`` (a package that has them). Run one
at a time on an otherwise idle machine: the stages share the cores.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def _ints(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", default=None, help="the package's source directory (default: the installed one)")
    parser.add_argument("--logs", default="csail", help="comma-separated: intel, aces, csail, fr079")
    parser.add_argument("--seeds", default="0", help="odometry seeds, e.g. 0-4 or 0,10")
    parser.add_argument("--every", default="1", help="comma-separated scan strides, e.g. 1,2")
    parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                        help="a keyword of run_log_slam, an int or a float (repeatable), e.g. branches=0")
    args = parser.parse_args(argv)
    if args.src is not None:
        sys.path.insert(0, str(Path(args.src).resolve()))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import numpy as np
    from seeded_logs import write_seeded_log

    import bayesmap
    import bayesmap.slam.pipeline as pipeline
    from bayesmap.evaluation.trajectory import absolute_trajectory_error
    from bayesmap.progress import StageRecorder
    from bayesmap.runs.slam import log_slam

    options = {}
    for text in args.option:
        name, _, value = text.partition("=")
        options[name] = float(value) if "." in value else int(value)
    if options:
        run_log_slam = pipeline.run_log_slam

        def with_options(*a, **k):
            return run_log_slam(*a, **{**k, **options})

        pipeline.run_log_slam = with_options
    for name in args.logs.split(","):
        for seed in _ints(args.seeds):
            for every in _ints(args.every):
                with tempfile.TemporaryDirectory() as tmp:
                    log, truth = write_seeded_log(name, seed, Path(tmp) / f"{name}-odom")
                    recorder = StageRecorder()
                    start = time.perf_counter()
                    run = log_slam(log, Path(tmp) / "x.log", scans=None if every == 1 else f"::{every}", seed=seed,
                                   final_map=False, progress=recorder)
                    wall = time.perf_counter() - start
                summary = recorder.summary()
                result, chosen = (run[1], run[2]) if isinstance(run, tuple) else (run.result, run.chosen)
                ate = absolute_trajectory_error(result.mean_path, np.asarray(truth)[chosen])["rmse_m"]
                print(json.dumps({"src": str(Path(bayesmap.__file__).parent.parent), "log": name, "seed": seed,
                                  "every": every, "options": options, "wall_s": round(wall, 1),
                                  "ate_m": round(float(ate), 3),
                                  "peak_mb": round(summary["peak_rss_mb"]),
                                  "stages": {s["stage"]: round(s["seconds"], 1) for s in summary["stages"]},
                                  "stage_peak_mb": {s["stage"]: round(s["peak_rss_mb"])
                                                    for s in summary["stages"]}}), flush=True)


if __name__ == "__main__":
    main()
