"""The benchmarks' own helpers: the trace reader of ``benchmarks/sweep_cost.py --profile``."""

import gzip
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
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
