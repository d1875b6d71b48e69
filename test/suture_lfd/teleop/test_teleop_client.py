"""
A teleoperation client written the way the dVRK's Python one is runs against the virtual MTMs
and the simulator: state commands answered by operating_state events, MTM ``move_cp`` for the
alignment (busy pulse), ``lock_orientation``, ``gripper/measured_js``, the pedals' Joy buttons,
and PSM ``servo_cp`` + ``jaw/servo_jp`` at 200 Hz.
"""

import math
import threading
import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped, Quaternion, WrenchStamped
from harness import wait_for
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState, Joy
from sim_bridge.common.geometry import quaternion_from_matrix
from sim_bridge.ros import conversions as cv
from std_msgs.msg import Bool, Empty
from suture_lfd.teleop.virtual_mtm import rotation_from_rotvec
from teleop_rig import BrowserOperator, SceneWatch, stream

# as crtk-py's ROS 2 layer makes them: depth 10 reliable volatile, latched = transient local
VOLATILE = QoSProfile(depth=10)
LATCH = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL)


class CrtkArm:
    """The crtk-utils features of one arm that the dVRK teleoperation uses."""

    def __init__(self, node, name, mtm=False):
        self.node, self.name = node, name
        self.lock = threading.Lock()
        self.measured = self.setpoint = self.state = None
        self.gripper = self.jaw = None
        self.busy_changes = []
        sub, pub = node.create_subscription, node.create_publisher
        sub(OperatingState, f'{name}/operating_state', self._on_state, VOLATILE)
        self.frame = ''
        sub(PoseStamped, f'{name}/setpoint_cp', self._on_setpoint, VOLATILE)
        self._state_command = pub(StringStamped, f'{name}/state_command', LATCH)
        if mtm:
            sub(PoseStamped, f'{name}/measured_cp', self._on_measured, VOLATILE)
            sub(JointState, f'{name}/gripper/measured_js',
                lambda m: setattr(self, 'gripper', m.position[0]), VOLATILE)
            self.move_cp_pub = pub(PoseStamped, f'{name}/move_cp', VOLATILE)
            self.lock_pub = pub(Quaternion, f'{name}/lock_orientation', LATCH)
            self.unlock_pub = pub(Empty, f'{name}/unlock_orientation', LATCH)
            self.gravity_pub = pub(Bool, f'{name}/use_gravity_compensation', LATCH)
            self.servo_cf_pub = pub(WrenchStamped, f'{name}/body/servo_cf', VOLATILE)
        else:
            sub(JointState, f'{name}/jaw/setpoint_js',
                lambda m: setattr(self, 'jaw', m.position[0]), VOLATILE)
            self.servo_cp_pub = pub(PoseStamped, f'{name}/servo_cp', VOLATILE)
            self.jaw_pub = pub(JointState, f'{name}/jaw/servo_jp', VOLATILE)
            self.hold_pub = pub(Empty, f'{name}/hold', VOLATILE)

    def _on_state(self, msg):
        with self.lock:
            if self.state is not None and msg.is_busy != self.state.is_busy:
                self.busy_changes.append(msg.is_busy)
            self.state = msg

    def _on_setpoint(self, msg):
        self.setpoint = cv.matrix_from_pose(msg.pose)
        self.frame = msg.header.frame_id

    def _on_measured(self, msg):
        self.measured = cv.matrix_from_pose(msg.pose)
        self.frame = msg.header.frame_id

    def stamp(self):
        return self.node.get_clock().now().to_msg()

    def state_command(self, command, done, timeout=60.0):
        """Send a command and wait for ``done(state)``, sending again every 5 s (crtk-py)."""
        for _ in range(int(timeout / 5)):
            self._state_command.publish(StringStamped(string=command))
            if wait_for(lambda: self.state is not None and done(self.state), timeout=5.0):
                return True
        return False

    def enable_and_home(self):
        assert self.state_command('enable', lambda s: s.state == 'ENABLED'), self.name
        assert self.state_command('home', lambda s: s.is_homed and not s.is_busy), self.name

    def move_cp(self, T):
        """Start a move and wait for its end as crtk's handle.wait(): busy, then not busy."""
        with self.lock:
            self.busy_changes.clear()
        self.move_cp_pub.publish(cv.pose_stamped(T, self.frame, self.stamp()))
        assert wait_for(lambda: True in self.busy_changes, timeout=10), 'move_cp: never busy'
        assert wait_for(lambda: self.busy_changes[-1] is False, timeout=10), 'move_cp: busy'

    def lock_orientation(self, R):
        x, y, z, w = quaternion_from_matrix(R).tolist()
        self.lock_pub.publish(Quaternion(x=x, y=y, z=z, w=w))


class JoystickButton:
    """crtk's joystick_button: the latest ``buttons[0]`` of a Joy topic."""

    def __init__(self, node, topic):
        self.value = None
        node.create_subscription(Joy, topic, lambda m: setattr(self, 'value', m.buttons[0]),
                                 VOLATILE)


class PythonStyleTeleop:
    """The run_enabled loop of the dVRK's Python teleoperation, at 200 Hz."""

    def __init__(self, node, mtm, psm, scale=0.2):
        self.node, self.mtm, self.psm, self.scale = node, mtm, psm, scale
        self.sent = 0
        self.timer = None

    def start(self):
        self.mtm.gravity_pub.publish(Bool(data=True))
        self.mtm.servo_cf_pub.publish(cv.wrench_stamped(np.zeros(6), '', self.mtm.stamp()))
        self.mtm.unlock_pub.publish(Empty())
        self.mtm_initial = self.mtm.measured.copy()
        self.psm_initial = self.psm.setpoint.copy()
        self.offset = self.mtm_initial[:3, :3].T @ self.psm_initial[:3, :3]
        self.timer = self.node.create_timer(0.005, self.run_enabled)

    def run_enabled(self):
        T = np.eye(4)
        T[:3, 3] = self.psm_initial[:3, 3] + self.scale * (self.mtm.measured[:3, 3]
                                                           - self.mtm_initial[:3, 3])
        T[:3, :3] = self.mtm.measured[:3, :3] @ self.offset
        stamp = self.mtm.stamp()
        self.psm.servo_cp_pub.publish(cv.pose_stamped(T, '', stamp))
        jaw = np.clip(self.mtm.gripper * 80.0 / 60.0, np.radians(-20), np.radians(80))
        self.psm.jaw_pub.publish(cv.joint_state(['jaw'], stamp, position=[jaw]))
        self.sent += 1

    def stop(self):
        self.timer.cancel()
        self.psm.hold_pub.publish(Empty())


@pytest.fixture
def client_graph(ros, launch):
    sim = launch('simulator', '--ros-args', '-p', 'footpedals:=false')
    mtms = launch('mtms', '--ros-args', '-p', 'device:=browser')
    node = ros.node('teleop_python')
    watch = SceneWatch(node, teleops=())
    operator = BrowserOperator(node)
    mtm, psm = CrtkArm(node, 'MTMR', mtm=True), CrtkArm(node, 'PSM1')
    clutch = JoystickButton(node, '/footpedals/clutch')
    coag = JoystickButton(node, '/footpedals/coag')
    assert wait_for(lambda: watch.ready() and operator.connected(), timeout=60), \
        sim.log() + mtms.log()
    operator.handles['MTMR'] = watch.world('PSM1')
    operator.handles['MTML'] = np.eye(4)
    stream(operator, 0.2)
    yield node, operator, mtm, psm, clutch, coag, watch, (sim, mtms)


def angle_between(T_a, T_b):
    """The angle (rad) of the rotation between two poses' orientations."""
    cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return math.acos(max(-1.0, min(1.0, cos)))


def test_a_dvrk_python_style_client_teleoperates_psm1_through_the_virtual_mtms(client_graph):
    node, op, mtm, psm, clutch, coag, watch, procs = client_graph
    # arms: enable and home, waiting on the operating_state events the commands cause
    psm.enable_and_home()
    mtm.enable_and_home()
    assert wait_for(lambda: mtm.measured is not None and psm.setpoint is not None, timeout=10)
    # alignment: the MTM's wrist turns to the PSM's orientation (busy pulse, then there)
    goal = mtm.measured.copy()
    goal[:3, :3] = psm.setpoint[:3, :3]
    mtm.move_cp(goal)
    # there as a physical MTM gets there: within its wrist's tracking error (0.5 deg RMS at the
    # virtual MTMs' dvrk preset), never exactly
    assert wait_for(lambda: angle_between(mtm.measured, goal) < math.radians(2.5), timeout=5)
    time.sleep(0.7)                                   # the move has ended
    aligned = mtm.measured.copy()
    # lock_orientation: turning the handle leaves the MTM's orientation where it is
    mtm.lock_orientation(aligned[:3, :3])
    turned = op.handles['MTMR'].copy()
    turned[:3, :3] = rotation_from_rotvec([0.0, 0.0, 0.5]) @ turned[:3, :3]
    op.handles['MTMR'] = turned
    stream(op, 0.5)
    assert angle_between(mtm.measured, aligned) < math.radians(0.2)   # encoder noise only
    # the operator presses coag (a Joy button from the virtual console)
    op.coag = True
    assert wait_for(lambda: (op.publish(), coag.value)[1] == 1, timeout=10)
    assert wait_for(lambda: mtm.gripper is not None, timeout=5)
    teleop = PythonStyleTeleop(node, mtm, psm)
    teleop.start()
    start_psm = psm.setpoint.copy()
    d = np.array([0.0, 0.02, -0.01])

    def during(s):
        op.handles['MTMR'] = op.handles['MTMR'].copy()
        op.handles['MTMR'][:3, 3] = turned[:3, 3] + min(1.0, 1.25 * s) * d
    op.grippers['MTMR'] = 0.9
    stream(op, 1.5, during=during)
    stream(op, 0.8)
    moved = psm.setpoint[:3, 3] - start_psm[:3, 3]
    # the Python client maps MTM translation into the PSM's frame as is: both are the camera's
    # (the console's display frame, the patient cart's ECM), so the hand's motion seen from the
    # camera is the tool's
    assert mtm.frame == 'HRSV' and psm.frame == 'ECM'
    R_camera_world = watch.camera()[:3, :3].T
    np.testing.assert_allclose(moved, 0.2 * R_camera_world @ d, atol=0.001)
    assert psm.jaw == pytest.approx(0.9 * 80 / 60, abs=0.02)
    # the clutch pedal: the client stops and holds
    op.clutch = True
    assert wait_for(lambda: (op.publish(), clutch.value)[1] == 1, timeout=10)
    teleop.stop()
    assert teleop.sent >= 10    # a 5 ms timer; its achieved rate depends on the machine's load
