"""
The simulation's configuration: ``config/world.yaml``'s sections and the scene, as dataclasses.

:func:`load_simulation_config` reads both files into a :class:`SimulationConfig`;
:class:`LoopConfig` holds the periods and thresholds of the physics step and :class:`NeedleStart`
where the needle lies when a scene starts.

Frames: ``world`` (z up); SI units.
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sim_bridge.arm import ArmConfig
from sim_bridge.common.configfile import dataclass_from_mapping, load_yaml, section
from sim_bridge.common.paths import config_path
from sim_bridge.realism.endoscope import EndoscopeRealism
from sim_bridge.realism.tissue_config import TissueRealismConfig
from sim_bridge.scene.camera import CameraConfig
from sim_bridge.scene.grasp import GraspConfig
from sim_bridge.scene.scene_config import SceneConfig, load_scene_config
from sim_bridge.scene.thread import ThreadDynamicsConfig
from sim_bridge.scene.world import WorldConfig


@dataclass(frozen=True)
class NeedleStart:
    """
    Where the needle lies when a scene starts: flat on the pad, dropped and settled.

    Attributes
    ----------
    position : (x, y)
        World x-y (m) of the needle frame origin (the arc centre).
    yaw : float
        Turn (rad) of the needle about world z (needle z up).
    position_jitter : float
        Half-width (m) of the seeded uniform offset of ``position``.
    yaw_jitter : float
        Half-width (rad) of the seeded uniform offset of ``yaw``.
    drop_height : float
        Height (m) above the support the needle is released from.
    settle_time : float
        Simulated time (s) the needle gets to come to rest (not part of the scene's time).

    """

    position: tuple[float, float] = (0.012, -0.010)
    yaw: float = 3.141592653589793
    position_jitter: float = 0.001
    yaw_jitter: float = 0.15
    drop_height: float = 0.002
    settle_time: float = 0.4


@dataclass(frozen=True)
class LoopConfig:
    """
    Settings of the simulation loop (``simulation`` section of ``config/world.yaml``).

    Attributes
    ----------
    thread_period : float
        Time (s) between thread updates; a multiple of the physics step.
    collision_period : float
        Time (s) between instrument-tissue contact checks; a multiple of the physics step.
    collision_depth : float
        Depth (m) an instrument point must reach below the tissue surface to be in contact.
    drop_distance : float
        Fall (m) of a released needle, below where it was released, that counts as a drop.
    rest_speed : float
        Speed (m/s) below which a free needle counts as still.
    rest_time : float
        Time (s) a free needle must stay still to be at rest (then physics stops moving it).
    initial_jaw : float
        PSM jaw angle (rad) when a scene starts.
    needle_start : NeedleStart
        Where the needle lies when a scene starts.
    target_pair : str or None
        Marker pair a scene starts aimed at (None: the phantom's first pair).

    """

    thread_period: float = 0.01
    collision_period: float = 0.01
    collision_depth: float = 0.0003
    drop_distance: float = 0.003
    rest_speed: float = 0.002
    rest_time: float = 0.1
    initial_jaw: float = 0.0
    needle_start: NeedleStart = field(default_factory=NeedleStart)
    target_pair: str | None = None


@dataclass(frozen=True)
class SimulationConfig:
    """
    Everything the simulation needs: ``config/world.yaml`` sections plus the scene.

    Attributes
    ----------
    world : WorldConfig
    grasp : GraspConfig
    camera : CameraConfig
    thread : ThreadDynamicsConfig
    loop : LoopConfig
    scene : SceneConfig
    psm_tool : str or None
        PSM instrument for :func:`sim_bridge.kinematics.psm_kinematics` (None: its default).
    arm : ArmConfig
        Arm options (tracking, power-up time); ``initial_jaw`` is taken from ``loop``.
    psm_rest_jp, ecm_rest_jp : tuple of float or None
        Where the PSMs / the ECM stand when a scene starts, before ``home`` (rad / m); None:
        at the homing goal (batch runs), so that ``home`` takes one step.
    kinematic_error_level : float
        Class (mm) of the PSMs' hidden kinematic errors (:mod:`sim_bridge.kinematic_errors`);
        0: perfect kinematics.
    kinematic_error_seed : int
        Seed of the errors' draw (fixed for the life of the simulation, as a robot's are).
    endoscope : EndoscopeRealism
        The endoscope's lens and frame timing (:mod:`sim_bridge.realism.endoscope`; default:
        an ideal camera).
    tissue_realism : sim_bridge.realism.tissue_config.TissueRealismConfig or None
        The needle-in-tissue effects (forces, grip, pad, thread drag); None or all levels 0:
        none (the simulation as without them).
    arm_realism : sim_bridge.realism.calibration.ArmRealismConfig or None
        The PSMs' realism model (calibration errors, cable transmission), drawn with
        ``kinematic_error_seed`` in place of the static offsets; None: the static model.

    """

    world: WorldConfig = field(default_factory=WorldConfig)
    grasp: GraspConfig = field(default_factory=GraspConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    thread: ThreadDynamicsConfig = field(default_factory=ThreadDynamicsConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    psm_tool: str | None = None
    arm: ArmConfig = field(default_factory=ArmConfig)
    psm_rest_jp: tuple[float, ...] | None = None
    ecm_rest_jp: tuple[float, ...] | None = None
    kinematic_error_level: float = 0.0
    kinematic_error_seed: int = 0
    endoscope: EndoscopeRealism = field(default_factory=EndoscopeRealism)
    tissue_realism: TissueRealismConfig | None = None
    arm_realism: Any = None


def load_simulation_config(world_path: str | Path | None = None,
                           scene_path: str | Path | None = None) -> SimulationConfig:
    """
    Read ``config/world.yaml`` and ``config/scene.yaml`` into a :class:`SimulationConfig`.

    Parameters
    ----------
    world_path, scene_path : str or Path, optional
        Files to read; default: the package's configuration files.

    Returns
    -------
    SimulationConfig

    """
    world_path = config_path('world.yaml') if world_path is None else world_path
    source = str(world_path)
    data = load_yaml(world_path)
    parts: dict[str, Any] = {}
    for key, cls in (('world', WorldConfig), ('grasp', GraspConfig), ('camera', CameraConfig),
                     ('thread', ThreadDynamicsConfig), ('simulation', LoopConfig)):
        mapping = section(data, key, source=source)
        parts[key] = dataclass_from_mapping(cls, mapping, source=source, prefix=key)
    return SimulationConfig(world=parts['world'], grasp=parts['grasp'], camera=parts['camera'],
                            thread=parts['thread'], loop=parts['simulation'],
                            scene=load_scene_config(scene_path))


def steps_per_period(period: float, dt: float, name: str) -> int:
    """
    Return how many physics steps of ``dt`` (s) make ``period`` (s).

    Raises
    ------
    ValueError
        If ``period`` is not a positive whole multiple of ``dt`` (``name`` says which period).

    """
    steps = int(round(period / dt))
    if steps < 1 or abs(steps * dt - period) > 1e-9:
        raise ValueError(f'simulation {name} ({period} s) must be a positive multiple of the '
                         f'physics step ({dt} s)')
    return steps
