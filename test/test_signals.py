"""
SIGINT and SIGTERM, sent to every node in the middle of its work, as a user or a script stops it.

Each node stops commanding (the arms hold), writes the result it has with outcome
``interrupted``, and exits with 128 + the signal number (130, 143): never 0 for a throw that did
not finish, and never a traceback (the ``launch`` fixture checks every log). A stop during
start-up (while the node's modules load, PyBullet connects, the node is built) is as clean.
"""

import json
import os
from pathlib import Path
import signal
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
