"""
``scripts/demonstrate.sh`` as the README gives it: every node starts, the phantom is resolved,
the bags go to ``demonstrations/`` in the working folder, and a node that dies stops the script
at once with that node's error line.
"""

import os
from pathlib import Path
import re
import signal
import subprocess
import threading
import time

from harness import wait_for
from sim_bridge.common.processes import popen

SCRIPTS = Path(__file__).resolve().parent.parent / 'scripts'
START_TIMEOUT = 300.0   # s for six nodes to start on a loaded 2-core machine
# what each node's log says once it is up (the log is named by the script; one teleop per
# hand, teleop_<MTM>_<PSM>)
READY = {'simulator': 'simulating', 'viewer': 'http://', 'mtms': 'virtual MTMR, MTML',
         'teleop_MTMR': ' (scale ', 'teleop_MTML': ' (scale ', 'recorder': 'recording'}


def ready_text(log_name):
    """What the log ``log_name`` says once its node is up."""
    return READY[log_name[:len('teleop_MTMx')] if log_name.startswith('teleop_') else log_name]


class Lines:
    """The lines of a stream, each with the monotonic time it arrived, read in a thread."""

    def __init__(self, stream):
        self.lines = []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream):
        for line in stream:
            self.lines.append((time.monotonic(), line.rstrip('\n')))

    def find(self, text):
        """Return ``(time, line)`` of the first line holding ``text``, or None."""
        return next(((t, line) for t, line in self.lines if text in line), None)

    def text(self):
        return '\n'.join(line for _, line in self.lines)


def _alive(pid):
    try:   # a zombie is gone for our purpose
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def test_demonstrate_starts_every_node_and_stops_with_the_error_line_of_a_killed_viewer(
        tmp_path):
    work = tmp_path / 'work'
    work.mkdir()
    logs = tmp_path / 'logs'
    env = {**os.environ, 'LOG_DIR': str(logs)}
    logs.mkdir()
    proc = popen([str(SCRIPTS / 'demonstrate.sh'), '--device', 'browser'], cwd=work, env=env,
                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err, out = Lines(proc.stderr), Lines(proc.stdout)
    try:
        assert wait_for(lambda: err.find('bags go to') or proc.poll() is not None,
                        timeout=START_TIMEOUT, period=0.2), err.text()
        assert proc.poll() is None, err.text()
        started = {m.group(1): int(m.group(2)) for _, line in err.lines
                   if (m := re.search(r'started (\S+) \(pid (\d+)\)', line))}
        assert {n[:len('teleop_MTMx')] if n.startswith('teleop_') else n
                for n in started} == set(READY) and len(started) == 6, err.text()
        # the phantom is resolved from the pair (synth1: synthetic) for every node given it
        viewer_args = Path(f'/proc/{started["viewer"]}/cmdline').read_bytes().split(b'\0')
        assert b'phantom:=synthetic' in viewer_args
        ready = wait_for(lambda: all(ready_text(n) in (logs / f'{n}.log').read_text()
                                     for n in started), timeout=START_TIMEOUT, period=0.5)
        assert ready, {n: (logs / f'{n}.log').read_text()[-500:] for n in started}
        assert all(_alive(pid) for pid in started.values()), err.text()
        # the bags go to demonstrations/ in the working folder, as the README says
        assert wait_for(lambda: out.lines, timeout=10)
        assert out.lines[0][1] == str(work / 'demonstrations')
        assert (work / 'demonstrations').is_dir()
        killed = time.monotonic()
        os.kill(started['viewer'], signal.SIGKILL)
        code = proc.wait(120)
        said = err.find('viewer exited')
        assert said is not None, err.text()
        assert said[0] - killed < 2.0, (said[0] - killed, err.text())
        assert 'code 137' in said[1] and 'http://' in said[1]   # the viewer's last line
        assert code != 0
        assert wait_for(lambda: not any(_alive(pid) for pid in started.values()), timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
