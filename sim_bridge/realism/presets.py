"""
The one reader of the realism preset files (``config/realism_*.yaml``).

Each file holds ``presets``: a mapping from a preset's name to its levels (and magnitudes), read
into a frozen dataclass. A missing file, a missing or unknown preset, an unknown key, a value of
the wrong type and a value the dataclass refuses (a negative level) all raise a
:class:`~sim_bridge.common.errors.ConfigError` naming the file, the dotted key and what was
expected.
"""

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from sim_bridge.common.configfile import dataclass_from_mapping, load_yaml, section
from sim_bridge.common.errors import ConfigError
from sim_bridge.common.paths import config_path

_T = TypeVar('_T')


def preset_file(file_name: str, path: str | Path | None = None) -> tuple[dict[str, Any], str]:
    """
    Read a preset file.

    Parameters
    ----------
    file_name : str
        Name of the file in the package's ``config/`` (``'realism_arm.yaml'``).
    path : str or Path, optional
        File to read instead.

    Returns
    -------
    data : dict
        The file's top-level mapping.
    source : str
        The file's path, for messages.

    Raises
    ------
    ConfigError
        If the file cannot be read or is not a YAML mapping.

    """
    path = config_path(file_name) if path is None else Path(path)
    return load_yaml(path), str(path)


def build(cls: type[_T], mapping: Mapping[str, Any] | None, *, source: str, key: str) -> _T:
    """
    Build ``cls`` from ``mapping``; a value it refuses raises a ConfigError naming the key.

    Parameters
    ----------
    cls : type
        A frozen dataclass.
    mapping : dict or None
        Values by field name (None: all defaults).
    source : str
        File named in messages.
    key : str
        Dotted key of ``mapping`` in the file (``'presets.dvrk'``).

    Returns
    -------
    cls

    Raises
    ------
    ConfigError
        On an unknown or missing key, a value of the wrong type, or one the dataclass's own
        checks refuse (the message names the file, the key and what was expected).

    """
    try:
        return dataclass_from_mapping(cls, dict(mapping or {}), source=source, prefix=key)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f'{source}: {key}: {exc}') from exc


def preset_from(cls: type[_T], data: Mapping[str, Any], name: str, *, source: str,
                defaults: Mapping[str, Any] | None = None,
                overrides: Mapping[str, Any] | None = None, also: Iterable[str] = ()) -> _T:
    """
    Build ``cls`` from ``presets.<name>`` of a preset file's data.

    Parameters
    ----------
    cls : type
        A frozen dataclass.
    data : dict
        The file's top-level mapping (:func:`preset_file`).
    name : str
        The preset.
    source : str
        The file, for messages.
    defaults : dict, optional
        Values the preset may set otherwise.
    overrides : dict, optional
        Values that replace the preset's.
    also : iterable of str
        Other names the caller accepts besides the presets (named in the message).

    Returns
    -------
    cls

    Raises
    ------
    ConfigError
        If there is no such preset (the message lists those there are) or a value is not what
        is expected.

    """
    presets = section(data, 'presets', source=source)
    if name not in presets:
        expected = sorted(map(str, presets)) + list(also)
        raise ConfigError(f'{source}: no preset {name!r} under presets; expected one of '
                          f'{", ".join(expected)}')
    key = f'presets.{name}'
    preset = presets[name]
    if preset is None:
        preset = {}
    if not isinstance(preset, dict):
        raise ConfigError(f'{source}: key {key!r} must be a mapping, got '
                          f'{type(preset).__name__}')
    return build(cls, {**(defaults or {}), **preset, **(overrides or {})}, source=source,
                 key=key)


def read_preset(cls: type[_T], file_name: str, name: str, path: str | Path | None = None, *,
                defaults: Mapping[str, Any] | None = None,
                overrides: Mapping[str, Any] | None = None, also: Iterable[str] = ()) -> _T:
    """
    Read ``presets.<name>`` of a preset file into ``cls``.

    Parameters
    ----------
    cls : type
        A frozen dataclass.
    file_name : str
        Name of the file in the package's ``config/``.
    name : str
        The preset.
    path : str or Path, optional
        File to read instead.
    defaults, overrides : dict, optional
        As for :func:`preset_from`.
    also : iterable of str
        As for :func:`preset_from`.

    Returns
    -------
    cls

    Raises
    ------
    ConfigError
        If the file, the preset or a value is not as expected (the message names them).

    """
    data, source = preset_file(file_name, path)
    return preset_from(cls, data, name, source=source, defaults=defaults, overrides=overrides,
                       also=also)
