"""
A PSM jaw closed on the needle: what ``jaw/measured_js`` reads when the wire stops the jaws.

A dVRK client closes the jaw by commanding a negative angle (-20 deg: ``jaw.close()``), which
the jaws never reach when they hold something: the wire stops them, the joint's PID pushes on
against the cables until its effort saturates, and the motor-side encoders read the angle where
the motors stalled, short of the command. The physical dVRK's jaw reading is offset from the
jaws themselves as well: at a measured 0 rad a Large Needle Driver is "still very much open", a
grip needs a negative angle (jhu-dvrk/sawIntuitiveResearchKit issue 215). So on a held needle
the measured jaw angle is not the commanded one: here it stops at ``stall`` and follows the
command below it by a fraction ``compliance`` (the cables stretching under the effort).

The grasp itself (:mod:`sim_bridge.scene.grasp`: closed at or below its close angle, open at or
above its release angle) reads the jaw as it moves, not this reading; a jaw holding nothing, or
one whose command lies above ``stall``, reads its angle unchanged. Level 0 (no
:class:`JawStall`) reads every jaw unchanged, bit for bit.

Units: rad, rad/s.
"""

from dataclasses import dataclass
import math


@dataclass(frozen=True)
class JawConfig:
    """
    A held needle's jaw reading at level 1.

    Attributes
    ----------
    stall : float
        Measured jaw angle (rad) at which the motors stall on the needle's wire.
    compliance : float
        Fraction (0 to 1) of the command below ``stall`` that the reading still follows.

    """

    stall: float = 0.0
    compliance: float = 1.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.stall):
            raise ValueError(f'jaw stall must be a finite angle (rad), got {self.stall}')
        if not (math.isfinite(self.compliance) and 0.0 <= self.compliance <= 1.0):
            raise ValueError(f'jaw compliance must lie in [0, 1], got {self.compliance}')


class JawStall:
    """
    The reading of a jaw that holds the needle, at a level.

    Parameters
    ----------
    config : JawConfig
    level : float
        Scale of the difference from the jaw's own angle (> 0; 1 is the preset's).

    """

    def __init__(self, config: JawConfig, level: float) -> None:
        self.stall = float(config.stall)
        self.compliance = float(config.compliance)
        self.level = float(level)

    def _factor(self, angle: float) -> float | None:
        """Slope of the reading against the angle below the stall, None above it."""
        if angle >= self.stall:
            return None
        return max(0.0, 1.0 - self.level * (1.0 - self.compliance))

    def read(self, angle: float) -> float:
        """
        Return what the jaw of a held needle reads for its angle ``angle`` (rad).

        Above ``stall`` the angle itself; below it ``stall`` plus ``compliance`` of the rest
        (at level 1; a level ``L`` scales the difference from ``angle``).
        """
        factor = self._factor(angle)
        if factor is None:
            return angle
        return self.stall + factor * (angle - self.stall)

    def read_velocity(self, angle: float, velocity: float) -> float:
        """Return the reading's rate of change (rad/s) for the jaw's ``velocity`` at ``angle``."""
        factor = self._factor(angle)
        return velocity if factor is None else factor * velocity
