"""
The stages of a study or sweep run on its engine, with the run's error and interrupt handling.

A run's jobs go in stages (:class:`Stage`: the demonstrations, then the throws learnt from
them), each made when it starts; :func:`run_job_stages` runs them one after the other on the
engine (:mod:`suture_lfd.study.engine`), opening a Dask session once if one is needed, and
turns an engine that cannot run jobs into one error line and SIGINT / SIGTERM into the
interrupted run's ending (:func:`suture_lfd.study.signals.end_interrupted`).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import sys
from typing import IO, Any

from suture_lfd.study.engine import (
    CodeMismatchError,
    EngineError,
    EngineSpec,
    open_session,
    run_stages_on,
)
from suture_lfd.study.jobs import init_worker, run_job
from suture_lfd.study.pool import PoolError
from suture_lfd.study.records import DemoJob, ThrowJob
from suture_lfd.study.runner import Progress, pending
from suture_lfd.study.signals import StopRequest, end_interrupted, signal_of
from suture_lfd.study.store import ResultStore


@dataclass(frozen=True)
class Stage:
    """
    One stage of a run: jobs made when it starts (after the stages before it), run together.

    Attributes
    ----------
    jobs : callable
        ``() -> list of jobs``: called when the stage starts, so that a stage of throws can
        attach the demonstrations the stages before it stored.
    initargs : tuple
        The arguments of :func:`suture_lfd.study.jobs.init_worker` for its processes.

    """

    jobs: Callable[[], Sequence[DemoJob | ThrowJob]]
    initargs: tuple[Any, ...]


def run_job_stages(what: str, engine: EngineSpec, stages: Sequence[Stage],
                   jobs: Sequence[DemoJob | ThrowJob], store: ResultStore, stop: StopRequest,
                   progress: Progress, workers: int, stream: IO[str]) -> int:
    """
    Run a study's or a sweep's stages on the engine, one after the other; return the status.

    A Dask engine's session is opened once (when any of ``jobs`` is pending) and closed at the
    end; an engine that cannot run jobs is one error line; SIGINT and SIGTERM end the run as
    :func:`suture_lfd.study.signals.end_interrupted` says.

    Parameters
    ----------
    what : str
        ``'study'`` or ``'sweep'`` (the messages' subject).
    engine : EngineSpec
        Where the jobs run.
    stages : list of Stage
        The stages, in order.
    jobs : list of DemoJob or ThrowJob
        Every job of the run (whether a Dask session is needed at all).
    store : suture_lfd.study.store.ResultStore
        Where records go.
    stop : suture_lfd.study.signals.StopRequest
        The run's stop request.
    progress : suture_lfd.study.runner.Progress
        The run's progress.
    workers : int
        Worker processes.
    stream : file-like
        Progress output.

    Returns
    -------
    int
        0 done, 1 the engine failed, ``128 + signal`` interrupted.

    """
    session = None
    interrupted = None
    status = 0
    try:
        if engine.kind == 'dask' and pending(jobs, store):
            with stop.deferred():  # a cluster is never left half started
                session = open_session(engine, workers)
            stop.check()
            print(f'{what}: jobs run on the {engine.describe()} '
                  f'({session.n_workers()} workers)', file=stream, flush=True)
        where = session or engine
        for stage in stages:
            run_stages_on(where, [stage.jobs()], run_job, store, workers=workers,
                          progress=progress, initializer=init_worker, initargs=stage.initargs)
    except (CodeMismatchError, EngineError, PoolError) as exc:
        progress.finish()
        print(f'suture-lfd {what}: error: {exc}', file=sys.stderr, flush=True)
        status = 1
    except KeyboardInterrupt as exc:
        interrupted = signal_of(exc)
    finally:
        if session is not None:
            session.close(stop=interrupted is not None)
    if interrupted is not None:
        return end_interrupted(what, progress, len(jobs), store, interrupted, stream)
    return status
