"""
dVRK kinematics from ``config/kinematics.yaml``: the PSM and ECM chains and their factories.

The chains are modified-DH serial chains (:mod:`sim_bridge.kinematics.dh_chain`) with closed-form
inverse kinematics around the remote centre of motion (:mod:`sim_bridge.kinematics.rcm`); this
module reads the dVRK numbers (joint names, DH parameters, limits, tool-tip offsets, jaw range,
trajectory limits) and builds them. It also re-exports the public names of both modules so that
``from sim_bridge.kinematics import PsmKinematics, UnreachableError`` works.

Units are SI (metres, radians); the tool-tip pose is ``T_base_tip`` in the RCM frame
``<ARM>_base``.
"""

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
import re
from typing import TypeVar

import numpy as np
from sim_bridge.common.configfile import ConfigError, dataclass_from_mapping, load_yaml
from sim_bridge.common.paths import config_path
from sim_bridge.kinematics.dh_chain import (
    DhJoint,
    SerialChain,
    check_joint_vector,
    check_pose,
    check_poses,
    pinocchio_model,
    rotation_angle,
    rotation_x,
)
from sim_bridge.kinematics.rcm import (
    IK_TOLERANCE,
    EcmKinematics,
    JawLimits,
    PsmKinematics,
    UnreachableError,
)

_T = TypeVar('_T')

__all__ = [
    'ArmChainConfig', 'check_joint_vector', 'check_pose', 'check_poses', 'DhJoint',
    'EcmKinematics', 'ecm_kinematics', 'IK_TOLERANCE', 'JawLimits', 'KinematicsConfig',
    'KinematicsDefaults', 'load_kinematics', 'pinocchio_model', 'psm_kinematics',
    'PsmKinematics', 'PsmToolConfig', 'read_kinematics_config', 'rotation_angle', 'SerialChain',
    'UnreachableError',
]


@dataclass(frozen=True)
class ArmChainConfig:
    """Arm part of a chain (PSM: yaw, pitch, insertion; ECM: all four joints)."""

    joints: tuple[DhJoint, ...]
    endoscope_prefix: str = ''


@dataclass(frozen=True)
class PsmToolConfig:
    """A PSM instrument: the arm generation it mounts on, its joints, tip offset and jaw."""

    arm: str
    tool_type: str
    joints: tuple[DhJoint, ...]
    tooltip_offset: tuple[tuple[float, float, float, float], ...]
    jaw: JawLimits


@dataclass(frozen=True)
class KinematicsDefaults:
    """Which variants :func:`load_kinematics` builds."""

    psm_tool: str = 'LARGE_NEEDLE_DRIVER_420006'
    ecm_generation: str = 'Classic'
    ecm_endoscope: str = 'STRAIGHT'


@dataclass(frozen=True)
class KinematicsConfig:
    """Contents of ``config/kinematics.yaml``."""

    defaults: KinematicsDefaults
    psm_home: tuple[float, ...]
    ecm_home: tuple[float, ...]
    psm_arms: dict[str, ArmChainConfig]
    psm_tools: dict[str, PsmToolConfig]
    ecm_arms: dict[str, ArmChainConfig]
    ecm_tooltip_offset: tuple[tuple[float, float, float, float], ...]
    ecm_endoscopes: dict[str, float]


# ---------------------------------------------------------------------------------------------
# factories reading config/kinematics.yaml


def _normalise_tool_name(tool: str) -> str:
    """Accept dVRK spellings: ``LARGE_NEEDLE_DRIVER:420006[1]`` -> ``..._420006``."""
    return re.sub(r'\[\d+\]$', '', tool.strip()).replace(':', '_')


def read_kinematics_config(path: str | Path | None = None) -> KinematicsConfig:
    """
    Read ``config/kinematics.yaml`` into a :class:`KinematicsConfig`.

    Parameters
    ----------
    path : str or Path, optional
        File to read; default: the package's ``config/kinematics.yaml``.

    Returns
    -------
    KinematicsConfig

    """
    path = config_path('kinematics.yaml') if path is None else path
    data = load_yaml(path)
    return dataclass_from_mapping(KinematicsConfig, data, source=str(path))


def _pick(mapping: Mapping[str, _T], key: str, what: str, source: str) -> _T:
    if key not in mapping:
        raise ConfigError(f'{source}: unknown {what} {key!r}; expected one of {sorted(mapping)}')
    return mapping[key]


def psm_kinematics(tool: str | None = None, path: str | Path | None = None,
                   arm: str | None = None) -> PsmKinematics:
    """
    Build the PSM kinematics for a tool (and, by default, the arm generation it mounts on).

    Parameters
    ----------
    tool : str, optional
        ``'LARGE_NEEDLE_DRIVER_420006'`` (Si, default) or ``'LARGE_NEEDLE_DRIVER_400006'``
        (Classic); dVRK spellings like ``'LARGE_NEEDLE_DRIVER:420006[1]'`` are accepted.
    path : str or Path, optional
        Kinematics YAML; default: the package's ``config/kinematics.yaml``.
    arm : str, optional
        Arm generation (``'Si'`` or ``'Classic'``) overriding the tool's own.

    Returns
    -------
    PsmKinematics

    """
    cfg = read_kinematics_config(path)
    source = str(path or 'kinematics.yaml')
    tool = _normalise_tool_name(tool or cfg.defaults.psm_tool)
    tool_cfg = _pick(cfg.psm_tools, tool, 'PSM tool', source)
    generation = arm or tool_cfg.arm
    arm_cfg = _pick(cfg.psm_arms, generation, 'PSM arm generation', source)
    return PsmKinematics(arm_cfg.joints + tool_cfg.joints, np.array(tool_cfg.tooltip_offset),
                         tool_cfg.jaw, home=cfg.psm_home, name=f'PSM {generation} + {tool}',
                         tool_type=tool_cfg.tool_type)


def ecm_kinematics(generation: str | None = None, endoscope: str | None = None,
                   path: str | Path | None = None) -> EcmKinematics:
    """
    Build the ECM kinematics.

    Parameters
    ----------
    generation : str, optional
        ``'Classic'`` (default) or ``'Si'``.
    endoscope : str, optional
        ``'STRAIGHT'`` (default), ``'UP'`` (tip tilted by RotX(-30 deg)) or ``'DOWN'``
        (RotX(+30 deg)).
    path : str or Path, optional
        Kinematics YAML; default: the package's ``config/kinematics.yaml``.

    Returns
    -------
    EcmKinematics

    """
    cfg = read_kinematics_config(path)
    source = str(path or 'kinematics.yaml')
    generation = generation or cfg.defaults.ecm_generation
    endoscope = endoscope or cfg.defaults.ecm_endoscope
    arm_cfg = _pick(cfg.ecm_arms, generation, 'ECM generation', source)
    tilt = _pick(cfg.ecm_endoscopes, endoscope, 'endoscope', source)
    offset = np.array(cfg.ecm_tooltip_offset)
    offset[:3, :3] = offset[:3, :3] @ rotation_x(tilt)
    return EcmKinematics(arm_cfg.joints, offset, home=cfg.ecm_home,
                         name=f'ECM {generation} {endoscope}',
                         endoscope_type=f'{arm_cfg.endoscope_prefix}_{endoscope}')


def load_kinematics(path: str | Path | None = None) -> dict[str, SerialChain]:
    """
    Build the default PSM and ECM kinematics named in the file's ``defaults``.

    Parameters
    ----------
    path : str or Path, optional
        Kinematics YAML; default: the package's ``config/kinematics.yaml``.

    Returns
    -------
    dict
        ``{'PSM': PsmKinematics, 'ECM': EcmKinematics}``.

    """
    return {'PSM': psm_kinematics(path=path), 'ECM': ecm_kinematics(path=path)}
