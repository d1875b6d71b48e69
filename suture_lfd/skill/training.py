"""
What a throw skill is learnt from: the needle trajectories of subtasks ii and iv and the pair.

Frames: ``world``; metres, seconds, quaternions (x, y, z, w).
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from sim_bridge.common.validation import check_array
from sim_bridge.common.vocabulary import TASKS
from suture_lfd.planning.suturing_frames import suture_frame
from suture_lfd.planning.throw_geometry import ThrowArc

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.scene.markers import MarkerPair
    from suture_lfd.demos.demonstration import Demonstration
    from suture_lfd.demos.segment_file import SegmentFile
    from suture_lfd.segmentation import Segmentation


@dataclass(frozen=True, eq=False)
class PairGeometry:
    """
    An entry/exit pair as the skill needs it (``world``, metres).

    Attributes
    ----------
    name : str
        Pair name.
    entry, exit : ndarray, shape (3,)
        Marker centres.
    normal : ndarray, shape (3,)
        Outward surface normal (unit).

    """

    name: str
    entry: np.ndarray
    exit: np.ndarray
    normal: np.ndarray

    @classmethod
    def of(cls, pair: Any) -> 'PairGeometry':
        """Return the geometry of anything with ``name``, ``entry``, ``exit``, ``normal``."""
        if isinstance(pair, cls):
            return pair
        return cls(str(getattr(pair, 'name', '')),
                   check_array(pair.entry, 'pair entry', shape=(3,)).copy(),
                   check_array(pair.exit, 'pair exit', shape=(3,)).copy(),
                   check_array(pair.normal, 'pair normal', shape=(3,)).copy())

    @property
    def frame(self) -> np.ndarray:
        """Suture frame ``T_world_suture`` (4, 4)."""
        return suture_frame(self.entry, self.exit, self.normal)

    def anchor(self, which: str) -> np.ndarray:
        """Suture-frame axes with the origin at ``'midpoint'``, ``'entry'`` or ``'exit'``."""
        T = self.frame
        if which != 'midpoint':
            T[:3, 3] = getattr(self, which)
        return T

    def arc_anchor(self, which: str, needle: 'NeedleGeometry') -> np.ndarray:
        """
        Needle pose ``T_world_needle`` (4, 4) with the tip at the ``'entry'`` or ``'exit'`` marker.

        The needle lies on its circle through both markers, in the plane of the markers and
        the surface normal, centre above the surface, turning tip first from entry to exit
        (:class:`suture_lfd.planning.throw_geometry.ThrowArc`): the pose an ideal throw passes
        through.

        Parameters
        ----------
        which : {'entry', 'exit'}
            Marker.
        needle : sim_bridge.common.needle.NeedleGeometry
            Needle (radius, arc).

        Raises
        ------
        ValueError
            If the markers are not closer than the needle's diameter.

        """
        arc = ThrowArc(cast('MarkerPair', self), needle)
        alpha = {'entry': arc.alpha_entry, 'exit': arc.alpha_exit}[which]
        return arc.T_world_needle(alpha)


@dataclass(frozen=True, eq=False)
class TrainingData:
    """
    What a skill is learnt from: the needle trajectories of ii and iv and the pair.

    Attributes
    ----------
    pair : PairGeometry
        Demonstrated pair.
    needle : dict of str to tuple
        ``'ii'``, ``'iv'`` -> ``(T (n,), P (n, 3), Q (n, 4))``: times (s), needle positions (m)
        and quaternions (x, y, z, w) in ``world``.
    timing : dict of str to tuple of float
        Subtask ``'i'`` .. ``'v'`` -> ``(start, end)`` times of the demonstration, s.
    source : str
        Where the data came from (file name or description).

    """

    pair: PairGeometry
    needle: dict
    timing: dict = field(default_factory=dict)
    source: str = ''


def training_data_from_demonstration(demo: 'Demonstration', segmentation: 'Segmentation',
                                     source: str = '') -> TrainingData:
    """
    Cut the needle trajectories of ii and iv out of a segmented demonstration.

    Parameters
    ----------
    demo : suture_lfd.demos.demonstration.Demonstration
        The record (needle ground truth in ``world``).
    segmentation : suture_lfd.segmentation.Segmentation
        Its five subtasks.
    source : str
        Description for messages and reports.

    Returns
    -------
    TrainingData

    """
    needle = {}
    for task in TASKS:
        seg = segmentation[task]
        cut = slice(seg.start_index, seg.end_index + 1)
        T = demo.t[cut]
        if T.size < 6:
            raise ValueError(f'{source or "demonstration"}: subtask {task} has {T.size} samples; '
                             'at least 6 are needed to learn it')
        needle[task] = (T.copy(), demo.needle_pose[cut, :3].copy(),
                        demo.needle_pose[cut, 3:].copy())
    timing = {s.name: (float(s.start_time), float(s.end_time)) for s in segmentation.subtasks}
    pair = PairGeometry(demo.pair, demo.entry, demo.exit, demo.normal)
    return TrainingData(pair, needle, timing, source)


def training_data(source: 'TrainingData | SegmentFile | str | Path') -> TrainingData:
    """
    Return the :class:`TrainingData` held by a segment file (or pass TrainingData through).

    Parameters
    ----------
    source : TrainingData, suture_lfd.demos.segment_file.SegmentFile, str or Path
        Learning input (a path is read with ``SegmentFile.load``).

    Returns
    -------
    TrainingData

    """
    if isinstance(source, TrainingData):
        return source
    from suture_lfd.demos.segment_file import SUBTASK_NAMES, SegmentFile

    if isinstance(source, (str, Path)):
        source = SegmentFile.load(source)
    if not isinstance(source, SegmentFile):
        raise ValueError(f'cannot learn a skill from a {type(source).__name__}; give a segment '
                         'file or TrainingData')
    needle = {}
    for task in TASKS:
        t, poses = source.needle(task)
        needle[task] = (np.asarray(t, dtype=float), np.asarray(poses[:, :3], dtype=float),
                        np.asarray(poses[:, 3:], dtype=float))
    pair = PairGeometry(source.pair, source.entry, source.exit, source.normal)
    timing = {name: source.times(name) for name in SUBTASK_NAMES}
    return TrainingData(pair, needle, timing, source.source)
