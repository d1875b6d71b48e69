"""
Perception on the endoscope's stereo pair: the entry/exit markers, the needle and its grasp.

Plain Python (numpy, scipy, OpenCV), no ROS: it sees only what a physical endoscope gives, the
two rectified RGB images and their ``camera_info`` (K, P, the baseline), never a simulator's
depth, segmentation or poses. All results are in the camera frame, the left optical frame
(``x`` right, ``y`` down, ``z`` forward; metres).

- :func:`stereo_from_camera_info` -> :class:`StereoModel`;
- :func:`detect_markers` -> :class:`MarkerDetections` (red dots, matched, triangulated, paired
  along the wound);
- :class:`NeedleTracker` ``.estimate(left, right, stereo, prior=None, tools=(),
  support_normal=None, support_point=None)`` -> :class:`NeedleEstimate` (pose, residual,
  visibility, "not found"); ``.fit_grasp(views, stereo, T_tool_needle)`` -> :class:`GraspFit`
  (one grasp fitted to several :class:`HeldView` pairs at once);
- :func:`estimate_grasp` -> :class:`GraspEstimate` (the needle in the jaw) and
  :func:`needle_prior`;
- :class:`StereoPerception` ``.process(left, right, stereo, t)`` -> :class:`PerceptionResult`:
  both, the needle tracked from pair to pair (what a loop calls).
"""

from suture_lfd.perception.grasp import (
    GraspEstimate,
    GraspFit,
    HeldView,
    estimate_grasp,
    needle_prior,
)
from suture_lfd.perception.markers import MarkerConfig, MarkerDetections, detect_markers
from suture_lfd.perception.needle import NeedleEstimate, NeedleTracker, TrackerConfig
from suture_lfd.perception.pipeline import PerceptionResult, StereoPerception
from suture_lfd.perception.stereo import StereoModel, stereo_from_camera_info

__all__ = ['GraspEstimate', 'GraspFit', 'HeldView', 'MarkerConfig', 'MarkerDetections',
           'NeedleEstimate', 'NeedleTracker', 'PerceptionResult', 'StereoModel',
           'StereoPerception', 'TrackerConfig', 'detect_markers', 'estimate_grasp',
           'needle_prior', 'stereo_from_camera_info']
