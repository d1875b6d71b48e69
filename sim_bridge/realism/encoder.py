"""
The joint encoders of a dVRK arm: what ``measured_js`` reads of where the motors are.

The dVRK reads relative optical encoders on its motors (homed from the potentiometers), so the
joints it reports are the motor-side joints on the encoder's grid of counts, plus a little
noise (electrical noise and the sampling of a moving count). Here each joint's reading is the
motor-side joint rounded to the nearest count plus a seeded Gaussian of ``noise`` counts; the
reading is drawn once per physics step and read the same however often it is asked for within
one step (a servo cycle's sample).

Without a :class:`JointEncoder` (level 0) an arm reports its motor-side joints unchanged, bit
for bit.

Frames/units: joints in rad (rotary) and m (insertion), in the arm's ``measured_js`` order.
"""

from dataclasses import dataclass
import math

import numpy as np


@dataclass(frozen=True)
class EncoderConfig:
    """
    Resolution and noise of an arm's joint encoders at level 1.

    Attributes
    ----------
    psm : tuple of float
        One count per PSM joint, joint side (rad / m).
    ecm : tuple of float
        One count per ECM joint, joint side (rad / m).
    noise : float
        Standard deviation of the reading's noise, in counts.

    """

    psm: tuple[float, ...] = (0.0,) * 6
    ecm: tuple[float, ...] = (0.0,) * 4
    noise: float = 0.0

    def __post_init__(self) -> None:
        for name, values in (('psm', self.psm), ('ecm', self.ecm), ('noise', (self.noise,))):
            if not all(math.isfinite(v) and v >= 0.0 for v in values):
                raise ValueError(f'encoder {name} must be finite numbers >= 0, got {values}')


class JointEncoder:
    """
    The encoders of one arm: quantisation to a count plus seeded noise, sampled once a step.

    Parameters
    ----------
    resolution : array_like, shape (n,)
        One count per joint (rad / m); a 0 leaves that joint unquantised.
    noise : float
        Standard deviation of the noise, in counts.
    rng : numpy.random.Generator
        Source of the noise (seeded by the caller).

    """

    def __init__(self, resolution: np.ndarray, noise: float, rng: np.random.Generator) -> None:
        self.resolution = np.asarray(resolution, dtype=float)
        self.noise = float(noise)
        self._rng = rng
        self._res = self.resolution.tolist()
        # (step, motor-side joints, reading) of the last sample, in plain floats
        self._sample: tuple[int, list[float], list[float]] | None = None

    def read(self, q: np.ndarray, step: int) -> np.ndarray:
        """
        Return the joints the encoders report for the motor-side joints ``q`` at ``step``.

        Parameters
        ----------
        q : ndarray, shape (n,)
            Motor-side joints (rad / m).
        step : int
            The physics step: within one step the same ``q`` reads the same.

        Returns
        -------
        ndarray, shape (n,)
            A new array.

        """
        values = np.asarray(q, dtype=float).tolist()
        s = self._sample
        if s is not None and s[0] == step and s[1] == values:
            return np.array(s[2])
        # joint by joint in plain floats, the same operations as NumPy's (round half to even)
        res = self._res
        counted = [round(x / r) * r if r > 0.0 else x for x, r in zip(values, res)]
        if self.noise > 0.0:
            noise = self._rng.normal(0.0, self.noise, len(values)).tolist()
            counted = [c + n * r for c, n, r in zip(counted, noise, res)]
        self._sample = (step, values, counted)
        return np.array(counted)
