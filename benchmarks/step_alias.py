"""Where the front end's large step errors come from: the scan, or the search.

For each log, odometry seed (``seeded_logs.seeded_log``) and scan set (``all``, or ``every2``: every other scan),
the script runs bayesmap's front end (:func:`bayesmap.slam.pipeline.front_end`, as ``slam`` runs it) and takes the
steps whose error against the true step exceeds ``--position`` meters or ``--heading`` radians. For each such step
``t -> t + 1`` it then matches scan ``t + 1`` with the scan alone (no motion model: the front end's coarse-to-fine
search, :func:`bayesmap.slam.scanmatch.search`, from the odometry's prediction) against a local map of the scans
within :data:`bayesmap.slam.scanmatch.LOCAL_MAP_DISTANCE` meters of travel before it, placed at their **true** poses,
and prints how far that match lies from the true pose (in the true pose's frame: along, across, heading). A match
that stays off with a map made at the truth is the scan's own preference, which no choice of the local map's poses
repairs and only the motion model or a later loop can overrule; a match that comes back to the truth is the front
end's earlier errors.

Two variants of the scan's score are printed beside it (each a common remedy for a scan that sees mostly new
space):

* ``unknown U``: an endpoint in space the local map has never observed (outside every local scan's free space: the
  cells nearer than a beam's reading less 0.15 m) reads the field as at least ``U``, not as unmapped (0), so that
  sliding a scan's new walls onto mapped ones gains less;
* ``thin C``: one returned endpoint per square cell of ``C`` meters (the first in beam order), so that a near object
  hit by many beams does not outweigh the far walls.

With ``--odometry-at T1,T2;T3,...``, instead: for each group of steps, the start path (the front end, then
:func:`bayesmap.slam.posegraph.close_loops`) with those steps' second scans left unmatched (their beams marked as not
returned, so the front end takes the odometry's prediction there and leaves them out of its local map), beside the
unchanged start: the front end's and the closed path's ATE, the closed graph's loop edges and its robust cost
(:func:`bayesmap.slam.posegraph.robust_cost`). It asks whether the other branch of an aliased step is the right one,
and whether the loop closure can tell.

Usage: PYTHONPATH=src python benchmarks/step_alias.py [--logs csail] [--seeds 0] [--scans every2]
    [--position 0.15] [--heading 0.05] [--unknown 0.3] [--thin 0.25] [--odometry-at "104;104,107"]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import scan_set_problem, scan_set_runs  # noqa: E402
from step_covariance import step_errors  # noqa: E402

from bayesmap.evaluation.trajectory import absolute_trajectory_error  # noqa: E402
from bayesmap.geometry.grid import Grid  # noqa: E402
from bayesmap.geometry.raycast import scan_endpoints  # noqa: E402
from bayesmap.model.motion import compose, wrap_angle  # noqa: E402
from bayesmap.slam import pipeline, posegraph, scanmatch  # noqa: E402

FREE_MARGIN = 0.15
"""Meters short of a beam's reading that still count as observed free space (``unknown``)."""

MAP_MARGIN = 35.0
"""Meters of grid around the local map's poses and the matched scan (CSAIL's 99th-percentile reading is 14 m)."""


def free_space(grid: Grid, poses, angles, readings) -> np.ndarray:
    """``(nx, ny)`` bool: the cells nearer to one of the scans at ``poses`` ``(L, 3)`` than its beam's reading less
    :data:`FREE_MARGIN`, inside the scan's field of view (``angles``, ``readings`` ``(L, K)``, angles increasing)."""
    ii, jj = np.meshgrid(np.arange(grid.shape[0]), np.arange(grid.shape[1]), indexing="ij")
    centers = np.stack([ii, jj], -1) * grid.resolution + np.asarray(grid.origin) + grid.resolution / 2
    seen = np.zeros(grid.shape, bool)
    for pose, angle, reading in zip(poses, angles, readings):
        offset = centers - pose[:2]
        bearing = np.asarray(wrap_angle(np.arctan2(offset[..., 1], offset[..., 0]) - pose[2]))
        beam = np.clip(np.searchsorted(angle, bearing), 0, len(angle) - 1)
        inside = (bearing >= angle[0]) & (bearing <= angle[-1])
        seen |= inside & (np.hypot(offset[..., 0], offset[..., 1]) < reading[beam] - FREE_MARGIN)
    return seen


def thinned(angles, readings, returned, cell: float) -> np.ndarray:
    """``(K,)`` bool: ``returned`` keeping the first returned endpoint (in beam order) of each square cell of
    ``cell`` meters, in the scan's own frame; ``cell`` 0 keeps every one."""
    if cell == 0:
        return np.asarray(returned)
    ends = np.asarray(scan_endpoints(jnp.zeros(3), angles, readings))
    keys = np.floor(ends / cell).astype(np.int64)
    keep = np.zeros(len(keys), bool)
    taken: set = set()
    for k in np.flatnonzero(returned):
        key = (int(keys[k, 0]), int(keys[k, 1]))
        keep[k] = key not in taken
        taken.add(key)
    return keep


def local_map(data, truth, s: int, travelled) -> tuple:
    """The local map of scan ``s`` at the true poses (module docstring): ``(grid, fields, local scan indices)``."""
    local = [u for u in range(s) if travelled[u] >= travelled[s] - scanmatch.LOCAL_MAP_DISTANCE]
    near = truth[[*local, s], :2]
    lo, hi = near.min(axis=0) - MAP_MARGIN, near.max(axis=0) + MAP_MARGIN
    grid = Grid(shape=tuple(int(n) for n in np.ceil((hi - lo) / pipeline.FRONT_END_RESOLUTION)),
                resolution=pipeline.FRONT_END_RESOLUTION, origin=tuple(float(v) for v in lo))
    fields = scanmatch.empty_fields(grid)
    for u in local:
        fields = scanmatch.add_to_fields(fields, grid, jnp.asarray(truth[u]), data.sensor_angles[u],
                                         data.readings[u], data.returned[u])
    return grid, fields, local


def scan_alone(data, truth, s: int, local_map_, unknown: float = 0.0, cell: float = 0.0) -> np.ndarray:
    """The offset ``(3,)`` (m, m, rad, in the true pose's frame) of scan ``s``'s match with the scan alone, against
    its :func:`local_map` ``local_map_``, from the odometry's prediction (module docstring)."""
    grid, fields, local = local_map_
    if unknown > 0:
        never = ~free_space(grid, truth[local], np.asarray(data.sensor_angles)[local], np.asarray(data.readings)[local])
        fields = tuple(jnp.maximum(f, jnp.where(jnp.asarray(never), unknown, 0.0)) for f in fields)
    returned = thinned(data.sensor_angles[s], data.readings[s], np.asarray(data.returned[s]), cell)
    start = compose(jnp.asarray(truth[s - 1]), jnp.asarray(data.increments[s - 1]))
    best, _ = scanmatch.search(fields, grid, start, data.sensor_angles[s], data.readings[s], jnp.asarray(returned),
                               scanmatch.lattices(scanmatch.MATCH_LEVELS))
    offset = posegraph.relative(truth[s][None], np.asarray(best, np.float64)[None])[0]
    offset[2] = float(wrap_angle(offset[2]))
    return offset


def _fmt(v) -> str:
    return ", ".join(f"{x:+.2f}" for x in v)


def run(name: str, seed: int, scans: str, position: float, heading: float, unknown: float, cell: float) -> list[str]:
    """The table's rows for one (log, seed, scan set)."""
    problem, truth = scan_set_problem(name, seed, scans)
    data = pipeline.scan_data(problem)
    front = pipeline.front_end(problem, data)
    error = step_errors(posegraph.relative(front.path[:-1], front.path[1:]), truth)
    odometry = step_errors(data.increments, truth)
    travelled = scanmatch.path_length(data.increments)
    rows = []
    for t in np.flatnonzero((np.hypot(error[:, 0], error[:, 1]) > position) | (np.abs(error[:, 2]) > heading)):
        s = int(t) + 1
        near = local_map(data, truth, s, travelled)
        alone = [scan_alone(data, truth, s, near), scan_alone(data, truth, s, near, unknown=unknown),
                 scan_alone(data, truth, s, near, cell=cell)]
        rows.append(f"| {name} | {seed} | {scans} | {t} | {_fmt(error[t])} | {_fmt(odometry[t])} | "
                    + " | ".join(_fmt(a) for a in alone) + " |")
    return rows


def branches(name: str, seed: int, scans: str, groups: list[list[int]]) -> list[str]:
    """The ``--odometry-at`` rows for one (log, seed, scan set) (module docstring)."""
    problem, truth = scan_set_problem(name, seed, scans)
    data = pipeline.scan_data(problem)
    rows = []
    for steps in [[], *groups]:
        returned = np.asarray(data.returned).copy()
        returned[[t + 1 for t in steps]] = False
        front = pipeline.front_end(problem, data._replace(returned=returned))
        path, edges, _ = posegraph.close_loops(front.path, data, step_cov=front.step_cov)
        rows.append(f"| {name} | {seed} | {scans} | {', '.join(map(str, steps)) or 'none'} | "
                    f"{absolute_trajectory_error(front.path, truth)['rmse_m']:.3f} | "
                    f"{absolute_trajectory_error(path, truth)['rmse_m']:.3f} | {len(edges.i) - (len(path) - 1)} | "
                    f"{posegraph.robust_cost(path, edges):.1f} |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="csail")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--scans", default="every2", help="comma-separated subset of all,every2")
    parser.add_argument("--position", type=float, default=0.15, help="meters: a step error to look at")
    parser.add_argument("--heading", type=float, default=0.05, help="radians: a step error to look at")
    parser.add_argument("--unknown", type=float, default=0.3, help="the field in never-observed space (variant)")
    parser.add_argument("--thin", type=float, default=0.25, help="meters: one endpoint per cell (variant)")
    parser.add_argument("--odometry-at", default=None,
                        help="groups of steps (';' between groups, ',' within) whose scans the front end leaves out")
    args = parser.parse_args(argv)
    runs = scan_set_runs(parser, args.logs, parse_seeds(args.seeds), args.scans)
    for flag in ("position", "heading", "unknown", "thin"):
        if not getattr(args, flag) >= 0:
            parser.error(f"--{flag} must be a number >= 0, got {getattr(args, flag)}")
    if args.odometry_at is not None:
        try:
            groups = [[int(t) for t in g.split(",") if t.strip()] for g in args.odometry_at.split(";") if g.strip()]
        except ValueError:
            parser.error(f"--odometry-at must be steps like '104;104,107', got {args.odometry_at!r}")
        if not groups or any(t < 0 for g in groups for t in g):
            parser.error(f"--odometry-at must name steps >= 0, got {args.odometry_at!r}")
        print("| log | seed | scans | steps left to the odometry | front end ATE m | closed ATE m | loop edges | "
              "robust cost |")
        print("|---|---|---|---|---|---|---|---|")
        for name, seed, scans in runs:
            for row in branches(name, seed, scans, groups):
                print(row, flush=True)
        return 0
    print("| log | seed | scans | step | front end's error (along m, across m, heading rad) | odometry's error | "
          f"scan alone, truth's map: offset from the truth | with unknown space at {args.unknown:g} | "
          f"with one endpoint per {args.thin:g} m |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, seed, scans in runs:
        for row in run(name, seed, scans, args.position, args.heading, args.unknown, args.thin):
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
