"""
The local engine's worker processes: one job at a time each, no helper threads.

:class:`WorkerPool` starts ``workers`` processes with ``spawn`` (each builds its own PyBullet
simulations) and talks to each over a pipe of its own: the driver sends a job to an idle worker
only, and waits on the workers' pipes and process sentinels together
(:func:`multiprocessing.connection.wait`) in its main thread, a fraction of a second at a time,
so it sees at once a record coming back, a worker that died, and a stop asked for by a signal
(:mod:`suture_lfd.study.signals`). There is no task or result thread that could block on the
pipe of a dead worker (``multiprocessing.Pool`` keeps two, and its ``terminate`` waits for them).

A worker that dies while running a job (a crash, the kernel's OOM killer) makes that job an
error record, stored and run again on resume, and a new worker takes its place; a worker that
dies before it took a job (its initializer failed) stops the run with :class:`PoolError`.

Workers ignore SIGINT (Ctrl-C reaches the whole process group; the driver decides) and exit on
SIGTERM (a study's via-ros workers first stop their nodes). :meth:`WorkerPool.close` with
``stop=True`` sends them SIGTERM, waits :data:`~suture_lfd.study.signals.STOP_GRACE_S` and kills
what is left.
"""

import collections
from collections.abc import Callable, Iterator, Sequence
import contextlib
from dataclasses import replace
import logging
import multiprocessing
from multiprocessing.connection import Connection, wait
import os
import signal
import time
from types import TracebackType
from typing import Any

from suture_lfd.study.records import RunJob, RunRecord
from suture_lfd.study.signals import STOP_GRACE_S, StopRequest, wait_gone

_LOG = logging.getLogger(__name__)

#: Longest time (s) the driver waits for a worker before it looks at the stop request again.
POLL_S = 0.1
# Thread counts of the BLAS libraries, read when NumPy loads them in a worker process.
_BLAS_THREADS = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


class PoolError(RuntimeError):
    """The worker processes cannot run jobs (a worker died before it took one)."""


@contextlib.contextmanager
def _one_blas_thread() -> Iterator[None]:
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


def _worker_main(conn: Connection, call: Callable[[RunJob, Any], RunRecord],
                 initializer: Callable[..., Any] | None, initargs: tuple[Any, ...]) -> None:
    """Run the initializer, then every job the driver sends, until None (a worker process)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    state = initializer(*initargs) if initializer is not None else None
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):  # the driver is gone
            return
        if job is None:
            return
        conn.send(call(job, state))


class _Worker:
    """One worker process, its end of the pipe and the job it runs (None: idle)."""

    def __init__(self, ctx: Any, call: Callable[[RunJob, Any], RunRecord],
                 initializer: Callable[..., Any] | None, initargs: tuple[Any, ...]) -> None:
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_worker_main, args=(child, call, initializer, initargs),
                                   daemon=True)
        self.process.start()
        child.close()  # only the worker holds its end: its death reads as EOF here
        self.job: RunJob | None = None
        self.started = False  # has taken a job

    def send(self, job: RunJob) -> None:
        self.conn.send(job)
        self.job = job
        self.started = True


class WorkerPool:
    """
    Worker processes that run one job at a time each.

    Parameters
    ----------
    workers : int
        Number of processes.
    call : callable
        Picklable ``(job, state) -> record``, run in the workers.
    initializer : callable, optional
        Module-level function run once in each worker before its first job; what it returns
        is the ``state`` given to every job of that worker (None without one).
    initargs : tuple
        Its arguments.

    """

    def __init__(self, workers: int, call: Callable[[RunJob, Any], RunRecord],
                 initializer: Callable[..., Any] | None = None,
                 initargs: tuple[Any, ...] = ()) -> None:
        self._ctx = multiprocessing.get_context('spawn')
        self._args = (call, initializer, initargs)
        self._workers: list[_Worker] = []
        with _one_blas_thread():
            for _ in range(max(1, int(workers))):
                self._workers.append(_Worker(self._ctx, *self._args))

    def run(self, jobs: Sequence[RunJob], on_record: Callable[[RunRecord], None],
            stop: StopRequest) -> None:
        """
        Run ``jobs`` and hand each record to ``on_record`` as it comes back.

        Parameters
        ----------
        jobs : list of job
            Jobs (:mod:`suture_lfd.study.records`: each with ``key`` and ``failed``).
        on_record : callable
            ``record -> None``, called in this thread (it stores the record).
        stop : suture_lfd.study.signals.StopRequest
            Checked between waits; a stop asked for raises
            :class:`~suture_lfd.study.signals.Interrupted`.

        Raises
        ------
        PoolError
            A worker died before it took a job.

        """
        queue = collections.deque(jobs)
        while queue or any(w.job is not None for w in self._workers):
            stop.check()
            for worker in self._workers:
                if worker.job is None and queue:
                    try:
                        worker.send(queue[0])
                    except (BrokenPipeError, OSError):
                        pass  # dead: its sentinel says so below
                    else:
                        queue.popleft()
            waits = {}
            for worker in self._workers:
                waits[worker.conn] = worker
                waits[worker.process.sentinel] = worker
            ready = dict.fromkeys(waits[r] for r in wait(list(waits), timeout=POLL_S))
            for worker in ready:  # once each, though both its pipe and its sentinel be ready
                if worker.job is None and worker.process.is_alive():
                    continue
                self._collect(worker, on_record)

    def _collect(self, worker: _Worker, on_record: Callable[[RunRecord], None]) -> None:
        """Take a record from a worker whose pipe or sentinel is ready (or replace it)."""
        if worker.job is not None and worker.conn.poll():
            try:
                record = worker.conn.recv()
            except (EOFError, OSError):
                record = None
            if record is not None:
                worker.job = None
                on_record(record)
                return
        if worker.process.is_alive():
            return
        worker.process.join()
        code = worker.process.exitcode
        if not worker.started:
            raise PoolError(f'a study worker process exited (code {code}) before it took a '
                            'job; its error is in the log above')
        job, worker.job = worker.job, None
        if job is not None:
            _LOG.error('the worker running job %s died (exit code %s)', job.key, code)
            on_record(replace(job.failed(f'the worker process running it died (exit code '
                                         f'{code})'), wall_s=float('nan')))
        self._replace(worker)

    def _replace(self, worker: _Worker) -> None:
        worker.conn.close()
        with _one_blas_thread():
            self._workers[self._workers.index(worker)] = _Worker(self._ctx, *self._args)

    def close(self, stop: bool = False) -> None:
        """
        End the workers: let them finish (``stop`` False) or stop them now (True).

        With ``stop`` the workers get SIGTERM (a running job is abandoned; a via-ros worker
        stops its nodes) and, after :data:`~suture_lfd.study.signals.STOP_GRACE_S`, SIGKILL.
        """
        processes = [w.process for w in self._workers]
        for worker in self._workers:
            if stop:
                with contextlib.suppress(OSError):
                    if worker.process.is_alive():
                        os.kill(worker.process.pid, signal.SIGTERM)
            else:
                with contextlib.suppress(OSError):
                    worker.conn.send(None)
        wait_gone(processes, time.monotonic() + (STOP_GRACE_S if stop else 30.0))
        for process in processes:
            if process.is_alive():
                process.kill()
                process.join(STOP_GRACE_S)
        for worker in self._workers:
            worker.conn.close()
        self._workers = []

    def __enter__(self) -> 'WorkerPool':
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close(stop=kind is not None)
