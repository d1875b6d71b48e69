"""The stereo endoscope: images agree with the intrinsics that camera_info publishes."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.bullet import pybullet
from sim_bridge.scene.camera import CameraConfig, StereoCamera


def _red_centroid(rgb):
    red = (rgb[:, :, 0].astype(int) - rgb[:, :, 1].astype(int)) > 80
    v, u = np.nonzero(red)
    return np.array([u.mean(), v.mean()]), red


def test_a_point_appears_where_k_r_t_projects_it_in_both_images(client):
    config = CameraConfig(width=320, height=240, vertical_fov=0.8, baseline=0.005)
    camera = StereoCamera(config, client)
    rng = np.random.default_rng(11)
    shape = client.createVisualShape(pybullet.GEOM_SPHERE, radius=0.0015, rgbaColor=[1, 0, 0, 1])
    ball = client.createMultiBody(0.0, -1, shape, [0.0, 0.0, 0.0])
    for _ in range(4):
        T_world_tip = np.eye(4)
        T_world_tip[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        T_world_tip[:3, 3] = rng.uniform(-0.1, 0.1, 3)
        # a point in the middle of the view, 6-12 cm in front of the rig
        p_tip = np.array([rng.uniform(-0.015, 0.015), rng.uniform(-0.01, 0.01),
                          rng.uniform(0.06, 0.12)])
        p_world = T_world_tip[:3, :3] @ p_tip + T_world_tip[:3, 3]
        client.resetBasePositionAndOrientation(ball, p_world.tolist(), [0, 0, 0, 1])
        frame = camera.render(T_world_tip)
        for rgb, depth, T_cam, side in ((frame.left_rgb, frame.left_depth, frame.T_world_left,
                                         'left'),
                                        (frame.right_rgb, frame.right_depth, frame.T_world_right,
                                         'right')):
            centroid, mask = _red_centroid(rgb)
            # K [R | t] with the camera pose, and camera_info's P with left-camera coordinates
            expected = camera.project(p_world, T_cam)[0]
            assert np.linalg.norm(centroid - expected) < 1.0
            info = camera.camera_info(side)
            p_left = np.linalg.inv(frame.T_world_left) @ np.append(p_world, 1.0)
            uvw = info.P @ p_left
            assert np.allclose(uvw[:2] / uvw[2], expected, atol=1e-9)
            # metric depth: the nearest surface of the ball, camera-frame z
            z = (np.linalg.inv(T_cam) @ np.append(p_world, 1.0))[2]
            assert depth[mask].min() == pytest.approx(z - 0.0015, abs=2e-4)


def test_camera_info_describes_a_rectified_pair_with_the_baseline_in_p():
    config = CameraConfig(width=640, height=480, vertical_fov=0.8, baseline=0.005)
    camera = StereoCamera(config)
    fy = 240.0 / np.tan(0.4)
    left, right = camera.camera_info('left'), camera.camera_info('right')
    assert np.allclose(left.K, [[fy, 0, 319.5], [0, fy, 239.5], [0, 0, 1]])
    assert left.distortion_model == 'plumb_bob' and not left.D.any()
    assert np.allclose(left.P[:, :3], left.K) and left.P[0, 3] == 0.0
    assert right.P[0, 3] == pytest.approx(-fy * 0.005)
    assert np.allclose(right.R, np.eye(3))
    T_left, T_right = camera.camera_poses(np.eye(4))
    assert np.allclose(T_right[:3, 3] - T_left[:3, 3], [0.005, 0.0, 0.0])


def test_explicit_intrinsics_override_the_field_of_view():
    camera = StereoCamera(CameraConfig(width=100, height=80, fx=90.0, fy=95.0, cx=40.0, cy=30.0))
    assert np.allclose(camera.K, [[90.0, 0, 40.0], [0, 95.0, 30.0], [0, 0, 1]])


def test_bad_settings_name_the_key():
    with pytest.raises(ValueError, match='near/far'):
        CameraConfig(near=0.5, far=0.1)
    with pytest.raises(ValueError, match="'left' or 'right'"):
        StereoCamera().camera_info('middle')


def test_realism_is_seeded_and_depth_is_computed_only_when_asked(client):
    shape = client.createVisualShape(pybullet.GEOM_SPHERE, radius=0.003, rgbaColor=[1, 0, 0, 1])
    client.createMultiBody(0.0, -1, shape, [0.0, 0.0, 0.08])
    ideal = StereoCamera(CameraConfig(width=160, height=120, depth=False), client)
    frame = ideal.render(np.eye(4))
    assert frame.left_depth is None and frame.right_depth is None
    config = CameraConfig(width=160, height=120, noise_std=4.0, blur_sigma=0.8,
                          light_jitter=0.2, seed=3)
    a = StereoCamera(config, client).render(np.eye(4))
    b = StereoCamera(config, client).render(np.eye(4))
    assert np.array_equal(a.left_rgb, b.left_rgb)  # the same seed, the same images
    assert a.left_depth is not None
    diff = a.left_rgb.astype(float) - frame.left_rgb
    assert 2.0 < diff[:20, :20].std() < 8.0  # noise on the flat background
    with pytest.raises(ValueError, match='noise_std'):
        CameraConfig(noise_std=-1.0)
