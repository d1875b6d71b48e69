"""
Child processes that die with their parent, and stopping a child process group.

:func:`popen` starts a node (or a script) in a process group of its own that the kernel sends
SIGTERM when the process that started it dies, however it dies (SIGKILL included: Linux's
``prctl(PR_SET_PDEATHSIG)``, set in the child before it executes the program). The child's
own SIGTERM handling then stops it as a Ctrl-C would. Note that the kernel means the *thread*
that forked the child: start long-lived children from a thread that lives as long as they
should (the main thread).

:func:`stop_group`: a ROS 2 node exits cleanly on SIGINT (Fast DDS then removes its
shared-memory files from ``/dev/shm``); one that does not within ``timeout`` gets SIGTERM, then
SIGKILL. Whatever is left of the process group afterwards is killed, so no child outlives its
leader.
"""

import ctypes
import os
import signal
import subprocess

ESCALATION = ((signal.SIGINT, None), (signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0))
PR_SET_PDEATHSIG = 1    # linux/prctl.h


def _libc_prctl():
    """Return libc's ``prctl`` (looked up once, in the parent: the child only calls it)."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):     # not Linux: children are stopped by stop_group only
        return None


_PRCTL = _libc_prctl()


def die_with_parent(sig=signal.SIGTERM):
    """
    Return a ``preexec_fn`` that makes the child receive ``sig`` when its parent dies.

    Parameters
    ----------
    sig : int
        Signal the kernel sends the child when the thread that started it exits.

    Returns
    -------
    callable
        Runs in the child between fork and exec; if the parent is already gone by then, the
        child sends ``sig`` to itself.

    """
    parent = os.getpid()

    def _preexec():
        if _PRCTL is not None:
            _PRCTL(PR_SET_PDEATHSIG, int(sig))
        if os.getppid() != parent:     # the parent died before the request took effect
            os.kill(os.getpid(), sig)

    return _preexec


def follow_parent(parent, sig=signal.SIGTERM):
    """
    Have this process receive ``sig`` when its parent ``parent`` dies (now, if it already has).

    For a process that starts nodes of its own (a study's worker): its handler of ``sig`` stops
    them, so that nothing outlives the process that started it all.

    Parameters
    ----------
    parent : int
        Pid of the parent this process must not outlive.
    sig : int
        Signal to receive.

    """
    if _PRCTL is not None:
        _PRCTL(PR_SET_PDEATHSIG, int(sig))
    if os.getppid() != parent:
        os.kill(os.getpid(), sig)


def popen(argv, **kwargs):
    """
    Start ``argv`` in a new session (its own process group) that dies with this process.

    Parameters
    ----------
    argv : list of str
        Program and arguments.
    **kwargs
        Further :class:`subprocess.Popen` arguments (``stdout``, ``env``, ``cwd``, ...).

    Returns
    -------
    subprocess.Popen
        The child, leader of its process group (stop it with :func:`stop_group`).

    """
    return subprocess.Popen(argv, start_new_session=True, preexec_fn=die_with_parent(),
                            **kwargs)


def kill_group(popen):
    """Send SIGKILL to what is left of the process group led by ``popen`` (if anything)."""
    try:
        os.killpg(popen.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def stop_group(popen, timeout=10.0):
    """
    Stop the process group led by ``popen`` and return the leader's exit code.

    Parameters
    ----------
    popen : subprocess.Popen
        Leader of its own process group (started with ``start_new_session=True``).
    timeout : float
        Wall seconds the group gets to exit after SIGINT before SIGTERM (then 3 s before
        SIGKILL).

    Returns
    -------
    int or None
        Exit code; None if the leader has still not exited 5 s after SIGKILL.

    """
    if popen.poll() is None:
        for sig, wait in ESCALATION:
            try:
                os.killpg(popen.pid, sig)
            except ProcessLookupError:
                break
            try:
                popen.wait(timeout if wait is None else wait)
                break
            except subprocess.TimeoutExpired:
                continue
    kill_group(popen)
    try:
        return popen.wait(5.0)
    except subprocess.TimeoutExpired:
        return None
