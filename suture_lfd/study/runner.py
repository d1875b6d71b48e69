"""
Run a study's jobs: in this process or in a pool of worker processes, with progress and resume.

A job is a small picklable frozen dataclass (:mod:`suture_lfd.study.records`) with ``key`` (its
name in the study), ``id`` (what decides its result, :mod:`suture_lfd.study.keys`) and
``failed(error)`` (its record as an error); a job function (module-level, so worker processes
can import it) turns a job and its process's state (what the stage's initializer returned, None
without one) into its result record (a frozen dataclass with ``id``, ``key``, ``error``,
``wall_s`` and ``cpu_s``). Jobs run in stages (the
demonstrations before the throws learnt from them); within a stage they run in any order,
``workers`` at a time (:class:`~suture_lfd.study.pool.WorkerPool`). Every finished record is
appended to the :class:`~suture_lfd.study.store.ResultStore` by this (the parent) process only,
so a kill at any moment loses at most the jobs that were running. Jobs whose ``id`` is already
stored without an ``error`` are not run again.

SIGINT and SIGTERM stop a run the same way (:mod:`suture_lfd.study.signals`): no new job is
handed out, the records stored stay, the workers are stopped and
:class:`~suture_lfd.study.signals.Interrupted` is raised.
"""

from collections.abc import Callable, Sequence
from dataclasses import replace
import logging
import shutil
import sys
import time
import traceback
from typing import IO, Any

from suture_lfd.study.pool import WorkerPool
from suture_lfd.study.records import RunJob, RunRecord
from suture_lfd.study.signals import stop_on_signals
from suture_lfd.study.store import ResultStore

_LOG = logging.getLogger(__name__)


def _format_duration(seconds: float) -> str:
    seconds = int(round(max(seconds, 0.0)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f'{h}:{m:02d}:{s:02d}' if h else f'{m}:{s:02d}'


class Progress:
    """
    Progress of a long run: jobs done, rate, elapsed time and time left.

    On a terminal it is one line redrawn in place with a bar; otherwise (a log file, a pipe)
    plain lines, one every ``every`` seconds (30 s by default: a 10-minute run gives about 20).

    Parameters
    ----------
    total : int
        Jobs of the whole study.
    done : int
        Jobs already finished before this run (resumed).
    stream : file-like, optional
        Where the lines go (default ``sys.stderr``).
    every : float, optional
        Shortest time (s) between two updates (the last job always prints); default 0.5 s on
        a terminal, 30 s otherwise.
    clock : callable, optional
        Wall clock (default ``time.monotonic``).

    """

    def __init__(self, total: int, done: int = 0, stream: IO[str] | None = None,
                 every: float | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.total = int(total)
        self.done = int(done)
        self.resumed = int(done)
        self.stream = stream if stream is not None else sys.stderr
        isatty = getattr(self.stream, 'isatty', None)
        self.terminal = bool(isatty and isatty())
        self.every = float(every if every is not None else 0.5 if self.terminal else 30.0)
        self.clock = clock
        self.start = clock()
        self._last = -1e30

    @property
    def elapsed(self) -> float:
        """Wall time (s) since this run started."""
        return self.clock() - self.start

    @property
    def rate(self) -> float:
        """Jobs per second finished by this run (0 before the first)."""
        ran = self.done - self.resumed
        return ran / self.elapsed if ran > 0 and self.elapsed > 0 else 0.0

    def line(self, label: str = '') -> str:
        """Return the current progress line."""
        pct = 100.0 * self.done / self.total if self.total else 100.0
        rate = self.rate
        left = (self.total - self.done) / rate if rate > 0 else float('nan')
        left_text = _format_duration(left) if left == left else '?'
        text = (f'study: {self.done}/{self.total} throws done ({pct:.1f} %), '
                f'{rate:.3f} throws/s, elapsed {_format_duration(self.elapsed)}, '
                f'left ~{left_text}')
        if self.resumed:
            text += f' ({self.resumed} resumed)'
        return text + (f' [{label}]' if label else '')

    def advance(self, label: str = '', n: int = 1) -> None:
        """Count ``n`` finished jobs and print a line if it is time to."""
        self.done += n
        now = self.clock()
        if now - self._last >= self.every or self.done >= self.total:
            self._last = now
            if self.terminal:
                self._redraw(label)
            else:
                print(self.line(label), file=self.stream, flush=True)

    def _redraw(self, label: str) -> None:
        """Draw the progress bar over the previous one (a new line when the run is done)."""
        width = 20
        filled = int(width * self.done / self.total) if self.total else width
        bar = '#' * filled + '-' * (width - filled)
        text = f'[{bar}] ' + self.line(label).removeprefix('study: ')
        columns = shutil.get_terminal_size((100, 20)).columns
        end = '\n' if self.done >= self.total else ''
        self.stream.write('\r\033[K' + text[:columns - 1] + end)
        self.stream.flush()

    def finish(self) -> None:
        """End the bar's line on a terminal (before other output follows it)."""
        if self.terminal and self.done < self.total:
            self.stream.write('\n')
            self.stream.flush()


def call_job(job_fn: Callable[[Any, Any], RunRecord], job: RunJob, state: Any = None
             ) -> RunRecord:
    """
    Run ``job_fn(job, state)``; an exception becomes an ``error`` record (its last line).

    The record gets ``wall_s`` and ``cpu_s``: the job's wall time and its process's CPU time
    (s), the latter a measure a loaded machine barely disturbs.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        record = job_fn(job, state)
    except Exception as exc:  # noqa: BLE001 -- one broken throw must not stop the study
        _LOG.error('job %s failed:\n%s', job.key, traceback.format_exc())
        record = job.failed(f'{type(exc).__name__}: {exc}')
    return replace(record, wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0)


def pending(jobs: Sequence[RunJob], store: ResultStore) -> list[RunJob]:
    """Return the jobs whose result is not stored yet (or stored with an error), in order."""
    out = []
    for job in jobs:
        record = store.records.get(job.id)
        if record is None or record.error:
            out.append(job)
    return out


def run_stages(stages: Sequence[Sequence[RunJob]], job_fn: Callable[[Any, Any], RunRecord],
               store: ResultStore, workers: int = 1, progress: Progress | None = None,
               initializer: Callable[..., Any] | None = None, initargs: tuple[Any, ...] = ()
               ) -> int:
    """
    Run the pending jobs of every stage, stage after stage, and store their records.

    Parameters
    ----------
    stages : list of list of job
        Jobs per stage; a stage starts when the one before it has finished.
    job_fn : callable
        Module-level function ``(job, state) -> record``.
    store : suture_lfd.study.store.ResultStore
        Where finished records go (and which jobs are already done).
    workers : int
        Parallel worker processes (1: run in this process).
    progress : Progress, optional
        Advanced once per finished job.
    initializer : callable, optional
        Module-level function run once in each worker (and here when ``workers == 1``); what
        it returns is the ``state`` of that process's jobs (one with a ``close()`` method is
        closed when a run in this process ends).
    initargs : tuple
        Its arguments.

    Returns
    -------
    int
        Jobs run by this call.

    Raises
    ------
    suture_lfd.study.signals.Interrupted
        On SIGINT or SIGTERM (a :class:`KeyboardInterrupt`); every record finished before it
        is stored and the workers are stopped.
    suture_lfd.study.pool.PoolError
        A worker process died before it took a job.

    """
    todo = [pending(stage, store) for stage in stages]
    if not any(todo):
        return 0
    ran = 0

    def keep(record: RunRecord) -> None:
        nonlocal ran
        store.add(record)
        ran += 1
        if progress is not None:
            progress.advance(record.key)

    with stop_on_signals() as stop:
        if workers <= 1:
            state = initializer(*initargs) if initializer is not None else None
            try:
                for stage in todo:
                    for job in stage:
                        record = call_job(job_fn, job, state)  # a signal stops it where it is
                        with stop.deferred():
                            keep(record)
                        stop.check()
            finally:
                close = getattr(state, 'close', None)
                if close is not None:
                    close()
            return ran
        with stop.deferred(), WorkerPool(workers, _JobCall(job_fn), initializer,
                                         initargs) as pool:
            for stage in todo:
                pool.run(stage, keep, stop)
        stop.check()
    return ran


class _JobCall:
    """Picklable ``(job, state) -> call_job(job_fn, job, state)``."""

    def __init__(self, job_fn: Callable[[Any, Any], RunRecord]) -> None:
        self.job_fn = job_fn

    def __call__(self, job: RunJob, state: Any = None) -> RunRecord:
        return call_job(self.job_fn, job, state)
