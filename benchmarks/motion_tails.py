"""How well the odometry motion model's covariances cover the true steps, step by step: the heavy tail of short steps.

For each log and odometry seed (``seeded_logs.seeded_log``: a corrected log with ``noisy_odometry.py``'s odometry),
the true path's motion error under each step's covariance (``bayesmap.model.motion.motion_error`` of the true poses
against the odometry's increments, the heading's difference wrapped), with and without the steps that have no
direction (``bayesmap.model.motion.UNDIRECTED_RADIUS``; set to 0 for "without"). Printed per log: the number of
steps and of those under the radius, the heading's |z| (error over the model's standard deviation) at the median,
the 99th percentile and the largest, the fraction of steps beyond 4 standard deviations in 3-D (squared Mahalanobis
distance above 16), and the log-density of the true steps (``motion_logpdf`` summed). About a minute for the
default logs.

Usage: PYTHONPATH=src:benchmarks python benchmarks/motion_tails.py [--runs fr079:2,fr079:0,aces:1,intel:0]
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np
from seeded_logs import seeded_log

from bayesmap.model import motion
from bayesmap.slam.problem import log_slam_problem


def tails(name: str, seed: int, radius: float) -> dict:
    """The scores of one log and seed under the motion model as it is now (module docstring); ``radius`` (meters)
    counts the steps shorter than it."""
    log, truth = seeded_log(name, seed)
    increments, covariances = log_slam_problem(log).motion_steps()
    error = np.array(motion.motion_error(jnp.asarray(truth[:-1]), jnp.asarray(truth[1:]), jnp.asarray(increments)))
    error[:, 2] = motion.wrap_angle(error[:, 2])
    cov = np.asarray(covariances, np.float64)
    z = np.abs(error[:, 2]) / np.sqrt(cov[:, 2, 2])
    d2 = np.einsum("si,sij,sj->s", error, np.linalg.inv(cov), error)
    log_density = -0.5 * d2 - 0.5 * np.linalg.slogdet(cov)[1] - 1.5 * np.log(2 * np.pi)
    trans = np.asarray(motion.odometry_decomposition(jnp.asarray(log.poses)))[:, 1]
    return {"log": name, "seed": seed, "steps": len(z), "under_radius": int(np.sum(trans < radius)),
            "z": np.quantile(z, [0.5, 0.99, 1.0]).round(2).tolist(), "beyond_4sd": float(np.mean(d2 > 16)),
            "log_density": float(np.sum(log_density))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", default="fr079:2,fr079:0,aces:1,intel:0", help="LOG:SEED,... (seeded_logs names)")
    args = parser.parse_args(argv)
    runs = [(part.split(":")[0], int(part.split(":")[1])) for part in args.runs.split(",")]
    radius = motion.UNDIRECTED_RADIUS
    for label, value in (("without steps with no direction", 0.0), ("with them", radius)):
        motion.UNDIRECTED_RADIUS = value  # read by the covariance at each call (odometry_controls is not jitted)
        print(f"\n{label}\nlog      seed  steps  under  heading |z| median / 99 % / largest  beyond 4 sd  log-density")
        for name, seed in runs:
            r = tails(name, seed, radius * motion.MotionParams().floor_xy)
            z = " / ".join(f"{v:g}" for v in r["z"])
            print(f"{r['log']:8s} {r['seed']:4d}  {r['steps']:5d}  {r['under_radius']:5d}  {z:38s}  "
                  f"{100 * r['beyond_4sd']:9.2f} %  {r['log_density']:11.1f}")
    motion.UNDIRECTED_RADIUS = radius
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
