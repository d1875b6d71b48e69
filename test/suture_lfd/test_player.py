"""The player as a real process: a replayed bag recorded again is the same bag; options; errors."""

import json
from pathlib import Path
import re
import time

from harness import SIGINT_EXIT, wait_for
import pytest
from suture_lfd import bags
from test_recorder import BURST_TOPICS, call, launch_recorder, make_message, message_types

T0_NS = 1_750_000_000 * 10**9
TICK_NS = 5_000_000  # 200 Hz
SOURCE_TOPICS = {t: BURST_TOPICS[t] for t in (
    '/PSM1/measured_js', '/PSM2/measured_js', '/PSM1/measured_cp', '/PSM1/servo_cp',
    '/PSM1/operating_state', '/sim/events')}
TYPE_NAMES = {'JointState': 'sensor_msgs/msg/JointState',
              'PoseStamped': 'geometry_msgs/msg/PoseStamped',
              'OperatingState': 'crtk_msgs/msg/OperatingState',
              'StringStamped': 'crtk_msgs/msg/StringStamped'}


def write_source_bag(path, n_ticks):
    """A bag of ``n_ticks`` ticks at 200 Hz on SOURCE_TOPICS; return {topic: [messages]}."""
    from rclpy.serialization import serialize_message

    sent = {t: [] for t in SOURCE_TOPICS}
    with bags.BagWriter(path) as writer:
        for topic, (kind, latched, _) in SOURCE_TOPICS.items():
            writer.add_topic(topic, TYPE_NAMES[kind], qos=[bags.make_qos(
                transient_local=latched, depth=1000 if latched else 100)])
        for tick in range(n_ticks):
            for topic, (kind, _, every) in SOURCE_TOPICS.items():
                if tick % every == 0:
                    msg = make_message(kind, tick)
                    writer.write(topic, T0_NS + tick * TICK_NS, serialize_message(msg))
                    sent[topic].append(msg)
    return sent


def launch_player(launch, bag, *params):
    args = ['--ros-args', '-p', f'bag:={bag}']
    for p in params:
        args += ['-p', p]
    return launch('player', *args)


def latched_status(ros, node):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    statuses = []
    node.create_subscription(
        String, '/recorder/status', lambda m: statuses.append(json.loads(m.data)),
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    return statuses


def test_replayed_bag_recorded_again_holds_the_same_messages(ros, launch, tmp_path):
    from rclpy.serialization import deserialize_message

    sent = write_source_bag(tmp_path / 'source', n_ticks=200)
    n_source = sum(len(v) for v in sent.values())
    recorder = launch_recorder(launch, tmp_path, 'status_period:=0.1')
    node = ros.node('replay_check')
    statuses = latched_status(ros, node)
    started = call(ros, node, '/recorder/start')
    assert started.success, started.message

    player = launch_player(launch, tmp_path / 'source', 'wait_for_subscribers:=20.0')
    assert player.popen.wait(30.0) == 0, player.log()
    assert f'done: {n_source} messages on {len(sent)} topics' in player.log()
    assert wait_for(lambda: statuses[-1].get('received') == n_source, 10.0), \
        (statuses[-1], recorder.log())
    stopped = call(ros, node, '/recorder/stop')
    assert stopped.success and json.loads(stopped.message)['written'] == n_source

    again = Path(started.message)
    source, copy = bags.bag_summary(tmp_path / 'source'), bags.bag_summary(again)
    assert {t: s.count for t, s in copy.topics.items()} == \
        {t: s.count for t, s in source.topics.items()}
    assert {t: s.msgtype for t, s in copy.topics.items()} == \
        {t: s.msgtype for t, s in source.topics.items()}
    # the original timing: the copy spans about the source's duration (a player without
    # timing would squeeze it into milliseconds). Receive stamps jitter on a busy machine: a
    # late first delivery shortens the span while the player keeps to its schedule, so the
    # bounds are wide and there is no per-message check.
    assert 0.5 * source.duration_s < copy.duration_s < 3.0 * source.duration_s, \
        (copy.duration_s, source.duration_s)
    # the player itself kept to the schedule: it cannot finish before the bag's duration (the
    # log rounds to 1 ms)
    played = float(re.search(r'done: \d+ messages on \d+ topics in ([0-9.]+) s',
                             player.log()).group(1))
    assert source.duration_s - 0.001 <= played < 3.0 * source.duration_s, \
        (played, source.duration_s)
    # the latched topics are played (and so recorded) as latched
    assert bags.qos_fields(copy.topics['/sim/events'].qos)[:2] == (True, True)
    types = message_types()
    with bags.open_bag(again) as reader:
        for topic, messages in sent.items():
            cls = types[SOURCE_TOPICS[topic][0]]
            replayed = [deserialize_message(bytes(m.rawdata), cls)
                        for m in reader.messages([topic])]
            assert replayed == messages, topic


def test_player_honours_rate_offset_topic_filter_and_clock(ros, launch, tmp_path):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    sent = write_source_bag(tmp_path / 'source', n_ticks=200)  # 1 s of bag time
    node = ros.node('options_check')
    got, other, clock = [], [], []
    node.create_subscription(JointState, '/PSM1/measured_js',
                             lambda m: got.append((time.monotonic(), m)), 1000)
    node.create_subscription(JointState, '/PSM2/measured_js', other.append, 1000)
    node.create_subscription(Clock, '/clock', lambda m: clock.append(
        m.clock.sec * 10**9 + m.clock.nanosec), QoSProfile(
            depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    player = launch_player(launch, tmp_path / 'source', 'rate:=2.0', 'start_offset:=0.5',
                           'topics:=[/PSM1/measured_js]', 'publish_clock:=true',
                           'clock_rate:=50.0', 'wait_for_subscribers:=20.0')
    assert player.popen.wait(30.0) == 0, player.log()
    expected = sent['/PSM1/measured_js'][100:]  # ticks at or after 0.5 s
    assert wait_for(lambda: len(got) == len(expected), 5.0), (len(got), player.log())
    assert [m for _, m in got] == expected
    assert other == []
    # 99 gaps of 5 ms of bag time at rate 2: 0.25 s of wall time by the player's clock (rate 1
    # would take 0.5 s); the receiver cannot see them all sooner than that
    played = re.search(r'done: \d+ messages on 1 topics in ([0-9.]+) s', player.log())
    assert played and float(played.group(1)) == pytest.approx(0.2475, abs=0.05), player.log()
    assert got[-1][0] - got[0][0] > 0.2
    assert clock and clock == sorted(clock)
    assert T0_NS + 500_000_000 <= clock[0] and clock[-1] <= T0_NS + 199 * TICK_NS
    assert len(clock) <= 0.5 * 50 + 2


def test_player_loops_until_stopped(ros, launch, tmp_path):
    from sensor_msgs.msg import JointState

    sent = write_source_bag(tmp_path / 'source', n_ticks=40)  # 0.2 s
    node = ros.node('loop_check')
    got = []
    node.create_subscription(JointState, '/PSM2/measured_js', got.append, 1000)
    player = launch_player(launch, tmp_path / 'source', 'loop:=true', 'rate:=2.0',
                           'topics:=[/PSM2/measured_js]', 'wait_for_subscribers:=20.0')
    n = len(sent['/PSM2/measured_js'])
    assert wait_for(lambda: len(got) >= 3 * n, 10.0), player.log()
    assert got[:2 * n] == sent['/PSM2/measured_js'] * 2
    assert player.running()
    assert player.stop() == SIGINT_EXIT, player.log()


@pytest.mark.parametrize('case', ['no-metadata', 'missing-topic', 'bad-rate'])
def test_player_refuses_a_bad_bag_or_parameter_naming_it(launch, tmp_path, case):
    write_source_bag(tmp_path / 'source', n_ticks=4)
    params = []
    if case == 'no-metadata':
        (tmp_path / 'source' / 'metadata.yaml').unlink()
        needle = f'{tmp_path / "source" / "metadata.yaml"} is missing'
    elif case == 'missing-topic':
        params = ['topics:=[/PSM3/measured_js]']
        needle = 'bag has no messages on /PSM3/measured_js'
    else:
        params = ['rate:=0.0']
        needle = 'parameter rate must be > 0'
    player = launch_player(launch, tmp_path / 'source', *params)
    assert player.popen.wait(20.0) == 2
    assert needle in player.log()
