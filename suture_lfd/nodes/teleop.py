"""
Teleop node: one MTM drives one PSM as the dVRK's teleoperation does, over CRTK topics only.

Runs against a physical dVRK console (``/MTMR``, ``/MTML``, ``/footpedals/*``) as well as the
virtual MTMs (``mtms``) and the simulated PSMs. Reads ``<MTM>/measured_cp``,
``<MTM>/gripper/measured_js``, ``<MTM>/operating_state``, ``<PSM>/setpoint_cp``,
``<PSM>/jaw/setpoint_js``, ``<PSM>/operating_state``, ``<ECM>/measured_cp`` (the camera),
``/tf_static`` (frames of the arms' bases) and the pedals ``clutch_topic`` and
``operator_present_topic`` (sensor_msgs/Joy, ``buttons[0]``); sends ``<PSM>/servo_cp``,
``<PSM>/jaw/servo_jp``, ``<PSM>/hold``, ``state_command`` to both arms, and to the MTM
``move_cp``, ``lock_orientation``, ``unlock_orientation``, ``use_gravity_compensation`` and
``body/servo_cf``. The state machine and the map are :mod:`suture_lfd.teleop.teleoperation`.

Publishes ``~/current_state`` (std_msgs/String: SETTING_ARMS, ALIGNING, CLUTCHED, FOLLOWING,
DISABLED) and ``~/following`` (std_msgs/Bool), latched; ``~/state_command``
(crtk_msgs/StringStamped ``enable``/``disable``) starts and stops it, as the dVRK teleop
components' topics. Run one per MTM/PSM pair, named like the dVRK's (``-r __node:=MTMR_PSM1``).
Parameters: ``config/teleop.yaml``. The cycle runs at ``rate`` while the operator is present
(coag), the teleoperation follows or is clutched, or for a second after the MTM's gripper moved
(a pinch may come before coag), and at ``idle_rate`` otherwise. The state streams (the MTM's
pose and gripper, the PSM's setpoint and jaw, the camera's pose) are read at the start of every
cycle, the newest sample of each, as the dVRK's teleop reads its arms' state: no callback per
sample, and none at all between the cycles of a teleop at rest.
"""

import sys

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped, Quaternion, WrenchStamped
import numpy as np
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState, Joy
from sim_bridge.common.geometry import matrix_from_quaternion, quaternion_from_matrix
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.params import declare_config
from sim_bridge.ros.polled import PolledInputs
from std_msgs.msg import Bool, Empty, Header, String
from suture_lfd.nodes import executables
from suture_lfd.teleop.frames import FrameTree
from suture_lfd.teleop.teleoperation import (
    CLUTCHED,
    FOLLOWING,
    ArmState,
    TeleopConfig,
    Teleoperation,
    TeleopInputs,
)
from tf2_msgs.msg import TFMessage


class TeleopNode(Node):
    """The ROS face of :class:`suture_lfd.teleop.teleoperation.Teleoperation`."""

    def __init__(self):
        super().__init__('teleop')
        cfg = self.config = declare_config(self, TeleopConfig, 'teleop.yaml', 'teleop')
        self.teleop = Teleoperation(cfg)
        self.frames = FrameTree()
        self._mtm_cp = self._psm_cp = None
        self._mtm_frame = self._psm_frame = ''
        self._gripper = self._jaw = None
        self._mtm_state = self._psm_state = None
        self._clutch = False
        self._present = not cfg.operator_present_topic
        self._R_C_M_param = matrix_from_quaternion(np.asarray(cfg.mtm_rotation, dtype=float))
        self._last_state = None
        self._warned = set()
        m, p = cfg.mtm, cfg.psm
        sub = self.create_subscription
        # the state streams: subscribed by a node no executor spins, read once per cycle
        self._inputs = rclpy.create_node(f'{self.get_name()}_inputs', context=self.context,
                                         use_global_arguments=False,  # names resolved here
                                         start_parameter_services=False)
        self._polled = PolledInputs(self._inputs, self.resolve_topic_name)
        poll = self._poll_input
        poll(PoseStamped, f'{m}/measured_cp', self._on_mtm_cp)
        poll(JointState, f'{m}/gripper/measured_js', self._on_gripper)
        sub(OperatingState, f'{m}/operating_state',
            lambda msg: setattr(self, '_mtm_state', self._arm_state(msg)), qos.EVENTS)
        poll(PoseStamped, f'{p}/setpoint_cp', self._on_psm_cp)
        poll(JointState, f'{p}/jaw/setpoint_js', self._on_jaw)
        sub(OperatingState, f'{p}/operating_state',
            lambda msg: setattr(self, '_psm_state', self._arm_state(msg)), qos.EVENTS)
        if cfg.ecm:
            poll(PoseStamped, f'{cfg.ecm}/measured_cp', self._on_ecm_cp)
        sub(TFMessage, '/tf_static', self._on_tf_static, qos.STATIC_TF)
        sub(Joy, cfg.clutch_topic, self._on_clutch, qos.EVENTS)
        if cfg.operator_present_topic:
            sub(Joy, cfg.operator_present_topic, self._on_present, qos.EVENTS)
        sub(StringStamped, '~/state_command', self._on_state_command, qos.STREAM)
        pub = self.create_publisher
        self._pubs = {
            ('psm', 'servo_cp'): pub(PoseStamped, f'{p}/servo_cp', qos.STREAM),
            ('psm', 'jaw_servo_jp'): pub(JointState, f'{p}/jaw/servo_jp', qos.STREAM),
            ('psm', 'hold'): pub(Empty, f'{p}/hold', qos.STREAM),
            ('psm', 'state_command'): pub(StringStamped, f'{p}/state_command', qos.STATE_COMMAND),
            ('mtm', 'state_command'): pub(StringStamped, f'{m}/state_command',
                                         qos.STATE_COMMAND),
            ('mtm', 'move_cp'): pub(PoseStamped, f'{m}/move_cp', qos.STREAM),
            ('mtm', 'lock_orientation'): pub(Quaternion, f'{m}/lock_orientation', qos.LATCHED),
            ('mtm', 'unlock_orientation'): pub(Empty, f'{m}/unlock_orientation', qos.LATCHED),
            ('mtm', 'use_gravity_compensation'): pub(Bool, f'{m}/use_gravity_compensation',
                                                     qos.LATCHED),
            ('mtm', 'body_servo_cf'): pub(WrenchStamped, f'{m}/body/servo_cf', qos.STREAM),
        }
        self._current = pub(String, '~/current_state', qos.LATCHED)
        self._following = pub(Bool, '~/following', qos.LATCHED)
        self._publish_state()
        self._period_ns = None
        self._active_until = -1.0       # s: a gripper that moved keeps the full rate until then
        self._timer = self.create_timer(1.0 / cfg.idle_rate, self._on_timer)
        self._pace()
        self.get_logger().info(f'{m} -> {p} (scale {cfg.scale}, camera '
                               f'{cfg.ecm or "none"}, align_mtm {cfg.align_mtm})')

    # --- inputs -----------------------------------------------------------------------------

    def _poll_input(self, msg_type, name, handler):
        """Subscribe to a state stream read at each cycle (newest sample) by ``handler``."""
        self._polled.add(msg_type, name, handler, qos.LATEST)

    def _read_inputs(self):
        """Hand the newest sample of every state stream, if a new one came, to its handler."""
        self._polled.read()

    @staticmethod
    def _arm_state(msg):
        return ArmState(msg.state, bool(msg.is_homed), bool(msg.is_busy))

    def _pose(self, msg, what):
        try:
            return cv.matrix_from_pose(msg.pose, what=what)
        except ValueError as exc:
            self._warn_once(what, str(exc))
            return None

    def _warn_once(self, key, text):
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def _on_mtm_cp(self, msg):
        T = self._pose(msg, f'{self.config.mtm}/measured_cp')
        if T is not None:
            self._mtm_cp, self._mtm_frame = T, msg.header.frame_id

    def _on_psm_cp(self, msg):
        T = self._pose(msg, f'{self.config.psm}/setpoint_cp')
        if T is not None:
            self._psm_cp, self._psm_frame = T, msg.header.frame_id

    def _on_ecm_cp(self, msg):
        T = self._pose(msg, f'{self.config.ecm}/measured_cp')
        if T is not None:
            self.frames.set(msg.header.frame_id, self.config.ecm, T)

    def _on_tf_static(self, msg):
        for tr in msg.transforms:
            t, q = tr.transform.translation, tr.transform.rotation
            T = np.eye(4)
            T[:3, :3] = matrix_from_quaternion(np.array([q.x, q.y, q.z, q.w]))
            T[:3, 3] = (t.x, t.y, t.z)
            self.frames.set(tr.header.frame_id, tr.child_frame_id, T)

    def _on_gripper(self, msg):
        if len(msg.position):
            gripper = float(msg.position[0])
            if gripper != self._gripper:
                self._active_until = self._now() + 1.0
                if self._period_ns != int(1e9 / self.config.rate):
                    self._pace()
            self._gripper = gripper

    def _on_jaw(self, msg):
        if len(msg.position):
            self._jaw = float(msg.position[0])

    def _on_clutch(self, msg):
        if len(msg.buttons):
            self._clutch = msg.buttons[0] == 1

    def _on_present(self, msg):
        if len(msg.buttons):
            self._present = msg.buttons[0] == 1
            self._pace()

    def _on_state_command(self, msg):
        if msg.string not in ('enable', 'disable'):
            self.get_logger().warning(f'~/state_command: {msg.string!r} is not enable or '
                                      'disable; ignored')
            return
        self.teleop.set_enabled(msg.string == 'enable', self._now())

    # --- the cycle --------------------------------------------------------------------------

    def _now(self):
        return self.get_clock().now().nanoseconds * 1e-9

    def _rotations(self):
        """Return ``(R_C_M, R_C_P)``, or ``(None, None)`` while a frame is unknown."""
        cfg = self.config
        camera = cfg.ecm
        if not camera:
            R_C_P = np.eye(3)
            R_C_M = self.frames.rotation(self._psm_frame, self._mtm_frame)
        else:
            R_C_P = self.frames.rotation(camera, self._psm_frame)
            R_C_M = self.frames.rotation(camera, self._mtm_frame)
        if R_C_M is None and self._mtm_frame and not self.frames.knows(self._mtm_frame):
            R_C_M = self._R_C_M_param    # a console frame: the configured rotation
        return R_C_M, R_C_P

    def _on_timer(self):
        self._read_inputs()
        R_C_M, R_C_P = self._rotations()
        inp = TeleopInputs(
            t=self._now(), mtm_cp=self._mtm_cp, gripper=self._gripper, psm_cp=self._psm_cp,
            psm_jaw=self._jaw, mtm_state=self._mtm_state, psm_state=self._psm_state,
            R_C_M=R_C_M, R_C_P=R_C_P, clutch=self._clutch, operator_present=self._present)
        commands = self.teleop.step(inp)
        if commands:
            stamp = self.get_clock().now().to_msg()
            for command in commands:
                self._send(command, stamp)
        self._publish_state()
        self._pace()

    def _pace(self):
        """Run the cycle at ``rate`` while someone teleoperates, at ``idle_rate`` otherwise."""
        cfg = self.config
        busy = self._present or self.teleop.state in (FOLLOWING, CLUTCHED) \
            or self._now() < self._active_until
        period_ns = int(1e9 / (cfg.rate if busy else cfg.idle_rate))
        if period_ns != self._period_ns:
            self._period_ns = period_ns
            self._timer.timer_period_ns = period_ns
            self._timer.reset()       # the next cycle one new period from now

    def _send(self, command, stamp):
        kind, arm, value = command
        pub = self._pubs[(arm, kind)]
        if kind in ('servo_cp', 'move_cp'):
            frame = self._psm_frame if arm == 'psm' else self._mtm_frame
            pub.publish(cv.pose_stamped(value, frame, stamp))
        elif kind == 'jaw_servo_jp':
            pub.publish(cv.joint_state(['jaw'], stamp, position=[value]))
        elif kind in ('hold', 'unlock_orientation'):
            pub.publish(Empty())
        elif kind == 'state_command':
            pub.publish(StringStamped(header=Header(stamp=stamp), string=value))
            self.get_logger().info(f'{self._arm_name(arm)}: {value}')
        elif kind == 'lock_orientation':
            x, y, z, w = quaternion_from_matrix(value).tolist()
            pub.publish(Quaternion(x=x, y=y, z=z, w=w))
        elif kind == 'use_gravity_compensation':
            pub.publish(Bool(data=bool(value)))
        elif kind == 'body_servo_cf':
            pub.publish(cv.wrench_stamped(value, '', stamp))

    def destroy_node(self):
        self._inputs.destroy_node()
        return super().destroy_node()

    def _arm_name(self, arm):
        return self.config.mtm if arm == 'mtm' else self.config.psm

    def _publish_state(self):
        state = self.teleop.state
        if state != self._last_state:
            self._last_state = state
            self._current.publish(String(data=state))
            self._following.publish(Bool(data=state == FOLLOWING))
            self.get_logger().info(f'{self.config.mtm} -> {self.config.psm}: {state}')


def main(args=None):
    return executables.teleop(args)


if __name__ == '__main__':
    sys.exit(main())
