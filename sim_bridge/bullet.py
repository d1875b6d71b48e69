"""
PyBullet without its banner: ``pybullet`` imported, and clients connected, quietly.

PyBullet's C library prints ``pybullet build time: ...`` on standard error when it is imported
and ``argv[0]=`` on standard output when a client connects, where they mix with a program's own
output (``suture-lfd info > file``) and logs. Modules of the package import PyBullet
from here (``from sim_bridge.bullet import pybullet``) and connect with :func:`connect`, so both
lines go to ``/dev/null`` at the file-descriptor level, which Python's ``sys.stdout`` and
``sys.stderr`` cannot reach.
"""

from collections.abc import Iterator
from contextlib import contextmanager
import ctypes
import os
import sys
from typing import Any


@contextmanager
def c_output_silenced() -> Iterator[None]:
    """
    Context manager: send what the C library writes to standard output and error to /dev/null.

    Python's ``sys.stdout`` and ``sys.stderr`` are flushed first, so nothing of theirs is lost;
    another thread's output to file descriptors 1 and 2 within the block is discarded too (keep
    it short).
    """
    libc = ctypes.CDLL(None)
    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        if stream is not None:
            stream.flush()
    devnull = os.open(os.devnull, os.O_WRONLY)
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    try:
        for fd in saved:
            os.dup2(devnull, fd)
        yield
    finally:
        libc.fflush(None)
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)


with c_output_silenced():
    import pybullet  # noqa: E402 (imported silenced: it prints its build time)
    from pybullet_utils import bullet_client  # noqa: E402


def connect(gui: bool = False) -> Any:
    """
    Connect a new PyBullet client without its banner.

    Parameters
    ----------
    gui : bool
        Open PyBullet's window (``pybullet.GUI``) instead of ``pybullet.DIRECT``.

    Returns
    -------
    pybullet_utils.bullet_client.BulletClient
        The client.

    """
    with c_output_silenced():
        return bullet_client.BulletClient(
            connection_mode=pybullet.GUI if gui else pybullet.DIRECT)


__all__ = ['bullet_client', 'c_output_silenced', 'connect', 'pybullet']
