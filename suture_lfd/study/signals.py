"""
How a study (or a sweep) stops when told: SIGINT and SIGTERM, once or twice.

SIGTERM is what ``timeout``, systemd, ``docker stop``, SLURM's ``scancel`` and a batch system's
time limit send; Ctrl-C sends SIGINT. Both stop a run the same way under every engine:

- the first signal asks the run to stop (:class:`StopRequest`): the job loops stop handing out
  jobs at their next turn (a fraction of a second), keep every record already stored, tell the
  workers to stop (SIGTERM to pool workers, cancelled futures and a closed local cluster for
  Dask) and raise :class:`Interrupted`, a :class:`KeyboardInterrupt` whose ``signum`` gives the
  exit status ``128 + signum`` (130 for SIGINT, 143 for SIGTERM);
- a second signal exits at once: every process this one started is killed and the process exits
  with the same status, without a report (the records stored so far stay in the results file).

Outside the job loops (between stages, in-process jobs) the first signal raises
:class:`Interrupted` where the run is; inside a :meth:`StopRequest.deferred` block (storing a
record, a loop that polls :meth:`StopRequest.check`, starting a Dask cluster) it only marks the
request, so a record is never cut in half and a cluster is never left half started.

Signals are per process, so the request is too: :func:`stop_on_signals` installs the handlers
in the main thread and returns the process's :class:`StopRequest`.
"""

from collections.abc import Iterable, Iterator
import contextlib
import logging
from multiprocessing import resource_tracker
from multiprocessing.process import BaseProcess
import os
import signal
import time
from types import FrameType
from typing import IO, TYPE_CHECKING

import psutil

if TYPE_CHECKING:
    from suture_lfd.study.runner import Progress
    from suture_lfd.study.store import ResultStore

_LOG = logging.getLogger(__name__)

#: Seconds a worker gets to stop on SIGTERM (its nodes, its files) before it is killed.
STOP_GRACE_S = 2.0


class Interrupted(KeyboardInterrupt):
    """
    A run stopped by a signal (SIGINT or SIGTERM).

    Attributes
    ----------
    signum : int
        The signal; the exit status is ``128 + signum``.

    """

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(f'stopped by {signal.Signals(signum).name}')
        self.signum = int(signum)


class StopRequest:
    """
    The stop asked for by a signal, shared by the handlers and the job loops of one process.

    Attributes
    ----------
    signum : int or None
        The first signal received (None: none yet).
    label : str
        What the process is (``'study'``, ``'sweep'``), for the line a second signal prints.

    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self.label = 'study'
        self._deferred = 0

    @property
    def requested(self) -> bool:
        """True once a stop signal arrived."""
        return self.signum is not None

    def check(self) -> None:
        """
        Raise :class:`Interrupted` if a stop was asked for (call at a safe point of a loop).

        Raises
        ------
        Interrupted
            With the signal received.

        """
        if self.signum is not None:
            raise Interrupted(self.signum)

    @contextlib.contextmanager
    def deferred(self) -> Iterator['StopRequest']:
        """Within the block a first signal only marks the request; :meth:`check` acts on it."""
        self._deferred += 1
        try:
            yield self
        finally:
            self._deferred -= 1

    def reset(self) -> None:
        """Forget a request (a new run in the same process)."""
        self.signum = None
        self._deferred = 0

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            _exit_at_once(signum, self.label)
        self.signum = signum
        if not self._deferred:
            raise Interrupted(signum)


STOP = StopRequest()  # signals are per process: so is the request they make


@contextlib.contextmanager
def stop_on_signals(label: str = 'study') -> Iterator[StopRequest]:
    """
    Install the SIGINT and SIGTERM handlers of a run while the block runs.

    Nested uses keep the outer handlers. Outside the main thread (where Python cannot install
    handlers) the block runs with the handlers it has.

    Parameters
    ----------
    label : str
        ``'study'`` or ``'sweep'``: names the process in the line a second signal prints.

    Yields
    ------
    StopRequest
        The process's request (:data:`STOP`).

    """
    if signal.getsignal(signal.SIGTERM) == STOP._handle:
        yield STOP
        return
    try:
        previous = {s: signal.signal(s, STOP._handle) for s in (signal.SIGINT, signal.SIGTERM)}
    except ValueError:  # not the main thread
        yield STOP
        return
    STOP.reset()
    STOP.label = label
    try:
        yield STOP
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _exit_at_once(signum: int, label: str) -> None:
    """Kill every process started here and exit without cleaning up (a second signal)."""
    os.write(2, f'\n{label} stopped at once by a second {signal.Signals(signum).name}; the '
                'results stored so far are kept: run the same command again to resume\n'
                .encode())
    for child in _children():
        with contextlib.suppress(psutil.Error):
            child.kill()
    os._exit(128 + signum)


def _children() -> list[psutil.Process]:
    try:
        return psutil.Process().children(recursive=True)
    except psutil.Error:
        return []


def _tracker_pid() -> int | None:
    """Process id of multiprocessing's resource tracker (started with spawned workers)."""
    pid: int | None = getattr(resource_tracker._resource_tracker, '_pid', None)
    return pid


def terminate_processes(pids: Iterable[int]) -> None:
    """
    Send SIGTERM to those of ``pids`` that this process started (no waiting: their owner reaps).

    Parameters
    ----------
    pids : iterable of int
        Process ids (of a local cluster's workers, say); others than this process's
        descendants are left alone.

    """
    wanted = set(pids) - {_tracker_pid()}
    for child in _children():
        if child.pid in wanted:
            with contextlib.suppress(psutil.Error):
                child.terminate()


def stop_children(grace: float = STOP_GRACE_S) -> int:
    """
    Stop every process this one started that is still running: SIGTERM, then SIGKILL.

    The last step of an interrupted run, after the engine closed what it knew of (pool workers,
    a local Dask cluster), so that no process of the run outlives it whatever the engine left.

    Parameters
    ----------
    grace : float
        Seconds the processes get to exit on SIGTERM before they are killed.

    Returns
    -------
    int
        Processes that were still running (but multiprocessing's resource tracker, which
        ignores SIGTERM and is killed at once).

    """
    children = _children()
    tracker = _tracker_pid()
    for child in children:
        with contextlib.suppress(psutil.Error):
            if child.pid == tracker:  # it ignores SIGTERM; nothing of a run is registered in it
                child.kill()
            else:
                child.terminate()
    _, alive = psutil.wait_procs(children, timeout=grace)
    for child in alive:
        with contextlib.suppress(psutil.Error):
            child.kill()
    psutil.wait_procs(alive, timeout=grace)
    others = [c for c in children if c.pid != tracker]
    if others:
        _LOG.info('stopped %d process(es) left by the run', len(others))
    return len(others)


def signal_of(exc: BaseException) -> int:
    """
    Return the signal that stopped a run, from the :class:`KeyboardInterrupt` it raised.

    An :class:`Interrupted` carries its signal; a plain :class:`KeyboardInterrupt` (Ctrl-C
    before the handlers were installed) is SIGINT.
    """
    return int(getattr(exc, 'signum', signal.SIGINT))


def end_interrupted(what: str, progress: 'Progress', total: int, store: 'ResultStore',
                    signum: int, stream: IO[str]) -> int:
    """
    End a run stopped by a signal: stop what is left of it, say so, return the exit status.

    Parameters
    ----------
    what : str
        ``'study'`` or ``'sweep'``.
    progress : suture_lfd.study.runner.Progress
        The run's progress (its line is ended; its count is the jobs stored).
    total : int
        Jobs of the whole run.
    store : suture_lfd.study.store.ResultStore
        Where the finished jobs are stored.
    signum : int
        The signal (:func:`signal_of`).
    stream : file-like
        Where the line goes.

    Returns
    -------
    int
        ``128 + signum``: 130 for SIGINT, 143 for SIGTERM.

    """
    progress.finish()
    stop_children()  # whatever the engine left: no process of the run outlives it
    print(f'{what} interrupted: {progress.done}/{total} jobs stored in {store.path.name}; run '
          'the same command again to resume', file=stream, flush=True)
    return 128 + int(signum)


def wait_gone(processes: Iterable[BaseProcess], deadline: float) -> None:
    """Wait until every ``multiprocessing.Process`` has exited or ``deadline`` (monotonic)."""
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
