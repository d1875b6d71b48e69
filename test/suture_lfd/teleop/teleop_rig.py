"""
A test-side operator at the viewer's input topics, and an observer of the simulated scene.

Publishes what the viewer page publishes for the browser back-end of the virtual MTMs
(``viewer/input/<MTM>/pose`` in ``world``, ``viewer/input/<MTM>/gripper``,
``viewer/input/pedals`` = ``[clutch, coag]``) and reads the simulator's PSM, ECM and ground
truth topics, over real DDS.
"""

import threading

from crtk_msgs.msg import OperatingState
from geometry_msgs.msg import PoseStamped
from harness import wait_for
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState, Joy
from sim_bridge.ros import conversions as cv
from std_msgs.msg import Float64, String

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATE = QoSProfile(depth=10)


class SceneWatch:
    """Latest PSM/ECM poses (``local/measured_cp``), jaws, states and teleop nodes' states."""

    def __init__(self, node, psms=('PSM1', 'PSM2'), teleops=('MTMR_PSM1',)):
        self.node = node
        self.lock = threading.Lock()
        self.cp, self.base, self.jaw, self.state, self.teleop = {}, {}, {}, {}, {}
        self.history = {a: [] for a in psms}
        for arm in (*psms, 'ECM'):
            # local/measured_cp: in <ARM>_base whatever frame measured_cp is in (patient cart)
            node.create_subscription(PoseStamped, f'{arm}/local/measured_cp',
                                     lambda m, a=arm: self._on_cp(a, m), STATE)
            node.create_subscription(PoseStamped, f'sim/{arm}/base_frame',
                                     lambda m, a=arm: self.base.__setitem__(
                                         a, cv.matrix_from_pose(m.pose)), LATCHED)
        for arm in psms:
            node.create_subscription(JointState, f'{arm}/jaw/measured_js',
                                     lambda m, a=arm: self.jaw.__setitem__(
                                         a, float(m.position[0])), STATE)
            node.create_subscription(OperatingState, f'{arm}/operating_state',
                                     lambda m, a=arm: self.state.__setitem__(a, m), LATCHED)
        for name in teleops:
            node.create_subscription(String, f'/{name}/current_state',
                                     lambda m, n=name: self.teleop.__setitem__(n, m.data),
                                     LATCHED)

    def _on_cp(self, arm, msg):
        T = cv.matrix_from_pose(msg.pose)
        with self.lock:
            self.cp[arm] = T
            if arm in self.history:
                self.history[arm].append((cv.seconds_from_stamp(msg.header.stamp), T))

    def world(self, arm):
        """Return the arm's tool tip in ``world`` (4x4)."""
        with self.lock:
            return self.base[arm] @ self.cp[arm]

    def ready(self):
        return all(a in self.cp and a in self.base for a in ('PSM1', 'ECM'))

    def camera(self):
        """Return ``T_world_camera`` (the ECM tip, optical axes)."""
        return self.world('ECM')


class BrowserOperator:
    """Publishes the viewer's input topics for the virtual MTMs."""

    def __init__(self, node, mtms=('MTMR', 'MTML')):
        self.node = node
        self.pose_pub = {m: node.create_publisher(PoseStamped, f'viewer/input/{m}/pose', STATE)
                         for m in mtms}
        self.gripper_pub = {m: node.create_publisher(Float64, f'viewer/input/{m}/gripper', STATE)
                            for m in mtms}
        self.pedal_pub = node.create_publisher(Joy, 'viewer/input/pedals', STATE)
        self.handles = {}
        self.grippers = dict.fromkeys(mtms, 0.6)
        self.clutch = self.coag = False

    def connected(self):
        return all(p.get_subscription_count() > 0 for p in self.pose_pub.values()) and \
            self.pedal_pub.get_subscription_count() > 0

    def publish(self):
        stamp = self.node.get_clock().now().to_msg()
        for m, T in self.handles.items():
            self.pose_pub[m].publish(cv.pose_stamped(T, 'world', stamp))
        for m, g in self.grippers.items():
            self.gripper_pub[m].publish(Float64(data=float(g)))
        msg = Joy()
        msg.header.stamp = stamp
        msg.buttons = [int(self.clutch), int(self.coag)]
        self.pedal_pub.publish(msg)


def stream(operator, seconds, rate=100.0, during=None):
    """Publish the operator's inputs at ``rate`` for ``seconds`` (``during(s)`` each time)."""
    import time
    n = max(1, int(seconds * rate))
    t0 = time.monotonic()
    for i in range(n):
        if during is not None:
            during(i / n)
        operator.publish()
        delay = t0 + (i + 1) / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)


def wait_teleop(watch, name, state, operator, timeout=60.0):
    """Keep publishing until the teleop node ``name`` is in ``state``."""
    def reached():
        operator.publish()
        return watch.teleop.get(name) == state
    return wait_for(reached, timeout=timeout, period=0.01)


def displacement_in_camera(watch, T_before, T_after):
    """Return the tool displacement (m) between two world poses, in camera axes."""
    R = watch.camera()[:3, :3]
    return R.T @ (np.asarray(T_after)[:3, 3] - np.asarray(T_before)[:3, 3])
