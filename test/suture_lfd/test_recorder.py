"""The recorder as a real process: bursts recorded whole, pedal toggle, bad commands, SIGKILL."""

import json
from pathlib import Path
import subprocess
import sys
import threading
import time

from harness import SIGINT_EXIT, wait_for
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import pytest
from rosbags.rosbag2 import Reader
from suture_lfd import bags

RATE_HZ = 200.0
# topic -> (type name, latched, publish every n-th tick)
BURST_TOPICS = {
    '/PSM1/measured_js': ('JointState', False, 1),
    '/PSM2/measured_js': ('JointState', False, 1),
    '/PSM1/measured_cp': ('PoseStamped', False, 1),
    '/PSM2/setpoint_cp': ('PoseStamped', False, 1),
    '/sim/needle/measured_cp': ('PoseStamped', False, 1),
    '/PSM1/servo_cp': ('PoseStamped', False, 2),
    '/PSM1/operating_state': ('OperatingState', True, 40),
    '/sim/events': ('StringStamped', True, 25),
}


def message_types():
    from crtk_msgs.msg import OperatingState, StringStamped
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState

    return {'JointState': JointState, 'PoseStamped': PoseStamped,
            'OperatingState': OperatingState, 'StringStamped': StringStamped}


def make_message(kind, tick):
    """A message of ``kind`` whose content identifies ``tick``."""
    cls = message_types()[kind]
    msg = cls()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1000 + tick // 1000, (tick % 1000) * 1000
    if kind == 'JointState':
        msg.name = [f'joint_{i}' for i in range(6)]
        msg.position = [tick + 0.125 * i for i in range(6)]
        msg.velocity = [0.5 * tick] * 6
    elif kind == 'PoseStamped':
        msg.header.frame_id = 'PSM1_base'
        msg.pose.position.x, msg.pose.position.y = 1e-3 * tick, -2e-3 * tick
        msg.pose.orientation.w = 1.0
    elif kind == 'OperatingState':
        msg.state, msg.is_homed, msg.is_busy = ('ENABLED', True, bool(tick % 2))
    else:
        msg.string = json.dumps({'kind': 'entry', 'arm': 'PSM1', 'tick': tick})
    return msg


class Burst:
    """Publishers of the burst topics in the test's own node, paced by ``time.sleep``."""

    def __init__(self, node, topics=BURST_TOPICS):
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        self.topics = topics
        self.sent = {t: [] for t in topics}
        self.pubs = {}
        for topic, (kind, latched, _) in topics.items():
            qos = QoSProfile(depth=1000 if latched else 100,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                         else DurabilityPolicy.VOLATILE))
            self.pubs[topic] = node.create_publisher(message_types()[kind], topic, qos)
        self._stop = threading.Event()

    def matched(self):
        return all(p.get_subscription_count() > 0 for p in self.pubs.values())

    def run(self, seconds, rate_hz=RATE_HZ, first_tick=0):
        """Publish for ``seconds`` at ``rate_hz`` ticks (blocking); return messages sent."""
        period = 1.0 / rate_hz
        t0 = time.monotonic()
        tick = 0
        while tick * period < seconds and not self._stop.is_set():
            for topic, (kind, _, every) in self.topics.items():
                if tick % every == 0:
                    msg = make_message(kind, first_tick + tick)
                    self.pubs[topic].publish(msg)
                    self.sent[topic].append(msg)
            tick += 1
            time.sleep(max(0.0, t0 + tick * period - time.monotonic()))
        return sum(len(v) for v in self.sent.values())

    def run_in_background(self, seconds):
        thread = threading.Thread(target=self.run, args=(seconds,), daemon=True)
        thread.start()
        return thread

    def stop(self):
        self._stop.set()

    def wait_acked(self, timeout=10.0):
        from rclpy.duration import Duration

        return all(p.wait_for_all_acked(Duration(seconds=timeout)) for p in self.pubs.values())


def call(ros, node, service, timeout=20.0, resend_after=5.0, starts=False):
    """
    Call a std_srvs/Trigger service; return the response.

    Fast DDS drops a response when the server takes the request before it has discovered the
    client's reply reader (the server logs "failed to send response (timeout)"); this happens on
    a loaded machine with UDP discovery. A request not answered within ``resend_after`` seconds
    is sent again from a new client. The recorder's ``~/start`` refuses a second start with
    "already recording to PATH": when ``starts`` (the caller starts a recorder that was idle),
    that refusal of a resent request says the first one was taken, and the answer returned is
    the first one's (success, PATH).
    """
    from std_srvs.srv import Trigger

    deadline = time.monotonic() + timeout
    resent = False
    while True:
        client = node.create_client(Trigger, service)
        assert wait_for(client.service_is_ready, timeout), f'{service} never appeared'
        future = client.call_async(Trigger.Request())
        left = deadline - time.monotonic()
        if wait_for(future.done, min(resend_after, max(left, 0.0))):
            break
        assert time.monotonic() < deadline, f'{service} did not answer'
        resent = True
    answer = future.result()
    prefix = 'already recording to '
    if (starts and resent and not answer.success
            and answer.message.startswith(prefix)):
        answer.success = True
        answer.message = answer.message[len(prefix):].split(';')[0]
    return answer


def launch_recorder(launch, tmp_path, *params, env=None):
    args = ['--ros-args', '-p', f'output_dir:={tmp_path / "bags"}']
    for p in params:
        args += ['-p', p]
    return launch('recorder', *args, env=env)


def read_with_rosbags(path):
    """{topic: [(t_ns, raw bytes), ...]} straight from rosbags' Reader."""
    got = {}
    with Reader(path) as reader:
        for conn, t_ns, raw in reader.messages():
            got.setdefault(conn.topic, []).append((t_ns, bytes(raw)))
    return got


def read_with_mcap(path):
    """{topic: [decoded message, ...]} from the MCAP file with mcap + mcap_ros2 only."""
    got = {}
    (mcap_file,) = Path(path).glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, ros in reader.iter_decoded_messages(log_time_order=False):
            got.setdefault(channel.topic, []).append(ros)
    return got


def test_recorder_writes_every_message_of_a_burst_readable_by_rosbags_and_mcap(
        ros, launch, tmp_path):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    proc = launch_recorder(launch, tmp_path, 'status_period:=0.2')
    node = ros.node('burst_source')
    statuses = []
    node.create_subscription(
        String, '/recorder/status', lambda m: statuses.append(json.loads(m.data)),
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    burst = Burst(node)
    assert wait_for(burst.matched, 20.0), proc.log()

    started = call(ros, node, '/recorder/start', starts=True)
    assert started.success, started.message
    bag = Path(started.message)
    assert bag.parent == tmp_path / 'bags'
    t0 = time.monotonic()
    total = burst.run(1.5)
    elapsed = time.monotonic() - t0
    assert burst.wait_acked()
    # acknowledged = in the recorder's reader; wait until its callbacks have taken them too
    assert wait_for(lambda: statuses[-1].get('received') == total, 5.0), statuses[-1]
    stopped = call(ros, node, '/recorder/stop')
    assert stopped.success, stopped.message
    counts = json.loads(stopped.message)

    # the recorder received what was published, and wrote what it received
    assert len(burst.sent['/PSM1/measured_js']) >= 100 * 1.5 and total / elapsed > 600
    assert counts['bag'] == str(bag) and counts['lost'] == 0
    assert counts['received'] == counts['written'] == total
    for topic, sent in burst.sent.items():
        assert counts['topics'][topic] == {'received': len(sent), 'carried': 0,
                                           'written': len(sent), 'missed': 0}
    assert any(s['recording'] and s.get('received', 0) > 0 for s in statuses)
    assert wait_for(lambda: statuses and not statuses[-1]['recording'], 5.0)

    # rosbags: every message, in publication order, byte-for-byte decodable by rclpy
    stored = read_with_rosbags(bag)
    assert set(stored) == set(burst.sent)
    types = message_types()
    for topic, sent in burst.sent.items():
        times = [t for t, _ in stored[topic]]
        assert times == sorted(times)
        cls = types[BURST_TOPICS[topic][0]]
        assert [deserialize_message(raw, cls) for _, raw in stored[topic]] == sent

    # mcap + mcap_ros2, from the schemas in the file alone
    decoded = read_with_mcap(bag)
    for topic, sent in burst.sent.items():
        assert len(decoded[topic]) == len(sent)
        kind = BURST_TOPICS[topic][0]
        for ros_msg, msg in zip(decoded[topic], sent):
            assert ros_msg.header.stamp.nanosec == msg.header.stamp.nanosec
            if kind == 'JointState':
                assert list(ros_msg.position) == list(msg.position)
            elif kind == 'OperatingState':
                assert (ros_msg.state, ros_msg.is_busy) == (msg.state, msg.is_busy)
            elif kind == 'StringStamped':
                assert ros_msg.string == msg.string
            else:
                assert ros_msg.pose.position.x == msg.pose.position.x

    # metadata: version 9, QoS of the latched topics kept for playback
    summary = bags.bag_summary(bag)
    assert summary.message_count == total
    assert summary.topics['/sim/events'].msgtype == 'crtk_msgs/msg/StringStamped'
    assert bags.qos_fields(summary.topics['/sim/events'].qos)[:2] == (True, True)
    assert bags.qos_fields(summary.topics['/PSM1/measured_js'].qos)[:2] == (True, False)
    assert 'version: 9' in (bag / 'metadata.yaml').read_text()
    assert proc.running()


def test_a_recording_holds_what_was_published_after_its_start_however_long_the_rest(
        ros, launch, tmp_path):
    # at rest the recorder does not take the streams; DDS holds their last messages, which a
    # recording must neither write nor count as missed
    from rclpy.serialization import deserialize_message

    streams = {t: v for t, v in BURST_TOPICS.items() if not v[1]}
    proc = launch_recorder(launch, tmp_path, 'depth:=50')
    node = ros.node('rest_source')
    burst = Burst(node, streams)
    assert wait_for(burst.matched, 20.0), proc.log()
    burst.run(1.0)                   # 200 messages per topic at rest: more than the depth
    assert burst.wait_acked()
    burst.sent = {t: [] for t in streams}
    started = call(ros, node, '/recorder/start', starts=True)
    assert started.success, started.message
    burst.run(0.5, first_tick=10_000)
    assert burst.wait_acked()
    time.sleep(1.0)                  # the recorder's callbacks take what its reader holds
    stopped = call(ros, node, '/recorder/stop')
    counts = json.loads(stopped.message)
    assert counts['lost'] == 0, counts
    for topic, sent in burst.sent.items():
        assert counts['topics'][topic] == {'received': len(sent), 'carried': 0,
                                           'written': len(sent), 'missed': 0}, topic
    stored = read_with_rosbags(Path(started.message))
    for topic, sent in burst.sent.items():
        cls = message_types()[streams[topic][0]]
        assert [deserialize_message(raw, cls) for _, raw in stored[topic]] == sent
    assert proc.running()


def test_recorder_refuses_a_bad_start_stop_sequence_and_keeps_running(ros, launch, tmp_path):
    proc = launch_recorder(launch, tmp_path)
    node = ros.node('bad_client')
    refused = call(ros, node, '/recorder/stop')
    assert not refused.success and 'not recording' in refused.message
    first = call(ros, node, '/recorder/start', starts=True)
    assert first.success
    again = call(ros, node, '/recorder/start')
    assert not again.success and 'already recording' in again.message
    assert first.message in again.message
    done = call(ros, node, '/recorder/stop')
    assert done.success and json.loads(done.message)['written'] == 0
    refused = call(ros, node, '/recorder/stop')
    assert not refused.success and 'call ~/start first' in refused.message
    second = call(ros, node, '/recorder/start', starts=True)
    assert second.success and second.message != first.message
    assert proc.running(), proc.log()
    assert proc.stop() == SIGINT_EXIT, proc.log()
    # stopping the process closes the open bag properly
    assert bags.bag_summary(second.message).message_count == 0


def test_camera_pedal_press_toggles_recording(ros, launch, tmp_path):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Joy
    from std_msgs.msg import String

    proc = launch_recorder(launch, tmp_path)
    node = ros.node('pedal_press')
    statuses = []
    node.create_subscription(
        String, '/recorder/status', lambda m: statuses.append(json.loads(m.data)),
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    pedal = node.create_publisher(Joy, '/footpedals/camera', QoSProfile(
        depth=100, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    assert wait_for(lambda: pedal.get_subscription_count() >= 2, 20.0), proc.log()
    assert wait_for(lambda: statuses, 10.0)
    pedal.publish(Joy(buttons=[1]))
    assert wait_for(lambda: statuses[-1]['recording'], 10.0), proc.log()
    pedal.publish(Joy(buttons=[0]))  # release: no change
    pedal.publish(Joy(buttons=[1]))
    assert wait_for(lambda: not statuses[-1]['recording'], 10.0), proc.log()
    bag = Path(statuses[-1]['bag'])
    # the pedal topic itself is recorded: the release, and the presses when their recording
    # callback ran after the toggle (both orders are legal in one executor)
    with bags.open_bag(bag, required=['/footpedals/camera']) as reader:
        presses = [reader.deserialize(m).buttons.tolist() for m in reader]
    assert presses in ([[0]], [[1], [0]], [[0], [1]], [[1], [0], [1]])
    assert proc.running()


def test_killed_recorder_leaves_a_bag_that_recover_restores(ros, launch, tmp_path):
    from rclpy.serialization import deserialize_message

    # UDP only: a killed process cannot clean Fast DDS shared-memory files.
    proc = launch_recorder(launch, tmp_path, 'chunk_seconds:=0.2',
                           env={'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'})
    node = ros.node('kill_source')
    topics = {t: BURST_TOPICS[t] for t in ('/PSM1/measured_js', '/PSM1/measured_cp',
                                           '/sim/events')}
    burst = Burst(node, topics)
    assert wait_for(burst.matched, 20.0), proc.log()
    started = call(ros, node, '/recorder/start', starts=True)
    assert started.success
    thread = burst.run_in_background(3.0)
    time.sleep(1.5)
    proc.kill()
    burst.stop()
    thread.join(5.0)
    killed = Path(started.message)
    assert not (killed / 'metadata.yaml').exists()
    with pytest.raises(bags.BagError, match='metadata.yaml is missing'):
        bags.open_bag(killed)

    cli = Path(sys.executable).parent / 'suture-lfd'
    out = tmp_path / 'recovered'
    result = subprocess.run([cli, 'bag', 'recover', killed, '--out', out],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    stored = read_with_rosbags(out)
    n_stored = sum(len(v) for v in stored.values())
    n_sent = sum(len(v) for v in burst.sent.values())
    # chunks flushed every 0.2 s of a ~1.5 s recording: most messages survive, none is invented
    # (without the timed flushes the 256 KiB chunk would still be open: nothing would survive)
    assert 0.3 * n_sent < n_stored <= n_sent, (n_stored, n_sent)
    types = message_types()
    for topic, raws in stored.items():
        cls = types[topics[topic][0]]
        # exactly the first messages published on each topic, in order
        assert [deserialize_message(raw, cls) for _, raw in raws] == \
            burst.sent[topic][:len(raws)]
    assert len(read_with_mcap(out)['/PSM1/measured_js']) == len(stored['/PSM1/measured_js'])


def test_a_recorder_on_sim_time_takes_clock_only_while_recording_and_stamps_with_it(
        ros, launch, tmp_path):
    # at rest /clock costs the recorder nothing: only its streams' node, spun while it records,
    # subscribes to it; a bag's stamps are the simulator's time, from its first message on
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    streams = {t: v for t, v in BURST_TOPICS.items() if t == '/PSM1/measured_js'}
    proc = launch_recorder(launch, tmp_path, 'use_sim_time:=true')
    node = ros.node('sim_clock')
    clock = node.create_publisher(Clock, '/clock', QoSProfile(
        depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    burst = Burst(node, streams)
    sim_t0 = 5000.0                  # s of sim time: far from the wall clock's
    ticks = {'n': 0}
    stop = threading.Event()

    def tick_clock():
        while not stop.is_set():
            t = sim_t0 + 0.005 * ticks['n']
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = int(t), int(round((t % 1) * 1e9))
            clock.publish(msg)
            ticks['n'] += 1
            time.sleep(0.005)
    ticker = threading.Thread(target=tick_clock, daemon=True)
    ticker.start()
    try:
        assert wait_for(burst.matched, 20.0), proc.log()

        def clock_readers():
            return sorted(i.node_name for i in node.get_subscriptions_info_by_topic('/clock'))
        assert wait_for(lambda: clock_readers() == ['recorder_streams'], 20.0), clock_readers()
        time.sleep(1.0)              # at rest, the clock ticks on
        started = call(ros, node, '/recorder/start', starts=True)
        assert started.success, started.message
        sim_start = sim_t0 + 0.005 * ticks['n']
        burst.run(0.5)
        time.sleep(1.0)
        stopped = call(ros, node, '/recorder/stop')
        sim_stop = sim_t0 + 0.005 * ticks['n']
        assert stopped.success, stopped.message
    finally:
        stop.set()
        ticker.join()
    stamps = [t_ns * 1e-9 for msgs in read_with_rosbags(Path(started.message)).values()
              for t_ns, _ in msgs]
    assert len(stamps) >= len(burst.sent['/PSM1/measured_js'])
    # the newest clock DDS held at the start stamps the first message: no wall time, no 0
    assert sim_start - 1.0 < min(stamps) and max(stamps) <= sim_stop + 1e-6, \
        (min(stamps), max(stamps), sim_start, sim_stop)
    assert proc.running(), proc.log()
