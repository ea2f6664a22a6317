"""Progress of long work, reported through a callback: library code reports, front ends draw.

A long function of bayesmap (a chain of many sweeps, the SLAM pipeline's stages) takes ``progress``, a
:data:`ProgressCallback` or None, and calls it with a :class:`Progress` after each unit of work: a sweep, a scan,
a stage. It never draws anything itself: the command line draws a tqdm bar with a rate and an ETA, the app its own
bar, a test may record the calls. ``None`` reports nothing.

Example::

    def show(p: Progress) -> None:
        print(f"{p.stage}: {p.done}/{p.total} {p.unit}s")

    run_inference(problem, "cellwise", 100, progress=show)
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional


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
