"""
The realism preset files (``config/realism_*.yaml``), read by one reader for the arm, the
endoscope and the tissue: the shipped presets load, and a bad name or value is named with the
file, the key and what was expected.
"""

import pytest
from sim_bridge.common.errors import ConfigError
from sim_bridge.realism.calibration import load_arm_realism
from sim_bridge.realism.endoscope import endoscope_preset
from sim_bridge.realism.tissue_config import load_tissue_realism
import yaml


def test_the_shipped_presets_load():
    assert load_arm_realism('dvrk').name == 'dvrk'
    assert load_arm_realism('dvrk', levels={'servo_level': 0.0}).servo_level == 0.0
    camera = endoscope_preset('dvrk')
    assert camera.lens.k1 == -0.25 and camera.timing.rate == 30.0
    assert endoscope_preset('off').is_ideal and endoscope_preset('').is_ideal
    assert load_tissue_realism('tissue').active and not load_tissue_realism('none').active


@pytest.mark.parametrize('read', [load_arm_realism, endoscope_preset, load_tissue_realism])
def test_an_unknown_preset_names_the_file_and_those_there_are(read):
    with pytest.raises(ConfigError, match=r'realism_\w+\.yaml: no preset .nope. under presets; '
                                          r'expected one of \w+'):
        read('nope')


def _write(tmp_path, data):
    path = tmp_path / 'realism.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize('read, preset, message', [
    (load_arm_realism, {'servo_level': 'fast'},
     r"key 'presets.p.servo_level' must be a number, got 'fast'"),
    (load_arm_realism, {'servo_level': -1.0}, r'presets.p: arm realism servo_level must be'),
    (load_arm_realism, {'speed': 1.0}, r"unknown key presets.p.'speed'; expected one of"),
    (endoscope_preset, {'timing': {'rate': 30.0, 'latency': -0.01}},
     r'presets.p: camera latency must be a finite number >= 0'),
    (endoscope_preset, {'lens': {'k4': 0.1}}, r"unknown key presets.p.lens.'k4'; expected one of"),
    (load_tissue_realism, {'grip': -1.0}, r'presets.p: tissue realism level grip must be >= 0'),
    (load_tissue_realism, [1.0], r"key 'presets.p' must be a mapping, got list"),
])
def test_a_bad_value_names_the_file_the_key_and_what_was_expected(tmp_path, read, preset,
                                                                  message):
    path = _write(tmp_path, {'magnitudes': {}, 'presets': {'p': preset}})
    with pytest.raises(ConfigError, match=f'^{path}: .*{message}'):
        read('p', path)


def test_a_bad_tissue_magnitude_is_named(tmp_path):
    path = _write(tmp_path, {'magnitudes': {'grip_force': 0.0}, 'presets': {'p': {}}})
    with pytest.raises(ConfigError, match=f'^{path}: magnitudes: .*grip_force must be > 0'):
        load_tissue_realism('p', path)
