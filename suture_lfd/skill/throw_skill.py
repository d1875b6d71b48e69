"""
Throw skills: the DMPs of subtasks ii and iv learnt on the needle trajectory, and their methods.

A :class:`ThrowSkill` holds one :class:`~suture_lfd.dmp.PoseDmp` per learnt subtask (ii:
insertion with PSM2, iv: extraction with PSM1), learnt from the **needle** pose of one
demonstration, and the demonstrated entry/exit pair. :meth:`ThrowSkill.plan` turns it into
needle trajectories for another pair. How the DMP is learnt and where its start and goal go on
the new pair is a :class:`Method`, registered by name in :data:`METHODS`:

``paper`` (the seed paper, Sec. II-III)
    Position DMP + quaternion DMP with LWR, hyper-parameters of Table I (``config/dmp.yaml``),
    learnt on the needle trajectory in ``world`` coordinates. The paper finds "the desired
    start and goal states" of a new pair from the ground truth of the needle and of the entry
    and exit points: here the needle pose that has the tip at the new **entry** marker on the
    needle's circle through the new markers (:class:`suture_lfd.planning.throw_geometry.ThrowArc`)
    is the insertion's start, the one with the tip at the new **exit** marker its goal, each with
    the subject's own demonstrated offset from the corresponding pose on the demonstrated pair; the
    extraction starts where the insertion ended and its goal is carried with the pair's suture
    frame (anchors ``'insertion_arc'``). Carried rigidly with the pair's midpoint instead
    (anchors ``'midpoint'``), an insertion learnt on the synthetic phantom's 8 mm pairs starts
    and ends 2 mm off the markers of the scanned phantom's 12 mm pairs, and the other way
    round.
``pair_frame`` (an improvement)
    The same DMPs learnt in a frame of the demonstrated pair: per subtask the needle pose on
    the pair's needle circle with the tip at the marker the subtask starts from (frame
    ``'arc'``), start and goal placed as ``paper`` places them. The per-axis scaling
    ``(g - y0)`` then acts along axes that turn with the pair and with the needle's circle
    through it: on markers further apart the needle circle sits lower and the tip meets the
    surface at another angle, which in ``world`` coordinates rotates the whole motion and
    rescales the forcing term of every axis differently (the extraction then sweeps the
    needle sideways through its punctures). Its weights are fitted by least squares over all
    basis functions instead of LWR (:attr:`Method.regression`): the extraction's pull, a
    short movement at its end, then reaches its goal.

Frames: ``world``; suture frames as in :mod:`suture_lfd.planning.suturing_frames`. Poses are
7-vectors ``(x, y, z, qx, qy, qz, qw)`` or 4x4 ``T_world_needle``; metres, radians, seconds.

The methods are defined in :mod:`suture_lfd.skill.method`, what a skill is learnt from in
:mod:`suture_lfd.skill.training`, the executor in :mod:`suture_lfd.skill.executor`.
"""

from collections.abc import Mapping
from dataclasses import asdict, replace
import functools
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.archive import load_archive, save_archive
from sim_bridge.common.configfile import ConfigError, dataclass_from_mapping
from sim_bridge.common.geometry import pose_from_transform, transform_from_pose
from sim_bridge.common.validation import check_array
from suture_lfd.demos.resampling import resample_poses
from suture_lfd.dmp import DmpParams, PoseDmp, PositionDmp, QuaternionDmp, load_dmp_params
from suture_lfd.planning.suturing_frames import (
    poses_from_frame,
    poses_in_frame,
    transfer_pose,
)
from suture_lfd.skill.method import Method, get_method
from suture_lfd.skill.training import (
    TASKS,
    PairGeometry,
    training_data,
)

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry

__all__ = ['SKILL_FORMAT', 'SKILL_FORMAT_VERSION', 'ThrowSkill', 'default_needle', 'learn_skill']

# Which marker each end of a learnt subtask is anchored to with anchors 'arc': the insertion
# runs from the tip at the entry to the tip out of the exit; the extraction pulls the needle
# on from there, the same turn whatever the distance between the markers.
_ARC_ANCHORS = {'ii': ('entry', 'exit'), 'iv': ('exit', 'exit')}
SKILL_FORMAT = 'suture_lfd.skill'
SKILL_FORMAT_VERSION = 1


def _params_for(params: Any, task: str) -> DmpParams:
    if params is None:
        return load_dmp_params(task=task)
    if isinstance(params, DmpParams):
        return params
    if isinstance(params, dict) and task in params:
        value = params[task]
        return value if isinstance(value, DmpParams) else dataclass_from_mapping(
            DmpParams, value, source='params', prefix=task)
    raise ValueError(f"params must be None, a DmpParams or a dict with 'ii' and 'iv', "
                     f'got {type(params).__name__}')


def _dmp_frame(method: Method, pair: PairGeometry, task: str,
               needle: 'NeedleGeometry | None' = None) -> np.ndarray | None:
    """``T_world_dmp`` (4, 4) of a task's DMP coordinates on a pair, or None for ``world``."""
    if method.frame == 'world':
        return None
    if method.frame == 'suture':
        return pair.frame
    return pair.arc_anchor(_ARC_ANCHORS[task][0], default_needle() if needle is None else needle)


def _to_frame(method: Method, pair: PairGeometry, P: np.ndarray, Q: np.ndarray, task: str = 'ii',
              needle: 'NeedleGeometry | None' = None) -> tuple[np.ndarray, np.ndarray]:
    """World needle positions/quaternions -> the method's DMP coordinates."""
    T = _dmp_frame(method, pair, task, needle)
    if T is None:
        return P, Q
    poses = poses_in_frame(T, np.hstack((P, Q)))
    return poses[:, :3], poses[:, 3:]


class ThrowSkill:
    """
    The learnt DMPs of subtasks ii and iv with the demonstrated pair and method.

    Parameters
    ----------
    method : Method
        How it was learnt.
    pair : PairGeometry
        Demonstrated pair.
    dmps : dict of str to PoseDmp
        ``'ii'`` and ``'iv'``, in the method's coordinates.
    timing : dict, optional
        Demonstrated subtask times (s), see :class:`TrainingData`.
    source : str
        Where it was learnt from.

    """

    def __init__(self, method: 'str | Method', pair: Any, dmps: Mapping[str, PoseDmp],
                 timing: Mapping[str, Any] | None = None, source: str = '') -> None:
        self.method = get_method(method)
        self.pair = PairGeometry.of(pair)
        self.dmps = dict(dmps)
        self.timing = dict(timing or {})
        self.source = str(source)

    @property
    def params(self) -> dict[str, DmpParams]:
        """Dict of str to DmpParams: hyper-parameters per task."""
        return {task: dmp.params for task, dmp in self.dmps.items()}

    def duration(self, task: str) -> float:
        """Demonstrated duration (s) of a learnt subtask."""
        duration = self.dmps[task].duration_
        assert duration is not None  # a skill's DMPs are fitted or loaded
        return float(duration)

    def demonstrated(self, task: str, needle: 'NeedleGeometry | None' = None
                     ) -> tuple[np.ndarray, np.ndarray]:
        """
        Return the demonstrated needle start and goal of a task in ``world``.

        ``needle`` (NeedleGeometry, optional): the needle, for frame ``'arc'`` (default the
        scene's).

        Returns
        -------
        start, goal : ndarray, shape (7,)

        """
        dmp = self.dmps[task]
        start, goal = dmp.start_, dmp.goal_
        T = _dmp_frame(self.method, self.pair, task, needle)
        if T is not None:
            start, goal = poses_from_frame(T, start), poses_from_frame(T, goal)
        return start, goal

    def start_goal(self, task: str, pair: Any, needle: 'NeedleGeometry | None' = None
                   ) -> tuple[np.ndarray, np.ndarray]:
        """
        Return the needle start and goal (``world``, 7-vectors) of a task on another pair.

        Parameters
        ----------
        task : {'ii', 'iv'}
            Subtask.
        pair : MarkerPair or PairGeometry
            Target pair.
        needle : sim_bridge.common.needle.NeedleGeometry, optional
            Needle of the throw (anchors ``'arc'``); default the scene's (``config/scene.yaml``).

        Returns
        -------
        start, goal : ndarray, shape (7,)

        """
        pair = PairGeometry.of(pair)
        start, goal = self.demonstrated(task, needle=needle)
        if self.method.anchors == 'arc' or (self.method.anchors == 'insertion_arc'
                                            and task == 'ii'):
            needle = default_needle() if needle is None else needle
            ends = _ARC_ANCHORS[task]
            return cast('tuple[np.ndarray, np.ndarray]', tuple(
                transfer_pose(pose, self.pair.arc_anchor(end, needle),
                              pair.arc_anchor(end, needle))
                for pose, end in zip((start, goal), ends)))
        if self.method.anchors in ('midpoint', 'insertion_arc'):
            return (transfer_pose(start, self.pair.frame, pair.frame),
                    transfer_pose(goal, self.pair.frame, pair.frame))
        return (transfer_pose(start, self.pair.anchor('entry'), pair.anchor('entry')),
                transfer_pose(goal, self.pair.anchor('exit'), pair.anchor('exit')))

    def rollout(self, task: str, pair: Any, start: ArrayLike | None = None,
                goal: ArrayLike | None = None, n_pts: int | None = None,
                needle: 'NeedleGeometry | None' = None,
                targets: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Regenerate a task's needle trajectory on a pair (``world``).

        Parameters
        ----------
        task : {'ii', 'iv'}
            Subtask.
        pair : MarkerPair or PairGeometry
            Target pair.
        start : array_like, shape (7,) or (4, 4), optional
            Needle start (world), e.g. the measured needle pose; default
            :meth:`start_goal`'s start.
        goal : array_like, shape (7,) or (4, 4), optional
            Needle goal (world); default :meth:`start_goal`'s goal.
        n_pts : int, optional
            Samples over the demonstrated duration (Table I's ``N_pts`` by default).
        needle : sim_bridge.common.needle.NeedleGeometry, optional
            Needle of the throw, as :meth:`start_goal`.
        targets : tuple of ndarray, optional
            ``start_goal(task, pair, needle)`` when the caller has it already.

        Returns
        -------
        T : ndarray, shape (n,)
            Times from the start of the subtask, s.
        P : ndarray, shape (n, 3)
            Needle positions, m (``world``).
        Q : ndarray, shape (n, 4)
            Needle quaternions (x, y, z, w), sign-continuous.

        """
        pair = PairGeometry.of(pair)
        s0, g0 = self.start_goal(task, pair, needle=needle) if targets is None else targets
        start = s0 if start is None else _pose7(start, 'start')
        goal = g0 if goal is None else _pose7(goal, 'goal')
        if np.dot(start[3:], s0[3:]) < 0.0:
            start = np.concatenate((start[:3], -start[3:]))
        if np.dot(goal[3:], g0[3:]) < 0.0:
            goal = np.concatenate((goal[:3], -goal[3:]))
        T_frame = _dmp_frame(self.method, pair, task, needle)
        if T_frame is not None:
            start, goal = poses_in_frame(T_frame, start), poses_in_frame(T_frame, goal)
        T, P, Q = self.dmps[task].rollout(start, goal, n_pts=n_pts)
        if T_frame is not None:
            poses = poses_from_frame(T_frame, np.hstack((P, Q)))
            P, Q = poses[:, :3], poses[:, 3:]
        return T, P, Q

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path) -> None:
        """
        Write the skill (method, hyper-parameters, DMP weights, pair) to an ``.npz`` file.

        Parameters
        ----------
        path : str or Path
            Output file (written as given).

        """
        meta = {'method': asdict(self.method), 'pair': self.pair.name, 'timing': self.timing,
                'source': self.source, 'tasks': list(self.dmps),
                'params': {task: asdict(dmp.params) for task, dmp in self.dmps.items()}}
        arrays = {'meta': np.array(json.dumps(meta)), 'pair.entry': self.pair.entry,
                  'pair.exit': self.pair.exit, 'pair.normal': self.pair.normal}
        for task, dmp in self.dmps.items():
            arrays[f'{task}.duration'] = np.array(dmp.duration_)
            for key, value in dmp._arrays().items():
                arrays[f'{task}.{key}'] = value
        save_archive(path, arrays, SKILL_FORMAT, SKILL_FORMAT_VERSION)

    @classmethod
    def load(cls, path: str | Path) -> 'ThrowSkill':
        """
        Read a skill written by :meth:`save`.

        Raises
        ------
        ValueError
            If the file is unreadable, of another format or version, or lacks a key; the
            message names the file and the key.

        """
        arrays = load_archive(path, SKILL_FORMAT, SKILL_FORMAT_VERSION, 'skill file')

        def need(key: str) -> Any:
            if key not in arrays:
                raise ValueError(f'{path}: skill file lacks the key {key!r}')
            return arrays[key]

        try:
            meta = json.loads(str(need('meta')))
            method = Method(**meta['method'])
            tasks, params = meta['tasks'], meta['params']
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: key 'meta' is not a readable skill description "
                             f'({type(exc).__name__}: {exc})') from exc
        dmps = {}
        for task in tasks:
            try:
                task_params = dataclass_from_mapping(DmpParams, params.get(task, {}),
                                                     source=str(path), prefix=f'params.{task}')
            except (ConfigError, AttributeError) as exc:
                raise ValueError(f'{path}: {exc}') from exc
            dmp = PoseDmp(task_params)
            dmp.position = PositionDmp._from_arrays(task_params, arrays, path,
                                                    prefix=f'{task}.position.')
            dmp.orientation = QuaternionDmp._from_arrays(task_params, arrays, path,
                                                         prefix=f'{task}.orientation.')
            dmp.duration_ = float(need(f'{task}.duration'))
            dmps[task] = dmp
        pair = PairGeometry(str(meta.get('pair', '')), need('pair.entry'), need('pair.exit'),
                            need('pair.normal'))
        timing = {k: tuple(v) for k, v in meta.get('timing', {}).items()}
        return cls(method, pair, dmps, timing, meta.get('source', ''))


@functools.cache
def default_needle() -> 'NeedleGeometry':
    """Return the scene's needle geometry (``config/scene.yaml``), read once."""
    from sim_bridge.scene.scene_config import load_scene_config

    return load_scene_config().needle


def _pose7(pose: ArrayLike, name: str) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    if pose.shape == (4, 4):
        return pose_from_transform(pose)
    pose = check_array(pose, name, shape=(7,))
    transform_from_pose(pose)  # validates the quaternion
    return pose


def learn_skill(segment_file: Any, method: 'str | Method' = 'paper', params: Any = None,
                needle: 'NeedleGeometry | None' = None) -> ThrowSkill:
    """
    Learn the DMPs of subtasks ii and iv from one segmented demonstration.

    Parameters
    ----------
    segment_file : suture_lfd.demos.segment_file.SegmentFile, str, Path or TrainingData
        The demonstration's segments (needle trajectories of ii and iv, pair, timing), or the
        path of a segment file.
    method : str or Method
        Name in :data:`METHODS` (``'paper'`` by default).
    params : DmpParams or dict of str to DmpParams, optional
        Hyper-parameters (one for both tasks, or per task); default: ``config/dmp.yaml``.
    needle : sim_bridge.common.needle.NeedleGeometry, optional
        Needle of the demonstrations (frame ``'arc'``); default the scene's.

    Returns
    -------
    ThrowSkill

    """
    method = get_method(method)
    data = training_data(segment_file)
    dmps = {}
    for task in TASKS:
        task_params = replace(_params_for(params, task), regression=method.regression)
        T, P, Q = data.needle[task]
        T, P, Q = resample_poses(T, P, Q, n_pts=task_params.n_pts)
        P, Q = _to_frame(method, data.pair, P, Q, task, needle)
        dmps[task] = PoseDmp(task_params).fit(T - T[0], P, Q)
    return ThrowSkill(method, data.pair, dmps, data.timing, data.source)
