"""
The dVRK CRTK ROS 2 face of one simulated arm: topics, services and events under ``<ARM>/``.

Names are relative (``PSM1/measured_js``), so ``--ros-args -r __ns:=/x`` and per-topic remaps
apply. Types, frame ids, joint names and QoS follow the dVRK 2.x (sawIntuitiveResearchKit with
cisst-ros):

- state (published at the simulator's ``rate``, RELIABLE, VOLATILE, depth 100; skipped while a
  topic has no subscriber, as cisst-ros does): ``measured_js``, ``setpoint_js``,
  ``measured_cp``, ``setpoint_cp``, ``local/measured_cp``, ``local/setpoint_cp``,
  ``measured_cv``, ``local/measured_cv``, ``body/measured_cf``, ``spatial/measured_cf``,
  ``body/jacobian``, ``spatial/jacobian``, ``gravity_compensation/setpoint_js``; PSMs add
  ``jaw/measured_js`` and ``jaw/setpoint_js``;
- events (RELIABLE, TRANSIENT_LOCAL, depth 100): ``operating_state``, ``goal_reached``,
  ``error``, ``warning``, ``status``, ``trajectory_j/ratio``, and ``tool_type`` (PSM) or
  ``endoscope_type`` (ECM); operating_state stamps are non-zero, strictly increasing and, when
  the simulator clock stands for the wall clock, never behind it (crtk clients compare them
  with their own ``now()``);
- streamed commands (RELIABLE, VOLATILE, depth 1: a new servo goal replaces the last):
  ``servo_jp``, ``servo_jr``, ``servo_jf``, ``servo_cp``; PSMs add ``jaw/servo_jp`` and
  ``jaw/servo_jf``;
- queued commands (RELIABLE, VOLATILE, depth 100: an ordered queue, a burst is never dropped):
  ``move_jp``, ``move_jr``, ``move_cp``, ``hold``, ``free``, ``spatial/servo_cf``,
  ``body/servo_cf``, ``body/set_cf_orientation_absolute``, ``use_gravity_compensation``,
  ``trajectory_j/set_ratio``, ``set_base_frame``; PSMs add ``jaw/move_jp`` and
  ``emulate_tool_present``; a latched publisher's goal arrives once matched, like on the dVRK;
- ``state_command``: a volatile and a transient-local reader (:mod:`sim_bridge.ros.intake`), so
  that a command that a latched publisher (crtk) sends before discovery has matched it still
  arrives, once, in order, and one written before the simulator started (an earlier client's,
  replayed to a restarted simulator) is dropped with a ``warning``. (A transient-local reader on
  ``move_*`` as well would make every volatile ``move_*`` publisher, crtk's included, warn of
  incompatible QoS; a move is sent after the client has seen the arm's state anyway.)
- services: ``operating_state``, ``crtk_version``, ``forward_kinematics``,
  ``local/forward_kinematics``, ``inverse_kinematics``.

Frames: ``measured_cp``/``setpoint_cp``/``measured_cv`` in the arm's reference frame (on a
patient cart the ECM camera frame ``ECM`` for a PSM and ``world`` for the ECM, else the RCM frame
``<ARM>_base``; ``set_base_frame`` names another); ``local/*`` always in ``<ARM>_base``; body
quantities in the tool-tip frame ``<ARM>``. SI units. ``servo_cp`` and ``move_cp`` goals are read
by their ``frame_id``: ``""`` or the reference frame; ``ECM_view`` (the dVRK simulators' view
frame: ``ECM`` turned half a turn about its z axis, x left, y up) while the reference frame is
``ECM``; ``<ARM>_base``; ``world``. A goal in any other frame is rejected with a ``warning``
(throttled as the arm's other warnings; a ``move_cp`` also gets a busy pulse ending with
``goal_reached`` false).

On a patient cart the set-up joints' topics tell a client where the arm's base is (the
simulated cart has no set-up joints to move, so their ``measured_js`` is empty):
``SUJ/<ARM>/measured_cp`` and ``SUJ/<ARM>/local/measured_cp`` (``T_world_<ARM>_base``, frame
``world``, child ``<ARM>_base``) and ``SUJ/<ARM>/measured_js``, at the state rate.

Joint commands carry their JointState names to the arm, which maps them by name in any order
(none, or numeric names: by position) and rejects an unknown name with an ``error``.

Every command is handed to :class:`sim_bridge.arm.Arm` unchanged; the arm validates it (NaN,
infinite values, non-unit quaternions, wrong vector lengths, joint limits, reachability, readiness)
and reports problems as ``error``/``warning`` events, which this face publishes.

Size: one arm's endpoints, the order in which its commands are applied and its state
publication are one table of topics; split, each part would need the others' tables.
"""

from contextlib import nullcontext
from functools import cached_property, partial

from crtk_msgs.msg import OperatingState, StringStamped
from crtk_msgs.srv import QueryForwardKinematics, QueryInverseKinematics, TriggerOperatingState
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
import numpy as np
from rclpy.callback_groups import CallbackGroup
from sensor_msgs.msg import JointState
from sim_bridge.common import cdr
from sim_bridge.kinematics import UnreachableError
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.intake import CommandIntake
from sim_bridge.ros.readers_gate import ReadersGate
from std_msgs.msg import Bool, Empty, Float64, Float64MultiArray, String
from std_srvs.srv import Trigger

CRTK_VERSION = '1.1.0'
# Streaming commands (up to 1 kHz from a teleoperation client): taken by the simulator right
# before each stepping round (:meth:`CrtkArm.take_commands`) instead of waking the executor for
# every message; like the dVRK, which applies servo goals in its control loop. Any other command
# first takes those published before it and handles those published after it (by the senders'
# source timestamps) after itself, so a client's sequence holds across topics.
POLLED_COMMANDS = ('servo_jp', 'servo_jr', 'servo_jf', 'servo_cp', 'jaw/servo_jp',
                   'jaw/servo_jf')
# A stepping round may take a streamed goal before the executor has run a move published
# earlier (both waiting at once): that move is then older than the goal already applied, and
# the command sent last wins, so the move is dropped. Moves by the part of the arm they drive.
MOVES = {'move_jp': 'arm', 'move_jr': 'arm', 'move_cp': 'arm', 'jaw/move_jp': 'jaw'}
_ZERO6 = np.zeros(6)
WORLD = 'world'
# The dVRK simulators' view frame in the camera frame ECM: x left, y up, z along the view.
VIEW_FRAME = 'ECM_view'
_T_ECM_VIEW = np.diag([-1.0, -1.0, 1.0, 1.0])
# Smallest step between two operating_state stamps: 1 us, so that clients comparing stamps as
# float seconds (about 0.24 us resolution at today's epoch) still see them increase.
_STAMP_STEP_NS = 1000


class _Polled(CallbackGroup):
    """Callback group no executor runs: its subscriptions are read by their owner."""

    def can_execute(self, entity):
        return False

    def beginning_execution(self, entity):
        return False

    def ending_execution(self, entity):
        pass


class ArmSnapshot:
    """
    The state of an arm at one publication, each quantity computed once and only when asked.

    Same values as the :class:`sim_bridge.arm.Arm` properties of the same names, but one forward
    kinematics per joint vector and one Jacobian for all the topics of a state publication
    (instead of one or more per topic); the arm keeps its poses and Jacobians from one publication
    to the next while it does not move, so an arm at rest costs no kinematics at all.
    """

    def __init__(self, arm, read_jp=None, read_jaw=None):
        self.arm = arm
        self.kinematics = arm.kinematics
        self.reference_frame = arm.reference_frame
        self._read_jp = read_jp  # the joints the encoders report; None: the arm's own
        self._read_jaw = read_jaw  # the jaw's (angle, velocity) reported; None: the arm's own

    @cached_property
    def jaw(self):
        """The jaw's measured angle and velocity (rad, rad/s)."""
        if self._read_jaw is None:
            return self.arm.jaw_measured_jp, self.arm.jaw_measured_jv
        return self._read_jaw()

    @cached_property
    def measured_jp(self):
        return self.arm.measured_jp if self._read_jp is None else self._read_jp()

    @cached_property
    def setpoint_jp(self):
        return self.arm.setpoint_jp

    @cached_property
    def base_frame(self):
        return self.arm.base_frame

    @cached_property
    def local_measured_cp(self):
        if self._read_jp is not None:  # the FK of what the encoders read
            return self.kinematics.fk(self.measured_jp)
        return self.arm.local_measured_cp  # kept by the arm while it does not move

    @cached_property
    def local_setpoint_cp(self):
        return self.arm.local_setpoint_cp

    @cached_property
    def measured_cp(self):
        return self.base_frame @ self.local_measured_cp

    @cached_property
    def setpoint_cp(self):
        return self.base_frame @ self.local_setpoint_cp

    @cached_property
    def jacobian_spatial(self):
        return self.arm.jacobian_spatial  # kept by the arm while it does not move

    @cached_property
    def jacobian_body(self):
        return self.arm.jacobian_body

    @cached_property
    def measured_cv(self):
        twist = self.jacobian_spatial @ self.arm.measured_jv
        R = self.base_frame[:3, :3]
        return np.concatenate([R @ twist[:3], R @ twist[3:]])

    @cached_property
    def local_measured_cv(self):
        return self.jacobian_body @ self.arm.measured_jv


class CrtkArm:
    """
    Publishers, subscriptions and services of one arm.

    Parameters
    ----------
    node : rclpy.node.Node
        The simulator node that owns the endpoints.
    name : str
        Arm name and namespace (``'PSM1'``, ``'PSM2'``, ``'ECM'``).
    get_arm : callable
        Returns the current :class:`sim_bridge.arm.Arm` (a scene reset replaces the object).
    now_ns : callable
        Returns the simulator clock now (int nanoseconds).
    on_command : callable, optional
        Called after every command the arm received (the node flushes events there).
    poll_servo : bool, optional
        Leave the :data:`POLLED_COMMANDS` subscriptions out of the executor; the owner calls
        :meth:`take_commands` before it steps the arm (default: the executor runs them).
    lock : callable, optional
        Returns a context manager that every callback (command, service) holds while it runs;
        the owner holds the same lock when it steps the arm or publishes (default: none).
    T_world_base : array_like, shape (4, 4), optional
        The arm's RCM frame ``<ARM>_base`` in ``world``: Cartesian goals stamped ``world`` are
        taken (default: rejected, as any frame the arm cannot place).
    suj : bool, optional
        Publish the patient cart's set-up joint topics ``SUJ/<ARM>/*`` (needs
        ``T_world_base``).
    read_jp : callable, optional
        Returns the joints the arm's encoders report (``measured_js``; ``measured_cp`` is their
        forward kinematics) (default: the arm's own joints).
    read_jaw : callable, optional
        Returns the jaw's angle and velocity ``jaw/measured_js`` reports (default: the arm's
        own jaw).
    stamp_floor_ns : callable, optional
        Returns a time (int ns) that ``operating_state`` stamps must not fall behind: the wall
        clock when the simulator clock stands for it. A client without ``use_sim_time`` takes
        ``now()`` just before it publishes a move and counts only states stamped later (crtk
        ``wait_move_handle``), while the simulator clock, stepped in rounds, lags the wall
        clock by up to a round (default: the simulator clock alone).

    Notes
    -----
    Not thread-safe by itself: the owner serialises access through ``lock``.

    """

    def __init__(self, node, name, get_arm, now_ns, on_command=None, poll_servo=False,
                 lock=None, stamp_floor_ns=None, T_world_base=None, suj=False, read_jp=None,
                 read_jaw=None):
        self.name = name
        self._read_jp = read_jp
        self._read_jaw = read_jaw
        self._T_world_base = None if T_world_base is None else np.array(T_world_base,
                                                                         dtype=float)
        self._T_base_world = None if T_world_base is None else np.linalg.inv(
            self._T_world_base)
        self._stamp_floor_ns = stamp_floor_ns or (lambda: 0)
        self._lock = lock or nullcontext
        self._polled_group = _Polled() if poll_servo else None
        self._polled = []
        self.intakes = {}  # topic -> CommandIntake (sim_bridge.ros.intake)
        self._streamed_ns = {'arm': -1, 'jaw': -1}  # newest streamed goal applied, source stamp
        self._node = node
        self._get_arm = get_arm
        self._now_ns = now_ns
        self._on_command = on_command or (lambda: None)
        self._last_state_ns = 0
        arm = get_arm()
        self._has_jaw = arm.has_jaw
        k = arm.kinematics
        self._joint_names = list(k.joint_names)
        self._state = {}
        # every state message is written as CDR bytes (sim_bridge.common.cdr): the same message as
        # building it, a fraction of the cost at ~40 messages per 10 ms
        names = tuple(self._joint_names)
        zeros = [0.0] * len(names)
        base = self.base_frame_id

        def pose(t, frame, T):
            return cdr.pose_stamped(t, frame, cv.pose_vector(T))

        add = self._add_state
        add('measured_js', JointState, lambda s, t: cdr.joint_state(
            t, names, s.measured_jp, s.arm.measured_jv, s.arm.measured_jf))
        add('setpoint_js', JointState, lambda s, t: cdr.joint_state(
            t, names, s.setpoint_jp, effort=s.arm.setpoint_jf))
        add('measured_cp', PoseStamped, lambda s, t: pose(t, s.reference_frame, s.measured_cp))
        add('setpoint_cp', PoseStamped, lambda s, t: pose(t, s.reference_frame, s.setpoint_cp))
        add('local/measured_cp', PoseStamped, lambda s, t: pose(t, base, s.local_measured_cp))
        add('local/setpoint_cp', PoseStamped, lambda s, t: pose(t, base, s.local_setpoint_cp))
        add('measured_cv', TwistStamped,
            lambda s, t: cdr.vector6_stamped(t, s.reference_frame, s.measured_cv))
        add('local/measured_cv', TwistStamped,
            lambda s, t: cdr.vector6_stamped(t, self.name, s.local_measured_cv))
        add('body/measured_cf', WrenchStamped,
            lambda s, t: cdr.vector6_stamped(t, self.name, _ZERO6))
        add('spatial/measured_cf', WrenchStamped,
            lambda s, t: cdr.vector6_stamped(t, s.reference_frame, _ZERO6))
        add('body/jacobian', Float64MultiArray, lambda s, t: cdr.jacobian_array(s.jacobian_body))
        add('spatial/jacobian', Float64MultiArray,
            lambda s, t: cdr.jacobian_array(s.jacobian_spatial))
        add('gravity_compensation/setpoint_js', JointState,
            lambda s, t: cdr.joint_state(t, names, effort=zeros))
        if suj and self._T_world_base is not None:
            base_pose = cv.pose_vector(self._T_world_base)
            for topic in ('measured_cp', 'local/measured_cp'):
                add(topic, PoseStamped, lambda s, t: cdr.pose_stamped(t, WORLD, base_pose),
                    prefix=f'SUJ/{name}')
            add('measured_js', JointState, lambda s, t: cdr.joint_state(t, (), []),
                prefix=f'SUJ/{name}')
        if self._has_jaw:
            add('jaw/measured_js', JointState, lambda s, t: cdr.joint_state(
                t, ('jaw',), [s.jaw[0]], [s.jaw[1]], [0.0]))
            add('jaw/setpoint_js', JointState, lambda s, t: cdr.joint_state(
                t, ('jaw',), [s.arm.jaw_setpoint_jp], effort=[0.0]))

        pub = node.create_publisher
        self._events = {
            'operating_state': pub(OperatingState, f'{name}/operating_state', qos.EVENTS),
            'goal_reached': pub(Bool, f'{name}/goal_reached', qos.EVENTS),
            'error': pub(String, f'{name}/error', qos.EVENTS),
            'warning': pub(String, f'{name}/warning', qos.EVENTS),
            'status': pub(String, f'{name}/status', qos.EVENTS),
            'ratio': pub(Float64, f'{name}/trajectory_j/ratio', qos.EVENTS),
        }
        self._held_events = []
        self._gate = ReadersGate(self._events['operating_state'], [
            self._state[f'{name}/{topic}'][0] for topic in ('measured_cp', 'setpoint_cp')])
        if self._has_jaw:
            self._type_pub = pub(String, f'{name}/tool_type', qos.EVENTS)
            self._type_pub.publish(String(data=str(getattr(k, 'tool_type', ''))))
        else:
            self._type_pub = pub(String, f'{name}/endoscope_type', qos.EVENTS)
            self._type_pub.publish(String(data=str(getattr(k, 'endoscope_type', ''))))

        sub = self._subscribe
        sub('state_command', StringStamped, lambda a, m: a.state_command(m.string))
        sub('servo_jp', JointState, lambda a, m: a.servo_jp(cv.raw_positions(m), m.name))
        sub('servo_jr', JointState, lambda a, m: a.servo_jr(cv.raw_positions(m), m.name))
        sub('servo_jf', JointState, lambda a, m: a.servo_jf(cv.raw_efforts(m), m.name))
        sub('move_jp', JointState, lambda a, m: a.move_jp(cv.raw_positions(m), m.name))
        sub('move_jr', JointState, lambda a, m: a.move_jr(cv.raw_positions(m), m.name))
        sub('servo_cp', PoseStamped, self._on_servo_cp)
        sub('move_cp', PoseStamped, self._on_move_cp)
        sub('hold', Empty, lambda a, m: a.hold())
        sub('free', Empty, lambda a, m: a.free())
        sub('trajectory_j/set_ratio', Float64, lambda a, m: a.set_ratio(m.data))
        sub('set_base_frame', PoseStamped, self._on_set_base_frame)
        for topic in ('spatial/servo_cf', 'body/servo_cf'):
            sub(topic, WrenchStamped, lambda a, m, t=topic: self._not_simulated(t))
        # accepted for compatibility; the kinematic simulation has no forces to act on
        sub('body/set_cf_orientation_absolute', Bool, lambda a, m: None)
        sub('use_gravity_compensation', Bool, lambda a, m: None)
        if self._has_jaw:
            sub('jaw/servo_jp', JointState,
                lambda a, m: a.jaw_servo_jp(cv.raw_positions(m), m.name))
            sub('jaw/move_jp', JointState,
                lambda a, m: a.jaw_move_jp(cv.raw_positions(m), m.name))
            sub('jaw/servo_jf', JointState, lambda a, m: None)
            sub('emulate_tool_present', Bool, lambda a, m: a.emulate_tool_present(m.data))

        def srv(srv_type, name, handler):
            def locked(request, response):
                with self._lock():
                    return handler(request, response)
            node.create_service(srv_type, name, locked)
        srv(TriggerOperatingState, f'{name}/operating_state', self._srv_operating_state)
        srv(Trigger, f'{name}/crtk_version', self._srv_crtk_version)
        srv(QueryForwardKinematics, f'{name}/forward_kinematics',
            lambda req, resp: self._srv_fk(req, resp, local=False))
        srv(QueryForwardKinematics, f'{name}/local/forward_kinematics',
            lambda req, resp: self._srv_fk(req, resp, local=True))
        srv(QueryInverseKinematics, f'{name}/inverse_kinematics', self._srv_ik)
        self._warned = set()

    def _on_servo_cp(self, arm, msg):
        """Stream a Cartesian goal to ``arm``, in the frame the message's ``frame_id`` names."""
        goal, local = self._cartesian_goal(arm, 'servo_cp', msg)
        if goal is not None:
            arm.servo_cp(goal, local=local)

    def _on_move_cp(self, arm, msg):
        """Start a Cartesian move of ``arm``, in the frame the message's ``frame_id`` names."""
        goal, local = self._cartesian_goal(arm, 'move_cp', msg)
        if goal is not None:
            arm.move_cp(goal, local=local)

    def _cartesian_goal(self, arm, topic, msg):
        """
        Return a Cartesian command's goal and whether it is in ``<ARM>_base``: ``(goal, local)``.

        The goal is in the arm's reference frame (``local`` False) or in ``<ARM>_base``
        (``local`` True). A pose the arm cannot take is passed on as it came (the arm names
        what is wrong with it); a frame it does not know is rejected here: ``(None, False)``.
        """
        frame = msg.header.frame_id
        reference = arm.reference_frame
        if not frame or frame == reference:
            return cv.vector_from_pose(msg.pose), False
        if frame == self.base_frame_id:
            return cv.vector_from_pose(msg.pose), True
        if frame == WORLD and self._T_base_world is not None:
            convert, local = self._T_base_world, True
        elif frame == VIEW_FRAME and reference == 'ECM':
            convert, local = _T_ECM_VIEW, False
        else:
            frames = [repr(reference), repr(self.base_frame_id)]
            if reference == 'ECM':
                frames.append(repr(VIEW_FRAME))
            if self._T_base_world is not None:
                frames.append(repr(WORLD))
            arm.reject_goal(topic, f'{self.name}: {topic} stamped in frame {frame!r} '
                                   f'ignored: send it in {", ".join(frames)} or with an '
                                   f"empty frame_id (the arm's reference frame)")
            return None, False
        try:
            T = cv.matrix_from_pose(msg.pose, what=f'{topic} pose')
        except ValueError:  # the arm names what is wrong with the goal
            return cv.vector_from_pose(msg.pose), local
        return convert @ T, local

    @property
    def base_frame_id(self):
        """Frame id of ``local/*``: the RCM frame ``<ARM>_base``."""
        return f'{self.name}_base'

    # -- wiring --------------------------------------------------------------------------------

    def _add_state(self, topic, msg_type, build, prefix=None):
        name = f'{prefix or self.name}/{topic}'
        pub = self._node.create_publisher(msg_type, name, qos.STATE)
        self._state[name] = (pub, build)

    def _subscribe(self, topic, msg_type, handler):
        """
        Subscribe ``handler(arm, msg)`` to the arm's command ``topic``.

        Streamed commands (:data:`POLLED_COMMANDS`, when polled) wait in their subscription
        until :meth:`take_commands`; the others are handled as they come, in the order their
        senders published them (:meth:`_deliver_in_order`).
        """
        deliver = partial(self._deliver, handler)
        name = f'{self.name}/{topic}'
        if self._polled_group is not None and topic in POLLED_COMMANDS:
            sub = self._node.create_subscription(msg_type, name, deliver, qos.ARM_COMMANDS,
                                                 callback_group=self._polled_group)
            self._polled.append((sub, 'jaw' if topic.startswith('jaw/') else 'arm'))
        elif topic == 'state_command':
            self.intakes[topic] = CommandIntake(
                self._node, msg_type, name, partial(self._deliver_in_order, topic, deliver),
                on_stale=partial(self._stale, topic))
        else:
            on_queued = partial(self._on_queued, topic, deliver)
            self._node.create_subscription(msg_type, name, on_queued, qos.QUEUED_COMMANDS)

    def _deliver(self, handler, msg):
        """Hand a command message to the arm, then wake the simulator."""
        handler(self._get_arm(), msg)
        self._on_command()

    def _on_queued(self, topic, deliver, msg, info):
        """Receive a queued command with its message info (the sender's publication stamp)."""
        self._deliver_in_order(topic, deliver, msg, info.get('source_timestamp'))

    def _deliver_in_order(self, topic, deliver, msg, sent):
        """
        Deliver a queued command after the streamed ones its sender published before it.

        Streamed commands sent before this one go first, those sent after it (already waiting
        too) after it: by the senders' publication stamps ``sent`` (ns).
        """
        with self._lock():
            later = self.take_commands(before_ns=sent)
            part = MOVES.get(topic)
            if part is None or sent is None or sent > self._streamed_ns[part]:
                deliver(msg)
            for sub, streamed, newer, stamp in later:
                self._handle_streamed(sub, streamed, newer, stamp)

    def _stale(self, topic, msg, age):
        """Warn that a latched command written before the simulator started was dropped."""
        what = f' {msg.string!r}' if hasattr(msg, 'string') else ''
        self._publish_text('warning', f'{self.name}: ignored a latched {topic}{what} written '
                                      f'{age:.1f} s before the simulator started (left by an '
                                      'earlier client or run); send it again')

    def take_commands(self, before_ns=None):
        """
        Handle the streaming commands (servo_*) received since the last call, in topic order.

        With ``before_ns`` only those published before it (source timestamp, ns) are handled;
        the others are returned as ``(subscription, part, message, source timestamp)`` for the
        caller to handle.
        """
        later = []
        for sub, part in self._polled:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
            if taken is None:  # depth 1: at most the newest one is waiting
                continue
            sent = taken[1].get('source_timestamp')
            if before_ns is not None and sent is not None and sent > before_ns:
                later.append((sub, part, taken[0], sent))
            else:
                self._handle_streamed(sub, part, taken[0], sent)
        return later

    def _handle_streamed(self, sub, part, msg, sent):
        """Apply a streamed goal of ``part`` and remember its source stamp (ns) for moves."""
        if sent is not None:
            self._streamed_ns[part] = max(self._streamed_ns[part], sent)
        sub.callback(msg)

    def _not_simulated(self, topic):
        if topic not in self._warned:
            self._warned.add(topic)
            self._publish_text('warning', f'{self.name}: {topic} is not simulated (the '
                               'simulated arm is kinematic); ignored')

    def _on_set_base_frame(self, arm, msg):
        try:
            T = cv.matrix_from_pose(msg.pose, what='set_base_frame pose')
        except ValueError as exc:
            self._publish_text('error', f'{self.name}: {exc}')
            return
        arm.set_base_frame(T, msg.header.frame_id or None)

    # -- publishing ----------------------------------------------------------------------------

    def publish_state(self, ns):
        """Publish every state topic that has a subscriber, stamped ``ns`` (int nanoseconds)."""
        state = None
        for pub, build in self._state.values():
            if pub.get_subscription_count():
                state = state or ArmSnapshot(self._get_arm(), self._read_jp, self._read_jaw)
                pub.publish(build(state, ns))

    def _state_stamp(self):
        """Return the simulator clock now, bumped so operating_state stamps strictly increase."""
        ns = max(self._now_ns(), self._stamp_floor_ns(), self._last_state_ns + _STAMP_STEP_NS, 1)
        self._last_state_ns = ns
        return cv.stamp_from_nanoseconds(ns)

    def publish_operating_state(self, state=None):
        """Publish an operating state (default: the arm's current one)."""
        state = state or self._get_arm().operating_state
        self._events['operating_state'].publish(
            cv.operating_state(state.state, state.is_homed, state.is_busy, self._state_stamp()))

    def _publish_text(self, kind, text):
        log = self._node.get_logger()
        (log.error if kind == 'error' else log.warning if kind == 'warning' else log.info)(text)
        self._events[kind].publish(String(data=text))

    def flush_events(self, arm=None):
        """
        Publish the arm's pending events (operating_state, goal_reached, messages, ratio).

        They are held, in order, while a reader of the arm's events is not yet a reader of its
        ``measured_cp`` and ``setpoint_cp`` (:class:`sim_bridge.ros.readers_gate.ReadersGate`):
        a client that enabled and homed the arm gets its state before it sees it ready.
        """
        arm = arm or self._get_arm()
        self._held_events.extend(arm.pop_events())
        if not self._held_events or self._gate.holds():
            return
        events, self._held_events = self._held_events, []
        for event in events:
            kind = event.kind
            if kind == 'operating_state':
                self.publish_operating_state(event.value)
            elif kind == 'goal_reached':
                self._events['goal_reached'].publish(Bool(data=bool(event.value)))
            elif kind == 'ratio':
                self._events['ratio'].publish(Float64(data=float(event.value)))
            else:  # error, warning, status: the arm has already logged them
                self._events[kind].publish(String(data=str(event.value)))

    # -- services ------------------------------------------------------------------------------

    def _srv_operating_state(self, request, response):
        state = self._get_arm().operating_state
        response.operating_state = cv.operating_state(state.state, state.is_homed,
                                                      state.is_busy, self._state_stamp())
        return response

    def _srv_crtk_version(self, request, response):
        response.success = True
        response.message = CRTK_VERSION
        return response

    def _srv_fk(self, request, response, local):
        """Return the FK of the first ``len(jp)`` joints (all of them: the tool tip)."""
        arm = self._get_arm()
        k = arm.kinematics
        jp = np.asarray(request.jp, dtype=float)
        n = jp.size
        if not 1 <= n <= k.n_joints or not np.all(np.isfinite(jp)):
            response.result = False
            response.message = (f'{self.name}: forward_kinematics needs 1 to {k.n_joints} finite '
                                f'joint values, got {jp.tolist()}')
            return response
        if n == k.n_joints:
            T = k.fk(jp)
        else:
            q = np.concatenate([jp, np.zeros(k.n_joints - n)])
            T = k.fk_links(q)[n]
        if not local:
            T = arm.base_frame @ T
        response.cp = cv.pose_from_matrix(T)
        response.result = True
        return response

    def _srv_ik(self, request, response):
        """
        Solve the IK of a tool-tip pose in the ``measured_cp`` frame near ``jp`` (or the setpoint).

        As ``forward_kinematics`` answers in that frame (``local/forward_kinematics`` in
        ``<ARM>_base``), the pose is read in it: the camera frame of a patient cart's PSMs.

        The ECM answers as it moves: the position, rolled about the shaft towards the
        orientation (:meth:`EcmKinematics.ik_position`); a position outside the workspace is
        ``result`` false.
        """
        arm = self._get_arm()
        k = arm.kinematics
        try:
            T = np.linalg.solve(arm.base_frame_view,
                                cv.matrix_from_pose(request.cp, what='inverse_kinematics cp'))
            q_ref = np.asarray(request.jp, dtype=float) if len(request.jp) else arm.setpoint_jp
            q_ref = k.check_q(q_ref, name='inverse_kinematics jp')
            if arm.has_jaw:
                q = k.ik(T, q_ref=q_ref)
            else:
                q, inside = k.ik_position(T, q_ref=q_ref)
                if not inside:
                    raise UnreachableError('the position is outside the workspace (joint limits)')
        except UnreachableError as exc:
            response.result, response.message = False, f'{self.name}: unreachable: {exc}'
            return response
        except ValueError as exc:
            response.result, response.message = False, f'{self.name}: {exc}'
            return response
        response.jp = [float(v) for v in q]
        response.result = True
        return response
