"""
Fixtures of the test harness (:mod:`harness`): ``ros`` and ``launch``.

Importing :mod:`harness` first sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a private
``ROS_DOMAIN_ID`` before anything imports rclpy. Tests import helpers from ``harness`` (not
from ``conftest``: a folder may hold its own conftest.py).
"""

import os
import signal

from harness import NodeProcess, RosHarness, executable, forbidden_lines
import pytest

# A test run started in the background of a non-interactive shell inherits SIGINT ignored, and
# so would every node and script it starts: they could not be stopped the way a user stops
# them (Ctrl-C). Give the run, and through it its children, the default disposition back.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def ros():
    """Give the test its own rclpy context on the private domain."""
    harness = RosHarness()
    try:
        yield harness
    finally:
        harness.close()


@pytest.fixture
def launch(tmp_path):
    """
    Start node executables as subprocesses; every one is stopped at teardown.

    At teardown every node's log is checked: no traceback, no ``RCLError``, no PyBullet banner.
    """
    started = []

    def _launch(name, *args, env=None, cwd=None):
        argv = [executable(name) if os.sep not in str(name) else name, *args]
        proc = NodeProcess(argv, tmp_path, env=env, cwd=cwd)
        started.append(proc)
        return proc

    yield _launch
    for proc in started:
        proc.stop()
    bad = {proc.log_path.name: forbidden_lines(proc.log()) for proc in started}
    bad = {name: lines for name, lines in bad.items() if lines}
    assert not bad, f'node logs hold forbidden lines: {bad}'
