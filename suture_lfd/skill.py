"""
Throw skills: the DMPs of subtasks ii and iv learnt on the needle trajectory, and their methods.

A :class:`ThrowSkill` holds one :class:`~suture_lfd.dmp.PoseDmp` per learnt subtask (ii:
insertion with PSM2, iv: extraction with PSM1), learnt from the **needle** pose of one
demonstration, and the demonstrated entry/exit pair. :meth:`ThrowSkill.plan` turns it into
needle trajectories for another pair. How the DMP is learnt and where its start and goal go on
the new pair is a :class:`Method`, registered by name in :data:`METHODS`:

``paper`` (the seed paper, Sec. II-III)
    Position DMP + quaternion DMP with LWR, hyper-parameters of Table I (``config/dmp.yaml``),
    learnt on the needle trajectory in ``world`` coordinates. The needle start and goal of a
    subtask on the new pair are the demonstrated ones carried rigidly from the demonstrated
    pair's suture frame to the new pair's (:func:`suture_lfd.suturing_frames.throw_start_goal`).
``pair_frame`` (an improvement)
    The same DMPs learnt in the demonstrated pair's suture frame, so the per-axis scaling
    ``(g - y0)`` acts along the pair's own axes (across, along the wound, normal) whatever the
    pair's heading; the start is placed relative to the new pair's **entry** marker and the
    goal relative to its **exit** marker, so the goal follows the pair's own geometry (its
    entry-exit distance) instead of the demonstrated pair's midpoint.

Frames: ``world``; suture frames as in :mod:`suture_lfd.suturing_frames`. Poses are 7-vectors
``(x, y, z, qx, qy, qz, qw)`` or 4x4 ``T_world_needle``; metres, radians, seconds.
"""

from dataclasses import asdict, dataclass, field
import json
from pathlib import Path
import zipfile

import numpy as np
from sim_bridge.configfile import ConfigError, dataclass_from_mapping
from suture_lfd.dmp import DmpParams, PoseDmp, PositionDmp, QuaternionDmp, load_dmp_params
from suture_lfd.geometry import pose_from_transform, transform_from_pose
from suture_lfd.resampling import resample_poses
from suture_lfd.suturing_frames import (
    poses_from_frame,
    poses_in_frame,
    suture_frame,
    transfer_pose,
)
from suture_lfd.validation import check_array

TASKS = ('ii', 'iv')
SKILL_FORMAT = 'suture_lfd.skill'
SKILL_FORMAT_VERSION = 1


@dataclass(frozen=True)
class Method:
    """
    How a throw skill is learnt and placed on a new pair.

    Attributes
    ----------
    name : str
        Registry name.
    frame : {'world', 'suture'}
        Coordinates the DMPs are learnt and rolled out in.
    anchors : {'midpoint', 'markers'}
        ``'midpoint'``: start and goal carried rigidly with the pair's suture frame (origin at
        the midpoint); ``'markers'``: the start carried with a frame at the entry marker, the
        goal with a frame at the exit marker (both with the suture frame's axes).
    description : str
        One line for reports.

    """

    name: str
    frame: str
    anchors: str
    description: str = ''

    def __post_init__(self):
        if self.frame not in ('world', 'suture'):
            raise ValueError(f"method {self.name}: frame must be 'world' or 'suture', "
                             f'got {self.frame!r}')
        if self.anchors not in ('midpoint', 'markers'):
            raise ValueError(f"method {self.name}: anchors must be 'midpoint' or 'markers', "
                             f'got {self.anchors!r}')


METHODS = {
    'paper': Method('paper', 'world', 'midpoint',
                    'seed paper: needle DMPs in world coordinates, start/goal carried with the '
                    'suture frame'),
    'pair_frame': Method('pair_frame', 'suture', 'markers',
                         'needle DMPs in the pair frame, start at the entry and goal at the '
                         'exit marker of the new pair'),
}


def get_method(name):
    """
    Return the registered :class:`Method` called ``name``.

    Raises
    ------
    ValueError
        If no method has that name (the message lists the registered ones).

    """
    if isinstance(name, Method):
        return name
    if name not in METHODS:
        raise ValueError(f'unknown skill method {name!r}; expected one of {sorted(METHODS)}')
    return METHODS[name]


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
    def of(cls, pair):
        """Return the geometry of anything with ``name``, ``entry``, ``exit``, ``normal``."""
        if isinstance(pair, cls):
            return pair
        return cls(str(getattr(pair, 'name', '')),
                   check_array(pair.entry, 'pair entry', shape=(3,)).copy(),
                   check_array(pair.exit, 'pair exit', shape=(3,)).copy(),
                   check_array(pair.normal, 'pair normal', shape=(3,)).copy())

    @property
    def frame(self):
        """Suture frame ``T_world_suture`` (4, 4)."""
        return suture_frame(self.entry, self.exit, self.normal)

    def anchor(self, which):
        """Suture-frame axes with the origin at ``'midpoint'``, ``'entry'`` or ``'exit'``."""
        T = self.frame
        if which != 'midpoint':
            T[:3, 3] = getattr(self, which)
        return T


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


def training_data_from_demonstration(demo, segmentation, source=''):
    """
    Cut the needle trajectories of ii and iv out of a segmented demonstration.

    Parameters
    ----------
    demo : suture_lfd.demonstration.Demonstration
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


def training_data(source):
    """
    Return the :class:`TrainingData` held by a segment file (or pass TrainingData through).

    Parameters
    ----------
    source : TrainingData, suture_lfd.segments.SegmentFile, str or Path
        Learning input (a path is read with ``SegmentFile.load``).

    Returns
    -------
    TrainingData

    """
    if isinstance(source, TrainingData):
        return source
    from suture_lfd.segments import SUBTASK_NAMES, SegmentFile

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


def _params_for(params, task):
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


def _to_frame(method, pair, P, Q):
    """World needle positions/quaternions -> the method's DMP coordinates."""
    if method.frame == 'world':
        return P, Q
    poses = poses_in_frame(pair.frame, np.hstack((P, Q)))
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

    def __init__(self, method, pair, dmps, timing=None, source=''):
        self.method = get_method(method)
        self.pair = PairGeometry.of(pair)
        self.dmps = dict(dmps)
        self.timing = dict(timing or {})
        self.source = str(source)

    @property
    def params(self):
        """Dict of str to DmpParams: hyper-parameters per task."""
        return {task: dmp.params for task, dmp in self.dmps.items()}

    def duration(self, task):
        """Demonstrated duration (s) of a learnt subtask."""
        return float(self.dmps[task].duration_)

    def demonstrated(self, task):
        """
        Return the demonstrated needle start and goal of a task in ``world``.

        Returns
        -------
        start, goal : ndarray, shape (7,)

        """
        dmp = self.dmps[task]
        start, goal = dmp.start_, dmp.goal_
        if self.method.frame == 'suture':
            T = self.pair.frame
            start, goal = poses_from_frame(T, start), poses_from_frame(T, goal)
        return start, goal

    def start_goal(self, task, pair):
        """
        Return the needle start and goal (``world``, 7-vectors) of a task on another pair.

        Parameters
        ----------
        task : {'ii', 'iv'}
            Subtask.
        pair : MarkerPair or PairGeometry
            Target pair.

        Returns
        -------
        start, goal : ndarray, shape (7,)

        """
        pair = PairGeometry.of(pair)
        start, goal = self.demonstrated(task)
        if self.method.anchors == 'midpoint':
            return (transfer_pose(start, self.pair.frame, pair.frame),
                    transfer_pose(goal, self.pair.frame, pair.frame))
        return (transfer_pose(start, self.pair.anchor('entry'), pair.anchor('entry')),
                transfer_pose(goal, self.pair.anchor('exit'), pair.anchor('exit')))

    def rollout(self, task, pair, start=None, goal=None, n_pts=None):
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
        s0, g0 = self.start_goal(task, pair)
        start = s0 if start is None else _pose7(start, 'start')
        goal = g0 if goal is None else _pose7(goal, 'goal')
        if np.dot(start[3:], s0[3:]) < 0.0:
            start = np.concatenate((start[:3], -start[3:]))
        if np.dot(goal[3:], g0[3:]) < 0.0:
            goal = np.concatenate((goal[:3], -goal[3:]))
        if self.method.frame == 'suture':
            T_frame = pair.frame
            start, goal = poses_in_frame(T_frame, start), poses_in_frame(T_frame, goal)
        T, P, Q = self.dmps[task].rollout(start, goal, n_pts=n_pts)
        if self.method.frame == 'suture':
            poses = poses_from_frame(T_frame, np.hstack((P, Q)))
            P, Q = poses[:, :3], poses[:, 3:]
        return T, P, Q

    # ------------------------------------------------------------------ files
    def save(self, path):
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
        arrays = {'format': np.array(SKILL_FORMAT),
                  'format_version': np.array(SKILL_FORMAT_VERSION),
                  'meta': np.array(json.dumps(meta)), 'pair.entry': self.pair.entry,
                  'pair.exit': self.pair.exit, 'pair.normal': self.pair.normal}
        for task, dmp in self.dmps.items():
            arrays[f'{task}.duration'] = np.array(dmp.duration_)
            for key, value in dmp._arrays().items():
                arrays[f'{task}.{key}'] = value
        with open(path, 'wb') as handle:
            np.savez(handle, **arrays)

    @classmethod
    def load(cls, path):
        """
        Read a skill written by :meth:`save`.

        Raises
        ------
        ValueError
            If the file is unreadable, of another format or version, or lacks a key; the
            message names the file and the key.

        """
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ValueError(f'{path}: not a readable skill file ({exc})') from exc
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise ValueError(f'{path}: not a skill file (expected an .npz archive)')
        with data:
            arrays = {key: data[key] for key in data.files}

        def need(key):
            if key not in arrays:
                raise ValueError(f'{path}: skill file lacks the key {key!r}')
            return arrays[key]

        if str(need('format')) != SKILL_FORMAT:
            raise ValueError(f'{path}: key \'format\' is {str(arrays["format"])!r}, expected '
                             f'{SKILL_FORMAT!r} (not a skill file)')
        version = int(need('format_version'))
        if version != SKILL_FORMAT_VERSION:
            raise ValueError(f"{path}: key 'format_version' is {version}, expected "
                             f'{SKILL_FORMAT_VERSION}')
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


def _pose7(pose, name):
    pose = np.asarray(pose, dtype=float)
    if pose.shape == (4, 4):
        return pose_from_transform(pose)
    pose = check_array(pose, name, shape=(7,))
    transform_from_pose(pose)  # validates the quaternion
    return pose


def learn_skill(segment_file, method='paper', params=None):
    """
    Learn the DMPs of subtasks ii and iv from one segmented demonstration.

    Parameters
    ----------
    segment_file : suture_lfd.segments.SegmentFile, str, Path or TrainingData
        The demonstration's segments (needle trajectories of ii and iv, pair, timing), or the
        path of a segment file.
    method : str or Method
        Name in :data:`METHODS` (``'paper'`` by default).
    params : DmpParams or dict of str to DmpParams, optional
        Hyper-parameters (one for both tasks, or per task); default: ``config/dmp.yaml``.

    Returns
    -------
    ThrowSkill

    """
    method = get_method(method)
    data = training_data(segment_file)
    dmps = {}
    for task in TASKS:
        task_params = _params_for(params, task)
        T, P, Q = data.needle[task]
        T, P, Q = resample_poses(T, P, Q, n_pts=task_params.n_pts)
        P, Q = _to_frame(method, data.pair, P, Q)
        dmps[task] = PoseDmp(task_params).fit(T - T[0], P, Q)
    return ThrowSkill(method, data.pair, dmps, data.timing, data.source)
