"""
A node's process, announced on a topic and watched by its peers on the same machine.

A simulator starved of CPU (a busier process at higher priority, a stopped process) and a dead
one look the same on the topics: nothing arrives. The process tells them apart: a starved one
still exists, a dead one is gone (or a zombie). The simulator announces itself with
:func:`announcement` (``sim/process``, latched); a client builds a :class:`ProcessWatch` from
it and asks :meth:`ProcessWatch.alive` once the topics fall silent. A peer on another machine
cannot be watched (``alive`` returns None) and the client falls back on its timeouts.
"""

import json
import os
import socket
import time


def _start_ticks(pid):
    """Start time of process ``pid`` (clock ticks since boot) and its state letter, or None."""
    try:
        with open(f'/proc/{int(pid)}/stat', 'rb') as f:
            stat = f.read().decode('ascii', 'replace')
    except (OSError, ValueError):
        return None
    fields = stat[stat.rfind(')') + 2:].split()   # after "pid (comm) "
    if len(fields) < 20:
        return None
    return int(fields[19]), fields[0]


def process_start_ns(pid=None):
    """
    Return when process ``pid`` (default: this one) started, on the system clock (int ns).

    From its start time in ``/proc`` (clock ticks since boot) and the time since boot now, both
    10 ms steps, so the result is rounded down by two ticks: never after the true start; without
    ``/proc`` (another system), the time of this call.
    """
    pid = os.getpid() if pid is None else int(pid)
    info = _start_ticks(pid)
    now = time.time_ns()
    try:
        with open('/proc/uptime', 'rb') as f:
            uptime = float(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return now
    if info is None:
        return now
    tick = 1.0 / os.sysconf('SC_CLK_TCK')
    age = uptime - info[0] * tick + 2 * tick
    return now - int(max(age, 0.0) * 1e9)


def announcement(pid=None):
    """Return the JSON text by which a process announces itself: pid, host, start time."""
    pid = os.getpid() if pid is None else int(pid)
    info = _start_ticks(pid)
    return json.dumps({'pid': pid, 'host': socket.gethostname(),
                       'start_ticks': info[0] if info else None})


class ProcessWatch:
    """
    Whether an announced process still runs.

    Parameters
    ----------
    text : str
        The peer's :func:`announcement`.

    Raises
    ------
    ValueError
        If ``text`` is not an announcement.

    """

    def __init__(self, text):
        try:
            data = json.loads(text)
            self.pid, self.host = int(data['pid']), str(data['host'])
            self.start_ticks = data.get('start_ticks')
        except (ValueError, TypeError, KeyError) as exc:
            raise ValueError(f'not a process announcement: {text!r} ({exc})') from None
        self.local = self.host == socket.gethostname() and os.path.isdir('/proc/self')

    def alive(self):
        """
        Return whether the process exists and has not exited.

        Returns
        -------
        bool or None
            True while it exists (running, sleeping, stopped or starved), False once it is gone
            or a zombie (or its pid belongs to a later process), None if it runs on another
            machine.

        """
        if not self.local:
            return None
        info = _start_ticks(self.pid)
        if info is None:
            return False
        ticks, state = info
        if self.start_ticks is not None and ticks != self.start_ticks:
            return False
        return state not in ('Z', 'X', 'x')
