"""
A client that works as the dVRK's teleoperation script does, run as its own process.

Written the way jhu-dvrk/dvrk_python ``scripts/dvrk_teleoperation.py`` works (not its code), for
``test_dvrk_teleop_script.py``: its node is created and the latched ``state_command`` of both arms
sent at once, without waiting for a connection (``enable``, then ``home`` once enabled, 10 s
each); a 5 ms loop whose getters raise ``TimeoutError`` on data older than four periods (20 ms);
the MTM's wrist aligned with ``move_cp``; following once the operator is present (coag) and
active (a pinch), with plain pose arithmetic between the MTM's ``measured_cp`` and the PSM's
``setpoint_cp`` (scale 0.2, ``R_goal = R_mtm (R_mtm0^-1 R_psm0)``), no frame conversion; the
clutch locks the MTM's orientation and holds the PSM, and its release aligns again (no
``unlock_orientation`` is ever sent).

Usage: ``python dvrk_teleop_client.py MTM PSM``. It prints one line per fact the test reads:
``HOMED <seconds>``, ``STATE <state>``, ``FRAMES <mtm frame> <psm frame>``, ``ERROR <text>`` (a
getter's data-age error: the script stops there, this client skips the cycle), ``FAIL <text>``;
it runs until SIGINT.
"""

import gc
import math
import sys
import threading
import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped, Quaternion, WrenchStamped
import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState, Joy
from sim_bridge.common.geometry import quaternion_from_matrix
from sim_bridge.ros import conversions as cv
from std_msgs.msg import Bool, Empty

PERIOD = 0.005            # the script's default interval
MAX_AGE = 4 * PERIOD      # crtk: data older than this raises
SCALE = 0.2
# crtk-py's ROS 2 profiles: depth 10, reliable, volatile; latched adds transient-local
VOLATILE = QoSProfile(depth=10)
LATCH = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
DEG = math.pi / 180.0


class DataAgeError(TimeoutError):
    """What crtk raises for stale data."""


class Stream:
    """The newest message of a topic and when it came (crtk's measured_cp etc.)."""

    def __init__(self, topic):
        self.topic = topic
        self.msg, self.at = None, None

    def put(self, msg):
        self.msg, self.at = msg, time.monotonic()

    def get(self, age=MAX_AGE):
        now = time.monotonic()
        if self.msg is None or now - self.at > age:
            late = 'never' if self.at is None else f'{now - self.at:.4f} s ago'
            raise DataAgeError(f'{self.topic}: last data received more than {age} seconds ago '
                               f'({late})')
        return self.msg


class Arm:
    """An arm as crtk's utils make it: operating state, getters, commands (no waiting)."""

    def __init__(self, node, name, mtm):
        self.name = name
        self.state = None
        self.states = []
        self.cp = {t: Stream(f'{name}/{t}') for t in ('measured_cp', 'setpoint_cp')}
        self.gripper, self.jaw = Stream(f'{name}/gripper'), Stream(f'{name}/jaw')
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
        self.state = None
        self.set_state('ALIGNING')
        self.errors = []
        self.sent = []            # (time, PSM servo_cp goal) while following
        self.following = False
        self.cycles = 0
        self.gripper_range = [math.inf, -math.inf]
        self.roll_range = [math.inf, -math.inf]
        self.frames_said = False
        self.active = False
        self.active_before_clutch = False
        self.move_at = None
        self.stop = threading.Event()

    # -- the loop ---------------------------------------------------------------------------

    def run(self):
        next_at = time.monotonic()
        while not self.stop.is_set():
            try:
                self.step()
            except DataAgeError as exc:
                # the script prints it and stops running; this client says so and goes on, so
                # that a test can tell its other claims apart from the data's age
                self.errors.append(str(exc))
                say('ERROR', exc)
            except ValueError as exc:
                # the script's arithmetic failed (math.acos out of its domain): it stops
                say('FAIL', f'{type(exc).__name__}: {exc}')
                return
            self.cycles += 1
            next_at += PERIOD
            delay = next_at - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_at = time.monotonic()

    def step(self):
        # run_all_states: every getter, every cycle (all of them asked, so that the errors name
        # every stale topic; the first one stops the cycle as it stops the script)
        stale = []
        for arm, topic in ((self.mtm, 'measured_cp'), (self.psm, 'setpoint_cp')):
            try:
                arm.cp[topic].get()
            except DataAgeError as exc:
                stale.append(exc)
        for exc in stale[1:]:
            say('ERROR', exc)
        if stale:
            raise stale[0]
        self.mtm_cp = self.mtm.pose('measured_cp')
        self.psm_cp = self.psm.pose('setpoint_cp')
        if not self.frames_said:
            self.frames_said = True
            say('FRAMES', f"{self.mtm.cp['measured_cp'].msg.header.frame_id} "
                          f"{self.psm.cp['setpoint_cp'].msg.header.frame_id}")
        getattr(self, f'_{self.state.lower()}')()

    # -- states -----------------------------------------------------------------------------

    def _aligning(self):
        now = time.monotonic()
        offset = self.mtm_cp[:3, :3].T @ self.psm_cp[:3, :3]
        error = math.acos(max(-1.0, min(1.0, (np.trace(offset) - 1.0) / 2.0)))  # GetRotAngle
        if self.operator.value == 1:
            g = float(self.mtm.gripper.get().position[0])
            self.gripper_range = [min(self.gripper_range[0], g), max(self.gripper_range[1], g)]
            self.active = self.active or self.gripper_range[1] - self.gripper_range[0] >= 5 * DEG
            # the script's roll: math.acos of the dot product of the two y axes, unclamped (a
            # ValueError there stops the script)
            roll = math.acos(float(np.dot(self.psm_cp[:3, 1], self.mtm_cp[:3, 1])))
            self.roll_range = [min(self.roll_range[0], roll), max(self.roll_range[1], roll)]
        if self.move_at is None or now - self.move_at > 4.0:
            goal = np.eye(4)
            goal[:3, :3] = self.psm_cp[:3, :3]     # the PSM's orientation, as it is, at the
            goal[:3, 3] = self.mtm.pose('setpoint_cp')[:3, 3]   # MTM's setpoint position
            self.mtm.move_cp_pub.publish(cv.pose_stamped(goal, '', self.stamp()))
            self.move_at = now
        if self.clutch.value == 1 and self.active:
            self._enter_clutched()
        elif error <= 5 * DEG and self.active and self.operator.value == 1:
            self._enter_enabled()

    def _enter_enabled(self):
        self.psm.jaw.get()                          # the script reads the jaw's setpoint here
        self.mtm0, self.psm0 = self.mtm_cp.copy(), self.psm_cp.copy()
        self.offset = self.mtm0[:3, :3].T @ self.psm0[:3, :3]
        self.mtm.gravity_pub.publish(Bool(data=True))
        self.mtm.servo_cf_pub.publish(cv.wrench_stamped(np.zeros(6), '', self.stamp()))
        self.set_state('ENABLED')
        self.following = True

    def _enabled(self):
        if self.clutch.value == 1:
            self._enter_clutched()
            return
        if self.operator.value != 1:
            self.following = False
            self.active = False
            self.set_state('ALIGNING')
            self.move_at = None
            return
        goal = np.eye(4)
        goal[:3, 3] = self.psm0[:3, 3] + SCALE * (self.mtm_cp[:3, 3] - self.mtm0[:3, 3])
        goal[:3, :3] = self.mtm_cp[:3, :3] @ self.offset
        stamp = self.stamp()
        self.psm.servo_cp_pub.publish(cv.pose_stamped(goal, '', stamp))
        self.sent.append((time.monotonic(), goal))
        g = float(self.mtm.gripper.get().position[0])
        jaw = min(80 * DEG, max(-20 * DEG, g * 80.0 / 60.0))
        self.psm.jaw_pub.publish(cv.joint_state(['jaw'], stamp, position=[jaw]))

    def _enter_clutched(self):
        self.following = False
        self.active_before_clutch = self.active
        x, y, z, w = quaternion_from_matrix(self.mtm_cp[:3, :3]).tolist()
        self.mtm.lock_pub.publish(Quaternion(x=x, y=y, z=z, w=w))
        self.mtm.gravity_pub.publish(Bool(data=True))
        self.psm.hold_pub.publish(Empty())
        self.set_state('CLUTCHED')

    def _clutched(self):
        if self.clutch.value != 1:
            self.active = self.active_before_clutch     # back from clutch
            self.set_state('ALIGNING')
            self.move_at = None

    def set_state(self, state):
        if state != self.state:
            self.state = state
            say('STATE', state)

    def stamp(self):
        return self.node.get_clock().now().to_msg()




def say(what, text):
    print(what, text, flush=True)


def wait_for(predicate, timeout):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def main(mtm_name, psm_name):
    rclpy.init()
    node = rclpy.create_node('dvrk_python_teleoperation')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    def spin():
        try:
            executor.spin()
        except ExternalShutdownException:   # SIGINT shut the context down: the end
            pass
    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    script = None
    try:
        mtm, psm = Arm(node, mtm_name, mtm=True), Arm(node, psm_name, mtm=False)
        t0 = time.monotonic()
        mtm.command('enable')
        psm.command('enable')
        for arm in (mtm, psm):
            if not wait_for(lambda a=arm: a.state is not None and a.state.state == 'ENABLED',
                            10.0):
                say('FAIL', f'failed to enable {arm.name} within 10.0 seconds')
                return 1
            arm.command('home')
        for arm in (mtm, psm):
            if not wait_for(lambda a=arm: a.state.is_homed and not a.state.is_busy, 10.0):
                say('FAIL', f'failed to home {arm.name} within 10.0 seconds')
                return 1
        say('HOMED', f'{time.monotonic() - t0:.3f}')
        script = TeleopScript(node, mtm, psm)
        gc.freeze()   # what start-up built stays out of the cyclic collector's full passes
        script.run()
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        executor.shutdown(timeout_sec=1.0)
        spinner.join(2.0)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main(*sys.argv[1:3]))
