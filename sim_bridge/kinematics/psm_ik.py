"""
The PSM's closed-form inverse kinematics for one pose, in plain Python floats.

The same solution as :meth:`sim_bridge.kinematics.rcm.PsmKinematics.ik_batch` (same branches,
same wrapping towards the reference, same choice), written for the streaming case: one
``servo_cp`` goal near the current setpoint. NumPy's per-call cost dominates a single pose, so
here every branch is a few dozen float operations, and branches whose yaw, pitch or insertion
already leave the joint limits are dropped before their wrist is solved. Anything but a clean
solution inside the limits returns None and the caller falls back to the batch solver, which
words the error.

Poses are tool tips in the RCM frame ``<ARM>_base`` (metres); joints in rad / m.
"""

from collections.abc import Iterable, Sequence
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # only for the annotations: rcm imports this module
    from sim_bridge.kinematics.rcm import PsmKinematics

_TWO_PI = 2.0 * math.pi
# a 3x3 matrix as 9 floats, row by row
_Flat3 = tuple[float, ...]
# a joint: (revolute, lowest and highest value counted inside, lower, upper, range)
_Joint = tuple[bool, float, float, float, float, float]


def _rz_mul(A: _Flat3, theta: float, B: _Flat3) -> _Flat3:
    """
    Return ``A @ RotZ(theta) @ B`` for flat row-major 3x3 tuples (9 floats).

    The rotation is applied to ``A`` first, row by row, then the product with ``B`` is formed
    element by element: the operations of the nested-tuple products this replaces, in order.
    """
    a, b, c, d, e, f, g, h, i = A
    co, si = math.cos(theta), math.sin(theta)
    a, b = a * co + b * si, b * co - a * si
    d, e = d * co + e * si, e * co - d * si
    g, h = g * co + h * si, h * co - g * si
    p, q, r, s, t, u, v, w, x = B
    return (a * p + b * s + c * v, a * q + b * t + c * w, a * r + b * u + c * x,
            d * p + e * s + f * v, d * q + e * t + f * w, d * r + e * u + f * x,
            g * p + h * s + i * v, g * q + h * t + i * w, g * r + h * u + i * x)


def _flat(M: Iterable[Iterable[float]]) -> _Flat3:
    """Return a 3x3 matrix as 9 floats, row by row."""
    return tuple(float(x) for row in M for x in row)


class PsmSingleIk:
    """
    Solver bound to one :class:`~sim_bridge.kinematics.rcm.PsmKinematics` chain.

    Parameters
    ----------
    chain : PsmKinematics
        The chain whose constants (DH offsets, signs, limits) are used.
    slack : float
        Joint values this far outside a limit count as inside (clipped onto it).

    """

    def __init__(self, chain: 'PsmKinematics', slack: float) -> None:
        self.slack = slack
        self.lower = [float(x) for x in chain.lower]
        self.upper = [float(x) for x in chain.upper]
        self.ranges = [u - lo for lo, u in zip(self.lower, self.upper)]
        self.revolute = [bool(x) for x in chain.is_revolute]
        self.theta0 = [float(x) for x in chain._theta0]
        self.s2, self.s3 = chain._s2, chain._s3
        self.s5, self.s6 = chain._s5, chain._s6
        self.a6, self.d6 = float(chain._a6), float(chain._d6)
        self.shaft_offset = float(chain._shaft_offset)
        self.R_pre1 = _flat(chain._R_pre1)
        self.R_x2 = _flat(chain._R_x2)
        self.R_x3_z3 = _flat(chain._R_x3_z3)
        self.R_x5 = _flat(chain._R_x5)
        self.R_x6 = _flat(chain._R_x6)
        self.tip_inverse = [[float(x) for x in row] for row in chain._tooltip_inverse]
        # its columns 0 (x axis), 2 (z axis) and 3 (translation)
        self._tip_columns = tuple(tuple(row[c] for row in self.tip_inverse) for c in (0, 2, 3))
        # per joint: (wrap it, lowest and highest value counted inside, lower, upper, range)
        self._joint = [(rev, lo - slack, hi + slack, lo, hi, hi - lo) for rev, lo, hi in
                       zip(self.revolute, self.lower, self.upper)]

    def _wrap(self, j: int, value: float, ref: float) -> float:
        """Wrap a revolute joint by 2 pi towards ``ref`` as the batch solver does."""
        return _wrap(self._joint[j], value, ref)

    def _violation(self, j: int, v: float) -> float:
        return max(0.0, self.lower[j] - v, v - self.upper[j]) / self.ranges[j]

    def solve(self, T: NDArray[np.float64],
              q_ref: Sequence[float] | NDArray[np.float64]) -> list[float] | None:
        """
        Return the joint solution closest to ``q_ref`` inside the limits, or None.

        Parameters
        ----------
        T : ndarray, shape (4, 4)
            Validated tool-tip pose in the RCM frame (metres).
        q_ref : sequence of 6 floats
            Reference configuration (rad / m).

        Returns
        -------
        list of float or None
            Joint values clipped into the limits; None when no branch lies inside the limits
            or the pose is degenerate (the batch solver then decides and words the error).

        Notes
        -----
        A branch whose yaw, pitch and insertion alone already cost at least as much as the best
        branch so far is not finished: the cost only grows with the wrist joints (a sum of
        squares, rounding is monotone), so it could not win.

        """
        Tm = T.tolist()
        ref = [float(x) for x in q_ref]
        r0, r1, r2, r3, r4, r5 = ref
        J0, J1, J2, J3, J4, J5 = self._joint
        theta0 = self.theta0
        th0, th1, th3, th4, th5 = theta0[0], theta0[1], theta0[3], theta0[4], theta0[5]
        # last-link pose (top three rows): T @ inverse(tooltip offset); its columns x, z, t
        (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3) = Tm[:3]
        (x0, x1, x2, x3), (z0, z1, z2, z3), (p0, p1, p2, p3) = self._tip_columns
        x6 = (a0 * x0 + a1 * x1 + a2 * x2 + a3 * x3, b0 * x0 + b1 * x1 + b2 * x2 + b3 * x3,
              c0 * x0 + c1 * x1 + c2 * x2 + c3 * x3)
        z6 = (a0 * z0 + a1 * z1 + a2 * z2 + a3 * z3, b0 * z0 + b1 * z1 + b2 * z2 + b3 * z3,
              c0 * z0 + c1 * z1 + c2 * z2 + c3 * z3)
        d6 = self.d6
        p = (a0 * p0 + a1 * p1 + a2 * p2 + a3 * p3 - d6 * z6[0],
             b0 * p0 + b1 * p1 + b2 * p2 + b3 * p3 - d6 * z6[1],
             c0 * p0 + c1 * p1 + c2 * p2 + c3 * p3 - d6 * z6[2])
        pz = p[0] * z6[0] + p[1] * z6[1] + p[2] * z6[2]
        n = (p[0] - pz * z6[0], p[1] - pz * z6[1], p[2] - pz * z6[2])
        n_norm = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        if n_norm < 1e-9:
            return None
        n = (n[0] / n_norm, n[1] / n_norm, n[2] / n_norm)
        slack = self.slack
        s2, s3, s5, s6, a6 = self.s2, self.s3, self.s5, self.s6, self.a6
        R_pre1, R_x2, R_x3_z3, R_x5, R_x6 = (self.R_pre1, self.R_x2, self.R_x3_z3, self.R_x5,
                                             self.R_x6)
        pa, pb, pc, pd, pe, pf, pg, ph, pi = R_pre1
        atan2 = math.atan2
        best, best_cost = None, math.inf
        for sx in (1.0, -1.0):
            x5 = (sx * n[0], sx * n[1], sx * n[2])
            P = (p[0] - a6 * x5[0], p[1] - a6 * x5[1], p[2] - a6 * x5[2])
            r = math.sqrt(P[0] * P[0] + P[1] * P[1] + P[2] * P[2])
            if r < 1e-9:
                continue
            e0, e1, e2 = P[0] / r, P[1] / r, P[2] / r
            # u = R_pre1^T (P / r)
            u = (pa * e0 + pd * e1 + pg * e2, pb * e0 + pe * e1 + ph * e2,
                 pc * e0 + pf * e1 + pi * e2)
            # z5 = -s6 (x5 x z6)
            z5 = (-s6 * (x5[1] * z6[2] - x5[2] * z6[1]),
                  -s6 * (x5[2] * z6[0] - x5[0] * z6[2]),
                  -s6 * (x5[0] * z6[1] - x5[1] * z6[0]))
            for s_shaft in (1.0, -1.0):
                q3 = s_shaft * r - self.shaft_offset
                v3 = _violation(J2, q3)
                if v3 > slack:
                    continue  # insertion outside its range: no branch of this sign is valid
                up = (s_shaft * u[0], s_shaft * u[1], s_shaft * u[2])
                rho = math.hypot(up[0], up[1])
                for b in (1.0, -1.0):
                    t2 = atan2(b * rho, -s3 * s2 * up[2])
                    sb = s3 * b
                    if rho > 1e-12:
                        t1 = atan2(sb * up[1], sb * up[0])
                    else:
                        t1 = th0 + r0
                    q0 = _wrap(J0, t1 - th0, r0)
                    q1 = _wrap(J1, t2 - th1, r1)
                    violation = v3 + _violation(J0, q0) + _violation(J1, q1)
                    if violation > slack:
                        continue
                    c0 = ((q0 - r0) / J0[5]) ** 2
                    c1 = ((q1 - r1) / J1[5]) ** 2
                    c2 = ((q3 - r2) / J2[5]) ** 2
                    partial = c0 + c1 + c2
                    if partial >= best_cost:
                        continue  # cannot win (see Notes)
                    R3 = _rz_mul(_rz_mul(R_pre1, t1, R_x2), t2, R_x3_z3)
                    a, b_, c, d, e, f, g, h, i = R3
                    # w = R3^T z5 (its first two components)
                    w0 = a * z5[0] + d * z5[1] + g * z5[2]
                    w1 = b_ * z5[0] + e * z5[1] + h * z5[2]
                    t4 = atan2(s5 * w0, -s5 * w1)
                    Rpre5 = _rz_mul(R3, t4, R_x5)
                    a, b_, c, d, e, f, g, h, i = Rpre5
                    t5 = atan2(b_ * x5[0] + e * x5[1] + h * x5[2],
                               a * x5[0] + d * x5[1] + g * x5[2])
                    a, b_, c, d, e, f, g, h, i = _rz_mul(Rpre5, t5, R_x6)
                    t6 = atan2(b_ * x6[0] + e * x6[1] + h * x6[2],
                               a * x6[0] + d * x6[1] + g * x6[2])
                    q4 = _wrap(J3, t4 - th3, r3)
                    violation += _violation(J3, q4)
                    q5 = _wrap(J4, t5 - th4, r4)
                    violation += _violation(J4, q5)
                    q6 = _wrap(J5, t6 - th5, r5)
                    violation += _violation(J5, q6)
                    if violation > slack:
                        continue
                    cost = (partial + ((q4 - r3) / J3[5]) ** 2 + ((q5 - r4) / J4[5]) ** 2
                            + ((q6 - r5) / J5[5]) ** 2)
                    if cost < best_cost:
                        best, best_cost = (q0, q1, q3, q4, q5, q6), cost
        if best is None:
            return None
        return [min(max(v, lo), hi) for v, lo, hi in zip(best, self.lower, self.upper)]


def _violation(joint: _Joint, v: float) -> float:
    """Return how far (in ranges) ``v`` lies outside the limits of ``joint``, 0 inside."""
    _, _, _, lo, hi, span = joint
    # max(0.0, lo - v, v - hi), written out: a later argument wins only when greater
    worst = lo - v
    worst = worst if worst > 0.0 else 0.0
    above = v - hi
    return (above if above > worst else worst) / span


def _wrap(joint: _Joint, value: float, ref: float) -> float:
    """Wrap a revolute joint value by 2 pi towards ``ref`` inside its limits (and slack)."""
    if not joint[0]:
        return value
    k = round((ref - value) / _TWO_PI)
    lo, hi = joint[1], joint[2]
    best, best_d = None, math.inf
    for m in (-1.0, 0.0, 1.0):
        v = value + _TWO_PI * (k + m)
        if lo <= v <= hi:
            d = abs(v - ref)
            if d < best_d:
                best, best_d = v, d
    return value + _TWO_PI * k if best is None else best
