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

A :class:`StageRecorder` wraps any callback and notes each stage's wall time and peak resident memory (what
summary.json's ``"stages"`` hold); the runs layer marks its own stages with :func:`start_stage`.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import IO, Callable, NamedTuple, Optional, Protocol


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


MB = 1e6
"""Bytes in a megabyte of the stage records (decimal, as the size refusal's gigabytes)."""


class PeakMemory(Protocol):
    """A reader of the process's peak resident memory: :class:`ProcessPeak`, or a fake in tests."""

    per_stage: bool
    """True when :meth:`reset` starts a new peak (the peak of a stage), False when the peak is the process's."""

    def reset(self) -> None:
        """Start a new peak at the memory resident now (nothing where that is not possible)."""

    def peak_mb(self) -> float:
        """The peak resident set size, MB, since the last :meth:`reset` (or the process's start)."""


class ProcessPeak:
    """This process's peak resident set size (RSS).

    On Linux, where ``/proc/self/clear_refs`` can be written, :meth:`reset` writes ``"5"`` to it, which sets the
    process's high-water mark to its resident memory now, and :meth:`peak_mb` reads the mark (``VmHWM`` of
    ``/proc/self/status``): the peak since the last reset (``per_stage`` True; see proc(5), "clear_refs"). The
    reset is the kernel's one mark for the whole process: ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` falls with
    it, so a caller that reads its own peak after a recorded run, or a parent that reads the process's at its exit
    (``wait4``, ``/usr/bin/time -v``'s "Maximum resident set size"), sees only the peak since the last stage began;
    the whole run's is :attr:`StageRecorder.peak_rss_mb` (summary.json's ``"peak_rss_mb"``).
    Elsewhere (or where the write fails) :meth:`reset` does nothing and :meth:`peak_mb` is ``ru_maxrss``, the
    process's peak since it started (``per_stage`` False).

    Args:
        proc: the process's ``/proc`` folder (a test may point elsewhere).
    """

    def __init__(self, proc: Path = Path("/proc/self")):
        self._proc = Path(proc)
        self.per_stage = (os.access(self._proc / "clear_refs", os.W_OK)
                          and (self._proc / "status").is_file() and self._hwm_kb() is not None)

    def _hwm_kb(self) -> Optional[int]:
        """``VmHWM`` of the status file, kB (1024 bytes), or None where it cannot be read."""
        try:
            for line in (self._proc / "status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
        except (OSError, ValueError, IndexError):
            return None
        return None

    def reset(self) -> None:
        """Set the high-water mark to the memory resident now (Linux); where the write fails, fall back for good
        to the process's peak (``per_stage`` becomes False)."""
        if not self.per_stage:
            return
        try:
            (self._proc / "clear_refs").write_text("5")
        except OSError:
            self.per_stage = False

    def peak_mb(self) -> float:
        """The peak resident set size in MB: since the last :meth:`reset` (``VmHWM``), or the process's
        (``ru_maxrss``: kB on Linux, bytes on macOS)."""
        kb = self._hwm_kb() if self.per_stage else None
        if kb is not None:
            return kb * 1024 / MB
        import resource  # (POSIX only: library modules that import this module need not have it)

        maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return maxrss / MB if sys.platform == "darwin" else maxrss * 1024 / MB


class StageRecord(NamedTuple):
    """One stage of a run: its name, wall ``seconds`` and peak resident memory ``peak_rss_mb`` (MB, 10**6
    bytes)."""

    stage: str
    seconds: float
    peak_rss_mb: float


class StageRecorder:
    """A :data:`ProgressCallback` that forwards every report to ``progress`` and notes, per stage, the wall time
    and the peak resident memory.

    A stage begins at its first report (a report whose stage or total differs from the last one's, or whose
    ``done`` went back, as :class:`ProgressBar` opens a bar) or at :meth:`start` (:func:`start_stage`: the
    caller's own stages, such as reading the log or drawing the figures, which are not forwarded), and lasts until
    the next stage begins or :meth:`finish`: the stages tile the time from the first start to the finish, so they
    add up to it. Time a library function spends before its first report counts in the stage before it.

    Memory: at each stage's start the process's high-water mark is reset and at its end read
    (:class:`ProcessPeak`): on Linux each stage's ``peak_rss_mb`` is the peak during that stage (the memory
    resident at its start included), elsewhere the process's peak so far (``memory.per_stage`` says which).
    :attr:`peak_rss_mb` is the whole process's: the largest of the stages' and the peak before the first stage.

    Example::

        stages = StageRecorder(bar)
        start_stage(stages, "read log")
        log = read_carmen(path)
        result = run_log_slam(problem, progress=stages)  # its stages, forwarded to bar
        summary.update(stages.summary())  # {"stages": [...], "peak_rss_mb": ...}

    Args:
        progress: the callback the reports are forwarded to; None: none.
        clock: seconds, monotonic (default ``time.perf_counter``; a test gives a fake).
        memory: the :class:`PeakMemory` read (default :class:`ProcessPeak`).
    """

    def __init__(self, progress: Optional[ProgressCallback] = None, clock: Callable[[], float] = time.perf_counter,
                 memory: Optional[PeakMemory] = None):
        self.progress = progress
        self.memory = ProcessPeak() if memory is None else memory
        self._clock = clock
        self._records: list[StageRecord] = []
        self._stage: Optional[str] = None
        self._key: Optional[tuple[str, int]] = None
        self._started = self._done = 0
        self._before_mb = self.memory.peak_mb()

    def __call__(self, progress: Progress) -> None:
        key = (progress.stage, progress.total)
        if self._stage is None or key != self._key or progress.done < self._done:
            self.start(progress.stage)
            self._key = key
        self._done = progress.done
        if self.progress is not None:
            self.progress(progress)

    def start(self, stage: str) -> None:
        """End the current stage, if any, and begin ``stage`` now (the high-water mark reset); starting again the
        caller's stage that is running continues it."""
        if stage == self._stage and self._key is None:
            return
        now = self._clock()
        self._close(now)
        self.memory.reset()
        self._stage, self._key, self._started, self._done = stage, None, now, 0

    def _close(self, now: float) -> None:
        if self._stage is not None:
            self._records.append(StageRecord(self._stage, now - self._started, self.memory.peak_mb()))
            self._stage = None

    def finish(self) -> list[StageRecord]:
        """End the current stage, if any, and return every stage so far, in order (a later report or
        :meth:`start` begins a new one)."""
        self._close(self._clock())
        return list(self._records)

    @property
    def peak_rss_mb(self) -> float:
        """The process's peak resident memory, MB, over the stages ended and before the first."""
        return max([self._before_mb] + [r.peak_rss_mb for r in self._records])

    def summary(self) -> dict:
        """:meth:`finish`, as summary.json holds it: ``{"stages": [{"stage", "seconds", "peak_rss_mb"}, ...],
        "peak_rss_mb": ...}``, seconds to the millisecond, MB to a tenth."""
        records = self.finish()
        return {"stages": [{"stage": r.stage, "seconds": round(r.seconds, 3), "peak_rss_mb": round(r.peak_rss_mb, 1)}
                           for r in records],
                "peak_rss_mb": round(self.peak_rss_mb, 1)}


def start_stage(progress: Optional[ProgressCallback], stage: str) -> None:
    """Begin the caller's own ``stage`` on ``progress`` if it is a :class:`StageRecorder`; nothing for any other
    callback (bars draw only the counted stages of the library) or None."""
    if isinstance(progress, StageRecorder):
        progress.start(stage)


def stage_summary(progress: Optional[ProgressCallback]) -> dict:
    """:meth:`StageRecorder.summary` of ``progress`` if it is a recorder, else ``{}``."""
    return progress.summary() if isinstance(progress, StageRecorder) else {}
