"""The explorer's state, without a browser: one :class:`Explorer` per browser tab (a session).

It holds the drawn map, the sensor, the settings, the simulated readings and the last runs; it runs inference and
SLAM through the runs layer (:func:`bayesmap.runs.infer.run_infer`, :func:`bayesmap.runs.slam.run_simulated_slam`),
reporting their progress into :attr:`Explorer.progress`; it draws itself as SVG (:mod:`bayesmap.app.svg`). The
NiceGUI page (:mod:`bayesmap.app.page`) only wires elements to it, so everything here is tested without a browser.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from bayesmap import scenes
from bayesmap.app.svg import draw
from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.geometry.raycast import sensor_distances
from bayesmap.inference.driver import DEFAULT_SWEEPS, InferenceResult
from bayesmap.io.ascii import format_map, parse_map, tutorial_map
from bayesmap.model.generative import make_params
from bayesmap.progress import Progress
from bayesmap.runs.infer import run_infer
from bayesmap.runs.slam import run_simulated_slam
from bayesmap.scenes import TUTORIAL_POS, Problem, tutorial_problem
from bayesmap.slam.joint import SlamResult
from bayesmap.slam.problem import SlamProblem, simulated_slam_problem

SAMPLER = "block"
"""The app's sampler: 2x2 block Gibbs, ``bayesmap infer``'s default for a map (one scan)."""

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
    result: SlamResult
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
        progress: fraction of the current run's work done, in [0, 1] (1 after a run).
        progress_known: True once the current run has reported work done (before that, compilation or a stage that
            reports no steps: the app shows a bar without a fraction).

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
        self.progress_known = False
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

    # -- path mode: a drawn path, simulated odometry and readings, joint SLAM ----------------------------------

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
        first third burn-in, seed = this session's seed) through :func:`bayesmap.runs.slam.run_simulated_slam`;
        call :meth:`start_run` first (blocking; the app calls it in a worker thread). Updates :attr:`progress`.

        Raises:
            BayesmapError: if the path has fewer than 2 poses.
        """

        try:
            scene = self._slam_scene()
            problem = self.slam_problem()
            sweeps = self.slam_sweeps()
            done = run_simulated_slam(problem, sweeps, sweeps // 3, self.seed, progress=self._report)
            run = SlamRun(problem=problem, result=done.result, sweeps=sweeps,
                          ate_mean=done.summary["posterior"]["ate_rmse_m"],
                          ate_odometry=done.summary["odometry"]["ate_rmse_m"])
            self.slam = run
            self.stale = self._slam_scene() != scene  # poses or settings changed while it ran
            return run
        finally:
            self._finish()

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
            self.progress_known = False
            return True

    def _report(self, p: Progress) -> None:
        """The runs' progress callback (called from the worker thread): the fraction of the stage done."""
        self.progress = p.done / p.total
        self.progress_known = self.progress_known or p.done > 0

    def _finish(self) -> None:
        """End a run (done or failed): a full bar, and the right to run again."""
        self.progress = 1.0
        self.progress_known = True
        self.running = False

    def run(self) -> InferenceResult:
        """Run the fast 2x2 block Gibbs sampler (``sweeps`` sweeps, half burn-in) on the current scene through
        :func:`bayesmap.runs.infer.run_infer`; call :meth:`start_run` first (blocking; the app calls it in a worker
        thread). Updates :attr:`progress`."""
        try:
            problem = self.problem
            result = run_infer(problem, sampler=SAMPLER, sweeps=self.sweeps, seed=self.seed,
                               progress=self._report).result
            if problem is self._problem:
                self.result = result
                self.stale = False
            return result
        finally:
            self._finish()

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
                done = f", {self.progress:.0%} done" if self.progress_known else ""
                return text + f"; run {self.runs}: SLAM running ({self.slam_sweeps()} sweeps{done})"
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

    def to_px(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """World points ``xy`` ``(..., 2)`` (meters, y up) to image pixels ``(px, py)`` (y down), each ``(...)``."""
        s = self.cell_px()
        cc = self.grid.to_cell_coords(np.asarray(xy, dtype=np.float64))
        return (cc[..., 0] + 0.5) * s, (self.grid.shape[1] - 0.5 - cc[..., 1]) * s

    def svg(self, shown: np.ndarray | None = None, heatmap: bool = False) -> str:
        """The SVG content of the drawing (:func:`bayesmap.app.svg.draw`): grid, inferred walls ``shown``
        (``(nx, ny)`` probabilities, as opacity or heatmap), true walls, and the beams, readings and sensor (or, in
        path mode, the path and the last SLAM run)."""
        return draw(self, shown, heatmap)
