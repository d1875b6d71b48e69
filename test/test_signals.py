"""
SIGINT and SIGTERM, sent to every node in the middle of its work, as a user or a script stops it;
and SIGKILL sent to what started the nodes (a test run, a script), which they do not outlive.

Each node stops commanding (the arms hold), writes the result it has with outcome
``interrupted``, and exits with 128 + the signal number (130, 143): never 0 for a throw that did
not finish, and never a traceback (the ``launch`` fixture checks every log). A stop during
start-up (while the node's modules load, PyBullet connects, the node is built) is as clean.
"""

import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

from geometry_msgs.msg import PoseStamped
from harness import wait_for
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from suture_lfd import bags
import yaml

SEGMENTS = Path(__file__).resolve().parent / 'suture_lfd' / 'data' / 'study_S01_synth1.npz'
SCRIPTS = Path(__file__).resolve().parent.parent / 'scripts'
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
WORK_TIMEOUT = 600.0  # s of wall time for a node to get to work on a loaded 2-core machine
SIGNALS = pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM],
                                  ids=['SIGINT', 'SIGTERM'])


def handles_signals(proc):
    """Return True once the process catches SIGTERM: its entry point has taken the signals."""
    try:
        status = Path(f'/proc/{proc.pid}/status').read_text()
    except OSError:
        return False
    caught = int(next(line for line in status.splitlines()
                      if line.startswith('SigCgt:')).split()[1], 16)
    return bool(caught & (1 << (signal.SIGTERM - 1)))


def interrupt(proc, sig, timeout=60.0):
    """Send ``sig`` to the node's process alone; return its exit code."""
    os.kill(proc.pid, sig)
    return proc.popen.wait(timeout)


def result_lines(log):
    """Return the JSON objects the node printed as result lines."""
    return [json.loads(line) for line in log.splitlines() if line.startswith('{')]


class Traffic:
    """Counts the PSMs' servo commands and keeps their joint setpoints."""

    def __init__(self, ros):
        self.node = ros.node('signal_watch')
        self.servo, self.setpoints, self.recorder = [], {'PSM1': [], 'PSM2': []}, []
        for arm in ('PSM1', 'PSM2'):
            self.node.create_subscription(PoseStamped, f'/{arm}/servo_cp',
                                          lambda m: self.servo.append(time.monotonic()), 100)
            self.node.create_subscription(
                JointState, f'/{arm}/setpoint_js',
                lambda m, a=arm: self.setpoints[a].append(tuple(m.position)), 100)
        self.node.create_subscription(String, '/recorder/status',
                                      lambda m: self.recorder.append(json.loads(m.data)),
                                      LATCHED)

    def commands_after(self, count, proc, timeout=WORK_TIMEOUT):
        """Wait until ``count`` servo commands arrived (False if ``proc`` exits first)."""
        wait_for(lambda: len(self.servo) >= count or not proc.running(), timeout, period=0.05)
        return len(self.servo) >= count and proc.running()

    def holding(self, seconds=1.0):
        """Return True when no servo command arrives and no setpoint moves for ``seconds``."""
        n = len(self.servo)
        last = {a: len(s) for a, s in self.setpoints.items()}
        time.sleep(seconds)
        return len(self.servo) == n and all(
            len(set(self.setpoints[a][last[a] - 1:])) == 1 for a in self.setpoints)

    def reset_scene(self):
        client = self.node.create_client(Trigger, '/sim/reset')
        assert wait_for(client.service_is_ready, 30.0)
        future = client.call_async(Trigger.Request())
        assert wait_for(future.done, 60.0) and future.result().success


@SIGNALS
def test_nodes_stopped_during_start_up_exit_cleanly(launch, tmp_path, sig):
    for argv in (['simulator'], ['segmenter', '--ros-args', '-p', f'bag:={tmp_path}'],
                 ['executor', '--ros-args', '-p', f'segments:={SEGMENTS}']):
        proc = launch(*argv)
        assert wait_for(lambda p=proc: handles_signals(p) or not p.running(), 120.0)
        assert interrupt(proc, sig) == 128 + sig, (argv, proc.log())
        log = proc.log()
        assert '_sigint_gc' not in log and 'RCLError' not in log, log


@SIGNALS
def test_every_node_stopped_mid_work_holds_reports_and_exits_with_the_signal(
        ros, launch, tmp_path, sig):
    code = 128 + sig
    sim = launch('simulator', '--ros-args', '-p', 'real_time_factor:=0.5')
    traffic = Traffic(ros)

    # The executor in the middle of a throw: result file and result line say interrupted.
    result = tmp_path / 'result.json'
    executor = launch('executor', '--ros-args', '-p', f'segments:={SEGMENTS}', '-p',
                      'pair:=synth1', '-p', f'result_file:={result}', '-p', 'clock_timeout:=5.0')
    assert traffic.commands_after(20, executor), executor.log()
    assert interrupt(executor, sig) == code, executor.log()
    record = json.loads(result.read_text())
    assert record['outcome'] == 'interrupted' and record['state'] == 'interrupted'
    assert signal.Signals(sig).name in record['reason']
    assert [r['outcome'] for r in result_lines(executor.log())] == ['interrupted']
    assert traffic.holding(), 'the arms kept moving after the executor stopped'

    # The demonstrator mid-throw, recorded by the recorder it started with the pedal.
    traffic.reset_scene()
    recorder = launch('recorder', '--ros-args', '-p', f'output_dir:={tmp_path / "bags"}')
    demonstrator = launch('demonstrator', '--ros-args', '-p', 'pair:=synth2')
    sent = len(traffic.servo)
    assert traffic.commands_after(sent + 20, demonstrator), demonstrator.log()
    assert interrupt(demonstrator, sig) == code, demonstrator.log()
    lines = result_lines(demonstrator.log())
    assert [r['outcome'] for r in lines] == ['interrupted'] and lines[0]['completed'] is False
    assert traffic.holding(), 'the arms kept moving after the demonstrator stopped'
    assert traffic.recorder and traffic.recorder[-1]['recording']
    assert interrupt(recorder, sig) == code, recorder.log()
    bag = next((tmp_path / 'bags').iterdir())
    summary = bags.bag_summary(bag)  # closed properly: readable, with the throw's commands
    assert summary.message_count > 0
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['custom_data']['suture_lfd.outcome'] == 'interrupted'

    # The player replaying that bag in a loop.
    player = launch('player', '--ros-args', '-p', f'bag:={bag}', '-p', 'loop:=true',
                    '-p', 'topics:=[/PSM1/measured_js]')
    assert wait_for(lambda: 'playing' in player.log(), 120.0), player.log()
    assert interrupt(player, sig) == code, player.log()

    # Nodes that serve until stopped.
    for name in ('footpedals', 'teleop', 'mtms'):
        proc = launch(name, '--ros-args', '-r', f'__node:=stopped_{name}')
        assert wait_for(lambda n=name: f'stopped_{n}' in traffic.node.get_node_names(), 120.0), \
            proc.log()
        assert interrupt(proc, sig) == code, proc.log()

    assert sim.running()
    assert interrupt(sim, sig) == code, sim.log()


# --- nodes die with what started them -------------------------------------------------------

CHILD_TEST = """
import os
import time

from conftest import launch  # noqa: F401 (the fixture under test)
from harness import wait_for
from test_signals import handles_signals


def test_that_is_killed(launch):
    procs = [launch('simulator'), launch('footpedals')]
    assert wait_for(lambda: all(handles_signals(p) for p in procs), 300.0, period=0.2)
    with open(os.environ['NODE_PIDS'], 'w') as f:
        f.write(' '.join(str(p.pid) for p in procs))
    time.sleep(600)
"""


def _gone(pid):
    """Return True once ``pid`` has exited (a zombie left to a reaper counts as gone)."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] == 'Z'
    except OSError:
        return True


def test_the_nodes_of_a_test_run_killed_with_sigkill_die_with_it(tmp_path):
    (tmp_path / 'test_child.py').write_text(CHILD_TEST)
    pids_file = tmp_path / 'pids'
    here = Path(__file__).resolve().parent
    env = {**os.environ, 'NODE_PIDS': str(pids_file),
           'PYTHONPATH': os.pathsep.join([str(here), os.environ.get('PYTHONPATH', '')])}
    runner = subprocess.Popen(
        [sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', '--rootdir',
         str(tmp_path), str(tmp_path / 'test_child.py')], cwd=tmp_path, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        assert wait_for(lambda: pids_file.exists() and pids_file.read_text().strip()
                        or runner.poll() is not None, WORK_TIMEOUT, period=0.2)
        assert runner.poll() is None, runner.stdout.read().decode()[-3000:]
        nodes = [int(pid) for pid in pids_file.read_text().split()]
        assert len(nodes) == 2 and not any(_gone(pid) for pid in nodes)
        os.kill(runner.pid, signal.SIGKILL)       # the runner alone: no clean-up of its own
        runner.wait(10)
        assert wait_for(lambda: all(_gone(pid) for pid in nodes), 60.0, period=0.1), \
            [Path(f'/proc/{pid}/cmdline').read_bytes() for pid in nodes if not _gone(pid)]
    finally:
        if runner.poll() is None:
            os.killpg(runner.pid, signal.SIGKILL)
            runner.wait(10)


def test_the_nodes_of_a_script_killed_with_sigkill_die_with_it(tmp_path):
    env = {**os.environ, 'LOG_DIR': str(tmp_path)}
    script = subprocess.Popen([str(SCRIPTS / 'simulator.sh')], env=env, stderr=subprocess.PIPE,
                              text=True, start_new_session=True)
    try:
        line = script.stderr.readline()
        while line and 'started simulator' not in line:
            line = script.stderr.readline()
        node = int(re.search(r'pid (\d+)', line).group(1))
        while line and 'simulator ready' not in line:
            line = script.stderr.readline()
        assert 'simulator ready' in line and not _gone(node)
        os.kill(script.pid, signal.SIGKILL)       # the script alone: its trap never runs
        script.wait(10)
        assert wait_for(lambda: _gone(node), 60.0, period=0.1)
    finally:
        if script.poll() is None:
            os.killpg(script.pid, signal.SIGKILL)
            script.wait(10)
