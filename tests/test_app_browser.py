"""The explorer app in a real browser: Debian's chromium driven by Playwright, against `bayesmap app` on a free port.

Every request that does not go to the app's own 127.0.0.1 address is aborted and recorded; the tests assert none
was attempted. Screenshots go to test-artifacts/ (app-before.png, app-after.png).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

playwright_api = pytest.importorskip("playwright.sync_api")

CHROMIUM = "/usr/bin/chromium"
ARTIFACTS = Path(__file__).resolve().parent.parent / "test-artifacts"
TUTORIAL_WALLS = 54  # walls of the built-in tutorial map

pytestmark = [
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason="Debian's chromium is not installed (make installs it)"),
    pytest.mark.xdist_group("app"),
]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def app_url():
    port = _free_port()
    ARTIFACTS.mkdir(exist_ok=True)
    log = open(ARTIFACTS / "app-server.log", "w")
    # NiceGUI switches to its own test mode when it sees pytest's variable: the app must run as a user runs it
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
    proc = subprocess.Popen([sys.executable, "-m", "bayesmap.cli", "app", "--port", str(port), "--no-browser"],
                            stdout=log, stderr=subprocess.STDOUT, env=env)
    deadline = time.time() + 120
    while time.time() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"bayesmap app exited with code {proc.returncode}; see test-artifacts/app-server.log")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                break
        except OSError:
            time.sleep(0.3)
    else:
        proc.kill()
        pytest.fail("bayesmap app did not start listening within 120 s")
    yield f"http://127.0.0.1:{port}/"
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.close()


@pytest.fixture(scope="module")
def browser():
    with playwright_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def open_page(browser, app_url):
    """Open a new page (a new session) on the app; requests off 127.0.0.1 are aborted and recorded."""
    blocked: list[str] = []
    contexts = []

    def _open():
        context = browser.new_context(viewport={"width": 1200, "height": 900}, accept_downloads=True)
        contexts.append(context)
        page = context.new_page()

        def route(r):
            if r.request.url.startswith(app_url) or r.request.url.startswith(app_url.replace("http", "ws")):
                r.continue_()
            else:
                blocked.append(r.request.url)
                r.abort()

        page.route("**/*", route)
        page.goto(app_url)
        page.wait_for_selector(".bm-map svg circle.sensor")
        return page

    yield _open
    for c in contexts:
        c.close()
    assert blocked == [], f"the app tried to reach the network: {blocked}"


# -- helpers reading and driving the drawing -----------------------------------------------------------------------


def _walls(page) -> set[tuple[int, int]]:
    return {tuple(v) for v in page.eval_on_selector_all(
        ".bm-map svg rect.wall", "els => els.map(e => [+e.dataset.i, +e.dataset.j])")}


def _inferred(page) -> dict[tuple[int, int], float]:
    rows = page.eval_on_selector_all(
        ".bm-map svg rect.inferred", "els => els.map(e => [+e.dataset.i, +e.dataset.j, +e.dataset.p])")
    return {(i, j): p for i, j, p in rows}


def _sensor_px(page) -> tuple[float, float]:
    box = page.locator(".bm-map").bounding_box()
    cx, cy = page.eval_on_selector(".bm-map svg circle.sensor", "e => [+e.getAttribute('cx'), +e.getAttribute('cy')]")
    return box["x"] + cx, box["y"] + cy


def _cell_px(page, i: int, j: int, n: int = 21) -> tuple[float, float]:
    """Page pixel of the center of cell (i, j) of an n x n grid (y up on the page)."""
    box = page.locator(".bm-map").bounding_box()
    s = box["width"] / n
    return box["x"] + (i + 0.5) * s, box["y"] + (n - 1 - j + 0.5) * s


def _wait_walls(page, count: int) -> None:
    page.wait_for_function(f"() => document.querySelectorAll('.bm-map svg rect.wall').length === {count}",
                           timeout=10000)


def _status(page) -> str:
    return page.inner_text(".bm-status")


# -- the tests --------------------------------------------------------------------------------------------------------


def test_draw_drag_sensor_and_infer(open_page):
    page = open_page()
    assert len(_walls(page)) == TUTORIAL_WALLS
    page.click(".bm-clear-walls")
    _wait_walls(page, 0)

    # a wall by clicking cells: x = 15, y = 5..15
    drawn = {(15, j) for j in range(5, 16)}
    for k, (i, j) in enumerate(sorted(drawn)):
        page.mouse.click(*_cell_px(page, i, j))
        _wait_walls(page, k + 1)
    # a wall by click-and-drag: y = 4, x = 6..15 (one press, moves through the cells, release)
    page.mouse.move(*_cell_px(page, 6, 4))
    page.mouse.down()
    for i in range(7, 16):
        page.mouse.move(*_cell_px(page, i, 4), steps=3)
    page.mouse.up()
    painted = {(i, 4) for i in range(6, 16)}
    _wait_walls(page, len(drawn | painted))
    assert _walls(page) == drawn | painted

    # clicking a wall again removes it; clicking it once more puts it back
    page.mouse.click(*_cell_px(page, 15, 10))
    _wait_walls(page, len(drawn | painted) - 1)
    assert (15, 10) not in _walls(page)
    page.mouse.click(*_cell_px(page, 15, 10))
    _wait_walls(page, len(drawn | painted))

    # no wall can be drawn on the sensor's cell (a click near its corner, away from the sensor handle)
    x, y = _cell_px(page, 10, 10)
    s = page.locator(".bm-map").bounding_box()["width"] / 21
    page.mouse.click(x + 0.45 * s, y - 0.45 * s)
    page.wait_for_timeout(300)
    assert (10, 10) not in _walls(page)

    # drag the sensor from (10, 10) to (11, 9)
    before = _sensor_px(page)
    target = _cell_px(page, 11, 9)
    page.mouse.move(*before)
    page.mouse.down()
    page.mouse.move(*target, steps=8)
    page.mouse.up()
    page.wait_for_function("() => document.querySelector('.bm-status').innerText.includes('sensor at (11.00, 9.00)')",
                           timeout=10000)
    after = _sensor_px(page)
    assert abs(after[0] - target[0]) < 2 and abs(after[1] - target[1]) < 2
    assert _walls(page) == drawn | painted  # dragging the sensor drew nothing

    page.screenshot(path=str(ARTIFACTS / "app-before.png"))
    page.click(".bm-run")
    page.wait_for_function("() => document.querySelector('.bm-status').innerText.includes('sweeps in')", timeout=120000)
    inferred = _inferred(page)
    page.screenshot(path=str(ARTIFACTS / "app-after.png"))

    # every drawn wall cell that a beam reaches is inferred a wall, and free space on the way to it is free (the
    # corner (15, 4) is hidden behind its neighbours from (11, 9): no beam reaches it, it stays at the prior)
    import numpy as np

    from bayesmap.scenes import tutorial_problem

    truth = np.zeros((21, 21), np.float32)
    truth[tuple(np.array(sorted(drawn | painted)).T)] = 1.0
    visible = tutorial_problem(truth, (11.0, 9.0)).visible
    seen = {cell for cell in drawn | painted if visible[cell]}
    assert len(seen) >= 19
    for cell in seen:
        assert inferred.get(cell, 0.0) > 0.9, (cell, inferred.get(cell))
    for i in range(11, 15):  # the free cells between the sensor and the wall at x = 15, at the sensor's row
        assert inferred.get((i, 9), 0.0) < 0.1, ((i, 9), inferred.get((i, 9)))
    assert "run 1: 100 sweeps" in _status(page)

    # browsing samples: switch the average off, the slider shows a sweep; walls still where drawn
    page.click(".bm-average")
    page.wait_for_function("() => document.querySelector('.bm-sample-label').innerText.startsWith('sweep 100')")
    sample = _inferred(page)
    assert set(sample.values()) <= {1.0}  # a sample is a 0/1 map: only walls are drawn
    assert drawn | painted <= set(sample)

    # clear inferred walls removes them, the drawn map stays
    page.click(".bm-clear-inferred")
    page.wait_for_function("() => document.querySelectorAll('.bm-map svg rect.inferred').length === 0")
    assert _walls(page) == drawn | painted


def test_two_pages_are_independent(open_page):
    a = open_page()
    b = open_page()
    a.mouse.click(*_cell_px(a, 12, 10))  # a free cell next to the sensor
    _wait_walls(a, TUTORIAL_WALLS + 1)
    a.click(".bm-clear-walls")
    _wait_walls(a, 0)
    b.wait_for_timeout(300)
    assert len(_walls(b)) == TUTORIAL_WALLS
    b.reload()
    b.wait_for_selector(".bm-map svg circle.sensor")
    assert len(_walls(b)) == TUTORIAL_WALLS
    assert "54 walls" in _status(b)


def test_bad_input_shows_message_and_changes_nothing(open_page, tmp_path):
    page = open_page()
    walls = _walls(page)
    field = page.locator(".bm-field-prior_wall_prob input")
    field.fill("1.5")
    field.press("Enter")
    page.wait_for_function("() => document.querySelector('.bm-message').innerText.includes('1.5')")
    assert "prior wall probability must be between 0.01 and 0.99" in page.inner_text(".bm-message")
    page.wait_for_function("() => document.querySelector('.bm-field-prior_wall_prob input').value === '0.5'")

    field = page.locator(".bm-field-num_angles input")
    field.fill("ten")
    field.press("Enter")
    page.wait_for_function("() => document.querySelector('.bm-message').innerText.includes(\"'ten' is not a number\")")
    assert page.locator(".bm-map svg g.readings circle").count() == 100

    bad = tmp_path / "broken.txt"
    bad.write_text("XX.\nX?.\n")
    page.set_input_files(".bm-upload input[type=file]", str(bad))
    page.wait_for_function("() => document.querySelector('.bm-message').innerText.includes('broken.txt')")
    assert "unknown character '?'" in page.inner_text(".bm-message")
    binary = tmp_path / "garbage.txt"
    binary.write_bytes(bytes(range(256)))
    page.set_input_files(".bm-upload input[type=file]", str(binary))
    page.wait_for_function("() => document.querySelector('.bm-message').innerText.includes('garbage.txt')")
    assert "not a text file" in page.inner_text(".bm-message")
    assert _walls(page) == walls
    assert "sensor at (10.00, 10.00), 100 beams" in _status(page)

    # a good value clears the message and takes effect
    field = page.locator(".bm-field-num_angles input")
    field.fill("40")
    field.press("Enter")
    page.wait_for_function("() => document.querySelectorAll('.bm-map svg g.readings circle').length === 40")
    assert page.inner_text(".bm-message") == ""


def test_load_save_and_single_run(open_page, tmp_path):
    page = open_page()
    room = tmp_path / "room.txt"
    room.write_text("XXXXXXX\nX.....X\nX.....X\nX.....X\nXXXXXXX\n")
    page.set_input_files(".bm-upload input[type=file]", str(room))
    page.wait_for_function("() => document.querySelector('.bm-status').innerText.startsWith('20 walls')")
    assert "sensor at (2.00, 3.00)" in _status(page)  # moved to the free cell nearest the new map's center
    with page.expect_download() as info:
        page.click(".bm-save")
    saved = Path(info.value.path()).read_text()
    assert saved == room.read_text()

    # a second click while running does not start a second run
    page.evaluate("() => { const b = document.querySelector('.bm-run'); b.click(); b.click(); b.click(); }")
    page.wait_for_function("() => document.querySelector('.bm-status').innerText.includes('sweeps in')", timeout=120000)
    page.wait_for_timeout(500)
    assert "run 1: 100 sweeps" in _status(page)
    inferred = _inferred(page)
    assert all(inferred.get((i, j), 0) > 0.9 for i, j in [(0, 3), (4, 3), (2, 0), (2, 6)])


def test_path_mode_runs_slam(open_page):
    """Path mode: clicks add poses (a wall click only shows a message), Run SLAM shows the map, odometry, pose samples,
    mean path and the ATEs."""
    page = open_page()
    walls = _walls(page)
    field = page.locator(".bm-field-sweeps input")
    field.fill("10")
    field.press("Enter")
    page.click(".bm-path-mode")
    page.wait_for_function("() => document.querySelector('.bm-run').textContent.includes('Run SLAM')")
    assert page.locator(".bm-map svg circle.sensor").count() == 0  # the single sensor is not drawn in path mode

    # too few poses: Run SLAM says so and runs nothing
    page.click(".bm-run")
    page.wait_for_function("() => document.querySelector('.bm-message').innerText.includes('at least 2 poses')")

    for k, (i, j) in enumerate([(4, 6), (10, 10), (14, 14)]):
        page.mouse.click(*_cell_px(page, i, j))
        page.wait_for_function(f"() => document.querySelectorAll('.bm-map svg g.pose').length === {k + 1}")
    assert page.inner_text(".bm-message") == ""
    page.mouse.click(*_cell_px(page, 2, 1))  # a wall: a message, no pose, no change to the map
    page.wait_for_function("() => document.querySelector('.bm-message').innerText.includes('cell (2, 1) is a wall')")
    assert page.locator(".bm-map svg g.pose").count() == 3 and _walls(page) == walls
    assert page.text_content(".bm-map svg g.pose[data-k='2'] text") == "3"

    page.evaluate("() => { const b = document.querySelector('.bm-run'); b.click(); b.click(); }")
    page.wait_for_function("() => document.querySelector('.bm-slam').innerText.includes('ATE of the posterior mean')",
                           timeout=120000)
    text = page.inner_text(".bm-slam")
    assert "3 poses, 10 sweeps" in text
    ate_mean, ate_odometry = (float(v) for v in re.findall(r"([0-9.]+) m", text))
    assert ate_mean < ate_odometry
    assert page.locator(".bm-map svg circle.pose-sample").count() == 7 * 3  # 10 sweeps, 3 burn-in, 3 poses
    assert page.locator(".bm-map svg polyline.mean-path").count() == 1
    assert page.locator(".bm-map svg polyline.odometry").count() == 1
    inferred = _inferred(page)
    # a free cell on the path (an absent cell is below 0.005) and a wall next to pose 3
    assert inferred.get((12, 10), 0.0) < 0.5 and inferred.get((12, 14), 0.0) > 0.5
    assert "run 1" in _status(page)
    page.screenshot(path=str(ARTIFACTS / "app-path.png"))

    # Clear path removes the poses and the SLAM result; back in map mode the sensor is there again
    page.click(".bm-clear-path")
    page.wait_for_function("() => document.querySelectorAll('.bm-map svg g.pose').length === 0")
    assert page.locator(".bm-map svg circle.pose-sample").count() == 0
    page.click(".bm-path-mode")
    page.wait_for_selector(".bm-map svg circle.sensor")
    assert _walls(page) == walls
