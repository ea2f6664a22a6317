"""The whole `bayesmap slam --log` command's wall time and peak memory on seeded logs, for this checkout's package or
another commit's.

    PYTHONPATH=src:benchmarks .venv/bin/python benchmarks/slam_command_times.py --logs csail --seeds 0-4 --every 2,1
    git worktree add /tmp/base 685e56c
    PYTHONPATH=src:benchmarks .venv/bin/python benchmarks/slam_command_times.py --src /tmp/base/src --seeds 0-4

Each run makes the log with ``noisy_odometry.py --seed N`` (:mod:`seeded_logs`, as ``karto_peer.py`` and
``stage_times.py``), then runs the command in a fresh process under ``/usr/bin/time`` (final map and figures included,
as a user runs it; ``--scans ::N`` for ``--every N``) and prints one JSON line: the package's source directory, log,
seed, every, wall seconds, the path's ATE against the truth (m), the whole run's peak resident memory (MB; the
summary's ``peak_rss_mb``), the peak ``/usr/bin/time`` reads at the process's exit (``time_peak_mb``: lower, since
the stage recorder resets the kernel's high-water mark at each stage, :class:`bayesmap.progress.ProcessPeak`; null
where the machine has no ``/usr/bin/time``, and then the wall seconds are this script's clock around the process),
the summary's ``runtime_s`` and each stage's seconds (``stages``). ``--src`` imports the package from another source
tree (a ``git worktree`` of an older commit), put before any ``PYTHONPATH`` already set (on a lent GPU machine,
``benchmarks/gpu/setup.sh``'s). Run one at a time on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from karto_peer import parse_seeds


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", default=None, help="the package's source directory (default: this checkout's)")
    parser.add_argument("--logs", default="csail", help="comma-separated: intel, aces, csail, fr079")
    parser.add_argument("--seeds", default="0", help="odometry seeds, e.g. 0-4 or 0,10")
    parser.add_argument("--every", default="1", help="comma-separated scan strides, e.g. 2,1")
    args = parser.parse_args(argv)
    here = Path(__file__).resolve().parent
    src = Path(args.src).resolve() if args.src else here.parent / "src"
    sys.path.insert(0, str(here))
    from seeded_logs import write_seeded_log

    from bayesmap.evaluation.trajectory import absolute_trajectory_error
    from bayesmap.io.tum import match_stamps, read_tum

    command = ("import sys; from bayesmap.__main__ import main; sys.argv = ['bayesmap'] + sys.argv[1:]; "
               "sys.exit(main())")
    timed = shutil.which("/usr/bin/time") is not None
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(src), os.environ.get("PYTHONPATH", "")) if p)}
    for name in args.logs.split(","):
        for seed in parse_seeds(args.seeds):
            with tempfile.TemporaryDirectory() as tmp:
                write_seeded_log(name, seed, Path(tmp) / f"{name}-odom")
                truth_stamps, truth = read_tum(Path(tmp) / f"{name}-odom.truth.tum")
                for every in (int(e) for e in args.every.split(",")):
                    out = Path(tmp) / f"out-{every}"
                    scans = [] if every == 1 else ["--scans", f"::{every}"]
                    timing = Path(tmp) / "time.txt"
                    timer = ["/usr/bin/time", "-f", "%e %M", "-o", str(timing)] if timed else []
                    start = time.perf_counter()
                    run = subprocess.run([*timer, sys.executable, "-c", command, "slam", "--log",
                                          str(Path(tmp) / f"{name}-odom.log.gz"), *scans, "--out", str(out)],
                                         env=env, capture_output=True, text=True)
                    wall = time.perf_counter() - start
                    if run.returncode:
                        raise SystemExit(f"slam --log failed on {name} seed {seed}: {run.stderr[-500:]}")
                    time_peak_mb = None
                    if timed:
                        wall, peak_kb = timing.read_text().split()[-2:]
                        time_peak_mb = round(int(peak_kb) / 1024)
                    summary = json.loads((out / "summary.json").read_text())
                    stamps, poses = read_tum(out / "trajectory.tum")
                    ate = absolute_trajectory_error(poses, truth[match_stamps(stamps, truth_stamps)])["rmse_m"]
                    print(json.dumps({"src": str(src), "log": name, "seed": seed, "every": every,
                                      "wall_s": round(float(wall), 1), "ate_m": round(float(ate), 3),
                                      "peak_mb": round(summary["peak_rss_mb"]),
                                      "time_peak_mb": time_peak_mb, "runtime_s": round(summary["runtime_s"], 1),
                                      "stages": {st["stage"]: st["seconds"] for st in summary["stages"]}}),
                          flush=True)


if __name__ == "__main__":
    main()
