"""
One call per stereo pair: the markers, then the needle tracked from frame to frame.

:class:`StereoPerception` is what a loop calls on each new pair (the ``perception`` node at its
rate; an executor in-process): it finds the markers (their plane tells on which surface a free
needle lies), then estimates the needle from the best prior it has -- the one the caller gives
(tool pose times grasp while held), else its own last estimate while that is recent, else none
(a detection). A needle the tracking loses, or that was last seen longer ago, is looked for
around where it was last seen, farther than tracking reaches
(:func:`suture_lfd.perception.reacquire.shifted_priors`): an arm may have carried it a few
millimetres between two pairs, and a held needle cannot be detected afresh (the jaw's metal
joins its pixels); only then is it detected anew.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from suture_lfd.perception.markers import MarkerConfig, MarkerDetections, detect_markers
from suture_lfd.perception.needle import NeedleEstimate, NeedleTracker
from suture_lfd.perception.stereo import StereoModel


@dataclass(frozen=True, eq=False)
class PerceptionResult:
    """
    What one stereo pair showed.

    Attributes
    ----------
    markers : suture_lfd.perception.markers.MarkerDetections or None
        The markers (None when not looked for).
    needle : suture_lfd.perception.needle.NeedleEstimate
        The needle.
    tracked : bool
        The needle estimate started from the previous one.

    """

    markers: MarkerDetections | None
    needle: NeedleEstimate
    tracked: bool


class StereoPerception:
    """
    Markers and a tracked needle from successive stereo pairs.

    Parameters
    ----------
    tracker : NeedleTracker, optional
    marker_config : MarkerConfig, optional
    track_timeout : float
        Age (s) beyond which the last estimate is no prior any more.
    markers : bool
        Look for the markers (their plane helps detect a free needle).
    search_reach : int
        Reach (pixels, either axis) of the search around the last estimate when tracking
        lost the needle; 0: no search.

    """

    def __init__(self, tracker: NeedleTracker | None = None,
                 marker_config: MarkerConfig | None = None, track_timeout: float = 1.0,
                 markers: bool = True, search_reach: int = 80) -> None:
        self.tracker = tracker or NeedleTracker()
        self.marker_config = marker_config or MarkerConfig()
        self.track_timeout = float(track_timeout)
        self.find_markers = bool(markers)
        self.search_reach = int(search_reach)
        # (time, T_camera_needle) of the last found estimate
        self._last: tuple[float, np.ndarray] | None = None
        self._normal: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the tracked needle (after the scene changed)."""
        self._last = None

    def process(self, left: np.ndarray, right: np.ndarray, stereo: StereoModel, t: float,
                prior: ArrayLike | None = None,
                tools: Sequence[ArrayLike] = ()) -> PerceptionResult:
        """
        Perceive one stereo pair.

        Parameters
        ----------
        left, right : ndarray, shape (height, width, 3), uint8
            Rectified RGB images.
        stereo : suture_lfd.perception.stereo.StereoModel
        t : float
            Time (s) of the pair.
        prior : array_like, shape (4, 4), optional
            ``T_camera_needle`` known from elsewhere (tool pose times grasp); overrides
            tracking.
        tools : sequence of array_like, shape (4, 4)
            Tool-tip poses (camera frame) of the instruments near the needle.

        Returns
        -------
        PerceptionResult

        Raises
        ------
        ValueError
            When an image is not uint8 RGB of the camera's size.

        """
        markers = None
        if self.find_markers:
            markers = detect_markers(left, right, stereo, self.marker_config)
            if markers.n_pairs:
                self._normal = markers.normal
        given = prior is not None
        tracked = False
        if not given and self._last is not None and t - self._last[0] <= self.track_timeout:
            prior, tracked = self._last[1], True
        est: NeedleEstimate | None = None
        if prior is not None:
            est = self.tracker.estimate(left, right, stereo, prior=prior, tools=tools)
        if est is None or (not given and not est.found):
            est, tracked = self._reacquire(left, right, stereo, tools)
        if est.found and est.pose_camera is not None:
            self._last = (t, est.pose_camera)
        return PerceptionResult(markers=markers, needle=est, tracked=tracked)

    def _reacquire(self, left: np.ndarray, right: np.ndarray, stereo: StereoModel,
                   tools: Sequence[ArrayLike]) -> tuple[NeedleEstimate, bool]:
        """Look for a needle not tracked: around its last pose first, then anywhere."""
        if self._last is not None and self.search_reach > 0:
            searched = self.tracker.estimate(left, right, stereo, prior=self._last[1],
                                             tools=tools, search=self.search_reach)
            if searched.found:
                return searched, True
        return self.tracker.estimate(left, right, stereo, tools=tools,
                                     support_normal=self._normal), False
