"""The frame of a SLAM run's map figure, with and without the crop to the returned beams' endpoints
(bayesmap.viz.common.crop_extent, FOCUS_COVERAGE): the grid, the seen cells' box and the cropped frame, meters, of
each run folder given (``bayesmap slam --log X --out DIR``).

    PYTHONPATH=src python benchmarks/figure_crop.py ../shared/data/slam/csail-odom.log.gz csail-slam [LOG DIR ...]
"""

import json
import sys
from pathlib import Path

from bayesmap.geometry.grid import Grid
from bayesmap.io.carmen import read_carmen
from bayesmap.io.maps_out import seen_cells_along
from bayesmap.io.tum import read_tum
from bayesmap.runs.slam import slam_endpoints
from bayesmap.slam.problem import log_slam_problem
from bayesmap.viz.common import crop_extent


def size(box) -> str:
    return f"{box[1] - box[0]:.1f} x {box[3] - box[2]:.1f}"


def main(args: list[str]) -> None:
    print("| log | grid, m | seen cells' box, m | frame, m |")
    print("|---|---|---|---|")
    for log, run in zip(args[::2], args[1::2]):
        problem = log_slam_problem(read_carmen(log))
        g = json.loads(Path(run, "summary.json").read_text())["grid"]
        grid = Grid(tuple(g["shape"]), resolution=g["resolution"], origin=tuple(g["origin"]))
        _, mean = read_tum(Path(run, "trajectory.tum"))
        seen = seen_cells_along(grid, mean, problem.sensor_angles, problem.readings, float(problem.params.max_range))
        framed = crop_extent(grid, seen, focus=slam_endpoints(problem, mean), include=mean[:, :2])
        print(f"| {Path(log).name} | {size(grid.extent)} | {size(crop_extent(grid, seen))} | {size(framed)} |")


if __name__ == "__main__":
    main(sys.argv[1:])
