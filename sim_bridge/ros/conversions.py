"""
Messages <-> arrays: the one place that knows both ROS message fields and array layouts.

Poses are 4x4 homogeneous matrices (metres), quaternions ``(x, y, z, w)``, twists and wrenches
``(6,)`` arrays ``[linear, angular]``, times in seconds. Incoming commands are validated here:
NaN or infinite values, zero or non-unit quaternions raise ``ValueError`` with a message that
says what is wrong, which the nodes forward to the arm's ``error`` topic.
"""

import dataclasses
import importlib
import json
import math

from builtin_interfaces.msg import Time
from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseStamped,
    TransformStamped,
    TwistStamped,
    WrenchStamped,
)
import numpy as np
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from sim_bridge.common.geometry import matrix_from_quaternion, quaternion_from_matrix
from sim_bridge.common.validation import check_quaternions
from std_msgs.msg import ColorRGBA, Float64MultiArray, MultiArrayDimension
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker


def stamp_from_seconds(t):
    """Return a ``builtin_interfaces/Time`` for ``t`` seconds (t >= 0)."""
    ns = int(round(float(t) * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_from_nanoseconds(ns):
    """Return a ``builtin_interfaces/Time`` for ``ns`` integer nanoseconds (ns >= 0)."""
    ns = int(ns)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def clock_message(stamp):
    """Return a ``rosgraph_msgs/Clock`` holding ``stamp``."""
    return Clock(clock=stamp)


def seconds_from_stamp(stamp):
    """Return the seconds of a ``builtin_interfaces/Time``."""
    return stamp.sec + stamp.nanosec * 1e-9


def nanoseconds_from_stamp(stamp):
    """Return the integer nanoseconds of a ``builtin_interfaces/Time``."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def matrix_from_pose(pose, what='pose'):
    """
    Return the 4x4 matrix of a ``geometry_msgs/Pose``.

    Raises
    ------
    ValueError
        If a value is NaN or infinite, or the quaternion is zero or not of unit norm.

    """
    p = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=float)
    q = np.array([pose.orientation.x, pose.orientation.y, pose.orientation.z,
                  pose.orientation.w], dtype=float)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise ValueError(f'{what} has NaN or infinite values (position {p.tolist()}, '
                         f'orientation {q.tolist()})')
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(check_quaternions(q, f'{what} orientation'))
    T[:3, 3] = p
    return T


def vector_from_pose(pose):
    """
    Return ``(x, y, z, qx, qy, qz, qw)`` of a ``geometry_msgs/Pose``, unchecked, shape (7,).

    For commands that the receiver validates itself (``sim_bridge.arm.Arm.servo_cp`` rejects NaN,
    infinite values and non-unit quaternions with an ``error`` event).
    """
    p, q = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=float)


def pose_vector(T):
    """Return ``(x, y, z, qx, qy, qz, qw)`` (floats) of a 4x4 matrix."""
    T = np.asarray(T, dtype=float)
    x, y, z = T[:3, 3].tolist()
    return (x, y, z, *quaternion_from_matrix(T[:3, :3]).tolist())


def pose_from_matrix(T):
    """Return the ``geometry_msgs/Pose`` of a 4x4 matrix."""
    pose = Pose()
    fill_pose(pose, T)
    return pose


def fill_pose(pose, T):
    """Write the position and orientation of a 4x4 matrix into a ``geometry_msgs/Pose``."""
    T = np.asarray(T, dtype=float)
    p, o = pose.position, pose.orientation
    p.x, p.y, p.z = T[:3, 3].tolist()
    o.x, o.y, o.z, o.w = quaternion_from_matrix(T[:3, :3]).tolist()


def pose_stamped(T, frame_id, stamp):
    """Return a ``geometry_msgs/PoseStamped`` of a 4x4 matrix in ``frame_id`` at ``stamp``."""
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.pose = pose_from_matrix(T)
    return msg


def transform_stamped(T, parent, child, stamp):
    """Return a ``geometry_msgs/TransformStamped`` ``parent -> child`` of a 4x4 matrix."""
    T = np.asarray(T, dtype=float)
    msg = TransformStamped()
    msg.header.frame_id = parent
    msg.header.stamp = stamp
    msg.child_frame_id = child
    tr = msg.transform
    tr.translation.x, tr.translation.y, tr.translation.z = T[:3, 3].tolist()
    tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w = quaternion_from_matrix(
        T[:3, :3]).tolist()
    return msg


def matrix_from_transform(transform):
    """Return the 4x4 matrix of a ``geometry_msgs/Transform`` (quaternion normalised)."""
    t, q = transform.translation, transform.rotation
    q = np.array([q.x, q.y, q.z, q.w], dtype=float)
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(q / np.linalg.norm(q))
    T[:3, 3] = (t.x, t.y, t.z)
    return T


def tf_message(transforms):
    """Return a ``tf2_msgs/TFMessage`` of ``TransformStamped`` messages."""
    return TFMessage(transforms=list(transforms))


def _floats(values):
    return np.asarray(values, dtype=float).ravel().tolist()


def joint_state(names, stamp, position=(), velocity=(), effort=()):
    """Return a ``sensor_msgs/JointState`` (frame_id empty, as the dVRK publishes it)."""
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    msg.position = _floats(position)
    msg.velocity = _floats(velocity)
    msg.effort = _floats(effort)
    return msg


def raw_positions(msg):
    """
    Return the ``position`` field of a JointState as a float array, unchecked, shape (k,).

    For commands that the receiver validates itself (``sim_bridge.arm.Arm`` checks length and
    finiteness and reports on its ``error`` event).
    """
    return np.asarray(msg.position, dtype=float)


def raw_efforts(msg):
    """Return the ``effort`` field of a JointState as a float array, unchecked, shape (k,)."""
    return np.asarray(msg.effort, dtype=float)


def positions_from_joint_state(msg, n, what='servo_jp'):
    """
    Return the ``position`` field of a command JointState as an ``(n,)`` array.

    Names are ignored (dVRK clients send none).

    Raises
    ------
    ValueError
        If the vector has the wrong length or holds NaN or infinite values.

    """
    q = np.asarray(msg.position, dtype=float)
    if q.shape != (n,):
        raise ValueError(f'{what}: expected {n} joint positions, got {q.size}')
    if not np.all(np.isfinite(q)):
        raise ValueError(f'{what}: joint positions must be finite, got {q.tolist()}')
    return q


def twist_stamped(v, frame_id, stamp):
    """Return a ``geometry_msgs/TwistStamped`` of a ``(6,)`` twist ``[linear, angular]``."""
    v = np.asarray(v, dtype=float)
    msg = TwistStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    lin, ang = msg.twist.linear, msg.twist.angular
    lin.x, lin.y, lin.z, ang.x, ang.y, ang.z = (float(x) for x in v[:6])
    return msg


def wrench_stamped(w, frame_id, stamp):
    """Return a ``geometry_msgs/WrenchStamped`` of a ``(6,)`` wrench ``[force, torque]``."""
    w = np.asarray(w, dtype=float)
    msg = WrenchStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    f, t = msg.wrench.force, msg.wrench.torque
    f.x, f.y, f.z, t.x, t.y, t.z = (float(x) for x in w[:6])
    return msg


def jacobian_array(J):
    """
    Return a ``std_msgs/Float64MultiArray`` of a ``(6, n)`` Jacobian, as cisst-ros lays it out.

    ``layout.dim[0]`` is ``rows`` (6), ``dim[1]`` is ``cols`` (n); data is row-major, so a client
    reshapes with ``(dim[0].size, dim[1].size)``.
    """
    J = np.asarray(J, dtype=float)
    rows, cols = J.shape
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label='rows', size=rows, stride=rows * cols),
                      MultiArrayDimension(label='cols', size=cols, stride=cols)]
    msg.data = _floats(J)
    return msg


def operating_state(state, is_homed, is_busy, stamp):
    """Return a ``crtk_msgs/OperatingState``."""
    msg = OperatingState(state=state, is_homed=bool(is_homed), is_busy=bool(is_busy))
    msg.header.stamp = stamp
    return msg


def event_message(kind, stamp, **fields):
    """
    Return a simulator event as ``crtk_msgs/StringStamped`` holding one JSON object.

    NumPy arrays and scalars become JSON lists and numbers; NaN becomes ``null``.
    """
    def plain(value):
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return plain({f.name: getattr(value, f.name) for f in dataclasses.fields(value)})
        if isinstance(value, np.ndarray):
            return [plain(v) for v in value.tolist()]
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {str(k): plain(v) for k, v in value.items()}
        if isinstance(value, (np.floating, float)):
            value = float(value)
            return value if math.isfinite(value) else None
        if isinstance(value, np.integer):
            return int(value)
        if isinstance(value, np.bool_):
            return bool(value)
        return value

    msg = StringStamped()
    msg.header.stamp = stamp
    msg.string = json.dumps({'kind': kind, **plain(fields)}, sort_keys=True)
    return msg


def event_from_message(msg):
    """Return ``(t_seconds, dict)`` of a simulator event message."""
    try:
        data = json.loads(msg.string)
    except json.JSONDecodeError as exc:
        raise ValueError(f'event is not a JSON object: {msg.string!r} ({exc})') from exc
    if not isinstance(data, dict) or 'kind' not in data:
        raise ValueError(f'event JSON must be an object with a "kind": {msg.string!r}')
    return seconds_from_stamp(msg.header.stamp), data


def image_message(rgb, frame_id, stamp):
    """
    Return a ``sensor_msgs/Image`` (``rgb8``) of an RGB image.

    Parameters
    ----------
    rgb : ndarray, shape (height, width, 3), uint8
        Colour image, row 0 at the top.
    frame_id : str
        Optical frame of the camera (x right, y down, z forward).
    stamp : builtin_interfaces/Time

    """
    return _image(np.ascontiguousarray(rgb, dtype=np.uint8), 'rgb8', frame_id, stamp)


def _image(array, encoding, frame_id, stamp):
    """Return a ``sensor_msgs/Image`` of a C-contiguous array (rows of ``strides[0]`` bytes)."""
    height, width = array.shape[:2]
    msg = Image()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.height, msg.width = int(height), int(width)
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = int(array.strides[0])
    msg.data = array.tobytes()
    return msg


def depth_message(depth, frame_id, stamp):
    """
    Return a ``sensor_msgs/Image`` (``32FC1``, metres) of a metric depth image.

    Parameters
    ----------
    depth : ndarray, shape (height, width)
        Camera-frame ``z`` (m) per pixel, row 0 at the top; ``inf`` where nothing is seen.
    frame_id : str
        Optical frame of the camera.
    stamp : builtin_interfaces/Time

    """
    return _image(np.ascontiguousarray(depth, dtype='<f4'), '32FC1', frame_id, stamp)


def rgb_from_image(msg, width=None, height=None):
    """
    Return the ``(height, width, 3)`` uint8 RGB array of a ``sensor_msgs/Image``.

    Parameters
    ----------
    msg : sensor_msgs/Image
        ``rgb8`` or ``bgr8``, rows of ``step`` bytes.
    width, height : int, optional
        Size the image must have (its ``camera_info``'s).

    Raises
    ------
    ValueError
        For another encoding, a size other than ``width`` x ``height`` or too little data;
        the message says which.

    """
    if msg.encoding not in ('rgb8', 'bgr8'):
        raise ValueError(f'image encoding {msg.encoding!r} is not supported: send rgb8 or bgr8')
    w, h = int(msg.width), int(msg.height)
    if width is not None and (w, h) != (int(width), int(height)):
        raise ValueError(f'image is {w}x{h} but camera_info says {width}x{height}')
    step = int(msg.step)
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if step < 3 * w or data.size < step * h:
        raise ValueError(f'image data too short: {data.size} bytes for {h} rows of {step} '
                         f'bytes ({w}x{h} {msg.encoding})')
    rgb = data[:step * h].reshape(h, step)[:, :3 * w].reshape(h, w, 3)
    return np.ascontiguousarray(rgb[:, :, ::-1] if msg.encoding == 'bgr8' else rgb)


def camera_info_arrays(msg):
    """
    Return a ``sensor_msgs/CameraInfo``'s size, ``K`` (3, 3), ``P`` (3, 4) and ``D`` as a dict.

    The keys are those of :func:`suture_lfd.perception.stereo.stereo_from_camera_info`:
    ``width``, ``height``, ``K``, ``P``, and ``D``: the ``plumb_bob`` coefficients, shape (5,)
    (zeros when the message has none: a rectified image).
    """
    d = np.zeros(5)
    d[:min(5, len(msg.d))] = np.asarray(msg.d, dtype=float)[:5]
    return {'width': int(msg.width), 'height': int(msg.height),
            'K': np.asarray(msg.k, dtype=float).reshape(3, 3),
            'P': np.asarray(msg.p, dtype=float).reshape(3, 4), 'D': d}


def camera_info_message(info, frame_id, stamp):
    """
    Return a ``sensor_msgs/CameraInfo`` of a :class:`sim_bridge.scene.camera.CameraInfo`.

    ``K`` (3, 3), ``R`` (3, 3) and ``P`` (3, 4) are written row-major as the message wants;
    ``P[0, 3] = -fx * baseline`` (m) for the right camera.
    """
    msg = CameraInfo()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.width, msg.height = int(info.width), int(info.height)
    msg.distortion_model = info.distortion_model
    msg.d = _floats(info.D)
    msg.k = _floats(info.K)
    msg.r = _floats(info.R)
    msg.p = _floats(info.P)
    return msg


def _color(rgba):
    r, g, b, a = (float(v) for v in rgba)
    return ColorRGBA(r=r, g=g, b=b, a=a)


def _points(points):
    return [Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
            for p in np.asarray(points, dtype=float).reshape(-1, 3)]


def line_strip_marker(points, ns, marker_id, frame_id, stamp, rgba, width):
    """
    Return a ``visualization_msgs/Marker`` LINE_STRIP through ``points``.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Vertices (m) in ``frame_id``.
    ns : str
        Marker namespace.
    marker_id : int
    frame_id : str
    stamp : builtin_interfaces/Time
    rgba : sequence of 4 float
        Colour, components in [0, 1].
    width : float
        Line width (m).

    """
    msg = Marker()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.ns, msg.id = ns, int(marker_id)
    msg.type, msg.action = Marker.LINE_STRIP, Marker.ADD
    msg.pose.orientation.w = 1.0
    msg.scale.x = float(width)
    msg.color = _color(rgba)
    msg.points = _points(points)
    return msg


def sphere_list_marker(points, ns, marker_id, frame_id, stamp, rgba, diameter):
    """
    Return a ``visualization_msgs/Marker`` SPHERE_LIST, one sphere per point.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Sphere centres (m) in ``frame_id``.
    ns : str
    marker_id : int
    frame_id : str
    stamp : builtin_interfaces/Time
    rgba : sequence of 4 float
    diameter : float
        Sphere diameter (m).

    """
    msg = Marker()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    msg.ns, msg.id = ns, int(marker_id)
    msg.type, msg.action = Marker.SPHERE_LIST, Marker.ADD
    msg.pose.orientation.w = 1.0
    msg.scale.x = msg.scale.y = msg.scale.z = float(diameter)
    msg.color = _color(rgba)
    msg.points = _points(points)
    return msg


def message_class(msgtype):
    """Return the rclpy message class of ``'pkg/msg/Name'``."""
    pkg, _, name = msgtype.partition('/msg/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f'message type {msgtype!r} is not installed ({exc})') from exc
