"""report.html: one self-contained offline file; it opens in headless Chromium with the network blocked."""

import contextlib
import io
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from helpers import run_main

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"

# both tests read the one report: on one xdist worker (--dist loadgroup), so the module-scoped run happens once
pytestmark = pytest.mark.xdist_group("report")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """``bayesmap infer --report`` on a small room (2 chains, 20 sweeps), in-process."""
    out = tmp_path_factory.mktemp("report")
    (out / "room.txt").write_text("XXXXXXXX\nX......X\nX..XX..X\nX......X\nXXXXXXXX\n")
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = run_main("infer", "--map", out / "room.txt", "--pos", 1, 2, "--sweeps", 20, "--chains", 2, "--report",
                        "--out", out / "run")
    assert code == 0 and "report.html" in printed.getvalue()
    return out / "run" / "report.html"


def test_report_is_self_contained(report):
    text = report.read_text(encoding="utf-8")
    assert not re.search(r"https?://|//cdn|<script[^>]+src=|<link[^>]+href=|@import|url\(", text)
    # every figure of the report: map, what the robot sees, posterior (+ std), convergence, importance, GIF
    for gid in ("fig-map", "fig-scan", "fig-posterior", "fig-convergence", "fig-importance", "fig-animation"):
        assert f'id="{gid}"' in text
    assert text.count("data:image/png;base64,") >= 5 and text.count("data:image/gif;base64,") == 1
    assert "wrong visible cells" in text and "worst split R-hat" in text and "runtime" in text
    assert 'id="chain-slider-page"' in text and "chain-slider" in text  # the slider page, inline (srcdoc)


def test_report_opens_offline_in_chromium(report):
    assert CHROMIUM.exists(), "Debian's chromium is needed (make installs it with apt-get)"
    from playwright.sync_api import sync_playwright

    attempted = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})

            def route(r):
                if r.request.url.startswith("file://"):
                    return r.continue_()
                attempted.append(r.request.url)
                return r.abort()

            page.route("**/*", route)
            page.goto(report.as_uri(), wait_until="load")
            images = page.evaluate("() => Array.from(document.images)"
                                   ".map(i => [i.complete, i.naturalWidth, i.alt])")
            assert len(images) >= 6
            assert all(done and width > 100 for done, width, _ in images), images
            frame = page.frame_locator("#chain-slider-page")
            sweep = frame.locator("#chain-sweep")
            before = sweep.inner_text()
            slider = frame.locator("#chain-slider")
            slider.focus()
            slider.press("End")
            assert sweep.inner_text() != before and "20" in sweep.inner_text()
            frame_img = frame.locator("#chain-frame")
            assert frame_img.evaluate("i => i.complete && i.naturalWidth > 100")
            ARTIFACTS.mkdir(exist_ok=True)
            shot = page.screenshot(full_page=True, path=str(ARTIFACTS / "report.png"))
            assert len(shot) > 10_000
        finally:
            browser.close()
    assert attempted == []  # nothing tried to reach the network


def test_a_logs_posterior_figure_is_cropped_to_the_cells_its_beams_crossed(monkeypatch, small_log):
    """A real log's grid reaches as far as its longest beam: the report's posterior figure gets the cells the beams
    crossed (``seen``), so it shows those."""
    import numpy as np

    import bayesmap.viz.report as report
    from bayesmap.io.carmen import read_carmen
    from bayesmap.io.maps_out import seen_cells
    from bayesmap.scenes import log_problem

    problem = log_problem(read_carmen(small_log), resolution=0.2)
    given = []
    draw = report.plot_posterior
    monkeypatch.setattr(report, "plot_posterior", lambda *a, **k: given.append(k["seen"]) or draw(*a, **k))
    result = SimpleNamespace(posterior=np.full(problem.grid.shape, 0.1), summary={"burn_in": 1, "sweeps": 2},
                             samples=np.zeros((2, *problem.grid.shape), dtype=bool))
    report._map_figures(problem, result)
    expected = seen_cells(problem.table, problem.ray_readings)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(given[0], expected)
