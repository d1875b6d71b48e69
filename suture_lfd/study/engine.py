"""
Where a study's jobs run: the local process pool, or a Dask cluster (local or existing).

``--engine`` takes one of

- ``local`` (default): :func:`suture_lfd.study.runner.run_stages`, a pool of ``spawn``-ed worker
  processes on this machine;
- ``dask``: a ``distributed.LocalCluster`` of ``--workers`` process workers on this machine
  (loopback only, no dashboard);
- ``tcp://HOST:PORT`` (or ``tls://...``): an existing Dask scheduler, e.g. one started by
  ``dask scheduler`` or by dask-jobqueue on SLURM/PBS;
- ``scheduler-file:PATH``: an existing scheduler that wrote its address to ``PATH``
  (``dask scheduler --scheduler-file PATH``).

Under every engine this process is the only writer of the study's
:class:`~suture_lfd.study.store.ResultStore`: workers return records, the driver stores them as
they arrive, so progress and resume are the same as with the local pool. The Dask driver keeps a
bounded window of jobs in flight (three per worker), so a study of 10⁶ jobs does not hand the
scheduler 10⁶ futures at once; a job whose worker dies is rescheduled by Dask (``retries`` and
the scheduler's ``allowed-failures``).

SIGINT and SIGTERM stop a Dask run as they stop the local pool (:mod:`suture_lfd.study.signals`):
the driver looks at the stop request between records (every :data:`POLL_S`), cancels the jobs in
flight, closes its client and the local cluster it started (its worker processes are stopped,
then killed after :data:`~suture_lfd.study.signals.STOP_GRACE_S`); a cluster that was already
running keeps running, the cancelled jobs dropped.

A Dask worker runs one job at a time per process (``threads_per_worker=1``: PyBullet's DIRECT
clients of a process must not be shared between threads), keeps its simulations between jobs
(the same per-process state as a pool worker) and never loads ROS. Every record carries the
worker's code digest (:func:`code_digest`, the sources a throw's result depends on); a record
computed by other code is refused with :class:`CodeMismatchError` and the study stops, nothing
of it stored.
"""

from collections.abc import Callable, Sequence
import contextlib
from dataclasses import dataclass, replace
import inspect
import logging
import time
from types import TracebackType
from typing import Any

from suture_lfd.study.digest import code_digest
from suture_lfd.study.records import RunJob, RunRecord
from suture_lfd.study.runner import Progress, call_job, pending, run_stages
from suture_lfd.study.signals import (
    STOP_GRACE_S,
    StopRequest,
    stop_on_signals,
    terminate_processes,
)
from suture_lfd.study.store import ResultStore

_LOG = logging.getLogger(__name__)

#: Jobs in flight per Dask worker: enough to keep every worker busy while records come back,
#: few enough that an interrupted study cancels little and the scheduler holds little.
IN_FLIGHT_PER_WORKER = 3
#: Longest time (s) the driver waits for a record before it looks at the stop request again.
POLL_S = 0.05
#: Times Dask reruns a job that raised in the worker machinery (a job's own exception is a
#: record with ``error``, never retried here; a dead worker is retried by the scheduler).
RETRIES = 2


class EngineError(RuntimeError):
    """The engine cannot run jobs (no scheduler at the address, no scheduler file, ...)."""


class CodeMismatchError(EngineError):
    """A worker computed a record with other code than the driver's."""


@dataclass(frozen=True)
class EngineSpec:
    """
    A parsed ``--engine`` value.

    Attributes
    ----------
    kind : str
        ``'local'`` or ``'dask'``.
    address : str or None
        Scheduler address of an existing cluster (``tcp://host:8786``).
    scheduler_file : str or None
        Scheduler file of an existing cluster.

    """

    kind: str = 'local'
    address: str | None = None
    scheduler_file: str | None = None

    def describe(self) -> str:
        """Return a short text for progress lines and the report."""
        if self.address:
            return f'dask cluster at {self.address}'
        if self.scheduler_file:
            return f'dask cluster of scheduler file {self.scheduler_file}'
        return 'local dask cluster' if self.kind == 'dask' else 'local process pool'


def parse_engine(text: str | None) -> EngineSpec:
    """
    Return the :class:`EngineSpec` of an ``--engine`` value.

    Raises
    ------
    ValueError
        On anything but ``local``, ``dask``, ``tcp://...``/``tls://...`` or
        ``scheduler-file:PATH``.

    """
    text = (text or 'local').strip()
    if text == 'local':
        return EngineSpec()
    if text == 'dask':
        return EngineSpec('dask')
    if text.startswith(('tcp://', 'tls://')) and len(text.split('://', 1)[1]) > 0:
        return EngineSpec('dask', address=text)
    if text.startswith('scheduler-file:') and len(text) > len('scheduler-file:'):
        return EngineSpec('dask', scheduler_file=text[len('scheduler-file:'):])
    raise ValueError(f'--engine {text!r} is not one of: local, dask, tcp://HOST:PORT, '
                     'scheduler-file:PATH')


def run_stages_on(engine: 'EngineSpec | DaskSession | None',
                  stages: Sequence[Sequence[RunJob]], job_fn: Callable[[Any, Any], RunRecord],
                  store: ResultStore, workers: int = 1, progress: Progress | None = None,
                  initializer: Callable[..., Any] | None = None,
                  initargs: tuple[Any, ...] = ()) -> int:
    """
    Run the pending jobs of every stage on ``engine``; the arguments of :func:`run_stages`.

    Parameters
    ----------
    engine : EngineSpec or DaskSession or None
        Where to run (None or a ``local`` spec: the process pool). A :class:`DaskSession`
        reuses its open client across calls (the stages of one study).

    Returns
    -------
    int
        Jobs run by this call.

    """
    if isinstance(engine, DaskSession):
        return engine.run_stages(stages, job_fn, store, progress, initializer, initargs)
    if engine is None or engine.kind == 'local':
        return run_stages(stages, job_fn, store, workers=workers, progress=progress,
                          initializer=initializer, initargs=initargs)
    with DaskSession(engine, workers) as session:
        return session.run_stages(stages, job_fn, store, progress, initializer, initargs)


def open_session(spec: EngineSpec, workers: int = 1) -> 'DaskSession':
    """
    Open a :class:`DaskSession` (close it with :meth:`DaskSession.close`).

    Raises
    ------
    EngineError
        When the cluster cannot be reached or started (the reason in the message).

    """
    session = DaskSession(spec, workers)
    try:
        return session.__enter__()
    except (OSError, TimeoutError, ValueError) as exc:
        session.close()
        raise EngineError(f'cannot use the {spec.describe()}: {type(exc).__name__}: {exc}') \
            from exc


class DaskSession:
    """
    An open Dask client (and the local cluster it started, if any) for one study.

    Parameters
    ----------
    spec : EngineSpec
        A ``dask`` engine.
    workers : int
        Worker processes of a local cluster (ignored for an existing cluster).

    """

    def __init__(self, spec: EngineSpec, workers: int = 1) -> None:
        if spec.kind != 'dask':
            raise ValueError(f'DaskSession needs a dask engine, got {spec.kind!r}')
        self.spec = spec
        self.workers = max(1, int(workers))
        self.client: Any = None
        self.cluster: Any = None
        self.code = code_digest()

    def __enter__(self) -> 'DaskSession':
        from distributed import Client, LocalCluster

        # the scheduler and client log every connection at INFO: keep the terminal to progress
        for name in ('distributed', 'dask'):
            logging.getLogger(name).setLevel(logging.WARNING)
        if self.spec.address:
            self.client = Client(self.spec.address, timeout='30s')
        elif self.spec.scheduler_file:
            self.client = Client(scheduler_file=self.spec.scheduler_file, timeout='30s')
        else:
            self.cluster = LocalCluster(
                n_workers=self.workers, threads_per_worker=1, processes=True,
                host='127.0.0.1', dashboard_address=None, silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close(stop=kind is not None and issubclass(kind, KeyboardInterrupt))

    def close(self, stop: bool = False) -> None:
        """
        Close the client and the local cluster it started.

        Parameters
        ----------
        stop : bool
            The run was interrupted: the local cluster's worker processes are stopped first
            (SIGTERM, SIGKILL after :data:`~suture_lfd.study.signals.STOP_GRACE_S`), so that
            the cluster closes at once instead of waiting for their jobs; an existing cluster
            is left running.

        """
        if stop and self.cluster is not None:
            logging.getLogger('distributed').setLevel(logging.CRITICAL)  # workers going down
            terminate_processes(nanny.pid for nanny in self.cluster.workers.values())
        if self.client is not None:
            with contextlib.suppress(TimeoutError, OSError):
                self.client.close(timeout=STOP_GRACE_S)
            self.client = None
        if self.cluster is not None:
            with contextlib.suppress(TimeoutError, OSError):
                self.cluster.close(timeout=STOP_GRACE_S if stop else None)
            self.cluster = None

    def n_workers(self) -> int:
        """Workers the scheduler knows now (at least 1)."""
        info = self.client.scheduler_info(n_workers=-1) if self._takes_n_workers() \
            else self.client.scheduler_info()
        return max(1, len(info.get('workers', {})))

    def _takes_n_workers(self) -> bool:
        return 'n_workers' in inspect.signature(self.client.scheduler_info).parameters

    def run_stages(self, stages: Sequence[Sequence[RunJob]],
                   job_fn: Callable[[Any, Any], RunRecord], store: ResultStore,
                   progress: Progress | None = None,
                   initializer: Callable[..., Any] | None = None,
                   initargs: tuple[Any, ...] = ()) -> int:
        """Run the pending jobs of every stage, stage after stage; return how many ran."""
        ran = 0
        todo = [pending(stage, store) for stage in stages]
        with stop_on_signals() as stop, stop.deferred():
            for stage in todo:
                if stage:
                    ran += self._run_stage(stage, job_fn, store, progress, initializer,
                                           initargs, stop)
        return ran

    def _submit(self, job: RunJob, job_fn: Callable[[Any, Any], RunRecord],
                initializer: Callable[..., Any] | None, initargs: tuple[Any, ...]) -> Any:
        return self.client.submit(
            dask_job, job_fn, job, initializer, initargs, self.code,
            key=f'suture-lfd-{job.id}-{time.monotonic_ns()}', pure=False,
            retries=RETRIES)

    def _run_stage(self, stage: Sequence[RunJob], job_fn: Callable[[Any, Any], RunRecord],
                   store: ResultStore, progress: Progress | None,
                   initializer: Callable[..., Any] | None, initargs: tuple[Any, ...],
                   stop: StopRequest) -> int:
        """Keep a bounded window of the stage's jobs in flight; store records as they come."""
        from distributed import as_completed

        window = IN_FLIGHT_PER_WORKER * self.n_workers()
        jobs = iter(stage)
        in_flight: dict[Any, str] = {}
        for _, job in zip(range(window), jobs):
            in_flight[self._submit(job, job_fn, initializer, initargs)] = job.key
        running = as_completed(list(in_flight))
        ran = 0
        try:
            while in_flight:
                stop.check()
                finished = running.next_batch(block=False)
                if not finished:
                    time.sleep(POLL_S)
                    continue
                for future in finished:
                    key = in_flight.pop(future)
                    try:
                        record = future.result()
                    except Exception as exc:  # the machinery, not the job: jobs return errors
                        raise EngineError(f'the Dask cluster could not run job {key}: '
                                          f'{type(exc).__name__}: {exc}') from exc
                    check_code(record, self.code)
                    store.add(record)
                    ran += 1
                    if progress is not None:
                        progress.advance(record.key)
                    following = next(jobs, None)
                    if following is not None:
                        future = self._submit(following, job_fn, initializer, initargs)
                        in_flight[future] = following.key
                        running.add(future)
        except BaseException:
            self.client.cancel(list(in_flight), force=True)
            raise
        return ran


def check_code(record: RunRecord, code: str) -> None:
    """
    Refuse a record computed by other code.

    Raises
    ------
    CodeMismatchError
        When the record's ``code`` differs from ``code``.

    """
    theirs = record.code
    if theirs != code:
        raise CodeMismatchError(
            f'a Dask worker ({record.worker or "?"}) runs other suture_lfd code '
            f"(code digest {theirs}, this study's is {code}); its result for "
            f'{record.key} was not stored. Install the same suture_lfd version on every '
            'worker (e.g. the same checkout, `pip install -e .`) and run the study again.')


# ---------------------------------------------------------------------- worker side
_WORKER: dict[str, Any] = {}


def dask_job(job_fn: Callable[[Any, Any], RunRecord], job: RunJob,
             initializer: Callable[..., Any] | None, initargs: tuple[Any, ...],
             code: str) -> RunRecord:
    """
    Run one job in a Dask worker (module-level, so workers import it by reference).

    The worker's own code digest goes into the record (``code``), with its address
    (``worker``); a worker whose digest differs from the driver's runs nothing.
    """
    mine = _WORKER.get('code')
    if mine is None:
        mine = _WORKER['code'] = code_digest()
    where = _worker_address()
    if mine != code:
        return replace(job.failed('code digest mismatch'), code=mine, worker=where)
    init = (getattr(initializer, '__module__', None), getattr(initializer, '__qualname__', None),
            repr(initargs))
    if initializer is not None and _WORKER.get('init') != init:
        logging.getLogger('distributed').setLevel(logging.ERROR)
        _WORKER['state'] = initializer(*initargs)
        _WORKER['init'] = init
    record = call_job(job_fn, job, _WORKER.get('state') if initializer is not None else None)
    return replace(record, code=mine)


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return 'not a dask worker'
