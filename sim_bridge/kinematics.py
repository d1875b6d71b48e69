"""
dVRK serial kinematics: modified-DH chains, forward kinematics, Jacobians, closed-form IK.

Conventions (dVRK / cisst ``robModifiedDH``, Craig's modified Denavit-Hartenberg):
the transform of link ``i`` relative to link ``i-1`` is

    T_i = RotX(alpha) * TransX(a) * RotZ(theta) * TransZ(d),

with ``theta = theta0 + offset + q`` for a revolute joint and ``d = d0 + offset + q`` for a
prismatic joint. The tool-tip pose in the arm's RCM frame ``<ARM>_base`` is

    T_base_tip = T_1 * ... * T_n * tooltip_offset.

The PSM jaw is not part of the chain; its limits travel with :class:`PsmKinematics`.
Units are SI (metres, radians); poses are 4x4 homogeneous matrices ``T_a_b``.

The PSM inverse kinematics is closed form and keeps the remote centre of motion (RCM) by
construction: the tool tip lies on the wrist-yaw axis, so the wrist-pitch point, the tip and the
RCM span the plane of the wrist-yaw axis and the shaft; that plane gives the wrist-pitch point,
the shaft through the RCM gives yaw, pitch and insertion, and the tool-tip orientation gives roll,
wrist pitch and wrist yaw. Every branch is enumerated and the one inside the joint limits closest
to a reference configuration wins.
"""

from dataclasses import dataclass
import re

import numpy as np
from sim_bridge.configfile import ConfigError, dataclass_from_mapping, load_yaml
from sim_bridge.paths import config_path

_TWO_PI = 2.0 * np.pi
_STRUCTURE_TOL = 1e-9
# Round-trip tolerance of an IK solution (metres and radians).
IK_TOLERANCE = 1e-6
# Joint values this far outside a limit (rounding) are clipped onto it instead of rejected.
_LIMIT_SLACK = 1e-9


class UnreachableError(ValueError):
    """A Cartesian goal has no joint solution inside the joint limits."""


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

    def __post_init__(self):
        if self.kind not in ('revolute', 'prismatic'):
            raise ValueError(
                f'joint {self.name!r}: kind must be revolute or prismatic, got {self.kind!r}')
        if not self.lower < self.upper:
            raise ValueError(
                f'joint {self.name!r}: lower limit {self.lower} must be below upper {self.upper}')
        if not (self.v_max > 0.0 and self.a_max > 0.0):
            raise ValueError(
                f'joint {self.name!r}: v_max and a_max must be positive, '
                f'got {self.v_max}, {self.a_max}')

    @property
    def is_revolute(self):
        """Whether the joint rotates (``q`` in rad) rather than slides (``q`` in m)."""
        return self.kind == 'revolute'


@dataclass(frozen=True)
class JawLimits:
    """
    PSM jaw opening range and trajectory limits (jaw = full opening angle, rad).

    Attributes
    ----------
    lower, upper : float
        Jaw angle limits (rad); negative angles squeeze (grip force).
    v_max : float
        Velocity limit (rad/s).
    a_max : float
        Acceleration limit (rad/s^2).

    """

    lower: float
    upper: float
    v_max: float
    a_max: float


@dataclass(frozen=True)
class ArmChainConfig:
    """Arm part of a chain (PSM: yaw, pitch, insertion; ECM: all four joints)."""

    joints: tuple[DhJoint, ...]
    endoscope_prefix: str = ''


@dataclass(frozen=True)
class PsmToolConfig:
    """A PSM instrument: the arm generation it mounts on, its joints, tip offset and jaw."""

    arm: str
    tool_type: str
    joints: tuple[DhJoint, ...]
    tooltip_offset: tuple[tuple[float, float, float, float], ...]
    jaw: JawLimits


@dataclass(frozen=True)
class KinematicsDefaults:
    """Which variants :func:`load_kinematics` builds."""

    psm_tool: str = 'LARGE_NEEDLE_DRIVER_420006'
    ecm_generation: str = 'Classic'
    ecm_endoscope: str = 'STRAIGHT'


@dataclass(frozen=True)
class KinematicsConfig:
    """Contents of ``config/kinematics.yaml``."""

    defaults: KinematicsDefaults
    psm_home: tuple[float, ...]
    ecm_home: tuple[float, ...]
    psm_arms: dict[str, ArmChainConfig]
    psm_tools: dict[str, PsmToolConfig]
    ecm_arms: dict[str, ArmChainConfig]
    ecm_tooltip_offset: tuple[tuple[float, float, float, float], ...]
    ecm_endoscopes: dict[str, float]


# ---------------------------------------------------------------------------------------------
# input checks


def check_joint_vector(q, n, name='q'):
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


def check_pose(T, name='T', tol=1e-6):
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
    return check_poses(np.asarray(T, dtype=float)[None] if np.ndim(T) == 2 else T,
                       name=name, tol=tol, single=True)[0]


def check_poses(T, name='T', tol=1e-6, single=False):
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


def rotation_angle(Ra, Rb):
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


def _rot_x(alpha):
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_z_batch(theta):
    """Rotations about z, shape (..., 3, 3)."""
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(np.shape(theta) + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 1] = -s
    R[..., 1, 0] = s
    R[..., 1, 1] = c
    R[..., 2, 2] = 1.0
    return R


def _link_constant(joint):
    """RotX(alpha) * TransX(a), shape (4, 4)."""
    C = np.eye(4)
    C[:3, :3] = _rot_x(joint.alpha)
    C[0, 3] = joint.a
    return C


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

    def __init__(self, joints, tooltip_offset=None, home=None, name='chain'):
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

    def __repr__(self):
        return f'{type(self).__name__}({self.name!r}, joints={list(self.joint_names)})'

    # -- joint-space helpers -------------------------------------------------------------------

    def check_q(self, q, name='q'):
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

    def clip(self, q):
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

    def within_limits(self, q, tol=0.0):
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

    def _link_transforms(self, Q):
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

    def _check_batch(self, Q, name='Q'):
        try:
            Q = np.array(Q, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{name} must be an (m, {self.n_joints}) array ({exc})') from exc
        if Q.ndim != 2 or Q.shape[1] != self.n_joints:
            raise ValueError(f'{name} must have shape (m, {self.n_joints}), got {Q.shape}')
        if not np.all(np.isfinite(Q)):
            raise ValueError(f'{name} contains NaN or infinite values')
        return Q

    def fk_batch(self, Q):
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

    def fk(self, q):
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
        return self.fk_batch(self.check_q(q)[None])[0]

    def fk_links(self, q):
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

    def fk_all(self, q):
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

    def jacobian(self, q):
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

    def jacobian_body(self, q):
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
# closed-form inverse kinematics around a remote centre of motion


def _sign_of_right_angle(alpha, what):
    s = np.sin(alpha)
    if abs(abs(s) - 1.0) > _STRUCTURE_TOL:
        raise ValueError(f'{what}: alpha must be +-pi/2 for the closed-form IK, got {alpha}')
    return float(np.sign(s))


class _RcmChain(SerialChain):
    """
    Chain whose first three joints are yaw, pitch (axes through the RCM) and insertion.

    The closed-form IK needs: joints 1, 2 revolute with a = d = 0, alpha_2, alpha_3 = +-pi/2;
    joint 3 prismatic with a = 0; joint 4 (roll) revolute about the shaft (alpha = a = 0).
    """

    def _check_rcm_structure(self):
        j = self.joints
        kinds = [x.kind for x in j[:4]]
        if kinds != ['revolute', 'revolute', 'prismatic', 'revolute']:
            raise ValueError(f'{self.name}: IK expects joints revolute, revolute, prismatic, '
                             f'revolute first, got {kinds}')
        for i in range(4):
            if abs(j[i].a) > _STRUCTURE_TOL:
                raise ValueError(f'{self.name}: IK expects a = 0 for joint {j[i].name!r}')
        if abs(j[0].d) > _STRUCTURE_TOL or abs(j[1].d) > _STRUCTURE_TOL:
            raise ValueError(f'{self.name}: IK expects yaw and pitch axes through the RCM (d = 0)')
        if abs(j[3].alpha) > _STRUCTURE_TOL:
            raise ValueError(f'{self.name}: IK expects the roll axis along the shaft (alpha = 0)')
        self._s2 = _sign_of_right_angle(j[1].alpha, f'{self.name} joint {j[1].name!r}')
        self._s3 = _sign_of_right_angle(j[2].alpha, f'{self.name} joint {j[2].name!r}')
        self._R_pre1 = _rot_x(j[0].alpha)
        self._R_x2 = _rot_x(j[1].alpha)
        self._R_x3_z3 = _rot_x(j[2].alpha) @ _rot_z_batch(self._theta0[2])
        # distance RCM -> roll frame origin along the shaft = d3 + d4 = q3 + shaft_offset
        self._shaft_offset = self._d0[2] + self._d0[3]
        self._ranges = self.upper - self.lower

    def _shaft_solutions(self, P, q_ref):
        """
        Yaw, pitch, insertion for a point P on the shaft (the roll-frame origin).

        Parameters
        ----------
        P : ndarray, shape (m, k, 3)
            Shaft points in the base frame.
        q_ref : ndarray, shape (m, n)

        Returns
        -------
        q123 : ndarray, shape (m, k, 4, 3)
            Four branches (shaft sign x pitch sign) per point.
        R3 : ndarray, shape (m, k, 4, 3, 3)
            Rotation of DH frame 3 for each branch.
        singular : ndarray of bool, shape (m, k)
            P at the RCM (shaft direction undefined).

        """
        r = np.linalg.norm(P, axis=-1)
        singular = r < 1e-9
        u = P / np.where(singular, 1.0, r)[..., None]
        out_q = []
        out_R = []
        for s_shaft in (1.0, -1.0):
            us = s_shaft * u
            # u' = RotX(alpha1)^T u = (s3 sin(t2) cos(t1), s3 sin(t2) sin(t1), -s3 s2 cos(t2))
            up = us @ self._R_pre1
            rho = np.hypot(up[..., 0], up[..., 1])
            for b in (1.0, -1.0):
                t2 = np.arctan2(b * rho, -self._s3 * self._s2 * up[..., 2])
                sb = self._s3 * b
                t1_ref = self._theta0[0] + q_ref[:, None, 0]
                t1 = np.where(rho > 1e-12, np.arctan2(sb * up[..., 1], sb * up[..., 0]), t1_ref)
                q3 = s_shaft * r - self._shaft_offset
                out_q.append(np.stack([t1 - self._theta0[0], t2 - self._theta0[1], q3], axis=-1))
                R3 = (self._R_pre1 @ _rot_z_batch(t1) @ self._R_x2 @ _rot_z_batch(t2)
                      @ self._R_x3_z3)
                out_R.append(R3)
        return np.stack(out_q, axis=-2), np.stack(out_R, axis=-3), singular

    def _select(self, cand, q_ref, feasible):
        """
        Wrap revolute joints near q_ref, check limits and pick the closest valid branch.

        Parameters
        ----------
        cand : ndarray, shape (m, B, n)
        q_ref : ndarray, shape (m, n)
        feasible : ndarray of bool, shape (m, B)

        Returns
        -------
        q : ndarray, shape (m, n)
        in_limits : ndarray of bool, shape (m,)
        any_feasible : ndarray of bool, shape (m,)

        """
        ref = q_ref[:, None, :]
        rev = self.is_revolute
        k = np.round((ref - cand) / _TWO_PI)
        opts = cand[..., None] + _TWO_PI * (k[..., None] + np.array([-1.0, 0.0, 1.0]))
        opts = np.where(rev[:, None], opts, cand[..., None])
        lo = (self.lower - _LIMIT_SLACK)[:, None]
        hi = (self.upper + _LIMIT_SLACK)[:, None]
        inside = (opts >= lo) & (opts <= hi)
        dist = np.abs(opts - ref[..., None])
        pick = np.where(inside.any(-1), np.argmin(np.where(inside, dist, np.inf), axis=-1), 1)
        q = np.take_along_axis(opts, pick[..., None], axis=-1)[..., 0]
        violation = np.maximum(0.0, np.maximum(self.lower - q, q - self.upper)) / self._ranges
        violation = violation.sum(-1)
        valid = feasible & (violation <= _LIMIT_SLACK)
        cost = np.sum(((q - ref) / self._ranges) ** 2, axis=-1)
        score = np.where(valid, cost, np.where(feasible, 1e6 + violation, np.inf))
        best = np.argmin(score, axis=1)
        q_best = np.take_along_axis(q, best[:, None, None], axis=1)[:, 0]
        in_limits = np.take_along_axis(valid, best[:, None], axis=1)[:, 0]
        q_best = np.where(in_limits[:, None], np.clip(q_best, self.lower, self.upper), q_best)
        return q_best, in_limits, feasible.any(axis=1)

    def _prepare_ik(self, T, q_ref):
        T = check_poses(T)
        m = T.shape[0]
        if q_ref is None:
            q_ref = np.broadcast_to(self.home, (m, self.n_joints))
        else:
            q_ref = np.asarray(q_ref, dtype=float)
            if q_ref.shape == (self.n_joints,):
                q_ref = np.broadcast_to(q_ref, (m, self.n_joints))
            if q_ref.shape != (m, self.n_joints) or not np.all(np.isfinite(q_ref)):
                raise ValueError(f'q_ref must be finite with shape ({self.n_joints},) or '
                                 f'({m}, {self.n_joints}), got shape {q_ref.shape}')
        T_last = T @ np.linalg.inv(self.tooltip_offset)
        return T, q_ref, T_last

    def _solve(self, T_last, q_ref):
        """Candidates (m, B, n) and feasibility (m, B) for last-link poses T_last (m, 4, 4)."""
        raise NotImplementedError

    def _ik_core(self, T, q_ref):
        """Return q (m, n), status (m,) with 0 ok, 1 singular, 2 limits, 3 pose mismatch."""
        T, q_ref, T_last = self._prepare_ik(T, q_ref)
        cand, feasible = self._solve(T_last, q_ref)
        q, in_limits, any_feasible = self._select(cand, q_ref, feasible)
        status = np.where(in_limits, 0, np.where(any_feasible, 2, 1))
        solved = status == 0
        if np.any(solved):
            Tq = self.fk_batch(np.where(solved[:, None], q, self.home))
            pos_err = np.linalg.norm(Tq[:, :3, 3] - T[:, :3, 3], axis=-1)
            rot_err = rotation_angle(Tq[:, :3, :3], T[:, :3, :3])
            mismatch = solved & ((pos_err > IK_TOLERANCE) | (rot_err > IK_TOLERANCE))
            status = np.where(mismatch, 3, status)
        else:
            pos_err = rot_err = np.zeros(len(q))
        return q, status, (pos_err, rot_err)

    def ik_batch(self, T, q_ref=None):
        """
        Closed-form inverse kinematics for many tool-tip poses.

        Parameters
        ----------
        T : array_like, shape (m, 4, 4)
            Tool-tip poses ``T_base_tip`` in the RCM frame ``<ARM>_base`` (metres).
        q_ref : array_like, shape (n,) or (m, n), optional
            Reference configuration(s) (rad / m): the branch closest to it wins and revolute
            joints are wrapped by 2*pi towards it. Default: :attr:`home`.

        Returns
        -------
        Q : ndarray, shape (m, n)
            Joint solutions (rad / m); rows of unreachable poses are NaN.
        reachable : ndarray of bool, shape (m,)
            False where no solution inside the joint limits reproduces the pose to
            ``IK_TOLERANCE`` (1e-6 m / rad).

        """
        q, status, _ = self._ik_core(T, q_ref)
        ok = status == 0
        return np.where(ok[:, None], q, np.nan), ok

    def ik(self, T, q_ref=None):
        """
        Closed-form inverse kinematics of one tool-tip pose.

        Parameters
        ----------
        T : array_like, shape (4, 4)
            Tool-tip pose ``T_base_tip`` in the RCM frame ``<ARM>_base`` (metres).
        q_ref : array_like, shape (n,), optional
            Reference configuration (rad / m), typically the current setpoint; the solution
            branch closest to it is returned and revolute joints (roll) are wrapped towards it.
            Default: :attr:`home`.

        Returns
        -------
        ndarray, shape (n,)
            Joint values inside the limits with ``fk(q) == T`` to 1e-6 m / rad.

        Raises
        ------
        UnreachableError
            The pose needs joint values outside the limits, sits on a singularity, or (ECM)
            has an orientation the chain cannot produce.
        ValueError
            ``T`` or ``q_ref`` is malformed (shape, NaN/inf, not a rotation).

        """
        T = check_pose(T)
        if q_ref is not None:
            q_ref = self.check_q(q_ref, name='q_ref')
        q, status, (pos_err, rot_err) = self._ik_core(T[None], q_ref)
        q, status = q[0], int(status[0])
        if status == 0:
            return q
        p = T[:3, 3]
        where = f'position ({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m'
        if status == 1:
            raise UnreachableError(
                f'{self.name}: pose at {where} is singular: {self._singular_reason()}')
        if status == 2:
            bad = []
            for name, v, lo, hi, rev in zip(self.joint_names, q, self.lower, self.upper,
                                            self.is_revolute):
                if v < lo - _LIMIT_SLACK or v > hi + _LIMIT_SLACK:
                    unit = 'rad' if rev else 'm'
                    bad.append(f'{name} = {v:.4f} {unit} outside [{lo:.4f}, {hi:.4f}]')
            raise UnreachableError(
                f'{self.name}: pose at {where} is outside the joint limits; the closest solution '
                f'needs ' + ', '.join(bad))
        raise UnreachableError(
            f'{self.name}: pose at {where} cannot be reached: the best solution misses it by '
            f'{pos_err[0]:.3g} m and {rot_err[0]:.3g} rad{self._mismatch_reason()}')

    def _singular_reason(self):
        return 'the wrist centre is at the remote centre of motion'

    def _mismatch_reason(self):
        return ''


class PsmKinematics(_RcmChain):
    """
    Patient-side manipulator: 3 arm joints + 3 tool joints, jaw alongside the chain.

    Parameters
    ----------
    joints : sequence of DhJoint
        ``yaw, pitch, insertion, roll, wrist_pitch, wrist_yaw``.
    tooltip_offset : array_like, shape (4, 4)
        Tip pose in the wrist-yaw DH frame.
    jaw : JawLimits
        Jaw range (rad) and trajectory limits.
    home : array_like, shape (6,), optional
        Home configuration (rad / m).
    name : str
        Label used in messages.
    tool_type : str
        dVRK tool name (``'LARGE_NEEDLE_DRIVER:420006[1]'``).

    Attributes
    ----------
    jaw_lower, jaw_upper : float
        Jaw angle limits (rad).
    jaw_v_max, jaw_a_max : float
        Jaw velocity (rad/s) and acceleration (rad/s^2) limits.
    tool_type : str

    """

    def __init__(self, joints, tooltip_offset, jaw, home=None, name='PSM', tool_type=''):
        super().__init__(joints, tooltip_offset, home=home, name=name)
        if self.n_joints != 6:
            raise ValueError(f'{name}: a PSM chain has 6 joints, got {self.n_joints}')
        self._check_rcm_structure()
        j5, j6 = self.joints[4], self.joints[5]
        if not (j5.is_revolute and j6.is_revolute):
            raise ValueError(f'{name}: wrist joints must be revolute')
        if abs(j5.a) > _STRUCTURE_TOL or abs(j5.d) > _STRUCTURE_TOL:
            raise ValueError(f'{name}: IK expects the wrist-pitch axis to cross the shaft '
                             f'(a = d = 0 for {j5.name!r})')
        self._s5 = _sign_of_right_angle(j5.alpha, f'{name} joint {j5.name!r}')
        self._s6 = _sign_of_right_angle(j6.alpha, f'{name} joint {j6.name!r}')
        self._R_x5 = _rot_x(j5.alpha)
        self._R_x6 = _rot_x(j6.alpha)
        self._a6 = j6.a
        self._d6 = self._d0[5]
        self.jaw_lower = float(jaw.lower)
        self.jaw_upper = float(jaw.upper)
        self.jaw_v_max = float(jaw.v_max)
        self.jaw_a_max = float(jaw.a_max)
        self.tool_type = tool_type

    def clip_jaw(self, angle):
        """
        Clip a jaw angle (rad) into ``[jaw_lower, jaw_upper]``.

        Parameters
        ----------
        angle : float
            Jaw opening angle (rad).

        Returns
        -------
        float

        """
        return float(np.clip(angle, self.jaw_lower, self.jaw_upper))

    def _singular_reason(self):
        return ('the tool tip lies on the wrist-yaw axis line through the RCM, or the '
                'wrist-pitch point is at the RCM (insertion near the shaft offset); move the '
                'tip off that line')

    def _solve(self, T_last, q_ref):
        m = T_last.shape[0]
        R6 = T_last[:, :3, :3]
        z6 = R6[:, :, 2]
        x6 = R6[:, :, 0]
        # frame-6 origin = wrist-pitch point + a6 * x5 + d6 * z6, with x5 perpendicular to z6
        p = T_last[:, :3, 3] - self._d6 * z6
        n_vec = p - np.sum(p * z6, axis=-1, keepdims=True) * z6
        n_norm = np.linalg.norm(n_vec, axis=-1)
        degenerate = n_norm < 1e-9
        n_hat = n_vec / np.where(degenerate, 1.0, n_norm)[:, None]
        x5 = np.stack([n_hat, -n_hat], axis=1)  # (m, 2, 3)
        P_wrist = p[:, None, :] - self._a6 * x5  # (m, 2, 3)
        q123, R3, singular = self._shaft_solutions(P_wrist, q_ref)  # (m,2,4,3), (m,2,4,3,3)
        x5b = np.broadcast_to(x5[:, :, None, :], R3.shape[:-1])
        z6b = np.broadcast_to(z6[:, None, None, :], R3.shape[:-1])
        x6b = np.broadcast_to(x6[:, None, None, :], R3.shape[:-1])
        # z6 = R5 RotX(alpha6) e_z = -s6 * y5  =>  z5 = x5 x y5 = -s6 * (x5 x z6)
        z5 = -self._s6 * np.cross(x5b, z6b)
        w = np.einsum('...ji,...j->...i', R3, z5)  # R3^T z5 (alpha4 = 0, a4 = 0)
        # z5 = R4 RotX(alpha5) e_z = R4 (0, -s5, 0):  sin t4 = s5 w_x, cos t4 = -s5 w_y
        t4 = np.arctan2(self._s5 * w[..., 0], -self._s5 * w[..., 1])
        R4 = R3 @ _rot_z_batch(t4)
        Rpre5 = R4 @ self._R_x5
        v5 = np.einsum('...ji,...j->...i', Rpre5, x5b)
        t5 = np.arctan2(v5[..., 1], v5[..., 0])
        Rpre6 = Rpre5 @ _rot_z_batch(t5) @ self._R_x6
        v6 = np.einsum('...ji,...j->...i', Rpre6, x6b)
        t6 = np.arctan2(v6[..., 1], v6[..., 0])
        q = np.concatenate([q123, np.stack([t4 - self._theta0[3], t5 - self._theta0[4],
                                            t6 - self._theta0[5]], axis=-1)], axis=-1)
        q = q.reshape(m, -1, self.n_joints)
        feasible = ~(degenerate[:, None] | singular)  # (m, 2)
        feasible = np.repeat(feasible, 4, axis=1)
        return q, feasible


class EcmKinematics(_RcmChain):
    """
    Endoscope camera manipulator: yaw, pitch, insertion, roll.

    With four joints the reachable tool-tip poses are those whose camera axis (tip z) points
    along the line from the RCM to the tip; :meth:`ik` reports any other pose as unreachable.

    Parameters
    ----------
    joints : sequence of DhJoint
        ``yaw, pitch, insertion, roll``.
    tooltip_offset : array_like, shape (4, 4)
        Camera (tip) pose in the roll DH frame.
    home : array_like, shape (4,), optional
        Home configuration (rad / m).
    name : str
        Label used in messages.
    endoscope_type : str
        dVRK endoscope name (``'Classic_SD_STRAIGHT'``).

    """

    def __init__(self, joints, tooltip_offset, home=None, name='ECM', endoscope_type=''):
        super().__init__(joints, tooltip_offset, home=home, name=name)
        if self.n_joints != 4:
            raise ValueError(f'{name}: an ECM chain has 4 joints, got {self.n_joints}')
        self._check_rcm_structure()
        self.endoscope_type = endoscope_type

    def _mismatch_reason(self):
        return (' (the ECM has 4 joints: the camera axis must point along the line from the RCM '
                'to the tip)')

    def _solve(self, T_last, q_ref):
        m = T_last.shape[0]
        P = T_last[:, None, :3, 3]  # roll-frame origin is on the shaft
        q123, R3, singular = self._shaft_solutions(P, q_ref)  # (m,1,4,3), (m,1,4,3,3)
        x4 = np.broadcast_to(T_last[:, None, None, :3, 0], R3.shape[:-1])
        v = np.einsum('...ji,...j->...i', R3, x4)
        t4 = np.arctan2(v[..., 1], v[..., 0])
        q = np.concatenate([q123, (t4 - self._theta0[3])[..., None]], axis=-1)
        q = q.reshape(m, -1, self.n_joints)
        feasible = np.repeat(~singular, 4, axis=1)
        return q, feasible


# ---------------------------------------------------------------------------------------------
# pinocchio model of a chain


def pinocchio_model(chain):
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
    for j, C, theta0, d0 in zip(chain.joints, chain._const, chain._theta0, chain._d0):
        M = C.copy()
        M[:3, :3] = M[:3, :3] @ _rot_z_batch(theta0)
        M[:3, 3] = M[:3, 3] + M[:3, :3] @ np.array([0.0, 0.0, d0])
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


# ---------------------------------------------------------------------------------------------
# factories reading config/kinematics.yaml


def _normalise_tool_name(tool):
    """Accept dVRK spellings: ``LARGE_NEEDLE_DRIVER:420006[1]`` -> ``..._420006``."""
    return re.sub(r'\[\d+\]$', '', tool.strip()).replace(':', '_')


def read_kinematics_config(path=None):
    """
    Read ``config/kinematics.yaml`` into a :class:`KinematicsConfig`.

    Parameters
    ----------
    path : str or Path, optional
        File to read; default: the package's ``config/kinematics.yaml``.

    Returns
    -------
    KinematicsConfig

    """
    path = config_path('kinematics.yaml') if path is None else path
    data = load_yaml(path)
    return dataclass_from_mapping(KinematicsConfig, data, source=str(path))


def _pick(mapping, key, what, source):
    if key not in mapping:
        raise ConfigError(f'{source}: unknown {what} {key!r}; expected one of {sorted(mapping)}')
    return mapping[key]


def psm_kinematics(tool=None, path=None, arm=None):
    """
    Build the PSM kinematics for a tool (and, by default, the arm generation it mounts on).

    Parameters
    ----------
    tool : str, optional
        ``'LARGE_NEEDLE_DRIVER_420006'`` (Si, default) or ``'LARGE_NEEDLE_DRIVER_400006'``
        (Classic); dVRK spellings like ``'LARGE_NEEDLE_DRIVER:420006[1]'`` are accepted.
    path : str or Path, optional
        Kinematics YAML; default: the package's ``config/kinematics.yaml``.
    arm : str, optional
        Arm generation (``'Si'`` or ``'Classic'``) overriding the tool's own.

    Returns
    -------
    PsmKinematics

    """
    cfg = read_kinematics_config(path)
    source = str(path or 'kinematics.yaml')
    tool = _normalise_tool_name(tool or cfg.defaults.psm_tool)
    tool_cfg = _pick(cfg.psm_tools, tool, 'PSM tool', source)
    generation = arm or tool_cfg.arm
    arm_cfg = _pick(cfg.psm_arms, generation, 'PSM arm generation', source)
    return PsmKinematics(arm_cfg.joints + tool_cfg.joints, np.array(tool_cfg.tooltip_offset),
                         tool_cfg.jaw, home=cfg.psm_home, name=f'PSM {generation} + {tool}',
                         tool_type=tool_cfg.tool_type)


def ecm_kinematics(generation=None, endoscope=None, path=None):
    """
    Build the ECM kinematics.

    Parameters
    ----------
    generation : str, optional
        ``'Classic'`` (default) or ``'Si'``.
    endoscope : str, optional
        ``'STRAIGHT'`` (default), ``'UP'`` (tip tilted by RotX(-30 deg)) or ``'DOWN'``
        (RotX(+30 deg)).
    path : str or Path, optional
        Kinematics YAML; default: the package's ``config/kinematics.yaml``.

    Returns
    -------
    EcmKinematics

    """
    cfg = read_kinematics_config(path)
    source = str(path or 'kinematics.yaml')
    generation = generation or cfg.defaults.ecm_generation
    endoscope = endoscope or cfg.defaults.ecm_endoscope
    arm_cfg = _pick(cfg.ecm_arms, generation, 'ECM generation', source)
    tilt = _pick(cfg.ecm_endoscopes, endoscope, 'endoscope', source)
    offset = np.array(cfg.ecm_tooltip_offset)
    offset[:3, :3] = offset[:3, :3] @ _rot_x(tilt)
    return EcmKinematics(arm_cfg.joints, offset, home=cfg.ecm_home,
                         name=f'ECM {generation} {endoscope}',
                         endoscope_type=f'{arm_cfg.endoscope_prefix}_{endoscope}')


def load_kinematics(path=None):
    """
    Build the default PSM and ECM kinematics named in the file's ``defaults``.

    Parameters
    ----------
    path : str or Path, optional
        Kinematics YAML; default: the package's ``config/kinematics.yaml``.

    Returns
    -------
    dict
        ``{'PSM': PsmKinematics, 'ECM': EcmKinematics}``.

    """
    return {'PSM': psm_kinematics(path=path), 'ECM': ecm_kinematics(path=path)}
