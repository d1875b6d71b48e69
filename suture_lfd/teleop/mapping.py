"""
The MTM -> PSM mapping of the dVRK's teleoperation, with the frames written out.

Frames: ``M`` is the frame of the MTM's ``measured_cp`` (a console's display frame, ``HRSV`` for
the virtual MTMs, whose axes are the camera's), ``P`` the frame of the PSM's
``measured_cp``/``servo_cp`` (the ECM tip ``ECM`` on a patient cart, or ``<PSM>_base``), ``C`` the
camera (ECM tip, optical convention: x right, y down, z along the view). ``R_C_M`` and ``R_C_P``
rotate M and P coordinates into C; on a patient cart with a console both are the identity.

At an anchor (entering following, and again after every clutch release) the MTM pose
``T_M_mtm0`` and the PSM setpoint ``T_P_psm0`` are kept; then, as the dVRK's teleoperation
(``dvrk_teleoperation.py``: ``puppet_translation = scale (p_mtm - p_mtm0) + p_psm0`` and
``puppet_rotation = R_mtm alignment_offset``)::

    A      = R_C_P^T R_C_M                     (MTM frame -> PSM frame, through the camera)
    p_goal = p_psm0 + scale A (p_mtm - p_mtm0)
    R_goal = A R_mtm offset,   offset = (A R_mtm0)^T R_psm0

so a hand moving right in the camera view moves the tool right in the camera image, and the
goal equals the PSM setpoint at the anchor (no jump when the clutch is released).

Gripper -> jaw: ``jaw = jaw_at_gripper_zero + (g - gripper_zero) k`` with
``k = (jaw_max - jaw_at_gripper_zero) / (gripper_max - gripper_zero)``, limited to
``[jaw_min, jaw_max]``; the jaw follows a "ghost" gripper angle that moves at most
``jaw_rate`` rad/s (``jaw_rate_back_from_clutch`` after a clutch until the ghost has caught up
with the gripper within ``tolerance_back_from_clutch``), as the dVRK does. The dVRK maps
``gripper_zero`` to a jaw of 0 (``jaw_at_gripper_zero = 0``): a physical MTM gripper reads below
zero when squeezed, which an everyday device cannot, so the default maps the device's closed
end to ``jaw_min`` (gripper 0..60 deg -> jaw -20..80 deg).

Rotations are 3x3 arrays, poses 4x4 homogeneous matrices ``T_a_b``; SI units.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.validation import check_positive

DEG = math.pi / 180.0


@dataclass(frozen=True)
class GripperToJaw:
    """
    Gripper angle (rad) -> jaw angle (rad) of the dVRK teleoperation, with its rate limits.

    Attributes
    ----------
    gripper_zero, gripper_max : float
        Gripper angles (rad) of the closed and the open end of the mapped range.
    jaw_min, jaw_max : float
        Jaw limits (rad) of the Large Needle Driver.
    jaw_at_gripper_zero : float
        Jaw angle (rad) at ``gripper_zero`` (the dVRK: 0).
    jaw_rate, jaw_rate_back_from_clutch : float
        Fastest change (rad/s, of the gripper angle) of the ghost gripper.
    tolerance_back_from_clutch : float
        Gripper error (rad) below which the ghost has caught up after a clutch.

    """

    gripper_zero: float = 0.0
    gripper_max: float = 60.0 * DEG
    jaw_min: float = -20.0 * DEG
    jaw_max: float = 80.0 * DEG
    jaw_at_gripper_zero: float = -20.0 * DEG
    jaw_rate: float = 2.0 * math.pi
    jaw_rate_back_from_clutch: float = 0.05 * math.pi
    tolerance_back_from_clutch: float = 2.0 * DEG

    def __post_init__(self) -> None:
        if not self.gripper_max > self.gripper_zero:
            raise ValueError(f'gripper_max ({self.gripper_max}) must be > gripper_zero '
                             f'({self.gripper_zero})')
        if not self.jaw_max > self.jaw_min:
            raise ValueError(f'jaw_max ({self.jaw_max}) must be > jaw_min ({self.jaw_min})')
        for name in ('jaw_rate', 'jaw_rate_back_from_clutch', 'tolerance_back_from_clutch'):
            check_positive(getattr(self, name), name)

    @property
    def scale(self) -> float:
        """Jaw radians per gripper radian."""
        return (self.jaw_max - self.jaw_at_gripper_zero) / (self.gripper_max - self.gripper_zero)

    def jaw_from_gripper(self, gripper: float) -> float:
        """Return the jaw angle (rad) of a gripper angle (rad), within the jaw limits."""
        jaw = self.jaw_at_gripper_zero + (gripper - self.gripper_zero) * self.scale
        return min(self.jaw_max, max(self.jaw_min, jaw))

    def gripper_from_jaw(self, jaw: float) -> float:
        """Return the gripper angle (rad) that maps to a jaw angle (rad)."""
        return self.gripper_zero + (jaw - self.jaw_at_gripper_zero) / self.scale


class JawRamp:
    """
    The rate-limited ghost gripper that the jaw follows.

    Parameters
    ----------
    mapping : GripperToJaw

    """

    def __init__(self, mapping: GripperToJaw) -> None:
        self.mapping = mapping
        self.ghost: float | None = None
        self.caught_up = True

    def start(self, jaw: float, back_from_clutch: bool = False) -> None:
        """Start from the PSM's jaw setpoint ``jaw`` (rad), slowly if back from a clutch."""
        self.ghost = self.mapping.gripper_from_jaw(jaw)
        self.caught_up = not back_from_clutch

    def step(self, gripper: float, dt: float) -> float:
        """
        Move the ghost towards ``gripper`` (rad) for ``dt`` s; return the jaw goal (rad).

        Raises
        ------
        RuntimeError
            If :meth:`start` was not called.

        """
        m = self.mapping
        if self.ghost is None:
            raise RuntimeError('JawRamp.step before start')
        if not self.caught_up and abs(gripper - self.ghost) < m.tolerance_back_from_clutch:
            self.caught_up = True
        delta = (m.jaw_rate if self.caught_up else m.jaw_rate_back_from_clutch) * dt
        if self.ghost <= gripper - delta:
            self.ghost += delta
        elif self.ghost >= gripper + delta:
            self.ghost -= delta
        else:
            self.ghost = gripper
        jaw = m.jaw_from_gripper(self.ghost)
        self.ghost = min(self.ghost, m.gripper_from_jaw(m.jaw_max))
        self.ghost = max(self.ghost, m.gripper_from_jaw(m.jaw_min))
        return jaw


def rotation_angle(R: np.ndarray) -> float:
    """Return the angle (rad, in [0, pi]) of a 3x3 rotation matrix."""
    c = (R[0][0] + R[1][1] + R[2][2] - 1.0) * 0.5
    return math.acos(max(-1.0, min(1.0, c)))


class CartesianMap:
    """
    MTM pose -> PSM goal, anchored where following starts.

    Parameters
    ----------
    scale : float
        PSM translation per MTM translation (the dVRK: 0.2).
    rotation_locked, translation_locked : bool
        Keep the PSM's anchor orientation / position (the dVRK teleop's locks).

    """

    def __init__(self, scale: float = 0.2, rotation_locked: bool = False,
                 translation_locked: bool = False) -> None:
        check_positive(scale, 'scale')
        self.scale = float(scale)
        self.rotation_locked = rotation_locked
        self.translation_locked = translation_locked
        self._A: np.ndarray | None = None
        self._p_mtm0: np.ndarray | None = None
        self._p_psm0: np.ndarray | None = None
        self._R_psm0: np.ndarray | None = None
        self._offset: np.ndarray | None = None

    @property
    def anchored(self) -> bool:
        """Whether :meth:`anchor` was called."""
        return self._A is not None

    @staticmethod
    def mtm_to_psm(R_C_M: ArrayLike, R_C_P: ArrayLike) -> np.ndarray:
        """Return ``A = R_C_P^T R_C_M``, MTM-frame vectors in the PSM frame, shape (3, 3)."""
        return np.asarray(R_C_P, dtype=float).T @ np.asarray(R_C_M, dtype=float)

    def anchor(self, T_M_mtm: ArrayLike, T_P_psm: ArrayLike, R_C_M: ArrayLike,
               R_C_P: ArrayLike) -> None:
        """
        Anchor the map: the MTM at ``T_M_mtm`` maps to the PSM at ``T_P_psm`` (4x4 each).

        Parameters
        ----------
        T_M_mtm : array_like, shape (4, 4)
            MTM ``measured_cp`` in its frame M.
        T_P_psm : array_like, shape (4, 4)
            PSM ``setpoint_cp`` in its frame P.
        R_C_M, R_C_P : array_like, shape (3, 3)
            Rotations of M and P into the camera frame C.

        """
        T_M_mtm = np.asarray(T_M_mtm, dtype=float)
        T_P_psm = np.asarray(T_P_psm, dtype=float)
        self._A = self.mtm_to_psm(R_C_M, R_C_P)
        self._p_mtm0 = T_M_mtm[:3, 3].copy()
        self._p_psm0 = T_P_psm[:3, 3].copy()
        self._R_psm0 = T_P_psm[:3, :3].copy()
        self._offset = (self._A @ T_M_mtm[:3, :3]).T @ self._R_psm0

    def goal(self, T_M_mtm: ArrayLike) -> np.ndarray:
        """
        Return the PSM goal (4x4, frame P) of an MTM pose (4x4, frame M).

        Raises
        ------
        RuntimeError
            If the map is not anchored.

        """
        if self._A is None:
            raise RuntimeError('CartesianMap.goal before anchor')
        # set with _A by anchor()
        assert self._p_mtm0 is not None and self._p_psm0 is not None
        assert self._R_psm0 is not None and self._offset is not None
        T_M_mtm = np.asarray(T_M_mtm, dtype=float)
        T = np.eye(4)
        if self.translation_locked:
            T[:3, 3] = self._p_psm0
        else:
            T[:3, 3] = self._p_psm0 + self.scale * (self._A @ (T_M_mtm[:3, 3] - self._p_mtm0))
        if self.rotation_locked:
            T[:3, :3] = self._R_psm0
        else:
            T[:3, :3] = self._A @ T_M_mtm[:3, :3] @ self._offset
        return T

    @staticmethod
    def aligned_mtm_rotation(R_P_psm: ArrayLike, R_C_M: ArrayLike,
                             R_C_P: ArrayLike) -> np.ndarray:
        """Return the MTM orientation (frame M, 3x3) that is aligned with the PSM's."""
        return CartesianMap.mtm_to_psm(R_C_M, R_C_P).T @ np.asarray(R_P_psm, dtype=float)

    @staticmethod
    def alignment_error(R_M_mtm: ArrayLike, R_P_psm: ArrayLike, R_C_M: ArrayLike,
                        R_C_P: ArrayLike) -> float:
        """Return the angle (rad) between the MTM's and the PSM's orientations, seen in C."""
        A = CartesianMap.mtm_to_psm(R_C_M, R_C_P)
        return rotation_angle((A @ np.asarray(R_M_mtm, dtype=float)).T
                              @ np.asarray(R_P_psm, dtype=float))
