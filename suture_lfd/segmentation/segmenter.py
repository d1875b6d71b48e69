"""
Velocity-based segmentation of a demonstration into the five suturing subtasks.

Each arm's motions are its motion keypoints (:mod:`suture_lfd.segmentation.keypoints`).

Subtasks (seed paper, after Schwaner et al. 2021), cut with the grasp signals:

- i: PSM2 picks the needle and brings its tip to the entry: the PSM2 motions before ii.
- ii: PSM2 inserts the needle to the exit: the PSM2 motions before PSM1 grasps the needle, from
  the one in which the needle tip went into the tissue for the last time before that grasp
  (from ``surface_depth`` to deeper than ``entered_depth`` below the pair's surface, entry
  marker and normal), or the last one if the tip never went that deep: a person who
  pauses during the insertion makes it of several motions, and the insertion starts where
  the tip was still at the surface, however many motions follow it in the tissue or once
  the tip is out of the exit.
- iii: PSM1 regrasps: from PSM1's first motion after ii to the moment PSM2 releases the needle.
- iv: PSM1 extracts the needle: PSM1's motions after PSM2 released it, before PSM2 grasps again.
- v: hand-over to PSM2 and move on: from the first motion after iv to the last motion.

Times in s, positions in m, quaternions (x, y, z, w).
"""

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from sim_bridge.common.geometry import (
    quaternion_rotate,
)
from sim_bridge.common.vocabulary import SUBTASKS as SUBTASK_NAMES
from suture_lfd.segmentation.keypoints import (
    Segment,
    SegmentationConfig,
    nearest_index,
    velocity_keypoints,
)

#: Each subtask of :data:`sim_bridge.common.vocabulary.SUBTASKS` with the arm that does it and
#: what it does: ``(name, arm, description)``.
SUBTASKS = tuple(zip(SUBTASK_NAMES, ('PSM2', 'PSM2', 'PSM1', 'PSM1', 'PSM2'), (
    'pick the needle and bring its tip to the entry point',
    'insert the needle through the tissue to the exit point',
    'regrasp the needle with PSM1',
    'extract the needle, completing the throw',
    'hand the needle over to PSM2 and move to the next initial pose',
), strict=True))


@runtime_checkable
class DemoRecord(Protocol):
    """
    What the segmenter reads of a demonstration.

    :class:`suture_lfd.demos.demonstration.Demonstration` has these fields; the segmenter
    depends on them only, not on the module that records demonstrations.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times (s).
    psm1_pose, psm2_pose, needle_pose : ndarray, shape (n, 7)
        Tool-tip and needle poses ``(x, y, z, qx, qy, qz, qw)`` in ``world`` (m).
    psm1_jaw, psm2_jaw : ndarray, shape (n,)
        Jaw angles (rad).
    psm1_holds, psm2_holds : ndarray of bool, shape (n,)
        Whether each arm holds the needle.
    entry, normal : ndarray, shape (3,)
        The pair's entry marker (m) and surface normal in ``world``.

    """

    # read-only members: a frozen dataclass (the Demonstration) meets them
    @property
    def t(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def psm1_pose(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def psm2_pose(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def psm1_jaw(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def psm2_jaw(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def needle_pose(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def psm1_holds(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def psm2_holds(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def entry(self) -> np.ndarray:
        """See the class docstring."""

    @property
    def normal(self) -> np.ndarray:
        """See the class docstring."""

    def validate(self) -> object:
        """Raise ``ValueError`` naming the first inconsistent field."""



@dataclass(frozen=True)
class Segmentation:
    """
    The five subtasks of one demonstration, in order.

    Attributes
    ----------
    subtasks : tuple of Segment
        Subtasks i .. v.
    psm1_motions, psm2_motions : tuple of Segment
        The motion keypoints found for each arm.

    """

    subtasks: tuple
    psm1_motions: tuple = ()
    psm2_motions: tuple = ()

    def __getitem__(self, name: str) -> Segment:
        """Return the subtask called ``name`` (``'i'`` .. ``'v'``)."""
        for subtask in self.subtasks:
            if subtask.name == name:
                return subtask
        raise KeyError(f'no subtask {name!r}; expected one of {[s.name for s in self.subtasks]}')

    def boundaries(self) -> np.ndarray:
        """
        Return the start and end times of the subtasks.

        Returns
        -------
        ndarray, shape (5, 2)
            ``[start_time, end_time]`` per subtask, s.

        """
        return np.array([[s.start_time, s.end_time] for s in self.subtasks])


def _grasp(holds: np.ndarray, jaw: np.ndarray, closed: float) -> np.ndarray:
    return holds if holds.any() else jaw < closed


def _edge(flags: np.ndarray, T: np.ndarray, after: float, rising: bool, name: str,
          meaning: str) -> float:
    """Return the first time after ``after`` where ``flags`` rises (or falls)."""
    change = np.flatnonzero(np.diff(flags.astype(np.int8)) == (1 if rising else -1)) + 1
    change = change[T[change] > after]
    if change.size == 0:
        raise ValueError(f'{name} never {"becomes true" if rising else "becomes false"} after '
                         f't = {after:.3f} s: {meaning}')
    return float(T[change[0]])


def _tip_depths(demo: DemoRecord, config: SegmentationConfig) -> np.ndarray:
    """Depth (m) of the needle tip below the pair's surface plane at each sample (< 0 above)."""
    pose = demo.needle_pose
    tip = pose[:, :3] + quaternion_rotate(pose[:, 3:], config.needle.tip)
    return -((tip - demo.entry) @ np.asarray(demo.normal, float))


def _insertion_start(inserting: list[Segment], T: np.ndarray, depth: np.ndarray,
                     t_regrasp: float, config: SegmentationConfig) -> int:
    """
    Index in ``inserting`` (PSM2's motions before the regrasp) of the insertion's first motion.

    The tip went in where it was last at ``config.surface_depth`` or above before it was last
    deeper than ``config.entered_depth`` (before ``t_regrasp``); the first motion is the one
    under way then, or the next one (the last one when the tip never went that deep).
    """
    deep = np.flatnonzero((T <= t_regrasp) & (depth > config.entered_depth))
    if deep.size == 0:
        return len(inserting) - 1
    surface = np.flatnonzero(depth[:deep[-1]] <= config.surface_depth)
    t_enter = T[surface[-1] + 1] if surface.size else T[0]
    going = [k for k, m in enumerate(inserting) if m.end_time > t_enter]
    return going[0] if going else len(inserting) - 1


def segment_demonstration(demo: DemoRecord,
                          config: SegmentationConfig | None = None) -> Segmentation:
    """
    Cut one demonstration into the five suturing subtasks.

    Parameters
    ----------
    demo : DemoRecord
        The record (tool poses, grasp flags or jaw angles).
    config : SegmentationConfig, optional
        Detector parameters.

    Returns
    -------
    Segmentation
        Subtasks i .. v with sample indices and times, plus each arm's motions.

    Raises
    ------
    ValueError
        If a grasp event or a motion a subtask needs is missing (named in the message).

    """
    if not isinstance(demo, DemoRecord):
        raise ValueError(f'demo must be a Demonstration, got {type(demo).__name__}')
    config = SegmentationConfig() if config is None else config
    demo.validate()
    T = demo.t
    m1 = velocity_keypoints(T, demo.psm1_pose[:, :3], demo.psm1_pose[:, 3:], config)
    m2 = velocity_keypoints(T, demo.psm2_pose[:, :3], demo.psm2_pose[:, 3:], config)
    h1 = _grasp(demo.psm1_holds, demo.psm1_jaw, config.jaw_closed_rad)
    h2 = _grasp(demo.psm2_holds, demo.psm2_jaw, config.jaw_closed_rad)
    t_first = float(T[0]) - 1.0
    t_psm2_grasp = float(T[0]) if h2[0] else _edge(
        h2, T, t_first, True, 'psm2_holds', 'PSM2 never picks up the needle (subtask i)')
    t_regrasp = _edge(h1, T, t_psm2_grasp, True, 'psm1_holds',
                      'PSM1 never grasps the needle (subtask iii)')
    t_release = _edge(h2, T, t_regrasp, False, 'psm2_holds',
                      'PSM2 never releases the needle to PSM1 (subtask iii)')
    t_handover = _edge(h2, T, t_release, True, 'psm2_holds',
                       'PSM2 never takes the needle back (subtask v)')

    inserting = [m for m in m2 if m.end_time <= t_regrasp + 1e-9]
    if not inserting:
        raise ValueError('no PSM2 motion before PSM1 grasps the needle: no insertion '
                         '(subtask ii) found')
    first = _insertion_start(inserting, T, _tip_depths(demo, config), t_regrasp, config)
    ii = Segment('motion', inserting[first].start_index, inserting[-1].end_index,
                 inserting[first].start_time, inserting[-1].end_time)
    approach = inserting[:first]
    i_start = approach[0] if approach else None
    i_end = approach[-1] if approach else None
    regrasp = [m for m in m1 if ii.end_time <= m.start_time < t_release]
    # PSM1's extraction starts as PSM2 lets go: the onset a filtered speed puts on it may fall
    # before the release, even before PSM1's own grasp, and a subject who barely stops on the
    # needle makes one motion of the last approach and the extraction; so a PSM1 motion after
    # the insertion that is still running at the release counts (subtask iv starts at the
    # release at the earliest)
    extract = [m for m in m1 if ii.end_time <= m.start_time and m.end_time > t_release
               and m.end_time <= t_handover + 1e-9]
    if not extract:
        raise ValueError('no PSM1 motion between PSM2 releasing the needle and taking it back: '
                         'no extraction (subtask iv) found')
    last_iv = extract[-1]
    later = sorted((m for m in m1 + m2 if m.start_time >= last_iv.end_time),
                   key=lambda m: m.start_time)
    if not later:
        raise ValueError('no motion after the extraction: no hand-over (subtask v) found')
    last_motion = max(later, key=lambda m: m.end_time)

    def make(k: int, start_time: float, end_time: float) -> Segment:
        return Segment(SUBTASKS[k][0], nearest_index(T, start_time),
                       nearest_index(T, end_time), float(start_time), float(end_time))

    subtasks = (
        make(0, i_start.start_time if i_start else T[0],
             i_end.end_time if i_end else ii.start_time),
        make(1, ii.start_time, ii.end_time),
        make(2, regrasp[0].start_time if regrasp else t_regrasp, t_release),
        make(3, max(extract[0].start_time, t_release), last_iv.end_time),
        make(4, later[0].start_time, last_motion.end_time),
    )
    return Segmentation(subtasks, tuple(m1), tuple(m2))
