"""
When an endoscope's images exist, and what time they carry: a frame rate and a latency.

A physical endoscope exposes a frame every ``1 / rate`` seconds (30 or 60 Hz on the dVRK's
stereo endoscopes) and its images reach ROS tens of milliseconds later, stamped when they
arrive (a frame grabber without hardware time stamps). :class:`FrameTiming` says which scene
instant the newest image shows at a time ``t`` and with which stamp: frame ``k`` shows the scene
at ``k / rate`` and is stamped, and available, at ``k / rate + latency``. Level 0 (``rate`` 0)
is today's camera: an image of the scene at the instant asked for, stamped with it.

Times in seconds of the simulation clock.
"""

from dataclasses import dataclass
import math


@dataclass(frozen=True)
class FrameTiming:
    """
    An endoscope's frame rate and latency.

    Attributes
    ----------
    rate : float
        Frames per second (0: an image at any instant, no latency: the ideal camera).
    latency : float
        s between the scene a frame shows and its stamp (when it reaches ROS).

    """

    rate: float = 0.0
    latency: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.rate) and self.rate >= 0.0):
            raise ValueError(f'camera frame rate must be a finite number >= 0, got {self.rate!r}')
        if not (math.isfinite(self.latency) and self.latency >= 0.0):
            raise ValueError(f'camera latency must be a finite number >= 0, got '
                             f'{self.latency!r}')

    @property
    def is_ideal(self) -> bool:
        """Whether images are of the instant asked for, unstamped by any delay."""
        return self.rate == 0.0 and self.latency == 0.0

    def newest(self, t: float) -> tuple[float, float] | None:
        """
        Return the newest image available at ``t``: (scene time it shows, its stamp).

        Parameters
        ----------
        t : float
            Now (s).

        Returns
        -------
        tuple of float or None
            ``(t_scene, t_stamp)``, with ``t_stamp = t_scene + latency <= t``; None before the
            first frame has arrived.

        """
        if self.rate == 0.0:
            scene = t - self.latency
        else:
            scene = math.floor((t - self.latency) * self.rate + 1e-9) / self.rate
        if scene < 0.0:
            return None
        return scene, scene + self.latency
