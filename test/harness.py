"""
Test harness helpers (test/conftest.py holds the fixtures): DDS confined to loopback, a
private domain, real node processes.

Every test run sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a private ``ROS_DOMAIN_ID``
before anything imports rclpy; subprocess nodes inherit both. Node processes are stopped with
SIGINT so that Fast DDS removes its shared-memory files from /dev/shm.
"""

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import threading
import time

from sim_bridge.common.processes import popen, stop_group
from sim_bridge.ros.dds import use_project_profile

REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID = 10 + os.getpid() % 90
# Simulator arguments of tests that need speed, not the dVRK's timings: arms power up at once
# and start at home, so that enable and home each take one step.
FAST_ARMS = ('-p', 'power_up_time:=0.0', '-p', 'start_at_home:=true')
os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ['PYTHONUNBUFFERED'] = '1'
use_project_profile()  # the project's Fast DDS profile for the test's participants and nodes

SIGINT_EXIT = 128 + signal.SIGINT    # a node stopped by SIGINT exits with 130
SIGTERM_EXIT = 128 + signal.SIGTERM  # ... by SIGTERM with 143
# Lines no node log or program output may hold: a traceback, a ROS error from a context torn
# down under a node, PyBullet's banner.
FORBIDDEN_LINES = ('Traceback (most recent call last)', 'RCLError', 'argv[0]=',
                   'pybullet build time')


def forbidden_lines(text):
    """Return the lines of ``text`` that hold one of :data:`FORBIDDEN_LINES`."""
    return [line for line in text.splitlines() if any(f in line for f in FORBIDDEN_LINES)]


def wait_for(predicate, timeout=10.0, period=0.005):
    """Poll ``predicate`` until it is true or ``timeout`` seconds pass; return its last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > deadline:
            return value
        time.sleep(period)


class RosHarness:
    """
    One rclpy context on the private domain, spun by a background executor.

    The executor is single-threaded: rclpy's multi-threaded executor takes a few hundred
    messages a second at best on a busy machine, so a 200 Hz stream overflowed a test
    subscriber's history and the test saw gaps that the node under test never made.
    """

    def __init__(self):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        import rclpy.signals

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID,
                   signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []
        self._thread = None

    def node(self, name, **kwargs):
        """
        Create a node in this context and spin it.

        Its endpoints carry no QoS-event handlers (:class:`sim_bridge.ros.qos.QuietEndpoints`),
        as the project's busy nodes: the test's executor would visit each at every message,
        and a test watching a few 100 Hz streams took a third of a core on a two-core machine
        that the nodes under test need.
        """
        from rclpy.node import Node
        from sim_bridge.ros.qos import QuietEndpoints

        class QuietNode(QuietEndpoints, Node):
            pass

        node = QuietNode(name, context=self.context, **kwargs)
        self.nodes.append(node)
        self.executor.add_node(node)
        if self._thread is None:
            self._thread = threading.Thread(target=self.executor.spin, daemon=True)
            self._thread.start()
        return node

    wait_for = staticmethod(wait_for)

    def close(self):
        self.executor.shutdown(timeout_sec=2.0)
        if self._thread is not None:
            self._thread.join(3.0)
        for node in self.nodes:
            node.destroy_node()
        self._rclpy.shutdown(context=self.context)


def executable(name):
    """Return the path of a console script installed with the package."""
    path = shutil.which(name, path=str(Path(sys.executable).parent))
    if path is None:
        raise FileNotFoundError(f'executable {name!r} is not installed next to {sys.executable}')
    return path


class NodeProcess:
    """
    A node executable running as a real subprocess in its own process group.

    It dies with the test run: the kernel sends it SIGTERM when the run's process dies, even by
    SIGKILL (:func:`sim_bridge.common.processes.popen`).
    """

    def __init__(self, argv, log_dir, env=None, cwd=None):
        self.argv = [str(a) for a in argv]
        name = Path(self.argv[0]).name
        self.log_path = Path(log_dir) / f'{name}-{int(time.monotonic() * 1e6)}.log'
        self._log = open(self.log_path, 'w')
        self.popen = popen(self.argv, stdout=self._log, stderr=subprocess.STDOUT, cwd=cwd,
                           env={**os.environ, **(env or {})})

    @property
    def pid(self):
        return self.popen.pid

    def running(self):
        return self.popen.poll() is None

    def log(self):
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def stop(self, timeout=10.0):
        """Ask the process to stop (SIGINT), escalate if it does not; return its exit code."""
        code = stop_group(self.popen, timeout)
        self._log.close()
        return code

    def kill(self):
        """Kill the process hard (SIGKILL), as a crash would."""
        os.killpg(self.popen.pid, signal.SIGKILL)
        return self.popen.wait(5.0)
