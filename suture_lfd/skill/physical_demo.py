"""
Demonstrations recorded on what a physical dVRK provides: CRTK state and perception outputs.

A bag recorded in physical mode (a dVRK, or the simulator with ``physical:=true``) holds no
ground truth: no needle, markers, bases or scene events. It holds, from the recorder's topic
list (node namespace ``/``):

- ``/PSM1/local/measured_cp``, ``/PSM2/local/measured_cp`` (PoseStamped, ``<ARM>_base``) and
  ``/PSM1/jaw/measured_js``, ``/PSM2/jaw/measured_js``: the arms' own reports;
- ``/ECM/local/measured_cp`` (``ECM_base``): the endoscope's pose;
- ``/tf_static``: ``world -> <ARM>_base`` (the robot's registration) and
  ``ECM -> ECM_left_optical`` (the camera's calibration);
- ``/perception/needle/measured_cp`` (PoseStamped, left optical frame), ``/perception/needle/
  status`` (JSON with ``found`` and ``stamp``), ``/perception/markers/entries|exits``
  (PoseArray, pair ``i`` along the wound at index ``i``, ``z`` axis the plane normal);
- ``/sim/target_pair`` (std_msgs/String): the pair the operator named.

:func:`demonstration_from_physical_bag` replays the bag, in the order it was received, into
the executor's own :class:`suture_lfd.skill.perceived_feed.PerceptionFeed`: the markers and the
lying needle as perceived, each grasp measured when a jaw closes near the perceived needle, the
held needle where the holder's reported pose and that grasp put it. So the segmenter and the
learner see the needle as the robot perceived it. :func:`record_physical_demonstration` records
such a bag in-process from a scripted demonstration on a simulation (the recorder's view of the
simulator node in physical mode, perception run on rendered frames at ``perception_rate``).

The module sits beside the feed it replays into, in the skill package, which may import the
demonstrations (not the other way).

Frames: ``world`` as the robot believes it; m, rad, s; quaternions (x, y, z, w).
"""

from collections.abc import Sequence
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import (
    invert_transform,
    matrix_from_quaternion,
    pose_from_transform,
    transform_from_pose,
)
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.control import Command, Observation
from suture_lfd import bags
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.demos.resampling import resample_quaternions
from suture_lfd.demos.scripted_demo import PausingExpert
from suture_lfd.perception import StereoPerception, stereo_from_camera_info
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.skill.perceived_feed import (
    NeedleStatus,
    PerceptionFeed,
    normal_quaternion,
    pair_index_from_name,
)

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore
    from sim_bridge.scene.scoring import ThrowScore
    from sim_bridge.simulation import Simulation

POSE = 'geometry_msgs/msg/PoseStamped'
POSES = 'geometry_msgs/msg/PoseArray'
JOINTS = 'sensor_msgs/msg/JointState'
STRING = 'std_msgs/msg/String'
TF = 'tf2_msgs/msg/TFMessage'
NEEDLE = '/perception/needle/measured_cp'
STATUS = '/perception/needle/status'
ROWS = {'entries': '/perception/markers/entries', 'exits': '/perception/markers/exits'}
OPTICAL = 'ECM_left_optical'
#: Topics a physical-mode bag must hold for :func:`demonstration_from_physical_bag`.
REQUIRED_TOPICS = ('/PSM1/local/measured_cp', '/PSM2/local/measured_cp',
                   '/PSM1/jaw/measured_js', '/PSM2/jaw/measured_js', '/ECM/local/measured_cp',
                   '/tf_static', NEEDLE, STATUS, ROWS['entries'], ROWS['exits'])
_LATCHED = bags.make_qos(transient_local=True, depth=1)
_STATE_QOS = bags.make_qos(depth=100)


def is_physical_bag(topics: Any) -> bool:
    """Return True for a bag recorded in physical mode (perception outputs, no needle truth)."""
    return '/sim/needle/measured_cp' not in topics and NEEDLE in topics


def _seconds(stamp: Any) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _matrix(pose: Any) -> np.ndarray:
    p, o = pose.position, pose.orientation
    return transform_from_pose([p.x, p.y, p.z, o.x, o.y, o.z, o.w])


class _Replay:
    """The bag's messages, in the order they came, into the arms' state and a feed."""

    def __init__(self, path: Path, feed: PerceptionFeed) -> None:
        self.path = path
        self.feed = feed
        self.bases: dict[str, np.ndarray] = {}
        self.optical: np.ndarray | None = None
        self.local: dict[str, tuple[float, np.ndarray]] = {}
        self.jaw: dict[str, float] = {}
        # (stamp, T_camera_needle) waiting for its status
        self._pose: tuple[float, np.ndarray] | None = None
        # (stamp, NeedleStatus) waiting for its pose
        self._status: tuple[float, NeedleStatus] | None = None
        self._rows: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        # (t, T_tool1, T_tool2, jaw1, jaw2, needle, holds1, holds2)
        self.rows: list[tuple[Any, ...]] = []

    def take(self, topic: str, msg: Any) -> None:
        if topic == '/tf_static':
            for t in msg.transforms:
                tr, rot = t.transform.translation, t.transform.rotation
                T = transform_from_pose([tr.x, tr.y, tr.z, rot.x, rot.y, rot.z, rot.w])
                if t.header.frame_id == 'world' and t.child_frame_id.endswith('_base'):
                    self.bases[t.child_frame_id[:-len('_base')]] = T
                elif t.header.frame_id == 'ECM' and t.child_frame_id == OPTICAL:
                    self.optical = T
        elif topic.endswith('/local/measured_cp'):
            arm = topic.split('/')[1]
            self.local[arm] = (_seconds(msg.header.stamp), _matrix(msg.pose))
            if arm == 'ECM' and 'ECM' in self.bases and self.optical is not None:
                self.feed.camera_moved(self.bases['ECM'] @ self.local['ECM'][1] @ self.optical)
            elif arm == PSMS[-1]:
                self._sample()
        elif topic.endswith('/jaw/measured_js'):
            if len(msg.position):
                self.jaw[topic.split('/')[1]] = float(msg.position[0])
        elif topic == NEEDLE:
            self._pose = (_seconds(msg.header.stamp), _matrix(msg.pose))
            self._match()
        elif topic == STATUS:
            try:
                data = json.loads(msg.data)
                self._status = (float(data['stamp']), NeedleStatus(bool(data['found']),
                                                                   str(data.get('reason') or '')))
            except (ValueError, TypeError, KeyError) as exc:
                raise bags.BagError(f'{self.path}: a {STATUS} message is not a status with '
                                    f'found and stamp ({exc})') from exc
            self._match()
        elif topic in ROWS.values():
            self._markers(topic, msg)

    def _match(self) -> None:
        if self._status is None:
            return
        stamp, status = self._status
        if not status.found:
            self.feed.needle_seen(stamp, None, status)
        elif self._pose is not None and self._pose[0] == stamp:
            self.feed.needle_seen(stamp, self._pose[1], status)
        else:
            return
        self._status = None

    def _markers(self, topic: str, msg: Any) -> None:
        which = 'entries' if topic == ROWS['entries'] else 'exits'
        points = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses],
                          dtype=float).reshape(-1, 3)
        normal = np.array([0.0, 0.0, -1.0])
        if msg.poses:
            o = msg.poses[0].orientation
            normal = matrix_from_quaternion([o.x, o.y, o.z, o.w])[:3, 2]
        self._rows[which] = (_seconds(msg.header.stamp), points, normal)
        e, x = self._rows.get('entries'), self._rows.get('exits')
        if e is not None and x is not None and e[0] == x[0] and len(e[1]) == len(x[1]):
            self.feed.markers_seen(e[0], e[1], x[1], e[2])

    def _sample(self) -> None:
        """One sample per PSM2 report: the arms as reported, the needle as perceived."""
        if not all(a in self.local and a in self.bases and a in self.jaw for a in PSMS) \
                or self.feed.T_world_camera is None:
            return
        t = max(self.local[a][0] for a in PSMS)
        arms = Observation(t=t, T_world_tool={a: self.bases[a] @ self.local[a][1] for a in PSMS},
                           jaw={a: self.jaw[a] for a in PSMS}, T_world_needle=None, holders=(),
                           pair=None, T_world_base={a: self.bases[a] for a in PSMS})
        obs = self.feed.observe(arms)
        if obs.T_world_needle is None or obs.pair is None:
            return  # nothing perceived yet
        self.rows.append((t, arms.T_world_tool['PSM1'], arms.T_world_tool['PSM2'],
                          arms.jaw['PSM1'], arms.jaw['PSM2'], obs.T_world_needle,
                          'PSM1' in obs.holders, 'PSM2' in obs.holders))


def demonstration_from_physical_bag(path: str | Path, pair: str | None = None,
                                    pair_index: int | None = None, sample_rate: float = 100.0,
                                    needle_geometry: Any = None) -> Demonstration:
    """
    Read a bag recorded in physical mode into a Demonstration, from the perceived needle.

    Parameters
    ----------
    path : str or Path
        Bag directory.
    pair : str, optional
        Sutured pair; default the bag's last ``/sim/target_pair``.
    pair_index : int, optional
        The pair's position along the wound (1 = leftmost in the camera); default the number
        the pair's name ends in.
    sample_rate : float
        Samples per second of the result.
    needle_geometry : sim_bridge.common.needle.NeedleGeometry, optional
        The needle's shape (default: perception's).

    Returns
    -------
    suture_lfd.demos.demonstration.Demonstration
        ``world`` as the robot believes it; the pair as perceived.

    Raises
    ------
    suture_lfd.bags.BagError
        Naming the bag and the missing topic or what was never perceived.

    """
    path = Path(path)
    if not sample_rate > 0.0:
        raise ValueError(f'sample_rate must be > 0 Hz, got {sample_rate}')
    with bags.open_bag(path, required=REQUIRED_TOPICS) as reader:
        if pair is None:
            names = [reader.deserialize(m).data for m in reader.messages(['/sim/target_pair'])] \
                if '/sim/target_pair' in reader.topics else []
            if not names:
                raise bags.BagError(f'{path}: the bag does not say which pair was sutured (no '
                                    '/sim/target_pair message); pass pair=')
            pair = names[-1]
        try:
            index = pair_index or pair_index_from_name(pair)
        except ValueError as exc:
            raise bags.BagError(f'{path}: {exc}') from exc
        replay = _Replay(path, PerceptionFeed(pair, index, needle_geometry))
        wanted = [t for t in reader.topics if t in REQUIRED_TOPICS]
        for message in reader.messages(wanted):
            replay.take(message.topic, reader.deserialize(message))
    rows = replay.rows
    if len(rows) < 6:
        missing = replay.feed.seen_since(-math.inf)
        raise bags.BagError(f'{path}: {len(rows)} samples with the needle and pair {pair} '
                            f'perceived (never seen: {", ".join(missing) or "pair " + pair})')
    cols = list(zip(*rows))
    times = np.asarray(cols[0], dtype=float)
    keep = np.concatenate(([True], np.diff(times) > 0.0))
    times = times[keep]
    n = int(math.floor((times[-1] - times[0]) * sample_rate + 1e-9)) + 1
    T = times[0] + np.arange(n) / float(sample_rate)

    def poses(k: int) -> np.ndarray:
        values = pose_from_transform(np.asarray(cols[k])[keep])
        P = np.column_stack([np.interp(T, times, values[:, j]) for j in range(3)])
        return np.hstack((P, resample_quaternions(times, values[:, 3:], T)))

    def signal(k: int) -> np.ndarray:
        return np.interp(T, times, np.asarray(cols[k], dtype=float)[keep])

    def flags(k: int) -> np.ndarray:
        held = np.asarray(cols[k], dtype=bool)[keep]
        return held[np.clip(np.searchsorted(times, T, side='right') - 1, 0, len(times) - 1)]

    seen = replay.feed._pair
    assert seen is not None  # every row was sampled with the pair perceived
    return Demonstration(
        t=T, psm1_pose=poses(1), psm2_pose=poses(2), psm1_jaw=signal(3), psm2_jaw=signal(4),
        needle_pose=poses(5), psm1_holds=flags(6), psm2_holds=flags(7), entry=seen.entry.copy(),
        exit=seen.exit.copy(), normal=seen.normal.copy(), pair=pair)


def record_physical_demonstration(sim: 'Simulation', pair_name: str, path: str | Path,
                                  seed: int = 0, perception_rate: float = 2.0,
                                  pause: float = 0.3, sample_period: float = 0.01,
                                  timeout: float = 60.0) -> tuple['ThrowScore', dict[str, int]]:
    """
    Record a scripted demonstration as a recorder on a simulator in physical mode would.

    The pausing scripted expert (:mod:`suture_lfd.demos.scripted_demo`, the synthetic subject:
    it sees the scene as a person at the console does) throws on ``pair_name``; every control
    period the arms' reports (``local/measured_cp`` in their bases, jaws, the ECM's pose) are
    written, and at ``perception_rate`` (simulated Hz) a rendered stereo pair goes through
    :class:`suture_lfd.perception.StereoPerception` and its outputs are written as the
    perception node publishes them. No ground truth is written.

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
        The scene (its kinematic errors are the robot's).
    pair_name : str
        Target pair.
    path : str or Path
        Bag directory to create (must not exist).
    seed : int
        Scene seed.
    perception_rate : float
        Looks per simulated second.
    pause, sample_period, timeout : float
        As :func:`suture_lfd.demos.scripted_demo.record_scripted_demonstration`.

    Returns
    -------
    score : sim_bridge.scene.scoring.ThrowScore
        The evaluation's score of the demonstration (kept out of the bag).
    counts : dict of str to int
        Messages written per topic.

    """
    if not perception_rate > 0.0:
        raise ValueError(f'perception_rate must be > 0 Hz, got {perception_rate}')
    store = bags.make_typestore()
    ty = store.types
    pair = start_episode(sim, pair_name, seed)
    expert = PausingExpert(pair, sim.needle_geometry, config=sim.config.scene.expert,
                           kinematics=sim.kinematics['PSM1'], pause=pause)
    camera = sim.camera
    stereo = stereo_from_camera_info(camera.camera_info('left'), camera.camera_info('right'))
    perception = StereoPerception()
    believed = {a: sim.believed_base(a) for a in ('ECM',) + PSMS}
    messages: list[tuple[float, str, str, Any]] = []   # (t, topic, msgtype, message or CDR)
    t0 = sim.time

    def put(t: float, topic: str, msgtype: str, msg: Any) -> None:
        messages.append((float(t), topic, msgtype, msg))

    def transform(T: ArrayLike, parent: str, child: str) -> Any:
        x, y, z, qx, qy, qz, qw = (float(v) for v in pose_from_transform(T))
        return ty['geometry_msgs/msg/TransformStamped'](
            header=_header(store, t0, parent), child_frame_id=child,
            transform=ty['geometry_msgs/msg/Transform'](
                translation=ty['geometry_msgs/msg/Vector3'](x=x, y=y, z=z),
                rotation=ty['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw)))

    put(t0, '/tf_static', TF, ty[TF](transforms=[transform(believed[a], 'world', f'{a}_base')
                                                 for a in believed]
                                     + [transform(camera.T_tip_left, 'ECM', OPTICAL)]))
    put(t0, '/sim/target_pair', STRING, ty[STRING](data=pair_name))
    looks = {'next': t0}

    def look(t: float) -> None:
        frame = sim.render()
        result = perception.process(frame.left_rgb, frame.right_rgb, stereo, t)
        est = result.needle
        if est.found:
            assert est.pose_camera is not None  # a found estimate carries its pose
            put(t, NEEDLE, POSE, bags.pose_stamped_cdr(t, OPTICAL, cast(
                Sequence[float], pose_from_transform(est.pose_camera))))
        put(t, STATUS, STRING, ty[STRING](data=json.dumps(
            {'found': bool(est.found), 'reason': est.reason, 'stamp': t})))
        if result.markers is not None:
            q = normal_quaternion(result.markers.normal)
            for which, points in (('entries', result.markers.entries),
                                  ('exits', result.markers.exits)):
                put(t, ROWS[which], POSES, ty[POSES](header=_header(store, t, OPTICAL), poses=[
                    ty['geometry_msgs/msg/Pose'](
                        position=ty['geometry_msgs/msg/Point'](x=float(p[0]), y=float(p[1]),
                                                               z=float(p[2])),
                        orientation=ty['geometry_msgs/msg/Quaternion'](
                            x=q[0], y=q[1], z=q[2], w=q[3])) for p in points]))

    class _Recorder:
        def step(self, obs: Observation) -> Command:
            command = expert.step(obs)
            t = obs.t
            for a in PSMS:
                put(t, f'/{a}/jaw/measured_js', JOINTS,
                    bags.joint_state_cdr(t, ('jaw',), (float(sim.arms[a].jaw_measured_jp),)))
            for a in ('ECM',) + PSMS:
                local = invert_transform(believed[a]) @ sim.reported_tool_pose(a)
                put(t, f'/{a}/local/measured_cp', POSE, bags.pose_stamped_cdr(
                    t, f'{a}_base', cast(Sequence[float], pose_from_transform(local))))
            if t >= looks['next'] - 1e-9:
                looks['next'] += 1.0 / perception_rate
                look(t)
            return command

    run_episode(sim, expert, sample_period, stepper=_Recorder(), timeout=timeout,
                always_settle=True)
    score = sim.score()
    messages.sort(key=lambda m: m[0])   # stable: keeps the order within one instant
    with bags.BagWriter(path, typestore=store) as writer:
        for t, topic, msgtype, msg in messages:
            if not writer.has_topic(topic):
                writer.add_topic(topic, msgtype, qos=[_LATCHED if topic == '/tf_static'
                                                      else _STATE_QOS])
            raw = msg if isinstance(msg, bytes) else store.serialize_cdr(msg, msgtype)
            # rosbags' serialize_cdr gives a memoryview, which the bag writer takes as bytes
            writer.write(topic, int(round(t * 1e9)), raw)  # type: ignore[arg-type]
        writer.set_custom_data('suture_lfd.demonstration', pair_name)
        return score, dict(writer.counts)


def _header(store: 'Typestore', t: float, frame_id: str = '') -> Any:
    ns = int(round(float(t) * 1e9))
    stamp = store.types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
    return store.types['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)
