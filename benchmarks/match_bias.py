"""Where the front end's match of a scan lands against a local map built at the true poses: its bias along the heading.

For each scan ``t`` of a log (scans 20 to ``S - 20``), the script builds the likelihood fields
(:func:`bayesmap.slam.scanmatch.add_to_fields`) of the scans within ``--window`` meters of travel before it (``past``,
the front end's local map) or on both sides of it (``both``), at their true poses, starts the front end's search
levels (:data:`bayesmap.slam.scanmatch.MATCH_LEVELS`, no motion model) 3 cm (x, y) and 0.01 rad (heading) from the
true pose (Normal draws, seed 0), and prints the mean and standard error of where the match lands in the true pose's
frame: along the heading, to its left (mm) and in heading (mrad). A local map on both sides shows what the map's
one-sidedness adds. No odometry enters, so every ``--seeds`` value gives the same figures.

Options that change the score, to measure what moves the bias (none of them is the front end's):
``--surface-gap M`` joins consecutive returned endpoints up to M meters apart in the fine field, by points a cell
apart on the segment between them (:func:`surface_beams`: the point-to-line idea of Censi 2008's PL-ICP);
``--seen-mask`` scores only the beams whose endpoint (at the search's start) a scan of the local map saw
(:func:`seen_beams`); ``--range-cap M`` drops readings beyond M meters from the map and the scan.

Usage: PYTHONPATH=src:benchmarks python benchmarks/match_bias.py [--logs aces,willow] [--seeds 0] [--scans every2]
       [--sides past,both] [--window 10] [--surface-gap 0] [--seen-mask] [--range-cap M]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import add_log_seed_options, scan_set_problem, scan_set_runs  # noqa: E402

from bayesmap.geometry.raycast import scan_endpoints  # noqa: E402
from bayesmap.slam import pipeline, posegraph  # noqa: E402
from bayesmap.slam.scanmatch import (  # noqa: E402
    FIELDS,
    MATCH_LEVELS,
    add_scan,
    add_to_fields,
    empty_fields,
    lattices,
    path_length,
    search,
)

MAP_SCANS = 128
"""The most scans of a local map (a fixed size, so one compilation; repeats add nothing to a scatter-max)."""

EDGE = 20
"""Scans left out at either end of the log, where a local map on both sides would be one-sided."""


def seen_beams(pose, sensor_angles, readings, returned, map_poses, map_angles, map_readings, map_returned,
               margin: float = 0.15):
    """``(K,)`` bool: the returned beams of a scan at ``pose`` ``(3,)`` (``sensor_angles``, ``readings``,
    ``returned`` ``(K,)``) whose endpoint some scan of a local map (``(M, 3)`` poses, ``(M, K')`` beams, angles
    increasing) saw: it lies in that scan's field of view, and that scan's nearest beam by bearing returned no nearer
    than the endpoint's distance less ``margin`` meters. An endpoint behind what a map scan's beam hit, past a beam
    with no return, or outside every field of view was not seen. Jittable."""
    ends = scan_endpoints(pose, sensor_angles, readings)

    def by_one(q, angles, ranges, ret):
        v = ends - q[:2]
        distance = jnp.hypot(v[:, 0], v[:, 1])
        bearing = jnp.mod(jnp.arctan2(v[:, 1], v[:, 0]) - q[2] + jnp.pi, 2 * jnp.pi) - jnp.pi
        half = 0.5 * jnp.abs(angles[1] - angles[0])
        j = jnp.clip(jnp.searchsorted(angles, bearing), 1, angles.shape[0] - 1)
        j = jnp.where(jnp.abs(angles[j - 1] - bearing) < jnp.abs(angles[j] - bearing), j - 1, j)
        inside = (bearing >= angles[0] - half) & (bearing <= angles[-1] + half)
        return inside & ret[j] & (distance <= ranges[j] + margin)

    return returned & jnp.any(jax.vmap(by_one)(map_poses, map_angles, map_readings, map_returned), axis=0)


def surface_beams(poses, sensor_angles, readings, returned, gap: float, spacing: float):
    """Scans ``(M, K)`` at ``poses`` ``(M, 3)`` with their surfaces joined: each pair of consecutive returned beams
    whose endpoints lie no more than ``gap`` meters apart gets ``n - 1`` more beams, ``n = ceil(gap / spacing)``,
    ending evenly on the segment between the two endpoints (so at most ``spacing`` apart), as ``(angles, readings,
    returned)`` ``(M, K + (K - 1) (n - 1))`` (a segment not joined: its beams not returned). Jittable."""
    pieces = max(1, int(np.ceil(gap / spacing - 1e-9)))
    ends = scan_endpoints(poses, sensor_angles, readings)  # (M, K, 2)
    a, b = ends[:, :-1], ends[:, 1:]
    joined = returned[:, :-1] & returned[:, 1:] & (jnp.sum((b - a) ** 2, axis=-1) <= gap**2)
    fraction = jnp.arange(1, pieces, dtype=ends.dtype) / pieces
    points = (a[:, :, None] + fraction[:, None] * (b - a)[:, :, None]).reshape(len(poses), -1, 2)
    v = points - poses[:, None, :2]
    angles = jnp.arctan2(v[..., 1], v[..., 0]) - poses[:, None, 2]
    ok = jnp.repeat(joined, pieces - 1, axis=1)
    ranges = jnp.hypot(v[..., 0], v[..., 1])
    return (jnp.concatenate([sensor_angles, angles], axis=1), jnp.concatenate([readings, ranges], axis=1),
            jnp.concatenate([returned, ok], axis=1))


def local_map_fields(grid, poses, sensor_angles, readings, returned, surface_gap: float) -> tuple:
    """The front end's fields (:func:`bayesmap.slam.scanmatch.add_to_fields`) of scans ``(M, K)`` at ``poses``
    ``(M, 3)``; with ``surface_gap`` above 0, the fine field (the first) also of their :func:`surface_beams`."""
    fields = add_to_fields(empty_fields(grid), grid, poses, sensor_angles, readings, returned)
    if surface_gap <= 0:
        return fields
    joined = surface_beams(poses, sensor_angles, readings, returned, surface_gap, grid.resolution)
    return (add_scan(fields[0], grid, poses, *joined, *FIELDS[0]),) + fields[1:]


def local_map_scans(travelled, t: int, window: float, sides: str) -> np.ndarray:
    """The indices of the scans of scan ``t``'s local map: within ``window`` meters of path length ``travelled``
    ``(S,)`` before it (``sides`` ``"past"``) or on either side (``"both"``), ``t`` itself left out."""
    index = np.arange(len(travelled))
    past = (travelled >= travelled[t] - window) & (index < t)
    if sides == "past":
        return np.flatnonzero(past)
    return np.flatnonzero(past | ((travelled <= travelled[t] + window) & (index > t)))


def match_bias(problem, truth, sides: str, window: float, surface_gap: float, seen_mask: bool,
               range_cap: float | None) -> dict:
    """The matches' offsets from the true poses (see the module docstring): ``n`` and, for ``along_mm``,
    ``left_mm`` and ``heading_mrad``, the mean and its standard error."""
    data = pipeline.scan_data(problem)
    returned = np.asarray(data.returned)
    if range_cap is not None:
        returned = returned & (np.asarray(data.readings) <= range_cap)
    grid = posegraph.local_map_grid()
    angles, readings, ret = (jnp.asarray(np.asarray(a)) for a in (data.sensor_angles, data.readings, returned))
    steps = lattices(MATCH_LEVELS)

    @jax.jit
    def match(poses, members, start, t):
        fields = local_map_fields(grid, poses, angles[members], readings[members], ret[members], surface_gap)
        scored = ret[t]
        if seen_mask:
            scored = seen_beams(start, angles[t], readings[t], ret[t], poses, angles[members], readings[members],
                                ret[members])
        return search(fields, grid, start, angles[t], readings[t], scored, steps)[0]

    travelled = path_length(np.diff(truth, axis=0))  # the true path's length (only x and y are read)
    rng = np.random.default_rng(0)
    offsets = []
    for t in range(EDGE, len(truth) - EDGE):
        members = local_map_scans(travelled, t, window, sides)
        if not len(members):
            continue
        members = np.pad(members, (0, MAP_SCANS - len(members)), mode="edge")[:MAP_SCANS]
        shift = np.array([truth[t, 0], truth[t, 1], 0.0])  # matched near the origin: float32 keeps its millimeters
        start = truth[t] - shift + np.array([*rng.normal(0.0, 0.03, 2), rng.normal(0.0, 0.01)])
        best = np.asarray(match(jnp.asarray(truth[members] - shift), jnp.asarray(members), jnp.asarray(start), t))
        d, h = best[:2] - (truth[t, :2] - shift[:2]), truth[t, 2]
        offsets.append((d[0] * np.cos(h) + d[1] * np.sin(h), -d[0] * np.sin(h) + d[1] * np.cos(h),
                        best[2] - truth[t, 2]))
    e = np.array(offsets).reshape(-1, 3) * 1000.0
    figures = {"n": len(e)}
    for k, name in enumerate(("along_mm", "left_mm", "heading_mrad")):
        figures[name] = float(e[:, k].mean()) if len(e) else float("nan")
        figures[name + "_se"] = float(e[:, k].std() / np.sqrt(len(e))) if len(e) > 1 else float("nan")
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_log_seed_options(parser, json_option=False)
    parser.add_argument("--scans", default="every2", help="comma-separated subset of all,every2 (default every2)")
    parser.add_argument("--sides", default="past,both", help="comma-separated subset of past,both")
    parser.add_argument("--window", type=float, default=10.0, help="meters of travel (default 10)")
    parser.add_argument("--surface-gap", type=float, default=0.0, help="meters (default 0: endpoints alone)")
    parser.add_argument("--seen-mask", action="store_true", help="score only the beams the local map saw")
    parser.add_argument("--range-cap", type=float, default=None, help="drop readings beyond this many meters")
    args = parser.parse_args(argv)
    sides = [s for s in args.sides.split(",") if s]
    if not sides or set(sides) - {"past", "both"}:
        parser.error(f"--sides must be a subset of past,both, got {args.sides!r}")
    print("| log | seed | scans | local map | matches | along the heading (mm) | to the left (mm) | heading (mrad) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, seed, scans in scan_set_runs(parser, args.logs, parse_seeds(args.seeds), args.scans):
        problem, truth = scan_set_problem(name, seed, scans)
        for side in sides:
            f = match_bias(problem, truth, side, args.window, args.surface_gap, args.seen_mask, args.range_cap)
            print(f"| {name} | {seed} | {scans} | {side} | {f['n']} | {f['along_mm']:+.2f} +- {f['along_mm_se']:.2f} "
                  f"| {f['left_mm']:+.2f} +- {f['left_mm_se']:.2f} "
                  f"| {f['heading_mrad']:+.3f} +- {f['heading_mrad_se']:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
