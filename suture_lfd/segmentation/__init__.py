"""
Segmentation of a demonstration into the five suturing subtasks of the seed paper.

- :mod:`~suture_lfd.segmentation.keypoints`: each tool's motions and rests from its velocity
  (:func:`velocity_keypoints`).
- :mod:`~suture_lfd.segmentation.segmenter`: the subtasks cut from the motions with the grasp
  signals (:func:`segment_demonstration`).

What the segmenter hands the executor is a segment file
(:mod:`suture_lfd.demos.segment_file`). Times in s, positions in m, quaternions (x, y, z, w).
"""

from suture_lfd.segmentation.keypoints import (
    Segment,
    SegmentationConfig,
    activity,
    angular_velocity,
    velocity_keypoints,
)
from suture_lfd.segmentation.segmenter import (
    SUBTASKS,
    DemoRecord,
    Segmentation,
    segment_demonstration,
)

__all__ = ['SUBTASKS', 'DemoRecord', 'Segment', 'Segmentation', 'SegmentationConfig', 'activity',
           'angular_velocity', 'segment_demonstration', 'velocity_keypoints']
