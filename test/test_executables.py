"""
Every executable as a newcomer first meets it: ``--help`` answers and never moves a robot.

A simulator runs in the test's domain while each executable is asked for help: asking must not
start a node (the demonstrator and executor would enable, home and move the arms), so every
arm's ``measured_js`` and ``operating_state`` stay as they were.
"""

from importlib.metadata import entry_points
import resource
import subprocess
import time

from crtk_msgs.msg import OperatingState
from harness import REPO, executable, forbidden_lines
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from sim_bridge.common.configfile import load_yaml
from sim_bridge.common.paths import config_path

ARMS = ('PSM1', 'PSM2', 'ECM')
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# A newcomer's patience is 5 s of wall time; on this shared 2-core machine a process may get a
# tenth of a core, so the test bounds the CPU time help takes (it must not import the node nor
# start ROS: about 0.3 s) and gives the wall clock the margin a loaded machine needs.
HELP_CPU_LIMIT = 2.0     # s of CPU time (user + system) of one --help
HELP_WALL_LIMIT = 60.0   # s of wall time


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
    """Run a help request; return its result, wall time and CPU time (s)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    began = time.monotonic()
    out = subprocess.run(argv, capture_output=True, text=True, timeout=120, **kwargs)
    wall = time.monotonic() - began
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return out, wall, cpu


def test_every_executable_answers_help_without_moving_an_arm(ros, launch):
    sim = launch('simulator')
    watch = ArmWatch(ros)
    assert ros.wait_for(watch.ready, timeout=120.0), sim.log()
    names = node_executables()
    for name in names:
        for flag in ('--help', '-h'):
            out, wall, cpu = _help([executable(name), flag])
            assert out.returncode == 0, (name, flag, out.stderr)
            assert cpu < HELP_CPU_LIMIT and wall < HELP_WALL_LIMIT, (name, flag, cpu, wall)
            assert out.stdout.startswith(f'usage: {name}'), out.stdout
            assert 'example:' in out.stdout
            for param in parameters(name):
                assert f'\n  {param} ' in out.stdout, (name, param, out.stdout)
            assert 'Traceback' not in out.stderr
    out, wall, cpu = _help([str(REPO / 'suture-lfd'), '--help'])
    assert out.returncode == 0 and cpu < HELP_CPU_LIMIT and wall < HELP_WALL_LIMIT, \
        (out.stderr, cpu, wall)
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



def test_pybullet_says_nothing_on_the_programs_output():
    """``suture-lfd info > file`` holds the report only: no PyBullet banner on either stream."""
    out = subprocess.run([executable('suture-lfd'), 'info', '--seconds', '0.01'],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith('phantom synthetic:'), out.stdout[:200]
    assert forbidden_lines(out.stdout + out.stderr) == []
