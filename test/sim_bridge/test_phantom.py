from dataclasses import replace
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.common.needle import NeedleGeometry
from sim_bridge.scene.heightfield import grid_mesh
from sim_bridge.scene.phantom import MarkerConfig, PhantomConfig, WoundConfig, build_phantom
from sim_bridge.scene.scene_config import load_scene_config
import trimesh


@pytest.fixture(scope='module')
def scene():
    return load_scene_config()


@pytest.fixture(scope='module')
def phantoms(scene):
    return {name: scene.build_phantom(name) for name in ('synthetic', 'scanned')}


def test_each_phantom_has_four_named_marker_pairs(phantoms):
    assert list(phantoms['synthetic'].markers) == ['synth1', 'synth2', 'synth3', 'synth4']
    assert list(phantoms['scanned'].markers) == ['scan1', 'scan2', 'scan3', 'scan4']


def test_meshes_are_watertight_and_centred_at_the_world_origin(phantoms):
    for p in phantoms.values():
        m = p.mesh_world()
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0
        centre = 0.5 * (m.bounds[0] + m.bounds[1])
        assert np.allclose(centre[:2], 0.0, atol=1e-3)
        assert abs(m.bounds[1][2]) < 0.003


def test_markers_lie_on_the_surface_with_unit_outward_normals(phantoms):
    for p in phantoms.values():
        for pair in p.markers_phantom.values():
            for q, n in ((pair.entry, pair.entry_normal), (pair.exit, pair.exit_normal)):
                assert abs(q[2] - p.height(q[:2])) < 1e-4
                assert np.linalg.norm(n) == pytest.approx(1.0)
                assert np.allclose(n, p.normal(q[:2]))
                assert n[2] > 0.9
            assert np.linalg.norm(pair.normal) == pytest.approx(1.0)


def test_markers_sit_across_the_wound_at_the_configured_distance(phantoms):
    chord = NeedleGeometry().chord
    for name, expected in (('synthetic', 0.008), ('scanned', 0.012)):
        for pair in phantoms[name].markers.values():
            assert pair.chord == pytest.approx(expected, abs=3e-4)
            assert pair.chord < 0.75 * chord
            # Entry on the +y side of a wound running along +x.
            assert pair.entry[1] > pair.exit[1]


def test_pair_frame_has_x_towards_the_exit_and_z_along_the_normal(phantoms):
    pair = phantoms['scanned'].markers['scan2']
    F = pair.frame
    assert np.allclose(F[:3, :3].T @ F[:3, :3], np.eye(3))
    assert np.allclose(F[:3, 2], pair.normal)
    assert np.dot(F[:3, 0], pair.exit - pair.entry) > 0.99 * pair.chord


def test_scanned_phantom_is_deterministic_for_a_seed(scene):
    cfg = scene.phantom_config('scanned')
    a, b = build_phantom(cfg), build_phantom(cfg)
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
    assert np.array_equal(a.surface.top, b.surface.top)
    for k in a.markers:
        assert np.array_equal(a.markers[k].entry, b.markers[k].entry)
    c = build_phantom(replace(cfg, seed=cfg.seed + 1))
    assert not np.allclose(a.surface.top, c.surface.top)


def test_scanned_surface_is_curved_and_irregular(phantoms):
    top = phantoms['scanned'].surface.top
    assert top.max() - top.min() > 0.003
    lap = np.abs(np.diff(top, 2, axis=0)).max()
    assert lap > 0.0


def test_is_inside_on_known_points(phantoms):
    p = phantoms['synthetic']
    pts = np.array([
        [0.0, 0.01, -0.001],    # under the surface
        [0.0, 0.01, 0.001],     # above
        [0.035, 0.0, -0.001],   # beyond the pad's end
        [0.0, 0.025, -0.001],   # beyond its side
        [0.0, 0.0, -0.011],     # below the bottom
        [0.0, 0.0, -0.001],     # in the wound slit: the tissue surface closes it
        [0.0299, 0.0199, -0.009],
    ])
    assert p.is_inside(pts).tolist() == [True, False, False, False, False, True, True]
    assert np.allclose(p.penetration(pts), [0.001, 0, 0, 0, 0, 0.001, 0.009])


def test_pose_moves_markers_and_tissue(scene):
    cfg = replace(scene.phantom_config('synthetic'), position=(0.01, 0.02, 0.03),
                  quaternion=tuple(Rotation.from_euler('z', 90, degrees=True).as_quat()))
    p = build_phantom(cfg)
    pair = p.markers['synth1']
    local = p.markers_phantom['synth1']
    assert np.allclose(pair.entry, p.T_world_phantom[:3, :3] @ local.entry + [0.01, 0.02, 0.03])
    below = pair.entry - 0.001 * pair.entry_normal
    above = pair.entry + 0.001 * pair.entry_normal
    assert p.is_inside(np.array([below, above])).tolist() == [True, False]


def box_stl(path, size_mm=(50.0, 30.0, 8.0)):
    box = trimesh.creation.box(extents=size_mm)
    box.apply_translation([0.0, 0.0, -0.5 * size_mm[2]])
    box.export(path)


def test_a_user_stl_in_millimetres_replaces_the_pad(tmp_path):
    box_stl(tmp_path / 'pad.stl')
    cfg = PhantomConfig(kind='mesh', mesh=str(tmp_path / 'pad.stl'), mesh_scale=0.001,
                        marker_prefix='user', resolution=0.0005)
    p = build_phantom(cfg)
    assert list(p.markers) == ['user1', 'user2', 'user3', 'user4']
    for pair in p.markers.values():
        assert abs(pair.entry[2]) < 1e-6 and abs(pair.exit[2]) < 1e-6
        assert np.allclose(pair.normal, [0, 0, 1])
    assert p.is_inside(np.array([[0.0, 0.01, -0.002], [0.0, 0.016, -0.002]])).tolist() == [
        True, False]


def test_a_curved_user_mesh_gets_markers_on_its_surface(tmp_path):
    xs = np.linspace(-0.03, 0.03, 121)
    ys = np.linspace(-0.02, 0.02, 81)
    X, Y = np.meshgrid(xs, ys)

    def dome(x, y):
        return 0.004 * np.exp(-(x ** 2 + y ** 2) / 0.015 ** 2)

    grid_mesh(xs, ys, dome(X, Y), -0.01).export(tmp_path / 'dome.ply')
    cfg = PhantomConfig(kind='mesh', mesh=str(tmp_path / 'dome.ply'),
                        wound=WoundConfig(half_width=0.006))
    p = build_phantom(cfg)
    for pair in p.markers.values():
        for q in (pair.entry, pair.exit):
            assert q[2] == pytest.approx(dome(q[0], q[1]), abs=1e-4)


def test_markers_given_explicitly_are_dropped_onto_the_surface(scene):
    cfg = replace(scene.phantom_config('scanned'),
                  markers={'scanA': MarkerConfig(entry=(0.0, 0.005), exit=(0.0, -0.005))})
    p = build_phantom(cfg)
    pair = p.markers_phantom['scanA']
    assert list(p.markers) == ['scanA']
    assert pair.entry[2] == pytest.approx(p.height(pair.entry[:2]))
    assert pair.chord == pytest.approx(0.010, abs=3e-4)


def test_an_unreadable_mesh_is_a_value_error_naming_the_file(tmp_path):
    bad = tmp_path / 'broken.stl'
    bad.write_bytes(b'solid nothing here\nthis is not an stl\n')
    with pytest.raises(ValueError, match='broken.stl'):
        build_phantom(PhantomConfig(kind='mesh', mesh=str(bad)))
    with pytest.raises(ValueError, match='missing.obj'):
        build_phantom(PhantomConfig(kind='mesh', mesh=str(tmp_path / 'missing.obj')))


def test_markers_off_the_pad_are_rejected():
    with pytest.raises(ValueError, match='outside the pad'):
        build_phantom(PhantomConfig(wound=WoundConfig(half_width=0.03)))
    with pytest.raises(ValueError, match='falls off the wound'):
        build_phantom(PhantomConfig(wound=WoundConfig(spacing=0.03)))


def test_surface_normal_matches_the_analytic_slope(tmp_path):
    xs = np.linspace(-0.03, 0.03, 61)
    ys = np.linspace(-0.02, 0.02, 41)
    X, Y = np.meshgrid(xs, ys)
    slope = math.tan(math.radians(10.0))
    grid_mesh(xs, ys, slope * X, -0.02).export(tmp_path / 'ramp.obj')
    p = build_phantom(PhantomConfig(kind='mesh', mesh=str(tmp_path / 'ramp.obj')))
    n = p.normal(np.array([[0.003, 0.004], [-0.01, 0.0]]))
    expected = np.array([-slope, 0.0, 1.0]) / math.hypot(slope, 1.0)
    assert np.allclose(n, expected, atol=1e-4)
