"""
A virtual MTM: the pose, gripper and wrist of a dVRK Master Tool Manipulator, driven by a device.

A device gives either an absolute handle pose (the viewer's 6-DOF handle) or a velocity (a
gamepad's sticks, a SpaceMouse) that :func:`integrate_twist` turns into a pose; in both cases
the device pose ``T_F_dev`` is in the MTM's frame F (``frame_id`` of its ``measured_cp``): the
console's display frame :data:`DISPLAY_FRAME`, aligned with the endoscope image as a surgeon's
console shows it (x right and y down in the image, z into it, origin at the camera), so that the
hand's motion in F is the tool's motion in the camera frame of a patient cart's PSMs, and plain
pose arithmetic between an MTM's ``measured_cp`` and a PSM's ``setpoint_cp`` teleoperates.
The MTM's measured pose is the device pose moved by an offset that the MTM's own commands
change, as a physical MTM's motors do:

- ``move_cp``: the MTM goes to the goal along a straight line and a slerp in ``move_duration``
  s (``is_busy`` true meanwhile, as a dVRK arm's trajectory), then stays there: the offset
  takes up the difference between the hand and the goal; with an imperfection
  (:mod:`suture_lfd.teleop.mtm_realism`) it ends a little off the goal, as a physical MTM's
  wrist does;
- ``lock_orientation``: the orientation stays at the given one, whatever the hand does;
  ``unlock_orientation``, or the operator letting go of the clutch pedal
  (:meth:`VirtualMtm.release_clutch`): it follows the hand's rotations again from there,
  without a jump.

Poses are 4x4 matrices ``T_F_x``; velocities ``(v, w)`` in m/s and rad/s, in frame F.
"""

from collections.abc import Iterable
import math

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import (
    matrix_from_quaternion,
    quaternion_from_matrix,
    quaternion_slerp,
)
from suture_lfd.teleop.mtm_realism import MtmImperfection

STATES = ('DISABLED', 'ENABLED')
# The console's display frame (named as the dVRK console's stereo viewer frame): the axes of the
# endoscope image (x right, y down, z into the view), its origin at the camera.
DISPLAY_FRAME = 'HRSV'


def deadband(values: Iterable[float], threshold: float) -> np.ndarray:
    """
    Return ``values`` with every component below ``threshold`` in magnitude set to 0.

    The rest is shifted towards 0 by ``threshold`` and rescaled so that 1 stays 1 (no step at
    the edge of the band), for inputs normalised to [-1, 1].

    Parameters
    ----------
    values : array_like, shape (n,)
    threshold : float
        In [0, 1).

    """
    if not 0.0 <= threshold < 1.0:
        raise ValueError(f'deadband threshold must be in [0, 1), got {threshold}')
    out: list[float] = []
    for x in values:
        a = abs(float(x))
        out.append(0.0 if a <= threshold else math.copysign((a - threshold) / (1 - threshold), x))
    return np.array(out)


def rotation_from_rotvec(r: ArrayLike) -> np.ndarray:
    """Return the 3x3 rotation of a rotation vector ``r`` (rad), Rodrigues' formula."""
    r = np.asarray(r, dtype=float)
    angle = float(np.linalg.norm(r))
    if angle < 1e-12:
        return np.eye(3)
    k = r / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def integrate_twist(T: ArrayLike, v: ArrayLike, w: ArrayLike, dt: float) -> np.ndarray:
    """
    Move the pose ``T`` (4x4, frame F) by the velocity ``(v, w)`` (frame F) for ``dt`` s.

    The position moves by ``v dt``; the orientation turns by ``w dt`` about F's axes, around
    the pose's own origin.
    """
    out = np.array(T, dtype=float)
    out[:3, 3] += np.asarray(v, dtype=float) * dt
    out[:3, :3] = rotation_from_rotvec(np.asarray(w, dtype=float) * dt) @ out[:3, :3]
    return out


class VirtualMtm:
    """
    One virtual MTM.

    Parameters
    ----------
    name : str
        ``MTML`` or ``MTMR``.
    T_F_dev : array_like, shape (4, 4)
        Device pose at start.
    move_duration : float
        s a ``move_cp`` takes.
    imperfection : MtmImperfection, optional
        Where a ``move_cp`` really ends (:meth:`MtmImperfection.reached`); None: at the goal.

    """

    def __init__(self, name: str, T_F_dev: ArrayLike | None = None,
                 move_duration: float = 0.5,
                 imperfection: MtmImperfection | None = None) -> None:
        self.name = name
        self.imperfection = imperfection
        self.move_duration = float(move_duration)
        self.device = np.eye(4) if T_F_dev is None else np.array(T_F_dev, dtype=float)
        self.gripper = 0.0
        self.state = 'DISABLED'
        self.is_homed = False
        self._p_offset = np.zeros(3)
        self._R_offset = np.eye(3)        # measured R = R_dev @ R_offset
        self._locked: np.ndarray | None = None  # locked orientation (3x3) or None
        self._move: tuple[float, np.ndarray, np.ndarray] | None = None  # (t0, T_start, T_goal)
        self.gravity_compensation = False
        self.moves = 0

    # --- operating state -------------------------------------------------------------------

    def state_command(self, command: str) -> str | None:
        """
        Apply a CRTK ``state_command``; return a warning (str) if it is not valid now.

        The virtual MTM has no motors to power or encoders to bias: ``enable`` and ``home``
        take effect at once.
        """
        if command == 'enable':
            self.state = 'ENABLED'
        elif command == 'disable':
            self.state = 'DISABLED'
        elif command == 'home':
            if self.state != 'ENABLED':
                return f'{self.name}: command home is not supported in state {self.state}'
            self.is_homed = True
        elif command == 'unhome':
            self.is_homed = False
        else:
            return f'{self.name}: unknown state_command {command!r}'
        return None

    def is_busy(self, t: float) -> bool:
        """Whether a ``move_cp`` is under way at ``t``."""
        return self._move is not None and t - self._move[0] < self.move_duration

    # --- the device ------------------------------------------------------------------------

    def set_device_pose(self, T_F_dev: ArrayLike) -> None:
        """Set the device's absolute pose (4x4, frame F)."""
        self.device = np.array(T_F_dev, dtype=float)

    def apply_twist(self, v: ArrayLike, w: ArrayLike, dt: float) -> None:
        """Integrate a device velocity ``(v, w)`` (m/s, rad/s, frame F) over ``dt`` s."""
        self.device = integrate_twist(self.device, v, w, dt)

    def set_gripper(self, angle: float) -> None:
        """Set the gripper opening angle (rad)."""
        self.gripper = float(angle)

    # --- MTM commands ----------------------------------------------------------------------

    def _held(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, 3] = self.device[:3, 3] + self._p_offset
        T[:3, :3] = self._locked if self._locked is not None \
            else self.device[:3, :3] @ self._R_offset
        return T

    def measured_cp(self, t: float) -> np.ndarray:
        """Return the MTM's pose (4x4, frame F) at ``t``; ends a finished ``move_cp``."""
        if self._move is not None:
            t0, T0, T1 = self._move
            s = (t - t0) / self.move_duration if self.move_duration > 0 else 1.0
            if s < 1.0:
                s = max(0.0, s)
                s = s * s * (3.0 - 2.0 * s)
                T = np.eye(4)
                T[:3, 3] = T0[:3, 3] + s * (T1[:3, 3] - T0[:3, 3])
                q = quaternion_slerp(quaternion_from_matrix(T0[:3, :3]),
                                     quaternion_from_matrix(T1[:3, :3]), s)
                T[:3, :3] = matrix_from_quaternion(q)
                return T
            self._move = None
            self._hold_at(T1)
        return self._held()

    def _hold_at(self, T_goal: np.ndarray) -> None:
        """Make the measured pose ``T_goal`` with the device where it is."""
        self._p_offset = T_goal[:3, 3] - self.device[:3, 3]
        if self._locked is not None:
            self._locked = T_goal[:3, :3].copy()
        else:
            self._R_offset = self.device[:3, :3].T @ T_goal[:3, :3]

    def move_cp(self, T_goal: ArrayLike, t: float) -> None:
        """Start a move to ``T_goal`` (4x4, frame F) at ``t``; the MTM is busy meanwhile."""
        T_goal = np.array(T_goal, dtype=float)
        if self.imperfection is not None:     # the wrist's controllers leave a small error
            T_goal = self.imperfection.reached(T_goal)
        self._move = (t, self.measured_cp(t), T_goal)
        self.moves += 1

    def lock_orientation(self, R: ArrayLike, t: float) -> None:
        """Keep the orientation at ``R`` (3x3, frame F)."""
        self.measured_cp(t)               # ends a move that has finished
        self._locked = np.array(R, dtype=float)
        if self._move is not None:        # a move under way keeps its position goal
            t0, T0, T1 = self._move
            T1 = T1.copy()
            T1[:3, :3] = self._locked
            self._move = (t0, T0, T1)

    def unlock_orientation(self, t: float) -> None:
        """Let the orientation follow the hand again, from where it is."""
        if self._locked is None:
            return
        R = self.measured_cp(t)[:3, :3]
        self._locked = None
        self._R_offset = self.device[:3, :3].T @ R

    def release_clutch(self, t: float) -> None:
        """
        Let the wrist follow the hand again, without a jump: the operator let go of the clutch.

        A clutch locks the orientation (``lock_orientation``); a console's MTM is free again
        when the pedal comes up, with or without an ``unlock_orientation`` after it.
        """
        self.unlock_orientation(t)
