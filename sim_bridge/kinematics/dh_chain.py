"""
Modified Denavit-Hartenberg serial chains: forward kinematics, link frames, Jacobians.

Convention (dVRK / cisst ``robModifiedDH``, Craig's modified Denavit-Hartenberg): the transform
of link ``i`` relative to link ``i-1`` is

    T_i = RotX(alpha) * TransX(a) * RotZ(theta) * TransZ(d),

with ``theta = theta0 + offset + q`` for a revolute joint and ``d = d0 + offset + q`` for a
prismatic joint. The tool-tip pose in the arm's base frame (the RCM frame ``<ARM>_base`` for the
dVRK arms) is

    T_base_tip = T_1 * ... * T_n * tooltip_offset.

Units are SI (metres, radians); poses are 4x4 homogeneous matrices ``T_a_b``.

Size: one chain class whose forward kinematics, link frames and Jacobians run over the same
per-link parameters and scalar arithmetic, with the input checks they share; the Pinocchio model
beside it is the same chain for the cross-check.
"""

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
import math
import struct
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sim_bridge.common.validation import check_positive

FloatArray = NDArray[np.float64]
# a pose's top three rows as nested tuples, and as 12 floats (rotation rows, then translation)
_Rows = tuple[tuple[float, ...], ...]
_Pose12 = tuple[float, float, float, float, float, float, float, float, float, float, float,
                float]


@dataclass(frozen=True)
class DhJoint:
    """
    One joint of a modified-DH chain, with its position, velocity and acceleration limits.

    Attributes
    ----------
    name : str
        Joint name as the dVRK publishes it (``'yaw'``, ``'insertion'``, ...).
    kind : str
        ``'revolute'`` or ``'prismatic'``.
    alpha : float
        Link twist about the previous x axis (rad).
    a : float
        Link length along the previous x axis (m).
    theta : float
        Constant joint angle ``theta0`` (rad).
    d : float
        Constant link offset ``d0`` along the joint z axis (m).
    offset : float
        Joint offset added to ``q`` (rad for revolute, m for prismatic joints).
    lower, upper : float
        Position limits of ``q`` (rad or m).
    v_max : float
        Trajectory velocity limit (rad/s or m/s), > 0.
    a_max : float
        Trajectory acceleration limit (rad/s^2 or m/s^2), > 0.

    """

    name: str
    kind: str
    alpha: float
    a: float
    theta: float
    d: float
    offset: float
    lower: float
    upper: float
    v_max: float
    a_max: float

    def __post_init__(self) -> None:
        if self.kind not in ('revolute', 'prismatic'):
            raise ValueError(
                f'joint {self.name!r}: kind must be revolute or prismatic, got {self.kind!r}')
        if not self.lower < self.upper:
            raise ValueError(
                f'joint {self.name!r}: lower limit {self.lower} must be below upper {self.upper}')
        check_positive(self.v_max, f'joint {self.name!r}: v_max')
        check_positive(self.a_max, f'joint {self.name!r}: a_max')

    @property
    def is_revolute(self) -> bool:
        """Whether the joint rotates (``q`` in rad) rather than slides (``q`` in m)."""
        return self.kind == 'revolute'


# ---------------------------------------------------------------------------------------------
# input checks


def check_joint_vector(q: ArrayLike, n: int, name: str = 'q') -> FloatArray:
    """
    Return ``q`` as a finite float array of shape (n,), or raise ValueError naming ``name``.

    Parameters
    ----------
    q : array_like, shape (n,)
        Joint values (rad or m).
    n : int
        Expected number of joints.
    name : str
        Argument name used in the error message.

    Returns
    -------
    ndarray, shape (n,)
        A float copy.

    """
    try:
        q = np.array(q, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{name} must be {n} numbers ({exc})') from exc
    if q.shape != (n,):
        raise ValueError(f'{name} must have {n} joint values, got shape {q.shape}')
    if not np.all(np.isfinite(q)):
        raise ValueError(f'{name} contains NaN or infinite values: {q.tolist()}')
    return q


def check_pose(T: ArrayLike, name: str = 'T', tol: float = 1e-6) -> FloatArray:
    """
    Validate a homogeneous transform and return it with an exactly orthonormal rotation.

    Parameters
    ----------
    T : array_like, shape (4, 4)
        Pose ``T_a_b`` (metres).
    name : str
        Argument name used in error messages.
    tol : float
        Largest accepted ``max |R^T R - I|``; within it the rotation is re-orthonormalised.

    Returns
    -------
    ndarray, shape (4, 4)
        A float copy with bottom row ``[0, 0, 0, 1]``.

    Raises
    ------
    ValueError
        Wrong shape, NaN/inf, bad bottom row, or a rotation that is not orthonormal with
        determinant +1.

    """
    if isinstance(T, np.ndarray) and T.shape == (4, 4):
        # the common case, a well-formed pose: checked in plain floats, no re-orthonormalising
        # needed when R^T R = I to 1e-12
        rows = T.tolist()
        (a, b, c, _), (d, e, f, _), (g, h, i, _), bottom = rows
        flat = [v for row in rows for v in row]
        if (bottom == [0.0, 0.0, 0.0, 1.0] and all(map(math.isfinite, flat))
                and max(abs(a * a + d * d + g * g - 1.0), abs(b * b + e * e + h * h - 1.0),
                        abs(c * c + f * f + i * i - 1.0), abs(a * b + d * e + g * h),
                        abs(a * c + d * f + g * i), abs(b * c + e * f + h * i)) <= 1e-12
                and a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) > 0.0):
            return np.array(rows, dtype=float)
    return check_poses(np.asarray(T, dtype=float)[None] if np.ndim(T) == 2 else T,
                       name=name, tol=tol, single=True)[0]


def check_poses(T: ArrayLike, name: str = 'T', tol: float = 1e-6,
                single: bool = False) -> FloatArray:
    """
    Validate a stack of homogeneous transforms (see :func:`check_pose`).

    Parameters
    ----------
    T : array_like, shape (m, 4, 4)
        Poses (metres).
    name : str
        Argument name used in error messages.
    tol : float
        Largest accepted ``max |R^T R - I|``.
    single : bool
        Word messages for a single pose.

    Returns
    -------
    ndarray, shape (m, 4, 4)
        Float copies with exactly orthonormal rotations.

    """
    try:
        T = np.array(T, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{name} must be a 4x4 homogeneous matrix ({exc})') from exc
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        shape = T.shape[1:] if single and T.ndim == 3 else T.shape
        expected = '(4, 4)' if single else '(m, 4, 4)'
        raise ValueError(f'{name} must have shape {expected}, got {shape}')
    if not np.all(np.isfinite(T)):
        raise ValueError(f'{name} contains NaN or infinite values')
    if np.max(np.abs(T[:, 3, :] - (0.0, 0.0, 0.0, 1.0))) > tol:
        raise ValueError(f'{name} bottom row must be [0, 0, 0, 1], got {T[:, 3, :][0].tolist()}')
    R = T[:, :3, :3]
    err = np.max(np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)), axis=(1, 2))
    det = np.linalg.det(R)
    bad = (err > tol) | (det <= 0.0)
    if np.any(bad):
        i = int(np.argmax(bad))
        where = '' if single else f' (pose {i})'
        raise ValueError(
            f'{name} rotation is not a proper rotation matrix{where}: max |R^T R - I| = '
            f'{err[i]:.3g}, det = {det[i]:.3g}')
    U, _, Vt = np.linalg.svd(R)
    T[:, :3, :3] = U @ Vt
    T[:, 3, :] = (0.0, 0.0, 0.0, 1.0)
    return T


def pose_mismatch(Ta: FloatArray, Tb: FloatArray) -> tuple[float, float]:
    """
    Distance (m) and rotation angle (rad) between two poses, in plain floats.

    Parameters
    ----------
    Ta, Tb : ndarray, shape (4, 4)
        Poses.

    Returns
    -------
    tuple of float
        ``|t_a - t_b|`` and the angle of ``R_a^T R_b`` (as :func:`rotation_angle`).

    """
    (a0, a1, a2, ax), (a3, a4, a5, ay), (a6, a7, a8, az) = Ta[:3].tolist()
    return pose_mismatch_values((a0, a1, a2, a3, a4, a5, a6, a7, a8, ax, ay, az), Tb)


def pose_mismatch_values(a: Sequence[float], Tb: FloatArray) -> tuple[float, float]:
    """
    :func:`pose_mismatch` of a pose given as 12 floats and a 4x4 pose.

    Parameters
    ----------
    a : sequence of 12 float
        Rotation rows then translation: ``(r00, r01, r02, r10, .., r22, x, y, z)``.
    Tb : ndarray, shape (4, 4)
        Pose.

    Returns
    -------
    tuple of float
        Distance (m) and rotation angle (rad).

    """
    a0, a1, a2, a3, a4, a5, a6, a7, a8, ax, ay, az = a
    (b0, b1, b2, bx), (b3, b4, b5, by), (b6, b7, b8, bz) = Tb[:3].tolist()
    # D = Ra^T Rb
    d01 = a0 * b1 + a3 * b4 + a6 * b7
    d10 = a1 * b0 + a4 * b3 + a7 * b6
    d02 = a0 * b2 + a3 * b5 + a6 * b8
    d20 = a2 * b0 + a5 * b3 + a8 * b6
    d12 = a1 * b2 + a4 * b5 + a7 * b8
    d21 = a2 * b1 + a5 * b4 + a8 * b7
    trace = (a0 * b0 + a3 * b3 + a6 * b6) + (a1 * b1 + a4 * b4 + a7 * b7) + (
        a2 * b2 + a5 * b5 + a8 * b8)
    s = 0.5 * math.sqrt((d21 - d12) ** 2 + (d02 - d20) ** 2 + (d10 - d01) ** 2)
    return (math.sqrt((ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2),
            math.atan2(s, 0.5 * (trace - 1.0)))


def rotation_angle(Ra: ArrayLike, Rb: ArrayLike) -> FloatArray:
    """
    Angle of the rotation ``Ra^T Rb`` (rad), accurate for small and large angles.

    Parameters
    ----------
    Ra, Rb : ndarray, shape (..., 3, 3)
        Rotation matrices.

    Returns
    -------
    ndarray, shape (...)
        Angles in [0, pi].

    """
    D = np.swapaxes(Ra, -1, -2) @ Rb
    s = 0.5 * np.sqrt((D[..., 2, 1] - D[..., 1, 2]) ** 2 + (D[..., 0, 2] - D[..., 2, 0]) ** 2
                      + (D[..., 1, 0] - D[..., 0, 1]) ** 2)
    c = 0.5 * (np.trace(D, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(s, c)


# ---------------------------------------------------------------------------------------------
# elementary transforms


def rotation_x(alpha: float) -> FloatArray:
    """
    Rotation about x by ``alpha`` (rad).

    Parameters
    ----------
    alpha : float
        Angle (rad).

    Returns
    -------
    ndarray, shape (3, 3)

    """
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_z(theta: float) -> FloatArray:
    """
    Rotations about z by ``theta`` (rad), vectorised.

    Parameters
    ----------
    theta : float or ndarray, shape (...)
        Angles (rad).

    Returns
    -------
    ndarray, shape (..., 3, 3)

    """
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(np.shape(theta) + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 1] = -s
    R[..., 1, 0] = s
    R[..., 1, 1] = c
    R[..., 2, 2] = 1.0
    return R


def _link_constant(joint: DhJoint) -> FloatArray:
    """RotX(alpha) * TransX(a), shape (4, 4)."""
    C = np.eye(4)
    C[:3, :3] = rotation_x(joint.alpha)
    C[0, 3] = joint.a
    return C


_PACK12 = struct.Struct('12d').pack  # the exact bytes of 12 floats


def _compose(a: float, b: float, c: float, d: float, e: float, f: float, g: float, h: float,
             i: float, x: float, y: float, z: float, C: _Rows) -> _Pose12:
    """Return ``[R | t] @ C`` for ``R`` = rows (a b c; d e f; g h i), t = (x, y, z), C 3x4 rows."""
    (p, q, r, u), (s, t, w, v), (k, m, n, o) = C
    return (a * p + b * s + c * k, a * q + b * t + c * m, a * r + b * w + c * n,
            d * p + e * s + f * k, d * q + e * t + f * m, d * r + e * w + f * n,
            g * p + h * s + i * k, g * q + h * t + i * m, g * r + h * w + i * n,
            a * u + b * v + c * o + x, d * u + e * v + f * o + y, g * u + h * v + i * o + z)


def _matrix(a: float, b: float, c: float, d: float, e: float, f: float, g: float, h: float,
            i: float, x: float, y: float, z: float) -> FloatArray:
    """Return the 4x4 array of rotation rows (a b c; d e f; g h i) and translation (x, y, z)."""
    return np.array((a, b, c, x, d, e, f, y, g, h, i, z, 0.0, 0.0, 0.0, 1.0)).reshape(4, 4)


_PACK16 = struct.Struct('16d').pack


def _read_only_matrix(a: float, b: float, c: float, d: float, e: float, f: float, g: float,
                      h: float, i: float, x: float, y: float, z: float) -> FloatArray:
    """:func:`_matrix` as a read-only array over the packed floats (cheaper to make)."""
    return np.frombuffer(_PACK16(a, b, c, x, d, e, f, y, g, h, i, z, 0.0, 0.0, 0.0, 1.0)
                         ).reshape(4, 4)


class SerialChain:
    """
    A modified-DH serial chain with a fixed tool-tip offset.

    Parameters
    ----------
    joints : sequence of DhJoint
        Joints from the base outwards.
    tooltip_offset : array_like, shape (4, 4)
        Pose of the tool tip in the last DH frame.
    home : array_like, shape (n,), optional
        Home configuration (rad / m); zeros if omitted.
    name : str
        Label used in messages (``'PSM Si + LARGE_NEEDLE_DRIVER_420006'``).

    Attributes
    ----------
    joints : tuple of DhJoint
    joint_names : tuple of str
    n_joints : int
    lower, upper : ndarray, shape (n,)
        Position limits (rad / m).
    v_max, a_max : ndarray, shape (n,)
        Trajectory velocity (rad/s, m/s) and acceleration (rad/s^2, m/s^2) limits.
    tooltip_offset : ndarray, shape (4, 4)
    home : ndarray, shape (n,)
    is_revolute : ndarray of bool, shape (n,)

    """

    def __init__(self, joints: Iterable[DhJoint], tooltip_offset: ArrayLike | None = None,
                 home: ArrayLike | None = None, name: str = 'chain') -> None:
        self.joints = tuple(joints)
        if not self.joints:
            raise ValueError('a serial chain needs at least one joint')
        self.name = name
        n = len(self.joints)
        self.n_joints = n
        self.joint_names = tuple(j.name for j in self.joints)
        self.lower = np.array([j.lower for j in self.joints])
        self.upper = np.array([j.upper for j in self.joints])
        self.v_max = np.array([j.v_max for j in self.joints])
        self.a_max = np.array([j.a_max for j in self.joints])
        self.is_revolute = np.array([j.is_revolute for j in self.joints])
        self.tooltip_offset = (np.eye(4) if tooltip_offset is None
                               else check_pose(tooltip_offset, name='tooltip_offset'))
        self.home = (np.zeros(n) if home is None
                     else self.clip(check_joint_vector(home, n, name='home')))
        self._const = np.stack([_link_constant(j) for j in self.joints])  # (n, 4, 4)
        self._theta0 = np.array([j.theta + (j.offset if j.is_revolute else 0.0)
                                 for j in self.joints])
        self._d0 = np.array([j.d + (0.0 if j.is_revolute else j.offset) for j in self.joints])
        for arr in (self.lower, self.upper, self.v_max, self.a_max, self.is_revolute, self.home,
                    self.tooltip_offset, self._const):
            arr.flags.writeable = False
        # plain-float copies for the one-pose forward kinematics
        self._float_chain = [
            (bool(rev), float(t0), float(d0), tuple(map(tuple, C[:3].tolist())))
            for rev, t0, d0, C in zip(self.is_revolute, self._theta0, self._d0, self._const)]
        self._float_tip: _Rows = tuple(map(tuple, self.tooltip_offset[:3].tolist()))
        # identity @ C of the first link, when it is C to the bit (signs of zeros too)
        (p, q, r, u), (s, t, w, v), (k, m, n, o) = self._float_chain[0][3]
        first = _compose(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0,
                         self._float_chain[0][3])
        plain = (p, q, r, s, t, w, k, m, n, u, v, o)
        self._float_first = first if _PACK12(*first) == _PACK12(*plain) else None

    def __repr__(self) -> str:
        return f'{type(self).__name__}({self.name!r}, joints={list(self.joint_names)})'

    # -- joint-space helpers -------------------------------------------------------------------

    def check_q(self, q: ArrayLike, name: str = 'q') -> FloatArray:
        """
        Validate a joint vector (shape (n,), finite) and return a float copy.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint values (rad / m).
        name : str
            Argument name used in the error message.

        Returns
        -------
        ndarray, shape (n,)

        """
        return check_joint_vector(q, self.n_joints, name=name)

    def clip(self, q: ArrayLike) -> FloatArray:
        """
        Clip joint values into the position limits.

        Parameters
        ----------
        q : array_like, shape (n,) or (m, n)
            Joint values (rad / m).

        Returns
        -------
        ndarray
            Same shape, inside ``[lower, upper]``.

        """
        q = np.asarray(q, dtype=float)
        if q.shape[-1:] != (self.n_joints,):
            raise ValueError(f'q must have {self.n_joints} joint values, got shape {q.shape}')
        if not np.all(np.isfinite(q)):
            raise ValueError('q contains NaN or infinite values')
        return np.clip(q, self.lower, self.upper)

    def within_limits(self, q: ArrayLike, tol: float = 0.0) -> bool | NDArray[np.bool_]:
        """
        Whether every joint value lies inside its limits (widened by ``tol``).

        Parameters
        ----------
        q : array_like, shape (n,) or (m, n)
            Joint values (rad / m).
        tol : float
            Slack (rad / m).

        Returns
        -------
        bool or ndarray of bool, shape (m,)

        """
        q = np.asarray(q, dtype=float)
        ok = np.all((q >= self.lower - tol) & (q <= self.upper + tol), axis=-1)
        return bool(ok) if np.ndim(ok) == 0 else ok

    # -- forward kinematics --------------------------------------------------------------------

    def joint_placements(self) -> FloatArray:
        """
        Return the fixed part of every link transform (the joint frames at ``q = 0``).

        Returns
        -------
        ndarray, shape (n, 4, 4)
            ``RotX(alpha) TransX(a) RotZ(theta0) TransZ(d0)`` of each joint in its parent link
            frame, offsets included (``theta0 = theta + offset`` for revolute joints,
            ``d0 = d + offset`` for prismatic ones); joint ``i`` then rotates about / slides
            along the z axis of this frame: ``T_i(q) = placement_i @ RotZ(q)`` or
            ``placement_i @ TransZ(q)``.

        """
        return self._link_transforms(np.zeros((1, self.n_joints)))[0]

    def _link_transforms(self, Q: FloatArray) -> FloatArray:
        """Link transforms T_i(q_i), shape (m, n, 4, 4), for Q of shape (m, n)."""
        theta = self._theta0 + np.where(self.is_revolute, Q, 0.0)
        d = self._d0 + np.where(self.is_revolute, 0.0, Q)
        M = np.zeros(Q.shape + (4, 4))
        c, s = np.cos(theta), np.sin(theta)
        M[..., 0, 0] = c
        M[..., 0, 1] = -s
        M[..., 1, 0] = s
        M[..., 1, 1] = c
        M[..., 2, 2] = 1.0
        M[..., 2, 3] = d
        M[..., 3, 3] = 1.0
        return self._const @ M

    def _check_batch(self, Q: ArrayLike, name: str = 'Q') -> FloatArray:
        try:
            Q = np.array(Q, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{name} must be an (m, {self.n_joints}) array ({exc})') from exc
        if Q.ndim != 2 or Q.shape[1] != self.n_joints:
            raise ValueError(f'{name} must have shape (m, {self.n_joints}), got {Q.shape}')
        if not np.all(np.isfinite(Q)):
            raise ValueError(f'{name} contains NaN or infinite values')
        return Q

    def fk_batch(self, Q: ArrayLike) -> FloatArray:
        """
        Tool-tip poses for many joint vectors.

        Parameters
        ----------
        Q : array_like, shape (m, n)
            Joint values (rad / m).

        Returns
        -------
        ndarray, shape (m, 4, 4)
            ``T_base_tip`` in the RCM frame ``<ARM>_base`` (metres).

        """
        Q = self._check_batch(Q)
        A = self._link_transforms(Q)
        T = A[:, 0]
        for i in range(1, self.n_joints):
            T = T @ A[:, i]
        return T @ self.tooltip_offset

    def fk(self, q: ArrayLike) -> FloatArray:
        """
        Tool-tip pose.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint values (rad / m).

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_base_tip``: tool tip in the RCM frame ``<ARM>_base`` (metres), including the
            tooltip offset.

        """
        return self._fk_floats(self.check_q(q).tolist())[0]

    def fk_unchecked(self, q: Sequence[float], read_only: bool = False) -> FloatArray:
        """
        :meth:`fk` of joint values already known to be valid, without checking them again.

        Parameters
        ----------
        q : sequence of float
            ``n_joints`` finite joint values (rad / m), e.g. an arm's own measured joints.
        read_only : bool
            Return a read-only array (made faster; for a pose that is kept and shared).

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_base_tip`` (metres), the same floats as :meth:`fk`.

        """
        tip = self._fk_values(q)[0]
        return _read_only_matrix(*tip) if read_only else _matrix(*tip)

    def fk_wrist_and_tip(self, q: ArrayLike, link: int) -> tuple[FloatArray, FloatArray]:
        """
        Frame of one DH link and the tool tip, for one joint vector.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint values (rad / m).
        link : int
            Link index ``1..n`` (as in :meth:`fk_links`).

        Returns
        -------
        T_link, T_tip : ndarray, shape (4, 4)
            ``T_base_link`` and ``T_base_tip`` (metres).

        """
        if not 1 <= link <= self.n_joints:
            raise ValueError(f'link must be in 1..{self.n_joints}, got {link}')
        tip, frame = self._fk_values(self.check_q(q).tolist(), link)
        return _matrix(*cast(_Pose12, frame)), _matrix(*tip)

    def wrist_and_tip_values(self, q: Sequence[float], link: int) -> tuple[_Pose12, _Pose12]:
        """
        :meth:`fk_wrist_and_tip` of joints already known to be valid, as plain floats.

        Parameters
        ----------
        q : sequence of float
            ``n_joints`` finite joint values (rad / m).
        link : int
            Link index ``1..n``.

        Returns
        -------
        T_link, T_tip : tuple of 12 float
            Each pose's rotation rows then translation: the floats of
            :meth:`fk_wrist_and_tip`'s arrays, without making them.

        """
        tip, frame = self._fk_values(q, link)
        return cast(_Pose12, frame), tip

    def _fk_floats(self, q: Sequence[float],
                   link: int | None = None) -> tuple[FloatArray, FloatArray | None]:
        """Return (tip pose, link frame or None) of ``q`` (list of floats) in plain floats."""
        tip, kept = self._fk_values(q, link)
        return _matrix(*tip), None if kept is None else _matrix(*kept)

    def _fk_values(self, q: Sequence[float],
                   link: int | None = None) -> tuple[_Pose12, _Pose12 | None]:
        """Return the tip (and link ``link``) of ``q`` as 12 floats: rotation rows, translation."""
        # plain floats: one pose costs a fraction of the batched NumPy path
        cos, sin = math.cos, math.sin
        links = zip(self._float_chain, q)
        first = self._float_first
        if first is not None:  # the first link's product with the identity, formed once
            (rev, theta0, d0, _), qi = next(links)
            a, b, c, d, e, f, g, h, i, x, y, z = first
            if rev:
                theta, dz = theta0 + qi, d0
            else:
                theta, dz = theta0, d0 + qi
            co, si = cos(theta), sin(theta)
            x, y, z = x + c * dz, y + f * dz, z + i * dz
            a, b = a * co + b * si, b * co - a * si
            d, e = d * co + e * si, e * co - d * si
            g, h = g * co + h * si, h * co - g * si
            k = 1
        else:
            a, b, c, d, e, f, g, h, i = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
            x = y = z = 0.0
            k = 0
        kept = (a, b, c, d, e, f, g, h, i, x, y, z) if link == 1 and k == 1 else None
        for (rev, theta0, d0, ((p, q_, r, u), (s, t, w, v), (kk, m, n, o))), qi in links:
            # [R | t] @ C, then the joint's RotZ(theta) TransZ(dz)
            a, b, c, d, e, f, g, h, i, x, y, z = (
                a * p + b * s + c * kk, a * q_ + b * t + c * m, a * r + b * w + c * n,
                d * p + e * s + f * kk, d * q_ + e * t + f * m, d * r + e * w + f * n,
                g * p + h * s + i * kk, g * q_ + h * t + i * m, g * r + h * w + i * n,
                a * u + b * v + c * o + x, d * u + e * v + f * o + y,
                g * u + h * v + i * o + z)
            if rev:
                theta, dz = theta0 + qi, d0
            else:
                theta, dz = theta0, d0 + qi
            co, si = cos(theta), sin(theta)
            x, y, z = x + c * dz, y + f * dz, z + i * dz
            a, b = a * co + b * si, b * co - a * si
            d, e = d * co + e * si, e * co - d * si
            g, h = g * co + h * si, h * co - g * si
            k += 1
            if k == link:
                kept = (a, b, c, d, e, f, g, h, i, x, y, z)
        return _compose(a, b, c, d, e, f, g, h, i, x, y, z, self._float_tip), kept

    def fk_links(self, q: ArrayLike) -> FloatArray:
        """
        Frames of every DH link, without the tooltip offset.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint values (rad / m).

        Returns
        -------
        ndarray, shape (n + 1, 4, 4)
            Index 0 is the base (RCM) frame itself (identity); index ``i`` (1..n) is
            ``T_base_link_i``, the modified-DH frame of link ``i`` after joint ``i`` moved: its
            z axis is the axis of joint ``i`` and its origin lies on that axis.

        """
        q = self.check_q(q)
        A = self._link_transforms(q[None])[0]
        frames = np.empty((self.n_joints + 1, 4, 4))
        frames[0] = np.eye(4)
        for i in range(self.n_joints):
            frames[i + 1] = frames[i] @ A[i]
        return frames

    def fk_all(self, q: ArrayLike) -> FloatArray:
        """
        Frames of every link, ending with the tool tip.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint values (rad / m).

        Returns
        -------
        ndarray, shape (n + 1, 4, 4)
            Poses in the RCM frame ``<ARM>_base`` (metres). Index 0 is the base frame
            (identity); index ``i`` for ``1 <= i < n`` is ``T_base_link_i``, the modified-DH frame
            of link ``i`` (z axis = axis of joint ``i``); the last index ``n`` is the tool tip
            ``T_base_link_n @ tooltip_offset`` (= :meth:`fk`). For the PSM the tip and the
            wrist-yaw link share their origin (rotation-only offset); use :meth:`fk_links` for
            the bare DH frame of the last link.

        """
        frames = self.fk_links(q)
        frames[-1] = frames[-1] @ self.tooltip_offset
        return frames

    def jacobian(self, q: ArrayLike) -> FloatArray:
        """
        Spatial Jacobian of the tool tip in the base frame.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint values (rad / m).

        Returns
        -------
        ndarray, shape (6, n)
            Rows ``[v; w]``: linear velocity of the tool-tip point (m/s per unit joint speed)
            and angular velocity (rad/s), both expressed in the RCM frame ``<ARM>_base``.

        """
        frames = self.fk_links(q)
        p = (frames[-1] @ self.tooltip_offset)[:3, 3]
        z = frames[1:, :3, 2]
        o = frames[1:, :3, 3]
        J = np.zeros((6, self.n_joints))
        rev = self.is_revolute
        J[:3, rev] = np.cross(z[rev], p - o[rev]).T
        J[3:, rev] = z[rev].T
        J[:3, ~rev] = z[~rev].T
        return J

    def jacobian_body(self, q: ArrayLike) -> FloatArray:
        """
        Body Jacobian of the tool tip.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint values (rad / m).

        Returns
        -------
        ndarray, shape (6, n)
            Rows ``[v; w]`` of the tool-tip twist expressed in the tool-tip frame.

        """
        J = self.jacobian(q)
        Rt = self.fk(q)[:3, :3].T
        return np.vstack([Rt @ J[:3], Rt @ J[3:]])


# ---------------------------------------------------------------------------------------------
# pinocchio model of a chain


def pinocchio_model(chain: SerialChain) -> tuple[Any, int]:
    """
    Build a pinocchio Model of the chain: one RZ/PZ joint per DH joint plus a tool-tip frame.

    Parameters
    ----------
    chain : SerialChain
        The chain to mirror.

    Returns
    -------
    model : pinocchio.Model
        Joint ``i`` has placement ``RotX(alpha) TransX(a) RotZ(theta0) TransZ(d0)`` (offsets
        included) in its parent, so ``q`` maps one to one; limits are copied.
    tip_frame_id : int
        Id of the operational frame ``'tool_tip'`` (placement = tooltip offset).

    """
    import pinocchio as pin

    model = pin.Model()
    model.name = chain.name
    parent = 0
    for j, M in zip(chain.joints, chain.joint_placements()):
        joint_model = pin.JointModelRZ() if j.is_revolute else pin.JointModelPZ()
        parent = model.addJoint(parent, joint_model, pin.SE3(M[:3, :3], M[:3, 3]), j.name)
        model.appendBodyToJoint(parent, pin.Inertia.Identity(), pin.SE3.Identity())
    offset = chain.tooltip_offset
    tip = pin.Frame('tool_tip', parent, pin.SE3(offset[:3, :3], offset[:3, 3]),
                    pin.FrameType.OP_FRAME)
    tip_frame_id = model.addFrame(tip)
    model.lowerPositionLimit = chain.lower.copy()
    model.upperPositionLimit = chain.upper.copy()
    model.velocityLimit = chain.v_max.copy()
    return model, tip_frame_id
