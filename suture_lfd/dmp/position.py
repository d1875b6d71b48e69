"""
Discrete position DMP (Ijspeert et al. 2013) with ``(g - y0)`` scaling and LWR weights.

Equations and integration: :mod:`suture_lfd.dmp.equations`. Positions in m, time in s.
"""

import logging
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.validation import FloatArray, check_array
from suture_lfd.dmp.base import DmpParams, PathLike, PrimitivePart
from suture_lfd.dmp.equations import (
    basis_centres,
    basis_widths,
    forcing_term,
    guarded_scale,
    linear_recurrence,
    normalised_features,
    position_forcing_target,
    transition_matrices,
    uniform_features,
)

LOG = logging.getLogger(__name__)


class PositionDmp(PrimitivePart):
    """
    Discrete position DMP (Ijspeert et al. 2013) with ``(g - y0)`` scaling and LWR weights.

    The attributes below are set by :meth:`fit`.

    Attributes
    ----------
    weights_ : ndarray, shape (n_bfs, n_dims)
        LWR weights.
    start_, goal_ : ndarray, shape (n_dims,)
        Demonstrated start and goal, m.
    duration_ : float
        Demonstrated duration, s.
    degenerate_ : ndarray of bool, shape (n_dims,)
        Dimensions learnt unscaled because the start and goal (nearly) coincide there.

    """

    KIND = 'position'
    PREFIX = 'position.'

    def __init__(self, params: DmpParams | None = None) -> None:
        super().__init__(params)
        c = basis_centres(self.params.n_bfs, self.params.alpha_x)
        self._centres, self._widths = c, basis_widths(c, self.params.alpha_x)

    def fit(self, T: ArrayLike, Y: ArrayLike) -> 'PositionDmp':
        """
        Learn the weights from one demonstration.

        Parameters
        ----------
        T : array_like, shape (n,)
            Strictly increasing sample times, s (``n >= 5``).
        Y : array_like, shape (n, n_dims)
            Positions, m, at rest at both ends for an exact reproduction.

        Returns
        -------
        self

        """
        T = check_array(T, 'T', shape=(None,))
        Y = check_array(Y, 'Y', shape=(None, None))
        s, x, duration = self._fit_time(T, Y.shape[0], 'Y')
        p = self.params
        start, goal = Y[0].copy(), Y[-1].copy()
        scale, degenerate = guarded_scale(goal - start, np.ptp(Y, axis=0), p.scale_guard,
                                          p.scale_guard_floor_m)
        if np.any(degenerate):
            LOG.info('position dimensions %s start and end at the same value; learnt unscaled',
                     np.flatnonzero(degenerate).tolist())
        targets = position_forcing_target(s, Y, goal, p.alpha_y, p.beta_y)
        psi = self._activations(s, x, self._centres, self._widths)
        self.weights_ = self._weights(psi, x, targets, scale)
        self.start_, self.goal_, self.degenerate_ = start, goal, degenerate
        self.duration_ = duration
        return self

    @property
    def n_dims(self) -> int:
        """int: Number of position dimensions."""
        self._check_fitted()
        return self.weights_.shape[1]

    def _endpoints(self, start: ArrayLike | None,
                   goal: ArrayLike | None) -> tuple[FloatArray, FloatArray]:
        start = self.start_ if start is None else check_array(start, 'start', shape=(self.n_dims,))
        goal = self.goal_ if goal is None else check_array(goal, 'goal', shape=(self.n_dims,))
        return np.array(start, dtype=float), np.array(goal, dtype=float)

    def scale(self, start: FloatArray, goal: FloatArray) -> FloatArray:
        """
        Return the forcing scale ``g - y0`` per dimension (1 in degenerate dimensions).

        Parameters
        ----------
        start, goal : ndarray, shape (n_dims,)
            Positions, m.

        Returns
        -------
        ndarray, shape (n_dims,)
            Scale, m (dimensionless 1 where guarded).

        """
        return np.where(self.degenerate_, 1.0, goal - start)

    def rollout(self, start: ArrayLike | None = None, goal: ArrayLike | None = None,
                n_pts: int | None = None, T: ArrayLike | None = None,
                return_velocity: bool = False) -> tuple[FloatArray, ...]:
        """
        Generate the whole trajectory from ``start`` to ``goal`` (constant goal, no coupling).

        Parameters
        ----------
        start, goal : array_like, shape (n_dims,), optional
            Positions, m; the demonstrated ones by default.
        n_pts : int, optional
            Number of points over the demonstrated duration (``params.n_pts`` by default).
        T : array_like, shape (n,), optional
            Evenly spaced output times, s; ``T[-1] - T[0]`` is the execution time ``tau``.
        return_velocity : bool
            Also return the velocities.

        Returns
        -------
        T : ndarray, shape (n,)
            Times, s.
        Y : ndarray, shape (n, n_dims)
            Positions, m (``Y[0] = start``).
        Yd : ndarray, shape (n, n_dims)
            Velocities, m/s (only with ``return_velocity``).

        """
        T, tau = self._time_grid(n_pts, T)
        start, goal = self._endpoints(start, goal)
        states = self._integrate(start, goal, T.size)
        Y = states[0].T + goal
        if return_velocity:
            return T, Y, states[1].T / tau
        return T, Y

    def _integrate(self, start: FloatArray, goal: FloatArray, n: int) -> FloatArray:
        """Return the states (2, n_dims, n) of (y - g, y') on n evenly spaced samples."""
        p = self.params
        _, features = uniform_features(n, p.n_bfs, p.alpha_x)
        f = forcing_term(features, self.weights_, self.scale(start, goal)).T
        Phi, _, B0, B1 = transition_matrices(p.alpha_y, p.beta_y, 1.0 / (n - 1))
        C = B0[:, 1, None, None] * f[None, :, :-1] + B1[:, 1, None, None] * f[None, :, 1:]
        state0 = np.stack((start - goal, np.zeros_like(start)))
        return linear_recurrence(Phi, C, state0)

    # --- online ------------------------------------------------------------------------------
    def _begin(self, start: ArrayLike | None, goal: ArrayLike | None) -> None:
        start, goal = self._endpoints(start, goal)
        self._y0, self._g, self._G = start, goal.copy(), goal.copy()
        self._y, self._v = start.copy(), np.zeros_like(start)

    def set_goal(self, goal: ArrayLike, immediate: bool = False) -> None:
        """
        Switch the goal of the online execution (position, m).

        The active goal follows the new one through ``g' = alpha_g (G - g)``, so the
        acceleration stays continuous; ``immediate=True`` jumps instead.

        Parameters
        ----------
        goal : array_like, shape (n_dims,)
            New goal, m.
        immediate : bool
            Skip the goal filter.

        """
        if not self._running:
            raise ValueError('call reset() before set_goal()')
        self._G = check_array(goal, 'goal', shape=(self.n_dims,)).copy()
        if immediate:
            self._g = self._G.copy()

    def _phase_error(self, measured: ArrayLike) -> float:
        measured = check_array(measured, 'measured', shape=(self.n_dims,))
        return self.params.phase_stop_position * float(np.sum((measured - self._y) ** 2))

    def _forcing_at(self, x: float, goal: FloatArray) -> FloatArray:
        features = normalised_features(np.array([x]), self._centres, self._widths)[0]
        return (features @ self.weights_) * self.scale(self._y0, goal)

    def _advance(self, h: float, x0: float, x1: float) -> None:
        p = self.params
        g0 = self._g
        g1 = self._G + (g0 - self._G) * math.exp(-p.goal_filter * h)
        ab = p.alpha_y * p.beta_y
        w0 = ab * g0 + self._forcing_at(x0, g0)
        w1 = ab * g1 + self._forcing_at(x1, g1)
        Phi, _, B0, B1 = transition_matrices(p.alpha_y, p.beta_y, h)
        state = Phi @ np.stack((self._y, self._v)) + B0[:, 1:2] * w0 + B1[:, 1:2] * w1
        self._y, self._v, self._g = state[0], state[1], g1

    def _output(self) -> FloatArray:
        return self._y.copy()

    @property
    def velocity(self) -> FloatArray:
        """ndarray, shape (n_dims,): Commanded velocity of the online execution, m/s."""
        return self._v / self._tau

    @property
    def goal(self) -> FloatArray:
        """ndarray, shape (n_dims,): Active (filtered) goal of the online execution, m."""
        return self._g.copy()

    # --- files -------------------------------------------------------------------------------
    @classmethod
    def _from_arrays(cls, params: DmpParams, arrays: dict[str, Any], path: PathLike,
                     prefix: str = 'position.') -> 'PositionDmp':
        dmp = cls(params)
        dmp._read_arrays(arrays, path, prefix)
        n_dims = dmp.start_.shape[0]
        if dmp.weights_.shape != (params.n_bfs, n_dims) or dmp.goal_.shape != (n_dims,):
            raise ValueError(f'{path}: position weights have shape {dmp.weights_.shape}, '
                             f'expected ({params.n_bfs}, {n_dims})')
        return dmp
