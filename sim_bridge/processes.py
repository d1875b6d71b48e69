"""
Stopping a child process group: SIGINT, then SIGTERM, then SIGKILL, nothing left behind.

A ROS 2 node exits cleanly on SIGINT (Fast DDS then removes its shared-memory files from
``/dev/shm``); one that does not within ``timeout`` gets SIGTERM, then SIGKILL. Whatever is left
of the process group afterwards is killed, so no child outlives its leader.
"""

import os
import signal
import subprocess

ESCALATION = ((signal.SIGINT, None), (signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0))


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
