"""
How far a physical MTM is from a perfect one: where its wrist lands, what its encoders read.

A dVRK MTM never lands exactly where it was sent nor reads exactly where it is:

- its wrist is driven by joint PID controllers that leave a tracking error when a ``move_cp``
  ends (the operator's hand on the handle adds to it); the dVRK's own teleoperation therefore
  tolerates an orientation offset between MTM and PSM when it starts following (5 degrees in
  ``dvrk_teleoperation.py``, ``operator_orientation_tolerance``) and removes "the small rotation
  offset" that always remains while following (dVRK documentation, "PSM teleoperation");
- its joint positions come from relative encoders (homed on potentiometers) through the
  kinematics, so ``measured_cp`` carries quantisation and a little noise, and its gripper angle
  comes from a Hall-effect sensor's analog reading, without an encoder (dVRK wiki, "Debugging
  potentiometer issues": the gripper is the MTM's one joint read only by its analog input).

:class:`MtmImperfection` models both with a level: ``level`` 0 is today's exact MTM (the pose
reached is the goal, every reading is the truth, nothing is drawn); level 1 is the ``dvrk``
preset (:class:`MtmRealism`'s defaults), larger levels scale every magnitude. Draws come from a
seeded generator, so a run is repeatable.

Poses are 4x4 matrices in the MTM's frame F (metres); angles in radians.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True)
class MtmRealism:
    """
    The magnitudes of a physical MTM's imperfection (the ``dvrk`` preset at level 1).

    Attributes
    ----------
    level : float
        Scale of every magnitude below (0: a perfect MTM, bit-identical to an ideal one).
    align_error : float
        rad, RMS orientation error the wrist is left with at the end of a ``move_cp`` (about a
        random axis; a fraction of the teleoperation's 5 degree tolerance).
    position_error : float
        m, RMS position error at the end of a ``move_cp``.
    angle_noise : float
        rad, standard deviation of the orientation read in each ``measured_cp``.
    position_noise : float
        m, standard deviation of the position read in each ``measured_cp``.
    position_quantum : float
        m, the reading's resolution (encoder counts through the arm's kinematics).
    gripper_noise : float
        rad, standard deviation of the gripper's analog (Hall-effect) reading.
    seed : int
        Seed of the draws.

    """

    level: float = 1.0
    align_error: float = math.radians(0.5)
    position_error: float = 1.0e-4
    angle_noise: float = math.radians(0.01)
    position_noise: float = 5.0e-6
    position_quantum: float = 1.0e-6
    gripper_noise: float = math.radians(0.1)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ('align_error', 'position_error', 'angle_noise', 'position_noise',
                     'position_quantum', 'gripper_noise'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'MTM realism: {name} must be a finite number >= 0, '
                                 f'got {value!r}')
        if not (math.isfinite(self.level) and self.level >= 0.0):
            raise ValueError(f'MTM realism: level must be a finite number >= 0, got '
                             f'{self.level!r}')


def _small_rotation(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad), Rodrigues' formula."""
    angle = math.sqrt(float(rotvec @ rotvec))
    if angle == 0.0:
        return np.eye(3)
    k = rotvec / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


class MtmImperfection:
    """
    One MTM's imperfection: the pose its wrist reaches, and what its sensors read.

    Parameters
    ----------
    realism : MtmRealism
        Magnitudes and level.
    stream : int
        Index of this MTM among those of one node (each draws its own sequence).

    """

    def __init__(self, realism: MtmRealism, stream: int = 0) -> None:
        self.realism = realism
        self.scale = float(realism.level)
        self._rng = np.random.default_rng([int(realism.seed), int(stream)])

    @property
    def is_perfect(self) -> bool:
        """Whether nothing is added (level 0)."""
        return self.scale == 0.0

    def reached(self, T_goal: ArrayLike) -> np.ndarray:
        """
        Return the pose a ``move_cp`` to ``T_goal`` ends at (4x4, frame F).

        Level 0 returns the goal itself (a copy).
        """
        T = np.array(T_goal, dtype=float)
        if self.is_perfect:
            return T
        r = self.realism
        axis = self._rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = abs(self._rng.normal(0.0, r.align_error * self.scale))
        T[:3, :3] = T[:3, :3] @ _small_rotation(axis * angle)
        T[:3, 3] += self._rng.normal(0.0, r.position_error * self.scale / math.sqrt(3.0), 3)
        return T

    def measured(self, T: ArrayLike) -> np.ndarray:
        """
        Return what the MTM reads of the pose ``T`` (4x4, frame F): noise and quantisation.

        Level 0 returns ``T`` itself (a copy).
        """
        T = np.array(T, dtype=float)
        if self.is_perfect:
            return T
        r = self.realism
        T[:3, :3] = T[:3, :3] @ _small_rotation(self._rng.normal(0.0, r.angle_noise * self.scale,
                                                                  3))
        p = T[:3, 3] + self._rng.normal(0.0, r.position_noise * self.scale, 3)
        q = r.position_quantum
        T[:3, 3] = np.round(p / q) * q if q > 0.0 else p
        return T

    def gripper(self, angle: float) -> float:
        """Return the gripper angle (rad) the analog sensor reads for ``angle``."""
        if self.is_perfect:
            return float(angle)
        return float(angle) + float(self._rng.normal(0.0, self.realism.gripper_noise
                                                     * self.scale))

