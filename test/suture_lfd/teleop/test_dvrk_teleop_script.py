"""
The dVRK's own teleoperation script's way of working, against ``simulator`` + ``mtms``.

A client written the way jhu-dvrk/dvrk_python ``scripts/dvrk_teleoperation.py`` works (not its
code): its node is created and the latched ``state_command`` of both arms sent at once, without
waiting for a connection (``enable``, then ``home`` once enabled, 10 s each); a 5 ms loop whose
getters raise ``TimeoutError`` on data older than four periods (20 ms); the MTM's wrist aligned
with ``move_cp``; following once the operator is present (coag) and active (a pinch), with
plain pose arithmetic between the MTM's ``measured_cp`` and the PSM's ``setpoint_cp`` (scale
0.2, ``R_goal = R_mtm (R_mtm0^-1 R_psm0)``), no frame conversion; the clutch locks the MTM's
orientation and holds the PSM, and its release aligns again (no ``unlock_orientation`` is ever
sent). Both nodes run with their default configuration; the operator is the viewer's browser
input (``viewer/input/*``) moved by the test.
"""

import math
import threading
import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped, Quaternion, WrenchStamped
from harness import wait_for
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState, Joy
from sim_bridge.geometry import quaternion_from_matrix
from sim_bridge.ros import conversions as cv
from std_msgs.msg import Bool, Empty
from teleop_rig import BrowserOperator, SceneWatch, stream

PERIOD = 0.005            # the script's default interval
MAX_AGE = 4 * PERIOD      # crtk: data older than this raises
SCALE = 0.2
RUN_TIME = 60.0
# crtk-py's ROS 2 profiles: depth 10, reliable, volatile; latched adds transient-local
VOLATILE = QoSProfile(depth=10)
LATCH = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
DEG = math.pi / 180.0


class DataAgeError(TimeoutError):
    """What crtk raises for stale data."""


class Stream:
    """The newest message of a topic and when it came (crtk's measured_cp etc.)."""

    def __init__(self):
        self.msg, self.at = None, None

    def put(self, msg):
        self.msg, self.at = msg, time.monotonic()

    def get(self, age=MAX_AGE):
        if self.msg is None or time.monotonic() - self.at > age:
            raise DataAgeError(f'last data received more than {age} seconds ago')
        return self.msg


class Arm:
    """An arm as crtk's utils make it: operating state, getters, commands (no waiting)."""

    def __init__(self, node, name, mtm):
        self.name = name
        self.state = None
        self.states = []
        self.cp = {t: Stream() for t in ('measured_cp', 'setpoint_cp')}
        self.gripper, self.jaw = Stream(), Stream()
        sub, pub = node.create_subscription, node.create_publisher
        sub(OperatingState, f'{name}/operating_state', self._on_state, VOLATILE)
        self.state_command_pub = pub(StringStamped, f'{name}/state_command', LATCH)
        for topic, stream_ in self.cp.items():
            sub(PoseStamped, f'{name}/{topic}', stream_.put, VOLATILE)
        if mtm:
            sub(JointState, f'{name}/gripper/measured_js', self.gripper.put, VOLATILE)
            self.move_cp_pub = pub(PoseStamped, f'{name}/move_cp', VOLATILE)
            self.lock_pub = pub(Quaternion, f'{name}/lock_orientation', LATCH)
            self.gravity_pub = pub(Bool, f'{name}/use_gravity_compensation', LATCH)
            self.servo_cf_pub = pub(WrenchStamped, f'{name}/body/servo_cf', VOLATILE)
        else:
            sub(JointState, f'{name}/jaw/setpoint_js', self.jaw.put, VOLATILE)
            self.servo_cp_pub = pub(PoseStamped, f'{name}/servo_cp', VOLATILE)
            self.jaw_pub = pub(JointState, f'{name}/jaw/servo_jp', VOLATILE)
            self.hold_pub = pub(Empty, f'{name}/hold', VOLATILE)

    def _on_state(self, msg):
        self.state = msg
        self.states.append((time.monotonic(), msg.state, msg.is_homed, msg.is_busy))

    def pose(self, topic):
        return cv.matrix_from_pose(self.cp[topic].get().pose)

    def command(self, what):
        self.state_command_pub.publish(StringStamped(string=what))

    def wait_state(self, done, timeout):
        return wait_for(lambda: self.state is not None and done(self.state), timeout)

    def enabled_and_homed(self):
        s = self.state
        return s is not None and s.state == 'ENABLED' and s.is_homed and not s.is_busy


class Button:
    """crtk's joystick_button: the newest ``buttons[0]`` (volatile subscriber)."""

    def __init__(self, node, topic):
        self.value = 0
        node.create_subscription(Joy, topic, self._on, VOLATILE)

    def _on(self, msg):
        if len(msg.buttons):
            self.value = msg.buttons[0]


class TeleopScript:
    """The script's state machine and loop, run on its own thread at 200 Hz."""

    def __init__(self, node, mtm, psm):
        self.node, self.mtm, self.psm = node, mtm, psm
        self.clutch = Button(node, '/footpedals/clutch')
        self.operator = Button(node, '/footpedals/coag')
        self.state = 'SETTING_ARMS'
        self.errors = []
        self.sent = []            # (time, PSM servo_cp goal) while following
        self.following = False
        self.cycles = 0
        self.gripper_range = [math.inf, -math.inf]
        self.active = False
        self.active_before_clutch = False
        self.move_at = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    # -- the loop ---------------------------------------------------------------------------

    def run(self):
        next_at = time.monotonic()
        while not self.stop.is_set():
            try:
                self.step()
            except DataAgeError as exc:   # the script prints it and stops running
                self.errors.append(str(exc))
                return
            self.cycles += 1
            next_at += PERIOD
            delay = next_at - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_at = time.monotonic()

    def step(self):
        # run_all_states: every getter, every cycle
        self.mtm_cp = self.mtm.pose('measured_cp')
        self.mtm.pose('setpoint_cp')
        self.psm_cp = self.psm.pose('setpoint_cp')
        getattr(self, f'_{self.state.lower()}')()

    # -- states -----------------------------------------------------------------------------

    def _setting_arms(self):
        if self.mtm.enabled_and_homed() and self.psm.enabled_and_homed():
            self.state = 'ALIGNING'
            self.move_at = None

    def _aligning(self):
        now = time.monotonic()
        if not self.clutch.value and (self.move_at is None or now - self.move_at > 10.0):
            goal = self.mtm_cp.copy()
            goal[:3, :3] = self.psm_cp[:3, :3]     # the PSM's orientation, as it is
            self.mtm.move_cp_pub.publish(cv.pose_stamped(goal, '', self.stamp()))
            self.move_at = now
            return
        if self.mtm.state.is_busy or now - self.move_at < 0.05:
            return
        offset = self.mtm_cp[:3, :3].T @ self.psm_cp[:3, :3]
        error = math.acos(max(-1.0, min(1.0, (np.trace(offset) - 1.0) / 2.0)))
        if not self.active:
            g = float(self.mtm.gripper.get(age=0.05).position[0])
            self.gripper_range = [min(self.gripper_range[0], g), max(self.gripper_range[1], g)]
            self.active = self.gripper_range[1] - self.gripper_range[0] >= 5 * DEG
        if error <= 5 * DEG and self.active and self.operator.value == 1:
            self._enter_enabled()

    def _enter_enabled(self):
        self.mtm0, self.psm0 = self.mtm_cp.copy(), self.psm_cp.copy()
        self.offset = self.mtm0[:3, :3].T @ self.psm0[:3, :3]
        self.mtm.gravity_pub.publish(Bool(data=True))
        self.mtm.servo_cf_pub.publish(cv.wrench_stamped(np.zeros(6), '', self.stamp()))
        self.state = 'ENABLED'
        self.following = True

    def _enabled(self):
        if self.clutch.value == 1:
            self.following = False
            self.active_before_clutch = self.active
            x, y, z, w = quaternion_from_matrix(self.mtm_cp[:3, :3]).tolist()
            self.mtm.lock_pub.publish(Quaternion(x=x, y=y, z=z, w=w))
            self.mtm.gravity_pub.publish(Bool(data=True))
            self.psm.hold_pub.publish(Empty())
            self.state = 'CLUTCHED'
            return
        if self.operator.value != 1:
            self.following = False
            self.active = False
            self.state = 'ALIGNING'
            self.move_at = None
            return
        goal = np.eye(4)
        goal[:3, 3] = self.psm0[:3, 3] + SCALE * (self.mtm_cp[:3, 3] - self.mtm0[:3, 3])
        goal[:3, :3] = self.mtm_cp[:3, :3] @ self.offset
        stamp = self.stamp()
        self.psm.servo_cp_pub.publish(cv.pose_stamped(goal, '', stamp))
        self.sent.append((time.monotonic(), goal))
        g = float(self.mtm.gripper.get(age=0.05).position[0])
        jaw = min(80 * DEG, max(-20 * DEG, g * 80.0 / 60.0))
        self.psm.jaw_pub.publish(cv.joint_state(['jaw'], stamp, position=[jaw]))

    def _clutched(self):
        if self.clutch.value != 1:
            self.active = self.active_before_clutch     # back from clutch
            self.state = 'ALIGNING'
            self.move_at = None

    def stamp(self):
        return self.node.get_clock().now().to_msg()


def test_the_dvrk_teleoperation_script_follows_in_the_camera_view_for_a_minute(ros, launch):
    sim = launch('simulator')                                  # the default configuration
    mtms = launch('mtms')
    # the script's node, spun by its own executor as crtk's ral does, and created at once
    node = rclpy.create_node('dvrk_python_teleoperation', context=ros.context)
    executor = SingleThreadedExecutor(context=ros.context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    script = None
    try:
        mtm, psm = Arm(node, 'MTMR', mtm=True), Arm(node, 'PSM1', mtm=False)
        # enable both at once (latched, no wait for connections), then home once enabled
        t0 = time.monotonic()
        mtm.command('enable')
        psm.command('enable')
        for arm in (mtm, psm):
            assert arm.wait_state(lambda s: s.state == 'ENABLED', 10.0), \
                f'failed to enable {arm.name} within 10.0 seconds\n{sim.log()[-2000:]}'
            arm.command('home')
        for arm in (mtm, psm):
            assert arm.wait_state(lambda s: s.is_homed and not s.is_busy, 10.0), \
                f'failed to home {arm.name} within 10.0 seconds'
        ready = time.monotonic() - t0
        assert ready <= 5.0, f'both arms enabled and homed after {ready:.2f} s'

        # the operator at the viewer's input: the hand on PSM1's tool, gripper half open
        op_node = ros.node('operator')
        watch = SceneWatch(op_node, teleops=())
        op = BrowserOperator(op_node)
        assert wait_for(lambda: watch.ready() and op.connected(), timeout=30)
        op.handles['MTMR'] = watch.world('PSM1')
        op.handles['MTML'] = watch.world('PSM2') if 'PSM2' in watch.base else np.eye(4)
        op.grippers['MTMR'] = 0.6
        stream(op, 0.3)
        assert wait_for(lambda: mtm.cp['measured_cp'].msg is not None, 10.0)
        assert mtm.cp['measured_cp'].msg.header.frame_id == 'HRSV'
        assert psm.cp['setpoint_cp'].msg.header.frame_id == 'ECM'

        script = TeleopScript(node, mtm, psm)
        script.thread.start()
        started = time.monotonic()

        def keep(seconds, during=None):
            stream(op, seconds, rate=50.0, during=during)
            assert not script.errors, script.errors

        # aligned, then coag and a pinch: following
        keep(1.0)
        op.coag = True
        keep(0.3)
        for g in (0.8, 0.5, 0.7):
            op.grippers['MTMR'] = g
            keep(0.2)
        deadline = time.monotonic() + 20.0
        while not script.following and time.monotonic() < deadline:
            keep(0.1)
        assert script.following, (script.state, script.active, script.errors)
        keep(0.5)

        right = watch.camera()[:3, 0]                  # image right, in world

        def move_hand(d_world, seconds=1.0):
            start = op.handles['MTMR'][:3, 3].copy()

            def during(s):
                op.handles['MTMR'] = op.handles['MTMR'].copy()
                op.handles['MTMR'][:3, 3] = start + min(1.0, 1.25 * s) * d_world
            keep(seconds, during)

        def tool_in_image():
            return cv.matrix_from_pose(psm.cp['measured_cp'].get(age=0.1).pose)

        # a hand 2 cm right in the camera view: the tool 4 mm right in the ECM image
        for _ in range(2):
            before = tool_in_image()
            move_hand(0.02 * right)
            keep(0.8)
            moved = tool_in_image()[:3, 3] - before[:3, 3]
            assert abs(np.linalg.norm(moved) - 0.004) <= 0.0005, moved
            off = math.degrees(math.acos(min(1.0, moved[0] / np.linalg.norm(moved))))
            assert off <= 3.0, (off, moved)

            # clutch, the hand back 2 cm, release: the tool stays, then follows again
            op.clutch = True
            assert wait_for(lambda: (op.publish(), script.state == 'CLUTCHED')[1], 10.0)
            held = psm.pose('setpoint_cp')
            t_clutch = time.monotonic()
            move_hand(-0.02 * right)
            op.clutch = False
            deadline = time.monotonic() + 15.0
            while not script.following and time.monotonic() < deadline:
                keep(0.1)
            assert script.following, (script.state, script.errors)
            keep(0.5)
            after = [T for t, T in script.sent if t > t_clutch]
            jumps = [np.linalg.norm(T[:3, 3] - held[:3, 3]) for T in after]
            assert jumps and max(jumps) < 0.0005, max(jumps)
            assert np.linalg.norm(psm.pose('setpoint_cp')[:3, 3] - held[:3, 3]) < 0.0005

        # the rest of the minute: small hand motions, following throughout
        k = 0
        while time.monotonic() - started < RUN_TIME:
            move_hand(0.004 * (-1) ** k * right, seconds=0.5)
            k += 1
        assert script.following and script.state == 'ENABLED'
        assert not script.errors, script.errors
        assert sim.running() and mtms.running()
    finally:
        if script is not None:
            script.stop.set()
            script.thread.join(2.0)
        executor.shutdown(timeout_sec=2.0)
        spinner.join(3.0)
        node.destroy_node()
