"""
The simulator as a patient cart shows it, over DDS: PSM poses in the live ECM camera frame.

A real simulator process and a client on loopback: moving the ECM moves every PSM's
``measured_cp`` as the camera frame predicts and leaves ``local/measured_cp`` where it was; a
``servo_cp`` goal in the camera frame reaches the same tool pose as its ``local`` equivalent; the
set-up joints' topics place the arms' bases; ``frames:=base`` keeps each arm in its own base.
"""

import threading
import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from sim_bridge.common.geometry import invert_transform
from sim_bridge.ros import conversions as cv

STREAM = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
COMMAND = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
POSES = ('PSM1/measured_cp', 'PSM1/local/measured_cp', 'PSM1/setpoint_cp',
         'PSM1/local/setpoint_cp', 'ECM/measured_cp', 'SUJ/PSM1/measured_cp',
         'SUJ/PSM1/local/measured_cp', 'SUJ/ECM/measured_cp', 'sim/PSM1/base_frame',
         'sim/ECM/base_frame')


class Cart:
    """A client of PSM1 and the ECM: newest poses (with frame ids), joints, states."""

    def __init__(self, ros):
        self.ros = ros
        self.node = node = ros.node('cart_client')
        self.lock = threading.Lock()
        self.poses, self.frames, self.js, self.state = {}, {}, {}, {}
        for topic in POSES:
            qos = LATCHED if topic.startswith('sim/') else STREAM
            node.create_subscription(PoseStamped, f'/{topic}',
                                     lambda m, t=topic: self._on_pose(t, m), qos)
        for arm in ('PSM1', 'ECM', 'SUJ/PSM1'):
            node.create_subscription(JointState, f'/{arm}/measured_js',
                                     lambda m, a=arm: self.js.__setitem__(a, m), STREAM)
        self.pubs = {}
        for arm in ('PSM1', 'ECM'):
            node.create_subscription(OperatingState, f'/{arm}/operating_state',
                                     lambda m, a=arm: self.state.__setitem__(a, m), STREAM)
            self.pubs[(arm, 'state_command')] = node.create_publisher(
                StringStamped, f'/{arm}/state_command', COMMAND)
            self.pubs[(arm, 'move_jp')] = node.create_publisher(JointState, f'/{arm}/move_jp',
                                                                COMMAND)
        self.pubs[('PSM1', 'servo_cp')] = node.create_publisher(PoseStamped, '/PSM1/servo_cp',
                                                                COMMAND)

    def _on_pose(self, topic, msg):
        with self.lock:
            self.poses[topic] = cv.matrix_from_pose(msg.pose)
            self.frames[topic] = msg.header.frame_id

    def pose(self, topic):
        with self.lock:
            return self.poses[topic].copy()

    def has(self, *topics):
        with self.lock:
            return all(t in self.poses for t in topics)

    def connected(self):
        return all(p.get_subscription_count() for p in self.pubs.values()) and 'ECM' in self.js

    def ready(self):
        """Enable and home PSM1 and the ECM (the simulator's fast start-up)."""
        def homed():
            return all(a in self.state and self.state[a].state == 'ENABLED'
                       and self.state[a].is_homed and not self.state[a].is_busy
                       for a in ('PSM1', 'ECM'))
        for command in ('enable', 'home'):
            for arm in ('PSM1', 'ECM'):
                self.pubs[(arm, 'state_command')].publish(StringStamped(string=command))
            time.sleep(0.3)
        assert self.ros.wait_for(homed, 20.0), self.state

    def send(self, arm, topic, msg):
        self.pubs[(arm, topic)].publish(msg)

    def settled(self, arm, q, tol=1e-6):
        """Wait until the arm's measured joints are at ``q``, then a few state periods more."""
        def there():
            js = self.js.get(arm)
            return js is not None and np.allclose(js.position, q, atol=tol)
        assert self.ros.wait_for(there, 20.0), (arm, self.js.get(arm))
        time.sleep(0.2)


def joints(q):
    return JointState(position=[float(v) for v in q])


def pose_msg(T, frame):
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose = cv.pose_from_matrix(T)
    return msg


def test_moving_the_ecm_moves_psm_poses_as_the_camera_frame_predicts(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    cart = Cart(ros)
    assert ros.wait_for(lambda: cart.connected() and cart.has(*POSES), 40.0), sim.log()
    cart.ready()
    assert cart.frames['PSM1/measured_cp'] == 'ECM'
    assert cart.frames['PSM1/local/measured_cp'] == 'PSM1_base'
    assert cart.frames['ECM/measured_cp'] == 'world'
    # the set-up joints' topics place the bases (no set-up joints to move: no joint values)
    for arm in ('PSM1', 'ECM'):
        np.testing.assert_allclose(cart.pose(f'SUJ/{arm}/measured_cp'),
                                   cart.pose(f'sim/{arm}/base_frame'), atol=1e-12)
        assert cart.frames[f'SUJ/{arm}/measured_cp'] == 'world'
    np.testing.assert_allclose(cart.pose('SUJ/PSM1/local/measured_cp'),
                               cart.pose('sim/PSM1/base_frame'), atol=1e-12)
    assert list(cart.js['SUJ/PSM1'].position) == []

    psm_q = np.array(cart.js['PSM1'].position)
    ecm_q = np.array(cart.js['ECM'].position)
    cart.settled('ECM', ecm_q)
    before = {t: cart.pose(t) for t in ('PSM1/measured_cp', 'PSM1/local/measured_cp',
                                        'ECM/measured_cp')}
    goal = ecm_q + np.array([0.10, 0.05, 0.0, 0.0])  # yaw and pitch, as in the issue
    cart.send('ECM', 'move_jp', joints(goal))
    cart.settled('ECM', goal)
    cart.settled('PSM1', psm_q)
    after = {t: cart.pose(t) for t in before}
    # local/measured_cp: unchanged, the PSM did not move
    np.testing.assert_allclose(after['PSM1/local/measured_cp'],
                               before['PSM1/local/measured_cp'], atol=1e-12)
    # measured_cp: the same tool seen from the moved camera
    predicted = invert_transform(after['ECM/measured_cp']) @ before['ECM/measured_cp'] \
        @ before['PSM1/measured_cp']
    moved = np.linalg.norm(after['PSM1/measured_cp'][:3, 3] - before['PSM1/measured_cp'][:3, 3])
    assert moved > 0.005, moved
    assert np.linalg.norm(after['PSM1/measured_cp'][:3, 3] - predicted[:3, 3]) < 1e-4
    np.testing.assert_allclose(after['PSM1/measured_cp'][:3, :3], predicted[:3, :3], atol=1e-6)
    # and it is measured_cp = T_camera_base @ local/measured_cp, from the cart's own topics
    T_camera_base = invert_transform(after['ECM/measured_cp']) @ cart.pose('SUJ/PSM1/measured_cp')
    np.testing.assert_allclose(after['PSM1/measured_cp'],
                               T_camera_base @ after['PSM1/local/measured_cp'], atol=1e-9)

    # a servo_cp goal in the camera frame reaches the same tool pose as its local equivalent
    local_goal = after['PSM1/local/measured_cp']
    local_goal[:3, 3] += (0.004, -0.003, -0.005)
    reached = {}
    for frame, goal_in_frame in (('', T_camera_base @ local_goal),
                                 ('PSM1_base', local_goal)):
        cart.send('PSM1', 'move_jp', joints(psm_q))
        cart.settled('PSM1', psm_q)
        for _ in range(20):
            cart.send('PSM1', 'servo_cp', pose_msg(goal_in_frame, frame))
            time.sleep(0.01)
        assert ros.wait_for(lambda: np.allclose(cart.pose('PSM1/local/setpoint_cp'),
                                                local_goal, atol=1e-9), 10.0), frame
        assert ros.wait_for(lambda: np.allclose(cart.pose('PSM1/local/measured_cp'),
                                                local_goal, atol=1e-6), 10.0), frame
        time.sleep(0.2)
        reached[frame] = (cart.pose('PSM1/local/measured_cp'), cart.pose('PSM1/measured_cp'))
    np.testing.assert_allclose(reached[''][0], reached['PSM1_base'][0], atol=1e-9)
    np.testing.assert_allclose(reached[''][1], reached['PSM1_base'][1], atol=1e-9)
    np.testing.assert_allclose(reached[''][1], T_camera_base @ local_goal, atol=1e-6)


def test_the_base_frames_option_keeps_each_arm_in_its_own_base(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS, '-p', 'frames:=base')
    cart = Cart(ros)
    plain = [t for t in POSES if not t.startswith('SUJ/')]
    assert ros.wait_for(lambda: cart.connected() and cart.has(*plain), 40.0), sim.log()
    cart.ready()
    assert cart.frames['PSM1/measured_cp'] == 'PSM1_base'
    assert cart.frames['ECM/measured_cp'] == 'ECM_base'
    for topic in ('/SUJ/PSM1/measured_cp', '/SUJ/ECM/measured_cp', '/SUJ/PSM1/measured_js'):
        assert not cart.node.get_publishers_info_by_topic(topic), topic  # no set-up joints
    psm_q = np.array(cart.js['PSM1'].position)
    before = cart.pose('PSM1/measured_cp')
    goal = np.array(cart.js['ECM'].position) + np.array([0.10, 0.05, 0.0, 0.0])
    cart.send('ECM', 'move_jp', joints(goal))
    cart.settled('ECM', goal)
    cart.settled('PSM1', psm_q)
    np.testing.assert_allclose(cart.pose('PSM1/measured_cp'), before, atol=1e-12)
    np.testing.assert_allclose(cart.pose('PSM1/measured_cp'),
                               cart.pose('PSM1/local/measured_cp'), atol=1e-12)
