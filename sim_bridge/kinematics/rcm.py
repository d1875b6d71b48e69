"""
Closed-form inverse kinematics of the dVRK arms around their remote centre of motion (RCM).

The PSM inverse kinematics keeps the RCM by construction: the tool tip lies on the wrist-yaw
axis, so the wrist-pitch point, the tip and the RCM span the plane of the wrist-yaw axis and the
shaft; that plane gives the wrist-pitch point, the shaft through the RCM gives yaw, pitch and
insertion, and the tool-tip orientation gives roll, wrist pitch and wrist yaw. The ECM (four
joints) solves yaw, pitch and insertion from the tip position and roll from the orientation;
:meth:`EcmKinematics.ik_position` does so for any orientation (the roll about the shaft closest
to it), which is how the ECM follows Cartesian goals.
Every branch is enumerated and the one inside the joint limits closest to a reference
configuration wins; revolute joints are wrapped by 2*pi towards the reference.

Poses are tool tips in the RCM frame ``<ARM>_base`` (metres, 4x4); joints in rad / m.

Size: the closed-form PSM and ECM solutions share the RCM geometry and the joint-limit handling;
the per-step solvers stay in one file for speed.
"""

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sim_bridge.common.errors import UnreachableError
from sim_bridge.kinematics.dh_chain import (
    DhJoint,
    SerialChain,
    check_pose,
    check_poses,
    pose_mismatch_values,
    rotation_angle,
    rotation_x,
    rotation_z,
)
from sim_bridge.kinematics.psm_ik import PsmSingleIk

FloatArray = NDArray[np.float64]
_TWO_PI = 2.0 * np.pi
_STRUCTURE_TOL = 1e-9
# Round-trip tolerance of an IK solution (metres and radians).
IK_TOLERANCE = 1e-6
# Joint values this far outside a limit (rounding) are clipped onto it instead of rejected.
_LIMIT_SLACK = 1e-9


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


def _sign_of_right_angle(alpha: float, what: str) -> float:
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

    def _check_rcm_structure(self) -> None:
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
        self._R_pre1 = rotation_x(j[0].alpha)
        self._R_x2 = rotation_x(j[1].alpha)
        self._R_x3_z3 = rotation_x(j[2].alpha) @ rotation_z(self._theta0[2])
        # distance RCM -> roll frame origin along the shaft = d3 + d4 = q3 + shaft_offset
        self._shaft_offset = self._d0[2] + self._d0[3]
        self._ranges = self.upper - self.lower
        self._tooltip_inverse = np.linalg.inv(self.tooltip_offset)
        # a one-pose solver in plain floats, where the chain has one
        self._single: PsmSingleIk | None = None

    def _shaft_solutions(self, P: np.ndarray,
                         q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
        # branches: (shaft sign, pitch sign) = (+, +), (+, -), (-, +), (-, -)
        s_shaft = np.array([1.0, 1.0, -1.0, -1.0])
        b = np.array([1.0, -1.0, 1.0, -1.0])
        # u' = RotX(alpha1)^T u = (s3 sin(t2) cos(t1), s3 sin(t2) sin(t1), -s3 s2 cos(t2))
        up = (u @ self._R_pre1)[..., None, :] * s_shaft[:, None]  # (m, k, 4, 3)
        rho = np.hypot(up[..., 0], up[..., 1])
        t2 = np.arctan2(b * rho, -self._s3 * self._s2 * up[..., 2])
        sb = self._s3 * b
        t1_ref = (self._theta0[0] + q_ref[:, 0])[:, None, None]
        t1 = np.where(rho > 1e-12, np.arctan2(sb * up[..., 1], sb * up[..., 0]), t1_ref)
        q3 = s_shaft * r[..., None] - self._shaft_offset
        q123 = np.stack([t1 - self._theta0[0], t2 - self._theta0[1], q3], axis=-1)
        R3 = self._R_pre1 @ rotation_z(t1) @ self._R_x2 @ rotation_z(t2) @ self._R_x3_z3
        return q123, R3, singular

    def _select(self, cand: np.ndarray, q_ref: np.ndarray,
                feasible: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
        return q_best, in_limits, np.asarray(feasible.any(axis=1))

    def _prepare_ik(self, T: ArrayLike, q_ref: ArrayLike | None,
                    checked: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        poses = np.asarray(T) if checked else check_poses(T)
        m = poses.shape[0]
        if q_ref is None:
            ref = np.broadcast_to(self.home, (m, self.n_joints))
        else:
            ref = np.asarray(q_ref, dtype=float)
            if ref.shape == (self.n_joints,):
                ref = np.broadcast_to(ref, (m, self.n_joints))
            if ref.shape != (m, self.n_joints) or not np.all(np.isfinite(ref)):
                raise ValueError(f'q_ref must be finite with shape ({self.n_joints},) or '
                                 f'({m}, {self.n_joints}), got shape {ref.shape}')
        T_last = poses @ self._tooltip_inverse
        return poses, ref, T_last

    def _solve(self, T_last: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidates (m, B, n) and feasibility (m, B) for last-link poses T_last (m, 4, 4)."""
        raise NotImplementedError

    def _ik_core(self, T: ArrayLike, q_ref: ArrayLike | None, checked: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """Return q (m, n), status (m,) with 0 ok, 1 singular, 2 limits, 3 pose mismatch."""
        T, q_ref, T_last = self._prepare_ik(T, q_ref, checked)
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

    def ik_batch(self, T: ArrayLike,
                 q_ref: ArrayLike | None = None) -> tuple[FloatArray, NDArray[np.bool_]]:
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

    def ik(self, T: ArrayLike, q_ref: ArrayLike | None = None) -> FloatArray:
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
        q = self._ik_single(T, self.home if q_ref is None else q_ref)
        if q is not None:
            return np.array(q)
        return self._ik_worded(T, q_ref)

    def ik_unchecked(self, T: FloatArray, q_ref: Sequence[float]) -> tuple[float, ...]:
        """
        :meth:`ik` of a pose and a reference already known to be valid, without checking them.

        Parameters
        ----------
        T : ndarray, shape (4, 4)
            Tool-tip pose, as :func:`check_pose` returned it (metres).
        q_ref : sequence of float, length n
            Finite reference configuration (rad / m), e.g. an arm's own setpoint.

        Returns
        -------
        tuple of float
            The joint values :meth:`ik` gives (rad / m).

        Raises
        ------
        UnreachableError
            As :meth:`ik`.

        """
        q = self._ik_single(T, q_ref)
        if q is not None:
            return tuple(q)
        return tuple(self._ik_worded(T, np.array(q_ref, dtype=float)).tolist())

    def _ik_single(self, T: FloatArray,
                   q_ref: Sequence[float] | FloatArray) -> list[float] | None:
        """Return the single-pose solver's answer when it is clean (list of float), else None."""
        if self._single is None:
            return None
        q = self._single.solve(T, q_ref)
        # the solver's finite floats need no check_q: their pose straight from the floats
        if q is not None and max(pose_mismatch_values(self._fk_values(q)[0], T)) <= IK_TOLERANCE:
            return q
        return None  # no clean solution here: the batch solver decides and words the error

    def _ik_worded(self, T: FloatArray, q_ref: FloatArray | None) -> FloatArray:
        """Batch-solve one checked pose; return q or raise UnreachableError saying why."""
        Q, codes, (pos_err, rot_err) = self._ik_core(T[None], q_ref, checked=True)
        q, status = Q[0], int(codes[0])
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

    def _singular_reason(self) -> str:
        return 'the wrist centre is at the remote centre of motion'

    def _mismatch_reason(self) -> str:
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

    def __init__(self, joints: Iterable[DhJoint], tooltip_offset: ArrayLike, jaw: JawLimits,
                 home: ArrayLike | None = None, name: str = 'PSM', tool_type: str = '') -> None:
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
        self._R_x5 = rotation_x(j5.alpha)
        self._R_x6 = rotation_x(j6.alpha)
        self._a6 = j6.a
        self._d6 = self._d0[5]
        self.jaw_lower = float(jaw.lower)
        self.jaw_upper = float(jaw.upper)
        self.jaw_v_max = float(jaw.v_max)
        self.jaw_a_max = float(jaw.a_max)
        self.tool_type = tool_type
        self._single = PsmSingleIk(self, _LIMIT_SLACK)

    def clip_jaw(self, angle: float) -> float:
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
        # np.clip with scalar bounds, written out: the angle wins a tie, NaN stays NaN
        x = float(angle)
        x = self.jaw_lower if x < self.jaw_lower else x
        return self.jaw_upper if x > self.jaw_upper else x

    def _singular_reason(self) -> str:
        return ('the tool tip lies on the wrist-yaw axis line through the RCM, or the '
                'wrist-pitch point is at the RCM (insertion near the shaft offset); move the '
                'tip off that line')

    def _solve(self, T_last: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
        R4 = R3 @ rotation_z(t4)
        Rpre5 = R4 @ self._R_x5
        v5 = np.einsum('...ji,...j->...i', Rpre5, x5b)
        t5 = np.arctan2(v5[..., 1], v5[..., 0])
        Rpre6 = Rpre5 @ rotation_z(t5) @ self._R_x6
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

    def __init__(self, joints: Iterable[DhJoint], tooltip_offset: ArrayLike,
                 home: ArrayLike | None = None, name: str = 'ECM',
                 endoscope_type: str = '') -> None:
        super().__init__(joints, tooltip_offset, home=home, name=name)
        if self.n_joints != 4:
            raise ValueError(f'{name}: an ECM chain has 4 joints, got {self.n_joints}')
        self._check_rcm_structure()
        self.endoscope_type = endoscope_type
        t = self.tooltip_offset[:3, 3]
        if abs(t[0]) > _STRUCTURE_TOL or abs(t[1]) > _STRUCTURE_TOL:
            raise ValueError(f'{name}: the camera tip must lie on the shaft axis (tooltip offset '
                             f'translation along z only), got {t.tolist()}')
        self._tip_along_shaft = float(t[2])  # roll-frame origin -> camera tip, along the shaft

    def ik_position(self, T: ArrayLike,
                    q_ref: ArrayLike | None = None) -> tuple[FloatArray, bool]:
        """
        Put the camera tip at the position of ``T``, rolled about the shaft towards its rotation.

        The tip position fixes yaw, pitch and insertion (the camera looks along the line from
        the RCM to the tip); roll is the rotation about the shaft that brings the tip frame
        closest to ``T``'s orientation (least-squares over the rotation matrix,
        ``atan2(M10 - M01, M00 + M11)`` with ``M`` the goal in the roll-less frame). A pose
        :meth:`ik` reaches gets the same joints.

        Parameters
        ----------
        T : array_like, shape (4, 4)
            Camera-tip goal ``T_base_tip`` in the RCM frame ``<ARM>_base`` (metres).
        q_ref : array_like, shape (4,), optional
            Reference configuration (rad / m): the closest branch wins and roll is wrapped by
            2*pi towards it. Default: :attr:`home`.

        Returns
        -------
        q : ndarray, shape (4,)
            Joint values (rad / m); outside the limits when ``inside`` is false.
        inside : bool
            Whether ``q`` is inside the joint limits, i.e. the position is in the workspace.

        Raises
        ------
        UnreachableError
            The position is the RCM itself (no shaft direction).
        ValueError
            ``T`` or ``q_ref`` is malformed.

        """
        T = check_pose(T)
        q_ref = self.home if q_ref is None else self.check_q(q_ref, name='q_ref')
        p = T[:3, 3]
        r = float(np.linalg.norm(p))
        if r < 1e-9:
            raise UnreachableError(f'{self.name}: a camera tip at the remote centre of motion '
                                   'has no shaft direction')
        P = p * ((r - self._tip_along_shaft) / r)
        q123, R3, _ = self._shaft_solutions(P[None, None, :], q_ref[None])
        M = np.swapaxes(R3, -1, -2) @ (T[:3, :3] @ self._tooltip_inverse[:3, :3])
        c, s = M[..., 0, 0] + M[..., 1, 1], M[..., 1, 0] - M[..., 0, 1]
        t4 = np.where(np.hypot(c, s) > 1e-9, np.arctan2(s, c), self._theta0[3] + q_ref[3])
        q = np.concatenate([q123, (t4 - self._theta0[3])[..., None]], axis=-1).reshape(1, 4, 4)
        q, inside, _ = self._select(q, q_ref[None], np.ones((1, 4), dtype=bool))
        return q[0], bool(inside[0])

    def _mismatch_reason(self) -> str:
        return (' (the ECM has 4 joints: the camera axis must point along the line from the RCM '
                'to the tip)')

    def _solve(self, T_last: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


