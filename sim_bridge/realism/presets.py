"""
The one reader of the realism preset files (``config/realism_*.yaml``).

Each file holds ``presets``: a mapping from a preset's name to its levels (and magnitudes), read
into a frozen dataclass. A missing file, a missing or unknown preset, an unknown key, a value of
the wrong type and a value the dataclass refuses (a negative level) all raise a
:class:`~sim_bridge.common.errors.ConfigError` naming the file, the dotted key and what was
expected.
"""

from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

from sim_bridge.common.configfile import dataclass_from_mapping, load_yaml, section
from sim_bridge.common.errors import ConfigError
from sim_bridge.common.paths import config_path

_T = TypeVar('_T')


def _build(cls: type[_T], mapping: Mapping[str, Any], *, source: str, key: str) -> _T:
    """Build ``cls`` from ``mapping`` (``key`` of ``source``); a refused value names the key."""
    try:
        return dataclass_from_mapping(cls, dict(mapping), source=source, prefix=key)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f'{source}: {key}: {exc}') from exc


def read_preset(cls: type[_T], file_name: str, name: str, path: str | Path | None = None, *,
                shared: Mapping[str, type] | None = None,
                defaults: Mapping[str, Any] | None = None,
                overrides: Mapping[str, Any] | None = None, also: Iterable[str] = ()) -> _T:
    """
    Read ``presets.<name>`` of a preset file into ``cls``.

    Parameters
    ----------
    cls : type
        A frozen dataclass.
    file_name : str
        Name of the file in the package's ``config/`` (``'realism_arm.yaml'``).
    name : str
        The preset.
    path : str or Path, optional
        File to read instead.
    shared : dict of str to type, optional
        Top-level sections every preset shares (``{'magnitudes': TissueMagnitudes}``): each is
        read into its dataclass and set as the preset's field of the same name.
    defaults : dict, optional
        Values the preset may set otherwise (``{'name': name}``).
    overrides : dict, optional
        Values that replace the preset's (levels given by a caller).
    also : iterable of str
        Other names the caller accepts besides the presets (``'off'``), for the message.

    Returns
    -------
    cls

    Raises
    ------
    ConfigError
        If the file cannot be read, has no such preset (the message lists those there are), or
        a key or value is not what is expected: an unknown or missing key, a value of the wrong
        type, or one the dataclass's own checks refuse (the message names the file, the dotted
        key and what was expected).

    """
    path = config_path(file_name) if path is None else Path(path)
    source = str(path)
    data = load_yaml(path)
    parts: dict[str, Any] = {
        key: _build(kind, section(data, key, source=source), source=source, key=key)
        for key, kind in (shared or {}).items()}
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
    config = _build(cls, {**(defaults or {}), **preset, **(overrides or {})}, source=source,
                    key=key)
    return replace(config, **parts) if parts else config  # type: ignore[type-var]
