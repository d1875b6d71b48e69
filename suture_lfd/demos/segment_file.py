"""
Segment files: what the segmenter hands the executor from one demonstration.

A :class:`SegmentFile` holds, for one demonstration of one throw:

- where it came from (``source``, ``subject``), the pair (``pair``, ``entry``, ``exit``,
  ``normal`` in ``world``) and the demonstration's time span;
- the five subtasks' timing (start and end, s, simulation time) from
  :func:`suture_lfd.segmentation.segment_demonstration`;
- the needle trajectories of tasks ii (insertion, PSM2) and iv (extraction, PSM1), resampled
  (quintic positions, SLERP orientations, :mod:`suture_lfd.demos.resampling`) to the ``n_pts`` of
  ``config/dmp.yaml`` (Table I: 500 and 100 points): times (s) and 7-vector poses (world);
- the grasps ``T_tool_needle`` (tool tip <- needle, 4x4) of PSM2 at the start of ii and of PSM1
  at the start of iv, measured in the demonstration.

It saves to an ``.npz`` file with a format tag and version; loading checks them and names the
file and key of anything wrong or missing.
"""

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from sim_bridge.common.archive import load_archive, save_archive
from sim_bridge.common.validation import check_array, check_quaternions
from sim_bridge.common.vocabulary import TASKS
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.demos.resampling import resample_poses
from suture_lfd.dmp import load_dmp_params
from suture_lfd.planning.suturing_frames import grasp_transform
from suture_lfd.segmentation import SUBTASKS, Segmentation

FORMAT = 'suture_lfd.segments'  # the files' format tag (kept when the module moved)
FORMAT_VERSION = 1
SUBTASK_NAMES = tuple(name for name, _, _ in SUBTASKS)
_STRINGS = ('source', 'subject', 'pair')


@dataclass(frozen=True, eq=False)
class SegmentFile:
    """
    The segments of one demonstration.

    Attributes
    ----------
    source : str
        Where the demonstration came from (bag path, or a description).
    subject : str
        Demonstrating subject (may be empty).
    pair : str
        Sutured marker pair.
    entry, exit, normal : ndarray, shape (3,)
        Entry and exit marker (m) and the unit surface normal, ``world``.
    demo_span : ndarray, shape (2,)
        First and last time (s) of the demonstration.
    subtask_times : ndarray, shape (5, 2)
        Start and end (s) of subtasks i .. v.
    ii_t, iv_t : ndarray, shape (n,)
        Times (s) of the resampled needle trajectories of tasks ii and iv.
    ii_needle, iv_needle : ndarray, shape (n, 7)
        Needle poses ``(x, y, z, qx, qy, qz, qw)`` in ``world``, sign-continuous quaternions.
    ii_grasp, iv_grasp : ndarray, shape (4, 4)
        ``T_tool_needle`` of PSM2 at the start of ii and of PSM1 at the start of iv.

    """

    source: str
    subject: str
    pair: str
    entry: np.ndarray
    exit: np.ndarray
    normal: np.ndarray
    demo_span: np.ndarray
    subtask_times: np.ndarray
    ii_t: np.ndarray
    ii_needle: np.ndarray
    iv_t: np.ndarray
    iv_needle: np.ndarray
    ii_grasp: np.ndarray
    iv_grasp: np.ndarray

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name in _STRINGS:
                if not isinstance(getattr(self, f.name), str):
                    raise ValueError(f'{f.name} must be a string')
                continue
            object.__setattr__(self, f.name, check_array(getattr(self, f.name), f.name).copy())
        for name in ('entry', 'exit', 'normal'):
            check_array(getattr(self, name), name, shape=(3,))
        check_array(self.demo_span, 'demo_span', shape=(2,))
        times = check_array(self.subtask_times, 'subtask_times', shape=(5, 2))
        if np.any(times[:, 1] < times[:, 0]):
            raise ValueError('subtask_times: every subtask must end after it starts')
        for task in TASKS:
            t = check_array(getattr(self, f'{task}_t'), f'{task}_t', shape=(None,))
            if t.size < 2 or np.any(np.diff(t) <= 0.0):
                raise ValueError(f'{task}_t must hold at least two increasing times')
            pose = check_array(getattr(self, f'{task}_needle'), f'{task}_needle',
                               shape=(t.size, 7))
            check_quaternions(pose[:, 3:], f'{task}_needle orientation', normalise=False)
            grasp = check_array(getattr(self, f'{task}_grasp'), f'{task}_grasp', shape=(4, 4))
            R = grasp[:3, :3]
            if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.abs(grasp[3] - [0, 0, 0, 1]).max():
                raise ValueError(f'{task}_grasp must be a rigid transform')

    def times(self, subtask: str) -> tuple[float, float]:
        """Return ``(start, end)`` (s) of a subtask ``'i'`` .. ``'v'``."""
        if subtask not in SUBTASK_NAMES:
            raise KeyError(f'no subtask {subtask!r}; expected one of {list(SUBTASK_NAMES)}')
        start, end = self.subtask_times[SUBTASK_NAMES.index(subtask)]
        return float(start), float(end)

    def needle(self, task: str) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(t (n,), poses (n, 7))`` of the needle in task ``'ii'`` or ``'iv'``."""
        if task not in TASKS:
            raise KeyError(f"needle trajectories exist for tasks 'ii' and 'iv', not {task!r}")
        return getattr(self, f'{task}_t'), getattr(self, f'{task}_needle')

    def grasp(self, task: str) -> np.ndarray:
        """Return the grasp ``T_tool_needle`` (4, 4) measured in task ``'ii'`` or ``'iv'``."""
        if task not in TASKS:
            raise KeyError(f"grasps exist for tasks 'ii' and 'iv', not {task!r}")
        return getattr(self, f'{task}_grasp')

    @property
    def durations(self) -> dict[str, float]:
        """Durations (s) of the subtasks, by name."""
        return {name: float(e - s) for name, (s, e) in zip(SUBTASK_NAMES, self.subtask_times)}

    def save(self, path: str | Path) -> None:
        """
        Write the segments to an ``.npz`` file (format tag and version included).

        Parameters
        ----------
        path : str or Path
            Output file (written as given).

        """
        arrays = {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}
        save_archive(path, arrays, FORMAT, FORMAT_VERSION)

    @classmethod
    def load(cls, path: str | Path) -> 'SegmentFile':
        """
        Read a segment file written by :meth:`save`.

        Raises
        ------
        ValueError
            If the file is unreadable, not a segment file, of another format version, lacks a
            key or holds invalid data; the message names the file (and the key).

        """
        arrays = load_archive(path, FORMAT, FORMAT_VERSION, 'segment file')
        values: dict[str, Any] = {}
        for f in fields(cls):
            if f.name not in arrays:
                raise ValueError(f'{path}: segment file lacks key {f.name!r}')
            values[f.name] = str(arrays[f.name]) if f.name in _STRINGS else arrays[f.name]
        try:
            return cls(**values)
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from exc


def _grasp_at(demo: Demonstration, arm: str, start: int, end: int) -> np.ndarray:
    holds = demo.psm1_holds if arm == 'PSM1' else demo.psm2_holds
    tools = demo.psm1_pose if arm == 'PSM1' else demo.psm2_pose
    held = np.flatnonzero(holds[start:end + 1])
    if held.size == 0:
        raise ValueError(f'{arm} does not hold the needle between t = {demo.t[start]:.3f} s and '
                         f'{demo.t[end]:.3f} s: no grasp to measure')
    k = start + int(held[0])
    return grasp_transform(tools[k], demo.needle_pose[k])


def make_segment_file(demo: Demonstration, segmentation: Segmentation,
                      dmp_config: str | Path | None = None, source: str = '',
                      subject: str = '') -> SegmentFile:
    """
    Build the segment file of a segmented demonstration.

    Parameters
    ----------
    demo : suture_lfd.demos.demonstration.Demonstration
        The record.
    segmentation : suture_lfd.segmentation.Segmentation
        Its subtasks (from :func:`suture_lfd.segmentation.segment_demonstration`).
    dmp_config : str or Path, optional
        ``dmp.yaml`` giving ``n_pts`` of tasks ii and iv; default the installed one.
    source, subject : str
        Provenance kept in the file.

    Returns
    -------
    SegmentFile

    """
    if not isinstance(demo, Demonstration):
        raise ValueError(f'demo must be a Demonstration, got {type(demo).__name__}')
    if not isinstance(segmentation, Segmentation):
        raise ValueError(f'segmentation must be a Segmentation, got '
                         f'{type(segmentation).__name__}')
    values = {}
    for task, arm in (('ii', 'PSM2'), ('iv', 'PSM1')):
        n_pts = load_dmp_params(dmp_config, task).n_pts
        seg = segmentation[task]
        window = slice(seg.start_index, seg.end_index + 1)
        T = demo.t[window]
        if T.size < 6:
            raise ValueError(f'subtask {task} spans only {T.size} samples; at least 6 are '
                             'needed to resample it')
        pose = demo.needle_pose[window]
        t_new, P, Q = resample_poses(T, pose[:, :3], pose[:, 3:], n_pts=n_pts)
        values[f'{task}_t'] = t_new
        values[f'{task}_needle'] = np.hstack((P, Q))
        values[f'{task}_grasp'] = _grasp_at(demo, arm, seg.start_index, seg.end_index)
    return SegmentFile(
        source=str(source), subject=str(subject), pair=demo.pair, entry=demo.entry,
        exit=demo.exit, normal=demo.normal, demo_span=np.array([demo.t[0], demo.t[-1]]),
        subtask_times=segmentation.boundaries(), **values)
