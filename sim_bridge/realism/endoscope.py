"""
The endoscope's realism presets (``config/realism_camera.yaml``): a lens and a frame timing.

:func:`endoscope_preset` reads a named preset into an :class:`EndoscopeRealism`; the name ``''``
(or ``off``) is the ideal camera of today (an ideal pinhole, an image at any instant).
"""

from dataclasses import dataclass, field
from pathlib import Path

from sim_bridge.realism.frame_timing import FrameTiming
from sim_bridge.realism.lens import LensConfig
from sim_bridge.realism.presets import read_preset

PRESET_FILE = 'realism_camera.yaml'


@dataclass(frozen=True)
class EndoscopeRealism:
    """
    What the endoscope adds to an ideal camera.

    Attributes
    ----------
    lens : LensConfig
        Distortion of the raw images.
    timing : FrameTiming
        Frame rate and latency of the images.

    """

    lens: LensConfig = field(default_factory=LensConfig)
    timing: FrameTiming = field(default_factory=FrameTiming)

    @property
    def is_ideal(self) -> bool:
        """Whether nothing is added (today's camera)."""
        return not self.lens.D.any() and self.timing.is_ideal


def endoscope_preset(name: str, path: str | Path | None = None) -> EndoscopeRealism:
    """
    Return the endoscope preset called ``name``.

    Parameters
    ----------
    name : str
        A key of ``presets`` in the file, or ``''`` / ``'off'`` for the ideal camera.
    path : str or pathlib.Path, optional
        The preset file (default ``config/realism_camera.yaml``).

    Returns
    -------
    EndoscopeRealism

    Raises
    ------
    ConfigError
        If the file has no such preset or a value is not what is expected; the message names
        the file and the key.

    """
    if name in ('', 'off'):
        return EndoscopeRealism()
    return read_preset(EndoscopeRealism, PRESET_FILE, name, path, also=('off',))
