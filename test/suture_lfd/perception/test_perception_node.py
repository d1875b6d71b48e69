"""
The perception node over ROS: the simulator's stereo pair in, the needle's pose out.

Real processes on the private domain: ``simulator`` (rendering the ECM's pair) and
``perception``; the test compares the node's needle pose with the simulator's ground truth
(``sim/needle/measured_cp`` carried into the left camera's optical frame) while PSM2 picks the
needle up and carries it, and feeds a second perception node bad images.
"""

import json

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState
from sim_bridge.common.geometry import invert_transform
from sim_bridge.kinematics import psm_kinematics
from sim_bridge.ros import conversions as cv
from sim_bridge.scene.camera import StereoCamera
from sim_bridge.scene.scene_config import load_scene_config
from sim_bridge.simulation import load_simulation_config
from std_msgs.msg import String
from suture_lfd.perception.evaluation import needle_errors

LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STREAM = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
IMAGES = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)


def grasp_pose(T_world_base, T_world_needle):
    """World tool pose grasping the needle a third from its tail, with the smallest wrist."""
    chain, needle = psm_kinematics(), load_scene_config().needle
    T_base_world = invert_transform(T_world_base)
    best, best_cost = None, np.inf
    for flip in (False, True):
        for roll in np.radians(np.arange(-180.0, 180.0, 15.0)):
            T_tool = T_world_needle @ invert_transform(needle.grasp_transform(roll=roll,
                                                                               flip=flip))
            Q, ok = chain.ik_batch((T_base_world @ T_tool)[None])
            if ok[0] and np.abs(Q[0, 4:]).max() < best_cost:
                best, best_cost = T_tool, np.abs(Q[0, 4:]).max()
    return best


def test_the_node_publishes_the_needle_within_bounds_while_psm2_carries_it(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS, '-p', 'camera_rate:=4.0',
                 '-p', 'visualization_rate:=0.0')
    node_proc = launch('perception', '--ros-args', '-p', 'rate:=4.0')
    node = ros.node('perception_probe')
    got = {'seen': [], 'status': [], 'truth': [], 'ecm': None, 'states': []}
    node.create_subscription(PoseStamped, '/perception/needle/measured_cp',
                             lambda m: got['seen'].append(m), STREAM)
    node.create_subscription(String, '/perception/needle/status',
                             lambda m: got['status'].append(json.loads(m.data)), STREAM)
    node.create_subscription(PoseStamped, '/sim/needle/measured_cp',
                             lambda m: got['truth'].append(m), STREAM)
    node.create_subscription(PoseStamped, '/ECM/measured_cp',
                             lambda m: got.__setitem__('ecm', m), STREAM)
    bases = {}
    for arm in ('ECM', 'PSM2'):
        node.create_subscription(PoseStamped, f'/sim/{arm}/base_frame',
                                 lambda m, a=arm: bases.__setitem__(a, m), LATCHED)
    node.create_subscription(OperatingState, '/PSM2/operating_state',
                             lambda m: got['states'].append(m), STREAM)
    state = node.create_publisher(StringStamped, '/PSM2/state_command', STREAM)
    move_cp = node.create_publisher(PoseStamped, '/PSM2/move_cp', STREAM)
    jaw = node.create_publisher(JointState, '/PSM2/jaw/move_jp', STREAM)
    camera = StereoCamera(load_simulation_config().camera)
    geometry = load_scene_config().needle

    def truth_at(stamp):
        """The true needle (left optical frame) at a pair's stamp."""
        T_world_ecm = cv.matrix_from_pose(got['ecm'].pose)  # a patient cart's: in world
        if got['ecm'].header.frame_id == 'ECM_base':  # an arm on a table's
            T_world_ecm = cv.matrix_from_pose(bases['ECM'].pose) @ T_world_ecm
        T_left = invert_transform(T_world_ecm @ camera.T_tip_left)
        ns = cv.nanoseconds_from_stamp(stamp)
        msg = min(got['truth'], key=lambda m: abs(cv.nanoseconds_from_stamp(m.header.stamp)
                                                  - ns))
        return T_left @ cv.matrix_from_pose(msg.pose)

    def errors(msg):
        return needle_errors(cv.matrix_from_pose(msg.pose), truth_at(msg.header.stamp),
                             geometry)

    assert ros.wait_for(lambda: got['seen'] and got['ecm'] and len(bases) == 2, 90.0), (
        sim.log() + node_proc.log() + str(got['status'][-3:]))
    assert got['ecm'].header.frame_id in ('world', 'ECM_base')
    first = got['seen'][-1]
    assert first.header.frame_id == 'ECM_left_optical'
    total, largest, _ = errors(first)
    assert largest < 0.003 and total < 0.005, (total, largest)  # lying free, detected

    # PSM2 picks the needle up and lifts it 15 mm; perception follows it
    T_world_base = cv.matrix_from_pose(bases['PSM2'].pose)
    T_grasp = grasp_pose(T_world_base, cv.matrix_from_pose(got['truth'][-1].pose))
    T_base_world = invert_transform(T_world_base)

    def send(pub, msg):
        pub.publish(msg)

    assert ros.wait_for(lambda: all(p.get_subscription_count() for p in (state, move_cp, jaw)),
                        20.0)
    send(state, StringStamped(string='enable'))
    assert ros.wait_for(lambda: got['states'] and got['states'][-1].state == 'ENABLED', 20.0)
    send(state, StringStamped(string='home'))
    assert ros.wait_for(lambda: got['states'][-1].is_homed and not got['states'][-1].is_busy,
                        20.0)
    above = T_grasp.copy()
    above[2, 3] += 0.01
    z0 = cv.matrix_from_pose(got['truth'][-1].pose)[2, 3]

    def step(pub, msg, settle=1.0):
        """Send a command, let it finish, and wait for perception to see two more pairs."""
        send(pub, msg)
        ros.wait_for(lambda: False, settle)
        k = len(got['status'])
        assert ros.wait_for(lambda: len(got['status']) >= k + 2, 30.0), node_proc.log()

    step(jaw, JointState(position=[0.8]))
    step(move_cp, _pose(T_base_world @ above), 2.0)
    step(move_cp, _pose(T_base_world @ T_grasp), 2.0)
    step(jaw, JointState(position=[-0.3]))
    for k in range(1, 6):  # lifted 3 mm at a time
        lifted = T_grasp.copy()
        lifted[2, 3] += 0.003 * k
        step(move_cp, _pose(T_base_world @ lifted))
    assert cv.matrix_from_pose(got['truth'][-1].pose)[2, 3] - z0 > 0.012, sim.log()
    n = len(got['seen'])  # while PSM2 holds the needle up
    assert ros.wait_for(lambda: len(got['seen']) >= n + 3, 60.0), (
        node_proc.log() + str([(s['found'], s['tracked'], s['reason'][:30])
                               for s in got['status']]))
    carried = [errors(m) for m in got['seen'][n:]]
    largest = max(e[1] for e in carried)
    assert largest < 0.003, carried  # while PSM2 carries it: no point more than 3 mm off
    assert np.median([e[0] for e in carried]) < 0.004, carried
    assert node_proc.running()


def test_bad_images_get_a_clear_error_and_the_node_goes_on(ros, launch):
    proc = launch('perception', '--ros-args', '-p', 'camera:=BAD', '-p', 'rate:=20.0')
    node = ros.node('perception_bad_images')
    status = []
    node.create_subscription(String, '/perception/needle/status',
                             lambda m: status.append(json.loads(m.data)), STREAM)
    images = {s: node.create_publisher(Image, f'/BAD/{s}/image_raw', IMAGES)
              for s in ('left', 'right')}
    infos = {s: node.create_publisher(CameraInfo, f'/BAD/{s}/camera_info', IMAGES)
             for s in ('left', 'right')}
    assert ros.wait_for(lambda: all(p.get_subscription_count() for p in
                                    (*images.values(), *infos.values())), 60.0), proc.log()
    camera = StereoCamera(load_simulation_config().camera)
    grey = np.full((480, 640, 3), 90, np.uint8)

    def send(rgb, k, encoding='rgb8'):
        stamp = cv.stamp_from_nanoseconds(1_000_000 * k)
        for side in ('left', 'right'):
            infos[side].publish(cv.camera_info_message(camera.camera_info(side),
                                                       f'BAD_{side}_optical', stamp))
            msg = cv.image_message(rgb, f'BAD_{side}_optical', stamp)
            msg.encoding = encoding
            images[side].publish(msg)

    send(grey[::2, ::2], 1)
    assert ros.wait_for(lambda: any('camera_info says 640x480' in s.get('error', '')
                                    for s in status), 20.0), proc.log()
    send(grey, 2, encoding='mono16')
    assert ros.wait_for(lambda: any("encoding 'mono16' is not supported" in s.get('error', '')
                                    for s in status), 20.0), proc.log()
    send(grey, 3)  # a good pair (nothing in it): answered, no error
    assert ros.wait_for(lambda: 'error' not in status[-1] and not status[-1]['found'], 20.0)
    assert proc.running()
    assert 'stereo pair refused' in proc.log()


def _pose(T):
    """A Cartesian goal in PSM2's base (RCM) frame."""
    msg = PoseStamped()
    msg.header.frame_id = 'PSM2_base'
    msg.pose = cv.pose_from_matrix(T)
    return msg
