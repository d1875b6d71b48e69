"""Bags: written, read back by rosbags and by mcap independently, recovered, refused."""

import json
from pathlib import Path
import shutil
import subprocess
import sys

from harness import REPO
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from sim_bridge.common import cdr
from suture_lfd import bags

JOINT_STATE = 'sensor_msgs/msg/JointState'
POSE = 'geometry_msgs/msg/PoseStamped'
OPSTATE = 'crtk_msgs/msg/OperatingState'
EVENT = 'crtk_msgs/msg/StringStamped'
TF = 'tf2_msgs/msg/TFMessage'


@pytest.fixture(scope='module')
def store():
    return bags.make_typestore()


def header(store, t_ns, frame):
    Time, Header = store.types['builtin_interfaces/msg/Time'], store.types['std_msgs/msg/Header']
    return Header(stamp=Time(sec=int(t_ns // 10**9), nanosec=int(t_ns % 10**9)), frame_id=frame)


def make_message(store, msgtype, t_ns, rng):
    """A message of ``msgtype`` with random content, stamped ``t_ns``."""
    T = store.types
    if msgtype == JOINT_STATE:
        return T[JOINT_STATE](header=header(store, t_ns, ''), name=[f'j{i}' for i in range(6)],
                              position=rng.normal(size=6), velocity=rng.normal(size=6),
                              effort=np.zeros(0))
    if msgtype == POSE:
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        return T[POSE](header=header(store, t_ns, 'PSM1_base'), pose=T['geometry_msgs/msg/Pose'](
            position=T['geometry_msgs/msg/Point'](*rng.normal(size=3)),
            orientation=T['geometry_msgs/msg/Quaternion'](*q)))
    if msgtype == OPSTATE:
        return T[OPSTATE](header=header(store, t_ns, ''),
                          state=str(rng.choice(['DISABLED', 'ENABLED', 'PAUSED'])),
                          is_homed=bool(rng.integers(2)), is_busy=bool(rng.integers(2)))
    if msgtype == EVENT:
        return T[EVENT](header=header(store, t_ns, 'world'),
                        string=json.dumps({'kind': 'entry', 'point': rng.normal(size=3).tolist()}))
    if msgtype == TF:
        tf = T['geometry_msgs/msg/TransformStamped'](
            header=header(store, t_ns, 'world'), child_frame_id='PSM1_base',
            transform=T['geometry_msgs/msg/Transform'](
                translation=T['geometry_msgs/msg/Vector3'](*rng.normal(size=3)),
                rotation=T['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 1.0)))
        return T[TF](transforms=[tf])
    raise AssertionError(msgtype)


TOPICS = {'/PSM1/measured_js': JOINT_STATE, '/PSM1/measured_cp': POSE,
          '/PSM2/measured_js': JOINT_STATE, '/sim/needle/measured_cp': POSE,
          '/PSM1/operating_state': OPSTATE, '/sim/events': EVENT, '/tf_static': TF}
LATCHED = {'/PSM1/operating_state', '/sim/events', '/tf_static'}


def write_bag(path, store, rng, n_ticks=300, chunk_bytes=bags.CHUNK_BYTES):
    """Write ``n_ticks`` ticks at 100 Hz on TOPICS; return the expected (topic, t, raw) list."""
    written = []
    with bags.BagWriter(path, typestore=store, chunk_bytes=chunk_bytes) as writer:
        for topic, msgtype in TOPICS.items():
            writer.add_topic(topic, msgtype, qos=[bags.make_qos(
                transient_local=topic in LATCHED, depth=1000 if topic in LATCHED else 100)])
        for tick in range(n_ticks):
            t_ns = 1_700_000_000 * 10**9 + tick * 10_000_000 + int(rng.integers(0, 1000))
            for topic, msgtype in TOPICS.items():
                if topic in LATCHED and tick % 25:
                    continue
                raw = bytes(store.serialize_cdr(make_message(store, msgtype, t_ns, rng), msgtype))
                writer.write(topic, t_ns, raw)
                written.append((topic, t_ns, raw))
    return written


def same_message(a, b):
    """Field-by-field equality of two rosbags messages (arrays compared by value)."""
    if hasattr(a, '__dataclass_fields__'):
        return type(a).__name__ == type(b).__name__ and all(
            same_message(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same_message(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return a == b


def test_own_interface_types_hash_like_the_compiled_packages(store):
    for msgtype in (OPSTATE, EVENT):
        pkg, _, name = msgtype.partition('/msg/')
        description = Path(sys.prefix) / 'share' / pkg / 'msg' / f'{name}.json'
        compiled = json.loads(description.read_text())['type_hashes'][0]
        assert compiled['type_name'] == msgtype
        assert store.hash_rihs01(msgtype) == compiled['hash_string']
    assert set(bags.interface_definitions()) >= {OPSTATE, EVENT, TF}


def test_written_bag_reads_back_identically_with_rosbags_and_mcap(tmp_path, store):
    rng = np.random.default_rng(1)
    written = write_bag(tmp_path / 'demo', store, rng)
    by_topic = {t: [(ts, raw) for tp, ts, raw in written if tp == t] for t in TOPICS}

    meta = (tmp_path / 'demo' / 'metadata.yaml').read_text()
    assert 'version: 9' in meta and 'storage_identifier: mcap' in meta

    # rosbags, straight from its Reader
    got = {t: [] for t in TOPICS}
    with Reader(tmp_path / 'demo') as reader:
        assert reader.message_count == len(written)
        for conn, ts, raw in reader.messages():
            assert conn.msgtype == TOPICS[conn.topic]
            got[conn.topic].append((ts, bytes(raw)))
    assert got == by_topic

    # mcap + mcap_ros2: decode from the schemas embedded in the file
    decoded = {t: [] for t in TOPICS}
    with open(tmp_path / 'demo' / 'demo.mcap', 'rb') as f:
        mcap = make_reader(f, decoder_factories=[DecoderFactory()])
        assert mcap.get_header().profile == 'ros2'
        for schema, channel, message, ros in mcap.iter_decoded_messages(log_time_order=False):
            assert schema.name == TOPICS[channel.topic] and schema.encoding == 'ros2msg'
            decoded[channel.topic].append((message.log_time, ros))
    for topic, msgtype in TOPICS.items():
        assert [ts for ts, _ in decoded[topic]] == [ts for ts, _ in by_topic[topic]]
        for (_, ros), (_, raw) in zip(decoded[topic], by_topic[topic]):
            ours = store.deserialize_cdr(raw, msgtype)
            if msgtype == JOINT_STATE:
                assert list(ros.position) == list(ours.position)
            elif msgtype == POSE:
                assert ros.pose.orientation.w == ours.pose.orientation.w
            elif msgtype == OPSTATE:
                assert (ros.state, ros.is_homed) == (ours.state, ours.is_homed)
            elif msgtype == EVENT:
                assert ros.string == ours.string
            else:
                assert ros.transforms[0].child_frame_id == 'PSM1_base'


def test_open_bag_yields_every_message_in_time_order_and_decodes_it(tmp_path, store):
    rng = np.random.default_rng(2)
    written = write_bag(tmp_path / 'demo', store, rng, n_ticks=120)
    with bags.open_bag(tmp_path / 'demo', required=['/PSM1/measured_js']) as reader:
        messages = list(reader)
        assert len(messages) == len(written)
        assert [m.t_ns for m in messages] == sorted(m.t_ns for m in messages)
        for topic in TOPICS:
            mine = [m for m in messages if m.topic == topic]
            theirs = [(ts, raw) for tp, ts, raw in written if tp == topic]
            assert [(m.t_ns, bytes(m.rawdata)) for m in mine] == theirs
            first = reader.deserialize(mine[0])
            assert same_message(first, store.deserialize_cdr(theirs[0][1], TOPICS[topic]))
        assert reader.topics['/sim/events'].qos[0].durability.name == 'TRANSIENT_LOCAL'
        only = list(reader.messages(['/sim/events']))
        assert {m.topic for m in only} == {'/sim/events'}


def test_summary_gives_topics_types_counts_and_duration(tmp_path, store):
    rng = np.random.default_rng(3)
    written = write_bag(tmp_path / 'demo', store, rng, n_ticks=50)
    summary = bags.bag_summary(tmp_path / 'demo')
    assert summary.message_count == len(written)
    assert {t: s.msgtype for t, s in summary.topics.items()} == TOPICS
    for topic in TOPICS:
        assert summary.topics[topic].count == sum(1 for tp, _, _ in written if tp == topic)
    times = [ts for _, ts, _ in written]
    assert (summary.start_ns, summary.end_ns) == (min(times), max(times))
    assert summary.duration_s == pytest.approx((max(times) - min(times)) * 1e-9)
    text = bags.format_summary(summary)
    assert '/PSM1/operating_state' in text and OPSTATE in text and 'transient_local' in text


def messages_per_chunk(mcap_path):
    """[(chunk end offset, [(channel topic, log_time)...]), ...] in file order."""
    chunks, topics = [], {}
    with open(mcap_path, 'rb') as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Chunk):
                inner = breakup_chunk(record)
                for r in inner:
                    if isinstance(r, Channel):
                        topics[r.id] = r.topic
                chunks.append((f.tell(), [(topics[r.channel_id], r.log_time) for r in inner
                                          if isinstance(r, Message)]))
    return chunks


def test_truncated_recording_is_recovered_up_to_its_last_complete_chunk(tmp_path, store):
    rng = np.random.default_rng(4)
    written = write_bag(tmp_path / 'demo', store, rng, n_ticks=400, chunk_bytes=16 * 1024)
    source = tmp_path / 'demo' / 'demo.mcap'
    chunks = messages_per_chunk(source)
    assert len(chunks) > 10
    data = source.read_bytes()
    for case, cut in enumerate(sorted(rng.integers(chunks[0][0] + 1, len(data), 12))):
        killed = tmp_path / f'killed{case}'
        killed.mkdir()
        (killed / f'killed{case}.mcap').write_bytes(data[:cut])
        # the unfinished bag is refused with a pointer to the recovery command
        with pytest.raises(bags.BagError, match='metadata.yaml is missing.*bag recover'):
            bags.open_bag(killed)
        summary = bags.recover_bag(killed)
        expected = [m for end, msgs in chunks if end <= cut for m in msgs]
        assert summary.path == tmp_path / f'killed{case}-recovered'
        assert summary.message_count == len(expected) > 0
        with bags.open_bag(summary.path) as reader:
            got = [(m.topic, m.t_ns, bytes(m.rawdata)) for m in reader]
        # exactly the written messages of the complete chunks, per topic in order
        for topic in TOPICS:
            want = [(tp, ts) for tp, ts in expected if tp == topic]
            have = [(tp, ts) for tp, ts, _ in got if tp == topic]
            assert have == want
            raws = [raw for tp, _, raw in written if tp == topic][:len(want)]
            assert [raw for tp, _, raw in got if tp == topic] == raws
        assert summary.topics['/sim/events'].qos[0].durability.name == 'TRANSIENT_LOCAL'


def test_recover_refuses_to_overwrite_and_reports_unrecoverable_files(tmp_path, store):
    rng = np.random.default_rng(5)
    write_bag(tmp_path / 'demo', store, rng, n_ticks=20)
    with pytest.raises(bags.BagError, match='exists already'):
        bags.recover_bag(tmp_path / 'demo', tmp_path / 'demo')
    junk = tmp_path / 'junk'
    junk.mkdir()
    (junk / 'junk.mcap').write_bytes(b'not an mcap file at all' * 10)
    with pytest.raises(bags.BagError, match=r'junk.*nothing to recover.*invalid magic'):
        bags.recover_bag(junk)
    assert not (tmp_path / 'junk-recovered').exists()
    empty = tmp_path / 'empty'
    empty.mkdir()
    with pytest.raises(bags.BagError, match=r'empty: no \.mcap file'):
        bags.recover_bag(empty)


@pytest.mark.parametrize('damage', ['no-metadata', 'truncated', 'garbage', 'bad-metadata',
                                    'no-storage-file', 'not-a-directory'])
def test_damaged_bag_raises_bag_error_naming_the_file(tmp_path, store, damage):
    rng = np.random.default_rng(6)
    write_bag(tmp_path / 'demo', store, rng, n_ticks=60)
    bag = tmp_path / 'demo'
    mcap, meta = bag / 'demo.mcap', bag / 'metadata.yaml'
    named = {'no-metadata': meta, 'truncated': mcap, 'garbage': mcap, 'bad-metadata': meta,
             'no-storage-file': mcap, 'not-a-directory': mcap}[damage]
    if damage == 'no-metadata':
        meta.unlink()
    elif damage == 'truncated':
        mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    elif damage == 'garbage':
        mcap.write_bytes(bytes(rng.integers(0, 256, 5000, dtype=np.uint8)))
    elif damage == 'bad-metadata':
        meta.write_text('rosbag2_bagfile_information: [this is not, a bag]\n')
    elif damage == 'no-storage-file':
        mcap.unlink()
    else:
        bag = mcap
    with pytest.raises(bags.BagError) as err:
        bags.open_bag(bag)
    assert isinstance(err.value, ValueError)
    assert str(named) in str(err.value)


def test_bag_without_the_needed_topics_is_refused(tmp_path, store):
    write_bag(tmp_path / 'demo', store, np.random.default_rng(7), n_ticks=10)
    with pytest.raises(bags.BagError, match=r'demo: bag has no messages on /PSM2/measured_cp'):
        bags.open_bag(tmp_path / 'demo', required=['/PSM1/measured_js', '/PSM2/measured_cp'])


def test_writer_never_overwrites_and_checks_its_topics(tmp_path, store):
    write_bag(tmp_path / 'demo', store, np.random.default_rng(8), n_ticks=5)
    with pytest.raises(bags.BagError, match='exists already'):
        bags.BagWriter(tmp_path / 'demo', typestore=store)
    with bags.BagWriter(tmp_path / 'other', typestore=store) as writer:
        with pytest.raises(bags.BagError, match='add_topic first'):
            writer.write('/nowhere', 0, b'\0\1\0\0')
        writer.add_topic('/a', JOINT_STATE)
        with pytest.raises(bags.BagError, match='/a is recorded as sensor_msgs/msg/JointState'):
            writer.add_topic('/a', POSE)
        with pytest.raises(bags.BagError, match="'nope_msgs/msg/Thing' is unknown"):
            writer.add_topic('/b', 'nope_msgs/msg/Thing')


def test_bag_commands_inspect_and_recover(tmp_path, store):
    write_bag(tmp_path / 'demo', store, np.random.default_rng(9), n_ticks=200,
              chunk_bytes=16 * 1024)
    cli = Path(sys.executable).parent / 'suture-lfd'
    info = subprocess.run([cli, 'bag', 'info', tmp_path / 'demo'], capture_output=True,
                          text=True, check=True)
    assert '/PSM1/measured_js' in info.stdout and 'duration  1.99' in info.stdout
    killed = tmp_path / 'killed'
    shutil.copytree(tmp_path / 'demo', killed)
    (killed / 'metadata.yaml').unlink()
    (killed / 'demo.mcap').write_bytes((tmp_path / 'demo' / 'demo.mcap').read_bytes()[:60000])
    bad = subprocess.run([cli, 'bag', 'info', killed], capture_output=True, text=True)
    assert bad.returncode == 1 and 'metadata.yaml is missing' in bad.stderr
    out = tmp_path / 'fixed'
    result = subprocess.run([cli, 'bag', 'recover', killed, '--out', out], capture_output=True,
                            text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert 'truncated' in result.stderr and str(out) in result.stdout
    with Reader(out) as reader:
        recovered = reader.message_count
    assert 0 < recovered < bags.bag_summary(tmp_path / 'demo').message_count


@pytest.mark.parametrize('frame', ['', 'w', 'world', 'PSM1_base', 'abcdefg', 'abcdefgh'])
def test_lean_pose_stamped_cdr_is_what_ros_serialises_and_reads_back(store, frame):
    from geometry_msgs.msg import PoseStamped
    from rclpy.serialization import deserialize_message, serialize_message

    rng = np.random.default_rng(len(frame))
    for t in (0.0, 1.23456789, 1_750_000_000.005, 12.999999999):
        pose = rng.normal(size=7)
        raw = bags.pose_stamped_cdr(t, frame, pose)
        msg = deserialize_message(raw, PoseStamped)
        assert msg.header.frame_id == frame
        assert msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 == pytest.approx(t, abs=1e-9)
        p, q = msg.pose.position, msg.pose.orientation
        assert [p.x, p.y, p.z, q.x, q.y, q.z, q.w] == pose.tolist()
        stamp, got_frame, got = cdr.pose_stamped_fields(raw)
        assert got_frame == frame and list(got) == pose.tolist()
        assert stamp == msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        assert raw == bytes(store.serialize_cdr(store.deserialize_cdr(raw, POSE), POSE))
        # ROS's own bytes (its padding is not zeroed) read the same
        assert cdr.pose_stamped_fields(serialize_message(msg)) == (stamp, got_frame, got)


@pytest.mark.parametrize('names', [['jaw'], ['a', 'bc', 'def'], []])
def test_lean_joint_state_cdr_is_what_ros_serialises_and_reads_back(store, names):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    position = np.arange(len(names)) * 0.5 + 0.25
    raw = bags.joint_state_cdr(3.14159, names, position)
    msg = deserialize_message(raw, JointState)
    assert list(msg.name) == names and list(msg.position) == position.tolist()
    assert list(msg.velocity) == [] and list(msg.effort) == []
    assert raw == bytes(store.serialize_cdr(store.deserialize_cdr(raw, JOINT_STATE), JOINT_STATE))
    got = cdr.joint_state_first_position(raw)
    assert got == (None if not names else (pytest.approx(3.14159, abs=1e-9), position[0]))
    assert cdr.joint_state_first_position(serialize_message(msg)) == got


def test_lean_readers_leave_what_they_cannot_read_to_the_full_decoder():
    from geometry_msgs.msg import PoseStamped
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    pose = bags.pose_stamped_cdr(1.0, 'world', [0.0] * 7)
    big_endian = b'\x00\x00' + pose[2:]
    assert cdr.pose_stamped_fields(big_endian) is None
    assert cdr.pose_stamped_fields(pose[:-8]) is None            # truncated
    assert cdr.pose_stamped_fields(b'') is None
    velocity_only = JointState(name=['jaw'], velocity=[1.0])
    assert cdr.joint_state_first_position(serialize_message(velocity_only)) is None
    assert cdr.joint_state_first_position(serialize_message(PoseStamped())) is None
