"""How much a scan's beams are worth together: the composite-likelihood magnitude adjustment of the front end's field
score at each matched pose, from the beams' own score contributions (no truth).

The front end scores a scan at a pose by the sum over its returned beams of ``log(field(endpoint) + FIELD_FLOOR)``
(:func:`bayesmap.slam.scanmatch.field_scores`), as if the beams were independent. They are not: neighbouring beams
see the same wall, and a wall the local map holds a little off moves all of them. Composite-likelihood theory gives
the power at which such a sum has the curvature of its own sampling variance (Pauli, Racugno & Ventura 2011,
"Bayesian composite marginal likelihoods", *Statistica Sinica* 21; Varin, Reid & Firth 2011, *Statistica Sinica* 21,
sec. 2.3): ``w = p / tr(H^-1 J)``, with ``H`` the score's information and ``J`` the variance of the score (the sum
of the beams' gradients), here ``p = 3`` pose components, ``H`` the beams' gradients' outer products and ``J``
their Bartlett-weighted autocovariance along the scan's beam order up to a bandwidth of ``b`` beams (a HAC estimate,
Newey & West 1987). ``b = 0`` treats the beams as independent (``w = 1``); a larger ``b`` lets neighbours correlate.
The front end's likelihood power is 0.1.

For each log and odometry seed the script runs the front end (:func:`bayesmap.slam.pipeline.front_end`), then for
every ``--every``-th scan builds its local map at the matched path (the scans of the 10 m of travel before it, the
fine field, :func:`bayesmap.slam.scanmatch.add_to_fields`) and prints the median and 10th-90th percentiles of ``w``
over the scans at each bandwidth, then at each scan's own data-driven bandwidth (:func:`automatic_bandwidth`) and
that bandwidth.

Usage: PYTHONPATH=src python benchmarks/beam_correlation.py [--logs aces] [--seeds 0] [--every 5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from karto_peer import parse_seeds  # noqa: E402
from seeded_logs import chosen_logs, seeded_log  # noqa: E402

from bayesmap.slam import pipeline, posegraph, scanmatch  # noqa: E402
from bayesmap.slam.problem import log_slam_problem  # noqa: E402

BANDWIDTHS = (0, 2, 5, 10, 20, 40)
"""Beams: the HAC estimate's bandwidths."""

NEIGHBOURS = 60
"""The most scans of a local map (the latest ones within its 10 m of travel): one compiled shape for all."""


def magnitude_adjustments(gradients: np.ndarray) -> list[float]:
    """``w = 3 / tr(H^-1 J_b)`` for each bandwidth ``b`` of :data:`BANDWIDTHS`, from the ``(K, 3)`` gradients of
    the returned beams' scores in beam order; then ``w`` at :func:`automatic_bandwidth` and that bandwidth."""
    h = gradients.T @ gradients
    h_inv = np.linalg.inv(h)
    automatic = automatic_bandwidth(gradients)
    lagged = {}  # each lag's autocovariance, both directions, computed once for every bandwidth (0 past the beams)
    for lag in range(1, max(*BANDWIDTHS, int(automatic)) + 1):
        c = gradients[lag:].T @ gradients[:-lag]
        lagged[lag] = c + c.T

    def adjustment(b: float) -> float:  # Bartlett weights 1 - lag / (b + 1) on the lags up to b
        j = h + sum((1 - lag / (b + 1)) * lagged[lag] for lag in range(1, int(b) + 1))
        return 3.0 / float(np.trace(h_inv @ j))

    return [adjustment(b) for b in BANDWIDTHS] + [adjustment(automatic), automatic]


def automatic_bandwidth(gradients: np.ndarray) -> float:
    """Beams: the Bartlett kernel's data-driven bandwidth ``1.1447 (alpha T)^(1/3)`` of Andrews (1991,
    "Heteroskedasticity and autocorrelation consistent covariance matrix estimation", *Econometrica* 59, eq. 6.2 and
    6.4), ``T`` the beams, ``alpha`` from an AR(1) fit to each gradient component in beam order (equal weights)."""
    num = den = 0.0
    for a in range(gradients.shape[1]):
        x = gradients[:, a] - gradients[:, a].mean()
        rho = float(np.clip(np.dot(x[1:], x[:-1]) / np.dot(x[:-1], x[:-1]), -0.97, 0.97))
        s2 = float(np.mean((x[1:] - rho * x[:-1]) ** 2))
        num += 4 * rho**2 * s2**2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2**2 / (1 - rho) ** 4
    return 1.1447 * (num / den * len(gradients)) ** (1 / 3)


def scan_adjustments(data, path, scans) -> list:
    """For each scan ``t`` of ``scans`` (``t >= 1``), :func:`magnitude_adjustments` of its returned beams' score
    gradients at its pose in ``path`` ``(S, 3)`` against its local map there (the scans of the 10 m of travel before
    it, at most :data:`NEIGHBOURS`, the fine field), or None where the gradients are degenerate (fewer than 3 beams or
    a condition number above 1e8). ``data`` is the scans' :class:`bayesmap.slam.scanmatch.ScanData`."""
    grid = posegraph.local_map_grid()
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path[:, :2], axis=0).T))])
    angles, readings, returned = (np.asarray(a) for a in (data.sensor_angles, data.readings, data.returned))

    @jax.jit
    def fine_field(poses, a, r, ret):
        return scanmatch.add_to_fields(scanmatch.empty_fields(grid), grid, poses, a, r, ret)[0]

    def beam_scores(pose, field, a, r, ret):  # (K,): each beam's term of field_scores
        one = jax.vmap(lambda ak, rk, retk: scanmatch.field_scores(field, grid, pose[None], ak[None], rk[None],
                                                                    retk[None])[0])
        return one(a, r, ret)

    gradient = jax.jit(jax.jacfwd(beam_scores))
    out = []
    for t in scans:
        near = np.flatnonzero((travel >= travel[t] - scanmatch.LOCAL_MAP_DISTANCE) & (np.arange(len(path)) < t))
        near = np.concatenate([np.full(max(NEIGHBOURS - len(near), 0), near[0]), near[-NEIGHBOURS:]])
        shift = np.array([path[t, 0], path[t, 1], 0.0])  # the local map's frame: scan t at its center
        field = fine_field(jnp.asarray(path[near] - shift), angles[near], readings[near], returned[near])
        g = np.asarray(gradient(jnp.asarray(path[t] - shift, jnp.float32), field, angles[t], readings[t],
                                returned[t]), np.float64)[returned[t]]
        ok = len(g) >= 3 and np.linalg.cond(g.T @ g) < 1e8
        out.append(magnitude_adjustments(g) if ok else None)
    return out


def run(name: str, seed: int, every: int) -> str:
    """One row of the table (module docstring)."""
    log, _ = seeded_log(name, seed)
    problem = log_slam_problem(log)
    data = pipeline.scan_data(problem)
    path = pipeline.front_end(problem, data).path
    rows = [w for w in scan_adjustments(data, path, range(every, len(path), every)) if w is not None]
    w = np.array(rows)
    cells = [f"{np.median(w[:, k]):.2f} ({np.percentile(w[:, k], 10):.2f}-{np.percentile(w[:, k], 90):.2f})"
             for k in range(len(BANDWIDTHS) + 2)]
    return f"| {name} | {seed} | {len(w)} | " + " | ".join(cells) + " |"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="aces")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--every", type=int, default=5, help="score every N-th scan (default 5)")
    args = parser.parse_args(argv)
    if args.every < 1:
        parser.error(f"--every must be at least 1, got {args.every}")
    print("| log | seed | scans | " + " | ".join(f"w, bandwidth {b}" for b in BANDWIDTHS)
          + " | w, automatic bandwidth | automatic bandwidth |")
    print("|---|---|---|" + "---|" * (len(BANDWIDTHS) + 2))
    for name in chosen_logs(parser, args.logs):
        for seed in parse_seeds(args.seeds):
            print(run(name, seed, args.every), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
