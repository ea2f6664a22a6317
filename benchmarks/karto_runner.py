"""Run Karto graph SLAM (the ``yag-slam`` package) on one scan sequence; executed with the Karto venv's python.

Not imported by bayesmap: ``benchmarks/karto_peer.py`` runs it as a subprocess with
``benchmarks/.venv-karto/bin/python`` (where yag-slam 0.3.0 and opencv-python-headless are installed) so that
yag-slam's dependencies (numba, an old-style numpy stack, its C++ extensions) stay out of bayesmap's environment.

Usage: karto_runner.py IN.npz OUT.npz

IN.npz holds
  ranges          (S, K) float64, meters, one row per scan in log order; values >= max_range mean "no return"
  odom            (S, 3) float64, odometry poses (x m, y m, theta rad)
  min_angle       float, radians: angle of beam 0 relative to the robot heading
  angle_increment float, radians between beams (counter-clockwise)
  max_range       float, meters (the log's saturation value; math.inf if none)
  range_threshold float, meters: readings above it are not used for matching (Karto's RangeThreshold)
OUT.npz holds
  poses           (S, 3) float64, Karto's corrected pose of each scan after the last graph optimization; rows of
                  scans that Karto did not keep are NaN (the caller fills them from odometry)
  kept            (S,) bool, which scans are vertices of Karto's pose graph
  runtime_s       float, seconds spent in GraphSlam.process_scan over all scans (imports and file I/O excluded)
  loop_closures   int, scans for which Karto closed a loop (each one re-optimizes the graph)

Algorithm: OpenKarto's correlative scan matcher (Olson, "Real-time correlative scan matching", ICRA 2009) against a
running buffer of the last 10 scans, loop closure by a coarse-then-fine match against near chains of older scans,
and sparse pose adjustment (Konolige et al., "Efficient sparse pose adjustment for 2D mapping", IROS 2010) after
every closed loop. All settings are yag-slam's defaults.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from yag_slam.graph_slam import GraphSlam
from yag_slam.models import LocalizedRangeScan
from yag_slam.scan_matching import Scan2DMatcherCpp


def make_slam() -> GraphSlam:
    """A GraphSlam with yag-slam's default sequential and loop-closure scan matchers.

    ``GraphSlam.default()`` is broken in yag-slam 0.3.0: it passes the two configuration dicts where it expects
    matcher objects, so both matchers are built here from the same defaults (``Scan2DMatcherCpp({})`` takes
    ``default_config``, ``loop=True`` takes ``default_config_loop``; ``None`` instead of ``{}`` raises).
    """
    return GraphSlam(Scan2DMatcherCpp({}), Scan2DMatcherCpp({}, loop=True))


def run(data: dict) -> dict:
    """Feed every scan to Karto in order and read back the corrected poses (layout: module docstring)."""
    ranges = np.asarray(data["ranges"], dtype=np.float64)
    odom = np.asarray(data["odom"], dtype=np.float64)
    min_angle = float(data["min_angle"])
    increment = float(data["angle_increment"])
    max_range = float(data["max_range"])
    threshold = float(data["range_threshold"])
    max_angle = min_angle + increment * (ranges.shape[1] - 1)
    sensor_max = max_range if np.isfinite(max_range) else float(ranges.max())
    slam = make_slam()
    scans = []
    closures = 0
    start = time.perf_counter()
    for row, (x, y, theta) in zip(ranges, odom):
        scan = LocalizedRangeScan(row, min_angle, max_angle, increment, 0.0, sensor_max, threshold, x, y, theta)
        _, closed = slam.process_scan(scan)
        closures += bool(closed)
        scans.append(scan)
    runtime = time.perf_counter() - start
    poses = np.full((len(scans), 3), np.nan)
    kept = np.zeros(len(scans), dtype=bool)
    index = {id(scan): i for i, scan in enumerate(scans)}
    for vertex in slam.graph.vertices:
        pose = vertex.obj.corrected_pose
        i = index[id(vertex.obj)]
        poses[i] = (pose.x, pose.y, pose.euler[-1])
        kept[i] = True
    return {"poses": poses, "kept": kept, "runtime_s": runtime, "loop_closures": closures}


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__.splitlines()[0] + "\nusage: karto_runner.py IN.npz OUT.npz", file=sys.stderr)
        return 2
    with np.load(sys.argv[1]) as data:
        result = run(dict(data))
    np.savez(sys.argv[2], **result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
