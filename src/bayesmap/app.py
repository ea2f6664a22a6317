"""The interactive map explorer: a local web app (NiceGUI) for the tutorial's scene.

It does what the tutorial's final interactive widget does, offline and without Jupyter:

* the grid with the true walls; a click toggles a wall, click-and-drag paints (walls or free space, whichever the
  first cell became); the sensor is a handle that can be dragged (no wall can be drawn on its cell, and it cannot be
  dropped on a wall);
* the beams and the noisy range readings, simulated from the model and redrawn whenever the walls, the sensor, the
  sensor noise or the number of beams change;
* sliders (each with a field to type a value) for ``prior_wall_prob``, ``sensor_noise``, ``num_angles`` and the
  number of sweeps;
* buttons Run inference (fast 2x2 block Gibbs in a worker thread, with a progress bar; a click while a run is going
  does nothing), Clear walls, Clear inferred walls; load an ASCII map file and save the drawn map;
* after a run, a sample slider and a "show average" switch; the inferred walls drawn as cell opacity (the tutorial's
  style) or as a heatmap;
* a path mode (issue 15): clicks on free cells append sensor poses to a path (headings towards the next pose); Run
  SLAM simulates odometry (:func:`bayesmap.slam.problem.simulate_odometry`) and readings along it and runs the
  joint chain (:func:`bayesmap.slam.joint.run_slam`), then draws the posterior map, the odometry, the pose samples, the
  posterior mean path and the ATE of the mean and of the odometry.

Each browser tab gets its own :class:`Explorer`, so tabs are independent sessions. The page's scripts and styles are
NiceGUI's own, served by the app itself: nothing is fetched from the network.

The logic lives in :class:`Explorer` (plain Python, tested without a browser); :class:`ExplorerPage` builds the
NiceGUI elements panel by panel and wires them to it (:func:`build_page`), and :func:`run_app` serves it.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from bayesmap import scenes
from bayesmap.errors import BayesmapError
from bayesmap.evaluation.trajectory import score_trajectory
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import sensor_distances
from bayesmap.inference.driver import DEFAULT_SWEEPS, InferenceResult, run_inference
from bayesmap.io.ascii import format_map, parse_map, tutorial_map
from bayesmap.model.generative import make_params
from bayesmap.scenes import TUTORIAL_POS, Problem, tutorial_problem
from bayesmap.slam.joint import run_slam
from bayesmap.slam.problem import SlamProblem, simulated_slam_problem

SAMPLER = "block"

SLAM_MAX_SWEEPS = 200
"""The most joint sweeps a path-mode run does (the sweeps setting is capped at it): a SLAM sweep costs about 0.25 s
on the tutorial map, against about 1 ms for a map-only sweep."""


@dataclass(frozen=True)
class Setting:
    """One numeric setting of the explorer: its range (inclusive), slider step and whether it is an integer."""

    label: str
    low: float
    high: float
    step: float
    integer: bool = False

    def check(self, value) -> float | int:
        """``value`` as a number of this setting.

        Raises:
            BayesmapError: naming the value, if it is not a number within ``[low, high]`` (an integer if required).
        """
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise BayesmapError(f"{self.label}: {value!r} is not a number") from None
        if not math.isfinite(number) or not (self.low <= number <= self.high):
            raise BayesmapError(f"{self.label} must be between {self.low:g} and {self.high:g}, got {value!r}")
        if self.integer:
            if number != int(number):
                raise BayesmapError(f"{self.label} must be a whole number, got {value!r}")
            return int(number)
        return number


@dataclass(frozen=True)
class SlamRun:
    """One path-mode run: the scene, the joint chain's result and the ATEs (root mean square, meters, after a
    rigid alignment: :func:`bayesmap.evaluation.trajectory.absolute_trajectory_error`).

    Attributes:
        problem: the :class:`~bayesmap.slam.problem.SlamProblem` (true path, odometry ``(S, 3)``, readings ``(S, K)``).
        result: the :class:`~bayesmap.slam.joint.SlamResult` (pose samples ``(N, S, 3)``, mean path ``(S, 3)``,
            posterior map ``(nx, ny)``).
        sweeps: joint sweeps run (the first third burn-in).
        ate_mean: ATE of the posterior mean path, meters.
        ate_odometry: ATE of the odometry, meters.
    """

    problem: SlamProblem
    result: object
    sweeps: int
    ate_mean: float
    ate_odometry: float


SETTINGS: dict[str, Setting] = {
    "prior_wall_prob": Setting("prior wall probability", 0.01, 0.99, 0.01),
    "sensor_noise": Setting("sensor noise (m)", 0.01, 2.0, 0.01),
    "num_angles": Setting("number of beams", 1, 400, 1, integer=True),
    "sweeps": Setting("sweeps", 10, 2000, 10, integer=True),
}


class Explorer:
    """The state of one explorer session: drawn map, sensor, settings, readings and the last inference.

    Args:
        walls: ``(nx, ny)`` initial map (cells > 0.5 are walls); default the tutorial's 21 x 21 map.
        pos: ``(2,)`` initial sensor position in world meters (the tutorial's unit cells); default the map's
            center cell (the tutorial's (10, 10)).
        seed: PRNG seed of the simulated readings and of the chain.

    Attributes:
        walls: ``(nx, ny)`` float32 0/1, the drawn (true) map.
        pos: ``(2,)`` float64 sensor position (meters).
        prior_wall_prob, sensor_noise, num_angles, sweeps: the settings (see :data:`SETTINGS`).
        result: the last :class:`~bayesmap.inference.driver.InferenceResult`, or None.
        stale: True when the map, sensor or a setting changed since the last run.
        runs: number of runs started in this session.
        running: True while a run is going.
        progress: fraction of the current run's sweeps done, in [0, 1].

    Raises:
        BayesmapError: if the map has no free cell for the sensor.
    """

    def __init__(self, walls=None, pos=None, seed: int = 0):
        self.walls = (tutorial_map() if walls is None else (np.asarray(walls) > 0.5)).astype(np.float32)
        self.grid = Grid(shape=self.walls.shape)
        self.seed = int(seed)
        self.prior_wall_prob = scenes.TUTORIAL_PRIOR
        self.sensor_noise = scenes.TUTORIAL_SENSOR_NOISE
        self.num_angles = scenes.TUTORIAL_NUM_ANGLES
        self.sweeps = DEFAULT_SWEEPS
        self.pos = self._free_position(TUTORIAL_POS if pos is None and self.walls.shape == (21, 21) else pos)
        self.result: InferenceResult | None = None
        self.stale = False
        self.runs = 0
        self.running = False
        self.progress = 0.0
        self._lock = threading.Lock()
        self._problem: Problem | None = None
        self._beams: tuple | None = None  # (problem, hits, readings) of the last drawing
        self.path_mode = False
        self.path: list[np.ndarray] = []
        self.slam: SlamRun | None = None

    # -- the scene ---------------------------------------------------------------------------------------------

    def _free_position(self, pos) -> np.ndarray:
        """``pos`` if it is inside the grid and not in a wall, else the free cell center nearest to the grid's
        center."""
        if pos is not None:
            xy = np.asarray(pos, dtype=np.float64)
            if self.grid.contains(xy) and not self._wall_at(xy):
                return xy
        free = np.argwhere(self.walls < 0.5)
        if len(free) == 0:
            raise BayesmapError("the map has no free cell to put the sensor in")
        center = (np.asarray(self.walls.shape) - 1) / 2.0
        i, j = free[np.argmin(np.sum((free - center) ** 2, axis=1))]
        return self.grid.cell_centers()[i, j].astype(np.float64)

    def cell_at(self, xy) -> tuple[int, int] | None:
        """The cell ``(i, j)`` containing the world point ``xy`` (meters), or None outside the grid."""
        i, j = (int(v) for v in self.grid.cell_index(xy))
        if 0 <= i < self.grid.shape[0] and 0 <= j < self.grid.shape[1]:
            return i, j
        return None

    def _wall_at(self, xy) -> bool:
        cell = self.cell_at(xy)
        return cell is not None and self.walls[cell] > 0.5

    def sensor_cell(self) -> tuple[int, int]:
        """The cell ``(i, j)`` the sensor is in."""
        return self.cell_at(self.pos)

    def _changed(self) -> None:
        self._problem = None
        if self.result is not None or self.slam is not None:
            self.stale = True

    def set_wall(self, cell: tuple[int, int], value: bool) -> bool:
        """Make ``cell`` a wall (``value`` True) or free; returns False (and changes nothing) for the sensor's cell
        or a cell outside the grid."""
        i, j = cell
        if not (0 <= i < self.grid.shape[0] and 0 <= j < self.grid.shape[1]) or (i, j) == self.sensor_cell():
            return False
        if (self.walls[i, j] > 0.5) != bool(value):
            self.walls[i, j] = float(value)
            self._changed()
        return True

    def toggle(self, cell: tuple[int, int]) -> bool | None:
        """Toggle ``cell``; returns its new state (True for a wall), or None if it cannot be drawn on."""
        new = not (self.walls[cell] > 0.5)
        return new if self.set_wall(cell, new) else None

    def move_sensor(self, xy) -> bool:
        """Move the sensor to the world point ``xy`` (meters); returns False (and does not move) if the point is
        outside the grid or in a wall."""
        xy = np.asarray(xy, dtype=np.float64).reshape(2)
        if not np.all(np.isfinite(xy)) or not self.grid.contains(xy) or self._wall_at(xy):
            return False
        if not np.array_equal(xy, self.pos):
            self.pos = xy
            self._changed()
        return True

    def clear_walls(self) -> None:
        """Remove every drawn wall."""
        if self.walls.any():
            self.walls[:] = 0.0
            self._changed()

    def clear_inferred(self) -> None:
        """Forget the last inference (and the last SLAM run)."""
        self.result = None
        self.slam = None
        self.stale = False

    # -- path mode ----------------------------------------------------------------------------------------------

    def set_path_mode(self, on: bool) -> None:
        """Switch path mode on or off (the drawn path and the last SLAM run are kept)."""
        self.path_mode = bool(on)

    def add_pose(self, cell: tuple[int, int]) -> None:
        """Append the center of ``cell`` ``(i, j)`` to the path.

        Raises:
            BayesmapError: naming the cell, if it is outside the grid, a wall, or the path's last pose (nothing
                changes).
        """
        i, j = (int(v) for v in cell)
        if not (0 <= i < self.grid.shape[0] and 0 <= j < self.grid.shape[1]):
            raise BayesmapError(f"cell ({i}, {j}) is outside the {self.grid.shape[0]} x {self.grid.shape[1]} grid")
        if self.walls[i, j] > 0.5:
            raise BayesmapError(f"cell ({i}, {j}) is a wall: a pose must be on a free cell (walls cannot be drawn "
                                "in path mode)")
        xy = self.grid.cell_centers()[i, j].astype(np.float64)
        if self.path and np.array_equal(xy, self.path[-1]):
            raise BayesmapError(f"cell ({i}, {j}) is already the path's last pose")
        self.path.append(xy)
        if self.slam is not None:
            self.stale = True

    def clear_path(self) -> None:
        """Remove every pose of the path and forget the last SLAM run."""
        self.path = []
        self.slam = None
        self.stale = self.result is not None and self.stale

    def true_path(self) -> np.ndarray:
        """``(S, 3)`` float64 drawn path (x m, y m, theta rad): each heading points to the next pose, the last
        pose keeps the heading of the step before it (0 for a single pose)."""
        xy = np.asarray(self.path, dtype=np.float64).reshape(-1, 2)
        if len(xy) < 2:
            return np.column_stack([xy, np.zeros(len(xy))])
        step = np.diff(xy, axis=0)
        heading = np.arctan2(step[:, 1], step[:, 0])
        return np.column_stack([xy, np.append(heading, heading[-1])])

    def slam_problem(self) -> SlamProblem:
        """The SLAM scene of the drawn walls and path: odometry simulated from the path by
        :func:`bayesmap.slam.problem.simulate_odometry` (:data:`bayesmap.slam.problem.SLAM_ODOMETRY_ALPHAS`, this
        session's seed), readings simulated at the true poses with the current ``num_angles`` beams (relative to the
        heading), ``sensor_noise`` and ``prior_wall_prob``, by :func:`bayesmap.slam.problem.simulated_slam_problem`
        (as the tutorial SLAM scene).

        Raises:
            BayesmapError: if the path has fewer than 2 poses.
        """

        if len(self.path) < 2:
            raise BayesmapError(f"the path needs at least 2 poses, it has {len(self.path)}: click free cells to add "
                                "poses")
        true_poses = self.true_path()
        params = make_params(self.prior_wall_prob, self.sensor_noise, self.num_angles, self.grid)
        return simulated_slam_problem(self.walls, true_poses, params, self.seed,
                                             source=f"app: path of {len(true_poses)} poses, seed {self.seed}")

    def _slam_scene(self) -> tuple:
        """What a SLAM run's scene depends on (to tell whether it changed during a run)."""
        return (tuple(map(tuple, self.true_path().tolist())), self.walls.tobytes(), self.prior_wall_prob,
                self.sensor_noise, self.num_angles)

    def slam_sweeps(self) -> int:
        """The joint sweeps of a path-mode run: the sweeps setting, at most :data:`SLAM_MAX_SWEEPS`."""
        return min(self.sweeps, SLAM_MAX_SWEEPS)

    def run_slam(self) -> SlamRun:
        """Run joint SLAM on the drawn walls and path (:meth:`slam_problem`; :meth:`slam_sweeps` sweeps, the
        first third burn-in, seed = this session's seed); call :meth:`start_run` first (blocking; the app calls it in
        a worker thread).

        Raises:
            BayesmapError: if the path has fewer than 2 poses.
        """

        try:
            scene = self._slam_scene()
            problem = self.slam_problem()
            sweeps = self.slam_sweeps()
            result = run_slam(problem, sweeps=sweeps, burn_in=sweeps // 3, seed=self.seed)
            self.progress = 1.0
            run = SlamRun(problem=problem, result=result, sweeps=sweeps,
                          ate_mean=score_trajectory(result.mean_path, problem.true_poses)["ate_rmse_m"],
                          ate_odometry=score_trajectory(problem.odometry, problem.true_poses)["ate_rmse_m"])
            self.slam = run
            self.stale = self._slam_scene() != scene  # poses or settings changed while it ran
            return run
        finally:
            self.running = False

    def slam_text(self) -> str:
        """One line about the last SLAM run (its ATEs), or how to start one."""
        if self.slam is None:
            return (f"path: {len(self.path)} poses (at least 2 needed); Run SLAM does up to {SLAM_MAX_SWEEPS} "
                    "sweeps (about 0.25 s each on the tutorial map)")
        s = self.slam
        return (f"SLAM: {s.problem.num_scans} poses, {s.sweeps} sweeps in {s.result.runtime_s:.1f} s; ATE of the "
                f"posterior mean {s.ate_mean:.3f} m, of the odometry {s.ate_odometry:.3f} m")

    def set_setting(self, name: str, value) -> float | int:
        """Set one of :data:`SETTINGS` after checking it; returns the value set.

        Raises:
            BayesmapError: on an unknown name or a value out of range (nothing changes).
        """
        if name not in SETTINGS:
            raise BayesmapError(f"unknown setting {name!r}")
        number = SETTINGS[name].check(value)
        if number != getattr(self, name):
            setattr(self, name, number)
            if name != "sweeps":
                self._changed()
        return number

    def load_map_text(self, text: str, source: str = "map") -> None:
        """Replace the drawn map by an ASCII map (see :func:`bayesmap.io.ascii.parse_map`); the sensor stays if it is
        still on a free cell inside the new grid, else it moves to the free cell nearest the center.

        Raises:
            BayesmapError: if the text is not a valid map or has no free cell (nothing changes).
        """
        walls = parse_map(text, source=source)
        if max(walls.shape) > 200:
            raise BayesmapError(f"{source}: the explorer draws maps of at most 200 x 200 cells, "
                                f"got {walls.shape[0]} x {walls.shape[1]}")
        old = (self.walls, self.grid, self.pos)
        self.walls, self.grid = walls, Grid(shape=walls.shape)
        try:
            self.pos = self._free_position(self.pos)
        except BayesmapError:
            self.walls, self.grid, self.pos = old
            raise BayesmapError(f"{source}: the map has no free cell to put the sensor in") from None
        self.result = None
        self.stale = False
        self._problem = None
        self.path = []
        self.slam = None

    def map_text(self) -> str:
        """The drawn map in the ASCII format (:func:`bayesmap.io.ascii.format_map`)."""
        return format_map(self.walls)

    @property
    def problem(self) -> Problem:
        """The scene as a :class:`~bayesmap.scenes.Problem`, readings simulated with this session's seed
        (recomputed after every change)."""
        if self._problem is None:
            self._problem = tutorial_problem(self.walls, tuple(self.pos), seed=self.seed,
                                             prior_wall_prob=self.prior_wall_prob, sensor_noise=self.sensor_noise,
                                             num_angles=self.num_angles, source="app")
        return self._problem

    def beams(self) -> tuple[np.ndarray, np.ndarray]:
        """``(hits (K, 2), readings (K, 2))``: world points of each beam's first wall (capped at the max distance) and
        of its noisy range reading, meters (recomputed only when the scene changed)."""
        pb = self.problem
        if self._beams is None or self._beams[0] is not pb:  # computed once per scene, not at every redraw
            exact = np.asarray(sensor_distances(self.walls, pb.pos, pb.beam_angles, pb.grid, pb.params.max_range))
            direction = np.stack([np.cos(pb.beam_angles), np.sin(pb.beam_angles)], axis=-1)
            self._beams = (pb, pb.pos + exact[:, None] * direction, pb.pos + pb.readings[:, None] * direction)
        return self._beams[1], self._beams[2]

    # -- inference ----------------------------------------------------------------------------------------------

    def start_run(self) -> bool:
        """Claim the right to run; False if a run is already going (then nothing must be started)."""
        with self._lock:
            if self.running:
                return False
            self.running = True
            self.runs += 1
            self.progress = 0.0
            return True

    def run(self) -> InferenceResult:
        """Run the fast 2x2 block Gibbs sampler (``sweeps`` sweeps, half burn-in) on the current scene; call
        :meth:`start_run` first (blocking; the app calls it in a worker thread). Updates :attr:`progress`."""
        try:
            problem = self.problem
            result = run_inference(problem, SAMPLER, self.sweeps, seed=self.seed, progress=False,
                                   on_progress=lambda done, total: setattr(self, "progress", done / total))
            if problem is self._problem:
                self.result = result
                self.stale = False
            return result
        finally:
            self.running = False

    def shown(self, sample: int | None) -> np.ndarray | None:
        """``(nx, ny)`` float wall probabilities to draw: the posterior mean (``sample`` None) or sample ``sample``
        (0-based sweep index) of the last run; None without a run. In path mode: the last SLAM run's posterior
        map (``sample`` ignored), or None."""
        if self.path_mode:
            return None if self.slam is None else self.slam.result.posterior
        if self.result is None:
            return None
        if sample is None:
            return self.result.posterior
        index = int(np.clip(sample, 0, len(self.result.samples) - 1))
        return self.result.samples[index].astype(np.float64)

    def status(self) -> str:
        """One line about the scene and the last run."""
        n_walls = int(self.walls.sum())
        if self.path_mode:
            text = f"{n_walls} walls, path of {len(self.path)} poses, {self.num_angles} beams"
            if self.running:
                return text + f"; run {self.runs}: SLAM running ({self.slam_sweeps()} sweeps)"
            if self.slam is not None:
                text += f"; run {self.runs}: SLAM, {self.slam.sweeps} sweeps in {self.slam.result.runtime_s:.2f} s"
                if self.stale:
                    text += " (the scene changed since; run again)"
            return text
        text = f"{n_walls} walls, sensor at ({self.pos[0]:.2f}, {self.pos[1]:.2f}), {self.num_angles} beams"
        if self.running:
            return text + f"; run {self.runs}: {self.progress:.0%} done"
        if self.result is not None:
            s = self.result.summary
            text += f"; run {self.runs}: {s['sweeps']} sweeps in {s['runtime_s']:.2f} s"
            if s.get("wrong_visible_cells") is not None:
                text += f", {s['wrong_visible_cells']} of {s['visible_cells']} visible cells wrong"
            if self.stale:
                text += " (the scene changed since; run again)"
        return text

    # -- drawing ------------------------------------------------------------------------------------------------

    def cell_px(self) -> int:
        """Pixels per cell on the page (about 500 px for the whole grid)."""
        return int(max(3, min(32, 504 // max(self.grid.shape))))

    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` of the drawing in pixels."""
        s = self.cell_px()
        return self.grid.shape[0] * s, self.grid.shape[1] * s

    def to_world(self, px: float, py: float) -> np.ndarray:
        """Image pixel ``(px, py)`` (y down) to world meters (y up)."""
        s = self.cell_px()
        ox, oy = self.grid.origin
        res = self.grid.resolution
        return np.array([ox + px / s * res, oy + (self.grid.shape[1] * s - py) / s * res])

    def _to_px(self, xy) -> tuple[np.ndarray, np.ndarray]:
        s = self.cell_px()
        cc = self.grid.to_cell_coords(np.asarray(xy, dtype=np.float64))
        return (cc[..., 0] + 0.5) * s, (self.grid.shape[1] - 0.5 - cc[..., 1]) * s

    def svg(self, shown: np.ndarray | None = None, heatmap: bool = False) -> str:
        """The SVG content of the drawing: grid, inferred walls ``shown`` (``(nx, ny)`` probabilities, as opacity or
        heatmap), true walls, beams, readings and the sensor. Elements carry classes and ``data-i``/``data-j``
        (and ``data-p`` for inferred cells) so that tests can read the drawing."""
        s = self.cell_px()
        nx, ny = self.grid.shape
        width, height = nx * s, ny * s
        out = [f'<rect x="0" y="0" width="{width}" height="{height}" fill="white" stroke="#999"/>']
        if s >= 8:
            lines = [f"M{i * s} 0V{height}" for i in range(1, nx)] + [f"M0 {j * s}H{width}" for j in range(1, ny)]
            out.append(f'<path d="{" ".join(lines)}" stroke="#eee" stroke-width="1"/>')
        if shown is not None:
            colors = _heat_colors() if heatmap else None
            for i, j in zip(*np.nonzero(shown > 0.005 if not heatmap else np.ones_like(shown, bool))):
                p = float(shown[i, j])
                x, y = i * s, (ny - 1 - j) * s
                if heatmap:
                    style = f'fill="{colors[int(round(p * 255))]}"'
                else:
                    style = f'fill="#d62728" fill-opacity="{p:.3f}"'
                out.append(f'<rect class="inferred" data-i="{i}" data-j="{j}" data-p="{p:.3f}" x="{x}" y="{y}" '
                           f'width="{s}" height="{s}" {style}/>')
        for i, j in zip(*np.nonzero(self.walls > 0.5)):
            x, y = i * s, (ny - 1 - j) * s
            if heatmap and shown is not None:
                out.append(f'<rect class="wall" data-i="{i}" data-j="{j}" x="{x + 1}" y="{y + 1}" width="{s - 2}" '
                           f'height="{s - 2}" fill="none" stroke="black" stroke-width="2"/>')
            else:
                inset = max(1, s // 5) if shown is not None else 0
                out.append(f'<rect class="wall" data-i="{i}" data-j="{j}" x="{x + inset}" y="{y + inset}" '
                           f'width="{s - 2 * inset}" height="{s - 2 * inset}" fill="#333"/>')
        if self.path_mode:
            out.append(self._path_svg())
            return "".join(out)
        hits, readings = self.beams()
        sx, sy = self._to_px(self.pos)
        hx, hy = self._to_px(hits)
        path = " ".join(f"M{sx:.1f} {sy:.1f}L{a:.1f} {b:.1f}" for a, b in zip(hx, hy))
        out.append(f'<path class="beams" d="{path}" stroke="#1f77b4" stroke-opacity="0.35" stroke-width="1"/>')
        rx, ry = self._to_px(readings)
        radius = max(1.5, s / 8)
        out.append('<g class="readings" fill="#1f77b4">'
                   + "".join(f'<circle cx="{a:.1f}" cy="{b:.1f}" r="{radius:.1f}"/>' for a, b in zip(rx, ry)) + "</g>")
        out.append(f'<circle class="sensor" cx="{sx:.1f}" cy="{sy:.1f}" r="{max(4.0, s * 0.4):.1f}" fill="#ff7f0e" '
                   'stroke="black" stroke-width="1.5" style="cursor: grab">'
                   '<title>sensor: drag to move</title></circle>')
        return "".join(out)

    def _path_svg(self) -> str:
        """The path mode's layer: the drawn path (orange) with its numbered poses and headings; after a SLAM run,
        above it, the odometry (grey dashes), the pose samples (small purple dots) and the posterior mean path
        (green)."""
        s = self.cell_px()
        out = []
        if self.path:
            true = self.true_path()
            out.append(_polyline(self, true, "path", 'stroke="#ff7f0e" stroke-width="1.5"'))
            px, py = self._to_px(true[:, :2])
            r = max(4.0, s * 0.35)
            for k, (a, b, t) in enumerate(zip(px, py, true[:, 2])):
                hx, hy = a + 1.6 * r * np.cos(t), b - 1.6 * r * np.sin(t)
                out.append(f'<g class="pose" data-k="{k}"><line x1="{a:.1f}" y1="{b:.1f}" x2="{hx:.1f}" '
                           f'y2="{hy:.1f}" stroke="black" stroke-width="1.5"/><circle cx="{a:.1f}" cy="{b:.1f}" '
                           f'r="{r:.1f}" fill="#ff7f0e" fill-opacity="0.6" stroke="black"/><text x="{a:.1f}" '
                           f'y="{b:.1f}" font-size="{r * 1.3:.0f}" text-anchor="middle" '
                           f'dominant-baseline="central">{k + 1}</text></g>')
        if self.slam is not None:
            res = self.slam.result
            out.append(_polyline(self, self.slam.problem.odometry, "odometry",
                                 'stroke="#777" stroke-width="2" stroke-dasharray="5 3"'))
            samples = res.pose_samples[:: max(1, len(res.pose_samples) // 100)].reshape(-1, 3)
            sx, sy = self._to_px(samples[:, :2])
            out.append('<g class="pose-samples" fill="#9467bd" fill-opacity="0.5">' + "".join(
                f'<circle class="pose-sample" cx="{a:.1f}" cy="{b:.1f}" r="2"/>' for a, b in zip(sx, sy)) + "</g>")
            out.append(_polyline(self, res.mean_path, "mean-path", 'stroke="#2ca02c" stroke-width="2"'))
        return "".join(out)


def _polyline(explorer: Explorer, xy, cls: str, style: str) -> str:
    """An SVG polyline of world points ``xy`` ``(S, 2+)`` (meters) with class ``cls``."""
    px, py = explorer._to_px(np.asarray(xy, dtype=np.float64)[:, :2])
    points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(px, py))
    return f'<polyline class="{cls}" points="{points}" fill="none" {style}/>'


def _heat_colors() -> list[str]:
    """256 hex colors of matplotlib's "viridis" colormap, for probabilities 0..1."""
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    cmap = colormaps["viridis"]
    return [to_hex(cmap(k / 255)) for k in range(256)]


def _legend_gradient(heatmap: bool) -> str:
    """CSS gradient of the drawing's colour scale for probabilities 0..1 (heatmap, or red opacity on white)."""
    if heatmap:
        colors = _heat_colors()
        return "linear-gradient(to right, " + ", ".join(colors[k] for k in range(0, 256, 51)) + ")"
    return "linear-gradient(to right, rgba(214, 39, 40, 0), rgba(214, 39, 40, 1))"


# -- NiceGUI ---------------------------------------------------------------------------------------------------


class ExplorerPage:
    """The NiceGUI page of one :class:`Explorer`: the header, the map panel, the controls panel, and the handlers
    that connect them to the explorer. Build it inside a NiceGUI page function (it creates its elements in the
    current client); :func:`build_page` does.

    Args:
        explorer: the session's state; default a new :class:`Explorer` of the tutorial's scene.

    Attributes:
        ex: the explorer.
        image: the drawing (an ``interactive_image`` whose content is :meth:`Explorer.svg`).
    """

    def __init__(self, explorer: Explorer | None = None):
        from nicegui import ui

        self.ui = ui
        self.ex = explorer or Explorer()
        self.drag = {"mode": None, "paint": None, "last": None}
        self._build_header()
        with ui.row().classes("items-start no-wrap gap-6"):
            self._build_map_panel()
            with ui.column().classes("gap-1").style("min-width: 360px"):
                self._build_settings()
                self._build_run_controls()
                self._build_path_controls()
                self._build_view_controls()
                self._build_file_controls()
        self._connect()
        self.redraw()

    # -- the elements, top to bottom and left to right ---------------------------------------------------------

    def _build_header(self) -> None:
        """Title, instructions and the line where errors are shown."""
        ui = self.ui
        ui.page_title("bayesmap explorer")
        ui.label("bayesmap: Bayesian occupancy-grid mapping").classes("text-h5")
        ui.label("Click a cell to toggle a wall, drag to paint, drag the orange sensor to move it. Run inference "
                 "to infer the walls from the beams' noisy range readings. In path mode, clicks on free cells add "
                 "poses to a path and Run SLAM infers the path and the map from simulated odometry and readings "
                 "(green: posterior mean path, dots: pose samples, grey dashes: odometry).").classes(
            "text-body2 text-grey-8")
        self.message = ui.label("").classes("bm-message text-negative text-body1")

    def _build_map_panel(self) -> None:
        """The drawing, the colour scale of the inferred walls and the status line."""
        ui = self.ui
        width, height = self.ex.image_size()
        with ui.column().style(f"width: {width}px") as self.left:
            self.image = ui.interactive_image(size=(width, height), content="", cross=False, sanitize=False,
                                              events=["mousedown", "mousemove", "mouseup", "mouseleave"])
            self.image.classes("bm-map").style(f"width: {width}px; height: {height}px; cursor: crosshair")
            with ui.row().classes("items-center no-wrap gap-2"):
                ui.label("inferred wall probability: 0").classes("text-caption")
                self.legend = (ui.element("div").classes("bm-legend")
                               .style("width: 160px; height: 12px; border: 1px solid #999"))
                ui.label("1").classes("text-caption")
            self.status = ui.label("").classes("bm-status text-body2")

    def _build_settings(self) -> None:
        """One slider and one text field per setting of :data:`SETTINGS`."""
        ui = self.ui
        self.fields = {}
        for name, setting in SETTINGS.items():
            with ui.row().classes("items-center no-wrap w-full"):
                ui.label(setting.label).classes("w-40")
                slider = ui.slider(min=setting.low, max=setting.high, step=setting.step,
                                   value=getattr(self.ex, name)).classes(f"bm-slider-{name} w-40")
                number = ui.input(value=str(getattr(self.ex, name))).classes(f"bm-field-{name} w-20").props("dense")
            self.fields[name] = (slider, number)

    def _build_run_controls(self) -> None:
        """Run inference, Clear walls, Clear inferred walls, and the progress bar of a run."""
        ui, ex = self.ui, self.ex
        with ui.row():
            self.run_button = ui.button("Run inference").classes("bm-run")
            (ui.button("Clear walls", on_click=lambda: (ex.clear_walls(), self.redraw()))
             .classes("bm-clear-walls").props("outline"))
            (ui.button("Clear inferred walls", on_click=lambda: (ex.clear_inferred(), self.redraw()))
             .classes("bm-clear-inferred").props("outline"))
        self.progress = ui.linear_progress(value=0.0, show_value=False).classes("bm-progress")
        self.progress.set_visibility(False)

    def _build_path_controls(self) -> None:
        """The path mode switch, Clear path, and the line with the last SLAM run's ATEs."""
        ui = self.ui
        ui.separator()
        with ui.row().classes("items-center"):
            self.path_switch = ui.switch("path mode (clicks add poses; Run SLAM)", value=False).classes("bm-path-mode")
            self.clear_path_button = (ui.button("Clear path", on_click=lambda: (self.ex.clear_path(), self.redraw()))
                                      .classes("bm-clear-path").props("outline"))
        self.slam_label = ui.label("").classes("bm-slam text-body2")

    def _build_view_controls(self) -> None:
        """What to show after a run: the average or one sample, as opacity or heatmap."""
        ui = self.ui
        ui.separator()
        self.average = ui.switch("show average", value=True).classes("bm-average")
        with ui.row().classes("items-center no-wrap w-full"):
            ui.label("sample").classes("w-16")
            self.sample_slider = ui.slider(min=1, max=2, step=1, value=1).classes("bm-sample w-56").props("label")
            self.sample_label = ui.label("").classes("bm-sample-label")
        self.heat = ui.toggle(["opacity", "heatmap"], value="opacity").classes("bm-style")

    def _build_file_controls(self) -> None:
        """Load an ASCII map file, save the drawn map."""
        ui, ex = self.ui, self.ex
        ui.separator()
        ui.label("Map file (ASCII: 'X' wall, '.' free; line i, column j is cell (i, j))").classes("text-caption")
        with ui.row().classes("items-center"):
            self.upload = (ui.upload(label="Load map", auto_upload=True, max_files=1)
                           .classes("bm-upload").props("accept=.txt,text/plain flat bordered"))
            (ui.button("Save map", on_click=lambda: ui.download.content(ex.map_text().encode(), "map.txt"))
             .classes("bm-save").props("outline"))

    def _connect(self) -> None:
        """Wire the elements' events to the handlers below."""
        self.image.on_mouse(self.on_mouse)
        for name, (slider, number) in self.fields.items():
            slider.on_value_change(lambda e, n=name, s=slider: self.apply_setting(n, e.value, s))
            number.on("keydown.enter", lambda _e, n=name, f=number: self.apply_setting(n, f.value, f))
            number.on("blur", lambda _e, n=name, f=number: self.apply_setting(n, f.value, f))
        self.run_button.on_click(self.run_clicked)
        self.path_switch.on_value_change(lambda e: (self.ex.set_path_mode(e.value), self.clear_error(), self.redraw()))
        self.average.on_value_change(lambda _e: self.redraw())
        self.sample_slider.on_value_change(lambda _e: self.redraw())
        self.heat.on_value_change(lambda _e: self.redraw())
        self.upload.on_upload(self.on_upload)

    # -- handlers ------------------------------------------------------------------------------------------------

    def show_error(self, text: str) -> None:
        """Show ``text`` on the error line and as a notification."""
        self.message.set_text(text)
        self.ui.notify(text, type="negative")

    def clear_error(self) -> None:
        """Empty the error line."""
        self.message.set_text("")

    def redraw(self) -> None:
        """Redraw the map, the colour scale, the sample controls and the status line from the explorer's state."""
        ex = self.ex
        result_on = ex.result is not None
        shown = ex.shown(None if (self.average.value or not result_on) else int(self.sample_slider.value) - 1)
        self.image.content = ex.svg(shown, heatmap=self.heat.value == "heatmap")
        self.legend.style(f"background: {_legend_gradient(self.heat.value == 'heatmap')}")
        self.run_button.set_text("Run SLAM" if ex.path_mode else "Run inference")
        self.clear_path_button.set_visibility(ex.path_mode)
        self.slam_label.set_visibility(ex.path_mode)
        self.slam_label.set_text(ex.slam_text())
        self.sample_slider.set_enabled(result_on and not self.average.value and not ex.path_mode)
        if ex.path_mode:
            self.sample_label.set_text("path mode: the SLAM posterior's average")
        elif result_on:
            n = len(ex.result.samples)
            self.sample_slider.props(f"max={n}")
            self.sample_label.set_text("average of sweeps %d-%d" % (ex.result.summary["burn_in"] + 1, n)
                                       if self.average.value else f"sweep {int(self.sample_slider.value)} of {n}")
        else:
            self.sample_label.set_text("no inference yet")
        self.status.set_text(ex.status())

    def on_mouse(self, e) -> None:
        """Mouse down on the sensor starts moving it, elsewhere toggles the cell and starts painting; moves with the
        button held move the sensor or paint; button up or leaving the drawing ends the drag."""
        ex, drag = self.ex, self.drag
        xy = ex.to_world(e.image_x, e.image_y)
        if ex.path_mode:
            if e.type == "mousedown":
                self.add_pose(xy)
            return
        if e.type == "mousedown":
            self.clear_error()
            if np.hypot(*(xy - ex.pos)) <= 0.6 * ex.grid.resolution:
                drag["mode"] = "sensor"
                return
            cell = ex.cell_at(xy)
            if cell is None:
                return
            new = ex.toggle(cell)
            drag["mode"] = "paint" if new is not None else None
            drag["paint"], drag["last"] = new, cell
            self.redraw()
        elif e.type == "mousemove" and drag["mode"] and (e.buttons & 1):
            if drag["mode"] == "sensor":
                if ex.move_sensor(xy):
                    self.redraw()
            else:
                cell = ex.cell_at(xy)
                if cell is not None and cell != drag["last"]:
                    drag["last"] = cell
                    ex.set_wall(cell, drag["paint"])
                    self.redraw()
        elif e.type in ("mouseup", "mouseleave") or not (e.buttons & 1):
            drag["mode"] = None

    def add_pose(self, xy) -> None:
        """Path mode: append the clicked cell to the path; a wall cell shows a message and changes nothing."""
        cell = self.ex.cell_at(xy)
        if cell is None:
            return
        try:
            self.ex.add_pose(cell)
        except BayesmapError as err:
            self.show_error(str(err))
            return
        self.clear_error()
        self.redraw()

    def apply_setting(self, name: str, value, source) -> None:
        """Set ``name`` from its slider or text field (``source``) and sync the other one; a bad value is shown
        as an error and the field is reset."""
        slider, number = self.fields[name]
        try:
            value = self.ex.set_setting(name, value)
        except BayesmapError as err:
            self.show_error(str(err))
            number.value = str(getattr(self.ex, name))
            return
        self.clear_error()
        if source is not slider and slider.value != value:
            slider.value = value
        if source is not number:
            number.value = str(value)
        self.redraw()

    async def run_clicked(self) -> None:
        """Run inference (in path mode: SLAM) in a worker thread with a progress bar (a click while a run is going
        only warns). SLAM reports no progress while it runs: its bar is indeterminate."""
        from nicegui import run

        ui, ex = self.ui, self.ex
        slam = ex.path_mode
        if slam and len(ex.path) < 2:
            self.show_error(f"the path needs at least 2 poses, it has {len(ex.path)}: click free cells to add poses")
            return
        if not ex.start_run():
            ui.notify("inference is already running", type="warning")
            return
        self.clear_error()
        self.run_button.disable()
        self.path_switch.disable()
        self.progress.set_visibility(True)
        self.progress.value = 0.0
        if slam:
            self.progress.props("indeterminate")
        poll = ui.timer(0.1, lambda: (self.progress.set_value(ex.progress), self.status.set_text(ex.status())))
        try:
            await run.io_bound(ex.run_slam if slam else ex.run)
        except BayesmapError as err:
            self.show_error(str(err))
        finally:
            poll.cancel()
            self.run_button.enable()
            self.path_switch.enable()
            self.progress.props(remove="indeterminate")
            self.progress.set_visibility(False)
            if ex.result is not None:
                self.sample_slider.value = len(ex.result.samples)
            self.redraw()

    async def on_upload(self, e) -> None:
        """Load an uploaded ASCII map and resize the drawing to it (errors shown, the map unchanged)."""
        ex = self.ex
        name = e.file.name or "uploaded file"
        try:
            data = await e.file.read()
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError:
                raise BayesmapError(f"{name}: not a text file (expected an ASCII map of 'X' and '.')") from None
            ex.load_map_text(text, source=name)
        except BayesmapError as err:
            self.show_error(str(err))
        else:
            self.clear_error()
            width, height = ex.image_size()
            self.image._props["size"] = (width, height)
            self.image.update()
            self.image.style(f"width: {width}px; height: {height}px")
            self.left.style(f"width: {width}px")
            self.redraw()
            self.ui.notify(f"loaded {name}: {ex.grid.shape[0]} x {ex.grid.shape[1]} cells")
        finally:
            self.upload.reset()


def build_page(explorer: Explorer | None = None) -> Explorer:
    """Build the explorer's page (an :class:`ExplorerPage`) for the current NiceGUI client (one :class:`Explorer`
    per browser tab).

    Returns the page's explorer."""
    return ExplorerPage(explorer).ex


def run_app(host: str = "127.0.0.1", port: int = 8080, show: bool = True) -> None:
    """Serve the explorer at ``http://host:port/`` until interrupted (blocking).

    Args:
        host: interface to listen on (default only this machine).
        port: TCP port.
        show: open the page in the default browser.

    Raises:
        BayesmapError: if the port cannot be used (in use, or not in 1..65535).
    """
    import socket

    if not (1 <= int(port) <= 65535):
        raise BayesmapError(f"port must be between 1 and 65535, got {port!r}")
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, int(port)))
        except OSError as err:
            raise BayesmapError(f"cannot listen on {host}:{port}: {err.strerror}") from None
    from nicegui import ui

    ui.run(build_page, host=host, port=int(port), show=show, reload=False, title="bayesmap explorer",
           show_welcome_message=True, uvicorn_logging_level="warning")
