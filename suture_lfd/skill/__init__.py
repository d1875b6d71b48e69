"""
Throw skills: the DMPs of subtasks ii and iv learnt on the needle trajectory, and their methods.

- :mod:`~suture_lfd.skill.throw_skill`: :class:`ThrowSkill` (one pose DMP per learnt subtask,
  planned onto another entry/exit pair), :func:`learn_skill` and the skill's file format.
- :mod:`~suture_lfd.skill.method`: how a DMP is learnt and anchored (:data:`METHODS`:
  ``paper``, ``pair_frame``).
- :mod:`~suture_lfd.skill.training`: what a skill is learnt from (:class:`TrainingData`).
- :mod:`~suture_lfd.skill.executor`: the executor that runs a skill's throw on the simulator.

Frames: ``world``; poses are 7-vectors ``(x, y, z, qx, qy, qz, qw)`` or 4x4; metres, radians,
seconds.
"""

from suture_lfd.skill.method import ANCHORS, METHODS, Method, get_method
from suture_lfd.skill.throw_skill import (
    SKILL_FORMAT,
    SKILL_FORMAT_VERSION,
    ThrowSkill,
    default_needle,
    learn_skill,
)
from suture_lfd.skill.training import (
    TASKS,
    PairGeometry,
    TrainingData,
    training_data,
    training_data_from_demonstration,
)

__all__ = ['ANCHORS', 'METHODS', 'SKILL_FORMAT', 'SKILL_FORMAT_VERSION', 'TASKS', 'Method',
           'PairGeometry', 'ThrowSkill', 'TrainingData', 'default_needle', 'get_method',
           'learn_skill', 'training_data', 'training_data_from_demonstration']
