"""The progress drawer of the front ends (one tqdm bar per stage, nothing for short work) and the stage recorder
(each stage's wall time and peak memory, forwarding every report)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from bayesmap.progress import (
    MB,
    ProcessPeak,
    Progress,
    ProgressBar,
    StageRecorder,
    report,
    stage_summary,
    start_stage,
)


def drawn(reports, delay=0.0) -> str:
    """What a ProgressBar draws for ``reports`` (a list of Progress), as the text of every refresh."""
    out = io.StringIO()
    with ProgressBar(delay=delay, file=out, leave=True) as bar:  # (leave: each bar's last state is drawn)
        for p in reports:
            bar(p)
    return out.getvalue()


def test_one_bar_per_stage_with_its_unit_and_count():
    """Each stage gets its own bar (its description, total and unit, with tqdm's rate), opened by the stage's first
    report and closed when the next stage starts; the count follows ``done``."""
    text = drawn([Progress("front end", d, 3, "scan") for d in range(4)]
                 + [Progress("final map", d, 5) for d in range(6)])
    assert "front end" in text and "3/3" in text and "scan/s" in text
    assert "final map" in text and "5/5" in text and "sweep/s" in text
    assert text.index("3/3") < text.index("final map")  # the first bar ends before the second starts


def test_a_repeated_stage_that_starts_over_gets_a_new_bar():
    """Two runs in a row with the same stage name: ``done`` going back opens a new bar instead of counting down
    (tqdm would draw a negative update); a new total does too."""
    text = drawn([Progress("sweeps", d, 2) for d in (0, 1, 2, 0, 1, 2)] + [Progress("sweeps", 0, 7)])
    assert text.count("2/2") >= 2 and "0/7" in text


def test_work_under_the_delay_draws_nothing_and_none_reports_nothing():
    """A stage that ends within the delay draws nothing (tqdm's delay); ``report`` with None calls nothing."""
    assert drawn([Progress("quick", d, 3) for d in range(4)], delay=60.0) == ""
    report(None, "sweeps", 1, 2)
    seen = []
    report(seen.append, "sweeps", 1, 2, "sweep")
    assert seen == [Progress("sweeps", 1, 2, "sweep")]


class FakeClock:
    """Seconds that move only when told (``tick``)."""

    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def tick(self, seconds: float) -> None:
        self.now += seconds


class FakeMemory:
    """A peak that a test sets (``touch``); ``reset`` brings it down to the memory resident now, as clear_refs."""

    per_stage = True

    def __init__(self, resident: float = 50.0):
        self.resident, self.peak, self.resets = resident, 80.0, 0  # 80: the process's peak before the recorder

    def touch(self, mb: float, then: float) -> None:
        """Reach ``mb`` resident, then fall back to ``then``."""
        self.peak, self.resident = max(self.peak, mb), then

    def reset(self) -> None:
        self.peak, self.resets = self.resident, self.resets + 1

    def peak_mb(self) -> float:
        return self.peak


def test_recorder_notes_each_stage_in_order_and_forwards_every_report():
    """The runs layer's stage, two library stages and the runs layer's again: each lasts from its first report (or
    start) to the next one's, so the seconds tile the clock's 1 + 2 + 3 + 0.5 s; the peaks are each stage's own
    (the reset brings the peak down to what is resident), the run's the largest, the stage's reports all forwarded
    unchanged and in order, the caller's stages not."""
    clock, memory, seen = FakeClock(), FakeMemory(), []
    recorder = StageRecorder(seen.append, clock=clock, memory=memory)
    reports = [Progress("front end", d, 2, "scan") for d in range(3)] + [Progress("final map", d, 4) for d in range(5)]
    start_stage(recorder, "read log")
    clock.tick(1.0)
    memory.touch(300.0, then=120.0)
    for p in reports[:3]:
        recorder(p)
        clock.tick(1.0)  # the front end: 3 reports, 1 s after each
    memory.touch(900.0, then=200.0)
    for p in reports[3:]:
        recorder(p)
        clock.tick(0.6)
    start_stage(recorder, "figures")
    clock.tick(0.5)
    records = recorder.finish()
    assert seen == reports
    assert [r.stage for r in records] == ["read log", "front end", "final map", "figures"]
    assert [r.seconds for r in records] == pytest.approx([1.0, 3.0, 3.0, 0.5])
    assert sum(r.seconds for r in records) == pytest.approx(7.5)
    assert [r.peak_rss_mb for r in records] == [300.0, 900.0, 200.0, 200.0]
    assert memory.resets == 4 and recorder.peak_rss_mb == 900.0
    summary = recorder.summary()  # finished already: the same stages, as summary.json holds them
    assert summary["stages"][1] == {"stage": "front end", "seconds": 3.0, "peak_rss_mb": 900.0}
    assert summary["peak_rss_mb"] == 900.0 and len(summary["stages"]) == 4


def test_recorder_splits_a_stage_that_starts_over_and_continues_a_caller_stage():
    """A stage whose ``done`` goes back (two runs in a row) or whose total changes is a new stage, as a new bar; a
    caller's stage started again while it runs continues; the peak before the first stage counts in the run's."""
    clock, memory = FakeClock(), FakeMemory()
    recorder = StageRecorder(None, clock=clock, memory=memory)
    recorder.start("figures")
    clock.tick(1.0)
    recorder.start("figures")
    clock.tick(1.0)
    for p in (Progress("sweeps", 0, 2), Progress("sweeps", 2, 2), Progress("sweeps", 0, 2), Progress("sweeps", 0, 3)):
        recorder(p)
        clock.tick(0.25)
    records = recorder.finish()
    assert [(r.stage, r.seconds) for r in records] == [("figures", 2.0), ("sweeps", 0.5), ("sweeps", 0.25),
                                                       ("sweeps", 0.25)]
    assert recorder.peak_rss_mb == 80.0  # no stage went above the process's peak before the recorder


def test_start_stage_and_stage_summary_touch_only_a_recorder():
    """Other callbacks (a bar, a list's append) and None get no stage and no summary."""
    seen = []
    start_stage(seen.append, "read log")
    start_stage(None, "read log")
    assert seen == [] and stage_summary(seen.append) == {} and stage_summary(None) == {}


@pytest.mark.skipif(not ProcessPeak().per_stage, reason="needs Linux's /proc/self/clear_refs")
def test_process_peak_is_the_peak_of_each_stage_on_linux():
    """A stage that fills 200 MB and frees them peaks at least 190 MB above the stage before it (the pages touched;
    numpy and the interpreter move a few MB either way); the next stage starts from the memory resident after the
    free and peaks well under it: the high-water mark was reset at its start."""
    recorder = StageRecorder()
    recorder.start("idle")
    recorder.start("big")
    block = np.ones(200 * 10**6 // 8)
    del block
    recorder.start("small")
    idle, big, small = recorder.finish()
    assert big.peak_rss_mb >= idle.peak_rss_mb + 190.0 and small.peak_rss_mb < big.peak_rss_mb - 150.0
    assert recorder.peak_rss_mb >= big.peak_rss_mb


def test_process_peak_falls_back_to_the_process_peak(tmp_path):
    """Without a writable clear_refs (here a folder with none), no reset, and the peak is ru_maxrss: the process's
    peak so far, in MB (kB on Linux)."""
    import resource
    import sys

    memory = ProcessPeak(proc=tmp_path)
    memory.reset()
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    expected = maxrss / MB if sys.platform == "darwin" else maxrss * 1024 / MB
    assert not memory.per_stage and memory.peak_mb() == pytest.approx(expected, rel=0.05)
