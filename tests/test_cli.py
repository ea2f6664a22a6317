"""The command line: outputs, the real scan, and one-line errors with exit code 2. (`bayesmap demo` runs end to end in
tests/test_install.py, from the installed wheel.)"""

import gzip
import json

import numpy as np
import pytest

from helpers import run_cli


def test_infer_on_a_map_file_writes_all_outputs(tmp_path, monkeypatch, capsys):
    (tmp_path / "room.txt").write_text("XXXXXXX\nX.....X\nX.....X\nX.....X\nXXXXXXX\n")
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--map", tmp_path / "room.txt", "--sweeps", 20,
                             "--num-angles", 60, "--out", tmp_path / "out")
    assert code in (0, None), err
    files = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert files == ["posterior.npy", "posterior.png", "readings.npy", "summary.json"]
    posterior = np.load(tmp_path / "out" / "posterior.npy")
    assert posterior.shape == (5, 7)
    assert np.load(tmp_path / "out" / "readings.npy").shape == (60,)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["sweeps"] == 20 and summary["pos"] == [2.0, 3.0] and summary["visible_cells"] == 31
    assert [s["stage"] for s in summary["stages"]] == ["build problem", "sweeps", "figures", "write outputs"]
    assert posterior[1:4, 1:6].max() < 0.5 and posterior[1:4, 1:6].mean() < 0.1  # the free interior is inferred free
    # (single-site Gibbs, any order, can get stuck here for 20+ sweeps with some seeds: a wall next to the sensor
    # shadows the true walls; the default 2x2 block sampler does not)
    assert summary["wrong_visible_cells"] == 0
    assert "wrong" in out and "runtime" in out
    # nothing is overwritten without asking
    before = (tmp_path / "out" / "summary.json").read_bytes()
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--map", tmp_path / "room.txt", "--out", tmp_path / "out")
    assert code == 2 and "--force" in err and (tmp_path / "out" / "summary.json").read_bytes() == before


def test_infer_on_a_log_records_its_stages(intel_log, tmp_path, monkeypatch, capsys):
    """summary.json of ``infer --log --scans`` holds each stage, the log-odds start one of its own, in the order
    they ran; the start and the sampler's stage hold the sampler's own runtime (and the summary computed after it);
    the run's peak is at least every stage's; the other keys are there as before. ``--tile-pairs`` at two thirds of
    the log's pairs sweeps it in two tiles (the marginals then differ from the whole table's about as two seeds' do:
    mean absolute difference 0.0012 measured, whole table seeds 0 and 1: 0.0007; asserted below 0.005)."""
    args = ["infer", "--log", intel_log, "--scans", "0:4", "--resolution", 0.2, "--sweeps", 4]
    code, out, err = run_cli(monkeypatch, capsys, *args, "--out", tmp_path / "out")
    assert code in (0, None), err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    stages = summary["stages"]
    assert [s["stage"] for s in stages] == ["read log", "build problem", "log-odds start", "sweeps", "figures",
                                            "write outputs"]
    assert stages[2]["seconds"] + stages[3]["seconds"] >= summary["runtime_s"] - 0.02  # (1 ms rounding each)
    assert summary["peak_rss_mb"] >= max(s["peak_rss_mb"] for s in stages) > 0  # (the peak before them counts too)
    assert summary["num_scans"] == 4 and summary["sweeps"] == 4
    assert summary["tiles"] == 1 and summary["ray_cell_pairs"] > 0
    budget = summary["ray_cell_pairs"] * 2 // 3 + 1
    code, out, err = run_cli(monkeypatch, capsys, *args, "--tile-pairs", budget, "--out", tmp_path / "tiled")
    assert code in (0, None), err
    tiled = json.loads((tmp_path / "tiled" / "summary.json").read_text())
    assert tiled["tiles"] >= 2 and tiled["tile_pairs"] == budget
    whole, parts = (np.load(tmp_path / name / "posterior.npy") for name in ("out", "tiled"))
    assert whole.shape == parts.shape and np.abs(whole - parts).mean() < 0.005


def test_infer_on_a_real_scan(intel_log, tmp_path, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "infer", "--log", intel_log, "--scan", 100, "--sweeps", 20,
                             "--sampler", "chromatic", "--out", tmp_path / "scan")
    assert code in (0, None), err
    summary = json.loads((tmp_path / "scan" / "summary.json").read_text())
    assert summary["grid"]["resolution"] == 0.1 and summary["num_angles"] == 180
    from bayesmap.io.carmen import read_carmen
    from bayesmap.scenes import scan_problem

    problem = scan_problem(read_carmen(intel_log), 100, sensor_noise=0.05)
    posterior = np.load(tmp_path / "scan" / "posterior.npy")
    direction = np.stack([np.cos(problem.beam_angles), np.sin(problem.beam_angles)], -1)
    hit = ~problem.max_range_mask
    ends = problem.pos + (problem.readings[:, None] + 0.05) * direction
    before = problem.pos + (problem.readings[:, None] - 0.3) * direction
    at_end = posterior[tuple(problem.grid.cell_index(ends[hit]).T)]
    in_front = posterior[tuple(problem.grid.cell_index(before[hit]).T)]
    assert np.median(at_end) > 0.75  # walls where the beams end
    assert in_front.mean() < 0.05  # free space the beams crossed


@pytest.mark.parametrize("make_args, match", [
    (lambda t: ["infer", "--map", t / "ragged.txt"], "line 2 has"),
    (lambda t: ["infer", "--map", t / "junk.txt"], "unknown character"),
    (lambda t: ["infer", "--map", t / "empty.txt"], "empty"),
    (lambda t: ["infer", "--map", t / "missing.txt"], "does not exist"),
    (lambda t: ["infer", "--pos", "30", "2"], r"\(30, 2\) is outside the grid"),
    (lambda t: ["infer", "--prior-wall-prob", "1.2"], "prior_wall_prob"),
    (lambda t: ["infer", "--sensor-noise", "0"], "sensor_noise"),
    (lambda t: ["infer", "--sampler", "magic"], "unknown sampler 'magic'"),
    (lambda t: ["infer", "--sweeps", "10", "--burn-in", "10"], "burn-in"),
    (lambda t: ["infer", "--log", t / "missing.log"], "missing.log"),
    (lambda t: ["infer", "--log", t / "one.log", "--scan", "0", "--scans", "0:1"], "either --scan N or --scans"),
    (lambda t: ["infer", "--log", t / "one.log", "--scans", "3:x"], "bad scan selection '3:x'"),
    (lambda t: ["infer", "--log", t / "one.log", "--scans", "7"], "scan 7 is out of range"),
    (lambda t: ["infer", "--scans", "0:2"], "need --log"),
    (lambda t: ["infer", "--log", t / "one.log", "--scan", "0", "--range-offset", "0.1"],
     "--range-offset and --likelihood-power apply"),
    (lambda t: ["infer", "--log", t / "one.log", "--scan", "0", "--likelihood-power", "0.5"],
     "--likelihood-power apply"),
    (lambda t: ["infer", "--likelihood-power", "0.5"], "need --log"),
    (lambda t: ["infer", "--geometry", "chord"],
     "--geometry, --wall-pass-prob, --cut-past-reading, --tile-pairs and the keyframe options apply to several "
     "scans of --log"),
    (lambda t: ["infer", "--tile-pairs", "1000"], "--tile-pairs and the keyframe options apply to several scans"),
    (lambda t: ["infer", "--log", t / "one.log", "--tile-pairs", "0"], "--tile-pairs must be an integer >= 1, got 0"),
    (lambda t: ["infer", "--log", t / "one.log", "--tile-pairs", "many"], "--tile-pairs.*got 'many'"),
    (lambda t: ["infer", "--log", t / "one.log", "--cut-past-reading", "0"], "cut_past_reading must be > 0"),
    (lambda t: ["infer", "--log", t / "one.log", "--scan", "0", "--geometry", "chord"],
     "--geometry, --wall-pass-prob, --cut-past-reading, --tile-pairs and the keyframe options apply to several "
     "scans"),
    (lambda t: ["infer", "--log", t / "one.log", "--scan", "0", "--tile-pairs", "1000"], "not to --scan N"),
    (lambda t: ["infer", "--log", t / "one.log", "--geometry", "inside"], "unknown geometry 'inside'"),
    (lambda t: ["infer", "--log", t / "one.log", "--likelihood-power", "1.5"], "likelihood_power must be in"),
    (lambda t: ["infer", "--method", "magic"], "unknown method 'magic'"),
    (lambda t: ["infer", "--method", "logodds", "--report"], "need --method gibbs"),
    (lambda t: ["infer", "--beam-model", "laser"], "laser"),
    (lambda t: ["infer", "--beam-weights", "0.5,0.5"], "four numbers HIT,SHORT,MAX,RAND, got 2"),
    (lambda t: ["infer", "--beam-weights", "0.5,x,0,0"], "four numbers"),
    (lambda t: ["infer", "--beam-weights", "0.5,0.2,0.2,0.2"], "beam weights must sum to 1"),
    (lambda t: ["infer", "--lambda-short", "-1"], "lambda_short"),
    (lambda t: ["infer", "--log", t / "missing.log", "--scan", "1"], "missing.log"),
    (lambda t: ["infer", "--log", t / "trunc.log.gz", "--scan", "1"], "trunc"),
    (lambda t: ["infer", "--log", t / "one.log", "--scan", "5"], "5"),
    (lambda t: ["infer", "--out", t / "file.txt" / "sub"], "file.txt"),
])
def test_user_errors_are_one_line_exit_2(tmp_path, monkeypatch, capsys, make_args, match, intel_log):
    (tmp_path / "ragged.txt").write_text("X..\nX.\n")
    (tmp_path / "junk.txt").write_text("X..\nX#.\n")
    (tmp_path / "empty.txt").write_text("")
    (tmp_path / "file.txt").write_text("x")
    (tmp_path / "trunc.log.gz").write_bytes(intel_log.read_bytes()[:50000])
    with gzip.open(intel_log, "rt") as handle:
        line = next(log_line for log_line in handle if log_line.startswith("FLASER"))
    (tmp_path / "one.log").write_text(line)
    code, out, err = run_cli(monkeypatch, capsys, *make_args(tmp_path), "--sweeps", "2", "--out", tmp_path / "o") \
        if "--out" not in make_args(tmp_path) else run_cli(monkeypatch, capsys, *make_args(tmp_path))
    assert code == 2
    lines = [err_line for err_line in err.strip().splitlines() if err_line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), err
    import re

    assert re.search(match, lines[0]), lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("args, match", [
    ([], "either --log FILE or --truth FILE"),
    (["--log", "{t}/one.log", "--every", "1"], "integer >= 2"),
    (["--log", "{t}/one.log"], "no scan to test"),
    (["--truth", "{t}/junk.txt"], "junk.txt"),
    (["--truth", "{t}/missing.pgm"], "missing.pgm"),
])
def test_evaluate_user_errors_are_one_line_exit_2(tmp_path, monkeypatch, capsys, args, match, intel_log):
    (tmp_path / "junk.txt").write_text("X..\nX#.\n")
    with gzip.open(intel_log, "rt") as handle:
        line = next(log_line for log_line in handle if log_line.startswith("FLASER"))
    (tmp_path / "one.log").write_text(line)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", *[a.format(t=tmp_path) for a in args])
    lines = [err_line for err_line in err.strip().splitlines() if err_line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error:"), err
    assert match in lines[0]
