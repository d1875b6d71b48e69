import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp
from sim_bridge.common.geometry import quaternion_angle, quaternion_from_rotvec, quaternion_product
from suture_lfd.demos.resampling import resample_poses, resample_positions, resample_quaternions


def test_quintic_resampling_is_exact_on_quintic_polynomials():
    rng = np.random.default_rng(0)
    T = np.sort(rng.uniform(0.0, 2.0, 40))
    coeffs = rng.normal(size=(6, 3))
    poly = np.stack([np.polyval(c, T) for c in coeffs.T], axis=1)
    T_new = np.linspace(T[0], T[-1], 500)
    expected = np.stack([np.polyval(c, T_new) for c in coeffs.T], axis=1)
    assert np.allclose(resample_positions(T, poly, T_new), expected, atol=1e-9)


def test_resampling_a_smooth_recording_to_500_points_is_accurate():
    T = np.linspace(0.0, 2.0, 120)
    P = 0.01 * np.column_stack((np.cos(2 * T), np.sin(3 * T), T ** 2))
    T_new, P_new, _ = resample_poses(T, P, np.tile([0.0, 0.0, 0.0, 1.0], (T.size, 1)), 500)
    truth = 0.01 * np.column_stack((np.cos(2 * T_new), np.sin(3 * T_new), T_new ** 2))
    assert T_new.shape == (500,) and np.isclose(T_new[-1], 2.0)
    assert np.abs(P_new - truth).max() < 1e-8


def test_slerp_resampling_matches_scipy_and_survives_sign_flips():
    rng = np.random.default_rng(1)
    T = np.linspace(0.0, 1.0, 30)
    Q = Rotation.from_rotvec(np.cumsum(rng.normal(scale=0.1, size=(30, 3)), axis=0)).as_quat()
    flipped = Q * np.where(rng.random(30) < 0.5, -1.0, 1.0)[:, None]
    T_new = np.linspace(0.0, 1.0, 301)
    ours = resample_quaternions(T, flipped, T_new)
    ref = Slerp(T, Rotation.from_quat(Q))(T_new).as_quat()
    assert np.degrees(quaternion_angle(ours, ref)).max() < 1e-7
    assert np.all(np.sum(ours[1:] * ours[:-1], axis=1) > 0.0)


def test_a_turn_of_more_than_180_degrees_is_kept():
    T = np.linspace(0.0, 1.0, 25)
    Q = quaternion_from_rotvec(np.radians(300.0) * T[:, None] * [0.0, 0.6, 0.8])
    out = resample_quaternions(T, Q, np.linspace(0.0, 1.0, 500))
    steps = quaternion_angle(out[1:], out[:-1])
    assert np.isclose(np.degrees(steps.sum()), 300.0)
    assert np.allclose(quaternion_angle(out[-1], quaternion_product(Q[-1], [0, 0, 0, 1])), 0.0,
                       atol=1e-9)


def test_bad_input_names_the_argument():
    T = np.linspace(0.0, 1.0, 10)
    P = np.zeros((10, 3))
    with pytest.raises(ValueError, match=r'T needs at least 6 points'):
        resample_positions(T[:4], P[:4], [0.5])
    with pytest.raises(ValueError, match=r'T_new must lie within'):
        resample_positions(T, P, [1.5])
    Q = np.tile([0.0, 0.0, 0.0, 1.0], (10, 1))
    Q[3] = 0.0
    with pytest.raises(ValueError, match=r'Q is not a unit quaternion'):
        resample_quaternions(T, Q, [0.5])
    with pytest.raises(ValueError, match=r'exactly one of n_pts and T_new'):
        resample_poses(T, P, np.tile([0.0, 0.0, 0.0, 1.0], (10, 1)))
