import math

import numpy as np
import pytest
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.needle import NeedleGeometry, ThreadGeometry


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_arc_points_lie_on_the_radius_in_the_xy_plane():
    g = NeedleGeometry()
    pts = g.arc_points(33)
    assert np.allclose(np.linalg.norm(pts, axis=1), 0.01018)
    assert np.allclose(pts[:, 2], 0.0)


def test_tail_and_tip_span_120_degrees_with_a_17_63_mm_chord():
    g = NeedleGeometry()
    cos = np.dot(g.tail, g.tip) / (np.linalg.norm(g.tail) * np.linalg.norm(g.tip))
    assert math.degrees(math.acos(cos)) == pytest.approx(120.0)
    assert np.linalg.norm(g.tip - g.tail) == pytest.approx(0.01763, abs=1e-5)
    assert g.chord == pytest.approx(0.01763, abs=1e-5)
    assert g.length == pytest.approx(0.01018 * 2.0 * math.pi / 3.0)


def test_tail_is_at_180_degrees_and_tip_at_60_degrees():
    g = NeedleGeometry()
    assert np.allclose(g.tail, [-0.01018, 0.0, 0.0])
    assert np.allclose(g.tip, 0.01018 * np.array([0.5, math.sqrt(3) / 2, 0.0]))
    assert np.allclose(g.point_at(0.0), g.tail) and np.allclose(g.point_at(1.0), g.tip)
    assert np.allclose(g.arc_points(5)[0], g.tail) and np.allclose(g.arc_points(5)[-1], g.tip)


def test_tip_leads_when_the_needle_turns_about_minus_z():
    g = NeedleGeometry()
    step = rot_z(-1e-4)
    for s in np.linspace(0.0, 1.0, 11):
        moved = step @ g.point_at(s)
        motion = moved - g.point_at(s)
        assert np.dot(motion, g.tangent_at(s)) > 0.99 * np.linalg.norm(motion)
    assert np.allclose(g.tip_direction, g.tangent_at(1.0))


def test_points_world_applies_the_pose():
    g = NeedleGeometry()
    T = np.eye(4)
    T[:3, :3] = rot_z(0.7)
    T[:3, 3] = [0.1, -0.2, 0.3]
    assert np.allclose(g.points_world(T, 7), g.arc_points(7) @ T[:3, :3].T + T[:3, 3])


def test_arc_parameter_round_trips_through_the_polar_angle():
    g = NeedleGeometry()
    s = np.linspace(-0.4, 1.4, 50)
    assert np.allclose(g.s_of_angle(g.angle_at(s)), s)


def test_distance_to_arc_is_radial_on_the_arc_and_to_the_ends_beyond_it():
    g = NeedleGeometry()
    rng = np.random.default_rng(1)
    for _ in range(200):
        p = rng.uniform(-0.02, 0.02, 3)
        d_arc = g.distance_to_arc(p[None])[0]
        d_circle = g.distance_to_circle(p[None])[0]
        dense = g.point_at(np.linspace(0.0, 1.0, 20001))
        assert d_arc >= d_circle - 1e-12
        assert d_arc == pytest.approx(np.min(np.linalg.norm(dense - p, axis=1)), abs=2e-6)


def test_canonical_grasp_holds_the_wire_between_the_jaws_a_third_from_the_tail():
    g = NeedleGeometry()
    T = g.T_tool_needle
    R = T[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
    grasped = R @ g.point_at(1.0 / 3.0) + T[:3, 3]
    assert np.allclose(grasped, [0.0, 0.0, g.grasp_depth], atol=1e-12)
    # Wire along tool x (jaws close across it), approach along minus the needle normal.
    assert np.allclose(R @ g.tangent_at(1.0 / 3.0), [1.0, 0.0, 0.0])
    assert np.allclose(R @ np.array([0.0, 0.0, 1.0]), [0.0, 0.0, -1.0])


def test_every_grasp_puts_the_wire_on_the_jaw_axis_at_the_grasp_depth():
    g = NeedleGeometry()
    rng = np.random.default_rng(2)
    for _ in range(100):
        s, roll, flip = rng.uniform(0, 1), rng.uniform(-math.pi, math.pi), bool(rng.integers(2))
        T = g.grasp_transform(s, roll=roll, flip=flip)
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3))
        assert np.allclose(T[:3, :3] @ g.point_at(s) + T[:3, 3], [0, 0, g.grasp_depth])
        x = T[:3, :3] @ g.tangent_at(s)
        assert abs(x[0]) == pytest.approx(1.0)
        assert np.allclose(invert_transform(invert_transform(T)), T)


def test_roll_minus_90_puts_the_needle_plane_in_the_tool_xz_plane():
    g = NeedleGeometry()
    T = g.grasp_transform(0.3, roll=-math.pi / 2)
    pts = g.arc_points(9) @ T[:3, :3].T + T[:3, 3]
    assert np.allclose(pts[:, 1], 0.0, atol=1e-12)


def test_thread_has_40_segments_from_the_tail():
    th = ThreadGeometry()
    assert th.n_segments == 40
    g = NeedleGeometry()
    pts = th.rest_points(g, np.eye(4))
    assert pts.shape == (41, 3)
    assert np.allclose(pts[0], g.tail)
    assert np.linalg.norm(pts[-1] - pts[0]) == pytest.approx(0.1)


@pytest.mark.parametrize('kwargs', [{'radius': 0.0}, {'arc_deg': 400.0},
                                    {'wire_diameter': 0.05}, {'grasp_s': 1.5}])
def test_invalid_needle_values_are_rejected(kwargs):
    with pytest.raises(ValueError, match='needle'):
        NeedleGeometry(**kwargs)
