"""
Servo dynamics of a dVRK joint: a PD loop with velocity feed-forward, within the joint limits.

The dVRK's joint PID does not put a joint on its setpoint at the next step: the measured joints
lag a moving setpoint and overshoot a little when it stops. Each joint here is a second-order
loop, ``qdd = wn^2 (r - q) + 2 zeta wn (w - qd)``, following the ideal motion ``r``, ``w``
(the setpoint tracked within the joint's velocity and acceleration limits) and clipped to the
position limits. Once the reference stands still, a joint whose error has decayed below its
``rest`` tolerance (a fraction of an encoder count: no reading can show it) and whose velocity
is of the same order is put on the setpoint exactly and rests there, so a settled arm costs
nothing more; without a tolerance, 1e-9 (the loop's own decay, about 0.4 s after a motion).

Without a :class:`ServoLag` the arm keeps its ideal tracking (level 0, bit-identical).

Frames/units: joints in rad / m; ``wn`` in rad/s.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math


@dataclass(frozen=True)
class ServoConfig:
    """
    A joint servo's closed-loop dynamics.

    Attributes
    ----------
    natural_frequency : float
        ``wn`` (rad/s), > 0.
    damping : float
        ``zeta``, > 0 (below 1: a small overshoot).
    rest : tuple of float
        Per joint, the error (rad / m) below which a joint whose reference stands still is put
        on it, its velocity below ``natural_frequency`` times that; empty: 1e-9 on every joint.

    """

    natural_frequency: float = 40.0
    damping: float = 0.8
    rest: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for key in ('natural_frequency', 'damping'):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f'servo {key} must be a finite number > 0, got {v}')
        if not all(math.isfinite(v) and v >= 0.0 for v in self.rest):
            raise ValueError(f'servo rest must be finite numbers >= 0, got {self.rest}')


class ServoLag:
    """
    The per-joint servo loop a :class:`sim_bridge.trajectory.JointMotion` steps with.

    Parameters
    ----------
    config : ServoConfig

    """

    def __init__(self, config: ServoConfig) -> None:
        self.config = config
        #: the ideal (limited) motion's (joints, velocities) the loop follows; None: at rest
        self.reference: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        self._k = config.natural_frequency ** 2
        self._c = 2.0 * config.damping * config.natural_frequency
        wn = config.natural_frequency
        #: per joint (position, velocity) tolerances of the rest; joints beyond ``rest``: 1e-9
        self._rest = tuple((max(r, 1e-9), max(wn * r, 1e-9)) for r in config.rest)

    def follow(self, measured: tuple[Sequence[float], Sequence[float]],
               reference: tuple[Sequence[float], Sequence[float]], dt: float,
               bounds: Sequence[tuple[float, float]]
               ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """
        Step the measured joints by ``dt`` after the reference motion.

        Parameters
        ----------
        measured : (sequence of float, sequence of float)
            Measured joints and velocities (rad / m, per s).
        reference : (sequence of float, sequence of float)
            The ideal motion's joints and velocities at the end of the step (within the joint
            limits: :class:`sim_bridge.trajectory.JointMotion`'s limited tracking).
        dt : float
            Step (s).
        bounds : sequence of (lower, upper)
            Position limits per joint.

        Returns
        -------
        (tuple of float, tuple of float)
            New joints and velocities.

        """
        k, c = self._k, self._c
        q_out, qd_out = [], []
        rest = self._rest
        n = len(rest)
        for j, (x, v, r, w, (lo, hi)) in enumerate(zip(*measured, *reference, bounds)):
            v_new = v + (k * (r - x) + c * (w - v)) * dt  # semi-implicit Euler
            x_new = x + v_new * dt
            e_max, v_max = rest[j] if j < n else (1e-9, 1e-9)
            if w == 0.0 and abs(r - x_new) < e_max and abs(v_new) < v_max:
                x_new, v_new = r, 0.0  # settled: rest exactly on the reference
            clipped = min(max(x_new, lo), hi)
            q_out.append(clipped)
            qd_out.append(v_new if clipped == x_new else 0.0)
        return tuple(q_out), tuple(qd_out)
