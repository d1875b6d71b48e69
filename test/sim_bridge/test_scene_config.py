from pathlib import Path

import pytest
from sim_bridge.common.configfile import ConfigError
from sim_bridge.common.paths import config_path
from sim_bridge.scene.scene_config import load_scene_config
import yaml


def write(tmp_path, data):
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def installed():
    return yaml.safe_load(Path(config_path('scene.yaml')).read_text())


def test_the_installed_scene_loads_with_both_phantoms():
    scene = load_scene_config()
    assert set(scene.phantoms) == {'synthetic', 'scanned'}
    assert scene.needle.radius == 0.01018 and scene.needle.arc_deg == 120.0
    assert scene.thread.n_segments == 40
    assert scene.phantom_for_pair('scan3') == 'scanned'
    assert scene.phantom_for_pair('synth1') == 'synthetic'


def test_unknown_key_names_file_and_key(tmp_path):
    data = installed()
    data['needle']['radius_mm'] = 10.18
    path = write(tmp_path, data)
    with pytest.raises(ConfigError, match=r'scene.yaml.*needle.*radius_mm'):
        load_scene_config(path)


def test_missing_value_names_the_key(tmp_path):
    data = installed()
    data['phantoms']['synthetic']['markers'] = {'synthA': {'entry': [0.0, 0.004]}}
    with pytest.raises(ConfigError, match=r'phantoms.synthetic.markers.synthA.exit'):
        load_scene_config(write(tmp_path, data))


def test_wrong_type_says_what_was_expected(tmp_path):
    data = installed()
    data['scoring']['marker_tolerance'] = 'tight'
    with pytest.raises(ConfigError, match=r'scoring.marker_tolerance.*must be a number'):
        load_scene_config(write(tmp_path, data))


def test_invalid_kind_is_a_config_error(tmp_path):
    data = installed()
    data['phantoms']['scanned']['kind'] = 'jelly'
    with pytest.raises(ConfigError, match=r'scene.yaml.*kind'):
        load_scene_config(write(tmp_path, data))


def test_unreadable_mesh_names_the_key_and_file(tmp_path):
    data = installed()
    data['phantoms']['scanned']['kind'] = 'mesh'
    data['phantoms']['scanned']['mesh'] = 'meshes/nowhere.stl'
    with pytest.raises(ConfigError, match=r'phantoms.scanned.mesh.*nowhere.stl'):
        load_scene_config(write(tmp_path, data))


def test_relative_mesh_paths_resolve_next_to_the_config(tmp_path):
    import trimesh
    (tmp_path / 'meshes').mkdir()
    trimesh.creation.box(extents=(0.05, 0.03, 0.01)).export(tmp_path / 'meshes' / 'pad.stl')
    data = installed()
    data['phantoms']['scanned'] = {'kind': 'mesh', 'mesh': 'meshes/pad.stl',
                                   'marker_prefix': 'scan', 'resolution': 0.0005}
    scene = load_scene_config(write(tmp_path, data))
    assert Path(scene.phantoms['scanned'].mesh) == tmp_path / 'meshes' / 'pad.stl'
    assert list(scene.build_phantom('scanned').markers) == ['scan1', 'scan2', 'scan3', 'scan4']


def test_unknown_active_phantom_is_rejected(tmp_path):
    data = installed()
    data['active_phantom'] = 'liver'
    with pytest.raises(ConfigError, match='active_phantom'):
        load_scene_config(write(tmp_path, data))
