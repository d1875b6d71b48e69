"""The everyday scripts: private DDS settings, and their node processes stop when they do."""

import os
from pathlib import Path
import re
import signal
import subprocess
import time

import pytest

SCRIPTS = Path(__file__).resolve().parent.parent / 'scripts'


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:   # a zombie is gone for our purpose
        return Path(f'/proc/{pid}/stat').read_text().split()[2] != 'Z'
    except OSError:
        return False


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT])
def test_stopping_the_simulator_script_stops_the_simulator(tmp_path, sig):
    env = {**os.environ, 'LOG_DIR': str(tmp_path), 'ROS_DOMAIN_ID': os.environ['ROS_DOMAIN_ID']}
    proc = subprocess.Popen([str(SCRIPTS / 'simulator.sh'), '--rtf', '1.0'], env=env,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        line = proc.stderr.readline()
        while line and 'started simulator' not in line:
            line = proc.stderr.readline()
        child = int(re.search(r'pid (\d+)', line).group(1))
        log = tmp_path / 'simulator.log'
        deadline = time.monotonic() + 120
        # the script announces the child before the child has opened its log
        while (not log.exists() or 'simulating' not in log.read_text()) \
                and time.monotonic() < deadline:
            time.sleep(0.2)
        assert 'simulating' in log.read_text()
        environ = Path(f'/proc/{child}/environ').read_bytes().split(b'\0')
        assert b'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST' in environ
        assert f'ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]}'.encode() in environ
        proc.send_signal(sig)          # the script only, not its process group
        assert proc.wait(60) != 0
        deadline = time.monotonic() + 30
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(child)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)


def test_a_script_refuses_an_unknown_option(tmp_path):
    out = subprocess.run([str(SCRIPTS / 'record_demo.sh'), '--colour', 'red'],
                         env={**os.environ, 'LOG_DIR': str(tmp_path)}, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 2 and '--colour' in out.stderr
