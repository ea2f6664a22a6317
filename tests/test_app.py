"""The explorer's logic (bayesmap.app.Explorer) without a browser, and `bayesmap app`'s argument errors."""

from __future__ import annotations

import re
import socket
import subprocess
import sys

import numpy as np
import pytest

from bayesmap.app import SETTINGS, Explorer
from bayesmap.errors import BayesmapError
from bayesmap.io.ascii import format_map, tutorial_map


def test_starts_from_the_tutorial_scene():
    ex = Explorer()
    assert np.array_equal(ex.walls, tutorial_map())
    assert tuple(ex.pos) == (10.0, 10.0)
    # the readings are the tutorial's (seed 0): the same problem as the CLI's demo
    from bayesmap.scenes import tutorial_problem

    assert np.array_equal(ex.problem.readings, tutorial_problem().readings)


def test_toggle_paint_and_the_sensor_cell():
    ex = Explorer()
    free = (12, 10)
    assert ex.walls[free] == 0
    assert ex.toggle(free) is True and ex.walls[free] == 1
    assert ex.toggle(free) is False and ex.walls[free] == 0
    assert ex.set_wall((10, 10), True) is False and ex.walls[10, 10] == 0  # the sensor's cell
    assert ex.toggle((10, 10)) is None
    assert ex.set_wall((21, 0), True) is False  # outside the grid
    ex.clear_walls()
    assert ex.walls.sum() == 0


def test_sensor_moves_only_to_free_points_inside():
    ex = Explorer()
    wall = tuple(np.argwhere(ex.walls > 0)[0])
    assert not ex.move_sensor(np.array(wall, float))
    assert not ex.move_sensor((25.0, 3.0))
    assert not ex.move_sensor((np.nan, 3.0))
    assert tuple(ex.pos) == (10.0, 10.0)
    assert ex.move_sensor((11.3, 8.7))
    assert ex.sensor_cell() == (11, 9)
    np.testing.assert_allclose(ex.problem.pos, [11.3, 8.7])


def test_settings_are_checked_and_bad_values_change_nothing():
    ex = Explorer()
    readings = ex.problem.readings.copy()
    for name, value, words in [("prior_wall_prob", 1.5, "between 0.01 and 0.99, got 1.5"),
                               ("sensor_noise", 0, "between 0.01 and 2, got 0"),
                               ("num_angles", "ten", "'ten' is not a number"),
                               ("num_angles", 2.5, "whole number, got 2.5"),
                               ("sweeps", float("inf"), "between 10 and 2000")]:
        with pytest.raises(BayesmapError, match=re.escape(words)):
            ex.set_setting(name, value)
    with pytest.raises(BayesmapError, match="unknown setting"):
        ex.set_setting("resolution", 1)
    assert (ex.prior_wall_prob, ex.sensor_noise, ex.num_angles, ex.sweeps) == (0.5, 0.2, 100, 100)
    assert np.array_equal(ex.problem.readings, readings)
    assert ex.set_setting("num_angles", "40") == 40
    assert ex.problem.readings.shape == (40,)
    assert all(s.low < s.high for s in SETTINGS.values())


def test_load_map_text_replaces_the_map_or_changes_nothing():
    ex = Explorer()
    before = ex.walls.copy()
    with pytest.raises(BayesmapError, match=r"room.txt: unknown character '\?'"):
        ex.load_map_text("XX\nX?\n", "room.txt")
    with pytest.raises(BayesmapError, match="no free cell"):
        ex.load_map_text("XX\nXX\n", "full.txt")
    with pytest.raises(BayesmapError, match="at most 200 x 200"):
        ex.load_map_text(("." * 201 + "\n") * 3, "huge.txt")
    assert np.array_equal(ex.walls, before) and ex.grid.shape == (21, 21) and tuple(ex.pos) == (10.0, 10.0)

    text = "XXXXXXX\nX.....X\nX.....X\nX.....X\nXXXXXXX\n"
    ex.load_map_text(text, "room.txt")
    assert ex.grid.shape == (5, 7)
    assert tuple(ex.pos) == (2.0, 3.0)  # (10, 10) is outside: the free cell nearest the center
    assert ex.map_text() == text == format_map(ex.walls)
    assert ex.image_size() == (5 * ex.cell_px(), 7 * ex.cell_px())


def test_pixels_and_world_agree():
    ex = Explorer()
    s = ex.cell_px()
    # the center of cell (i, j) is at pixel ((i + 0.5) s, (ny - 1 - j + 0.5) s): y grows up in the world, down on screen
    np.testing.assert_allclose(ex.to_world(3.5 * s, (21 - 1 - 7 + 0.5) * s), [3.0, 7.0])
    px, py = ex.to_px(np.array([3.0, 7.0]))
    assert (px, py) == (3.5 * s, 13.5 * s)


def test_svg_draws_walls_beams_readings_and_inferred_cells():
    ex = Explorer()
    svg = ex.svg()
    assert svg.count('class="wall"') == int(ex.walls.sum())
    assert len(re.findall(r"<circle cx", svg)) == 100  # one reading per beam
    assert svg.count('class="inferred"') == 0
    shown = np.zeros(ex.grid.shape)
    shown[2, 3], shown[4, 5] = 0.25, 1.0
    svg = ex.svg(shown)
    cells = re.findall(r'class="inferred" data-i="(\d+)" data-j="(\d+)" data-p="([\d.]+)"', svg)
    assert sorted(cells) == [("2", "3", "0.250"), ("4", "5", "1.000")]
    heat = ex.svg(shown, heatmap=True)
    assert heat.count('class="inferred"') == 21 * 21  # the heatmap colours every cell


def test_run_guard_result_and_staleness():
    ex = Explorer()
    assert ex.start_run()
    assert not ex.start_run()  # a second run cannot start while one is going
    result = ex.run()
    assert not ex.running and ex.runs == 1 and ex.progress == 1.0
    assert result.summary["sweeps"] == 100 and result.summary["sampler"] == "block"
    # the tutorial scene: the block sampler gets all but at most 2 of the 217 visible cells right
    assert result.summary["wrong_visible_cells"] <= 2
    assert np.array_equal(ex.shown(None), result.posterior)
    assert set(np.unique(ex.shown(99))) <= {0.0, 1.0}
    assert ex.shown(10_000).shape == (21, 21)  # clipped to the last sample
    assert not ex.stale and "run 1: 100 sweeps" in ex.status()
    ex.toggle((12, 10))
    assert ex.stale and "run again" in ex.status()
    ex.clear_inferred()
    assert ex.shown(None) is None and ex.start_run()


def test_cli_app_rejects_bad_port_in_one_line():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        for args, words in ([["--port", "0"], "port must be between 1 and 65535, got 0"],
                            [["--port", str(port)], f"cannot listen on 127.0.0.1:{port}"]):
            out = subprocess.run([sys.executable, "-m", "bayesmap.cli", "app", "--no-browser", *args],
                                 capture_output=True, text=True, timeout=120)
            assert out.returncode == 2, out.stderr
            assert len(out.stderr.strip().splitlines()) == 1 and out.stderr.startswith("error: ")
            assert words in out.stderr


# -- path mode: a drawn path, simulated odometry and readings, joint SLAM -----------------------------------------


def test_path_building_refuses_walls_and_repeats():
    ex = Explorer()
    ex.set_path_mode(True)
    ex.add_pose((4, 6))
    ex.add_pose((10, 10))
    with pytest.raises(BayesmapError, match=r"cell \(2, 1\) is a wall"):
        ex.add_pose((2, 1))
    with pytest.raises(BayesmapError, match=r"cell \(10, 10\) is already"):
        ex.add_pose((10, 10))
    with pytest.raises(BayesmapError, match=r"cell \(21, 3\) is outside"):
        ex.add_pose((21, 3))
    ex.add_pose((10, 14))
    assert np.array_equal(ex.walls, tutorial_map())  # nothing was drawn
    # headings point to the next pose; the last pose keeps the last step's heading
    np.testing.assert_allclose(ex.true_path(), [[4, 6, np.arctan2(4, 6)], [10, 10, np.pi / 2], [10, 14, np.pi / 2]])
    ex.clear_path()
    assert ex.path == [] and ex.true_path().shape == (0, 3)


def test_slam_scene_needs_two_poses_and_uses_the_settings():
    ex = Explorer()
    ex.set_path_mode(True)
    ex.add_pose((4, 6))
    assert ex.start_run()  # claim a run: a refused scene must still release it
    with pytest.raises(BayesmapError, match="at least 2 poses, it has 1"):
        ex.run_slam()
    assert not ex.running and ex.slam is None
    ex.clear_path()
    ex.add_pose((8, 8))
    ex.add_pose((14, 8))
    ex.set_setting("num_angles", 24)
    ex.set_setting("sensor_noise", 0.2)
    pb = ex.slam_problem()
    from bayesmap.slam.problem import SLAM_ODOMETRY_ALPHAS, simulate_odometry

    assert pb.readings.shape == pb.sensor_angles.shape == (2, 24)
    assert pb.params.sensor_noise == pytest.approx(0.2)
    np.testing.assert_array_equal(pb.true_poses, ex.true_path())
    np.testing.assert_array_equal(pb.odometry, simulate_odometry(ex.true_path(), SLAM_ODOMETRY_ALPHAS, ex.seed))
    # the readings are simulated at the true poses, beams relative to the heading (+x here): the beam straight
    # ahead of the first pose reads about the 8.5 m to the wall at x = 17 (noise 0.2 m: 5 sigma)
    ahead = np.argmin(np.abs(pb.sensor_angles[0]))
    assert pb.sensor_angles[0, ahead] == 0.0 and abs(pb.readings[0, ahead] - 8.5) < 1.0
    assert ex.slam_sweeps() == 100 and (ex.set_setting("sweeps", 2000), ex.slam_sweeps())[1] == 200


def test_slam_run_on_a_three_pose_path():
    ex = Explorer()
    ex.set_path_mode(True)
    for cell in [(4, 6), (10, 10), (14, 14)]:
        ex.add_pose(cell)
    ex.set_setting("sweeps", 10)
    assert ex.start_run() and not ex.start_run()
    run = ex.run_slam()
    assert not ex.running and ex.slam is run and not ex.stale
    res = run.result
    assert run.sweeps == 10
    assert res.pose_samples.shape == (10 - 10 // 3, 3, 3) and res.mean_path.shape == (3, 3)
    assert res.posterior.shape == (21, 21) and np.array_equal(ex.shown(None), res.posterior)
    np.testing.assert_allclose(res.pose_samples[:, 0], np.broadcast_to(ex.true_path()[0], (7, 3)), atol=1e-6)  # fixed
    # the joint chain beats the odometry it starts from (seed 0: 0.02 m against 0.20 m); the map is nearly right
    assert run.ate_mean < 0.5 * run.ate_odometry
    assert np.sum((res.posterior > 0.5) != (ex.walls > 0)) <= 20
    assert "ATE of the posterior mean" in ex.slam_text()
    svg = ex.svg(ex.shown(None))
    assert svg.count('class="pose"') == 3 and svg.count('class="pose-sample"') == 7 * 3
    assert 'class="mean-path"' in svg and 'class="odometry"' in svg and 'class="sensor"' not in svg
    ex.add_pose((12, 10))
    assert ex.stale and "run again" in ex.status()
    ex.set_path_mode(False)
    assert 'class="sensor"' in ex.svg(ex.shown(None)) and ex.shown(None) is None  # the map mode is untouched
