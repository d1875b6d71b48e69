"""
Synthetic needle throws: a reproducible stand-in for a demonstrated insertion (subtask ii).

The needle turns about its own axis with minimum-jerk timing while its centre drifts slightly
and its axis wobbles a few degrees, so no coordinate is degenerate and the rotation is not
about a fixed axis; the tip sweeps an arc of the needle radius. Used by tests and benchmarks
as the "realistic" workload of lfd_anchors section 3.0.
"""

import math

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import (
    quaternion_from_rotvec,
    quaternion_product,
    quaternion_rotate,
)
from sim_bridge.common.validation import check_array, check_positive


def minimum_jerk(s: ArrayLike) -> np.ndarray:
    """
    Return the minimum-jerk profile ``10 s^3 - 15 s^4 + 6 s^5``.

    Parameters
    ----------
    s : array_like
        Normalised time in [0, 1].

    Returns
    -------
    ndarray
        Progress in [0, 1], at rest (zero velocity and acceleration) at both ends.

    """
    s = np.asarray(s, dtype=float)
    return s ** 3 * (10.0 - 15.0 * s + 6.0 * s * s)


def needle_throw(n_pts: int = 500, duration: float = 1.0, *, radius: float = 0.010,
                 rotation_deg: float = 150.0, wobble_deg: float = 5.0,
                 drift: ArrayLike = (0.0010, -0.0006, 0.0004),
                 centre: ArrayLike = (0.0, 0.0, 0.0), start_rotvec: ArrayLike = (0.4, -0.3, 0.2)
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return times, needle-tip positions and needle orientations of a synthetic throw.

    Parameters
    ----------
    n_pts : int
        Number of samples.
    duration : float
        Duration, s.
    radius : float
        Needle radius, m (the tip is this far from the needle centre).
    rotation_deg : float
        Turn of the needle about its axis, degrees (may exceed 180).
    wobble_deg : float
        Peak tilt of the needle axis during the throw, degrees.
    drift : array_like, shape (3,)
        Displacement of the needle centre over the throw, m (world).
    centre : array_like, shape (3,)
        Needle centre at the start, m (world).
    start_rotvec : array_like, shape (3,)
        Needle orientation at the start as a rotation vector, rad (world).

    Returns
    -------
    T : ndarray, shape (n_pts,)
        Times, s.
    P : ndarray, shape (n_pts, 3)
        Needle-tip positions, m (world).
    Q : ndarray, shape (n_pts, 4)
        Needle orientations (x, y, z, w), sign-continuous (world).

    """
    if isinstance(n_pts, bool) or not isinstance(n_pts, int) or n_pts < 2:
        raise ValueError(f'n_pts must be an integer >= 2, got {n_pts!r}')
    duration = check_positive(duration, 'duration')
    drift = check_array(drift, 'drift', shape=(3,))
    centre = check_array(centre, 'centre', shape=(3,))
    q_start = quaternion_from_rotvec(check_array(start_rotvec, 'start_rotvec', shape=(3,)))
    T = np.linspace(0.0, duration, n_pts)
    m = minimum_jerk(T / duration)
    axis = quaternion_rotate(q_start, np.array([0.0, 0.0, 1.0]))       # needle axis, world
    tilt = quaternion_rotate(q_start, np.array([1.0, 0.0, 0.0]))       # in the needle plane
    turn = quaternion_from_rotvec(math.radians(rotation_deg) * m[:, None] * axis)
    wobble = quaternion_from_rotvec(
        math.radians(wobble_deg) * np.sin(math.pi * m)[:, None] * tilt)
    Q = quaternion_product(quaternion_product(wobble, turn), q_start)
    tip_in_needle = np.array([radius, 0.0, 0.0])
    P = centre + m[:, None] * drift + quaternion_rotate(Q, tip_in_needle)
    return T, P, Q
