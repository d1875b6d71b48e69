"""
Configuration as data: YAML files read into frozen dataclasses, with errors that name the key.

Every component takes a frozen dataclass; this module is the one place that reads YAML and says
which key of which file is wrong and what was expected.
"""

from dataclasses import MISSING, fields, is_dataclass
import math
from pathlib import Path
import types
import typing

from sim_bridge.common.errors import ConfigError
import yaml


def load_yaml(path):
    """
    Read a YAML file into a mapping.

    Parameters
    ----------
    path : str or Path
        File to read.

    Returns
    -------
    dict
        The top-level mapping.

    Raises
    ------
    ConfigError
        If the file cannot be read, is not valid YAML, or is not a mapping.

    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read configuration file ({exc.strerror})') from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f'{path}: not valid YAML ({exc})') from exc
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(
            f'{path}: expected a mapping at the top level, got {type(data).__name__}')
    return data


def section(data, key, *, source):
    """
    Return ``data[key]`` as a mapping, or raise a ConfigError naming the file and key.

    Parameters
    ----------
    data : dict
        Parsed YAML mapping.
    key : str
        Dotted path of the section (``'simulator.ros__parameters'``).
    source : str
        File name used in error messages.

    Returns
    -------
    dict
        The section.

    """
    node = data
    for part in key.split('.'):
        if not isinstance(node, dict) or part not in node:
            raise ConfigError(f'{source}: missing key {key!r} (expected a mapping)')
        node = node[part]
    if node is None:
        node = {}
    if not isinstance(node, dict):
        raise ConfigError(f'{source}: key {key!r} must be a mapping, got {type(node).__name__}')
    return node


def _type_name(tp):
    return getattr(tp, '__name__', None) or str(tp).replace('typing.', '')


def _coerce(value, tp, *, source, key):
    """Check ``value`` against the annotation ``tp`` and return it converted."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is typing.Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, source=source, key=key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f'{source}: key {key!r} may not be null')
    if is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(
                f'{source}: key {key!r} must be a mapping for {tp.__name__}, '
                f'got {type(value).__name__}')
        return dataclass_from_mapping(tp, value, source=source, prefix=key)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(
                f'{source}: key {key!r} must be a list, got {type(value).__name__}')
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], source=source, key=f'{key}[{i}]')
                         for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(
                f'{source}: key {key!r} must be a list of {len(args)} values, got {len(value)}')
        return tuple(_coerce(v, a, source=source, key=f'{key}[{i}]')
                     for i, (v, a) in enumerate(zip(value, args)))
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(
                f'{source}: key {key!r} must be a mapping, got {type(value).__name__}')
        kt, vt = args if args else (typing.Any, typing.Any)
        return {_coerce(k, kt, source=source, key=f'{key}.{k}'):
                _coerce(v, vt, source=source, key=f'{key}.{k}') for k, v in value.items()}
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(
                f'{source}: key {key!r} must be a number, got {value!r}')
        if not math.isfinite(value):
            raise ConfigError(f'{source}: key {key!r} must be finite, got {value!r}')
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f'{source}: key {key!r} must be an integer, got {value!r}')
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f'{source}: key {key!r} must be true or false, got {value!r}')
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f'{source}: key {key!r} must be a string, got {value!r}')
        return value
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    raise ConfigError(f'{source}: key {key!r} must be {_type_name(tp)}, got {value!r}')


def dataclass_from_mapping(cls, mapping, *, source, prefix=''):
    """
    Build the frozen dataclass ``cls`` from a mapping, checking every key.

    Unknown keys, missing keys without a default, and values of the wrong type raise a
    ConfigError naming ``source``, the dotted key and what was expected. Nested dataclasses,
    ``tuple[float, ...]``, fixed-length tuples, ``dict[str, X]`` and optionals are supported.

    Parameters
    ----------
    cls : type
        A dataclass type.
    mapping : dict
        Values by field name.
    source : str
        File (or other origin) named in error messages.
    prefix : str
        Dotted key of ``mapping`` inside its file, for messages.

    Returns
    -------
    cls
        The instance.

    """
    if not isinstance(mapping, dict):
        raise ConfigError(f'{source}: key {prefix or "<top>"!r} must be a mapping')
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in fields(cls) if f.init}
    dotted = (prefix + '.') if prefix else ''
    unknown = sorted(set(mapping) - set(known))
    if unknown:
        raise ConfigError(
            f'{source}: unknown key {dotted}{unknown[0]!r}; expected one of {sorted(known)}')
    values = {}
    for name, field in known.items():
        key = f'{dotted}{name}'
        if name in mapping:
            values[name] = _coerce(mapping[name], hints[name], source=source, key=key)
        elif field.default is MISSING and field.default_factory is MISSING:
            raise ConfigError(
                f'{source}: missing key {key!r} (expected {_type_name(hints[name])})')
    return cls(**values)
