"""The benchmarks' own helpers: the trace reader of ``benchmarks/sweep_cost.py --profile``, the selection rules
of ``benchmarks/map_cv.py``, the watchdog, slopes and table of ``benchmarks/scale.py``, and the truth carried onto
the model's first pose by ``target_at_truth.py`` and ``step_covariance.py``, the coverage-rank figure of
``coverage_ranks.py``, the similarity scale of ``path_scale.py`` and the local maps and seen beams of
``match_bias.py``."""

import gzip
import json
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import coverage_ranks  # noqa: E402
import map_cv  # noqa: E402
import match_bias  # noqa: E402
import path_scale  # noqa: E402
import scale  # noqa: E402
import sweep_cost  # noqa: E402

EVENTS = [
    {"ph": "X", "name": "loop", "pid": 1, "tid": 1, "ts": 0, "dur": 100},
    {"ph": "X", "name": "score", "pid": 1, "tid": 1, "ts": 10, "dur": 30},
    {"ph": "X", "name": "score", "pid": 1, "tid": 1, "ts": 50, "dur": 20},
    {"ph": "X", "name": "inner", "pid": 1, "tid": 1, "ts": 55, "dur": 5},
    {"ph": "X", "name": "other", "pid": 1, "tid": 2, "ts": 20, "dur": 40},  # another thread: not inside "loop"
    {"ph": "X", "name": "after", "pid": 1, "tid": 1, "ts": 100, "dur": 7},  # starts as "loop" ends: not inside
    {"ph": "i", "name": "mark", "pid": 1, "tid": 1, "ts": 5},  # an instant event: no duration, ignored
]


@pytest.mark.parametrize("wrapped", [True, False])
def test_self_times_subtract_the_events_nested_on_the_same_thread(tmp_path, wrapped):
    trace = tmp_path / "perfetto_trace.json.gz"
    with gzip.open(trace, "wt") as f:
        json.dump({"traceEvents": EVENTS} if wrapped else EVENTS, f)
    rows = sweep_cost.self_times(trace)
    # loop: 100 - 30 - 20 (its two children; "inner" is the second score's); score: 30 + 20 - 5
    assert rows == [("loop", 0.05, 1), ("score", 0.045, 2), ("other", 0.04, 1), ("after", 0.007, 1),
                    ("inner", 0.005, 1)]


def _cv_row(log, res, setting, auc, nll, lo_auc=0.9, lo_nll=2.0):
    power, run_length, pi = setting
    return dict(log=log, resolution=res, power=power, readings_per_cell=0.0, run_length=run_length, noise=0.1,
                z_rand=0.1, pass_prob=0.5, prior=pi, auc=auc, nll=nll, logodds_auc=lo_auc, logodds_nll=lo_nll)


def test_map_cv_rules_choose_by_mean_margin_and_break_ties_by_nll():
    """Three settings on two logs x two resolutions: A has the largest mean AUC margin (+0.0302), B is 0.0002 below
    it with a lower NLL everywhere, C has the largest margin of all but one NLL above log-odds' (not eligible), D is
    0.002 below A with the lowest NLL. The mean rule picks A; the tie rule (within 0.0005) B, not D."""
    a, b, c, d = (0.1, 1.0, 0.1), (0.1, 1.0, 0.3), (0.1, 2.0, 0.1), (0.2, 1.0, 0.1)
    rows = []
    for log in ("x", "y"):
        for res in (0.1, 0.2):
            rows += [_cv_row(log, res, a, 0.9302, 1.5), _cv_row(log, res, b, 0.9300, 1.2),
                     _cv_row(log, res, c, 0.95, 2.5 if (log, res) == ("y", 0.2) else 1.0),
                     _cv_row(log, res, d, 0.9282, 0.5)]
    pick = {tie: map_cv.choose(rows, ["x", "y"], tie) for tie in (0.0, map_cv.TIE)}
    assert pick[0.0] == map_cv.setting_of(_cv_row("x", 0.1, a, 0, 0))
    assert pick[map_cv.TIE] == map_cv.setting_of(_cv_row("x", 0.1, b, 0, 0))
    # a setting missing one (log, resolution) is not eligible, whatever its scores
    rows.append(_cv_row("x", 0.1, (0.5, 1.0, 0.1), 0.99, 0.1))
    assert map_cv.choose(rows, ["x", "y"], 0.0) == pick[0.0]


def test_scale_slope_is_the_least_squares_fit_per_thousand_scans():
    """Points on a line of 40 s per 1,000 scans plus 5 s give 40 exactly; noise of +-1 s at 250 and 1,000 scans
    (the middle point 0) moves the slope by 2 / 0.75 = 2.67 s per 1,000 (least squares: sum(dx dy) / sum(dx^2) with
    dx = -0.25, 0.5 thousand from the mean 0.5833... computed by hand below); one prefix gives no slope."""
    scans = [250, 500, 1000]
    assert scale.fit_slope(scans, [5 + 0.04 * n for n in scans]) == pytest.approx(40.0)
    x = [0.25, 0.5, 1.0]
    mean = sum(x) / 3
    dy = [-1.0, 0.0, 1.0]
    by_hand = sum((a - mean) * b for a, b in zip(x, dy)) / sum((a - mean) ** 2 for a in x)
    noisy = [5 + 0.04 * n + d for n, d in zip(scans, dy)]
    assert scale.fit_slope(scans, noisy) == pytest.approx(40.0 + by_hand)
    assert scale.fit_slope([500], [3.0]) is None and scale.fit_slope([500, 500], [3.0, 4.0]) is None


def _scale_records():
    stages = [{"stage": name, "seconds": seconds, "peak_rss_mb": 100.0 * k} for k, (name, seconds) in enumerate([
        ("read log", 0.1), ("front end", 30.0), ("loop closure 1/3", 4.0), ("loop closure 2/3", 2.0),
        ("round 1/3: map", 50.0), ("round 1/3: poses", 10.0), ("round 2/3: map", 40.0), ("final map", 20.4),
        ("figures", 3.0)])]
    return [
        {"scans": 500, "method": "karto", "status": "ok", "wall_s": 4.0, "peak_mb": 400.0, "ate_m": 0.5},
        {"scans": 250, "method": "bayesmap", "status": "ok", "wall_s": 120.0, "peak_mb": 2000.0, "ate_m": 0.25,
         "stages": stages},
        {"scans": 500, "method": "bayesmap", "status": "ok", "wall_s": 300.0, "peak_mb": 5000.0, "ate_m": 0.3,
         "stages": stages[:2] + [{"stage": "build problem", "seconds": 1.0, "peak_rss_mb": 7.0}] + stages[2:]},
        {"scans": 1000, "method": "bayesmap", "status": "killed", "killed": "memory", "wall_s": 93.4,
         "peak_mb": 10100.0, "memory_limit_gb": 10.0, "time_limit_s": 1800.0},
        {"scans": 4791, "method": "bayesmap", "status": "refused", "returncode": 2, "wall_s": 6.0, "peak_mb": None,
         "message": "the ray-cell table would take about 72 GB | more"},
        {"scans": 250, "method": "karto", "status": "ok", "wall_s": 2.0, "peak_mb": 350.0, "ate_m": 0.4},
    ]


def test_scale_table_rows_statuses_and_stage_columns():
    """One row per run, by prefix then method (bayesmap first); a killed run says at what and when, a refused one
    its message (a "|" escaped, not a new column); the rounds' map and pose stages sum (50 + 10 + 40), the loop
    closure's rounds too (4 + 2); the slopes use the finished runs alone."""
    records = _scale_records()
    lines = scale.markdown_table(records).splitlines()
    assert lines[0].startswith("| prefix scans | method | status | wall s | peak MB | ATE m | front end s")
    assert [line.split(" | ")[:2] for line in lines[2:]] == [["| 250", "bayesmap"], ["| 250", "karto"],
                                                             ["| 500", "bayesmap"], ["| 500", "karto"],
                                                             ["| 1,000", "bayesmap"], ["| 4,791", "bayesmap"]]
    assert lines[2] == "| 250 | bayesmap | ok | 120 | 2,000 | 0.25 | 30 | 6 | 100 | 20 | - |"  # no scan placed
    assert lines[3] == "| 250 | karto | ok | 2 | 350 | 0.40 | - | - | - | - | - |"
    assert "| killed at 10 GB after 93 s | 93 | 10,100 | - |" in lines[6]
    assert "refused: the ray-cell table would take about 72 GB \\| more | 6 | - | - |" in lines[7]
    assert all(line.replace("\\|", "").count("|") == lines[0].count("|") for line in lines[2:])  # the columns
    fits = scale.slopes(records)
    assert fits["bayesmap"]["prefixes"] == [250, 500]
    assert fits["bayesmap"]["seconds_per_1000"] == pytest.approx(720.0)  # (300 - 120) s over 0.25 thousand scans
    assert fits["bayesmap"]["mb_per_1000"] == pytest.approx(12000.0)
    assert fits["karto"]["seconds_per_1000"] == pytest.approx(8.0)
    assert scale.status_text({**records[3], "killed": "time", "wall_s": 1800.2}) == (
        "killed at the 1800 s limit after 1800 s")


def test_scale_prefixes_and_error_line():
    assert scale.parse_prefixes("500, 250,all,250", 4791) == [250, 500, 4791]
    for bad in ("0", "5000", "x", ""):
        with pytest.raises(ValueError):
            scale.parse_prefixes(bad, 4791)
    text = "front end: 10%\rfront end: 20%\nerror: the grid would have 9 cells\n"
    assert scale.error_line(text) == "the grid would have 9 cells"
    assert scale.error_line("Traceback\nKeyError: 3\n") == "KeyError: 3"


ALLOCATE = """
import os, sys, time
open(sys.argv[1], "w").write(str(os.getpid()))
blocks = []
for _ in range(60):  # 5 MB more every 0.02 s, touched (a bytearray is zeroed): 300 MB after 1.2 s
    blocks.append(bytearray(5 * 10**6))
    time.sleep(0.02)
time.sleep(30)
"""


def test_scale_watchdog_kills_the_whole_tree_above_the_memory_limit(tmp_path):
    """A child whose own child (a grandchild) fills 300 MB: the tree's memory is polled, the tree killed soon after
    it passes 150 MB (not after the grandchild's 30 s sleep), the grandchild gone too; the run reports no exit code
    and at least the limit seen."""
    pid_file = tmp_path / "pid"
    parent = f"import subprocess, sys; subprocess.run([sys.executable, '-c', {ALLOCATE!r}, {str(pid_file)!r}])"
    start = time.perf_counter()
    watched = scale.run_watched([sys.executable, "-c", parent], memory_limit_mb=150.0, time_limit_s=60.0,
                                poll_s=0.1)
    assert watched.killed == "memory" and watched.returncode is None
    assert watched.polled_peak_mb > 150.0 and time.perf_counter() - start < 15.0
    assert max(watched.peaks.values()) > 100.0  # the grandchild's own high-water mark (it held most of it)
    grandchild = int(pid_file.read_text())
    deadline = time.perf_counter() + 5.0
    while time.perf_counter() < deadline and _alive(grandchild):
        time.sleep(0.05)
    assert not _alive(grandchild)


def _alive(pid: int) -> bool:
    import psutil

    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_scale_watchdog_time_limit_and_exit_codes(tmp_path):
    """A run past its time limit is killed; one that ends reports its exit code, its wall time and its process's
    peak (the high-water mark read while it held 50 MB for a second: at least that), and its output is kept."""
    slow = scale.run_watched([sys.executable, "-c", "import time; time.sleep(30)"], memory_limit_mb=1e6,
                             time_limit_s=0.5, poll_s=0.1)
    assert slow.killed == "time" and slow.wall_s < 10.0
    output = tmp_path / "out.txt"
    code = "import sys, time; block = bytearray(50 * 10**6); print('error: refused here'); time.sleep(1); sys.exit(2)"
    done = scale.run_watched([sys.executable, "-c", code], memory_limit_mb=1e6, time_limit_s=60.0, output=output,
                             poll_s=0.1)
    assert done.killed is None and done.returncode == 2
    assert list(done.peaks) == [scale.process_label([sys.executable, "-c"])] and max(done.peaks.values()) >= 50.0
    assert scale.error_line(output.read_text()) == "refused here"
    assert 0.0 < done.wall_s < 30.0


def test_scale_stage_table_has_every_stage_of_the_finished_bayesmap_runs():
    """One row per stage in the order they ran (a stage only one prefix has: blank cells for the others), two
    columns (seconds, peak MB) per finished bayesmap prefix; Karto's and unfinished runs have no columns."""
    lines = scale.stage_table(_scale_records()).splitlines()
    assert lines[0] == "| stage | 250 scans: s | 250 scans: peak MB | 500 scans: s | 500 scans: peak MB |"
    assert [line.split(" | ")[0] for line in lines[2:]] == ["| read log", "| front end", "| build problem",
                                                            "| loop closure 1/3", "| loop closure 2/3",
                                                            "| round 1/3: map", "| round 1/3: poses",
                                                            "| round 2/3: map", "| final map", "| figures"]
    assert lines[3] == "| front end | 30.0 | 100 | 30.0 | 100 |" and lines[4] == "| build problem |  |  | 1.0 | 7 |"
    assert scale.stage_table([r for r in _scale_records() if r["method"] == "karto"]) == ""


def test_target_at_truth_carries_the_truth_onto_the_first_pose():
    """The truth carried onto another first pose keeps every relative pose and unwraps its headings."""
    import numpy as np
    import target_at_truth

    from bayesmap.slam.posegraph import relative

    rng = np.random.default_rng(0)
    path = np.cumsum(rng.normal(0, 0.3, (6, 3)), axis=0)
    path[:, 2] = np.angle(np.exp(1j * 3 * path[:, 2]))  # wrapped headings
    moved = target_at_truth.in_model_frame(path, np.array([1.0, -2.0, 0.7]))
    np.testing.assert_allclose(moved[0], [1.0, -2.0, 0.7], atol=1e-12)
    np.testing.assert_allclose(relative(moved[:-1], moved[1:]), relative(path[:-1], path[1:]), atol=1e-12)
    assert np.all(np.abs(np.diff(moved[:, 2])) < np.pi)


def test_first_pose_coverage_places_the_truth_by_its_first_pose_only():
    """A truth moved rigidly is inside every ellipse; an offset of the later poses, which a fit to every pose would
    partly absorb, is counted where it lies."""
    import numpy as np
    import step_covariance

    from bayesmap.evaluation.trajectory import ellipse_coverage

    rng = np.random.default_rng(0)
    path = np.cumsum(rng.normal(0, 0.3, (50, 3)), axis=0)
    cov = np.repeat(np.eye(3)[None] * 1e-4, 50, axis=0)  # 1 cm standard deviations
    cov[0] = 0.0  # the fixed first pose
    turn = np.array([[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]])
    truth = np.column_stack([path[:, :2] @ turn.T + [3.0, -2.0], path[:, 2] + 0.7])
    assert step_covariance.first_pose_coverage(path, cov, truth) == 1.0
    shifted = truth.copy()
    shifted[10:, :2] += 0.05  # 5 standard deviations, from the eleventh pose on
    assert step_covariance.first_pose_coverage(path, cov, shifted) == 10 / 50
    assert ellipse_coverage(path, cov, shifted) > 0.5  # a fit to every pose absorbs most of the offset


def test_coverage_ranks_figure_and_table(tmp_path, capsys):
    """Three records (ranks 0, 0.5 and 1) and one without bayesmap's rank (skipped): the figure is written, the
    table has the three runs, and the five bins count them 1, 0, 1, 0, 1 (a rank of 1 in the last bin). A folder
    with no such record, or an existing figure without --force, is one line and exit code 2."""
    runs = tmp_path / "runs"
    runs.mkdir()
    for k, rank in enumerate([0.0, 0.5, 1.0]):
        scores = {"coverage": 0.9 + 0.01 * k, "samples_coverage_min": 0.85, "samples_coverage_median": 0.95,
                  "samples_coverage_max": 0.99, "coverage_rank": rank}
        (runs / f"aces-s{k}.json").write_text(json.dumps({"log": "aces", "seed": k, "bayesmap": scores}))
    (runs / "aces-s9.json").write_text(json.dumps({"log": "aces", "seed": 9, "karto": {"ate_m": 1.0}}))
    png = tmp_path / "ranks.png"
    assert coverage_ranks.main([str(runs), "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| aces s1 | 0.910 | 0.850-0.990 (0.950) | 0.50 |" in out and "aces s9" not in out
    assert "ranks in 5 bins over [0, 1]: 1, 0, 1, 0, 1 (a calibrated posterior: 0.6 each)" in out
    empty = tmp_path / "empty"
    empty.mkdir()
    for args in ([str(empty), "--png", str(tmp_path / "other.png")], [str(runs), "--png", str(png)]):
        with pytest.raises(SystemExit) as exit_info:
            coverage_ranks.main(args)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and ("holds no" in err or "already exists" in err)


def test_path_scale_recovers_a_similarity(tmp_path, capsys):
    """A path that is the truth shrunk by 0.5 % about a point, turned and moved: the truth is 1 / 0.995 times as
    large (+0.503 %), and the similarity leaves no error where the rigid alignment leaves some."""
    import numpy as np

    rng = np.random.default_rng(3)
    truth = np.column_stack([np.cumsum(rng.normal(0, 1, (60, 2)), axis=0), rng.normal(0, 1, 60)])
    c, s = np.cos(0.4), np.sin(0.4)
    path = truth.copy()
    path[:, :2] = 0.995 * (truth[:, :2] - [3.0, -2.0]) @ np.array([[c, -s], [s, c]]).T + [10.0, 4.0]
    scale, rmse = path_scale.similarity_fit(path, truth)
    assert scale == pytest.approx(1 / 0.995, rel=1e-12) and rmse < 1e-9
    np.savez(tmp_path / "aces-s0.npz", mean=path, truth=truth)
    assert path_scale.main([str(tmp_path)]) == 0
    assert "| aces-s0 | +0.503 |" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:
        path_scale.main([str(tmp_path / "none")])
    assert exit_info.value.code == 2


def test_match_bias_local_maps_and_the_beams_a_map_scan_saw():
    import jax.numpy as jnp
    import numpy as np

    travelled = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(match_bias.local_map_scans(travelled, 3, 2.0, "past"), [1, 2])
    np.testing.assert_array_equal(match_bias.local_map_scans(travelled, 3, 2.0, "both"), [1, 2, 4, 5])
    # a map scan at the origin facing +x whose beams read 2 m (a wall at x = 2), its last beam no return; the scan
    # matched stands at (1, 0) facing +x: its endpoints on the wall were seen, one 1 m behind the wall was not (the
    # wall hid it), one behind the map scan's back (outside its field of view) was not, nor one past no return
    angles = jnp.asarray(np.linspace(-np.pi / 2, np.pi / 2, 181))
    map_readings = jnp.full((1, 181), 2.0)
    map_returned = jnp.ones((1, 181), bool).at[0, 180].set(False)
    pose = jnp.asarray([1.0, 0.0, 0.0])
    beams = jnp.asarray([0.0, np.pi / 4, 0.0, np.pi, np.pi / 2])
    readings = jnp.asarray([1.0, np.sqrt(2.0), 2.0, 2.0, 1.0])  # (2, 0), (2, 1), (3, 0), (-1, 0), (1, 1)
    seen = match_bias.seen_beams(pose, beams, readings, jnp.ones(5, bool), jnp.zeros((1, 3)), angles[None],
                                 map_readings, map_returned)
    # (2, 1) is 2.24 m out along a beam that read 2 m: behind the wall's 0.15 m margin; (1, 1) lies at bearing
    # pi/4 from the map scan, 1.41 m out: in front of its 2 m reading
    np.testing.assert_array_equal(np.asarray(seen), [True, False, False, False, True])
    # where the map scan's beam toward an endpoint had no return, the endpoint was not seen
    edge = match_bias.seen_beams(jnp.asarray([0.0, 0.0, 0.0]), jnp.asarray([np.pi / 2]), jnp.asarray([1.0]),
                                 jnp.ones(1, bool), jnp.zeros((1, 3)), angles[None], map_readings, map_returned)
    assert not bool(edge[0])


def test_match_bias_surface_beams_join_only_close_returned_neighbours():
    import jax.numpy as jnp
    import numpy as np

    from bayesmap.geometry.grid import Grid
    from bayesmap.geometry.raycast import scan_endpoints

    # a scan at (1, 2) facing +y: its endpoints 0.1 m apart along a wall, then 0.5 m apart, then a beam with no return
    pose = jnp.asarray([[1.0, 2.0, np.pi / 2]])
    ends = np.array([[0.0, 3.0], [0.1, 3.0], [0.6, 3.0], [0.7, 3.0]])
    v = ends - [1.0, 2.0]
    angles = jnp.asarray(np.arctan2(v[:, 1], v[:, 0]) - np.pi / 2)[None]
    readings = jnp.asarray(np.hypot(v[:, 0], v[:, 1]))[None]
    returned = jnp.asarray([[True, True, True, False]])
    a, r, ok = match_bias.surface_beams(pose, angles, readings, returned, 0.25, 0.05)
    assert a.shape == r.shape == ok.shape == (1, 4 + 3 * 4)
    np.testing.assert_array_equal(np.asarray(ok[0, 4:]).reshape(3, 4).all(axis=1), [True, False, False])
    joined = np.asarray(scan_endpoints(pose, a, r))[0, 4:8]
    np.testing.assert_allclose(joined, [[0.02, 3.0], [0.04, 3.0], [0.06, 3.0], [0.08, 3.0]], atol=1e-6)
    # the fine field gains along the joined segment only; the broad one is the endpoints' alone
    grid = Grid(shape=(60, 60), resolution=0.05, origin=(-1.0, 1.0))
    plain = match_bias.local_map_fields(grid, pose, angles, readings, returned, 0.0)
    surface = match_bias.local_map_fields(grid, pose, angles, readings, returned, 0.25)
    assert np.all(np.asarray(surface[0]) >= np.asarray(plain[0]))
    np.testing.assert_array_equal(np.asarray(surface[1]), np.asarray(plain[1]))
    (i, j), (k, m) = (np.floor(np.asarray(grid.to_cell_coords(jnp.asarray(p))) + 0.5).astype(int)
                      for p in ([0.05, 3.0], [0.35, 3.0]))
    assert float(surface[0][i, j]) > float(plain[0][i, j]) and float(surface[0][i, j]) > 0.8
    assert float(surface[0][k, m]) == float(plain[0][k, m])  # the 0.5 m gap stays open
