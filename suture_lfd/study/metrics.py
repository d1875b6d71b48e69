"""
Trajectory errors for evaluating regenerated needle trajectories (DTW-aligned), with definitions.

"DTW distance" means different numbers in different libraries (lfd_anchors section 2.8), so
every result here carries a ``definition`` string next to its numbers. The warping path is the
classic one: local cost = Euclidean distance (positions) or rotation angle (orientations);
steps (1, 0), (0, 1), (1, 1) with unit weights; the path runs from the first pair of samples
to the last and minimises the summed local cost.

Units: positions are given in m and reported in mm; orientations are quaternions (x, y, z, w)
and errors are reported in degrees.
"""

import math
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.distance import cdist
from sim_bridge.common.geometry import quaternion_angle
from sim_bridge.common.validation import FloatArray, check_array, check_quaternions

if TYPE_CHECKING:
    from typing_extensions import Buffer

DTW_DEFINITION = (
    'DTW warping path with local cost {cost}; steps (1,0), (0,1), (1,1) with unit weights; '
    'path from (0,0) to (n-1,m-1) minimising the summed local cost')
POSITION_DEFINITION = (
    'mean_mm / max_mm = mean / max Euclidean distance in mm between the samples paired by the '
    'DTW warping path (' + DTW_DEFINITION.format(cost='= Euclidean distance') + ')')
ORIENTATION_DEFINITION = (
    'mean_deg / max_deg = mean / max rotation angle in degrees between the orientations paired '
    'by the DTW warping path, angle = 2 atan2(|v|, |w|) of q_b * conj(q_a) (q and -q equal) ('
    + DTW_DEFINITION.format(cost='= that angle') + ')')
ENDPOINT_DEFINITION = (
    'start_mm / goal_mm = Euclidean distance in mm between the first / last sample of the '
    'trajectory (t = 0 / t = T) and the desired start / goal; start_deg / goal_deg = rotation '
    'angle in degrees between the first / last orientation and the desired one')


def _trajectory(A: ArrayLike, name: str) -> FloatArray:
    A = check_array(A, name)
    if A.ndim == 1:
        A = A[:, None]
    if A.ndim != 2 or A.shape[0] < 1:
        raise ValueError(f'{name} must have shape (n, n_dims) with n >= 1, got {A.shape}')
    return A


def dtw_accumulated_cost(cost: ArrayLike) -> FloatArray:
    """
    Return the accumulated DTW cost matrix.

    ``D[i, j] = c[i, j] + min(D[i-1, j], D[i, j-1], D[i-1, j-1])``, ``D[0, 0] = c[0, 0]``.

    Row by row without an inner Python loop: with ``m_j = c_j + min(D[i-1, j], D[i-1, j-1])``,
    the row recurrence ``D_j = min(m_j, c_j + D_{j-1})`` is
    ``D_j = S_j + min_{k <= j}(m_k - S_k)`` with ``S`` the running sum of ``c`` along the row,
    a ``numpy.minimum.accumulate``.

    Parameters
    ----------
    cost : ndarray, shape (n, m)
        Non-negative local costs.

    Returns
    -------
    ndarray, shape (n, m)
        Accumulated costs; ``D[-1, -1]`` is the DTW cost.

    """
    cost = np.ascontiguousarray(cost, dtype=float)
    n, m = cost.shape
    S = np.cumsum(cost, axis=1)
    E = cost - S
    D = np.empty((n, m + 1))
    D[:, 0] = np.inf
    D[0, 1:] = S[0]
    here = list(D[:, 1:])
    left = list(D[:, :-1])
    rows_E = list(E)
    rows_S = list(S)
    t = np.empty(m)
    minimum, accumulate, add = np.minimum, np.minimum.accumulate, np.add
    for i in range(1, n):
        minimum(here[i - 1], left[i - 1], out=t)
        add(t, rows_E[i], out=t)
        accumulate(t, out=t)
        add(t, rows_S[i], out=here[i])
    return D[:, 1:]


def _backtrack(D: FloatArray) -> np.ndarray:
    """Return the optimal path (K, 2) through accumulated costs, diagonal first on ties."""
    n, m = D.shape
    flat = memoryview(cast('Buffer', np.ascontiguousarray(D).reshape(-1)))
    i, j = n - 1, m - 1
    rows, cols = [i], [j]
    while i > 0 and j > 0:
        k = i * m + j
        diag, up, left = flat[k - m - 1], flat[k - m], flat[k - 1]
        if diag <= up and diag <= left:
            i -= 1
            j -= 1
        elif up <= left:
            i -= 1
        else:
            j -= 1
        rows.append(i)
        cols.append(j)
    if i > 0:
        rows.extend(range(i - 1, -1, -1))
        cols.extend([0] * i)
    elif j > 0:
        cols.extend(range(j - 1, -1, -1))
        rows.extend([0] * j)
    return np.column_stack((rows[::-1], cols[::-1]))


def dtw_path_from_cost(cost: ArrayLike) -> tuple[np.ndarray, float]:
    """
    Return the DTW warping path for a matrix of local costs, and its summed cost.

    Parameters
    ----------
    cost : array_like, shape (n, m)
        Non-negative local costs between sample i of the first and j of the second sequence.

    Returns
    -------
    path : ndarray of int, shape (K, 2)
        Index pairs ``(i, j)``, from ``(0, 0)`` to ``(n - 1, m - 1)``, each step one of
        ``(1, 0)``, ``(0, 1)``, ``(1, 1)``.
    total : float
        Summed local cost along the path.

    """
    cost = check_array(cost, 'cost', shape=(None, None))
    if cost.size == 0 or np.any(cost < 0.0):
        raise ValueError('cost must be a non-empty matrix of non-negative local costs')
    D = dtw_accumulated_cost(cost)
    return _backtrack(D), float(D[-1, -1])


def dtw_path(A: ArrayLike, B: ArrayLike) -> tuple[np.ndarray, float]:
    """
    Return the DTW warping path between two trajectories and its summed Euclidean cost.

    Parameters
    ----------
    A : array_like, shape (n, n_dims)
        First trajectory (any unit; positions in m for the error functions below).
    B : array_like, shape (m, n_dims)
        Second trajectory, same unit.

    Returns
    -------
    path : ndarray of int, shape (K, 2)
        Index pairs ``(i, j)``, from ``(0, 0)`` to ``(n - 1, m - 1)``.
    total : float
        Summed Euclidean distance along the path (unit of the trajectories).

    """
    return dtw_path_from_cost(cdist(*_pair(A, B)))


def _pair(A: ArrayLike, B: ArrayLike) -> tuple[FloatArray, FloatArray]:
    A = _trajectory(A, 'A')
    B = _trajectory(B, 'B')
    if A.shape[1] != B.shape[1]:
        raise ValueError(f'A and B must have the same number of columns, got {A.shape[1]} '
                         f'and {B.shape[1]}')
    return A, B


def dtw_distance(A: ArrayLike, B: ArrayLike) -> float:
    """
    Return the DTW cost: the summed Euclidean distance along the optimal warping path.

    Parameters
    ----------
    A : array_like, shape (n, n_dims)
        First trajectory.
    B : array_like, shape (m, n_dims)
        Second trajectory, same unit.

    Returns
    -------
    float
        Sum over the path of ``|a_i - b_j|`` (unit of the trajectories; not the square root of
        a sum of squares as dtaidistance and tslearn report).

    """
    return float(dtw_accumulated_cost(cdist(*_pair(A, B)))[-1, -1])


def trajectory_error(A: ArrayLike, B: ArrayLike, path: ArrayLike | None = None
                     ) -> dict[str, Any]:
    """
    Return the DTW position trajectory error, in mm, with its definition.

    Parameters
    ----------
    A : array_like, shape (n, 3)
        Reference trajectory (e.g. the demonstration), m.
    B : array_like, shape (m, 3)
        Trajectory to evaluate (e.g. the regenerated one), m, same frame.
    path : array_like of int, shape (K, 2), optional
        Warping path to use (from :func:`dtw_path`); computed if omitted.

    Returns
    -------
    dict
        ``mean_mm``, ``max_mm`` (floats), ``n_pairs`` (int), ``path`` (ndarray (K, 2)) and
        ``definition`` (str): mean / max Euclidean distance between path pairs.

    """
    A, B = _pair(A, B)
    if path is None:
        path, _ = dtw_path(A, B)
    path = _check_path(path, A.shape[0], B.shape[0])
    d = np.linalg.norm(A[path[:, 0]] - B[path[:, 1]], axis=1) * 1e3
    return {'mean_mm': float(d.mean()), 'max_mm': float(d.max()), 'n_pairs': int(d.size),
            'path': path, 'definition': POSITION_DEFINITION}


def orientation_trajectory_error(QA: ArrayLike, QB: ArrayLike, path: ArrayLike | None = None
                                 ) -> dict[str, Any]:
    """
    Return the DTW orientation trajectory error, in degrees, with its definition.

    Parameters
    ----------
    QA : array_like, shape (n, 4)
        Reference orientations, unit quaternions (x, y, z, w).
    QB : array_like, shape (m, 4)
        Orientations to evaluate, same frame.
    path : array_like of int, shape (K, 2), optional
        Warping path to use (e.g. the position path, to pair the same samples); by default
        the DTW path with the rotation angle as local cost.

    Returns
    -------
    dict
        ``mean_deg``, ``max_deg`` (floats), ``n_pairs`` (int), ``path`` (ndarray (K, 2)) and
        ``definition`` (str).

    """
    QA = check_quaternions(check_array(QA, 'QA', shape=(None, 4), min_rows=1), 'QA')
    QB = check_quaternions(check_array(QB, 'QB', shape=(None, 4), min_rows=1), 'QB')
    definition = ORIENTATION_DEFINITION
    if path is None:
        cost = 2.0 * np.arccos(np.minimum(np.abs(QA @ QB.T), 1.0))
        path, _ = dtw_path_from_cost(cost)
    else:
        definition = definition.replace(
            'paired by the DTW warping path', 'paired by the given warping path')
    path = _check_path(path, QA.shape[0], QB.shape[0])
    d = np.degrees(quaternion_angle(QA[path[:, 0]], QB[path[:, 1]]))
    return {'mean_deg': float(d.mean()), 'max_deg': float(d.max()), 'n_pairs': int(d.size),
            'path': path, 'definition': definition}


def _check_path(path: ArrayLike, n: int, m: int) -> np.ndarray:
    path = np.asarray(path)
    if (path.ndim != 2 or path.shape[1] != 2 or path.shape[0] == 0
            or not np.issubdtype(path.dtype, np.integer)):
        raise ValueError(f'path must be an integer array of shape (K, 2), got {path.shape}')
    if (path.min(axis=0) < 0).any() or path[:, 0].max() >= n or path[:, 1].max() >= m:
        raise ValueError(f'path indexes outside the trajectories ({n} and {m} samples)')
    return path


def endpoint_errors(P: ArrayLike, start: ArrayLike, goal: ArrayLike, Q: ArrayLike | None = None,
                    start_q: ArrayLike | None = None, goal_q: ArrayLike | None = None
                    ) -> dict[str, Any]:
    """
    Return the start and goal errors of a trajectory (goal error at t = T, its last sample).

    With the paper's ``alpha_x = 1`` the forcing term is still active at t = T, so the goal
    error is defined there, not after convergence (lfd_anchors section 2.2).

    Parameters
    ----------
    P : array_like, shape (n, 3)
        Trajectory positions, m.
    start, goal : array_like, shape (3,)
        Desired start and goal positions, m, same frame.
    Q : array_like, shape (n, 4), optional
        Trajectory orientations (x, y, z, w).
    start_q, goal_q : array_like, shape (4,), optional
        Desired start and goal orientations (required with ``Q``).

    Returns
    -------
    dict
        ``start_mm``, ``goal_mm`` and, with orientations, ``start_deg``, ``goal_deg``; plus
        ``definition`` (str).

    """
    P = check_array(P, 'P', shape=(None, 3), min_rows=1)
    start = check_array(start, 'start', shape=(3,))
    goal = check_array(goal, 'goal', shape=(3,))
    out: dict[str, Any] = {'start_mm': float(np.linalg.norm(P[0] - start) * 1e3),
           'goal_mm': float(np.linalg.norm(P[-1] - goal) * 1e3)}
    if Q is not None:
        if start_q is None or goal_q is None:
            raise ValueError('start_q and goal_q are required when Q is given')
        Q = check_quaternions(check_array(Q, 'Q', shape=(None, 4), min_rows=1), 'Q')
        start_q = check_quaternions(check_array(start_q, 'start_q', shape=(4,)), 'start_q')
        goal_q = check_quaternions(check_array(goal_q, 'goal_q', shape=(4,)), 'goal_q')
        out['start_deg'] = math.degrees(float(quaternion_angle(Q[0], start_q)))
        out['goal_deg'] = math.degrees(float(quaternion_angle(Q[-1], goal_q)))
    out['definition'] = ENDPOINT_DEFINITION
    return out
