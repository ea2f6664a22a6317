"""A building nobody tuned for: a corrected CARMEN log simulated in the Willow Garage floor plan.

Every SLAM default of bayesmap was chosen by cross-validation on the Intel, ACES and CSAIL logs. This script makes a
fourth problem from a building none of those choices saw, ``shared/data/maps/willow-full.pgm`` (54 x 58.7 m, 0.1 m
pixels): a robot drives a tour of its corridors and rooms with two loops, and a SICK-like laser (180 beams over 180
degrees, 0.02 m range noise, 40 m maximum range) scans the plan at every pose. The poses are exact, so the log is a
"corrected" log, and ``shared/tools/noisy_odometry.py`` turns it into a SLAM problem as it did the other three
(``seeded_logs.write_seeded_log("willow", seed, prefix)``; ``karto_peer.py --logs willow``).

The tour: the waypoints of :data:`WAYPOINTS` (meters, chosen by looking at the plan once: a loop around the left
half, the right half, back through the middle), each moved to the point of most clearance within 1.5 m, joined by
the shortest path through the plan's known free space with at least 0.35 m of clearance (Dijkstra on the 8-connected
pixel graph, each step's length weighted by ``1 + (1 m / clearance)^2`` to keep to the middle of a corridor), then a
scan every 0.7 m of path (the three real logs: 0.55-0.94 m), heading along the path's direction smoothed over
+-1 m. Walls are the plan's pixels whose occupancy probability is above its ``occupied_thresh`` (0.65); a beam ends
at the first wall pixel it reaches (marched in 0.01 m steps), one that reaches none within 40 m reads 40 m (no
return). The unknown (grey) pixels outside the building do not stop a beam, as the windows of the real building did
not.

Run ``PYTHONPATH=src python benchmarks/willow_log.py OUT.log.gz [--png PNG]`` to write the log (and a picture of the
tour on the plan). The log is the same on every run (a fixed seed for the range noise).
"""

from __future__ import annotations

import argparse
import gzip
import math
import sys
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from bayesmap.errors import BayesmapError  # noqa: E402
from bayesmap.io.carmen import beam_offsets  # noqa: E402
from bayesmap.io.files import write_atomic  # noqa: E402
from bayesmap.io.rosmap import read_rosmap  # noqa: E402

WILLOW_PLAN = ROOT.parent / "shared" / "data" / "maps" / "willow-full.pgm"
WAYPOINTS = np.array([  # meters, the tour in order (see the module docstring)
    (9.0, 12.0), (9.0, 30.0), (9.0, 46.0), (16.0, 48.0), (21.0, 51.0), (30.0, 51.0), (31.0, 40.0), (31.0, 26.0),
    (26.0, 18.0), (20.0, 22.0), (12.0, 23.0), (9.0, 20.0), (9.0, 12.0), (9.0, 30.0), (9.0, 46.0), (16.0, 48.0),
    (21.0, 51.0), (31.0, 51.0), (43.0, 50.0), (44.0, 36.0), (44.0, 20.0), (44.0, 5.0), (37.0, 4.0), (37.0, 14.0),
    (34.0, 19.0), (31.0, 26.0), (31.0, 40.0), (31.0, 51.0),
])
SCAN_SPACING = 0.7  # meters of path between scans
NUM_BEAMS = 180
MAX_RANGE = 40.0  # meters
RANGE_NOISE = 0.02  # meters, standard deviation
MIN_CLEARANCE = 0.35  # meters
MARCH_STEP = 0.01  # meters


def plan_cells(path: Path = WILLOW_PLAN) -> tuple[np.ndarray, np.ndarray, float]:
    """The plan's wall and known-free pixels, ``walls[i, j]`` and ``free[i, j]`` (bool, i along x, j along y, origin
    (0, 0)), and its resolution in meters per pixel.

    Raises:
        BayesmapError: the plan cannot be read (``bayesmap.io.rosmap.read_rosmap``).
    """
    plan = read_rosmap(path, resolution=0.1)
    walls = plan.occupancy > plan.occupied_thresh
    free = plan.occupancy <= 0.1  # white; the unknown grey (205) has probability 0.2
    return walls, free, plan.grid.resolution


def tour(free: np.ndarray, resolution: float, waypoints: np.ndarray = WAYPOINTS) -> np.ndarray:
    """The robot's route, ``(P, 2)`` float64 meters: a pixel-center polyline through ``waypoints`` (see the module
    docstring).

    Raises:
        BayesmapError: a waypoint has no pixel of enough clearance within 1.5 m, or two waypoints are not connected.
    """
    clearance = ndimage.distance_transform_edt(free) * resolution
    ok = clearance >= MIN_CLEARANCE
    nx, ny = ok.shape
    index = -np.ones(ok.shape, dtype=np.int64)
    cells = np.argwhere(ok)
    index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    rows, cols, weights = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = cells
        b = cells + (di, dj)
        inside = (b[:, 0] >= 0) & (b[:, 0] < nx) & (b[:, 1] >= 0) & (b[:, 1] < ny)
        a, b = a[inside], b[inside]
        both = ok[b[:, 0], b[:, 1]]
        a, b = a[both], b[both]
        c = 0.5 * (clearance[a[:, 0], a[:, 1]] + clearance[b[:, 0], b[:, 1]])
        w = math.hypot(di, dj) * resolution * (1.0 + (1.0 / c) ** 2)
        rows.append(index[a[:, 0], a[:, 1]])
        cols.append(index[b[:, 0], b[:, 1]])
        weights.append(w)
    rows, cols, weights = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    both_ways = (np.concatenate([rows, cols]), np.concatenate([cols, rows]))
    graph = coo_matrix((np.concatenate([weights, weights]), both_ways), shape=(len(cells), len(cells))).tocsr()
    snapped = []
    for x, y in waypoints:
        ci, cj = int(round(x / resolution)), int(round(y / resolution))
        r = int(round(1.5 / resolution))
        i0, j0 = max(ci - r, 0), max(cj - r, 0)
        near = (slice(i0, ci + r + 1), slice(j0, cj + r + 1))
        window = clearance[near] * ok[near]
        if window.max() <= 0:
            raise BayesmapError(f"waypoint ({x}, {y}) m has no pixel with {MIN_CLEARANCE} m of clearance within 1.5 m")
        wi, wj = np.unravel_index(int(np.argmax(window)), window.shape)
        snapped.append(index[i0 + wi, j0 + wj])
    route = [snapped[0]]
    for start, goal in zip(snapped[:-1], snapped[1:]):
        _, pred = dijkstra(graph, indices=start, return_predecessors=True)
        if pred[goal] < 0 and goal != start:
            raise BayesmapError(f"no path between waypoints at pixels {cells[start]} and {cells[goal]}")
        leg = [goal]
        while leg[-1] != start:
            leg.append(pred[leg[-1]])
        route.extend(leg[::-1][1:])
    return (cells[np.array(route)] + 0.5) * resolution


def scan_poses(route: np.ndarray, spacing: float = SCAN_SPACING) -> np.ndarray:
    """Poses ``(S, 3)`` float64 (x, y m, theta rad) every ``spacing`` meters along ``route`` ``(P, 2)``, heading along
    the route's direction smoothed over +-1 m of path."""
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    fine = np.arange(0.0, arc[-1], 0.05)
    xy = np.column_stack([np.interp(fine, arc, route[:, 0]), np.interp(fine, arc, route[:, 1])])
    d = np.gradient(xy, axis=0)
    k = int(round(1.0 / 0.05))
    kernel = np.ones(2 * k + 1)
    dx = np.convolve(np.pad(d[:, 0], k, mode="edge"), kernel, mode="valid")
    dy = np.convolve(np.pad(d[:, 1], k, mode="edge"), kernel, mode="valid")
    heading = np.arctan2(dy, dx)
    take = np.round(np.arange(0.0, arc[-1], spacing) / 0.05).astype(int)
    return np.column_stack([xy[take], heading[take]])


def simulate_ranges(walls: np.ndarray, resolution: float, poses: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Range readings ``(S, NUM_BEAMS)`` float64 in meters at ``poses`` (see the module docstring)."""
    angles = beam_offsets(NUM_BEAMS)
    steps = np.arange(MARCH_STEP, MAX_RANGE, MARCH_STEP)
    out = np.empty((len(poses), NUM_BEAMS))
    for s, (x, y, th) in enumerate(poses):
        a = th + angles
        first = _first_wall_steps(walls, resolution, x, y, np.cos(a), np.sin(a), steps)
        r = np.where(first >= 0, steps[np.maximum(first, 0)], MAX_RANGE)
        noisy = r + rng.normal(0.0, RANGE_NOISE, size=r.shape)
        out[s] = np.where(first >= 0, np.clip(noisy, MARCH_STEP, MAX_RANGE - MARCH_STEP), MAX_RANGE)
    return out


def _first_wall_steps(walls, resolution, x, y, cos, sin, steps, chunk: int = 256) -> np.ndarray:
    """Per beam ``(K,)`` the index into ``steps`` of the first march step on a wall pixel, or -1: the steps marched
    ``chunk`` at a time, each chunk only for the beams without a hit yet (the same indices as marching all at once,
    in a sixth of the time on the Willow tour: 2.6 s against 16.3 s)."""
    first = np.full(len(cos), -1, np.int64)
    open_beams = np.arange(len(cos))
    for lo in range(0, len(steps), chunk):
        d = steps[lo:lo + chunk]
        px = x + cos[open_beams, None] * d[None, :]
        py = y + sin[open_beams, None] * d[None, :]
        i = np.floor(px / resolution).astype(np.int64)
        j = np.floor(py / resolution).astype(np.int64)
        inside = (i >= 0) & (i < walls.shape[0]) & (j >= 0) & (j < walls.shape[1])
        hit = np.zeros(i.shape, dtype=bool)
        hit[inside] = walls[i[inside], j[inside]]
        any_hit = hit.any(axis=1)
        first[open_beams[any_hit]] = lo + hit[any_hit].argmax(axis=1)
        open_beams = open_beams[~any_hit]
        if not len(open_beams):
            break
    return first


def flaser_lines(ranges: np.ndarray, poses: np.ndarray) -> list[str]:
    """CARMEN FLASER lines, the pose in both pose fields (a corrected log), timestamps 1 s apart."""
    lines = []
    for s, (r, (x, y, th)) in enumerate(zip(ranges, poses)):
        values = " ".join(f"{v:.3f}" for v in r)
        stamp = f"{1.0 + s:.6f}"
        lines.append(f"FLASER {len(r)} {values} {x:.6f} {y:.6f} {th:.6f} {x:.6f} {y:.6f} {th:.6f} {stamp} sim {stamp}")
    return lines


def write_willow_log(out: Path, png: Path | None = None) -> np.ndarray:
    """Write the simulated corrected log to ``out`` (gzip CARMEN; whole or not at all: a temporary file renamed) and
    return its true poses ``(S, 3)``; with ``png``, a picture of the tour on the plan."""
    walls, free, resolution = plan_cells()
    poses = scan_poses(tour(free, resolution))
    ranges = simulate_ranges(walls, resolution, poses, np.random.default_rng(20261124))
    text = ("# simulated in shared/data/maps/willow-full.pgm by bayesmap benchmarks/willow_log.py\n"
            + "\n".join(flaser_lines(ranges, poses)) + "\n")
    write_atomic(out, gzip.compress(text.encode("utf-8")), overwrite=True)
    if png is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(8, 8.7))
        ax.imshow(np.where(walls, 0.0, np.where(free, 1.0, 0.8)).T, origin="lower", cmap="gray",
                  extent=[0, walls.shape[0] * resolution, 0, walls.shape[1] * resolution])
        ax.plot(poses[:, 0], poses[:, 1], "-", color="tab:blue", lw=1)
        ax.plot(poses[0, 0], poses[0, 1], "o", color="tab:green")
        length = np.sum(np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1))
        ax.set_title(f"simulated Willow tour: {len(poses)} scans, {length:.0f} m")
        fig.savefig(png, dpi=90, bbox_inches="tight")
        plt.close(fig)
    return poses


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the log to write (.log.gz)")
    parser.add_argument("--png", type=Path, default=None, help="also draw the tour on the plan here")
    args = parser.parse_args(argv)
    if args.out.exists():
        parser.error(f"{args.out} exists; remove it first")
    poses = write_willow_log(args.out, args.png)
    print(f"{args.out}: {len(poses)} scans")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
