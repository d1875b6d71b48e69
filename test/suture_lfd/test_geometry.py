import numpy as np
from scipy.spatial.transform import Rotation, Slerp
from sim_bridge.common.geometry import (
    compose_poses,
    invert_pose,
    invert_transform,
    matrix_from_quaternion,
    pose_from_transform,
    quaternion_angle,
    quaternion_conjugate,
    quaternion_exp,
    quaternion_from_matrix,
    quaternion_from_rotvec,
    quaternion_log,
    quaternion_product,
    quaternion_rotate,
    quaternion_sign_continuous,
    quaternion_slerp,
    rotvec_from_quaternion,
    transform_from_pose,
)

N = 300


def random_quaternions(rng, n=N):
    return Rotation.random(n, random_state=rng).as_quat()


def test_product_and_matrices_agree_with_scipy():
    rng = np.random.default_rng(0)
    a, b = random_quaternions(rng), random_quaternions(rng)
    ra, rb = Rotation.from_quat(a), Rotation.from_quat(b)
    assert np.allclose(matrix_from_quaternion(a), ra.as_matrix())
    assert np.allclose(matrix_from_quaternion(quaternion_product(a, b)), (ra * rb).as_matrix())
    v = rng.normal(size=(N, 3))
    assert np.allclose(quaternion_rotate(a, v), ra.apply(v))
    assert np.allclose(quaternion_product(a, quaternion_conjugate(a)), [0.0, 0.0, 0.0, 1.0])


def test_matrix_round_trip_including_half_turns():
    rng = np.random.default_rng(1)
    q = random_quaternions(rng)
    axes = rng.normal(size=(20, 3))
    half_turns = quaternion_from_rotvec(np.pi * axes / np.linalg.norm(axes, axis=1)[:, None])
    for quats in (q, half_turns):
        back = quaternion_from_matrix(matrix_from_quaternion(quats))
        assert np.all(back[:, 3] >= 0.0)
        assert np.allclose(quaternion_angle(back, quats), 0.0, atol=1e-7)


def test_literal_log_keeps_the_long_way_and_exp_inverts_it():
    rng = np.random.default_rng(2)
    axes = rng.normal(size=(N, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    angles = rng.uniform(0.0, 2.0 * np.pi - 1e-3, N)
    q = quaternion_from_rotvec(angles[:, None] * axes)
    r = 2.0 * quaternion_log(q)
    assert np.allclose(np.linalg.norm(r, axis=1), angles)          # up to 360 degrees
    assert np.allclose(quaternion_exp(quaternion_log(q)), q)
    shortest = rotvec_from_quaternion(q)
    assert np.all(np.linalg.norm(shortest, axis=1) <= np.pi + 1e-12)
    assert np.allclose(Rotation.from_rotvec(shortest).as_quat(canonical=True),
                       Rotation.from_quat(q).as_quat(canonical=True))
    assert np.allclose(quaternion_log([0.0, 0.0, 0.0, 1.0]), 0.0)


def test_slerp_between_q_and_minus_q_prime_takes_the_short_way():
    rng = np.random.default_rng(3)
    q0, q1 = random_quaternions(rng), random_quaternions(rng)
    t = rng.uniform(0.0, 1.0, N)
    ours = quaternion_slerp(q0, -q1, t)
    short = quaternion_angle(q0, q1)
    assert np.allclose(quaternion_angle(q0, ours), t * short, atol=1e-7)
    assert np.allclose(quaternion_angle(ours, q1), (1.0 - t) * short, atol=1e-7)
    for k in range(20):
        ref = Slerp([0.0, 1.0], Rotation.from_quat([q0[k], -q1[k]]))([t[k]]).as_quat()[0]
        assert quaternion_angle(ours[k], ref) < 1e-7
    # with shortest_path=False the sign decides: the long way round
    long = quaternion_slerp(q0, -q1, 0.5, shortest_path=False)
    assert np.all(quaternion_angle(q0, long) >= 0.5 * short - 1e-9)


def test_random_sign_flips_are_made_continuous():
    rng = np.random.default_rng(4)
    steps = quaternion_from_rotvec(rng.normal(scale=0.05, size=(N, 3)))
    q = [np.array([0.0, 0.0, 0.0, 1.0])]
    for step in steps:
        q.append(quaternion_product(step, q[-1]))
    q = np.array(q)
    flipped = q * np.where(rng.random(len(q)) < 0.4, -1.0, 1.0)[:, None]
    smooth = quaternion_sign_continuous(flipped, reference=q[0])
    assert np.allclose(smooth, q)
    assert np.all(np.sum(smooth[1:] * smooth[:-1], axis=1) > 0.0)


def test_poses_and_transforms_round_trip():
    rng = np.random.default_rng(5)
    poses = np.hstack((rng.normal(size=(N, 3)), random_quaternions(rng)))
    T = transform_from_pose(poses)
    assert np.allclose(transform_from_pose(pose_from_transform(T)), T)
    assert np.allclose(T @ invert_transform(T), np.eye(4))
    others = np.hstack((rng.normal(size=(N, 3)), random_quaternions(rng)))
    assert np.allclose(transform_from_pose(compose_poses(poses, others)),
                       T @ transform_from_pose(others))
    assert np.allclose(transform_from_pose(invert_pose(poses)), invert_transform(T))


def test_quaternion_angle_ignores_the_sign():
    rng = np.random.default_rng(6)
    q = random_quaternions(rng)
    assert np.allclose(quaternion_angle(q, -q), 0.0)
    small = quaternion_product(quaternion_from_rotvec([1e-7, 0.0, 0.0]), q[0])
    assert np.isclose(quaternion_angle(q[0], small), 1e-7, rtol=1e-6)


def test_one_matrix_gives_the_quaternion_of_the_batch():
    """The plain-float path for one matrix agrees with the batch, including half turns."""
    R = np.concatenate((Rotation.random(500, random_state=5).as_matrix(),
                        np.array([np.eye(3), np.diag([1.0, -1.0, -1.0]),
                                  np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])])))
    batch = quaternion_from_matrix(R)
    one = np.array([quaternion_from_matrix(r) for r in R])
    np.testing.assert_array_equal(one, batch)
    assert np.all(one[:, 3] >= 0.0)
