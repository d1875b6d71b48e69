"""
Levels and magnitudes of the needle-in-tissue effects: the one reader of ``realism_tissue.yaml``.

Four effects, each with a level (0 off, 1 the cited magnitudes, more is stronger):

- ``needle_tissue``: forces of the tissue on the needle (puncture, friction, off-arc resistance);
- ``grip``: how easily the needle turns or slides in the jaw (the grip's torque and force
  limits are divided by the level; 0: a weld, as without this module);
- ``pad``: how far the surface gives under the tip before it punctures (the deflection depth
  is the level times puncture force / pad stiffness);
- ``thread_drag``: the thread's pull on the tail between the exit and the extraction.

Units: N, m, s, rad.
"""

from dataclasses import dataclass, fields, replace
from pathlib import Path

from sim_bridge.realism.presets import read_preset

#: Name of the configuration file (in the package's ``config/``).
CONFIG_FILE = 'realism_tissue.yaml'


@dataclass(frozen=True)
class TissueMagnitudes:
    """
    Magnitudes of the effects at level 1 (see ``config/realism_tissue.yaml`` for sources).

    Attributes
    ----------
    puncture_force : float
        Push (N) the surface takes before the tip punctures it.
    pad_stiffness : float
        Surface stiffness (N/m) under the tip before puncture.
    lateral_stiffness : float
        Stiffness (N/m) per occupied puncture against the needle leaving its arc.
    friction_per_length : float
        Friction (N per m of wire inside the tissue) along the wire.
    grip_torque : float
        Torque (N m) about the jaw's long axis the grip holds before the needle turns.
    grip_force : float
        Force (N) along the wire the grip holds before the needle slides.
    slip_event_angle : float
        A slip episode turning the needle at least this much (rad) is reported.
    slip_event_slide : float
        A slip episode sliding the needle at least this far (m) is reported.
    max_slip_step : float
        Largest turn (rad) per physics step (and a hundredth of it in m of slide).
    break_angle, break_slide : float
        Turn (rad) and slide (m) since the grasp past which the grasp breaks: the jaw no longer
        holds the needle.
    deflection_spread : float
        Gaussian radius (m) of the surface dimple around the tip.
    relax_time : float
        Time constant (s) of the surface's relaxation after the puncture.
    thread_drag : float
        Pull (N) of the thread on the tail between exit and extraction.

    """

    puncture_force: float = 1.0
    pad_stiffness: float = 2000.0
    lateral_stiffness: float = 1000.0
    friction_per_length: float = 5.0
    grip_torque: float = 0.0097
    grip_force: float = 10.0
    slip_event_angle: float = 0.0087
    slip_event_slide: float = 0.0002
    max_slip_step: float = 0.02
    break_angle: float = 0.5236
    break_slide: float = 0.01
    deflection_spread: float = 0.004
    relax_time: float = 0.15
    thread_drag: float = 0.2

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not value > 0.0:
                raise ValueError(f'tissue realism magnitude {f.name} must be > 0, got {value}')


@dataclass(frozen=True)
class TissueRealismConfig:
    """
    Levels of the needle-in-tissue effects and their magnitudes at level 1.

    Attributes
    ----------
    needle_tissue, grip, pad, thread_drag : float
        Levels (>= 0; 0 off).
    magnitudes : TissueMagnitudes
        Magnitudes at level 1.

    """

    needle_tissue: float = 0.0
    grip: float = 0.0
    pad: float = 0.0
    thread_drag: float = 0.0
    magnitudes: TissueMagnitudes = TissueMagnitudes()

    def __post_init__(self) -> None:
        for name in ('needle_tissue', 'grip', 'pad', 'thread_drag'):
            value = getattr(self, name)
            if not value >= 0.0:
                raise ValueError(f'tissue realism level {name} must be >= 0, got {value}')

    @property
    def active(self) -> bool:
        """Whether any effect is on (else the simulation is exactly as without it)."""
        return any(getattr(self, n) > 0.0 for n in ('needle_tissue', 'grip', 'pad',
                                                    'thread_drag'))

    def scaled(self, level: float) -> 'TissueRealismConfig':
        """
        Return this configuration with every level multiplied by ``level`` (a sweep's value).

        Parameters
        ----------
        level : float
            Factor (>= 0).

        Returns
        -------
        TissueRealismConfig

        """
        return replace(self, needle_tissue=self.needle_tissue * level, grip=self.grip * level,
                       pad=self.pad * level, thread_drag=self.thread_drag * level)


def load_tissue_realism(name: str, path: str | Path | None = None) -> TissueRealismConfig:
    """
    Read the preset ``name`` of ``config/realism_tissue.yaml``.

    Parameters
    ----------
    name : str
        Preset (``'none'``, ``'tissue'``).
    path : str or Path, optional
        File to read; default: the package's ``realism_tissue.yaml``.

    Returns
    -------
    TissueRealismConfig

    Raises
    ------
    ConfigError
        If the file, the preset or a value is not as expected (the message names them).

    """
    return read_preset(TissueRealismConfig, CONFIG_FILE, name, path,
                       shared={'magnitudes': TissueMagnitudes})
