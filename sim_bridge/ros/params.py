"""
Node parameters from ``config/<node>.yaml``, shared by the nodes of both packages.

:func:`declare_config` declares a node's parameters with their defaults from
``config/<node>.yaml`` (shape ``<node_name>: ros__parameters: {...}``), so that
``--ros-args -p name:=value`` and parameter files override them, and returns the node's frozen
configuration dataclass, checked by :mod:`sim_bridge.common.configfile`.
"""

from dataclasses import MISSING, fields
import typing

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter
from sim_bridge.common.configfile import ConfigError, dataclass_from_mapping, load_yaml
from sim_bridge.common.paths import config_path

_ARRAY_TYPES = {str: Parameter.Type.STRING_ARRAY, float: Parameter.Type.DOUBLE_ARRAY,
                int: Parameter.Type.INTEGER_ARRAY, bool: Parameter.Type.BOOL_ARRAY}
_SCALAR_TYPES = {str: Parameter.Type.STRING, float: Parameter.Type.DOUBLE,
                 int: Parameter.Type.INTEGER, bool: Parameter.Type.BOOL}


def _parameter_type(annotation):
    if typing.get_origin(annotation) is tuple:
        return _ARRAY_TYPES[typing.get_args(annotation)[0]]
    return _SCALAR_TYPES[annotation]


def _file_defaults(path, names):
    data = load_yaml(path)
    for key in names:
        if key in data:
            node = data[key] or {}
            if not isinstance(node, dict):
                raise ConfigError(f'{path}: key {key!r} must be a mapping')
            params = node.get('ros__parameters', {}) or {}
            if not isinstance(params, dict):
                raise ConfigError(f'{path}: key {key + ".ros__parameters"!r} must be a mapping')
            return params
    raise ConfigError(f'{path}: no section for the node; expected one of '
                      f'{", ".join(repr(n) for n in names)} with a ros__parameters mapping')


def declare_config(node, cls, config_file, default_name):
    """
    Declare the node's parameters from ``config/<config_file>`` and return the configuration.

    Parameters
    ----------
    node : rclpy.node.Node
        The node; its parameters are declared once, one per field of ``cls``.
    cls : type
        Frozen dataclass; field names are the parameter names and YAML keys.
    config_file : str
        File name in the package's ``config/`` folder (``'recorder.yaml'``).
    default_name : str
        Section of the file to use when there is none for the node's (remapped) name.

    Returns
    -------
    cls
        The configuration: YAML defaults, overridden by ``--ros-args``.

    Raises
    ------
    ConfigError
        If the file or a parameter value does not match ``cls``; the message names the key.

    """
    path = config_path(config_file)
    names = [node.get_fully_qualified_name(), node.get_name(), default_name, '/**']
    defaults = _file_defaults(path, list(dict.fromkeys(names)))
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(defaults) - known - {'use_sim_time'})
    if unknown:
        raise ConfigError(f'{path}: unknown parameter {unknown[0]!r}; expected one of '
                          f'{sorted(known)}')
    hints = typing.get_type_hints(cls)
    values = {}
    for field in fields(cls):
        if field.name in defaults:
            default = defaults[field.name]
        elif field.default is not MISSING:
            default = field.default
        elif field.default_factory is not MISSING:
            default = field.default_factory()
        else:
            raise ConfigError(f'{path}: missing parameter {field.name!r}')
        if isinstance(default, tuple):
            default = list(default)
        if _parameter_type(hints[field.name]) == Parameter.Type.DOUBLE and \
                isinstance(default, int) and not isinstance(default, bool):
            default = float(default)
        if default == []:
            # an empty list has no type of its own: declare the field's type
            value = node.declare_parameter(field.name, _parameter_type(hints[field.name])).value
        else:
            # dynamic typing: `-p rate:=2` is accepted for a float; the dataclass checks types
            value = node.declare_parameter(
                field.name, default, ParameterDescriptor(dynamic_typing=True)).value
        values[field.name] = default if value is None else value
    for name, value in values.items():
        if not isinstance(value, (str, bytes)) and hasattr(value, '__len__') \
                and not isinstance(value, list):
            values[name] = list(value)
    return dataclass_from_mapping(cls, values, source=f'{path} (with --ros-args overrides)')
