"""Progress of long work, reported through a callback: library code reports, front ends draw.

A long function of bayesmap (a chain of many sweeps, the SLAM pipeline's stages) takes ``progress``, a
:data:`ProgressCallback` or None, and calls it with a :class:`Progress` when a stage starts (``done`` 0) and after
each unit of work: a sweep, a scan. It never draws anything itself: the command line draws tqdm bars with a rate and
an ETA (:class:`ProgressBar`), the app its own bar, a test may record the calls. ``None`` reports nothing.

Example::

    def show(p: Progress) -> None:
        print(f"{p.stage}: {p.done}/{p.total} {p.unit}s")

    run_inference(problem, "cellwise", 100, progress=show)

    with ProgressBar() as bar:  # one tqdm bar per stage, on stderr
        run_log_slam(problem, progress=bar)
"""

from __future__ import annotations

import sys
from typing import IO, Callable, NamedTuple, Optional


class Progress(NamedTuple):
    """One report of progress.

    Attributes:
        stage: what is running, for a person: ``"sweeps"``, ``"front end"``, ``"round 2/3: map"``, ``"final map"``.
            A new stage starts a new count.
        done: units of this stage finished, ``0 <= done <= total``.
        total: units in this stage, >= 1.
        unit: the unit counted, singular: ``"sweep"``, ``"scan"``, ``"stage"``.
    """

    stage: str
    done: int
    total: int
    unit: str = "sweep"


ProgressCallback = Callable[[Progress], None]
"""A function that takes a :class:`Progress`; called from the thread that does the work."""


def report(progress: Optional[ProgressCallback], stage: str, done: int, total: int, unit: str = "sweep") -> None:
    """Call ``progress`` with ``Progress(stage, done, total, unit)``; nothing when ``progress`` is None."""
    if progress is not None:
        progress(Progress(stage, int(done), int(total), unit))


class ProgressBar:
    """A :data:`ProgressCallback` that draws the reports as tqdm bars (a count, a rate and an ETA), one bar per
    stage: a report whose stage or total differs from the last one's, or whose ``done`` went back, closes the bar
    and opens the next stage's (description the stage, unit its unit). A stage that ends within ``delay`` seconds
    draws nothing (tqdm's ``delay``). A context manager: entering gives the callback, leaving closes the last bar.

    Example::

        with ProgressBar() as bar:
            run_log_slam(problem, progress=bar)

    Args:
        delay: seconds a stage runs before its bar appears.
        file: where the bars are drawn; default ``sys.stderr`` (at the time of drawing).
        leave: keep a stage's finished bar on screen; default: erase it when the next stage starts.
    """

    def __init__(self, delay: float = 1.0, file: IO[str] | None = None, leave: bool = False):
        self.delay, self.file, self.leave = delay, file, leave
        self._bar = None
        self._key: tuple[str, int] | None = None

    def __call__(self, progress: Progress) -> None:
        from tqdm import tqdm  # (only front ends draw: library modules that import this module do not need it)

        key = (progress.stage, progress.total)
        if self._bar is None or key != self._key or progress.done < self._bar.n:
            self.close()
            self._bar = tqdm(total=progress.total, desc=progress.stage, unit=progress.unit, delay=self.delay,
                             file=self.file if self.file is not None else sys.stderr, leave=self.leave)
            self._key = key
        self._bar.update(progress.done - self._bar.n)

    def close(self) -> None:
        """Close the current stage's bar, if any (a later report opens a new one)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
