"""
Unit-quaternion DMP (Ude et al. 2014) with ``D_o`` scaling, Ude's literal log and LWR weights.

Equations and integration: :mod:`suture_lfd.dmp.equations`. Quaternions (x, y, z, w), angles
in rad, time in s.
"""

import logging
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import lfilter
from sim_bridge.common.geometry import (
    quaternion_angle,
    quaternion_conjugate,
    quaternion_exp,
    quaternion_log,
    quaternion_product,
    quaternion_sign_continuous,
    so3_left_jacobian_apply,
)
from sim_bridge.common.validation import FloatArray, check_array, check_quaternions
from suture_lfd.dmp.base import DmpParams, PathLike, PrimitivePart
from suture_lfd.dmp.equations import (
    basis_centres,
    basis_widths,
    forcing_term,
    guarded_scale,
    input_filters,
    input_response,
    linear_recurrence,
    nonlinear_rate,
    normalised_features,
    position_forcing_target,
    quaternion_forcing_target,
    transition_matrices,
    uniform_features,
)

LOG = logging.getLogger(__name__)

# The literal log is singular at a full turn; keep demonstrations clear of it.
MAX_ROTATION = 2.0 * math.pi - 0.05
# A change dn of the rate moves u by at most about dn / beta_z (the static gain from n to u);
# the result takes one more sweep past the last change, so the error left is far smaller.
_RELAX_TOLERANCE = 1e-6
_RELAX_ITERATIONS = 60


class QuaternionDmp(PrimitivePart):
    """
    Unit-quaternion DMP (Ude et al. 2014) with ``D_o`` scaling, literal log and LWR weights.

    The literal log keeps a demonstrated turn of more than 180 degrees (the goal's sign is
    chosen to match the demonstration, :meth:`align_goal`). Limitation of the Ude form: while
    the remaining rotation ``theta`` exceeds 180 degrees, deviations across the rotation axis
    grow (in ``u = 2 log(q conj(g))`` the rate across the axis is scaled by
    ``1 - c(theta) theta^2 < 0``), so a turn near 360 degrees about an axis that wobbles by a
    degree or more is not reproduced (measured: 340 degrees with 1 degree of wobble, 7.5
    degrees mean error, the same with Euler integration in ``q``). ``orientation_form='log'``
    avoids it.

    The attributes below are set by :meth:`fit`.

    Attributes
    ----------
    weights_ : ndarray, shape (n_bfs_o, 3)
        LWR weights.
    start_, goal_ : ndarray, shape (4,)
        Demonstrated start and goal quaternions (x, y, z, w), sign-continuous with the demo.
    duration_ : float
        Demonstrated duration, s.
    degenerate_ : ndarray of bool, shape (3,)
        Components of ``2 log(g * conj(q0))`` learnt unscaled (``D_o`` guard).

    """

    KIND = 'quaternion'
    PREFIX = 'orientation.'

    def __init__(self, params: DmpParams | None = None) -> None:
        super().__init__(params)
        c = basis_centres(self.params.n_bfs_o, self.params.alpha_x)
        self._centres, self._widths = c, basis_widths(c, self.params.alpha_x)
        self._log_form = self.params.orientation_form == 'log'

    def fit(self, T: ArrayLike, Q: ArrayLike) -> 'QuaternionDmp':
        """
        Learn the weights from one demonstration.

        Parameters
        ----------
        T : array_like, shape (n,)
            Strictly increasing sample times, s (``n >= 5``).
        Q : array_like, shape (n, 4)
            Unit quaternions (x, y, z, w); signs may flip between samples (they are made
            continuous). The rotation relative to the goal must stay below 357 degrees.

        Returns
        -------
        self

        """
        T = check_array(T, 'T', shape=(None,))
        Q = check_quaternions(check_array(Q, 'Q', shape=(None, 4)), 'Q')
        s, x, duration = self._fit_time(T, Q.shape[0], 'Q')
        p = self.params
        Q = quaternion_sign_continuous(Q)
        start, goal = Q[0].copy(), Q[-1].copy()
        if self._log_form:
            U = 2.0 * quaternion_log(quaternion_product(Q, quaternion_conjugate(goal)))
            targets = position_forcing_target(s, U, np.zeros(3), p.alpha_z, p.beta_z)
        else:
            targets, U = quaternion_forcing_target(s, Q, goal, p.alpha_z, p.beta_z)
        largest = float(np.max(np.linalg.norm(U, axis=1)))
        if largest > MAX_ROTATION:
            raise ValueError(
                f'Q turns by {math.degrees(largest):.1f} degrees relative to its goal; the '
                f'quaternion DMP needs less than {math.degrees(MAX_ROTATION):.0f} (split the '
                'movement)')
        scale, degenerate = guarded_scale(-U[0], np.ptp(U, axis=0), p.scale_guard,
                                          p.scale_guard_floor_rad)
        psi = self._activations(s, x, self._centres, self._widths)
        self.weights_ = self._weights(psi, x, targets, scale)
        self.start_, self.goal_, self.degenerate_ = start, goal, degenerate
        self.duration_ = duration
        return self

    def align_goal(self, start: FloatArray, goal: FloatArray) -> FloatArray:
        """
        Return ``goal`` or ``-goal``, whichever turns from ``start`` most like the demonstration.

        With the literal log the sign decides which way round the primitive turns; this keeps
        the demonstrated direction (and a demonstrated turn of more than 180 degrees).

        Parameters
        ----------
        start, goal : ndarray, shape (4,)
            Unit quaternions (x, y, z, w).

        Returns
        -------
        ndarray, shape (4,)
            The goal with the chosen sign.

        """
        self._check_fitted()
        demo = quaternion_product(self.goal_, quaternion_conjugate(self.start_))
        new = quaternion_product(goal, quaternion_conjugate(start))
        return -goal if float(np.dot(demo, new)) < 0.0 else np.array(goal, dtype=float)

    def _endpoints(self, start: ArrayLike | None,
                   goal: ArrayLike | None) -> tuple[FloatArray, FloatArray]:
        self._check_fitted()
        start = self.start_ if start is None else check_quaternions(
            check_array(start, 'start', shape=(4,)), 'start')
        goal = self.goal_ if goal is None else check_quaternions(
            check_array(goal, 'goal', shape=(4,)), 'goal')
        return np.array(start, dtype=float), self.align_goal(start, goal)

    def scale(self, start: FloatArray, goal: FloatArray) -> FloatArray:
        """
        Return the diagonal of ``D_o = diag(2 log(g * conj(q0)))`` (1 in guarded components).

        Parameters
        ----------
        start, goal : ndarray, shape (4,)
            Unit quaternions (x, y, z, w), goal sign aligned (:meth:`align_goal`).

        Returns
        -------
        ndarray, shape (3,)
            Scale, rad.

        """
        offset = 2.0 * quaternion_log(quaternion_product(goal, quaternion_conjugate(start)))
        return np.where(self.degenerate_, 1.0, offset)

    def rollout(self, start: ArrayLike | None = None, goal: ArrayLike | None = None,
                n_pts: int | None = None, T: ArrayLike | None = None,
                return_velocity: bool = False) -> tuple[FloatArray, ...]:
        """
        Generate the whole orientation trajectory from ``start`` to ``goal``.

        Parameters
        ----------
        start, goal : array_like, shape (4,), optional
            Unit quaternions (x, y, z, w); the demonstrated ones by default. The goal's sign
            is chosen by :meth:`align_goal`.
        n_pts : int, optional
            Number of points over the demonstrated duration (``params.n_pts`` by default).
        T : array_like, shape (n,), optional
            Evenly spaced output times, s.
        return_velocity : bool
            Also return the angular velocities.

        Returns
        -------
        T : ndarray, shape (n,)
            Times, s.
        Q : ndarray, shape (n, 4)
            Sign-continuous unit quaternions.
        W : ndarray, shape (n, 3)
            Angular velocities in the frame of the quaternions, rad/s (only with
            ``return_velocity``).

        """
        T, tau = self._time_grid(n_pts, T)
        start, goal = self._endpoints(start, goal)
        with np.errstate(over='ignore', invalid='ignore'):
            U, W = self._integrate(start, goal, T.size)
        if not (np.isfinite(U).all() and np.isfinite(W).all()):
            raise ValueError(self._divergence(start, goal))
        Q = quaternion_product(quaternion_exp(0.5 * U), goal)
        if return_velocity:
            return T, Q, W / tau
        return T, Q

    def _divergence(self, start: FloatArray, goal: FloatArray) -> str:
        """Say why a rollout from ``start`` to ``goal`` diverged (the forcing scale)."""
        demo = self.scale(self.start_, self.goal_)
        new = self.scale(start, goal)
        ratio = np.abs(new) / np.maximum(np.abs(demo), 1e-12)
        k = int(np.argmax(ratio))
        return (f'the orientation DMP diverges from this start to this goal: the goal-relative '
                f'rotation {np.round(np.degrees(new), 1).tolist()} deg scales a forcing term '
                f'learnt on {np.round(np.degrees(demo), 2).tolist()} deg, {ratio[k]:.0f} times '
                f'in component {"xyz"[k]} (the D_o scaling of the demonstrated turn)')

    def _integrate(self, start: FloatArray, goal: FloatArray,
                   n: int) -> tuple[FloatArray, FloatArray]:
        """Return (u, omega), each (n, 3): goal-relative rotation vector and angular velocity."""
        p = self.params
        _, features = uniform_features(n, p.n_bfs_o, p.alpha_x)
        f = forcing_term(features, self.weights_, self.scale(start, goal)).T
        Phi, Gz, B0, B1 = transition_matrices(p.alpha_z, p.beta_z, 1.0 / (n - 1))
        C_f = B0[:, 1, None, None] * f[None, :, :-1] + B1[:, 1, None, None] * f[None, :, 1:]
        u0 = 2.0 * quaternion_log(quaternion_product(start, quaternion_conjugate(goal)))
        state0 = np.stack((u0, np.zeros(3)))
        if self._log_form:
            Z = linear_recurrence(Phi, C_f, state0)
            return Z[0].T, so3_left_jacobian_apply(Z[0].T, Z[1].T)
        # Solve the explicit recurrence by relaxation: the nonlinear rate is evaluated on the
        # previous sweep (superlinear convergence; one sweep for a rotation about a fixed axis).
        # The recurrence is linear in its input, so a sweep adds the response to the nonlinear
        # rate (one lfilter for u; omega follows from the first row of the recurrence) to the
        # fixed response to the forcing term.
        gain = Gz[:, 0]
        b_u, _, a = input_filters(Phi, gain)
        Z_f = linear_recurrence(Phi, C_f, state0)
        U_f, W_f = Z_f[0, :, :-1], Z_f[1, :, :-1]
        U, W = U_f, W_f
        N = np.zeros((3, n - 1))
        for _ in range(_RELAX_ITERATIONS):
            N_new = nonlinear_rate(U, W)
            change = float(np.abs(N_new - N).max(initial=0.0))
            if change <= _RELAX_TOLERANCE * (1.0 + float(np.abs(W).max())):
                # one more sweep with the newest rate, without another rate evaluation
                Z = Z_f.copy()
                Z[:, :, 1:] += input_response(Phi, gain, N_new)
                return Z[0].T, Z[1].T
            N = N_new
            r = lfilter(b_u, a, N, axis=-1)  # response of u at samples 1 .. n-1
            U = U_f.copy()
            U[:, 1:] += r[:, :-1]
            W = W_f.copy()
            W[:, 1:] += (r[:, 1:] - Phi[0, 0] * r[:, :-1] - gain[0] * N[:, 1:]) / Phi[0, 1]
        LOG.debug('quaternion rollout: relaxation did not settle; stepping sequentially')
        U, W = np.empty((3, n)), np.empty((3, n))
        U[:, 0], W[:, 0] = state0
        for k in range(n - 1):
            z = (Phi @ np.stack((U[:, k], W[:, k])) + Gz[:, 0:1] * nonlinear_rate(U[:, k], W[:, k])
                 + C_f[:, :, k])
            U[:, k + 1], W[:, k + 1] = z
        return U.T, W.T

    # --- online ------------------------------------------------------------------------------
    def _begin(self, start: ArrayLike | None, goal: ArrayLike | None) -> None:
        start, goal = self._endpoints(start, goal)
        self._q0, self._g, self._G = start, goal.copy(), goal.copy()
        self._q, self._w = start.copy(), np.zeros(3)

    def set_goal(self, goal: ArrayLike, immediate: bool = False) -> None:
        """
        Switch the goal of the online execution (unit quaternion x, y, z, w).

        The active goal turns towards the new one along the geodesic with
        ``2 log(g(t) * conj(g(0))) = (1 - exp(-alpha_g t)) 2 log(G * conj(g(0)))``.

        Parameters
        ----------
        goal : array_like, shape (4,)
            New goal.
        immediate : bool
            Skip the goal filter.

        """
        if not self._running:
            raise ValueError('call reset() before set_goal()')
        goal = check_quaternions(check_array(goal, 'goal', shape=(4,)), 'goal')
        self._G = self.align_goal(self._q0, goal)
        if immediate:
            self._g = self._G.copy()

    def _phase_error(self, measured: ArrayLike) -> float:
        measured = check_quaternions(check_array(measured, 'measured', shape=(4,)), 'measured')
        return self.params.phase_stop_orientation * float(quaternion_angle(measured, self._q)) ** 2

    def _advance(self, h: float, x0: float, x1: float) -> None:
        p = self.params
        g0 = self._g
        towards = quaternion_product(self._G, quaternion_conjugate(g0))
        if towards[3] < 0.0:
            towards = -towards
        g1 = quaternion_product(
            quaternion_exp((1.0 - math.exp(-p.goal_filter * h)) * quaternion_log(towards)), g0)
        u = 2.0 * quaternion_log(quaternion_product(self._q, quaternion_conjugate(g0)))
        f0 = self._forcing_at(x0, g0)
        f1 = self._forcing_at(x1, g1)
        Phi, Gz, B0, B1 = transition_matrices(p.alpha_z, p.beta_z, h)
        z = Phi @ np.stack((u, self._w)) + B0[:, 1:2] * f0 + B1[:, 1:2] * f1
        if not self._log_form:
            z += Gz[:, 0:1] * nonlinear_rate(u, self._w)[None, :]
        self._q = quaternion_product(quaternion_exp(0.5 * z[0]), g0)
        self._w, self._g = z[1], g1

    def _forcing_at(self, x: float, goal: FloatArray) -> FloatArray:
        features = normalised_features(np.array([x]), self._centres, self._widths)[0]
        return (features @ self.weights_) * self.scale(self._q0, goal)

    def _output(self) -> FloatArray:
        return self._q.copy()

    @property
    def angular_velocity(self) -> FloatArray:
        """ndarray, shape (3,): Commanded angular velocity (frame of the quaternions), rad/s."""
        if self._log_form:
            u = 2.0 * quaternion_log(quaternion_product(self._q, quaternion_conjugate(self._g)))
            return so3_left_jacobian_apply(u, self._w) / self._tau
        return self._w / self._tau

    @property
    def goal(self) -> FloatArray:
        """ndarray, shape (4,): Active (filtered) goal of the online execution."""
        return self._g.copy()

    # --- files -------------------------------------------------------------------------------
    @classmethod
    def _from_arrays(cls, params: DmpParams, arrays: dict[str, Any], path: PathLike,
                     prefix: str = 'orientation.') -> 'QuaternionDmp':
        dmp = cls(params)
        dmp._read_arrays(arrays, path, prefix)
        if dmp.weights_.shape != (params.n_bfs_o, 3) or dmp.start_.shape != (4,):
            raise ValueError(f'{path}: orientation weights have shape {dmp.weights_.shape}, '
                             f'expected ({params.n_bfs_o}, 3)')
        return dmp
