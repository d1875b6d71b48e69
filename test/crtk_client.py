"""
A dVRK arm client that behaves as the dVRK's own Python client (``crtk`` + ``dvrk`` packages).

Written from what those packages do, for tests of what an unchanged client assumes about timing
and order (facts in the project's dVRK reference, "How a client uses it"):

- every endpoint of ``dvrk.psm`` / ``dvrk.ecm``: subscriptions and publishers RELIABLE, VOLATILE,
  depth 10; ``state_command``, ``trajectory_j/set_ratio``, ``use_gravity_compensation``,
  ``body/set_cf_orientation_absolute`` and ``emulate_tool_present`` latched (TRANSIENT_LOCAL);
  :meth:`ArmClient.check_connections` waits until each one is matched;
- ``operating_state`` is kept only when its stamp is later than the one kept before;
- ``enable(t)`` / ``home(t)`` return at once when the cached state already says so, otherwise
  send the command and wait up to ``t`` s for ENABLED / homed and not busy;
- a getter (``setpoint_jp()``) raises ``TimeoutError('no data received yet')`` before the first
  message and ``TimeoutError`` when the last one is older than ``connection_timeout`` (wall time);
- ``move_*`` take ``start_time = now()`` (the client's clock) just before they publish; the
  handle's ``wait()`` needs a busy operating_state stamped after ``start_time`` followed by an idle
  one (the stamp comparison of crtk 1.3.1, the stricter of the two releases), ``is_busy()`` is
  True until an operating_state stamped after ``start_time`` says otherwise.
"""

import threading
import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from sim_bridge.ros import conversions as cv
from std_msgs.msg import Bool, Empty, Float64, Float64MultiArray

VOLATILE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)

# (topic, type) of dvrk.arm; PSMs add the jaw and emulate_tool_present
SUBSCRIBED = (('operating_state', OperatingState), ('setpoint_js', JointState),
              ('setpoint_cp', PoseStamped), ('measured_js', JointState),
              ('measured_cp', PoseStamped), ('measured_cv', TwistStamped),
              ('trajectory_j/ratio', Float64), ('spatial/measured_cf', WrenchStamped),
              ('spatial/jacobian', Float64MultiArray), ('body/measured_cf', WrenchStamped),
              ('body/jacobian', Float64MultiArray), ('local/measured_cp', PoseStamped),
              ('local/setpoint_cp', PoseStamped))
PUBLISHED = (('state_command', StringStamped, True), ('hold', Empty, False),
             ('free', Empty, False), ('servo_jp', JointState, False),
             ('servo_jr', JointState, False), ('servo_cp', PoseStamped, False),
             ('servo_jf', JointState, False), ('move_jp', JointState, False),
             ('move_jr', JointState, False), ('move_cp', PoseStamped, False),
             ('spatial/servo_cf', WrenchStamped, False), ('body/servo_cf', WrenchStamped, False),
             ('body/set_cf_orientation_absolute', Bool, True),
             ('use_gravity_compensation', Bool, True),
             ('trajectory_j/set_ratio', Float64, True))
JAW_SUBSCRIBED = (('jaw/measured_js', JointState), ('jaw/setpoint_js', JointState))
JAW_PUBLISHED = (('jaw/servo_jp', JointState, False), ('jaw/move_jp', JointState, False),
                 ('jaw/servo_jf', JointState, False), ('emulate_tool_present', Bool, True))


class MoveHandle:
    """What a ``move_*`` returns: ``wait()`` and ``is_busy()`` against its start time."""

    def __init__(self, arm, start_ns):
        self.arm = arm
        self.start_ns = start_ns

    def wait(self, is_busy=False, timeout=30.0):
        """Wait for busy after the start (``is_busy=True``) or for busy then idle; True if seen."""
        def seen():
            after = [busy for stamp, busy in self.arm.busy_history() if stamp > self.start_ns]
            if is_busy:
                return True in after
            return True in after and False in after[after.index(True):]
        return self.arm.wait_state(seen, timeout)

    def is_busy(self, timeout=30.0):
        if self.arm.now_ns() - self.start_ns > timeout * 1e9:
            raise RuntimeWarning('is_busy past timeout')
        state = self.arm.state()
        if state is not None and cv.nanoseconds_from_stamp(state.header.stamp) > self.start_ns:
            return state.is_busy
        return True


class ArmClient:
    """
    One dVRK arm as ``dvrk.psm`` / ``dvrk.ecm`` sees it.

    Parameters
    ----------
    node : rclpy.node.Node
        The client's node, spun by a single-threaded executor (as ``crtk.ral`` does).
    name : str
        Arm name and namespace (``'PSM1'``, ``'ECM'``).
    connection_timeout : float
        Age (s of wall time) past which a getter's data is too old (``dvrk.psm``: 5 s).

    """

    def __init__(self, node, name, connection_timeout=5.0):
        self.node, self.name = node, name
        self.connection_timeout = connection_timeout
        self._cond = threading.Condition()
        self._data = {}  # topic -> (message, wall time received)
        self._state = None
        self._busy = []  # (stamp ns, is_busy) of every operating_state kept
        self.ignored_states = 0  # operating_state messages dropped for a stamp not later
        jaw = name.startswith('PSM')
        self._subs = [node.create_subscription(t, f'{name}/{topic}',
                                               lambda m, k=topic: self._on(k, m), VOLATILE)
                      for topic, t in SUBSCRIBED + (JAW_SUBSCRIBED if jaw else ())]
        self._pubs = {topic: node.create_publisher(t, f'{name}/{topic}',
                                                   LATCHED if latched else VOLATILE)
                      for topic, t, latched in PUBLISHED + (JAW_PUBLISHED if jaw else ())}

    # -- ral ---------------------------------------------------------------------------------

    def now_ns(self):
        return self.node.get_clock().now().nanoseconds

    def check_connections(self, timeout=5.0):
        """Wait until every publisher and subscription has a peer; TimeoutError otherwise."""
        deadline = time.monotonic() + timeout
        while True:
            missing = [f'{self.name}/{t}' for t, p in self._pubs.items()
                       if p.get_subscription_count() == 0]
            missing += [s.topic_name for s in self._subs
                        if self.node.count_publishers(s.topic_name) == 0]
            if not missing:
                return
            if time.monotonic() > deadline:
                raise TimeoutError(f'check_connections: no peer for {missing}')
            time.sleep(0.01)

    # -- subscriptions -----------------------------------------------------------------------

    def _on(self, topic, msg):
        with self._cond:
            if topic == 'operating_state':
                stamp = cv.nanoseconds_from_stamp(msg.header.stamp)
                if self._state is not None and \
                        stamp <= cv.nanoseconds_from_stamp(self._state.header.stamp):
                    self.ignored_states += 1
                    return
                self._state = msg
                self._busy.append((stamp, msg.is_busy))
            self._data[topic] = (msg, time.time())
            self._cond.notify_all()

    def state(self):
        with self._cond:
            return self._state

    def busy_history(self):
        with self._cond:
            return list(self._busy)

    def wait_state(self, predicate, timeout):
        with self._cond:
            return self._cond.wait_for(predicate, timeout)

    def _get(self, topic):
        with self._cond:
            if topic not in self._data:
                raise TimeoutError('no data received yet')
            msg, received = self._data[topic]
        age = time.time() - received
        if age > self.connection_timeout:
            raise TimeoutError(f'last data received more than {self.connection_timeout} '
                               f'seconds ago ({age:.3f} s)')
        return msg

    def setpoint_jp(self):
        msg = self._get('setpoint_js')
        return np.array(msg.position), cv.seconds_from_stamp(msg.header.stamp)

    def measured_jp(self):
        msg = self._get('measured_js')
        return np.array(msg.position), cv.seconds_from_stamp(msg.header.stamp)

    def setpoint_cp(self):
        msg = self._get('setpoint_cp')
        return cv.matrix_from_pose(msg.pose), cv.seconds_from_stamp(msg.header.stamp)

    def measured_cp(self):
        msg = self._get('measured_cp')
        return cv.matrix_from_pose(msg.pose), cv.seconds_from_stamp(msg.header.stamp)

    def local_setpoint_cp(self):
        msg = self._get('local/setpoint_cp')
        return cv.matrix_from_pose(msg.pose), cv.seconds_from_stamp(msg.header.stamp)

    # -- operating state ---------------------------------------------------------------------

    def _state_command(self, command):
        msg = StringStamped(string=command)
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._pubs['state_command'].publish(msg)

    def enable(self, timeout=0.0):
        state = self.state()
        if state is not None and state.state == 'ENABLED':
            self._state_command('enable')
            return True
        self._state_command('enable')
        return self.wait_state(lambda: self._state is not None
                               and self._state.state == 'ENABLED', timeout)

    def home(self, timeout=0.0):
        state = self.state()
        if state is not None and state.is_homed:
            self._state_command('home')
            return True
        self._state_command('home')
        return self.wait_state(lambda: self._state is not None and self._state.is_homed
                               and not self._state.is_busy, timeout)

    # -- commands ----------------------------------------------------------------------------

    def servo_cp(self, T):
        msg = PoseStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.pose = cv.pose_from_matrix(T)
        self._pubs['servo_cp'].publish(msg)

    def move_jp(self, q):
        start = self.now_ns()
        msg = JointState(position=[float(v) for v in q])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._pubs['move_jp'].publish(msg)
        return MoveHandle(self, start)

    def move_cp(self, T):
        start = self.now_ns()
        msg = PoseStamped()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.pose = cv.pose_from_matrix(T)
        self._pubs['move_cp'].publish(msg)
        return MoveHandle(self, start)
