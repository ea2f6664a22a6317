"""The benchmarks' own helpers: the trace reader of ``benchmarks/sweep_cost.py --profile`` and the selection rules
of ``benchmarks/map_cv.py``."""

import gzip
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import map_cv  # noqa: E402
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
