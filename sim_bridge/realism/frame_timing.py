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


class Exposures:
    """
    The scene states an endoscope exposed, kept until newer frames have been delivered.

    In-process, an image is rendered only when someone looks (rendering is the costly part),
    yet the image a look gets must be the endoscope's: the newest frame whose scene is at or
    before now minus the latency. At each frame instant the scene's drawn state (a few poses,
    cheap to copy) is kept; a look renders the newest delivered one, lazily. A frame is exposed
    at the first physics step at or after its instant (the scene does not exist between
    steps), shows the scene then and is delivered ``latency`` later.

    Parameters
    ----------
    timing : FrameTiming
        The endoscope's frame rate and latency (ideal: nothing is kept).

    """

    def __init__(self, timing: FrameTiming) -> None:
        self.timing = timing
        self.active = not timing.is_ideal
        # frames still to be delivered, plus the newest delivered one
        rate = timing.rate
        self._keep = 2 + (math.ceil(timing.latency * rate) if rate else 1000)
        self._frames: list[tuple[float, object]] = []

    def clear(self) -> None:
        """Forget every exposure (the scene starts again)."""
        self._frames.clear()

    def due(self, t: float, dt: float) -> bool:
        """Whether a frame instant lies in the step ``(t - dt, t]`` (every step at rate 0)."""
        rate = self.timing.rate
        if not rate:
            return True
        return math.floor(t * rate + 1e-9) > math.floor((t - dt) * rate + 1e-9)

    def add(self, t: float, state: object) -> None:
        """Keep the scene's state ``state`` exposed at ``t``."""
        frames = self._frames
        if frames and frames[-1][0] == t:
            frames.pop()  # the same instant exposed again (the scene set up anew at t = 0)
        frames.append((float(t), state))
        if len(frames) > self._keep:
            del frames[:len(frames) - self._keep]

    def delivered(self, now: float) -> tuple[float, object] | None:
        """
        Return the newest frame delivered at ``now``: (scene time it shows, the state then).

        Before the first frame has arrived (the first ``latency`` of a scene), the first
        frame: the scene has just been set up and stands still.
        """
        frames = self._frames
        if not frames:
            return None
        for t, state in reversed(frames):
            if t + self.timing.latency <= now + 1e-9:
                return t, state
        return frames[0]
