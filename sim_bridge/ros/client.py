"""
A client of the simulator's topics for a node that drives the two PSMs.

:class:`SimClient` lives on a node the caller made (it is not a node itself), so the caller keeps
its own timers, parameters and topics. It subscribes to what a controller needs and publishes
what it sends, with the profiles of :mod:`sim_bridge.ros.qos`:

- arms' state: ``<ARM>/measured_cp``, ``<ARM>/local/measured_cp``, ``<ARM>/measured_js``,
  ``<ARM>/jaw/measured_js``, ``<ARM>/operating_state``;
- ground truth: ``sim/<ARM>/base_frame``, ``sim/needle/measured_cp``,
  ``sim/markers/<pair>/entry|exit`` (of the pairs given to :meth:`SimClient.watch_pairs`) and
  the scene events ``sim/events`` (grasps and releases are followed in
  :attr:`SimClient.holders`; every event goes to the ``on_event`` callback);
- commands: ``<ARM>/state_command`` (:meth:`SimClient.enable_and_home`), ``<ARM>/servo_cp`` and
  ``<ARM>/jaw/servo_jp`` (:meth:`SimClient.send`, a :class:`sim_bridge.control.Command` in
  ``world``, sent in the frame the arm reports ``measured_cp`` in), ``sim/target_pair``
  (:meth:`SimClient.select_pair`).

:meth:`SimClient.observation` assembles a :class:`sim_bridge.control.Observation` from the
arms' newest consistent state, so a core controller (scripted expert, demonstrator, executor)
runs the same way in-process and over ROS. Typical use in a node's timer::

    client = SimClient(node, on_event=self._on_event)
    client.watch_pairs(['synth1'])
    ...
    if client.ready(['synth1']) and client.enable_and_home():
        command = controller.step(client.observation('synth1'))
        client.send(command, cv.stamp_from_seconds(command.t))

With ``physical=True`` (a physical dVRK, or the simulator in physical mode) the client reads
only what a robot provides: none of the ``sim/`` ground truth (no needle, markers or scene
events; :attr:`SimClient.holders` stays empty), the bases ``T_world_<ARM>_base`` (PSMs and ECM)
from ``/tf_static`` as the robot's registration places them, the camera's optical frames
``ECM -> ECM_left_optical`` from there too, and the ECM's ``local/measured_cp``, so
:meth:`SimClient.camera_pose` gives the camera in ``world``. :meth:`SimClient.observation` then
has no needle, holders or pair: a perception estimator adds them.

**The arms' state is consistent.** An arm's ``measured_cp``, ``local/measured_cp``,
``measured_js`` and ``jaw/measured_js`` are paired by their stamp
(:class:`sim_bridge.common.stamp_sets.StampSets`): the arm's state is the newest stamp at which
all four have come, never the newest of each (which, when the stream lags or bursts after a
stalled period, joins a tool pose to the joints of another instant). :meth:`SimClient.ready`
waits for such a set of every arm, :meth:`SimClient.observation` is made of them and
:meth:`SimClient.measured_stamps` gives their stamps, so a controller stepped once per new stamp
steps only on consistent data.

The client refuses to read the evaluation's ground truth: a topic it would subscribe to that
resolves (after remapping) under ``/evaluation/``, where a simulator in physical mode publishes
the truth, raises :class:`ValueError` naming it.

Frames: ``world``; ``<ARM>_base``; poses 4x4; metres, radians, seconds. The arms' frames are
converted here, once, so a controller sees ``world`` whatever frame the arms report in: the tool
pose is ``T_world_base @ local/measured_cp`` (``local/*`` is in ``<ARM>_base`` on every dVRK);
goals are sent in the frame of ``measured_cp``: ``<ARM>_base`` or ``world`` as they are, any
other (the camera frame ``ECM`` of a patient cart) through ``T_ref_base = measured_cp @
local/measured_cp^-1`` of the newest pair published together (same stamp), so they follow the
ECM as the arm's reference frame does.
"""

import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped
import numpy as np
from sensor_msgs.msg import JointState
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.stamp_sets import StampSets
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.control import Observation
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.scene.phantom import MarkerPair
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

#: the messages of one stamp that make an arm's state
STATE_PARTS = ('cp', 'local', 'js', 'jaw')
EVALUATION = '/evaluation/'  # the ground truth a simulator keeps for the evaluation
STATE_COMMAND_PERIOD = 2.0  # s of wall time between repeated enable/home commands


class SimClient:
    """
    The simulator's arms, ground truth and events, as seen from a client node.

    Parameters
    ----------
    node : rclpy.node.Node
        The node the subscriptions and publishers are made on.
    arms : sequence of str
        The PSMs to follow and command.
    on_event : callable, optional
        Called as ``on_event(stamp_s, data)`` with every scene event (``data`` the decoded
        JSON mapping), after :attr:`holders` is updated.
    on_measured_cp : callable, optional
        Called as ``on_measured_cp(arm, stamp_s)`` after each ``measured_cp`` is stored.
    physical : bool
        Read only what a physical dVRK provides (see the module's docstring).

    Attributes
    ----------
    tools : dict of str to tuple
        Per arm the newest ``measured_cp``: ``(stamp_s, frame_id, T_frame_tool)``.
    sets : sim_bridge.common.stamp_sets.StampSets
        Per arm the newest consistent state: ``measured_cp`` ``(frame_id, T_frame_tool)``,
        ``local/measured_cp`` ``T_base_tool``, ``measured_js`` and ``jaw/measured_js`` messages
        (parts ``cp``, ``local``, ``js``, ``jaw``) of one stamp.
    local : dict of str to tuple
        Per arm the newest ``local/measured_cp``: ``(stamp_s, T_base_tool)``.
    q, jaw, state : dict of str to message
        Newest ``measured_js``, ``jaw/measured_js`` and ``operating_state`` per arm.
    bases : dict of str to ndarray (4, 4)
        ``T_world_base`` per arm.
    needle : ndarray (4, 4) or None
        Newest ``T_world_needle``.
    markers : dict of str to dict
        Per watched pair, ``{'entry': T_world_marker, 'exit': T_world_marker}`` as received.
    holders : set of str
        Arms holding the needle, from the grasp/release/reset events.
    published : dict of str to int
        Messages sent per topic name.

    """

    def __init__(self, node, arms=PSMS, *, on_event=None, on_measured_cp=None, physical=False):
        self.node = node
        self.arms = tuple(arms)
        self.physical = bool(physical)
        self.optical = {}  # 'ECM_left_optical' -> T_ECM_optical (physical mode, /tf_static)
        self.tools, self.q, self.jaw, self.state = {}, {}, {}, {}
        self.local = {}
        self.sets = StampSets(self.arms, STATE_PARTS)
        self._T_ref_base = {}  # arm -> (stamp_s, T_ref_base) of the newest matching pair
        self.bases, self.markers = {}, {}
        self.needle = None
        self.holders = set()
        self.published = {}
        self._on_event_cb = on_event
        self._on_cp_cb = on_measured_cp
        self._marker_subs = []
        self._last_state_command = -float('inf')
        self._commanded_on = None  # arm states when enable/home were last sent
        pub = node.create_publisher
        self._servo = {a: pub(PoseStamped, f'{a}/servo_cp', qos.SERVO_STREAM)
                       for a in self.arms}
        self._jaw_pub = {a: pub(JointState, f'{a}/jaw/servo_jp', qos.SERVO_STREAM)
                         for a in self.arms}
        self._command = {a: pub(StringStamped, f'{a}/state_command', qos.STATE_COMMAND)
                         for a in self.arms}
        self._target = pub(String, 'sim/target_pair', qos.STREAM)
        sub = self._subscribe
        for a in self.arms:
            sub(PoseStamped, f'{a}/measured_cp', lambda m, a=a: self._on_cp(a, m), qos.STREAM)
            sub(PoseStamped, f'{a}/local/measured_cp', lambda m, a=a: self._on_local(a, m),
                qos.STREAM)
            sub(JointState, f'{a}/measured_js', lambda m, a=a: self._on_js(a, 'js', m),
                qos.STREAM)
            sub(JointState, f'{a}/jaw/measured_js', lambda m, a=a: self._on_js(a, 'jaw', m),
                qos.STREAM)
            sub(OperatingState, f'{a}/operating_state',
                lambda m, a=a: self.state.__setitem__(a, m), qos.LATCHED)
            if not self.physical:
                sub(PoseStamped, f'sim/{a}/base_frame',
                    lambda m, a=a: self.bases.__setitem__(a, cv.matrix_from_pose(m.pose)),
                    qos.LATCHED)
        if self.physical:
            sub(TFMessage, '/tf_static', self._on_tf_static, qos.STATIC_TF)
            sub(PoseStamped, 'ECM/local/measured_cp', lambda m: self._on_local('ECM', m),
                qos.STREAM)
        else:
            sub(PoseStamped, 'sim/needle/measured_cp', self._on_needle, qos.STREAM)
            sub(StringStamped, 'sim/events', self._on_event, qos.SCENE_EVENTS)

    def _subscribe(self, msg_type, topic, callback, profile):
        """Subscribe on the node, refusing a topic that resolves into the evaluation's truth."""
        resolved = self.node.resolve_topic_name(topic)
        if resolved.startswith(EVALUATION):
            raise ValueError(f'{topic} resolves to {resolved}: the ground truth under '
                             f'{EVALUATION} is for the evaluation only; a controller must not '
                             f'read it (remove the remapping)')
        return self.node.create_subscription(msg_type, topic, callback, profile)

    # --- inputs -------------------------------------------------------------------------------

    def _on_cp(self, arm, msg):
        stamp = cv.seconds_from_stamp(msg.header.stamp)
        self.tools[arm] = (stamp, msg.header.frame_id, cv.matrix_from_pose(msg.pose))
        self.sets.put(arm, 'cp', stamp, self.tools[arm][1:])
        self._pair_frames(arm)
        if self._on_cp_cb is not None:
            self._on_cp_cb(arm, stamp)

    def _on_local(self, arm, msg):
        self.local[arm] = (cv.seconds_from_stamp(msg.header.stamp), cv.matrix_from_pose(msg.pose))
        if arm in self.arms:
            self.sets.put(arm, 'local', *self.local[arm])
            self._pair_frames(arm)

    def _on_js(self, arm, part, msg):
        (self.q if part == 'js' else self.jaw)[arm] = msg
        self.sets.put(arm, part, cv.seconds_from_stamp(msg.header.stamp), msg)

    def _on_tf_static(self, msg):
        """Keep the bases ``world -> <ARM>_base`` and the camera's ``ECM -> *_optical``."""
        for t in msg.transforms:
            parent, child = t.header.frame_id, t.child_frame_id
            if parent == 'world' and child.endswith('_base'):
                self.bases[child[:-len('_base')]] = cv.matrix_from_transform(t.transform)
            elif parent == 'ECM' and child.endswith('_optical'):
                self.optical[child] = cv.matrix_from_transform(t.transform)

    def _pair_frames(self, arm):
        """Keep ``T_ref_base`` of the newest measured_cp and local/measured_cp of one stamp."""
        tool, local = self.tools.get(arm), self.local.get(arm)
        if tool is None or local is None or tool[0] != local[0]:
            return
        if tool[1] in ('world', f'{arm}_base'):
            return  # a frame placed by the base frames alone: no pair needed
        self._T_ref_base[arm] = (tool[0], tool[2] @ invert_transform(local[1]))

    def _on_needle(self, msg):
        self.needle = cv.matrix_from_pose(msg.pose)

    def _on_event(self, msg):
        try:
            stamp, data = cv.event_from_message(msg)
        except ValueError as exc:
            self.node.get_logger().warning(f'sim/events: {exc}')
            return
        kind, arm = data.get('kind'), data.get('arm')
        if kind == 'grasp' and arm in self.arms:
            self.holders.add(arm)
        elif kind == 'release' and arm in self.arms:
            self.holders.discard(arm)
        elif kind == 'reset':
            self.holders.clear()
        if self._on_event_cb is not None:
            self._on_event_cb(stamp, data)

    def watch_pairs(self, names):
        """
        Follow the entry and exit markers of exactly these pairs, afresh.

        Earlier marker subscriptions are dropped with what they received; the new ones get the
        markers' latched poses.

        Parameters
        ----------
        names : iterable of str
            Marker pair names (``'synth1'``); empty names are skipped.

        """
        for s in self._marker_subs:
            self.node.destroy_subscription(s)
        self.markers = {}
        self._marker_subs = []
        for name in dict.fromkeys(n for n in names if n):
            self.markers[name] = {}
            for which in ('entry', 'exit'):
                self._marker_subs.append(self._subscribe(
                    PoseStamped, f'sim/markers/{name}/{which}',
                    lambda m, n=name, w=which: self.markers[n].__setitem__(
                        w, cv.matrix_from_pose(m.pose)), qos.LATCHED))

    # --- state --------------------------------------------------------------------------------

    def has_pair(self, name):
        """Return True once both markers of a watched pair have come."""
        return len(self.markers.get(name, ())) == 2

    def ready(self, pairs=()):
        """
        Return True once the arms' consistent state, base frames, needle and pairs' markers came.

        In physical mode: the arms' state, their bases and the camera's pose (no needle and no
        markers: those come from perception).
        """
        if self.physical:
            return self.camera_pose() is not None and all(
                a in self.tools and a in self.bases and a in self.jaw and a in self.state
                and self._placed(a) for a in self.arms)
        return (all(self.has_pair(p) for p in pairs) and self.needle is not None and all(
            a in self.tools and a in self.bases and a in self.jaw and a in self.state
            and self._placed(a) for a in self.arms))

    def _placed(self, arm):
        """Whether the arm has a consistent state, placed in world, and its goals a frame."""
        if self.sets.newest(arm) is None:
            return False
        frame = self.tools[arm][1]
        return frame in ('world', f'{arm}_base') or (arm in self.local
                                                     and arm in self._T_ref_base)

    def homed(self):
        """Return True when every arm is enabled, homed and not busy."""
        return all(a in self.state and self.state[a].state == 'ENABLED'
                   and self.state[a].is_homed and not self.state[a].is_busy for a in self.arms)

    def fault(self):
        """Return ``'<ARM> is <STATE>'`` for the first arm that is not enabled, else None."""
        for a in self.arms:
            s = self.state.get(a)
            if s is not None and s.state != 'ENABLED':
                return f'{a} is {s.state}'
        return None

    def measured_stamps(self):
        """Return per arm the stamp (s) of its newest consistent state (see the docstring)."""
        return self.sets.stamps()

    def world_tool(self, arm):
        """Return the arm's tool pose ``T_world_tool`` in its newest consistent state."""
        state = self.sets.newest(arm)
        if state is None:  # not yet a whole set: the newest messages
            _, frame, T = self.tools[arm]
            local = self.local[arm][1] if arm in self.local else None
        else:
            (frame, T), local = state[1]['cp'], state[1]['local']
        if frame == 'world':
            return T
        if frame != f'{arm}_base':
            T = local  # in <ARM>_base on every dVRK
        return self.bases[arm] @ T

    def camera_pose(self, optical='ECM_left_optical'):
        """
        Return the camera's pose ``T_world_<optical>`` as the robot reports it, or None.

        ``T_world_ECM_base @ ECM local/measured_cp @ T_ECM_optical``: the ECM's registration, its
        own kinematics and the camera's calibration (physical mode; None until all three came).
        """
        if 'ECM' not in self.bases or 'ECM' not in self.local or optical not in self.optical:
            return None
        return self.bases['ECM'] @ self.local['ECM'][1] @ self.optical[optical]

    def marker_pair(self, name):
        """Return a watched pair as a :class:`sim_bridge.scene.phantom.MarkerPair` (world)."""
        entry, exit_ = self.markers[name]['entry'], self.markers[name]['exit']
        n = entry[:3, 2] + exit_[:3, 2]
        return MarkerPair(name=name, entry=entry[:3, 3].copy(), exit=exit_[:3, 3].copy(),
                          normal=n / np.linalg.norm(n), entry_normal=entry[:3, 2].copy(),
                          exit_normal=exit_[:3, 2].copy())

    def observation(self, pair):
        """
        Return what a controller sees now, from the newest messages.

        Parameters
        ----------
        pair : str
            The watched pair the controller works on.

        Returns
        -------
        sim_bridge.control.Observation
            Each arm as in its newest consistent state (see the module's docstring; the newest
            messages for an arm without one yet); time is the newest of their stamps. In
            physical mode (or with ``pair`` None) without needle, holders or pair: the arms'
            reports only.

        """
        stamps, js, jaw = [], {}, {}
        for a in self.arms:
            state = self.sets.newest(a)
            if state is None:
                stamps.append(self.tools[a][0])
                js[a], jaw[a] = self.q.get(a), self.jaw[a]
            else:
                stamps.append(state[0])
                js[a], jaw[a] = state[1]['js'], state[1]['jaw']
        q = {a: np.asarray(m.position, dtype=float) for a, m in js.items()
             if m is not None and len(m.position) >= 6}
        return Observation(
            t=max(stamps),
            T_world_tool={a: self.world_tool(a) for a in self.arms},
            jaw={a: float(m.position[0]) if len(m.position) else 0.0 for a, m in jaw.items()},
            T_world_needle=self.needle, holders=tuple(sorted(self.holders)),
            pair=None if pair is None else self.marker_pair(pair),
            T_world_base={a: T for a, T in self.bases.items() if a in self.arms}, q=q or None)

    # --- commands -----------------------------------------------------------------------------

    def _count(self, publisher):
        topic = publisher.topic_name
        self.published[topic] = self.published.get(topic, 0) + 1

    def state_command(self, arm, command):
        """Send a CRTK state command (``'enable'``, ``'home'``, ``'disable'``) to one arm."""
        msg = StringStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.string = command
        self._command[arm].publish(msg)

    def enable_and_home(self):
        """
        Bring the arms to enabled and homed; return True when they are.

        Sends ``enable`` to an arm that is not enabled and ``home`` to one that is enabled but
        not homed; again when an arm's state changes, and every :data:`STATE_COMMAND_PERIOD`
        seconds while they are not.
        """
        if self.homed():
            return True
        now = time.monotonic()
        # at once when an arm's state changes (a dVRK arm powers up for a while, then homes in
        # a motion of seconds), and again every STATE_COMMAND_PERIOD
        seen = [(s.state, s.is_homed, s.is_busy) for s in (self.state.get(a) for a in self.arms)
                if s is not None]
        if seen != self._commanded_on or now - self._last_state_command > STATE_COMMAND_PERIOD:
            self._last_state_command, self._commanded_on = now, seen
            for a in self.arms:
                s = self.state.get(a)
                if s is None:
                    continue
                if s.state != 'ENABLED':
                    self.state_command(a, 'enable')
                elif not s.is_homed and not s.is_busy:
                    self.state_command(a, 'home')
        return False

    def target_matched(self):
        """Return True when a subscriber (the simulator) takes ``sim/target_pair``."""
        return self._target.get_subscription_count() > 0

    def select_pair(self, name):
        """Ask the simulator to make ``name`` the target pair (``sim/target_pair``)."""
        self._target.publish(String(data=name))

    def send(self, command, stamp):
        """
        Send a command's tool and jaw targets.

        Parameters
        ----------
        command : sim_bridge.control.Command
            Targets in ``world``; an arm's missing or None target is not sent.
        stamp : builtin_interfaces.msg.Time
            Header stamp of the messages.

        Returns
        -------
        int
            Number of ``servo_cp`` messages sent.

        """
        sent = 0
        for arm in self.arms:
            T = command.T_world_tool.get(arm)
            if T is not None:
                _, frame, _ = self.tools[arm]
                if frame == 'world':
                    T_cmd = T
                elif frame == f'{arm}_base':
                    T_cmd = np.linalg.solve(self.bases[arm], T)
                else:
                    T_cmd = self._T_ref_base[arm][1] @ np.linalg.solve(self.bases[arm], T)
                self._servo[arm].publish(cv.pose_stamped(T_cmd, frame, stamp))
                self._count(self._servo[arm])
                sent += 1
            jaw = command.jaw.get(arm)
            if jaw is not None:
                self._jaw_pub[arm].publish(cv.joint_state(['jaw'], stamp, position=[jaw]))
                self._count(self._jaw_pub[arm])
        return sent
