"""
Cable transmission of a dVRK arm: backlash (a play operator) and stretch under load.

The PSM's joints are driven by cables and capstans: a reversing joint first takes up the slack
before it moves (backlash, so the reached angle depends on the direction of motion), and a
tensioned cable stretches in proportion to the load it carries (here the elastic load of the
joint's deflection from its neutral angle, after Haghighipanah et al. 2016's cable-tension model
on RAVEN). The encoders sit on the motors, so the arm reports the joint angles its motors put
out: the true joints are ``q_true = q_reported + backlash state + stretch * (q_reported - q0)``.

Level 0 (no backlash, no stretch) returns its input unchanged, bit for bit.

Frames/units: joints in rad (rotary) and m (insertion), in the arm's ``measured_js`` order.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TransmissionConfig:
    """
    Magnitudes of one arm's cable transmission.

    Attributes
    ----------
    backlash : tuple of float
        Full dead-band width per joint (rad / m): the play a reversal takes up.
    stretch : tuple of float
        Per joint, true minus reported joint per unit of deflection from ``neutral``
        (dimensionless; a compliance times the elastic load).
    neutral : tuple of float
        Joint angles (rad / m) at which the cables carry no extra load.

    """

    backlash: tuple[float, ...] = (0.0,) * 6
    stretch: tuple[float, ...] = (0.0,) * 6
    neutral: tuple[float, ...] = (0.0,) * 6

    def __post_init__(self) -> None:
        n = len(self.backlash)
        if len(self.stretch) != n or len(self.neutral) != n:
            raise ValueError(f'transmission backlash, stretch and neutral must have one value per '
                             f'joint each, got {len(self.backlash)}, {len(self.stretch)}, '
                             f'{len(self.neutral)}')
        for name, values in (('backlash', self.backlash), ('stretch', self.stretch)):
            if not all(np.isfinite(v) and v >= 0.0 for v in values):
                raise ValueError(f'transmission {name} must be finite numbers >= 0, got {values}')

    @property
    def is_zero(self) -> bool:
        """Whether the transmission is ideal (level 0)."""
        return not any(self.backlash) and not any(self.stretch)


class JointTransmission:
    """
    The stateful cable transmission of one arm (play operator plus linear stretch).

    Parameters
    ----------
    config : TransmissionConfig
    initial : array_like, optional
        Initial play per joint, in ``[-backlash/2, backlash/2]`` (default: centred, 0).

    """

    def __init__(self, config: TransmissionConfig, initial: np.ndarray | None = None) -> None:
        self.config = config
        half = 0.5 * np.asarray(config.backlash, dtype=float)
        play = (np.zeros_like(half) if initial is None
                else np.clip(np.asarray(initial, dtype=float), -half, half))
        # plain floats: six joints are cheaper joint by joint than through NumPy calls
        self._joints = tuple(zip((-half).tolist(), half.tolist(),
                                 [float(v) for v in config.stretch],
                                 [float(v) for v in config.neutral]))
        self._play = play.tolist()
        self._last: list[float] | None = None

    @property
    def play(self) -> np.ndarray:
        """The current backlash state per joint (true minus motor side, rad / m), a copy."""
        return np.array(self._play)

    def apply(self, reported: np.ndarray) -> np.ndarray:
        """
        Return where the joints truly are for the motor-side (reported) joints ``reported``.

        Repeating the same input leaves the state unchanged (rate-independent hysteresis).

        Parameters
        ----------
        reported : ndarray, shape (n,)
            Joints as the encoders report them (rad / m).

        Returns
        -------
        ndarray, shape (n,)
            True joints (rad / m).

        """
        q = np.asarray(reported, dtype=float).tolist()
        last, play = self._last, self._play
        if last is not None:
            # the load side lags behind a moving motor by the half dead band, in the direction
            # of motion; inside the band it stays put (np.clip's max, then min)
            for j, (x, x0, (lo, hi, _, _)) in enumerate(zip(q, last, self._joints)):
                p = play[j] - (x - x0)
                p = lo if lo > p else p
                play[j] = hi if hi < p else p
        self._last = q
        return np.array([x + p + s * (x - n)
                         for x, p, (_, _, s, n) in zip(q, play, self._joints)])
