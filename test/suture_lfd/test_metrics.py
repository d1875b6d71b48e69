import numpy as np
import pytest
from scipy.spatial.distance import cdist
from sim_bridge.common.geometry import quaternion_from_rotvec, quaternion_product
from suture_lfd.demos.synthetic_throw import needle_throw
from suture_lfd.study.metrics import (
    dtw_distance,
    dtw_path,
    dtw_path_from_cost,
    endpoint_errors,
    orientation_trajectory_error,
    trajectory_error,
)


def direct_dtw(cost):
    """The textbook O(nm) double loop."""
    n, m = cost.shape
    D = np.full((n + 1, m + 1), np.inf)
    D[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            D[i, j] = cost[i - 1, j - 1] + min(D[i - 1, j], D[i, j - 1], D[i - 1, j - 1])
    return D[n, m]


def test_dtw_agrees_with_the_direct_double_loop():
    rng = np.random.default_rng(0)
    for _ in range(200):
        n, m = rng.integers(1, 30, size=2)
        dims = int(rng.integers(1, 4))
        A, B = rng.normal(size=(n, dims)), rng.normal(size=(m, dims))
        if rng.random() < 0.3:
            B = np.round(B)                                  # ties in the cost
            A = np.round(A)
        path, total = dtw_path(A, B)
        assert np.isclose(total, direct_dtw(cdist(A, B)), rtol=1e-12, atol=1e-12)
        assert np.isclose(dtw_distance(A, B), total)
        assert tuple(path[0]) == (0, 0) and tuple(path[-1]) == (n - 1, m - 1)
        steps = np.diff(path, axis=0)
        assert np.all(np.isin(steps, [0, 1])) and np.all(steps.sum(axis=1) >= 1)
        assert np.isclose(np.linalg.norm(A[path[:, 0]] - B[path[:, 1]], axis=1).sum(), total)


def test_dtw_undoes_a_change_of_timing():
    T, P, _ = needle_throw(500, 1.0)
    warped_time = np.linspace(0.0, 1.0, 450) ** 1.3
    Pw = np.column_stack([np.interp(warped_time, T, p) for p in P.T])
    error = trajectory_error(P, Pw)
    assert error['mean_mm'] < 0.05
    lockstep = np.linalg.norm(P[np.linspace(0, 499, 450).astype(int)] - Pw, axis=1)
    assert np.mean(lockstep) * 1e3 > 10 * error['mean_mm']


def test_errors_are_reported_in_mm_and_degrees_with_their_definition():
    T, _, Q = needle_throw(200, 1.0)
    P = np.column_stack((np.linspace(0.0, 0.02, 200), np.zeros(200), np.zeros(200)))
    shifted = trajectory_error(P, P + [0.0, 0.0, 0.001])     # across the path: DTW can't slide
    assert np.isclose(shifted['mean_mm'], 1.0) and np.isclose(shifted['max_mm'], 1.0)
    assert 'Euclidean distance in mm' in shifted['definition']
    still = np.tile(Q[0], (200, 1))
    error = orientation_trajectory_error(still, -quaternion_product(
        quaternion_from_rotvec([0.0, 0.0, np.radians(2.0)]), still))
    assert np.isclose(error['mean_deg'], 2.0) and np.isclose(error['max_deg'], 2.0)
    assert 'degrees' in error['definition']
    turned = quaternion_product(quaternion_from_rotvec([0.0, 0.0, np.radians(2.0)]), Q)
    same_path = orientation_trajectory_error(Q, turned, path=shifted['path'])
    assert 'given warping path' in same_path['definition']
    ends = endpoint_errors(P + [0.0, 0.0, 0.002], P[0], P[-1], turned, Q[0], Q[-1])
    assert np.isclose(ends['start_mm'], 2.0) and np.isclose(ends['goal_mm'], 2.0)
    assert np.isclose(ends['goal_deg'], 2.0)
    assert 't = T' in ends['definition']


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match=r'^A must be finite'):  # names the argument
        trajectory_error(np.array([[0.0, np.nan, 0.0]]), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r'same number of columns'):
        dtw_path(np.zeros((3, 3)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r'non-negative'):
        dtw_path_from_cost(-np.ones((2, 2)))
    with pytest.raises(ValueError, match=r'QB is not a unit quaternion \(norm 0'):
        orientation_trajectory_error(np.tile([0, 0, 0, 1.0], (3, 1)), np.zeros((3, 4)))
    with pytest.raises(ValueError, match=r'start_q and goal_q'):
        endpoint_errors(np.zeros((2, 3)), np.zeros(3), np.zeros(3), Q=np.tile([0, 0, 0, 1.0],
                                                                                (2, 1)))
