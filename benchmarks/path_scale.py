"""How much larger the truth is than bayesmap's path: the best similarity alignment's scale (karto_peer.py's arrays).

For each ``DIR/LOG-sSEED.npz`` that ``karto_peer.py --methods bayesmap --cache DIR`` left (the mean path and the true
poses), the script prints the scale ``s`` of the least-squares similarity (rotation, translation and scale) that
maps the path's positions onto the true ones (Umeyama 1991, restricted to the plane), as ``(s - 1)`` in percent (above
0: the truth is larger, the path shrunk), and the position RMSE after the rigid alignment (the ATE) and after the
similarity one. A path that is right but for its scale has a rigid ATE that the similarity's removes; the ATE target
is the rigid one.

Usage: PYTHONPATH=src python benchmarks/path_scale.py DIR [DIR ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bayesmap.evaluation.trajectory import absolute_trajectory_error, align_rigid_2d, similarity_scale


def similarity_fit(estimate, truth) -> tuple[float, float]:
    """``(s, rmse)``: the scale of the least-squares similarity of ``estimate``'s positions ``(S, 2+)`` onto
    ``truth``'s (:func:`bayesmap.evaluation.trajectory.similarity_scale`; its rotation is the rigid alignment's) and
    the position RMSE after it (meters)."""
    e, g = np.asarray(estimate, np.float64)[:, :2], np.asarray(truth, np.float64)[:, :2]
    scale = similarity_scale(e, g)
    rot, _ = align_rigid_2d(e, g)
    moved = scale * (e - e.mean(axis=0)) @ rot.T + g.mean(axis=0)
    return scale, float(np.sqrt(np.mean(np.sum((moved - g) ** 2, axis=1))))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path, help="karto_peer.py --cache folders")
    args = parser.parse_args(argv)
    files = [path for folder in args.folders for path in sorted(folder.glob("*.npz"))]
    if not files:
        parser.exit(2, f"path_scale.py: no karto_peer.py arrays (*.npz) in {', '.join(map(str, args.folders))}\n")
    print("| run | truth's scale over the path's, % | ATE m (rigid) | RMSE m after the similarity |")
    print("|---|---|---|---|")
    for path in files:
        with np.load(path) as arrays:
            mean, truth = arrays["mean"], arrays["truth"]
        scale, rmse = similarity_fit(mean, truth)
        print(f"| {path.stem} | {100 * (scale - 1):+.3f} | {absolute_trajectory_error(mean, truth)['rmse_m']:.3f} | "
              f"{rmse:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
