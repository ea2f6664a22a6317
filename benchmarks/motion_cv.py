"""Leave-one-log-out cross-validation of the odometry motion model's noise (the motion-noise defaults).

For each SLAM problem (a noisy-odometry log and its true trajectory, ``../shared/data/slam/X-odom.*`` or any made by
``noisy_odometry.py``) the score of motion parameters is the mean log-density per step of the true path given the
odometry under the motion model (:func:`bayesmap.model.motion.path_logpdf`): how well the model predicts where the
robot really went. The four alphas (PR Table 5.6, as standard deviations) are fitted by maximum likelihood on all
logs but one (scipy's L-BFGS-B on their logarithms) and scored on the one left out, beside the defaults
(:class:`bayesmap.model.motion.MotionParams`). The floors stay at the defaults' (1 cm, 0.005 rad): they only keep a
standing robot's covariance positive definite, and a simulated odometry that adds no noise to a standing robot would
drive their maximum-likelihood value to 0.

Usage: PYTHONPATH=src python benchmarks/motion_cv.py [PREFIX ...]   (default: the three shared seed-0 problems;
a PREFIX names PREFIX.log.gz and PREFIX.truth.tum)
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from bayesmap.io.carmen import read_carmen
from bayesmap.io.tum import read_tum
from bayesmap.model.motion import MotionParams, make_motion_params, odometry_controls, path_logpdf

SLAM = Path(__file__).resolve().parents[2] / "shared" / "data" / "slam"


def load(prefix: str):
    """``(odometry (S, 3), truth (S, 3))`` of a SLAM problem, the truth's heading unwrapped (the motion model's
    heading is a real number, :mod:`bayesmap.model.motion`)."""
    log = read_carmen(f"{prefix}.log.gz")
    truth = read_tum(f"{prefix}.truth.tum")[1]
    truth[:, 2] = np.unwrap(truth[:, 2])
    return np.asarray(log.poses, np.float64), truth


def score(problem, params: MotionParams) -> float:
    """Mean log-density per step of the true path given the odometry."""
    odometry, truth = problem
    inc, cov = odometry_controls(odometry, params)
    truth = jnp.asarray(truth)
    return float(path_logpdf(truth, truth[0], inc, cov)) / (len(truth) - 1)


def fit(problems) -> MotionParams:
    """The alphas of maximum total log-density over ``problems`` (floors fixed at the defaults)."""
    default = MotionParams()

    def loss(log_alphas):
        params = make_motion_params(np.exp(log_alphas))
        return -sum(score(p, params) * (len(p[1]) - 1) for p in problems)

    start = np.log([default.a1, default.a2, default.a3, default.a4])
    best = minimize(loss, start, method="L-BFGS-B", bounds=[(-12.0, 1.0)] * 4)
    return make_motion_params(np.exp(best.x))


def main(argv: list[str]) -> int:
    jax.config.update("jax_enable_x64", True)
    prefixes = argv or [str(SLAM / f"{name}-odom") for name in ("intel", "aces", "csail")]
    problems = {Path(p).name: load(p) for p in prefixes}
    print("| held-out log | fitted a1, a2, a3, a4 (on the others) | held-out log-density per step, fitted | "
          "defaults |")
    print("|---|---|---|---|")
    for name, held in problems.items():
        params = fit([p for n, p in problems.items() if n != name])
        alphas = ", ".join(f"{getattr(params, a):.4f}" for a in ("a1", "a2", "a3", "a4"))
        print(f"| {name} | {alphas} | {score(held, params):.3f} | {score(held, MotionParams()):.3f} |", flush=True)
    params = fit(list(problems.values()))
    print("all logs:", ", ".join(f"{a} {getattr(params, a):.4f}" for a in ("a1", "a2", "a3", "a4")))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
