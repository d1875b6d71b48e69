"""
Demonstration bags: the simulator topics a recorder keeps for one throw, written and read back.

A demonstration bag is a rosbag2 directory (:mod:`suture_lfd.bags`) holding, among whatever
else the recorder took, the topics of :data:`DEMO_TOPICS` (the simulator's topic contract, node
namespace ``/``):

- ``/PSM1/measured_cp``, ``/PSM2/measured_cp`` (geometry_msgs/PoseStamped): tool tip in the
  arm's base frame (frame_id ``<ARM>_base``, the dVRK default) or in ``world``; in the camera
  frame ``ECM`` of a patient cart, ``/PSM1/local/measured_cp`` and ``/PSM2/local/measured_cp``
  (in ``<ARM>_base``, recorded beside them) are read instead;
- ``/sim/PSM1/base_frame``, ``/sim/PSM2/base_frame`` (PoseStamped, latched): ``T_world_base``;
- ``/PSM1/jaw/measured_js``, ``/PSM2/jaw/measured_js`` (sensor_msgs/JointState): jaw angle;
- ``/sim/needle/measured_cp`` (PoseStamped, ``world``): needle pose;
- ``/sim/markers/<pair>/entry`` and ``.../exit`` (PoseStamped, ``world``, latched): marker
  centres, ``z`` axis the outward surface normal;
- ``/sim/events`` (crtk_msgs/StringStamped, JSON ``{"kind", "t", ...}``, stamped on the
  clock of the other topics): ``grasp`` and ``release`` (with ``arm``) give who holds the
  needle, ``reset`` clears it; ``target_pair`` (with ``pair``) names the pair;
- ``/sim/target_pair`` (std_msgs/String): the pair chosen for the throw.

:func:`write_demonstration_bag` writes a :class:`suture_lfd.demos.demonstration.Demonstration` as
the recorder would have recorded it from the simulator; :func:`demonstration_from_bag` reads any
such bag (written here or by the recorder node) back into a Demonstration, on the time axis of
the message header stamps (simulation time), resampled to a common rate.

Frames: ``world`` unless a frame_id says otherwise; m, rad, s; quaternions (x, y, z, w).
"""

from collections.abc import Callable, Iterable, Mapping, Sequence
import json
import math
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common import cdr
from sim_bridge.common.geometry import (
    pose_from_transform,
    transform_from_pose,
)
from sim_bridge.common.validation import FloatArray
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.scene.markers import marker_frame
from suture_lfd import bags
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.demos.resampling import resample_quaternions

POSE = 'geometry_msgs/msg/PoseStamped'
JOINTS = 'sensor_msgs/msg/JointState'
EVENTS = 'crtk_msgs/msg/StringStamped'
STRING = 'std_msgs/msg/String'

#: Topics of a demonstration bag (besides the marker topics of its pairs) and their types.
DEMO_TOPICS = {
    '/PSM1/measured_cp': POSE,
    '/PSM2/measured_cp': POSE,
    '/PSM1/jaw/measured_js': JOINTS,
    '/PSM2/jaw/measured_js': JOINTS,
    '/sim/PSM1/base_frame': POSE,
    '/sim/PSM2/base_frame': POSE,
    '/sim/needle/measured_cp': POSE,
    '/sim/events': EVENTS,
    '/sim/target_pair': STRING,
}
#: Topics a bag must hold for :func:`demonstration_from_bag`.
REQUIRED_TOPICS = ('/PSM1/measured_cp', '/PSM2/measured_cp', '/PSM1/jaw/measured_js',
                   '/PSM2/jaw/measured_js', '/sim/PSM1/base_frame', '/sim/PSM2/base_frame',
                   '/sim/needle/measured_cp')
MARKER_TOPIC = '/sim/markers/{pair}/{which}'
_LATCHED = bags.make_qos(transient_local=True, depth=1)
_EVENT_QOS = bags.make_qos(transient_local=True, depth=1000)
_STATE_QOS = bags.make_qos(depth=100)


def marker_topics(pair: str) -> tuple[str, str]:
    """Return the entry and exit marker topics of a pair (absolute names)."""
    return (MARKER_TOPIC.format(pair=pair, which='entry'),
            MARKER_TOPIC.format(pair=pair, which='exit'))


# --- messages (rosbags objects) <-> arrays ---------------------------------------------------

def _stamp(store: Any, t: float) -> Any:
    ns = int(round(float(t) * 1e9))
    return store.types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)


def _header(store: Any, t: float, frame_id: str = '') -> Any:
    return store.types['std_msgs/msg/Header'](stamp=_stamp(store, t), frame_id=frame_id)


def _pose_stamped(store: Any, pose: ArrayLike, frame_id: str, t: float) -> Any:
    """PoseStamped of a 7-vector pose ``(x, y, z, qx, qy, qz, qw)`` or a 4x4 matrix."""
    vector = np.asarray(pose, dtype=float)
    if vector.shape == (4, 4):
        vector = pose_from_transform(vector)
    x, y, z, qx, qy, qz, qw = (float(v) for v in vector)
    ty = store.types
    msg = ty['geometry_msgs/msg/Pose'](
        position=ty['geometry_msgs/msg/Point'](x=x, y=y, z=z),
        orientation=ty['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw))
    return ty[POSE](header=_header(store, t, frame_id), pose=msg)


def _joint_state(store: Any, names: Iterable[str], position: ArrayLike, t: float) -> Any:
    return store.types[JOINTS](header=_header(store, t), name=list(names),
                               position=np.asarray(position, dtype=np.float64),
                               velocity=np.zeros(0), effort=np.zeros(0))


def _event(store: Any, t: float, kind: str, **data: Any) -> Any:
    text = json.dumps({'kind': kind, 't': float(t), **data}, sort_keys=True)
    return store.types[EVENTS](header=_header(store, t), string=text)


def _seconds(stamp: Any) -> float:
    return float(stamp.sec + stamp.nanosec * 1e-9)


def _pose_vector(msg: Any) -> FloatArray:
    p, q = msg.pose.position, msg.pose.orientation
    return np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=float)


# --- writing ---------------------------------------------------------------------------------

def default_base_frames() -> dict[str, FloatArray]:
    """Return ``T_world_base`` of PSM1 and PSM2 from ``config/world.yaml`` (4x4 each)."""
    from sim_bridge.scene.world import read_world_config
    world = read_world_config()
    return {arm: np.array(world.arms[arm].T, dtype=float) for arm in PSMS}


def write_demonstration_bag(path: str | Path, demo: Demonstration, *,
                            base_frames: Mapping[str, ArrayLike] | None = None,
                            measured_frame: str = 'base',
                            other_pairs: Mapping[str, tuple[ArrayLike, ArrayLike, ArrayLike]]
                            | None = None, typestore: Any = None) -> dict[str, int]:
    """
    Write a demonstration as the recorder records it from the simulator.

    Parameters
    ----------
    path : str or Path
        Bag directory to create (must not exist).
    demo : suture_lfd.demos.demonstration.Demonstration
        The record (world frame).
    base_frames : dict of str to array_like (4, 4), optional
        ``T_world_base`` of PSM1 and PSM2; default :func:`default_base_frames`.
    measured_frame : {'base', 'world'}
        Frame of ``measured_cp``: ``<ARM>_base`` (dVRK default) or ``world``.
    other_pairs : dict, optional
        More marker pairs to publish, ``name -> (entry (3,), exit (3,), normal (3,))``.
    typestore : rosbags typestore, optional
        Default :func:`suture_lfd.bags.make_typestore`.

    Returns
    -------
    dict of str to int
        Messages written per topic.

    """
    if not isinstance(demo, Demonstration):
        raise ValueError(f'demo must be a Demonstration, got {type(demo).__name__}')
    if measured_frame not in ('base', 'world'):
        raise ValueError(f"measured_frame must be 'base' or 'world', got {measured_frame!r}")
    if not demo.pair:
        raise ValueError('the demonstration has no pair name; a bag names its marker topics '
                         'after the pair')
    store = typestore if typestore is not None else bags.make_typestore()
    frames = default_base_frames() if base_frames is None else {
        arm: np.asarray(base_frames[arm], dtype=float) for arm in PSMS}
    pairs: dict[str, tuple[ArrayLike, ArrayLike, ArrayLike]] = {
        demo.pair: (demo.entry, demo.exit, demo.normal)}
    pairs.update(other_pairs or {})
    t = demo.t
    t0 = float(t[0])
    messages: list[tuple[float, str, Any]] = []   # (t, topic, message object or CDR bytes)

    def put(time: float, topic: str, msg: Any) -> None:
        messages.append((float(time), topic, msg))

    for arm in PSMS:
        put(t0, f'/sim/{arm}/base_frame', _pose_stamped(store, frames[arm], 'world', t0))
    for name, points in pairs.items():
        entry, exit_, normal = (np.asarray(v, dtype=float) for v in points)
        topic_in, topic_out = marker_topics(name)
        put(t0, topic_in, _pose_stamped(store, marker_frame(entry, normal, exit_), 'world', t0))
        put(t0, topic_out, _pose_stamped(store, marker_frame(exit_, normal, entry), 'world',
                                         t0))
    put(t0, '/sim/target_pair', store.types[STRING](data=demo.pair))
    put(t0, '/sim/events', _event(store, t0, 'target_pair', pair=demo.pair))
    poses = {'PSM1': demo.psm1_pose, 'PSM2': demo.psm2_pose}
    if measured_frame == 'base':
        poses = {arm: pose_from_transform(np.einsum(
            'ij,njk->nik', np.linalg.inv(frames[arm]), transform_from_pose(poses[arm])))
            for arm in PSMS}
    jaws = {'PSM1': demo.psm1_jaw, 'PSM2': demo.psm2_jaw}
    holds = {'PSM1': demo.psm1_holds, 'PSM2': demo.psm2_holds}
    needle = demo.needle_pose
    # the per-sample messages go straight to CDR bytes (bags.pose_stamped_cdr, the same bytes
    # as serialising a message object, several times faster)
    frames_of = {arm: 'world' if measured_frame == 'world' else f'{arm}_base' for arm in PSMS}
    rows = {arm: poses[arm].tolist() for arm in PSMS}
    jaw_rows = {arm: np.asarray(jaws[arm], dtype=float).tolist() for arm in PSMS}
    needle_rows = np.asarray(needle, dtype=float).tolist()
    for k, tk in enumerate(t.tolist()):
        for arm in PSMS:
            put(tk, f'/{arm}/measured_cp', bags.pose_stamped_cdr(tk, frames_of[arm], rows[arm][k]))
            put(tk, f'/{arm}/jaw/measured_js', bags.joint_state_cdr(tk, ('jaw',),
                                                                    (jaw_rows[arm][k],)))
            if holds[arm][k] != (holds[arm][k - 1] if k else False):
                kind = 'grasp' if holds[arm][k] else 'release'
                put(tk, '/sim/events', _event(store, tk, kind, arm=arm))
        put(tk, '/sim/needle/measured_cp', bags.pose_stamped_cdr(tk, 'world', needle_rows[k]))
    messages.sort(key=lambda m: m[0])   # stable: keeps the order within one instant
    qos = {topic: [_LATCHED] for topic in messages_topics(messages)
           if topic.startswith('/sim/markers/') or topic.endswith('/base_frame')}
    qos['/sim/events'] = [_EVENT_QOS]
    with bags.BagWriter(path, typestore=store) as writer:
        for time, topic, msg in messages:
            msgtype = DEMO_TOPICS.get(topic, POSE)
            if not writer.has_topic(topic):
                writer.add_topic(topic, msgtype, qos=qos.get(topic, [_STATE_QOS]))
            raw = msg if isinstance(msg, bytes) else cast(bytes,
                                                          store.serialize_cdr(msg, msgtype))
            writer.write(topic, int(round(time * 1e9)), raw)
        writer.set_custom_data('suture_lfd.demonstration', demo.pair)
        return dict(writer.counts)


def messages_topics(messages: Iterable[tuple[float, str, Any]]) -> list[str]:
    """Return the distinct topics of ``(t, topic, msg)`` tuples, in first-seen order."""
    return list(dict.fromkeys(topic for _, topic, _ in messages))


# --- reading ---------------------------------------------------------------------------------

def _series(reader: Any, messages: Iterable[Any], decode: Callable[[Any], Any],
            fast: Callable[[bytes], tuple[float, Any] | None] | None = None
            ) -> tuple[FloatArray, list[Any]]:
    """
    Return (stamps (n,), values list) of one topic's messages, by header stamp, sorted.

    ``fast(raw) -> (stamp, value) or None`` reads a message's bytes directly; a message it
    cannot read is decoded into a message object and given to ``decode``.
    """
    times: list[float] = []
    values: list[Any] = []
    for message in messages:
        got = fast(message.rawdata) if fast is not None else None
        if got is None:
            msg = reader.deserialize(message)
            stamp = _seconds(msg.header.stamp) if hasattr(msg, 'header') else message.t_ns * 1e-9
            got = stamp, decode(msg)
        times.append(got[0])
        values.append(got[1])
    order = np.argsort(np.asarray(times), kind='stable')
    return np.asarray(times)[order], [values[i] for i in order]


def _fast_pose(raw: bytes) -> tuple[float, tuple[str, FloatArray]] | None:
    got = cdr.pose_stamped_fields(raw)
    return None if got is None else (got[0], (got[1], np.array(got[2])))


def _fast_pose_matrix(raw: bytes) -> tuple[float, FloatArray] | None:
    got = cdr.pose_stamped_fields(raw)
    return None if got is None else (got[0], transform_from_pose(np.array(got[2])))


def _fast_pose_vector(raw: bytes) -> tuple[float, FloatArray] | None:
    got = cdr.pose_stamped_fields(raw)
    return None if got is None else (got[0], np.array(got[2]))


def _unique(times: FloatArray, values: Sequence[Any] | FloatArray, path: Path, topic: str
            ) -> tuple[FloatArray, FloatArray]:
    keep = np.concatenate(([True], np.diff(times) > 0.0))
    kept = np.asarray(values)[keep]
    if times[keep].size < 2:
        raise bags.BagError(f'{path}: topic {topic} has fewer than two distinct time stamps')
    return times[keep], kept


def _world_poses(frames: Sequence[str], poses: ArrayLike, arm: str, T_world_base: FloatArray,
                 path: Path) -> FloatArray:
    """World 7-vector poses of ``measured_cp`` samples given in ``frames`` (n,)."""
    world = np.asarray(poses, dtype=float)
    unknown = sorted(set(frames) - {'world', '', f'{arm}_base'})
    if unknown:
        raise bags.BagError(f'{path}: /{arm}/measured_cp is in frame {unknown[0]!r}; expected '
                            f'{arm}_base or world')
    in_base = np.array([f != 'world' for f in frames])
    if in_base.any():
        T = np.einsum('ij,njk->nik', T_world_base, transform_from_pose(world[in_base]))
        world = world.copy()
        world[in_base] = pose_from_transform(T)
    return world


def _pose_topic(reader: Any, by_topic: Mapping[str, list[Any]], arm: str) -> str:
    """
    Return the topic an arm's tool poses are read from: ``measured_cp`` or its local one.

    A patient cart reports ``measured_cp`` in the moving camera frame ``ECM``; its
    ``local/measured_cp`` (in ``<ARM>_base``, recorded beside it) is then read instead.
    """
    topic, local = f'/{arm}/measured_cp', f'/{arm}/local/measured_cp'
    messages = by_topic[topic]
    if messages and by_topic.get(local):
        frame = reader.deserialize(messages[0]).header.frame_id
        if frame not in ('world', '', f'{arm}_base'):
            return local
    return topic


def _events(reader: Any) -> list[tuple[float, dict[str, Any]]]:
    out: list[tuple[float, dict[str, Any]]] = []
    if '/sim/events' not in reader.topics:
        return out
    for message in reader.messages(['/sim/events']):
        msg = reader.deserialize(message)
        try:
            data = json.loads(msg.string)
        except json.JSONDecodeError as exc:
            raise bags.BagError(f'{reader.path}: a /sim/events message is not JSON '
                                f'({exc})') from exc
        if not isinstance(data, dict) or 'kind' not in data:
            continue
        # the header stamp is on the clock of the other topics; "t" counts from the scene start
        t = _seconds(msg.header.stamp)
        if t == 0.0 and isinstance(data.get('t'), (int, float)):
            t = float(data['t'])
        out.append((t, data))
    out.sort(key=lambda e: e[0])
    return out


def _pair_name(reader: Any, events: Sequence[tuple[float, dict[str, Any]]], path: Path) -> str:
    names: list[str] = []
    if '/sim/target_pair' in reader.topics:
        for message in reader.messages(['/sim/target_pair']):
            names.append(reader.deserialize(message).data)
    names += [d['pair'] for _, d in events if d['kind'] == 'target_pair' and 'pair' in d]
    if names:
        return str(names[-1])
    pairs = sorted({t.split('/')[3] for t in reader.topics if t.startswith('/sim/markers/')})
    if len(pairs) == 1:
        return str(pairs[0])
    raise bags.BagError(f'{path}: the bag does not say which pair was sutured (no '
                        f'/sim/target_pair message or target_pair event); pass pair= one of '
                        f'{pairs}')


def demonstration_from_bag(path: str | Path, pair: str | None = None,
                           sample_rate: float = 100.0) -> Demonstration:
    """
    Read a demonstration bag into a Demonstration (world frame).

    The arm, jaw and needle topics are resampled (linear positions and angles, SLERP
    orientations) to ``sample_rate`` over the span all of them cover, on their header stamps
    (simulation time). Grasp flags come from the ``grasp``/``release`` events of
    ``/sim/events`` (nobody holds the needle before the first event).

    Parameters
    ----------
    path : str or Path
        Bag directory.
    pair : str, optional
        Sutured pair; default the bag's last ``/sim/target_pair`` (or ``target_pair`` event).
    sample_rate : float
        Samples per second of the result.

    Returns
    -------
    suture_lfd.demos.demonstration.Demonstration

    Raises
    ------
    suture_lfd.bags.BagError
        Naming the bag and the missing topic or the problem.

    """
    path = Path(path)
    if not sample_rate > 0.0:
        raise ValueError(f'sample_rate must be > 0 Hz, got {sample_rate}')
    with bags.open_bag(path, required=REQUIRED_TOPICS) as reader:
        events = _events(reader)
        name = pair if pair is not None else _pair_name(reader, events, path)
        topic_in, topic_out = marker_topics(name)
        missing = [t for t in (topic_in, topic_out)
                   if t not in reader.topics or reader.topics[t].count == 0]
        if missing:
            have = sorted({t.split('/')[3] for t in reader.topics
                           if t.startswith('/sim/markers/')})
            raise bags.BagError(f'{path}: bag has no messages on {", ".join(missing)} (marker '
                                f'pair {name!r}; pairs in the bag: {have})')
        # one pass over the bag, then each topic from its own list
        wanted = [topic_in, topic_out, '/sim/needle/measured_cp']
        for arm in PSMS:
            wanted += [f'/sim/{arm}/base_frame', f'/{arm}/measured_cp', f'/{arm}/jaw/measured_js']
            if f'/{arm}/local/measured_cp' in reader.topics:
                wanted.append(f'/{arm}/local/measured_cp')
        by_topic: dict[str, list[Any]] = {topic: [] for topic in wanted}
        for message in reader.messages(wanted):
            by_topic[message.topic].append(message)

        def matrix(m: Any) -> FloatArray:
            return transform_from_pose(_pose_vector(m))

        def lean(topic: str, msgtype: str, reader_of_bytes: Callable[[bytes], Any]
                 ) -> Callable[[bytes], Any] | None:
            # the byte readers know one layout each: other types take the full decoder
            info = reader.topics.get(topic)
            return reader_of_bytes if info is not None and info.msgtype == msgtype else None
        markers: dict[str, FloatArray] = {}
        for topic in (topic_in, topic_out):
            _, values = _series(reader, by_topic[topic], matrix,
                                lean(topic, POSE, _fast_pose_matrix))
            markers[topic] = values[-1]
        bases: dict[str, FloatArray] = {}
        for arm in PSMS:
            topic = f'/sim/{arm}/base_frame'
            _, values = _series(reader, by_topic[topic], matrix,
                                lean(topic, POSE, _fast_pose_matrix))
            bases[arm] = values[-1]
        series: dict[str, tuple[FloatArray, FloatArray]] = {}
        for arm in PSMS:
            topic = _pose_topic(reader, by_topic, arm)
            times, values = _series(reader, by_topic[topic],
                                    lambda m: (m.header.frame_id, _pose_vector(m)),
                                    lean(topic, POSE, _fast_pose))
            world = _world_poses([v[0] for v in values], [v[1] for v in values], arm,
                                 bases[arm], path) if values else np.zeros((0, 7))
            series[f'{arm}_pose'] = _unique(times, list(world), path, f'/{arm}/measured_cp')

            def jaw(m: Any, a: str = arm) -> float:
                if len(m.position) < 1:
                    raise bags.BagError(f'{path}: a /{a}/jaw/measured_js message has no '
                                        'position')
                return float(m.position[0])
            topic = f'/{arm}/jaw/measured_js'
            times, values = _series(reader, by_topic[topic], jaw,
                                    lean(topic, JOINTS, cdr.joint_state_first_position))
            series[f'{arm}_jaw'] = _unique(times, values, path, f'/{arm}/jaw/measured_js')
        topic = '/sim/needle/measured_cp'
        times, values = _series(reader, by_topic[topic], _pose_vector,
                                lean(topic, POSE, _fast_pose_vector))
        series['needle'] = _unique(times, values, path, '/sim/needle/measured_cp')
    start = max(s[0][0] for s in series.values())
    stop = min(s[0][-1] for s in series.values())
    if not stop > start:
        raise bags.BagError(f'{path}: the arm, jaw and needle topics do not overlap in time')
    n = int(math.floor((stop - start) * sample_rate + 1e-9)) + 1
    T = start + np.arange(n) / float(sample_rate)
    if n < 6:
        raise bags.BagError(f'{path}: only {n} samples of the demonstration overlap '
                            f'({stop - start:.3f} s)')

    def resampled_poses(key: str) -> FloatArray:
        times, values = series[key]
        P = np.column_stack([np.interp(T, times, values[:, k]) for k in range(3)])
        return np.hstack((P, resample_quaternions(times, values[:, 3:], T)))

    def resampled_signal(key: str) -> FloatArray:
        times, values = series[key]
        return np.interp(T, times, np.asarray(values, dtype=float))

    holds = {arm: np.zeros(n, dtype=bool) for arm in PSMS}
    for t_event, data in events:
        who = data.get('arm')
        if data['kind'] in ('grasp', 'release') and who in holds:
            holds[who][T >= t_event - 1e-9] = data['kind'] == 'grasp'
        elif data['kind'] == 'reset':
            for flags in holds.values():
                flags[T >= t_event - 1e-9] = False
    T_in, T_out = markers[topic_in], markers[topic_out]
    normal = T_in[:3, 2] + T_out[:3, 2]
    normal /= np.linalg.norm(normal)
    return Demonstration(
        t=T, psm1_pose=resampled_poses('PSM1_pose'), psm2_pose=resampled_poses('PSM2_pose'),
        psm1_jaw=resampled_signal('PSM1_jaw'), psm2_jaw=resampled_signal('PSM2_jaw'),
        needle_pose=resampled_poses('needle'),
        psm1_holds=holds['PSM1'], psm2_holds=holds['PSM2'], entry=T_in[:3, 3].copy(),
        exit=T_out[:3, 3].copy(), normal=normal, pair=name)
