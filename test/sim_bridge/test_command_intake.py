"""
No command lost, none applied twice, none stale: the simulator's and the virtual MTMs' command
intake, real processes over DDS on loopback.

Every state command the arm cannot apply comes back on its ``error`` topic with its text
(``unknown state command 'L0-017'``), so commands with unique texts show, in the order the arm
applied them, which arrived, how often and in what order.
"""

import gc
import os
import re
import threading
import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

# as crtk publishes state_command (latched); 50 deep so that a burst sent before discovery is
# all in the publisher's history when the simulator's reader matches
LATCHED = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
VOLATILE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
READER = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
UNKNOWN = re.compile(r"unknown state command '([^']+)'")
BURST = 25


class Watch:
    """An arm's operating_state, error and warning messages, as received."""

    def __init__(self, ros, arm, name):
        self.node = node = ros.node(name)
        self.lock = threading.Lock()
        self.states, self.errors, self.warnings = [], [], []
        node.create_subscription(OperatingState, f'{arm}/operating_state',
                                 lambda m: self._add(self.states, m), EVENTS)
        node.create_subscription(String, f'{arm}/error', lambda m: self._add(self.errors, m.data),
                                 EVENTS)
        node.create_subscription(String, f'{arm}/warning',
                                 lambda m: self._add(self.warnings, m.data), EVENTS)

    def _add(self, items, value):
        with self.lock:
            items.append(value)

    def unknown(self):
        """The texts of the unknown state commands the arm reported, in its order."""
        with self.lock:
            return [m.group(1) for m in map(UNKNOWN.search, self.errors) if m]

    def state(self):
        with self.lock:
            return self.states[-1] if self.states else None


def send(pub, texts):
    for text in texts:
        pub.publish(StringStamped(string=text))


def linked(ros, pub, watch, tag, timeout=60.0):
    """
    Wait until a volatile publisher reaches the arm: probes (``P<tag>-<i>``) until one returns.

    ``get_subscription_count() > 0`` is not enough: it says the publisher has matched the
    reader, and the reader may match the publisher a moment later, dropping what came before.
    """
    deadline = time.monotonic() + timeout
    i = 0
    while time.monotonic() < deadline:
        if any(t.startswith(f'P{tag}-') for t in watch.unknown()):
            return True
        if pub.get_subscription_count():
            send(pub, [f'P{tag}-{i}'])
            i += 1
        time.sleep(0.05)
    return False


def burst(tag, k):
    return [f'{tag}-{k * BURST + i:03d}' for i in range(BURST)]


def test_state_command_bursts_from_latched_and_volatile_publishers_arrive_once_in_order(
        ros, launch):
    """200 commands: latched and volatile, publishers made before and after the simulator."""
    early = ros.node('early_client')
    pubs = {'L0': early.create_publisher(StringStamped, 'PSM1/state_command', LATCHED),
            'V0': early.create_publisher(StringStamped, 'PSM1/state_command', VOLATILE)}
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    time.sleep(0.1)
    # the latched one at once, before the simulator's node exists (as crtk does)
    sent = {'L0': burst('L0', 0)}
    send(pubs['L0'], sent['L0'])
    watch = Watch(ros, 'PSM1', 'watch')
    # a volatile publisher loses what it sends before the match (DDS): it waits for it
    assert linked(ros, pubs['V0'], watch, 'V0'), sim.log()
    sent['V0'] = burst('V0', 0)
    send(pubs['V0'], sent['V0'])
    sent['L0'] += burst('L0', 1)
    send(pubs['L0'], sent['L0'][BURST:])
    late = ros.node('late_client')
    pubs['L1'] = late.create_publisher(StringStamped, 'PSM1/state_command', LATCHED)
    pubs['V1'] = late.create_publisher(StringStamped, 'PSM1/state_command', VOLATILE)
    sent['L1'] = burst('L1', 0)
    send(pubs['L1'], sent['L1'])  # right after its node was made, no wait
    assert linked(ros, pubs['V1'], watch, 'V1')
    for k in (0, 1):  # interleaved bursts of all four
        sent.setdefault('V1', []).extend(burst('V1', k))
        send(pubs['V1'], burst('V1', k))
        if k == 0:
            sent['V0'] += burst('V0', 1)
            send(pubs['V0'], burst('V0', 1))
            sent['L1'] += burst('L1', 1)
            send(pubs['L1'], burst('L1', 1))
    total = sum(len(v) for v in sent.values())
    assert total == 200
    everything = {t for v in sent.values() for t in v}
    assert ros.wait_for(lambda: everything <= set(watch.unknown()), 60.0), \
        ' '.join(sorted(everything - set(watch.unknown())))
    time.sleep(1.0)  # a copy applied twice would come now
    got = [t for t in watch.unknown() if not t.startswith('P')]
    twice = sorted({t for t in got if got.count(t) > 1})
    assert len(got) == total, f'{len(got)} applied for {total} sent; twice: {twice}'
    assert sorted(got) == sorted(t for v in sent.values() for t in v)  # each once
    for tag, texts in sent.items():  # each publisher's order kept
        assert [t for t in got if t.startswith(tag)] == texts, tag
    assert sim.running()


def test_pause_then_resume_back_to_back_both_apply(ros, launch):
    watch = Watch(ros, 'PSM1', 'watch')
    node = ros.node('pause_client')
    pub = node.create_publisher(StringStamped, 'PSM1/state_command', LATCHED)
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    send(pub, ['enable', 'home'])  # at once, before discovery
    assert ros.wait_for(lambda: (s := watch.state()) is not None and s.state == 'ENABLED'
                        and s.is_homed and not s.is_busy, 60.0), sim.log()
    for _ in range(3):
        start = len(watch.states)
        send(pub, ['pause', 'resume'])
        assert ros.wait_for(lambda k=start: 'PAUSED' in [m.state for m in watch.states[k:]]
                            and watch.state().state == 'ENABLED', 10.0), watch.states[start:]
    with watch.lock:
        assert not [w for w in watch.warnings if 'not supported' in w], watch.warnings


def test_a_stale_latched_command_is_not_replayed_to_a_restarted_simulator(ros, launch):
    node = ros.node('long_lived_client')
    pub = node.create_publisher(StringStamped, 'PSM1/state_command', LATCHED)
    first = launch('simulator', '--ros-args', *FAST_ARMS)
    watch = Watch(ros, 'PSM1', 'watch')
    assert ros.wait_for(lambda: pub.get_subscription_count() > 0, 60.0), first.log()
    send(pub, ['enable'])
    assert ros.wait_for(lambda: (s := watch.state()) is not None and s.state == 'ENABLED',
                        30.0), first.log()
    first.stop()
    # the client lives on with 'enable' in its publisher's history; a new simulator starts
    watch2 = Watch(ros, 'PSM1', 'watch2')
    second = launch('simulator', '--ros-args', *FAST_ARMS)
    assert ros.wait_for(lambda: any('ignored a latched state_command' in w
                                    for w in watch2.warnings), 60.0), second.log()
    stale = [w for w in watch2.warnings if 'ignored a latched' in w]
    assert "'enable'" in stale[0] and 'before the simulator started' in stale[0]
    time.sleep(1.0)
    assert watch2.state() is not None and watch2.state().state == 'DISABLED'
    send(pub, ['enable'])  # sent again: applied
    assert ros.wait_for(lambda: watch2.state().state == 'ENABLED', 30.0), second.log()


def test_servo_jp_is_mapped_by_name_and_an_unknown_name_is_rejected(ros, launch):
    watch = Watch(ros, 'PSM1', 'watch')
    node = ros.node('named_client')
    command = node.create_publisher(StringStamped, 'PSM1/state_command', LATCHED)
    servo = node.create_publisher(JointState, 'PSM1/servo_jp', VOLATILE)
    move = node.create_publisher(JointState, 'PSM1/move_jp', VOLATILE)
    setpoints = []
    node.create_subscription(JointState, 'PSM1/setpoint_js', setpoints.append, READER)
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    send(command, ['enable', 'home'])
    assert ros.wait_for(lambda: (s := watch.state()) is not None and s.is_homed
                        and not s.is_busy and servo.get_subscription_count() > 0, 60.0), \
        sim.log()
    names = ('yaw', 'pitch', 'insertion', 'roll', 'wrist_pitch', 'wrist_yaw')
    goal = dict(zip(names, (0.1, -0.05, 0.13, 0.2, 0.15, -0.1)))
    shuffled = ('roll', 'insertion', 'wrist_yaw', 'yaw', 'wrist_pitch', 'pitch')

    def setpoint_is(values):
        return setpoints and all(abs(a - b) < 1e-9
                                 for a, b in zip(setpoints[-1].position, values))

    msg = JointState(name=list(shuffled), position=[goal[n] for n in shuffled])
    assert ros.wait_for(lambda: servo.publish(msg) or setpoint_is([goal[n] for n in names]),
                        10.0), setpoints[-1] if setpoints else None
    assert list(setpoints[-1].name) == list(names)
    # numeric names: by position
    numeric = [0.0, 0.0, 0.12, 0.0, 0.0, 0.0]
    msg = JointState(name=[str(i) for i in range(6)], position=numeric)
    assert ros.wait_for(lambda: servo.publish(msg) or setpoint_is(numeric), 10.0)
    # an unknown name: an error naming it, the setpoint kept, the node alive
    bad = JointState(name=['yaw', 'pitch', 'insertion', 'roll', 'wrist_pitch', 'elbow'],
                     position=[0.3] * 6)
    servo.publish(bad)
    move.publish(bad)
    assert ros.wait_for(lambda: len([e for e in watch.errors if "'elbow'" in e]) >= 2, 10.0), \
        watch.errors
    error = next(e for e in watch.errors if "'elbow'" in e)
    assert 'unknown joint name' in error and 'yaw, pitch, insertion' in error
    time.sleep(0.3)
    assert setpoint_is(numeric)
    assert sim.running()


@pytest.mark.parametrize('rate, late_share', [(100.0, 0.10), (200.0, 0.05)])
def test_state_gaps_stay_within_the_dvrk_teleop_limit_with_a_client_running(ros, launch, rate,
                                                                            late_share):
    """
    A client of PSM1's state as the dVRK's teleoperation script reads it, for 10 s.

    The gaps between consecutive ``measured_cp``/``setpoint_cp``/``measured_js`` messages, as
    received: the dVRK publishes every 10 ms and the script raises on data older than 20 ms.
    The bounds are a recorded measurement, not a speed race: on a shared two-core machine under
    a load average of 14 to 21 (ten times more work than cores), the dVRK's 100 Hz gave 0.5 to
    4.4 % of the gaps over 20 ms and a longest gap of 45 to 320 ms (either process kept off the
    cores for a moment), ``rate:=200`` (the README's setting for the dVRK's teleoperation
    script) 0.1 to 0.2 % and 31 ms; the bounds allow about twice the worst of that, so that
    they fail on a stall of the simulator, not of the machine. bench/bench_simulator_node.py
    --gaps gives the distributions.
    """
    sim = launch('simulator', '--ros-args', *FAST_ARMS, '-p', f'rate:={rate}')
    node = ros.node('gap_client')
    arrivals = {topic: [] for topic in ('measured_cp', 'setpoint_cp', 'measured_js')}
    types = {'measured_cp': PoseStamped, 'setpoint_cp': PoseStamped, 'measured_js': JointState}
    for topic, times in arrivals.items():
        node.create_subscription(types[topic], f'PSM1/{topic}',
                                 lambda m, t=times: t.append(time.monotonic()), READER)
    assert ros.wait_for(lambda: all(len(t) > 100 for t in arrivals.values()), 60.0), sim.log()
    # the test process holds far more objects than a client script: keep its own collector off
    # them, so that the gaps measured are the simulator's (a full collection here stalls the
    # client for a few hundred ms)
    gc.collect()
    gc.freeze()
    try:
        start = time.monotonic()
        time.sleep(10.0)
        end = time.monotonic()
    finally:
        gc.unfreeze()
    gaps = np.concatenate([np.diff([t for t in times if start <= t <= end])
                           for times in arrivals.values()])
    summary = (f'median {np.median(gaps) * 1e3:.1f} ms, p99 {np.percentile(gaps, 99) * 1e3:.1f} '
               f'ms, max {gaps.max() * 1e3:.1f} ms, {int(np.sum(gaps > 0.020))} of {gaps.size} '
               f'over 20 ms, load average {os.getloadavg()[0]:.1f}')
    print(f'PSM1 state gaps over 10 s at {rate:g} Hz: {summary}')
    assert gaps.size > 0.8 * 3 * 10.0 * rate, summary
    assert 0.8 / rate < np.median(gaps) < 1.2 / rate, summary
    assert np.mean(gaps > 0.020) <= late_share, summary
    assert gaps.max() < 1.0, summary
