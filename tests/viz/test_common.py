"""Tests for bayesmap.viz.common: rendering and saving figures (whole or not at all), and figures drawn in threads."""

from __future__ import annotations

import threading

import pytest

from bayesmap.errors import BayesmapError
from bayesmap.viz.common import save_figure
from bayesmap.viz.maps import plot_map, plot_posterior
from helpers import POS, blurred

# ---------------------------------------------------------------------------------------------------------------
# save_figure
# ---------------------------------------------------------------------------------------------------------------


def test_save_png_and_no_overwrite(tmp_path, grid, walls, scan):
    a, r = scan
    fig = plot_map(grid, walls, POS, a, r)
    path = tmp_path / "map.png"
    assert save_figure(fig, path) == path
    data = path.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 1000
    other = plot_posterior(grid, blurred(walls))
    with pytest.raises(BayesmapError, match="already exists"):
        save_figure(other, path)
    assert path.read_bytes() == data
    save_figure(other, path, overwrite=True)
    assert path.read_bytes() != data and path.read_bytes().startswith(b"\x89PNG")
    assert [p.name for p in tmp_path.iterdir()] == ["map.png"]  # no temporary files left


def test_save_svg(tmp_path, grid, walls):
    path = save_figure(plot_posterior(grid, blurred(walls), truth=walls), tmp_path / "post.SVG")
    text = path.read_text(encoding="utf-8")
    assert "<svg" in text[:2000]


def test_save_bad_suffix_and_folder(tmp_path, grid):
    fig = plot_map(grid)
    with pytest.raises(BayesmapError, match=r"'\.jpg'"):
        save_figure(fig, tmp_path / "map.jpg")
    with pytest.raises(BayesmapError, match="no suffix"):
        save_figure(fig, tmp_path / "map")
    with pytest.raises(BayesmapError, match="cannot write"):
        save_figure(fig, tmp_path / "missing" / "map.png")
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------------------------
# Threads and speed
# ---------------------------------------------------------------------------------------------------------------


def test_plots_in_threads(tmp_path, grid, walls, scan):
    a, r = scan
    errors = []

    def work(k):
        try:
            fig = plot_posterior(grid, blurred(walls), truth=walls, pos=POS, beam_angles=a, readings=r)
            save_figure(fig, tmp_path / f"p{k}.png")
        except Exception as err:  # pragma: no cover - reported below
            errors.append(err)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert all((tmp_path / f"p{k}.png").read_bytes().startswith(b"\x89PNG") for k in range(4))

