"""
Resampling of recorded trajectories to a fixed number of points before learning.

As in the seed paper's preprocessing: quintic interpolation for positions, spherical linear
interpolation (SLERP) for orientations. SLERP runs between neighbouring samples along the short
arc, after making the sequence sign-continuous, so a turn of more than 180 degrees in total is
kept (only the start-to-goal log of the DMP goes the long way).

Times in s, positions in any length unit (m in this package), quaternions (x, y, z, w).
"""

import numpy as np
from scipy.interpolate import make_interp_spline
from sim_bridge.common.geometry import quaternion_sign_continuous, quaternion_slerp
from sim_bridge.common.validation import check_array, check_quaternions, check_times

QUINTIC_MIN_POINTS = 6


def uniform_times(T, n_pts):
    """
    Return ``n_pts`` evenly spaced times spanning ``T``.

    Parameters
    ----------
    T : array_like, shape (n,)
        Strictly increasing times, s.
    n_pts : int
        Number of output times (>= 2).

    Returns
    -------
    ndarray, shape (n_pts,)
        ``linspace(T[0], T[-1], n_pts)``.

    """
    T = check_times(T, 'T')
    if isinstance(n_pts, bool) or not isinstance(n_pts, (int, np.integer)) or n_pts < 2:
        raise ValueError(f'n_pts must be an integer >= 2, got {n_pts!r}')
    return np.linspace(T[0], T[-1], int(n_pts))


def _query_times(T, T_new):
    T_new = check_array(T_new, 'T_new', shape=(None,))
    if T_new.size and (T_new.min() < T[0] - 1e-12 or T_new.max() > T[-1] + 1e-12):
        raise ValueError(f'T_new must lie within [{T[0]!r}, {T[-1]!r}] s (no extrapolation), '
                         f'got [{T_new.min()!r}, {T_new.max()!r}]')
    return np.clip(T_new, T[0], T[-1])


def resample_positions(T, P, T_new):
    """
    Return positions at new times by a quintic interpolating spline (C4, ``k = 5``).

    Parameters
    ----------
    T : array_like, shape (n,)
        Strictly increasing sample times, s (``n >= 6``).
    P : array_like, shape (n, n_dims)
        Positions.
    T_new : array_like, shape (m,)
        Output times within ``[T[0], T[-1]]``, s.

    Returns
    -------
    ndarray, shape (m, n_dims)
        Interpolated positions (the spline passes through every sample).

    """
    T = check_times(T, 'T', min_points=QUINTIC_MIN_POINTS)
    P = check_array(P, 'P', shape=(T.size, None))
    T_new = _query_times(T, T_new)
    return make_interp_spline(T, P, k=5, axis=0)(T_new)


def resample_quaternions(T, Q, T_new):
    """
    Return orientations at new times by SLERP between the neighbouring samples.

    Parameters
    ----------
    T : array_like, shape (n,)
        Strictly increasing sample times, s (``n >= 2``).
    Q : array_like, shape (n, 4)
        Unit quaternions (x, y, z, w); signs may flip between samples.
    T_new : array_like, shape (m,)
        Output times within ``[T[0], T[-1]]``, s.

    Returns
    -------
    ndarray, shape (m, 4)
        Sign-continuous unit quaternions, starting with the sign of ``Q[0]``.

    """
    T = check_times(T, 'T')
    Q = check_quaternions(check_array(Q, 'Q', shape=(T.size, 4)), 'Q')
    T_new = _query_times(T, T_new)
    Q = quaternion_sign_continuous(Q)
    k = np.clip(np.searchsorted(T, T_new, side='right') - 1, 0, T.size - 2)
    u = (T_new - T[k]) / (T[k + 1] - T[k])
    return quaternion_slerp(Q[k], Q[k + 1], u, shortest_path=True)


def resample_poses(T, P, Q, n_pts=None, T_new=None):
    """
    Return a pose trajectory resampled to ``n_pts`` evenly spaced times (or to ``T_new``).

    Parameters
    ----------
    T : array_like, shape (n,)
        Strictly increasing sample times, s (``n >= 6``).
    P : array_like, shape (n, 3)
        Positions, m.
    Q : array_like, shape (n, 4)
        Unit quaternions (x, y, z, w).
    n_pts : int, optional
        Number of evenly spaced output samples over ``[T[0], T[-1]]``.
    T_new : array_like, shape (m,), optional
        Output times instead of ``n_pts``.

    Returns
    -------
    T_new : ndarray, shape (m,)
        Output times, s.
    P_new : ndarray, shape (m, 3)
        Quintic-interpolated positions, m.
    Q_new : ndarray, shape (m, 4)
        SLERP-interpolated, sign-continuous quaternions.

    """
    if (n_pts is None) == (T_new is None):
        raise ValueError('give exactly one of n_pts and T_new')
    T = check_times(T, 'T', min_points=QUINTIC_MIN_POINTS)
    if T_new is None:
        T_new = uniform_times(T, n_pts)
    P_new = resample_positions(T, check_array(P, 'P', shape=(T.size, 3)), T_new)
    return np.asarray(T_new, dtype=float), P_new, resample_quaternions(T, Q, T_new)
