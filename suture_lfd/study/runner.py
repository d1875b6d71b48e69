"""
Run a study's jobs: in this process or in a pool of worker processes, with progress and resume.

A job is a small picklable ``dict`` with ``key`` (unique name) and ``kind``; a job function
(module-level, so worker processes can import it) turns it into a result record (``dict``).
Jobs run in stages (the demonstrations before the throws learnt from them); within a stage they
run in any order, ``workers`` at a time. Every finished record is appended to the
:class:`~suture_lfd.study.store.ResultStore` by this (the parent) process only, so a kill at any
moment loses at most the jobs that were running. Jobs whose key is already stored without an
``error`` are not run again.

Worker processes are started with ``spawn`` (each builds its own PyBullet simulations) and
ignore SIGINT; the parent stops them when it is interrupted (SIGINT, or SIGTERM, which it turns
into the same :class:`KeyboardInterrupt`).
"""

import contextlib
import logging
import multiprocessing
import os
import shutil
import signal
import sys
import time
import traceback

_LOG = logging.getLogger(__name__)


def _format_duration(seconds):
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

    def __init__(self, total, done=0, stream=None, every=None, clock=time.monotonic):
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
    def elapsed(self):
        """Wall time (s) since this run started."""
        return self.clock() - self.start

    @property
    def rate(self):
        """Jobs per second finished by this run (0 before the first)."""
        ran = self.done - self.resumed
        return ran / self.elapsed if ran > 0 and self.elapsed > 0 else 0.0

    def line(self, label=''):
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

    def advance(self, label='', n=1):
        """Count ``n`` finished jobs and print a line if it is time to."""
        self.done += n
        now = self.clock()
        if now - self._last >= self.every or self.done >= self.total:
            self._last = now
            if self.terminal:
                self._redraw(label)
            else:
                print(self.line(label), file=self.stream, flush=True)

    def _redraw(self, label):
        """Draw the progress bar over the previous one (a new line when the run is done)."""
        width = 20
        filled = int(width * self.done / self.total) if self.total else width
        bar = '#' * filled + '-' * (width - filled)
        text = f'[{bar}] ' + self.line(label).removeprefix('study: ')
        columns = shutil.get_terminal_size((100, 20)).columns
        end = '\n' if self.done >= self.total else ''
        self.stream.write('\r\033[K' + text[:columns - 1] + end)
        self.stream.flush()

    def finish(self):
        """End the bar's line on a terminal (before other output follows it)."""
        if self.terminal and self.done < self.total:
            self.stream.write('\n')
            self.stream.flush()


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def call_job(job_fn, job):
    """Run one job; an exception becomes a record with ``error`` (the traceback's last line)."""
    t0 = time.perf_counter()
    try:
        record = job_fn(job)
    except Exception as exc:  # noqa: BLE001 -- one broken throw must not stop the study
        _LOG.error('job %s failed:\n%s', job['key'], traceback.format_exc())
        record = {**job, 'error': f'{type(exc).__name__}: {exc}'}
    record.setdefault('error', '')
    record['wall_s'] = time.perf_counter() - t0
    return record


class Terminated(KeyboardInterrupt):
    """A SIGTERM that stops the run, handled as Ctrl-C is (``signum``: the signal)."""

    signum = signal.SIGTERM


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Turn SIGTERM into a KeyboardInterrupt (:class:`Terminated`) while the block runs."""
    def handler(signum, frame):
        raise Terminated(f'signal {signum}')

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def pending(jobs, store):
    """Return the jobs not yet stored (or stored with an error), in order."""
    out = []
    for job in jobs:
        record = store.records.get(job['key'])
        if record is None or record.get('error'):
            out.append(job)
    return out


def run_stages(stages, job_fn, store, workers=1, progress=None, initializer=None, initargs=()):
    """
    Run the pending jobs of every stage, stage after stage, and store their records.

    Parameters
    ----------
    stages : list of list of dict
        Jobs per stage; a stage starts when the one before it has finished.
    job_fn : callable
        Module-level function ``job -> record``.
    store : suture_lfd.study.store.ResultStore
        Where finished records go (and which jobs are already done).
    workers : int
        Parallel worker processes (1: run in this process).
    progress : Progress, optional
        Advanced once per finished job.
    initializer : callable, optional
        Module-level function run once in each worker (and here when ``workers == 1``).
    initargs : tuple
        Its arguments.

    Returns
    -------
    int
        Jobs run by this call.

    Raises
    ------
    KeyboardInterrupt
        On SIGINT or SIGTERM; every record finished before it is stored.

    """
    ran = 0
    todo = [pending(stage, store) for stage in stages]
    if not any(todo):
        return 0
    with sigterm_as_interrupt():
        if workers <= 1:
            if initializer is not None:
                initializer(*initargs)
            for stage in todo:
                for job in stage:
                    record = call_job(job_fn, job)
                    store.add(record)
                    ran += 1
                    if progress is not None:
                        progress.advance(job['key'])
            return ran
        ctx = multiprocessing.get_context('spawn')
        with _one_blas_thread():
            pool = ctx.Pool(workers, initializer=_init_worker, initargs=(initializer, initargs))
        try:
            for stage in todo:
                if not stage:
                    continue
                # chunksize 1: a long job never holds finished ones back from the store.
                for record in pool.imap_unordered(_JobCall(job_fn), stage, chunksize=1):
                    store.add(record)
                    ran += 1
                    if progress is not None:
                        progress.advance(record['key'])
            pool.close()
        except BaseException:
            pool.terminate()
            raise
        finally:
            pool.join()
    return ran


# Thread counts of the BLAS libraries, read when NumPy loads them in a worker process.
_BLAS_THREADS = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


@contextlib.contextmanager
def _one_blas_thread():
    """
    Start worker processes with one BLAS thread each, as Dask starts its workers.

    The workers already keep every core busy; a job's few larger linear-algebra calls (the
    least-squares fit of a DMP) split over threads cost several times their CPU on a loaded
    machine, and give the same results. A thread count the user set is kept.
    """
    added = [name for name in _BLAS_THREADS if name not in os.environ]
    for name in added:
        os.environ[name] = '1'
    try:
        yield
    finally:
        for name in added:
            os.environ.pop(name, None)


def _init_worker(initializer, initargs):
    _ignore_sigint()
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


class _JobCall:
    """Picklable ``job -> call_job(job_fn, job)``."""

    def __init__(self, job_fn):
        self.job_fn = job_fn

    def __call__(self, job):
        return call_job(self.job_fn, job)
