"""The evaluation drivers end to end through the CLI: held-out scans of a log, and a floor plan."""

from __future__ import annotations

import json

import numpy as np

from bayesmap.io.rosmap import write_pgm
from helpers import run_cli


def test_evaluate_log_writes_the_table(small_log, tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", small_log, "--every", 4, "--resolution", 0.2,
                             "--sweeps", 6, "--json", tmp_path / "scores.json")
    assert code in (0, None), err
    scores = json.loads((tmp_path / "scores.json").read_text())
    for method in ("bayesmap", "logodds"):
        assert 0.5 < scores[method]["auc"] <= 1.0 and np.isfinite(scores[method]["nll"])
    assert scores["setup"]["test_scans"] == 3 and scores["setup"]["train_scans"] == 9
    # the log defaults, in meters whatever the resolution
    from bayesmap import scenes
    assert scores["setup"]["prior_wall_prob"] == scenes.LOG_STRUCTURED_PRIOR
    assert scores["setup"]["sensor_noise"] == scenes.LOG_SENSOR_NOISE and scores["setup"]["range_offset"] == 0.0
    assert scores["setup"]["geometry"] == "chord" and scores["setup"]["coupling"] == scenes.log_coupling(0.2)
    assert scores["setup"]["cut_past_reading"] == scenes.LOG_CUT_PAST_READING
    assert "bayesmap" in out and "logodds" in out and "auc" in out
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--log", small_log, "--json", tmp_path / "scores.json")
    assert code == 2 and "already exists" in err


def test_evaluate_truth_on_a_floor_plan(tmp_path, monkeypatch, capsys):
    # a 6 m x 4 m room with a pillar, as a bare PGM of 0.1 m pixels: 0 wall, 255 free, 205 unknown outside
    image = np.full((44, 64), 205, np.uint8)
    image[2:42, 2:62] = 0
    image[3:41, 3:61] = 255
    image[18:24, 30:34] = 0
    write_pgm(tmp_path / "room.pgm", image)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--truth", tmp_path / "room.pgm", "--num-poses", 4,
                             "--num-angles", 90, "--max-range", 8, "--sweeps", 10, "--json", tmp_path / "s.json")
    assert code in (0, None), err
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["setup"]["cells_scored"] > 500
    assert scores["setup"]["sensor_noise"] == 0.05  # the simulated sensor's (scenes.SIMULATED_SENSOR_NOISE)
    for method in ("bayesmap", "logodds"):
        assert set(scores[method]) >= {"accuracy", "auc", "brier", "cells"}
    # four viewpoints in a small room: the posterior gets nearly every seen cell right
    assert scores["bayesmap"]["accuracy"] > 0.9 and scores["bayesmap"]["brier"] < 0.1
