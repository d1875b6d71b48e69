"""
The endoscope's realism: a lens that distorts and a rectification that undoes it, a region of
interest rendered alone, frames at a rate and stamped late (real PyBullet renders).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.bullet import pybullet
from sim_bridge.realism.frame_timing import FrameTiming
from sim_bridge.realism.lens import Lens, LensConfig
from sim_bridge.scene.camera import CameraConfig, StereoCamera

# barrel distortion of the order a wide-angle rigid endoscope's calibration gives
BARREL = LensConfig(level=1.0, k1=-0.25, k2=0.08, p1=5e-4, p2=-3e-4, k3=0.0)


def _red_centroid(rgb):
    red = (rgb[:, :, 0].astype(int) - rgb[:, :, 1].astype(int)) > 80
    v, u = np.nonzero(red)
    return np.array([u.mean(), v.mean()])


def test_a_point_through_distortion_and_rectification_lands_on_its_pinhole_projection():
    camera = StereoCamera(CameraConfig(width=640, height=480, vertical_fov=0.8), lens=BARREL)
    rng = np.random.default_rng(3)
    T_world_cam = np.eye(4)
    points = np.column_stack([rng.uniform(-0.03, 0.03, 200), rng.uniform(-0.02, 0.02, 200),
                              rng.uniform(0.06, 0.12, 200)])
    ideal = camera.project(points, T_world_cam)
    raw = camera.lens.distort_points(ideal)
    # the lens moves points, most far from the centre (barrel: towards it)
    moved = np.linalg.norm(raw - ideal, axis=1)
    assert moved.max() > 5.0
    back = camera.lens.undistort_points(raw)
    assert np.abs(back - ideal).max() < 0.1
    # OpenCV's own projection with the camera_info of the raw image agrees with the lens
    import cv2

    info = camera.camera_info('left', raw=True)
    assert info.D == pytest.approx(BARREL.D)
    projected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), info.K, info.D)
    assert np.abs(projected.reshape(-1, 2) - raw).max() < 1e-6
    # the rectified camera_info is an ideal pinhole
    assert not camera.camera_info('left').D.any()


def test_the_rectified_image_puts_a_ball_where_the_pinhole_does(client):
    config = CameraConfig(width=320, height=240, vertical_fov=0.8, baseline=0.005)
    ideal_camera = StereoCamera(config, client)
    lens_camera = StereoCamera(config, client, lens=BARREL)
    shape = client.createVisualShape(pybullet.GEOM_SPHERE, radius=0.002, rgbaColor=[1, 0, 0, 1])
    # towards a corner of the view, where the distortion is largest
    T_world_tip = np.eye(4)
    client.createMultiBody(0.0, -1, shape, [0.022, 0.015, 0.08])
    ideal = ideal_camera.render(T_world_tip)
    seen = lens_camera.render(T_world_tip)
    c_ideal = _red_centroid(ideal.left_rgb)
    c_raw = _red_centroid(seen.left_raw)
    c_rect = _red_centroid(seen.left_rgb)
    assert np.linalg.norm(c_raw - c_ideal) > 2.0          # the raw image is distorted
    assert np.linalg.norm(c_rect - c_ideal) < 0.3         # image_rect undoes it
    # level 0: no raw images apart, the colour images untouched
    assert ideal.left_raw is None
    assert Lens(ideal_camera.K, np.zeros(5), (320, 240)).distort(ideal.left_rgb) is ideal.left_rgb


def test_a_window_renders_as_the_same_window_of_the_full_image(client):
    config = CameraConfig(width=320, height=240, vertical_fov=0.8, baseline=0.005, depth=True)
    camera = StereoCamera(config, client)
    rng = np.random.default_rng(5)
    for k in range(6):
        shape = client.createVisualShape(pybullet.GEOM_BOX, halfExtents=[0.004, 0.003, 0.002],
                                         rgbaColor=[*rng.uniform(0.2, 1.0, 3), 1.0])
        client.createMultiBody(0.0, -1, shape, rng.uniform([-0.02, -0.015, 0.07],
                                                           [0.02, 0.015, 0.1]).tolist(),
                               Rotation.random(random_state=k).as_quat().tolist())
    T_cam = np.eye(4)
    full_rgb, full_depth = camera.render_view(T_cam, [0.2, -0.3, 1.0])
    seen = 0
    for window in ((40, 30, 120, 90), (200, 150, 100, 80), (0, 0, 64, 48)):
        u0, v0, w, h = window
        rgb, depth = camera.render_view(T_cam, [0.2, -0.3, 1.0], window=window)
        assert rgb.shape == (h, w, 3)
        part = full_rgb[v0:v0 + h, u0:u0 + w]
        differs = np.abs(rgb.astype(int) - part.astype(int)).max(axis=2) > 8
        assert differs.mean() < 0.01, (window, differs.mean())   # edge pixels at most
        finite = np.isfinite(depth) & np.isfinite(full_depth[v0:v0 + h, u0:u0 + w])
        if finite.any():
            seen += 1
            assert np.median(np.abs(depth[finite] - full_depth[v0:v0 + h, u0:u0 + w][finite])) \
                < 1e-4
    assert seen >= 2                                      # windows with the boxes in them
    with pytest.raises(ValueError, match='not inside'):
        camera.render_view(T_cam, window=(300, 200, 64, 48))


def test_a_frame_shows_the_scene_of_its_exposure_and_is_stamped_latency_later():
    timing = FrameTiming(rate=30.0, latency=0.05)
    assert timing.newest(0.04) is None                    # the first frame has not arrived
    for t in np.linspace(0.06, 2.0, 97):
        scene, stamp = timing.newest(float(t))
        assert stamp == pytest.approx(scene + 0.05)
        assert stamp <= t + 1e-12
        assert t - stamp < 1.0 / 30.0 + 1e-9              # the newest one
        assert abs(scene * 30.0 - round(scene * 30.0)) < 1e-6   # at an exposure instant
    # level 0: the instant asked for, stamped with it
    assert FrameTiming().newest(0.7) == (0.7, 0.7)
    with pytest.raises(ValueError, match='latency'):
        FrameTiming(rate=30.0, latency=-0.01)
