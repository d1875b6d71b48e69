"""A user's own phantom mesh: markers laid on its top surface, phantom files, throws on it."""

from dataclasses import replace
import logging

import numpy as np
import pytest
from sim_bridge.common.configfile import ConfigError
from sim_bridge.scene.heightfield import grid_mesh
from sim_bridge.scene.phantom import PhantomConfig, WoundConfig, build_phantom
from sim_bridge.scene.scene_config import (
    load_phantom_file,
    load_scene_config,
    phantom_from_argument,
)
from sim_bridge.simulation import Simulation
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.segmentation.segments import make_segment_file
from suture_lfd.skill.executor import execute_throw, learn_skill
import trimesh

SIZE, BASE, TOP = 0.154, 0.005, 0.0135  # a scanned suture pad: 154 x 154 x 13.5 mm
PADS = [(cx, cy) for cx in (0.040, 0.114) for cy in (0.040, 0.114)]  # raised pad centres
HALF = 0.030  # raised pads 60 x 60 mm


def pad_height(x, y):
    """Top of the test pad (file frame, m): the base, and the raised pads."""
    h = np.full(np.shape(x), BASE)
    for cx, cy in PADS:
        h = np.where((np.abs(x - cx) <= HALF) & (np.abs(y - cy) <= HALF), TOP, h)
    return h


def scanned_pad(path, scale=1.0):
    """Write the test pad (corner at the origin, like a scan's own frame) as a mesh file."""
    edges = []
    for c in (0.040, 0.114):
        edges += [c - HALF - 1e-4, c - HALF, c + HALF, c + HALF + 1e-4]
    xs = np.unique(np.concatenate([np.linspace(0.0, SIZE, 78), edges]))
    X, Y = np.meshgrid(xs, xs)
    mesh = grid_mesh(xs, xs, pad_height(X, Y), 0.0)
    mesh.apply_scale(scale)
    mesh.export(path)
    return path


@pytest.fixture(scope='module')
def pad_obj(tmp_path_factory):
    return scanned_pad(tmp_path_factory.mktemp('pad') / 'pad.obj')


def in_file(phantom, points):
    """Phantom-frame points (n, 3) in the mesh file's frame."""
    T = np.linalg.inv(phantom.T_phantom_file)
    return np.asarray(points) @ T[:3, :3].T + T[:3, 3]


def test_markers_of_a_user_mesh_lie_on_its_raised_top_surface(pad_obj, caplog):
    scene = load_scene_config()
    name, config = phantom_from_argument(scene, pad_obj)
    with caplog.at_level(logging.INFO, logger='sim_bridge.scene.phantom'):
        phantom = build_phantom(config, name=name)
    assert list(phantom.markers) == ['mesh1', 'mesh2', 'mesh3', 'mesh4']
    assert 'longest flat-enough line' in phantom.placement
    assert phantom.placement in caplog.text  # the log says where the markers are
    for pair in phantom.markers_phantom.values():
        points = in_file(phantom, [pair.entry, pair.exit])
        # on the surface of the file's mesh within 0.5 mm, on a raised pad, not the base
        assert np.abs(points[:, 2] - pad_height(points[:, 0], points[:, 1])).max() < 5e-4
        assert np.allclose(points[:, 2], TOP, atol=5e-4)
        assert pair.chord == pytest.approx(2 * config.wound.half_width, abs=1e-4)
        assert np.allclose(pair.normal, [0.0, 0.0, 1.0], atol=1e-3)
    # the phantom frame is the wound's: origin on the surface at its centre, x along it
    mids = np.array([p.midpoint for p in phantom.markers_phantom.values()])
    assert np.allclose(mids[:, 1:], 0.0, atol=1e-6)
    assert mids[:, 0].mean() == pytest.approx(0.0, abs=1e-6)


@pytest.fixture(scope='module')
def synth1_segments(tmp_path_factory):
    synthetic = Simulation()
    demo, _, score = record_scripted_demonstration(synthetic, 'synth1', seed=0)
    synthetic.close()
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('segments') / 'synth1.npz'
    make_segment_file(demo, segment_demonstration(demo), source='synth1 expert').save(path)
    return path


def test_a_throw_learnt_on_the_synthetic_pad_succeeds_on_the_user_mesh(pad_obj, synth1_segments):
    path = synth1_segments
    user = Simulation(phantom=pad_obj)
    try:
        outcomes = {}
        for pair in ('mesh1', 'mesh2', 'mesh3'):
            outcomes[pair] = execute_throw(user, learn_skill(path, 'pair_frame'), pair, seed=3)
        full = [p for p, o in outcomes.items() if o.score == 1.0]
        assert len(full) >= 2, {p: (o.score, o.failure) for p, o in outcomes.items()}
    finally:
        user.close()


def test_an_unreachable_throw_says_which_parameter_to_change(synth1_segments):
    scene = load_scene_config()
    far = replace(scene.phantom_config('synthetic'), position=(0.25, 0.0, 0.0))
    sim = Simulation(phantom=far)
    try:
        outcome = execute_throw(sim, learn_skill(synth1_segments, 'pair_frame'), 'synth2')
    finally:
        sim.close()
    assert outcome.score == 0.0 and outcome.failure.startswith('unreachable')
    for advice in ('simulator parameter seed', 'position and quaternion in the phantom file',
                   'world.arms.<ARM> in world.yaml'):
        assert advice in outcome.failure


def test_a_phantom_file_gives_scale_pose_and_wound_line_in_file_coordinates(tmp_path):
    scanned_pad(tmp_path / 'pad_mm.stl', scale=1000.0)  # the scan is in millimetres
    # a wound along y on the pad at (40, 114) mm, in metres after the scale
    (tmp_path / 'pad.yaml').write_text(
        'mesh: pad_mm.stl\nmesh_scale: 0.001\nmarker_prefix: pad\n'
        'position: [0.0, 0.0, 0.001]\n'
        'wound:\n  line: [[0.040, 0.095], [0.040, 0.135]]\n  n_pairs: 3\n')
    name, config = phantom_from_argument(load_scene_config(), tmp_path / 'pad.yaml')
    phantom = build_phantom(config, name=name)
    assert name == 'pad' and list(phantom.markers) == ['pad1', 'pad2', 'pad3']
    pts = in_file(phantom, [p.midpoint for p in phantom.markers_phantom.values()])
    assert np.allclose(pts[:, 0], 0.040, atol=1e-6)
    assert np.allclose(pts[:, 1], [0.103, 0.115, 0.127], atol=1e-6)
    assert np.allclose(pts[:, 2], TOP, atol=5e-4)
    world = np.array([p.midpoint for p in phantom.markers.values()])
    assert np.allclose(world[:, 2], 0.001, atol=5e-4)  # the pose places the surface
    # explicit pairs, file coordinates
    (tmp_path / 'pairs.yaml').write_text(
        'mesh: pad_mm.stl\nmesh_scale: 0.001\n'
        'markers:\n  a: {entry: [0.110, 0.118], exit: [0.110, 0.110]}\n'
        '  b: {entry: [0.120, 0.118], exit: [0.120, 0.110]}\n')
    phantom = build_phantom(load_phantom_file(tmp_path / 'pairs.yaml'), name='pairs')
    pair = phantom.markers_phantom['a']
    assert in_file(phantom, [pair.entry])[0] == pytest.approx([0.110, 0.118, TOP], abs=5e-4)
    assert pair.entry[1] > pair.exit[1]  # entry on the wound's left: the phantom's +y


def test_bad_phantom_files_and_meshes_say_what_to_change(tmp_path):
    (tmp_path / 'bad.yaml').write_text('mesh: nowhere.obj\n')
    with pytest.raises(ConfigError, match="'mesh'.*nowhere.obj"):
        load_phantom_file(tmp_path / 'bad.yaml')
    (tmp_path / 'typo.yaml').write_text('mesh: x.obj\nmesh_scal: 0.001\n')
    with pytest.raises(ConfigError, match='mesh_scal'):
        load_phantom_file(tmp_path / 'typo.yaml')
    trimesh.creation.icosphere(radius=0.01).export(tmp_path / 'ball.stl')
    with pytest.raises(ValueError, match='wound.line'):
        build_phantom(PhantomConfig(kind='mesh', mesh=str(tmp_path / 'ball.stl'),
                                    frame='wound', wound=WoundConfig(line=())))
    with pytest.raises(ValueError, match='phantom file .*missing.obj does not exist'):
        phantom_from_argument(load_scene_config(), tmp_path / 'missing.obj')
