"""Message <-> array conversions: round trips and the validation of incoming commands."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.common import cdr
from sim_bridge.ros import conversions as cv


def random_pose(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    T[:3, 3] = rng.uniform(-0.2, 0.2, 3)
    return T


def test_poses_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(200):
        T = random_pose(rng)
        msg = cv.pose_stamped(T, 'PSM1_base', cv.stamp_from_seconds(12.5))
        assert msg.header.frame_id == 'PSM1_base'
        assert cv.seconds_from_stamp(msg.header.stamp) == 12.5
        np.testing.assert_allclose(cv.matrix_from_pose(msg.pose), T, atol=1e-12)


def test_quaternions_of_published_poses_are_the_rotation_with_w_nonnegative():
    from scipy.spatial.transform import Rotation
    rotations = list(Rotation.random(2000, random_state=3).as_matrix())
    for axis in np.eye(3):  # half turns and near half turns: the sign is decided there
        rotations += [Rotation.from_rotvec(axis * a).as_matrix()
                      for a in (0.0, math.pi / 2, math.pi - 1e-9, math.pi)]
    for R in rotations:
        T = np.eye(4)
        T[:3, :3] = R
        q = np.array(cv.pose_vector(T)[3:])
        assert q[3] >= 0.0
        expected = Rotation.from_matrix(R).as_quat()
        assert q == pytest.approx(expected if q @ expected >= 0.0 else -expected, abs=1e-15)


@pytest.mark.parametrize('q, message', [
    ((0.0, 0.0, 0.0, 0.0), 'not a unit quaternion (norm 0)'),
    ((0.0, 0.0, 0.0, 2.0), 'not a unit quaternion (norm 2)'),
    ((math.nan, 0.0, 0.0, 1.0), 'NaN or infinite'),
])
def test_bad_command_orientations_are_rejected(q, message):
    pose = cv.pose_from_matrix(np.eye(4))
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = q
    with pytest.raises(ValueError, match=message.replace('(', r'\(').replace(')', r'\)')):
        cv.matrix_from_pose(pose, 'servo_cp')


def test_joint_commands_are_checked_for_length_and_finiteness():
    msg = cv.joint_state([], cv.stamp_from_seconds(0), position=[0, 0, 0.1, 0, 0, 0])
    np.testing.assert_array_equal(cv.positions_from_joint_state(msg, 6), [0, 0, 0.1, 0, 0, 0])
    with pytest.raises(ValueError, match='expected 6 joint positions, got 5'):
        cv.positions_from_joint_state(cv.joint_state([], msg.header.stamp, [0] * 5), 6)
    with pytest.raises(ValueError, match='must be finite'):
        cv.positions_from_joint_state(
            cv.joint_state([], msg.header.stamp, [0, 0, math.inf, 0, 0, 0]), 6)


def test_jacobian_layout_matches_the_dvrk_client_reshape():
    J = np.arange(36.0).reshape(6, 6)[:, :5]
    msg = cv.jacobian_array(J)
    rows, cols = msg.layout.dim[0].size, msg.layout.dim[1].size
    np.testing.assert_array_equal(np.array(msg.data).reshape(rows, cols), J)


def test_events_carry_json_and_sim_time():
    msg = cv.event_message('entry', cv.stamp_from_seconds(3.25), point=np.array([1.0, 2.0, 3.0]),
                           distance_to_marker=np.float64(0.001), bad=math.nan)
    t, data = cv.event_from_message(msg)
    assert t == 3.25
    assert data == {'kind': 'entry', 'point': [1.0, 2.0, 3.0], 'distance_to_marker': 0.001,
                    'bad': None}
    msg.string = 'not json'
    with pytest.raises(ValueError, match='not a JSON object'):
        cv.event_from_message(msg)


# --- CDR bytes the simulator publishes ---------------------------------------------------------
# rclpy reads them back as the message the builder above makes; rosbags (an independent CDR
# implementation, padding zeroed) writes the same bytes for that message.

def _rosbags_bytes(raw, msgtype):
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    return bytes(store.serialize_cdr(store.deserialize_cdr(raw, msgtype), msgtype))


@pytest.mark.parametrize('frame', ['', 'w', 'PSM1_base', 'abcdefg', 'abcdefgh', 'é'])
def test_stamped_pose_twist_and_wrench_bytes_are_the_messages(frame):
    from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
    from rclpy.serialization import deserialize_message
    rng = np.random.default_rng(len(frame))
    for ns in (0, 1, 1_795_417_849_107_387_903, 12_999_999_999):
        stamp = cv.stamp_from_nanoseconds(ns)
        T = random_pose(rng)
        raw = cdr.pose_stamped(ns, frame, cv.pose_vector(T))
        assert deserialize_message(raw, PoseStamped) == cv.pose_stamped(T, frame, stamp)
        assert _rosbags_bytes(raw, 'geometry_msgs/msg/PoseStamped') == raw
        vector = rng.normal(size=7)
        raw = cdr.pose_stamped(ns, frame, vector)
        p, q = (msg := deserialize_message(raw, PoseStamped)).pose.position, msg.pose.orientation
        assert [p.x, p.y, p.z, q.x, q.y, q.z, q.w] == vector.tolist()
        v = rng.normal(size=6)
        raw = cdr.vector6_stamped(ns, frame, v)
        assert deserialize_message(raw, TwistStamped) == cv.twist_stamped(v, frame, stamp)
        assert deserialize_message(raw, WrenchStamped) == cv.wrench_stamped(v, frame, stamp)
        assert _rosbags_bytes(raw, 'geometry_msgs/msg/TwistStamped') == raw


@pytest.mark.parametrize('names', [(), ('jaw',), ('a', 'bc', 'def', 'ghij', 'klmno'),
                                   ('outer_yaw', 'outer_pitch', 'outer_insertion', 'outer_roll',
                                    'outer_wrist_pitch', 'outer_wrist_yaw')])
def test_joint_state_bytes_are_the_message(names):
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    rng = np.random.default_rng(len(names))
    n = len(names)
    for fields in ((rng.normal(size=n), rng.normal(size=n), rng.normal(size=n)),
                   (rng.normal(size=n), (), rng.normal(size=n)),
                   ((), (), np.zeros(n)), ((), (), ())):
        raw = cdr.joint_state(123_456_789_012, names, *fields)
        expected = cv.joint_state(names, cv.stamp_from_nanoseconds(123_456_789_012), *fields)
        assert deserialize_message(raw, JointState) == expected
        assert _rosbags_bytes(raw, 'sensor_msgs/msg/JointState') == raw


@pytest.mark.parametrize('shape', [(6, 4), (6, 6), (6, 7)])
def test_jacobian_bytes_are_the_message(shape):
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64MultiArray
    J = np.random.default_rng(shape[1]).normal(size=shape)
    raw = cdr.jacobian_array(J)
    assert deserialize_message(raw, Float64MultiArray) == cv.jacobian_array(J)
    assert _rosbags_bytes(raw, 'std_msgs/msg/Float64MultiArray') == raw
