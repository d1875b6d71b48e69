"""
Calibration-shaped arm errors a physical dVRK keeps after its own calibration.

Static errors, fixed for the life of a robot: an offset on every joint (the wrist's included,
where the potentiometer/encoder homing leaves a few degrees), and a registration error of the
arm's base with both a translation and a rotation. Unlike :mod:`sim_bridge.kinematic_errors`
(offsets on joints 1-3 and a base translation only: the very form the six-pose registration
fits), these include shapes the registration does not model (wrist offsets, base rotation).

The same preset also leaves the robot's other calibrations a little off: the ECM's (its joints
and base, so the camera's reported pose: a hand-eye error), the endoscope's intrinsics (the
``camera_info`` the robot side uses, while the render keeps the true ones), and it reads the
joints through encoders (:mod:`sim_bridge.realism.encoder`). Each has its own level and draws
from its own seeded stream, so a level at 0 leaves the others' draws as they were.

Frames: ``world``; joints in rad / m; ``T_*`` 4x4 poses.
"""

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
import math
from pathlib import Path

import numpy as np
from sim_bridge.kinematic_errors import ArmError
from sim_bridge.realism.encoder import EncoderConfig, JointEncoder
from sim_bridge.realism.jaw import JawConfig, JawStall
from sim_bridge.realism.presets import read_preset
from sim_bridge.realism.servo import ServoConfig
from sim_bridge.realism.transmission import JointTransmission, TransmissionConfig

#: A servoed joint rests on its setpoint within this fraction of an encoder count.
SERVO_REST_COUNTS = 0.1
#: The per-effect levels of an :class:`ArmRealismConfig` (keys of a preset and of a sweep).
ARM_LEVELS = ('calibration_level', 'transmission_level', 'servo_level', 'encoder_level',
              'ecm_level', 'intrinsics_level', 'jaw_level')
#: Streams of the seeded draws besides the PSMs' own (``default_rng([seed, stream])``).
_ECM_STREAM, _INTRINSICS_STREAM, _ENCODER_STREAM = 1, 2, 3


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
class IntrinsicsConfig:
    """
    How far the endoscope's calibrated intrinsics are from the true ones (each uniform in ``±``).

    Attributes
    ----------
    focal : float
        Relative error of each focal length (``fx``, ``fy``; 0.007: 0.7 %).
    principal_point : float
        Error of each principal point coordinate (px).
    baseline : float
        Relative error of the stereo baseline.

    """

    focal: float = 0.0
    principal_point: float = 0.0
    baseline: float = 0.0

    def __post_init__(self) -> None:
        values = (self.focal, self.principal_point, self.baseline)
        if not all(math.isfinite(v) and v >= 0.0 for v in values) or self.focal >= 0.5 \
                or self.baseline >= 0.5:
            raise ValueError(f'intrinsics errors must be finite numbers >= 0 (the relative ones '
                             f'below 0.5), got focal={self.focal}, principal_point='
                             f'{self.principal_point}, baseline={self.baseline}')


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
    encoder : EncoderConfig
        The joint encoders (PSMs and ECM).
    ecm : CalibrationConfig
        The ECM's calibration errors (four joint offsets, its base): the camera's reported pose.
    intrinsics : IntrinsicsConfig
        The endoscope's calibration errors.
    jaw : JawConfig
        What a PSM jaw closed on the needle reads (:mod:`sim_bridge.realism.jaw`).
    calibration_level, transmission_level : float
        Scale of each effect (>= 0).
    servo_level : float
        0: ideal tracking; ``L > 0``: the servo loop with its natural frequency divided by ``L``
        (more lag).
    encoder_level, ecm_level, intrinsics_level, jaw_level : float
        Scale of each (>= 0); the encoder's noise and counts both scale.

    """

    name: str = 'dvrk'
    calibration: CalibrationConfig = CalibrationConfig()
    transmission: TransmissionConfig = TransmissionConfig()
    servo: ServoConfig = ServoConfig()
    encoder: EncoderConfig = EncoderConfig()
    ecm: CalibrationConfig = CalibrationConfig(joint_offset=(0.0,) * 4)
    intrinsics: IntrinsicsConfig = IntrinsicsConfig()
    jaw: JawConfig = JawConfig()
    calibration_level: float = 1.0
    transmission_level: float = 1.0
    servo_level: float = 1.0
    encoder_level: float = 1.0
    ecm_level: float = 1.0
    intrinsics_level: float = 1.0
    jaw_level: float = 1.0

    def __post_init__(self) -> None:
        for key in ARM_LEVELS:
            v = getattr(self, key)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f'arm realism {key} must be a finite number >= 0, got {v}')


def servo_config(config: ArmRealismConfig, arm: str = 'PSM1') -> ServoConfig | None:
    """
    Return an arm's servo loop at ``config``'s servo level (None at level 0).

    A joint rests on its setpoint once within :data:`SERVO_REST_COUNTS` of one count of the
    preset's encoders (whatever the encoder level: the arm's encoders are what they are; a
    residual of a tenth of a count, under the reading's noise, no ``measured_js`` can show).

    Parameters
    ----------
    config : ArmRealismConfig
    arm : str
        ``'ECM'`` takes the ECM's encoder counts, any other arm the PSM's.

    Returns
    -------
    ServoConfig or None

    """
    if config.servo_level == 0.0:
        return None
    counts = config.encoder.ecm if arm == 'ECM' else config.encoder.psm
    rest = (tuple(SERVO_REST_COUNTS * float(c) for c in counts) if any(counts)
            else config.servo.rest)
    return replace(config.servo,
                   natural_frequency=config.servo.natural_frequency / config.servo_level,
                   rest=rest)


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
        offset, T = _draw_calibration(cal, cl, rng)
        start = rng.uniform(-0.5, 0.5, len(trans_cfg.backlash)) * np.asarray(trans_cfg.backlash)
        transmission = None if trans_cfg.is_zero else JointTransmission(trans_cfg, start)
        offset.flags.writeable = False
        T.flags.writeable = False
        out[name] = ArmError(offset, T, transmission)
    return out


def _draw_calibration(cal: CalibrationConfig, level: float, rng: np.random.Generator
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Return joint offsets and ``T_believed_true`` drawn at ``level`` of ``cal``."""
    magnitudes = level * np.asarray(cal.joint_offset, dtype=float)
    offset = rng.uniform(-1.0, 1.0, magnitudes.size) * magnitudes
    T = np.eye(4)
    T[:3, 3] = rng.uniform(-1.0, 1.0, 3) * level * cal.base_translation
    angle = rng.uniform(-1.0, 1.0) * level * cal.base_rotation
    axis = rng.normal(size=3)
    if angle != 0.0:
        T[:3, :3] = _rotation(axis, angle)
    return offset, T


def draw_ecm_error(config: ArmRealismConfig, seed: int) -> ArmError | None:
    """
    Draw the ECM's hidden calibration error (its reported camera pose is off by it).

    Parameters
    ----------
    config : ArmRealismConfig
    seed : int
        The robot's error seed (the ECM draws from a stream of its own).

    Returns
    -------
    ArmError or None
        None at ``ecm_level`` 0.

    """
    if config.ecm_level == 0.0:
        return None
    offset, T = _draw_calibration(config.ecm, config.ecm_level,
                                  np.random.default_rng([int(seed), _ECM_STREAM]))
    offset.flags.writeable = False
    T.flags.writeable = False
    return ArmError(offset, T)


def draw_intrinsics_error(config: ArmRealismConfig, seed: int
                          ) -> tuple[float, float, float, float, float] | None:
    """
    Draw how the endoscope's calibration is off: what it reports over the truth.

    Parameters
    ----------
    config : ArmRealismConfig
    seed : int
        The robot's error seed (a stream of its own).

    Returns
    -------
    (float, float, float, float, float) or None
        ``(fx scale, fy scale, cx shift px, cy shift px, baseline scale)``; None at
        ``intrinsics_level`` 0.

    """
    level, c = config.intrinsics_level, config.intrinsics
    if level == 0.0:
        return None
    rng = np.random.default_rng([int(seed), _INTRINSICS_STREAM])
    u = rng.uniform(-1.0, 1.0, 5) * level
    return (float(1.0 + u[0] * c.focal), float(1.0 + u[1] * c.focal),
            float(u[2] * c.principal_point), float(u[3] * c.principal_point),
            float(1.0 + u[4] * c.baseline))


def build_encoders(config: ArmRealismConfig, seed: int, arms: Iterable[str]
                   ) -> dict[str, JointEncoder]:
    """
    Give each arm its joint encoders at ``config``'s encoder level.

    Parameters
    ----------
    config : ArmRealismConfig
    seed : int
        The robot's error seed (each arm's noise a stream of its own).
    arms : sequence of str
        Arms (``'ECM'`` takes the ECM's resolution, the others the PSM's).

    Returns
    -------
    dict of str to JointEncoder
        Empty at ``encoder_level`` 0.

    """
    level, c = config.encoder_level, config.encoder
    if level == 0.0:
        return {}
    out = {}
    for i, name in enumerate(arms):
        resolution = np.asarray(c.ecm if name == 'ECM' else c.psm, dtype=float) * level
        out[name] = JointEncoder(resolution, c.noise,
                                 np.random.default_rng([int(seed), _ENCODER_STREAM, i]))
    return out


def build_jaw_stall(config: ArmRealismConfig) -> JawStall | None:
    """Return the PSM jaws' reading of a held needle at ``config``'s jaw level (None at 0)."""
    if config.jaw_level == 0.0:
        return None
    return JawStall(config.jaw, config.jaw_level)


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
