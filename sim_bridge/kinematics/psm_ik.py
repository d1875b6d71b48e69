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

import math

_TWO_PI = 2.0 * math.pi


def _mul(A, B):
    """Return the 3x3 product of row-major nested tuples."""
    (a, b, c), (d, e, f), (g, h, i) = A
    (p, q, r), (s, t, u), (v, w, x) = B
    return ((a * p + b * s + c * v, a * q + b * t + c * w, a * r + b * u + c * x),
            (d * p + e * s + f * v, d * q + e * t + f * w, d * r + e * u + f * x),
            (g * p + h * s + i * v, g * q + h * t + i * w, g * r + h * u + i * x))


def _mul_rz(A, theta):
    """Return ``A @ RotZ(theta)``."""
    c, s = math.cos(theta), math.sin(theta)
    return tuple((r0 * c + r1 * s, r1 * c - r0 * s, r2) for r0, r1, r2 in A)


def _tmul(A, v):
    """Return ``A^T @ v``."""
    return (A[0][0] * v[0] + A[1][0] * v[1] + A[2][0] * v[2],
            A[0][1] * v[0] + A[1][1] * v[1] + A[2][1] * v[2],
            A[0][2] * v[0] + A[1][2] * v[1] + A[2][2] * v[2])


def _as_tuple(M):
    return tuple(tuple(float(x) for x in row) for row in M)


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

    def __init__(self, chain, slack):
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
        self.R_pre1 = _as_tuple(chain._R_pre1)
        self.R_x2 = _as_tuple(chain._R_x2)
        self.R_x3_z3 = _as_tuple(chain._R_x3_z3)
        self.R_x5 = _as_tuple(chain._R_x5)
        self.R_x6 = _as_tuple(chain._R_x6)
        self.tip_inverse = [[float(x) for x in row] for row in chain._tooltip_inverse]

    def _wrap(self, j, value, ref):
        """Wrap a revolute joint by 2 pi towards ``ref`` as the batch solver does."""
        if not self.revolute[j]:
            return value
        k = round((ref - value) / _TWO_PI)
        lo, hi = self.lower[j] - self.slack, self.upper[j] + self.slack
        best, best_d = None, math.inf
        for m in (-1.0, 0.0, 1.0):
            v = value + _TWO_PI * (k + m)
            if lo <= v <= hi:
                d = abs(v - ref)
                if d < best_d:
                    best, best_d = v, d
        return value + _TWO_PI * k if best is None else best

    def _violation(self, j, v):
        return max(0.0, self.lower[j] - v, v - self.upper[j]) / self.ranges[j]

    def solve(self, T, q_ref):
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

        """
        Tm = T.tolist()
        ref = [float(x) for x in q_ref]
        # last-link pose (top three rows): T @ inverse(tooltip offset)
        inv = self.tip_inverse
        R = [[row[0] * inv[0][c] + row[1] * inv[1][c] + row[2] * inv[2][c] + row[3] * inv[3][c]
              for c in range(4)] for row in Tm[:3]]
        z6 = (R[0][2], R[1][2], R[2][2])
        x6 = (R[0][0], R[1][0], R[2][0])
        p = (R[0][3] - self.d6 * z6[0], R[1][3] - self.d6 * z6[1], R[2][3] - self.d6 * z6[2])
        pz = p[0] * z6[0] + p[1] * z6[1] + p[2] * z6[2]
        n = (p[0] - pz * z6[0], p[1] - pz * z6[1], p[2] - pz * z6[2])
        n_norm = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        if n_norm < 1e-9:
            return None
        n = (n[0] / n_norm, n[1] / n_norm, n[2] / n_norm)
        slack = self.slack
        best, best_cost = None, math.inf
        for sx in (1.0, -1.0):
            x5 = (sx * n[0], sx * n[1], sx * n[2])
            P = (p[0] - self.a6 * x5[0], p[1] - self.a6 * x5[1], p[2] - self.a6 * x5[2])
            r = math.sqrt(P[0] * P[0] + P[1] * P[1] + P[2] * P[2])
            if r < 1e-9:
                continue
            u = _tmul(self.R_pre1, (P[0] / r, P[1] / r, P[2] / r))
            for s_shaft in (1.0, -1.0):
                q3 = s_shaft * r - self.shaft_offset
                v3 = self._violation(2, q3)
                if v3 > slack:
                    continue  # insertion outside its range: no branch of this sign is valid
                up = (s_shaft * u[0], s_shaft * u[1], s_shaft * u[2])
                rho = math.hypot(up[0], up[1])
                for b in (1.0, -1.0):
                    t2 = math.atan2(b * rho, -self.s3 * self.s2 * up[2])
                    sb = self.s3 * b
                    if rho > 1e-12:
                        t1 = math.atan2(sb * up[1], sb * up[0])
                    else:
                        t1 = self.theta0[0] + ref[0]
                    q = [self._wrap(0, t1 - self.theta0[0], ref[0]),
                         self._wrap(1, t2 - self.theta0[1], ref[1]), q3]
                    violation = v3 + self._violation(0, q[0]) + self._violation(1, q[1])
                    if violation > slack:
                        continue
                    R3 = _mul(_mul_rz(_mul(_mul_rz(self.R_pre1, t1), self.R_x2), t2),
                              self.R_x3_z3)
                    # z5 = -s6 (x5 x z6)
                    z5 = (-self.s6 * (x5[1] * z6[2] - x5[2] * z6[1]),
                          -self.s6 * (x5[2] * z6[0] - x5[0] * z6[2]),
                          -self.s6 * (x5[0] * z6[1] - x5[1] * z6[0]))
                    w = _tmul(R3, z5)
                    t4 = math.atan2(self.s5 * w[0], -self.s5 * w[1])
                    Rpre5 = _mul(_mul_rz(R3, t4), self.R_x5)
                    v5 = _tmul(Rpre5, x5)
                    t5 = math.atan2(v5[1], v5[0])
                    Rpre6 = _mul(_mul_rz(Rpre5, t5), self.R_x6)
                    v6 = _tmul(Rpre6, x6)
                    t6 = math.atan2(v6[1], v6[0])
                    for j, t in ((3, t4), (4, t5), (5, t6)):
                        value = self._wrap(j, t - self.theta0[j], ref[j])
                        q.append(value)
                        violation += self._violation(j, value)
                    if violation > slack:
                        continue
                    cost = sum(((q[j] - ref[j]) / self.ranges[j]) ** 2 for j in range(6))
                    if cost < best_cost:
                        best, best_cost = q, cost
        if best is None:
            return None
        return [min(max(v, lo), hi) for v, lo, hi in zip(best, self.lower, self.upper)]
