"""
Calibration-shaped arm errors a physical dVRK keeps after its own calibration.

Static errors, fixed for the life of a robot: an offset on every joint (the wrist's included,
where the potentiometer/encoder homing leaves a few degrees), and a registration error of the
arm's base with both a translation and a rotation. Unlike :mod:`sim_bridge.kinematic_errors`
(offsets on joints 1-3 and a base translation only: the very form the six-pose registration
fits), these include shapes the registration does not model (wrist offsets, base rotation).

Frames: ``world``; joints in rad / m; ``T_*`` 4x4 poses.
"""

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
import math
from pathlib import Path

import numpy as np
from sim_bridge.kinematic_errors import ArmError
from sim_bridge.realism.presets import read_preset
from sim_bridge.realism.servo import ServoConfig
from sim_bridge.realism.transmission import JointTransmission, TransmissionConfig


@dataclass(frozen=True)
class CalibrationConfig:
    """
    Magnitudes of an arm's static calibration errors (each drawn uniformly in ``±value``).

    Attributes
    ----------
    joint_offset : tuple of float
        Per joint (rad / m).
    base_translation : float
        Per axis of the base registration's translation (m).
    base_rotation : float
        Angle of the base registration's rotation about a random axis (rad).

    """

    joint_offset: tuple[float, ...] = (0.0,) * 6
    base_translation: float = 0.0
    base_rotation: float = 0.0

    def __post_init__(self) -> None:
        values = (*self.joint_offset, self.base_translation, self.base_rotation)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise ValueError(f'calibration magnitudes must be finite numbers >= 0, got '
                             f'joint_offset={self.joint_offset}, '
                             f'base_translation={self.base_translation}, '
                             f'base_rotation={self.base_rotation}')


@dataclass(frozen=True)
class ArmRealismConfig:
    """
    One arm model's effects, each scaled by its level (0: off, 1: the preset's magnitude).

    Attributes
    ----------
    name : str
        Preset name (``dvrk``), for reports.
    calibration : CalibrationConfig
    transmission : TransmissionConfig
    servo : ServoConfig
        The joints' servo loop at level 1 (PSMs and ECM).
    calibration_level, transmission_level : float
        Scale of each effect (>= 0).
    servo_level : float
        0: ideal tracking; ``L > 0``: the servo loop with its natural frequency divided by ``L``
        (more lag).

    """

    name: str = 'dvrk'
    calibration: CalibrationConfig = CalibrationConfig()
    transmission: TransmissionConfig = TransmissionConfig()
    servo: ServoConfig = ServoConfig()
    calibration_level: float = 1.0
    transmission_level: float = 1.0
    servo_level: float = 1.0

    def __post_init__(self) -> None:
        for key in ('calibration_level', 'transmission_level', 'servo_level'):
            v = getattr(self, key)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f'arm realism {key} must be a finite number >= 0, got {v}')


def servo_config(config: ArmRealismConfig) -> ServoConfig | None:
    """
    Return the arms' servo loop at ``config``'s servo level (None at level 0).

    Parameters
    ----------
    config : ArmRealismConfig

    Returns
    -------
    ServoConfig or None

    """
    if config.servo_level == 0.0:
        return None
    return replace(config.servo,
                   natural_frequency=config.servo.natural_frequency / config.servo_level)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def draw_arm_realism(config: ArmRealismConfig, rng: np.random.Generator,
                     arms: Iterable[str]) -> dict[str, ArmError]:
    """
    Draw each arm's hidden error (calibration) and give it a cable transmission.

    Parameters
    ----------
    config : ArmRealismConfig
    rng : numpy.random.Generator
        Source of the draws (seeded by the caller).
    arms : sequence of str
        Arms to draw for, in order.

    Returns
    -------
    dict of str to ArmError
        With ``transmission`` set when the transmission level is positive.

    """
    cal, cl = config.calibration, config.calibration_level
    trans_cfg = TransmissionConfig(
        backlash=tuple(config.transmission_level * b for b in config.transmission.backlash),
        stretch=tuple(config.transmission_level * s for s in config.transmission.stretch),
        neutral=config.transmission.neutral)
    out = {}
    for name in arms:
        magnitudes = cl * np.asarray(cal.joint_offset, dtype=float)
        offset = rng.uniform(-1.0, 1.0, magnitudes.size) * magnitudes
        T = np.eye(4)
        T[:3, 3] = rng.uniform(-1.0, 1.0, 3) * cl * cal.base_translation
        angle = rng.uniform(-1.0, 1.0) * cl * cal.base_rotation
        axis = rng.normal(size=3)
        if angle != 0.0:
            T[:3, :3] = _rotation(axis, angle)
        start = rng.uniform(-0.5, 0.5, len(trans_cfg.backlash)) * np.asarray(trans_cfg.backlash)
        transmission = None if trans_cfg.is_zero else JointTransmission(trans_cfg, start)
        offset.flags.writeable = False
        T.flags.writeable = False
        out[name] = ArmError(offset, T, transmission)
    return out


def load_arm_realism(name: str, path: str | Path | None = None,
                     levels: Mapping[str, float] | None = None) -> ArmRealismConfig:
    """
    Read the preset ``name`` of ``config/realism_arm.yaml`` (``presets.<name>``).

    Parameters
    ----------
    name : str
        Preset name (``'dvrk'``).
    path : str or Path, optional
        File to read; default: the package's ``realism_arm.yaml``.
    levels : dict of str to float, optional
        Per-effect levels overriding the preset's (``{'transmission_level': 0.0}``).

    Returns
    -------
    ArmRealismConfig

    Raises
    ------
    ConfigError
        If the file, the preset or a value is wrong (naming the file and key).

    """
    return read_preset(ArmRealismConfig, 'realism_arm.yaml', name, path, defaults={'name': name},
                       overrides=levels)
