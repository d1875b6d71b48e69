"""
The dVRK's kinematic errors, hidden from what the arms report.

A physical dVRK's tool tips are not where its kinematics say (Hwang et al. 2020: 2.96 mm mean
before correction), and its PSMs are off in the camera's view after the ECM-PSM registration
(jhu-dvrk/dvrk_camera_registration: "a 5 mm to 10 mm cube"). The model here follows the
Surgical Robotics Challenge's joint-error model: each PSM has fixed joint offsets, added to the
joints it is commanded to and taken off the joints it measures, so that ``measured_js/cp`` stay
consistent with the commands while the tool is really elsewhere; and a registration error, a
translation of the arm's believed base in ``world``.

Level ``L`` (a "mm class"): offsets drawn uniformly in ``±L`` degrees on joints 1-2 (yaw,
pitch), ``±L`` mm on the insertion (joint 3), and a registration translation uniform in a cube of
``±L`` mm per axis. Level 5 is SRC's range (±5 deg, ±5 mm) with the 10 mm cube a registration
leaves; level 0 is perfect kinematics (the simulation then runs exactly as without errors).

Frames: ``world``; joints in rad / m; ``T_*`` 4x4 poses.
"""

from collections.abc import Iterable
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from sim_bridge.common.validation import check_positive

# Per unit of level: degrees on joints 1-2, metres on the insertion, metres of registration.
_JOINT_DEG = 1.0
_INSERTION_M = 0.001
_REGISTRATION_M = 0.001


@dataclass(frozen=True, eq=False)
class ArmError:
    """
    The hidden kinematic error of one arm.

    Attributes
    ----------
    joint_offset : ndarray, shape (n,)
        True joints minus reported joints (rad / m).
    T_believed_true : ndarray, shape (4, 4)
        The registration error: the arm's believed base is ``T_believed_true @ T_world_base``
        (a translation in ``world``; with :mod:`sim_bridge.realism.calibration`, a rotation too).
    transmission : sim_bridge.realism.transmission.JointTransmission or None
        The arm's cable transmission (backlash, stretch), stateful; None: ideal.

    """

    joint_offset: np.ndarray
    T_believed_true: np.ndarray
    transmission: Any = None

    @property
    def is_zero(self) -> bool:
        """Whether the arm has no error at all (perfect kinematics)."""
        return (self.transmission is None and not self.joint_offset.any()
                and np.array_equal(self.T_believed_true, np.eye(4)))

    def true_jp(self, q: np.ndarray) -> np.ndarray:
        """
        Return the joints where the arm truly is when its encoders report ``q``.

        Parameters
        ----------
        q : ndarray, shape (n,)
            Reported (measured) joints (rad / m).

        Returns
        -------
        ndarray, shape (n,)

        """
        if self.transmission is not None:
            q = self.transmission.apply(q)
        return q + self.joint_offset


def draw_arm_errors(level: float, rng: np.random.Generator, arms: Iterable[str],
                    n_joints: int = 6) -> dict[str, ArmError]:
    """
    Draw each arm's hidden kinematic error at ``level``.

    Parameters
    ----------
    level : float
        Error class (mm, >= 0); 0 gives errors of exactly zero without drawing.
    rng : numpy.random.Generator
        Source of the draws (seeded by the caller).
    arms : sequence of str
        Arms to draw for, in order (``('PSM1', 'PSM2')``).
    n_joints : int
        Joints per arm.

    Returns
    -------
    dict of str to ArmError

    """
    level = float(level)
    if not (math.isfinite(level) and level >= 0.0):
        raise ValueError(f'kinematic error level must be a finite number >= 0 (mm class), '
                         f'got {level}')
    out = {}
    for name in arms:
        offset = np.zeros(n_joints)
        T = np.eye(4)
        if level > 0.0:
            check_positive(level, 'kinematic error level')
            offset[:2] = np.radians(rng.uniform(-level * _JOINT_DEG, level * _JOINT_DEG, 2))
            offset[2] = rng.uniform(-level * _INSERTION_M, level * _INSERTION_M)
            T[:3, 3] = rng.uniform(-level * _REGISTRATION_M, level * _REGISTRATION_M, 3)
        offset.flags.writeable = False
        T.flags.writeable = False
        out[name] = ArmError(offset, T)
    return out
