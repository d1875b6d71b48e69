"""Configuration files: every mistake names the file, the key and what was expected."""

from dataclasses import dataclass

import pytest
from sim_bridge.common.configfile import ConfigError, dataclass_from_mapping, load_yaml, section


@dataclass(frozen=True)
class Inner:
    gain: float
    names: tuple[str, ...] = ()


@dataclass(frozen=True)
class Outer:
    inner: Inner
    rate: float = 100.0
    count: int = 1
    enabled: bool = True
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    label: str | None = None


def test_a_valid_mapping_builds_the_dataclass():
    cfg = dataclass_from_mapping(
        Outer, {'inner': {'gain': 2, 'names': ['a', 'b']}, 'pose': [1, 2, 3], 'count': 4},
        source='x.yaml')
    assert cfg == Outer(inner=Inner(2.0, ('a', 'b')), pose=(1.0, 2.0, 3.0), count=4)
    assert isinstance(cfg.inner.gain, float)


@pytest.mark.parametrize('mapping, message', [
    ({'inner': {'gain': 1.0}, 'rte': 5}, "x.yaml: unknown key 'rte'"),
    ({'inner': {}}, "x.yaml: missing key 'inner.gain' (expected float)"),
    ({'inner': {'gain': 'fast'}}, "x.yaml: key 'inner.gain' must be a number, got 'fast'"),
    ({'inner': {'gain': 1.0}, 'count': 2.5}, "key 'count' must be an integer"),
    ({'inner': {'gain': 1.0}, 'enabled': 'yes'}, "key 'enabled' must be true or false"),
    ({'inner': {'gain': 1.0}, 'pose': [1, 2]}, "key 'pose' must be a list of 3 values, got 2"),
    ({'inner': {'gain': float('nan')}}, "key 'inner.gain' must be finite"),
    ({'inner': 3}, "key 'inner' must be a mapping for Inner"),
])
def test_mistakes_name_file_key_and_expectation(mapping, message):
    with pytest.raises(ConfigError) as err:
        dataclass_from_mapping(Outer, mapping, source='x.yaml')
    assert message in str(err.value)


def test_unreadable_and_malformed_files_are_named(tmp_path):
    with pytest.raises(ConfigError, match='missing.yaml: cannot read'):
        load_yaml(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('a: [1, 2\n')
    with pytest.raises(ConfigError, match='bad.yaml: not valid YAML'):
        load_yaml(bad)
    scalar = tmp_path / 'scalar.yaml'
    scalar.write_text('3\n')
    with pytest.raises(ConfigError, match='scalar.yaml: expected a mapping'):
        load_yaml(scalar)


def test_sections_are_found_or_named():
    data = {'simulator': {'ros__parameters': {'rate': 5}}}
    assert section(data, 'simulator.ros__parameters', source='s.yaml') == {'rate': 5}
    with pytest.raises(ConfigError, match="s.yaml: missing key 'recorder.ros__parameters'"):
        section(data, 'recorder.ros__parameters', source='s.yaml')
