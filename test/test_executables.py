"""
Every executable as a newcomer first meets it: ``--help`` answers and never moves a robot.

A simulator runs in the test's domain while each executable is asked for help: asking must not
start a node (the demonstrator and executor would enable, home and move the arms), so every
arm's ``measured_js`` and ``operating_state`` stay as they were.
"""

from importlib.metadata import entry_points
import subprocess
import time

from crtk_msgs.msg import OperatingState
from harness import REPO, executable
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from sim_bridge.configfile import load_yaml
from sim_bridge.paths import config_path

ARMS = ('PSM1', 'PSM2', 'ECM')
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
HELP_WALL_LIMIT = 5.0  # s: a newcomer's patience, on a busy machine


def node_executables():
    """Return the node executables of the package (console scripts other than the CLI)."""
    names = sorted(ep.name for ep in entry_points(group='console_scripts')
                   if ep.value.split('.')[0] in ('sim_bridge', 'suture_lfd')
                   and '.nodes.' in ep.value)
    assert 'simulator' in names and 'executor' in names, names
    return names


def parameters(name):
    """Return the parameter names of an executable's ``config/<name>.yaml`` (none: [])."""
    try:
        path = config_path(f'{name}.yaml')
    except FileNotFoundError:
        return []
    if not path.exists():
        return []
    return list((load_yaml(path).get(name) or {}).get('ros__parameters') or {})


class ArmWatch:
    """Every arm's joint positions and operating state, as the simulator publishes them."""

    def __init__(self, ros):
        self.node = ros.node('arm_watch')
        self.positions = {arm: [] for arm in ARMS}
        self.states = {arm: [] for arm in ARMS}
        for arm in ARMS:
            self.node.create_subscription(
                JointState, f'/{arm}/measured_js',
                lambda m, a=arm: self.positions[a].append(tuple(m.position)), 10)
            self.node.create_subscription(
                OperatingState, f'/{arm}/operating_state',
                lambda m, a=arm: self.states[a].append(m.state), LATCHED)

    def ready(self):
        return all(self.positions[a] and self.states[a] for a in ARMS)

    def moved(self):
        """Return the arms whose joints or state changed since the watch began."""
        return [a for a in ARMS if len(set(self.positions[a])) > 1
                or len(set(self.states[a])) > 1]


def _help(argv, **kwargs):
    began = time.monotonic()
    out = subprocess.run(argv, capture_output=True, text=True, timeout=60, **kwargs)
    return out, time.monotonic() - began


def test_every_executable_answers_help_without_moving_an_arm(ros, launch):
    sim = launch('simulator')
    watch = ArmWatch(ros)
    assert ros.wait_for(watch.ready, timeout=120.0), sim.log()
    names = node_executables()
    for name in names:
        for flag in ('--help', '-h'):
            out, took = _help([executable(name), flag])
            assert out.returncode == 0, (name, flag, out.stderr)
            assert took < HELP_WALL_LIMIT, (name, flag, took)
            assert out.stdout.startswith(f'usage: {name}'), out.stdout
            assert 'example:' in out.stdout
            for param in parameters(name):
                assert f'\n  {param} ' in out.stdout, (name, param, out.stdout)
            assert 'Traceback' not in out.stderr
    out, took = _help([str(REPO / 'suture-lfd'), '--help'])
    assert out.returncode == 0 and took < HELP_WALL_LIMIT, (out.stderr, took)
    for command in ('study', 'test', 'setup', 'info', 'bag', *names):
        assert command in out.stdout, (command, out.stdout)
    for flag in ('-h', 'help'):
        assert _help([str(REPO / 'suture-lfd'), flag])[0].stdout == out.stdout
    time.sleep(1.0)  # anything a help request had started would be moving by now
    assert watch.positions['PSM1'] and watch.moved() == []
    assert sim.running()


def test_a_mistyped_argument_never_starts_the_demonstrator(ros, launch):
    sim = launch('simulator')
    watch = ArmWatch(ros)
    assert ros.wait_for(watch.ready, timeout=120.0), sim.log()
    for argv, says in ((['--pair', 'synth2'], "unknown argument '--pair'"),
                       (['--ros-args', '-p', 'subjet:=S02'], "unknown parameter 'subjet'")):
        out = subprocess.run([executable('demonstrator'), *argv], capture_output=True,
                             text=True, timeout=120)
        assert out.returncode == 2
        assert says in out.stderr.strip().splitlines()[-1], out.stderr
        assert 'Traceback' not in out.stderr
    time.sleep(1.0)
    assert watch.moved() == []


def test_a_node_that_cannot_start_says_why_in_one_line(tmp_path):
    out = subprocess.run([executable('demonstrator'), '--ros-args', '-p', 'subject:=S11'],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.startswith('demonstrator: error: ') and "'S11'" in out.stderr
    assert out.stderr.count('\n') == 1, out.stderr
    assert out.stdout == ''

