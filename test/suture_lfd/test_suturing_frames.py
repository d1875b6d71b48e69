import numpy as np
import pytest
from sim_bridge.common.geometry import (
    compose_poses,
    quaternion_angle,
    quaternion_from_rotvec,
    transform_from_pose,
)
from suture_lfd.demos.synthetic_throw import needle_throw
from suture_lfd.dmp import DmpParams, PoseDmp
from suture_lfd.planning.suturing_frames import (
    grasp_transform,
    needle_from_tool_trajectory,
    poses_from_frame,
    poses_in_frame,
    suture_frame,
    throw_start_goal,
    tool_from_needle_trajectory,
    transfer_pose,
)


def same_pose(a, b):
    return np.allclose(a[..., :3], b[..., :3]) and np.all(quaternion_angle(a[..., 3:],
                                                                           b[..., 3:]) < 1e-9)


def random_pair(rng):
    entry = rng.uniform(-0.05, 0.05, 3)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    along = np.cross(normal, rng.normal(size=3))
    return entry, entry + 0.01 * along / np.linalg.norm(along), normal


def test_suture_frame_axes():
    rng = np.random.default_rng(0)
    for _ in range(50):
        entry, exit, normal = random_pair(rng)
        T = suture_frame(entry, exit + 0.002 * normal, 3.0 * normal)
        R = T[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(R[:, 2], normal)
        assert np.allclose(R[:, 0], (exit - entry) / np.linalg.norm(exit - entry))
        assert np.allclose(T[:3, 3], 0.5 * (entry + exit + 0.002 * normal))


def test_a_transferred_pose_keeps_its_coordinates_in_the_suture_frame():
    rng = np.random.default_rng(1)
    for _ in range(30):
        A, B = suture_frame(*random_pair(rng)), suture_frame(*random_pair(rng))
        pose = np.concatenate((rng.normal(size=3) * 0.02, quaternion_from_rotvec(rng.normal(
            size=3))))
        moved = transfer_pose(pose, A, B)
        assert same_pose(poses_in_frame(B, moved), poses_in_frame(A, pose))
        assert same_pose(transfer_pose(pose, A, A), pose)
        assert same_pose(poses_from_frame(A, poses_in_frame(A, pose)), pose)
        assert np.allclose(transfer_pose(transform_from_pose(pose), A, B),
                           transform_from_pose(moved))


def test_a_throw_learnt_in_its_pair_frame_carries_over_rigidly_to_another_pair():
    rng = np.random.default_rng(2)
    T, P, Q = needle_throw(300, 1.5, rotation_deg=160.0)
    demo_pair, new_pair = suture_frame(*random_pair(rng)), suture_frame(*random_pair(rng))
    local = poses_in_frame(demo_pair, np.hstack((P, Q)))
    dmp = PoseDmp(DmpParams(n_bfs=60, n_bfs_o=40)).fit(T, local[:, :3], local[:, 3:])
    start, goal = throw_start_goal(np.r_[P[0], Q[0]], np.r_[P[-1], Q[-1]], demo_pair, new_pair)
    _, P_loc, Q_loc = dmp.rollout(poses_in_frame(new_pair, start), poses_in_frame(new_pair, goal))
    executed = poses_from_frame(new_pair, np.hstack((P_loc, Q_loc)))
    _, P_ref, Q_ref = dmp.rollout()
    expected = transfer_pose(poses_from_frame(demo_pair, np.hstack((P_ref, Q_ref))),
                             demo_pair, new_pair)
    assert np.abs(executed[:, :3] - expected[:, :3]).max() < 1e-9
    assert quaternion_angle(executed[:, 3:], expected[:, 3:]).max() < 1e-9


def test_the_tool_trajectory_carries_the_needle_whatever_the_grasp():
    rng = np.random.default_rng(3)
    T, P, Q = needle_throw(200, 1.0, rotation_deg=200.0)
    needle = np.hstack((P, Q))
    for _ in range(10):
        grasp_pose = np.concatenate((rng.normal(size=3) * 0.01, quaternion_from_rotvec(
            rng.normal(size=3))))
        tool_at_start = compose_poses(needle[0], np.r_[-grasp_pose[:3], 0, 0, 0, 1])
        G = grasp_transform(tool_at_start, needle[0])
        tool = tool_from_needle_trajectory(needle, G)
        carried = needle_from_tool_trajectory(tool, G)
        assert np.abs(carried[:, :3] - P).max() < 1e-12
        assert quaternion_angle(carried[:, 3:], Q).max() < 1e-9
        assert same_pose(tool[0], tool_at_start)
        assert np.all(np.sum(tool[1:, 3:] * tool[:-1, 3:], axis=1) > 0.0)   # signs continuous


def test_degenerate_pairs_are_rejected():
    with pytest.raises(ValueError, match='normal must be a non-zero'):
        suture_frame([0, 0, 0], [0.01, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match='entry and exit must be apart'):
        suture_frame([0, 0, 0], [0, 0, 0.01], [0, 0, 1])
    with pytest.raises(ValueError, match=r'poses must be 7-vector poses'):
        transfer_pose(np.zeros(5), np.eye(4), np.eye(4))
    with pytest.raises(ValueError, match=r'T_world_to must be a rigid'):
        transfer_pose(np.r_[0, 0, 0, 0, 0, 0, 1.0], np.eye(4), 2 * np.eye(4))
