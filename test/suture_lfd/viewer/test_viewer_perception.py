"""
The viewer draws what perception sees beside the truth: the estimated needle and the markers.

Real processes on the private domain: ``simulator`` (rendering the ECM's stereo pair),
``perception`` and ``viewer``. No browser: the viewer's ``viewer/stats`` reports the pose of the
perceived needle's arc and the perceived markers as its scene holds them (world), and the test
compares them with the simulator's truth (``sim/needle/measured_cp``, ``/tf_static`` markers).
"""

import json
import threading

from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.ros import conversions as cv
from std_msgs.msg import String
from suture_lfd.viewer.assets import needle_arc
from tf2_msgs.msg import TFMessage

STREAM = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def arc_world(position, wxyz, points):
    """The needle's arc points ``(n, 3)`` in world for a drawn pose (viser ``wxyz``)."""
    w, x, y, z = wxyz
    R = np.asarray(matrix_from_quaternion((x, y, z, w)))[:3, :3]
    return points @ R.T + np.asarray(position)


def test_the_viewer_draws_the_perceived_needle_and_markers_beside_the_true_ones(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS, '-p', 'camera_rate:=4.0',
                 '-p', 'visualization_rate:=0.0')
    perception = launch('perception', '--ros-args', '-p', 'rate:=4.0')
    viewer = launch('viewer', '--port', '0')
    node = ros.node('viewer_perception_probe')
    lock = threading.Lock()
    got = {'stats': None, 'truth': None, 'markers': {}}

    def on_static(msg):
        with lock:
            for tr in msg.transforms:
                if tr.child_frame_id.endswith(('_entry', '_exit')):
                    t = tr.transform.translation
                    got['markers'][tr.child_frame_id] = (t.x, t.y, t.z)

    node.create_subscription(String, '/viewer/stats',
                             lambda m: got.__setitem__('stats', json.loads(m.data)), LATCHED)
    node.create_subscription(PoseStamped, '/sim/needle/measured_cp',
                             lambda m: got.__setitem__('truth', m), STREAM)
    node.create_subscription(TFMessage, '/tf_static', on_static, LATCHED)

    def drawn():
        seen = (got['stats'] or {}).get('perception') or {}
        needle = seen.get('needle')
        return needle is not None and needle['found'] and len(seen['markers']) >= 2

    assert ros.wait_for(drawn, 240.0, period=0.2), (
        f'no perceived needle in the viewer: {got["stats"]}\n' + sim.log() + perception.log()
        + viewer.log())
    seen = got['stats']['perception']
    points, _ = needle_arc()
    estimated = arc_world(seen['needle']['position'], seen['needle']['wxyz'], points)
    true = cv.matrix_from_pose(got['truth'].pose)   # the needle lies still: any message will do
    assert got['truth'].header.frame_id == 'world'
    true = points @ true[:3, :3].T + true[:3, 3]
    off = np.linalg.norm(estimated - true, axis=1)
    assert off.max() < 0.003, f'perceived arc {off.max() * 1e3:.2f} mm from the true one'
    assert seen['residual_px'] is not None and seen['residual_px'] >= 0.0

    # every perceived marker is drawn on a true one (placed through the ECM's camera frame)
    with lock:
        markers = np.array(list(got['markers'].values()))
    assert len(markers) >= 2
    for p in seen['markers']:
        nearest = np.linalg.norm(markers - np.asarray(p), axis=1).min()
        assert nearest < 0.002, f'perceived marker {p} is {nearest * 1e3:.2f} mm from any true one'


def test_a_needle_not_found_is_greyed_at_its_last_pose_and_unseen_markers_are_left_out():
    from suture_lfd.viewer.page import ViewerPage
    from suture_lfd.viewer.perceived import LOST_COLOR, NEEDLE_COLOR, PerceivedLayer
    points, diameter = needle_arc()
    page = ViewerPage(points, diameter, port=0)   # a real viser server on this machine
    try:
        layer = PerceivedLayer(page.server.scene, page.scene.tf, points, diameter)
        assert layer.summary()['needle'] is None and not layer.render()
        T_world_camera = np.eye(4)
        T_world_camera[:3, :3] = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
        T_world_camera[:3, 3] = (0.0, 0.0, 0.1)      # 10 cm above the pad, looking down
        page.scene.set_transform('world', 'ECM_left_optical', T_world_camera)
        T_camera_needle = np.eye(4)
        T_camera_needle[:3, 3] = (0.01, 0.0, 0.08)
        layer.set_needle('ECM_left_optical', T_camera_needle)
        layer.set_status(True, 0.42)
        layer.set_markers('ECM_left_optical', [(0.0, 0.0, 0.09), (np.nan, np.nan, np.nan)])
        assert layer.render()
        seen = layer.summary()
        np.testing.assert_allclose(seen['needle']['position'], (0.01, 0.0, 0.02), atol=1e-9)
        assert seen['needle']['found'] and seen['residual_px'] == 0.42
        np.testing.assert_allclose(seen['markers'], [(0.0, 0.0, 0.01)], atol=1e-9)
        assert (layer.needle.colors == NEEDLE_COLOR).all()
        assert '0.42 px' in layer.status_text() and 'not found' not in layer.status_text()
        assert not layer.render()                     # nothing moved: nothing sent

        layer.set_status(False, None)
        assert layer.render()
        assert not layer.summary()['needle']['found']
        assert (layer.needle.colors == LOST_COLOR).all() and layer.needle.visible
        assert 'not found' in layer.status_text()
    finally:
        page.close()
