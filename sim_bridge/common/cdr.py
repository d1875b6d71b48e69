"""
CDR encoding and decoding of the message layouts the simulator publishes and bags store.

Encoders build the bytes of the published layouts; lean readers (at the end) decode the two
layouts a demonstration bag is made of.

The simulator publishes ~40 state messages per 10 ms; building a message object and having rclpy
convert it costs ~10-40 us each, while the bytes of these layouts follow from the CDR rules
(little-endian XCDR1, as Fast DDS and rosbag2 use it: a 4-byte encapsulation header, then each
primitive aligned to its size relative to the body after that header, padding zeroed). An rclpy
publisher sends such bytes as they are (``Publisher.publish(bytes)``); a rosbag2 writer stores
them. Field meanings and array layouts are those of :mod:`sim_bridge.ros.conversions`, whose
message builders make the same messages (the tests read these bytes back with rclpy and write them
again with rosbags). No ROS imports: bag writing runs without ROS.
"""

import functools
import struct

import numpy as np

_CDR_LE = b'\x00\x01\x00\x00'
_HEADER = struct.Struct('<iII')          # stamp sec, nanosec, frame_id length (with its NUL)
_U32 = struct.Struct('<I')
_POSE7 = struct.Struct('<7d')
_VECTOR6 = struct.Struct('<6d')
_NS = 1_000_000_000


@functools.lru_cache(maxsize=256)
def _frame_tail(frame_id, alignment):
    """Return the frame_id's CDR string length (with NUL) and bytes padded to ``alignment``."""
    frame = frame_id.encode('utf-8') + b'\x00'
    used = 12 + len(frame)               # body bytes after stamp + length + string
    return len(frame), frame + bytes(-used % alignment)


def _cdr_header(ns, frame_id, alignment):
    """Return the encapsulation and a Header of stamp ``ns`` (int), padded to ``alignment``."""
    length, tail = _frame_tail(frame_id, alignment)
    return _CDR_LE + _HEADER.pack(ns // _NS, ns % _NS, length) + tail


def pose_stamped(ns, frame_id, pose):
    """
    Return the CDR bytes of a ``geometry_msgs/PoseStamped``.

    Parameters
    ----------
    ns : int
        Header stamp (integer nanoseconds, >= 0).
    frame_id : str
    pose : sequence of 7 float
        ``(x, y, z, qx, qy, qz, qw)``, written as given
        (:func:`sim_bridge.ros.conversions.pose_vector` of a matrix).

    """
    return _cdr_header(ns, frame_id, 8) + _POSE7.pack(*pose)


def vector6_stamped(ns, frame_id, v):
    """
    Return the CDR bytes of a ``geometry_msgs/TwistStamped`` or ``WrenchStamped``.

    Both are a Header and two Vector3 (``[linear, angular]`` or ``[force, torque]``), the same
    bytes; ``v`` is the ``(6,)`` array.
    """
    return _cdr_header(ns, frame_id, 8) + _VECTOR6.pack(*np.asarray(v, dtype=float).tolist())


@functools.lru_cache(maxsize=64)
def string_sequence(names):
    """Return the CDR bytes of a ``string[]`` (tuple of str), from a 4-byte aligned offset."""
    out = bytearray(_U32.pack(len(names)))
    for name in names:
        out += bytes(-len(out) % 4)
        text = name.encode('utf-8') + b'\x00'
        out += _U32.pack(len(text)) + text
    return bytes(out)


def _append_doubles(out, values):
    """Append a ``float64[]`` to ``out`` (a CDR body without its 4-byte header)."""
    out += bytes(-len(out) % 4)
    out += _U32.pack(len(values))
    if len(values):
        out += bytes(-len(out) % 8)
        out += struct.pack(f'<{len(values)}d', *values)


def joint_state(ns, names, position=(), velocity=(), effort=()):
    """
    Return the CDR bytes of a ``sensor_msgs/JointState`` (frame_id empty, as the dVRK's).

    Parameters
    ----------
    ns : int
        Header stamp (integer nanoseconds, >= 0).
    names : tuple of str
    position, velocity, effort : sequence of float

    """
    body = bytearray(_cdr_header(ns, '', 4)[4:])
    body += string_sequence(tuple(names))
    for values in (position, velocity, effort):
        _append_doubles(body, np.asarray(values, dtype=float).ravel().tolist())
    return _CDR_LE + bytes(body)


def jacobian_array(J):
    """
    Return the CDR bytes of a ``(6, n)`` Jacobian as a ``std_msgs/Float64MultiArray``.

    The layout of :func:`sim_bridge.ros.conversions.jacobian_array` (cisst-ros's).
    """
    J = np.asarray(J, dtype=float)
    rows, cols = J.shape
    body = bytearray(_U32.pack(2))
    for label, size, stride in (('rows', rows, rows * cols), ('cols', cols, cols)):
        body += bytes(-len(body) % 4)
        text = label.encode('utf-8') + b'\x00'
        body += _U32.pack(len(text)) + text
        body += bytes(-len(body) % 4)
        body += _U32.pack(size) + _U32.pack(stride)
    body += _U32.pack(0)                 # data_offset
    _append_doubles(body, J.ravel().tolist())
    return _CDR_LE + bytes(body)


# --- decoding: lean readers for the two message layouts a demonstration is made of ------------
# A demonstration bag holds thousands of PoseStamped and JointState messages; decoding each into a
# message object costs ~40 us, while its few fields sit at offsets the CDR rules fix. These read
# just those fields from little-endian CDR (XCDR1, the rosbag2 default) and return None for
# anything else, so a caller falls back to a full deserializer.

_CDR_LE_KIND = b'\x00\x01'           # encapsulation kind CDR_LE (options ignored)
_DOUBLE = struct.Struct('<d')


def _read_header(raw):
    """(stamp seconds, frame_id, offset after it from the CDR body start) or None."""
    if len(raw) < 16 or raw[:2] != _CDR_LE_KIND:
        return None
    sec, nanosec, length = _HEADER.unpack_from(raw, 4)
    end = 16 + length
    if length < 1 or end > len(raw) or raw[end - 1] != 0:
        return None
    return sec + nanosec * 1e-9, raw[16:end - 1].decode('utf-8', 'replace'), end - 4


def pose_stamped_fields(raw):
    """
    Read a geometry_msgs/PoseStamped from CDR bytes without building a message object.

    Returns
    -------
    tuple or None
        ``(stamp_s, frame_id, (x, y, z, qx, qy, qz, qw))``; None if the bytes are not a
        little-endian CDR PoseStamped of the expected size.

    """
    head = _read_header(raw)
    if head is None:
        return None
    stamp, frame, at = head
    at = (at + 7) & ~7
    if len(raw) - 4 - at not in (56, 57, 58, 59, 60, 61, 62, 63):   # 7 doubles (+ padding)
        return None
    return stamp, frame, _POSE7.unpack_from(raw, 4 + at)


def joint_state_first_position(raw):
    """
    Read the stamp and ``position[0]`` of a sensor_msgs/JointState from CDR bytes.

    Returns
    -------
    tuple or None
        ``(stamp_s, position_0)``; None if the bytes are not a little-endian CDR JointState
        with at least one position.

    """
    head = _read_header(raw)
    if head is None:
        return None
    stamp, _, at = head
    n = len(raw) - 4
    try:
        at = (at + 3) & ~3
        (names,) = _U32.unpack_from(raw, 4 + at)
        at += 4
        for _ in range(names):
            at = (at + 3) & ~3
            (length,) = _U32.unpack_from(raw, 4 + at)
            at += 4 + length
        at = (at + 3) & ~3
        (count,) = _U32.unpack_from(raw, 4 + at)
        at = (at + 4 + 7) & ~7
        if count < 1 or at + 8 > n:
            return None
        return stamp, _DOUBLE.unpack_from(raw, 4 + at)[0]
    except struct.error:
        return None
