"""
Rotations and rigid transforms for the LfD pipeline, vectorised over leading axes.

Conventions (one page, used by every ``suture_lfd`` module):

- Quaternions are ``(x, y, z, w)``, scalar last (as ROS messages, PyBullet and SciPy's
  ``Rotation.as_quat()``); ``q`` and ``-q`` are the same rotation.
- A rotation vector ``r`` (rad) is the axis times the angle; ``q = exp(r / 2)``.
- ``quaternion_log`` is Ude's literal logarithm ``log(q) = arccos(w) v / |v|`` with **no**
  hemisphere flip, so ``2 log(q)`` has an angle in [0, 2 pi]: a sign-continuous quaternion
  sequence keeps a rotation of more than 180 degrees (Ude et al. 2014). Use
  ``rotvec_from_quaternion(q, shortest=True)`` for the shortest-path rotation vector.
- A pose is a 7-vector ``(x, y, z, qx, qy, qz, qw)`` (m, unit quaternion) or a 4x4 homogeneous
  matrix ``T_a_b`` that maps coordinates in frame ``b`` into frame ``a``.
- Conversions are named ``<target>_from_<source>``.

Size: the conventions are written on one page, for every rotation and transform function beside
them; each function is short.
"""

import math

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.validation import FloatArray, check_array, check_quaternions

_SMALL_ANGLE = 1e-8


def quaternion_product(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """
    Return the Hamilton product ``p * q`` of quaternions (x, y, z, w).

    Parameters
    ----------
    p, q : array_like, shape (..., 4)
        Quaternions; leading axes broadcast.

    Returns
    -------
    ndarray, shape (..., 4)
        The product (rotation ``q`` first, then ``p``).

    """
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    px, py, pz, pw = np.moveaxis(p, -1, 0)
    qx, qy, qz, qw = np.moveaxis(q, -1, 0)
    return np.stack((
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    ), axis=-1)


def quaternion_conjugate(q: ArrayLike) -> FloatArray:
    """
    Return the conjugate ``(-x, -y, -z, w)``, the inverse of a unit quaternion.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternions (x, y, z, w).

    Returns
    -------
    ndarray, shape (..., 4)
        Conjugates.

    """
    q = np.array(q, dtype=float)
    q[..., :3] *= -1.0
    return q


def quaternion_log(q: ArrayLike) -> FloatArray:
    """
    Return Ude's quaternion logarithm ``arccos(w) v / |v|`` (rad), without hemisphere flip.

    ``2 * quaternion_log(q)`` is the rotation vector whose angle lies in [0, 2 pi]; for
    ``w < 0`` it is the long way round. At ``q = (0, 0, 0, -1)`` (a full turn) the axis is
    undefined and the zero vector is returned.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions (x, y, z, w).

    Returns
    -------
    ndarray, shape (..., 3)
        Half rotation vectors, rad.

    """
    q = np.asarray(q, dtype=float)
    v = q[..., :3]
    s = np.linalg.norm(v, axis=-1)
    half = np.arctan2(s, q[..., 3])  # = arccos(w) for unit q, accurate near w = +-1
    with np.errstate(invalid='ignore', divide='ignore'):
        factor = np.where(s > _SMALL_ANGLE, half / np.where(s > 0.0, s, 1.0),
                          np.where(q[..., 3] > 0.0, 1.0, 0.0))
    return v * factor[..., None]


def quaternion_exp(r: ArrayLike) -> FloatArray:
    """
    Return the quaternion exponential ``(sin|r| r/|r|, cos|r|)`` of half rotation vectors.

    Parameters
    ----------
    r : array_like, shape (..., 3)
        Half rotation vectors, rad (``r = theta / 2 * axis``).

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternions (x, y, z, w); ``(0, 0, 0, 1)`` for ``r = 0``.

    """
    r = np.asarray(r, dtype=float)
    a = np.linalg.norm(r, axis=-1)
    # sin(a)/a with its series near 0
    sinc = np.where(a > 1e-4, np.sin(a) / np.where(a > 0.0, a, 1.0), 1.0 - a * a / 6.0)
    return np.concatenate((r * sinc[..., None], np.cos(a)[..., None]), axis=-1)


def rotvec_from_quaternion(q: ArrayLike, shortest: bool = True) -> FloatArray:
    """
    Return the rotation vector ``2 log(q)`` (rad).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions (x, y, z, w).
    shortest : bool
        If true, flip ``q`` into the ``w >= 0`` hemisphere first so the angle is in [0, pi]
        (shortest path). If false, keep the sign of ``q`` (Ude's literal log, angle in
        [0, 2 pi]).

    Returns
    -------
    ndarray, shape (..., 3)
        Rotation vectors, rad.

    """
    q = np.asarray(q, dtype=float)
    if shortest:
        q = np.where(q[..., 3:4] < 0.0, -q, q)
    return 2.0 * quaternion_log(q)


def quaternion_from_rotvec(r: ArrayLike) -> FloatArray:
    """
    Return the unit quaternion ``exp(r / 2)`` of rotation vectors.

    Parameters
    ----------
    r : array_like, shape (..., 3)
        Rotation vectors (axis times angle), rad.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternions (x, y, z, w).

    """
    return quaternion_exp(0.5 * np.asarray(r, dtype=float))


def quaternion_sign_continuous(Q: ArrayLike, reference: ArrayLike | None = None) -> FloatArray:
    """
    Return a quaternion sequence with signs chosen so that neighbours have a positive dot.

    Tracker and message streams flip ``q`` to ``-q`` arbitrarily; the DMP needs a continuous
    sequence (lfd_anchors section 2.5).

    Parameters
    ----------
    Q : array_like, shape (n, 4)
        Quaternions (x, y, z, w) in time order.
    reference : array_like, shape (4,), optional
        If given, the first quaternion takes the sign closest to it.

    Returns
    -------
    ndarray, shape (n, 4)
        The same rotations, sign-continuous.

    """
    Q = np.asarray(Q, dtype=float)
    if Q.shape[0] == 0:
        return Q.copy()
    dots = np.einsum('ij,ij->i', Q[1:], Q[:-1])
    flips = np.concatenate(([1.0], np.where(dots < 0.0, -1.0, 1.0)))
    if reference is not None and np.dot(Q[0], np.asarray(reference, dtype=float)) < 0.0:
        flips[0] = -1.0
    return Q * np.cumprod(flips)[:, None]


def quaternion_slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike,
                     shortest_path: bool = True) -> FloatArray:
    """
    Return the spherical linear interpolation from ``q0`` (t = 0) to ``q1`` (t = 1).

    Parameters
    ----------
    q0, q1 : array_like, shape (..., 4)
        Unit quaternions (x, y, z, w); leading axes broadcast with ``t``.
    t : array_like, shape (...)
        Interpolation parameter, normally in [0, 1].
    shortest_path : bool
        Replace ``q1`` by ``-q1`` when that is closer, so the interpolation takes the short arc
        (the same rotation either way).

    Returns
    -------
    ndarray, shape (..., 4)
        Interpolated unit quaternions.

    """
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    t = np.asarray(t, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    if shortest_path:
        q1 = np.where(dot < 0.0, -q1, q1)
        dot = np.abs(dot)
    dot = np.clip(dot, -1.0, 1.0)
    omega = np.arccos(dot)
    sin_omega = np.sin(omega)
    small = sin_omega < 1e-9
    safe = np.where(small, 1.0, sin_omega)
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * omega) / safe)
    w1 = np.where(small, t, np.sin(t * omega) / safe)
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def quaternion_angle(q1: ArrayLike, q2: ArrayLike) -> FloatArray:
    """
    Return the rotation angle between two orientations (rad, in [0, pi]).

    The double cover is accounted for: ``q`` and ``-q`` are at distance 0.

    Parameters
    ----------
    q1, q2 : array_like, shape (..., 4)
        Unit quaternions (x, y, z, w); leading axes broadcast.

    Returns
    -------
    ndarray, shape (...)
        Angle of ``q2 * conj(q1)``, rad.

    """
    d = quaternion_product(q2, quaternion_conjugate(q1))
    return 2.0 * np.arctan2(np.linalg.norm(d[..., :3], axis=-1), np.abs(d[..., 3]))


def quaternion_rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """
    Rotate vectors by unit quaternions.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions (x, y, z, w).
    v : array_like, shape (..., 3)
        Vectors; leading axes broadcast with ``q``.

    Returns
    -------
    ndarray, shape (..., 3)
        ``R(q) v``.

    """
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    u = q[..., :3]
    t = 2.0 * cross(u, v)
    return v + q[..., 3:4] * t + cross(u, t)


def matrix_from_quaternion(q: ArrayLike) -> FloatArray:
    """
    Return rotation matrices of unit quaternions.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions (x, y, z, w).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.

    """
    q = np.asarray(q, dtype=float)
    x, y, z, w = np.moveaxis(q, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    R = np.stack((
        1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
        2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
        2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy),
    ), axis=-1)
    return R.reshape(q.shape[:-1] + (3, 3))


def quaternion_from_matrix(R: ArrayLike) -> FloatArray:
    """
    Return unit quaternions (x, y, z, w) with ``w >= 0`` from rotation matrices.

    Shepperd's method: the largest of the four squared components is computed from the
    trace, the others from off-diagonal sums, so every case is well conditioned.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternions.

    """
    R = np.asarray(R, dtype=float)
    if R.shape == (3, 3):
        return _quaternion_from_one_matrix(R.tolist())
    r00, r01, r02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    r10, r11, r12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    r20, r21, r22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # candidates scaled by 4 * component: rows x, y, z, w
    cand = np.stack((
        np.stack((1.0 + r00 - r11 - r22, r01 + r10, r02 + r20, r21 - r12), axis=-1),
        np.stack((r01 + r10, 1.0 - r00 + r11 - r22, r12 + r21, r02 - r20), axis=-1),
        np.stack((r02 + r20, r12 + r21, 1.0 - r00 - r11 + r22, r10 - r01), axis=-1),
        np.stack((r21 - r12, r02 - r20, r10 - r01, 1.0 + r00 + r11 + r22), axis=-1),
    ), axis=-2)
    diag = np.stack((r00 - r11 - r22, -r00 + r11 - r22, -r00 - r11 + r22,
                     r00 + r11 + r22), axis=-1)
    k = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def _quaternion_from_one_matrix(rows: list[list[float]]) -> FloatArray:
    """Return :func:`quaternion_from_matrix` of one matrix (nested lists), in plain floats."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
    diag = (r00 - r11 - r22, -r00 + r11 - r22, -r00 - r11 + r22, r00 + r11 + r22)
    k = diag.index(max(diag))  # the first largest, as numpy.argmax
    if k == 0:
        q = (1.0 + r00 - r11 - r22, r01 + r10, r02 + r20, r21 - r12)
    elif k == 1:
        q = (r01 + r10, 1.0 - r00 + r11 - r22, r12 + r21, r02 - r20)
    elif k == 2:
        q = (r02 + r20, r12 + r21, 1.0 - r00 - r11 + r22, r10 - r01)
    else:
        q = (r21 - r12, r02 - r20, r10 - r01, 1.0 + r00 + r11 + r22)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[3] < 0.0:
        n = -n
    return np.array([q[0] / n, q[1] / n, q[2] / n, q[3] / n])


def transform_from_pose(pose: ArrayLike) -> FloatArray:
    """
    Return 4x4 homogeneous matrices from 7-vector poses.

    Parameters
    ----------
    pose : array_like, shape (..., 7)
        ``(x, y, z, qx, qy, qz, qw)``: position (m) and unit quaternion.

    Returns
    -------
    ndarray, shape (..., 4, 4)
        ``T_a_b`` for a pose of frame ``b`` given in frame ``a``.

    Raises
    ------
    ValueError
        If the last axis is not 7 long, an entry is not finite or a quaternion is not unit.

    """
    pose = check_array(pose, 'pose')
    if pose.ndim == 0 or pose.shape[-1] != 7:
        raise ValueError(f'pose must have shape (..., 7) (x y z qx qy qz qw), got {pose.shape}')
    q = check_quaternions(pose[..., 3:], 'pose orientation')
    T = np.zeros(pose.shape[:-1] + (4, 4))
    T[..., :3, :3] = matrix_from_quaternion(q)
    T[..., :3, 3] = pose[..., :3]
    T[..., 3, 3] = 1.0
    return T


def pose_from_transform(T: ArrayLike) -> FloatArray:
    """
    Return 7-vector poses from 4x4 homogeneous matrices.

    Parameters
    ----------
    T : array_like, shape (..., 4, 4)
        Homogeneous transforms ``T_a_b``.

    Returns
    -------
    ndarray, shape (..., 7)
        ``(x, y, z, qx, qy, qz, qw)`` with ``qw >= 0``.

    """
    T = check_array(T, 'T')
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise ValueError(f'T must have shape (..., 4, 4), got {T.shape}')
    return np.concatenate((T[..., :3, 3], quaternion_from_matrix(T[..., :3, :3])), axis=-1)


# the identity the single inverse starts from (copied: cheaper than making one)
_EYE4 = np.eye(4)


def invert_transform(T: ArrayLike) -> FloatArray:
    """
    Return the inverse of rigid transforms, ``T_b_a`` from ``T_a_b``.

    Parameters
    ----------
    T : array_like, shape (..., 4, 4)
        Homogeneous rigid transforms.

    Returns
    -------
    ndarray, shape (..., 4, 4)
        Inverses (rotation transposed, translation ``-R^T p``).

    """
    T = np.asarray(T, dtype=float)
    if T.ndim == 2:  # one transform (the simulator's hot path): no einsum overhead
        out = _EYE4.copy()
        Rt = T[:3, :3].T
        out[:3, :3] = Rt
        out[:3, 3] = -Rt @ T[:3, 3]
        return out
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum('...ij,...j->...i', Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def compose_poses(pose_a_b: ArrayLike, pose_b_c: ArrayLike) -> FloatArray:
    """
    Return the composition ``pose_a_c`` of 7-vector poses (``T_a_c = T_a_b T_b_c``).

    Parameters
    ----------
    pose_a_b, pose_b_c : array_like, shape (..., 7)
        Poses ``(x, y, z, qx, qy, qz, qw)``; leading axes broadcast.

    Returns
    -------
    ndarray, shape (..., 7)
        The composed pose; its quaternion keeps the sign of the product.

    """
    pose_a_b = np.asarray(pose_a_b, dtype=float)
    pose_b_c = np.asarray(pose_b_c, dtype=float)
    p = pose_a_b[..., :3] + quaternion_rotate(pose_a_b[..., 3:], pose_b_c[..., :3])
    q = quaternion_product(pose_a_b[..., 3:], pose_b_c[..., 3:])
    lead = np.broadcast_shapes(p.shape[:-1], q.shape[:-1])
    return np.concatenate((np.broadcast_to(p, lead + (3,)), np.broadcast_to(q, lead + (4,))),
                          axis=-1)


def invert_pose(pose: ArrayLike) -> FloatArray:
    """
    Return the inverse of 7-vector poses (``pose_b_a`` from ``pose_a_b``).

    Parameters
    ----------
    pose : array_like, shape (..., 7)
        Poses ``(x, y, z, qx, qy, qz, qw)``.

    Returns
    -------
    ndarray, shape (..., 7)
        Inverse poses.

    """
    pose = np.asarray(pose, dtype=float)
    qi = quaternion_conjugate(pose[..., 3:])
    return np.concatenate((-quaternion_rotate(qi, pose[..., :3]), qi), axis=-1)


def skew(v: ArrayLike) -> FloatArray:
    """
    Return the cross-product matrices ``[v]x`` of vectors.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Vectors.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Skew-symmetric matrices with ``[v]x w = v x w``.

    """
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack((z, -w, y, w, z, -x, -y, x, z), axis=-1).reshape(v.shape[:-1] + (3, 3))


def cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """
    Return ``a x b`` along the last axis (as ``numpy.cross``, with less overhead).

    Parameters
    ----------
    a, b : ndarray, shape (..., 3)
        Vectors (broadcast against each other).

    Returns
    -------
    ndarray, shape (..., 3)

    """
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = ay * bz - az * by
    out[..., 1] = az * bx - ax * bz
    out[..., 2] = ax * by - ay * bx
    return out


def so3_left_jacobian_apply(r: ArrayLike, w: ArrayLike) -> FloatArray:
    """
    Return ``J_l(r) w``, the world angular velocity of ``exp(r/2)`` moving at ``dr/dt = w``.

    ``J_l(r) = I + (1 - cos a)/a^2 [r]x + (a - sin a)/a^3 [r]x^2`` with ``a = |r|``.

    Parameters
    ----------
    r : array_like, shape (..., 3)
        Rotation vectors, rad.
    w : array_like, shape (..., 3)
        Rates of the rotation vector, rad/s.

    Returns
    -------
    ndarray, shape (..., 3)
        Angular velocities in the world frame, rad/s.

    """
    r = np.asarray(r, dtype=float)
    w = np.asarray(w, dtype=float)
    a = np.linalg.norm(r, axis=-1, keepdims=True)
    a2 = a * a
    small = a < 1e-4
    safe = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(a)) / (safe * safe))
    c2 = np.where(small, 1.0 / 6.0 - a2 / 120.0, (a - np.sin(a)) / (safe * safe * safe))
    rw = cross(r, w)
    return w + c1 * rw + c2 * cross(r, rw)


def so3_left_jacobian_inverse_apply(r: ArrayLike, omega: ArrayLike) -> FloatArray:
    """
    Return ``J_l(r)^-1 omega``, the rate of the rotation vector of ``exp(r/2)`` (rad/s).

    ``J_l^-1(r) = I - 1/2 [r]x + (1/a^2 - (1 + cos a)/(2 a sin a)) [r]x^2``; singular at
    ``a = 2 pi`` (a full turn).

    Parameters
    ----------
    r : array_like, shape (..., 3)
        Rotation vectors, rad.
    omega : array_like, shape (..., 3)
        Angular velocities in the world frame, rad/s.

    Returns
    -------
    ndarray, shape (..., 3)
        ``dr/dt``, rad/s.

    """
    r = np.asarray(r, dtype=float)
    omega = np.asarray(omega, dtype=float)
    ro = cross(r, omega)
    return omega - 0.5 * ro + _jinv_coefficient(r)[..., None] * cross(r, ro)


def _jinv_coefficient(r: FloatArray) -> FloatArray:
    """Return ``1/a^2 - (1 + cos a)/(2 a sin a)`` with its series near a = 0."""
    a = np.linalg.norm(r, axis=-1)
    small = a < 1e-3
    safe = np.where(small, 1.0, a)
    sin_a = np.sin(safe)
    sin_a = np.where(np.abs(sin_a) < 1e-12, 1e-12, sin_a)
    exact = 1.0 / (safe * safe) - (1.0 + np.cos(safe)) / (2.0 * safe * sin_a)
    return np.where(small, 1.0 / 12.0 + a * a / 720.0, exact)
