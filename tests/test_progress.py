"""The progress drawer of the front ends: one tqdm bar per stage, nothing for short work."""

from __future__ import annotations

import io

from bayesmap.progress import Progress, ProgressBar, report


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
