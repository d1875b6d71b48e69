"""
Virtual MTMs node: ``MTML`` and ``MTMR`` and the console's foot pedals, driven by a device.

The dVRK MTM interface of each, driven by an input device (``device``: ``browser``,
``gamepad`` or ``spacemouse``).

Per MTM (namespace = its name), what a dVRK teleoperation client uses, from the start (a
browser's MTM stands at a rest pose until the page's handle gives it one):

- published: ``operating_state`` (crtk_msgs/OperatingState, latched event, again after every
  ``state_command``), ``measured_cp``, ``setpoint_cp`` (geometry_msgs/PoseStamped, in the
  console's display frame ``HRSV``: the endoscope image's axes, x right, y down, z into the
  view, origin at the camera; :mod:`suture_lfd.teleop.virtual_mtm`), ``measured_cv``
  (TwistStamped), ``gripper/measured_js`` (JointState ``gripper``, rad), every ``1/rate`` s;
  ``goal_reached`` (Bool), ``error``/``warning``/``status`` (String) events;
- subscribed: ``state_command`` (crtk_msgs/StringStamped; latched and volatile publishers
  alike, :mod:`sim_bridge.ros.intake`), ``move_cp`` (PoseStamped, queued; ``is_busy``
  true until the MTM is there, then ``goal_reached``), ``lock_orientation``
  (geometry_msgs/Quaternion), ``unlock_orientation`` (std_msgs/Empty),
  ``use_gravity_compensation`` (std_msgs/Bool), ``body/servo_cf`` (WrenchStamped: accepted and
  ignored, a virtual MTM has no motors). Releasing the clutch pedal unlocks the orientation,
  as a console's MTM does: a client need not send ``unlock_orientation`` after a clutch.

Velocity devices move the MTMs in the display frame itself; the browser's handles are posed in
``world`` and are seen from the camera: ``<camera>/measured_cp`` (the ECM, with ``/tf_static``
when its frame is not ``world``) places them, live with the ECM's motion.

Pedals (``pedals: own``): ``/footpedals/clutch``, ``/footpedals/coag``, ``/footpedals/camera``
and the console's ``/console/clutch``, ``/console/operator_present``, ``/console/camera``
(sensor_msgs/Joy ``buttons=[1|0]``, latched events on every change), so run the simulator with
``footpedals:=false``; ``pedals: emulate`` presses the simulator's pedals through
``/footpedals/<name>/emulate`` instead. The browser back-end reads the viewer's
``viewer/input/<MTM>/pose``, ``viewer/input/<MTM>/gripper`` and ``viewer/input/pedals``
(``[clutch, coag, camera]``: the page's clutch, coag and record controls).
Parameters: ``config/mtms.yaml``.

Nobody moving costs little: the cycle (device polling and the state topics) runs at ``rate``
while something changes (a device input, a pose, a gripper, a pedal, a ``move_cp``) and for
``idle_after`` s after; then at ``keep_alive_rate`` while an MTM is enabled, at ``idle_rate``
otherwise. The keep-alive rate is the dVRK's own state rate (100 Hz): a client such as
``dvrk_teleoperation.py`` reads its state every 5 ms and takes data received more than 20 ms
ago as a fault, so an enabled MTM nobody moves still publishes well within that age (50 Hz
would leave no margin: data 20 ms old plus its delivery). The browser's hand poses and grippers
are read at the start of every cycle, the newest of each (no callback per sample); a new one
brings the full rate back. A state stream nobody reads is not written.

Size: one node, its parameters, the MTMs' commands (state commands held until a client's
readers get the MTM's poses: :class:`sim_bridge.ros.readers_gate.ReadersGate`) and its cycle;
the MTM itself, its imperfection and the devices are core modules of :mod:`suture_lfd.teleop`.
"""

from dataclasses import dataclass
import math
import sys

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped, Quaternion, TwistStamped, WrenchStamped
import numpy as np
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState, Joy
from sim_bridge.common import cdr
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.common.validation import check_quaternions
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.intake import CommandIntake
from sim_bridge.ros.params import declare_config
from sim_bridge.ros.polled import PolledInputs
from sim_bridge.ros.readers_gate import ReadersGate
from std_msgs.msg import Bool, Empty, Float64, String
from suture_lfd.nodes import executables
from suture_lfd.teleop.devices import CAMERA_FRAME, PEDALS, open_device
from suture_lfd.teleop.frames import FrameTree
from suture_lfd.teleop.mtm_realism import MtmImperfection, MtmRealism
from suture_lfd.teleop.virtual_mtm import DISPLAY_FRAME, VirtualMtm
from tf2_msgs.msg import TFMessage

# an MTM's pose and gripper streams, written at each cycle to those that have readers
POSE_STREAMS = ('measured_cp', 'setpoint_cp', 'gripper')
CONSOLE = {'clutch': 'clutch', 'coag': 'operator_present', 'camera': 'camera'}


@dataclass(frozen=True)
class MtmsConfig:
    """
    Parameters of the virtual MTMs node (names as in ``config/mtms.yaml``).

    Attributes
    ----------
    device : str
        ``browser``, ``gamepad`` or ``spacemouse``.
    mtms : tuple of str
        The MTMs served.
    rate : float
        Hz of the state topics and of the device polling.
    idle_rate : float
        Hz of both while nothing changes and no MTM is enabled.
    keep_alive_rate : float
        Hz of both while nothing changes and an MTM is enabled (its state stays fresh for a
        client that refuses data older than 20 ms).
    idle_after : float
        s without a change before the cycle slows to ``idle_rate``.
    pedals : str
        ``own`` (publish ``/footpedals/*``) or ``emulate`` (press the simulator's).
    move_duration : float
        s a ``move_cp`` takes.
    gripper_start : float
        Gripper angle (rad) before the device gives one.
    browser_prefix : str
        Namespace of the viewer's input topics.
    linear_speed, angular_speed : float
        Velocity devices: m/s and rad/s at full deflection.
    deadband : float
        Velocity devices: fraction of full deflection ignored (jhu-dvrk's SpaceMouse: 0.03).
    gripper_speed : float
        Velocity devices: rad/s of the gripper while a gripper button is held.
    device_index : int
        Gamepad: SDL joystick index.
    device_path : str
        SpaceMouse: hidraw path (``''``: the first 3Dconnexion device found).
    camera : str
        The arm whose ``measured_cp`` is the camera (the display frame's origin and axes),
        for a device that gives poses in another frame (the browser's ``world``).
    realism_level : float
        How imperfect the MTMs are (:mod:`suture_lfd.teleop.mtm_realism`): 0 a perfect MTM
        (exact alignment, exact readings), 1 the ``dvrk`` preset, more scales it.
    realism_seed : int
        Seed of the MTMs' imperfection draws.

    """

    device: str = 'browser'
    mtms: tuple[str, ...] = ('MTMR', 'MTML')
    rate: float = 200.0
    idle_rate: float = 10.0
    keep_alive_rate: float = 100.0
    idle_after: float = 0.5
    pedals: str = 'own'
    move_duration: float = 0.5
    gripper_start: float = 0.5
    browser_prefix: str = 'viewer/input'
    linear_speed: float = 0.05
    angular_speed: float = 1.0
    deadband: float = 0.03
    gripper_speed: float = 1.5
    device_index: int = 0
    device_path: str = ''
    camera: str = 'ECM'
    realism_level: float = 1.0
    realism_seed: int = 0

    def __post_init__(self):
        if self.device not in ('browser', 'gamepad', 'spacemouse'):
            raise ValueError(f'parameter device must be browser, gamepad or spacemouse, got '
                             f'{self.device!r}')
        if self.pedals not in ('own', 'emulate'):
            raise ValueError(f'parameter pedals must be own or emulate, got {self.pedals!r}')
        if not self.mtms:
            raise ValueError('parameter mtms must name at least one MTM')
        for name in ('rate', 'idle_rate', 'keep_alive_rate', 'idle_after', 'linear_speed',
                     'angular_speed', 'gripper_speed'):
            if not getattr(self, name) > 0:
                raise ValueError(f'parameter {name} must be > 0, got {getattr(self, name)}')
        if self.move_duration < 0:
            raise ValueError(f'parameter move_duration must be >= 0, got {self.move_duration}')
        if not (math.isfinite(self.realism_level) and self.realism_level >= 0):
            raise ValueError(f'parameter realism_level must be a finite number >= 0, got '
                             f'{self.realism_level}')


class MtmsNode(qos.QuietEndpoints, Node):
    """Virtual MTMs and foot pedals driven by one input device."""

    def __init__(self):
        super().__init__('mtms')
        cfg = self.config = declare_config(self, MtmsConfig, 'mtms.yaml', 'mtms')
        options = {}
        if cfg.device != 'browser':
            options = {'linear_speed': cfg.linear_speed, 'angular_speed': cfg.angular_speed,
                           'deadband': cfg.deadband, 'gripper_speed': cfg.gripper_speed,
                       'gripper_start': cfg.gripper_start}
            if cfg.device == 'gamepad':
                options['index'] = cfg.device_index
            else:
                options['path'] = cfg.device_path
        self.device = open_device(cfg.device, cfg.mtms, **options)
        self.frame_id = DISPLAY_FRAME
        self._device_frame = self.device.frame_id
        self.frames = FrameTree()  # the camera in the device's frame, for devices not in it
        # the camera's and the browser's streams: subscribed by a node no executor spins, read
        # once per cycle (the newest sample of each)
        self._inputs = rclpy.create_node(f'{self.get_name()}_inputs', context=self.context,
                                         use_global_arguments=False,  # names resolved here
                                         start_parameter_services=False)
        self._polled = PolledInputs(self._inputs, self.resolve_topic_name)
        self._camera_key = None    # the camera pose message the frames hold
        self._T_display_device = None  # computed again when a frame changes
        if self._device_frame != CAMERA_FRAME:
            if not cfg.camera:
                raise ValueError(f'parameter camera must name the ECM: the {cfg.device} gives '
                                 f'poses in {self._device_frame!r}, seen from the camera')
            self._poll_input(PoseStamped, f'{cfg.camera}/measured_cp', self._on_camera)
            self.create_subscription(TFMessage, '/tf_static', self._on_tf_static,
                                     qos.STATIC_TF)
        t = self._now()
        self._t = t
        self.mtms = {}
        self._pubs = {}
        self._last_cp = {}
        self._last_gripper = {}
        self._busy = {}
        self._active_until = -1.0      # s: the cycle runs at the full rate until then
        self._period_ns = None
        self._intakes = {}
        self._gates = {}
        self._held = {}      # MTM name: state commands held until its readers get its state
        realism = MtmRealism(level=cfg.realism_level, seed=cfg.realism_seed)
        self._imperfect = {}
        for k, name in enumerate(cfg.mtms):
            T0 = np.eye(4)
            T0[:3, 3] = (0.05 if name.endswith('R') else -0.05, 0.0, 0.15)
            imperfect = self._imperfect[name] = MtmImperfection(realism, stream=k)
            mtm = self.mtms[name] = VirtualMtm(name, T0, cfg.move_duration, imperfect)
            mtm.set_gripper(cfg.gripper_start)
            self._busy[name] = False
            pub = self.create_publisher
            self._pubs[name] = {
                'measured_cp': pub(PoseStamped, f'{name}/measured_cp', qos.STREAM),
                'setpoint_cp': pub(PoseStamped, f'{name}/setpoint_cp', qos.STREAM),
                'measured_cv': pub(TwistStamped, f'{name}/measured_cv', qos.STREAM),
                'gripper': pub(JointState, f'{name}/gripper/measured_js', qos.STREAM),
                'operating_state': pub(OperatingState, f'{name}/operating_state', qos.EVENTS),
                'goal_reached': pub(Bool, f'{name}/goal_reached', qos.EVENTS),
                'error': pub(String, f'{name}/error', qos.EVENTS),
                'warning': pub(String, f'{name}/warning', qos.EVENTS),
                'status': pub(String, f'{name}/status', qos.EVENTS),
            }
            sub = self.create_subscription
            # a latched state_command (crtk's, sent before discovery) arrives once, in order;
            # one written before this node started is dropped (sim_bridge.ros.intake)
            self._intakes[name] = CommandIntake(
                self, StringStamped, f'{name}/state_command',
                lambda m, sent, n=name: self._on_state_command(n, m),
                on_stale=lambda m, age, n=name: self._on_stale_command(n, m, age))
            sub(PoseStamped, f'{name}/move_cp', lambda m, n=name: self._on_move_cp(n, m),
                qos.QUEUED_COMMANDS)
            sub(Quaternion, f'{name}/lock_orientation',
                lambda m, n=name: self._on_lock(n, m), qos.LATCHED)
            sub(Empty, f'{name}/unlock_orientation',
                lambda m, n=name: self.mtms[n].unlock_orientation(self._now()), qos.LATCHED)
            sub(Bool, f'{name}/use_gravity_compensation',
                lambda m, n=name: setattr(self.mtms[n], 'gravity_compensation', m.data),
                qos.LATCHED)
            sub(WrenchStamped, f'{name}/body/servo_cf', lambda m: None, qos.STREAM)
            if cfg.device == 'browser':
                prefix = cfg.browser_prefix
                self._poll_input(PoseStamped, f'{prefix}/{name}/pose',
                                 lambda m, n=name: self._on_handle(n, m))
                self._poll_input(Float64, f'{prefix}/{name}/gripper',
                                 lambda m, n=name: self._on_gripper(n, m))
            self._gates[name] = ReadersGate(self._pubs[name]['operating_state'], [
                self._pubs[name][topic] for topic in ('measured_cp', 'setpoint_cp', 'gripper')])
            self._publish_state(name)
        if cfg.device == 'browser':
            self.create_subscription(Joy, f'{cfg.browser_prefix}/pedals', self._on_pedals,
                                     qos.STREAM)
        self._pedal_state = dict.fromkeys(PEDALS, False)
        self._pedal_pubs = {}
        for pedal in PEDALS:
            if cfg.pedals == 'own':
                self._pedal_pubs[pedal] = [
                    self.create_publisher(Joy, f'/footpedals/{pedal}', qos.EVENTS),
                    self.create_publisher(Joy, f'/console/{CONSOLE[pedal]}', qos.EVENTS)]
            else:
                self._pedal_pubs[pedal] = [
                    self.create_publisher(Joy, f'/footpedals/{pedal}/emulate', qos.STREAM)]
        self._timer = self.create_timer(1.0 / cfg.rate, self._on_timer)
        self._wake()
        self.get_logger().info(f'virtual {", ".join(cfg.mtms)} on the {cfg.device} '
                               f'(frame {self.frame_id}), pedals {cfg.pedals}')

    def _now(self):
        return self.get_clock().now().nanoseconds * 1e-9

    # --- MTM commands -----------------------------------------------------------------------

    def _publish_state(self, name):
        mtm = self.mtms[name]
        busy = mtm.is_busy(self._now())
        self._busy[name] = busy
        self._pubs[name]['operating_state'].publish(cv.operating_state(
            mtm.state, mtm.is_homed, busy, self.get_clock().now().to_msg()))

    def _on_state_command(self, name, msg):
        """
        Apply a state command, once whoever reads the MTM's state can read its poses.

        A physical MTM powers up and homes in seconds, long after a client's streams have
        matched; the virtual one takes commands at once, so they wait (in order, for 0.5 s at
        most: :class:`sim_bridge.ros.readers_gate.ReadersGate`) while a reader of its
        ``operating_state`` does not yet get its ``measured_cp``, ``setpoint_cp`` and gripper.
        """
        held = self._held.setdefault(name, [])
        held.append(msg)
        self._release_commands(name)
        if self._held[name]:
            self._wake()            # look again at the full rate

    def _release_commands(self, name):
        held = self._held.get(name)
        if not held or self._gates[name].holds():
            return
        self._held[name] = []
        self._publish_poses(name)   # the client's first getter finds a pose, even idle
        for msg in held:
            self._apply_state_command(name, msg)
        self._wake()

    def _publish_poses(self, name):
        """Publish an MTM's poses and gripper now (before a state change it announces)."""
        self._write_poses(name, self.mtms[name].measured_cp(self._now()),
                          self.get_clock().now().nanoseconds)

    def _write_poses(self, name, T, ns):
        """
        Write an MTM's pose ``T`` and gripper, stamped ``ns``, on the streams that have readers.

        A stream nobody reads is not written: an MTM left alone (MTML while MTMR teleoperates)
        costs its node a reader count per cycle. The messages are CDR bytes (common.cdr): a
        fraction of building them, on a cycle a teleoperation client wants every 5 ms.
        """
        pubs, imperfect = self._pubs[name], self._imperfect[name]
        measured, setpoint, gripper = (pubs[topic] if pubs[topic].get_subscription_count()
                                       else None for topic in POSE_STREAMS)
        if measured is not None or setpoint is not None:
            pose = cdr.pose_stamped(ns, self.frame_id, cv.pose_vector(T))
            if measured is not None:
                # what the encoders read (level 0: the pose itself, one message for both)
                measured.publish(pose if imperfect.is_perfect else cdr.pose_stamped(
                    ns, self.frame_id, cv.pose_vector(imperfect.measured(T))))
            if setpoint is not None:
                setpoint.publish(pose)
        if gripper is not None:
            gripper.publish(cdr.joint_state(ns, ('gripper',),
                                            [imperfect.gripper(self.mtms[name].gripper)]))

    def _apply_state_command(self, name, msg):
        problem = self.mtms[name].state_command(msg.string)
        if problem:
            self._pubs[name]['warning'].publish(String(data=problem))
            self.get_logger().warning(problem)
        self._publish_state(name)

    def _on_stale_command(self, name, msg, age):
        text = (f'{name}: ignored a latched state_command {msg.string!r} written {age:.1f} s '
                'before the virtual MTMs started (left by an earlier client or run); send it '
                'again')
        self._pubs[name]['warning'].publish(String(data=text))
        self.get_logger().warning(text)

    def _reject(self, name, text):
        self._pubs[name]['error'].publish(String(data=text))
        self.get_logger().error(text)

    def _on_move_cp(self, name, msg):
        try:
            T = cv.matrix_from_pose(msg.pose, what=f'{name}/move_cp pose')
        except ValueError as exc:
            self._reject(name, str(exc))
            return
        mtm = self.mtms[name]
        if mtm.state != 'ENABLED':
            self._reject(name, f'{name}: move_cp, arm not ready')
            self._pubs[name]['goal_reached'].publish(Bool(data=False))
            return
        mtm.move_cp(T, self._now())
        self._publish_state(name)
        self._wake()

    def _on_lock(self, name, msg):
        try:
            q = check_quaternions((msg.x, msg.y, msg.z, msg.w), f'{name}: lock_orientation')
        except ValueError as exc:
            self._reject(name, str(exc))
            return
        self.mtms[name].lock_orientation(matrix_from_quaternion(q), self._now())

    # --- frames -------------------------------------------------------------------------------

    def _on_camera(self, msg):
        p, q = msg.pose.position, msg.pose.orientation
        key = (msg.header.frame_id, p.x, p.y, p.z, q.x, q.y, q.z, q.w)
        if key == self._camera_key:
            return  # the camera has not moved: the cached transform holds
        try:
            T = cv.matrix_from_pose(msg.pose, what=f'{self.config.camera}/measured_cp')
        except ValueError as exc:
            self.get_logger().warning(str(exc))
            return
        self._camera_key, self._T_display_device = key, None
        self.frames.set(msg.header.frame_id, CAMERA_FRAME, T)

    def _on_tf_static(self, msg):
        for tr in msg.transforms:
            self.frames.set(tr.header.frame_id, tr.child_frame_id, cv.matrix_from_transform(
                tr.transform))
        self._T_display_device = None

    def _display_pose(self, T_dev):
        """Return a device pose in the display frame, or None while the camera is unknown."""
        if self._device_frame == CAMERA_FRAME:
            return T_dev
        if self._T_display_device is None:
            self._T_display_device = self.frames.transform(CAMERA_FRAME, self._device_frame)
        T = self._T_display_device
        return None if T is None else T @ T_dev

    # --- device inputs ----------------------------------------------------------------------

    def _on_handle(self, name, msg):
        try:
            T = cv.matrix_from_pose(msg.pose, what=f'{self.config.browser_prefix}/{name}/pose')
        except ValueError as exc:
            self.get_logger().warning(str(exc))
            return
        self.device.set_pose(name, T)
        self._wake()

    def _on_gripper(self, name, msg):
        self.device.set_gripper(name, msg.data)
        self._wake()

    def _on_pedals(self, msg):
        try:
            self.device.set_pedals(list(msg.buttons))
        except ValueError as exc:
            self.get_logger().warning(str(exc))
        self._wake()

    def _poll_input(self, msg_type, name, handler):
        """Subscribe to a device stream read at each cycle (newest sample) by ``handler``."""
        self._polled.add(msg_type, name, handler, qos.SENSOR)

    def _read_inputs(self):
        """Hand the newest sample of every device stream, if a new one came, to its handler."""
        self._polled.read()

    # --- the pace of the cycle --------------------------------------------------------------

    def _wake(self):
        """Something changed: the cycle runs at the full rate for ``idle_after`` s."""
        self._active_until = self._now() + self.config.idle_after
        self._pace(self.config.rate)

    def _pace(self, rate):
        """Run the cycle at ``rate`` Hz from now on."""
        period_ns = int(1e9 / rate)
        if period_ns != self._period_ns:
            self._period_ns = period_ns
            self._timer.timer_period_ns = period_ns
            self._timer.reset()       # the next cycle one new period from now

    def _press(self, pedal, pressed):
        msg = Joy()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.buttons = [1 if pressed else 0]
        for pub in self._pedal_pubs[pedal]:
            pub.publish(msg)

    # --- the cycle --------------------------------------------------------------------------

    def _on_timer(self):
        self._read_inputs()
        for name in self._held:
            self._release_commands(name)
        t = self._now()
        dt = max(0.0, t - self._t)
        self._t = t
        reading = self.device.poll(t)
        ns = self.get_clock().now().nanoseconds
        changed = False
        for pedal, pressed in reading.pedals.items():
            if pedal in self._pedal_state and pressed != self._pedal_state[pedal]:
                self._pedal_state[pedal] = pressed
                self._press(pedal, pressed)
                changed = True
                if pedal == 'clutch' and not pressed:
                    for mtm in self.mtms.values():
                        mtm.release_clutch(t)
        for name, mtm in self.mtms.items():
            arm = reading.arms.get(name)
            if arm is not None:
                pose = None if arm.pose is None else self._display_pose(arm.pose)
                if pose is not None:
                    mtm.set_device_pose(pose)
                elif arm.twist is not None:
                    mtm.apply_twist(arm.twist[0], arm.twist[1], dt)
                if arm.gripper is not None:
                    mtm.set_gripper(arm.gripper)
            T = mtm.measured_cp(t)
            pubs = self._pubs[name]
            self._write_poses(name, T, ns)
            last = self._last_cp.get(name)
            velocity = pubs['measured_cv']
            if velocity.get_subscription_count():
                v = w = np.zeros(3)
                if last is not None and dt > 0:
                    v = (T[:3, 3] - last[:3, 3]) / dt
                    dR = T[:3, :3] @ last[:3, :3].T
                    w = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0],
                                  dR[1, 0] - dR[0, 1]]) * 0.5 / dt
                velocity.publish(cdr.vector6_stamped(ns, self.frame_id, np.concatenate([v, w])))
            changed = changed or last is None or not np.array_equal(T, last) \
                or mtm.gripper != self._last_gripper.get(name)
            self._last_cp[name] = T
            self._last_gripper[name] = mtm.gripper
            busy = mtm.is_busy(t)
            changed = changed or busy
            if busy != self._busy[name]:
                self._publish_state(name)
                if not busy:
                    pubs['goal_reached'].publish(Bool(data=True))
        if changed:
            self._active_until = t + self.config.idle_after
        # an enabled MTM nobody moves keeps its state fresh at the keep-alive rate: a dVRK
        # client (dvrk_teleoperation.py) takes data older than 4 of its 5 ms periods as a fault
        cfg = self.config
        if t < self._active_until:
            self._pace(cfg.rate)
        elif any(mtm.state == 'ENABLED' for mtm in self.mtms.values()):
            self._pace(cfg.keep_alive_rate)
        else:
            self._pace(cfg.idle_rate)

    def destroy_node(self):
        self._inputs.destroy_node()
        self.device.close()
        return super().destroy_node()


def main(args=None):
    return executables.mtms(args)


if __name__ == '__main__':
    sys.exit(main())
