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
"""

from dataclasses import asdict, dataclass, field, replace
import functools
import json
from pathlib import Path

import numpy as np
from sim_bridge.configfile import ConfigError, dataclass_from_mapping
from sim_bridge.geometry import pose_from_transform, transform_from_pose
from sim_bridge.validation import check_array
from suture_lfd.archive import load_archive, save_archive
from suture_lfd.demos.resampling import resample_poses
from suture_lfd.dmp import DmpParams, PoseDmp, PositionDmp, QuaternionDmp, load_dmp_params
from suture_lfd.dmp.base import REGRESSIONS
from suture_lfd.planning.suturing_frames import (
    poses_from_frame,
    poses_in_frame,
    suture_frame,
    transfer_pose,
)
from suture_lfd.planning.throw_geometry import ThrowArc

TASKS = ('ii', 'iv')
ANCHORS = ('arc', 'insertion_arc', 'midpoint', 'markers')
# Which marker each end of a learnt subtask is anchored to with anchors 'arc': the insertion
# runs from the tip at the entry to the tip out of the exit; the extraction pulls the needle
# on from there, the same turn whatever the distance between the markers.
_ARC_ANCHORS = {'ii': ('entry', 'exit'), 'iv': ('exit', 'exit')}
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
    frame : {'world', 'suture', 'arc'}
        Coordinates the DMPs are learnt and rolled out in: ``'arc'`` is, per subtask, the
        needle pose on the pair's needle circle with the tip at the marker the subtask starts
        from (:meth:`PairGeometry.arc_anchor`; entry for ii, exit for iv), so a pair whose
        markers are further apart turns the needle on its own circle, not the demonstrated
        motion's world axes.
    anchors : {'arc', 'insertion_arc', 'midpoint', 'markers'}
        ``'arc'``: the insertion's start carried with the needle pose that has the tip at the
        entry marker on the needle's circle through the pair, its goal and both ends of the
        extraction with the pose that has the tip at the exit marker
        (:meth:`PairGeometry.arc_anchor`); ``'insertion_arc'``: the insertion as ``'arc'``,
        the extraction as ``'midpoint'`` (its goal, out of the tissue, keeps the demonstrated
        direction from the needle's circle in ``world`` axes, which a ``world`` DMP needs to
        keep the demonstrated shape: its ``(g - y0)`` scaling is per axis); ``'midpoint'``:
        start and goal carried rigidly with the pair's suture frame (origin at the midpoint);
        ``'markers'``: the start carried with a frame at the entry marker, the goal with a
        frame at the exit marker (both with the suture frame's axes). ``'midpoint'`` and
        ``'markers'`` keep the demonstrated needle rotation from start to goal, so on a pair
        whose markers are further apart (or closer) than the demonstrated ones the tip misses
        them (``'midpoint'``) or the needle is dragged sideways through the tissue
        (``'markers'``).
    description : str
        One line for reports.
    regression : {'lwr', 'least_squares'}
        How the DMP weights are fitted (``DmpParams.regression``): ``'lwr'`` as the paper,
        ``'least_squares'`` all basis functions together. Task iv's needle centre rests while
        the needle turns about it and moves only in the last sixth of the subtask, when it is
        pulled clear; LWR's overlapping local averages smooth that pull away and the rollout
        ends short of the goal (1.7 mm on average at ``t = T``); the least-squares fit of the
        same Table I bases keeps it (0.05 mm).

    """

    name: str
    frame: str
    anchors: str
    description: str = ''
    regression: str = 'lwr'

    def __post_init__(self):
        if self.frame not in ('world', 'suture', 'arc'):
            raise ValueError(f"method {self.name}: frame must be 'world', 'suture' or 'arc', "
                             f'got {self.frame!r}')
        if self.regression not in REGRESSIONS:
            raise ValueError(f'method {self.name}: regression must be one of {REGRESSIONS}, '
                             f'got {self.regression!r}')
        if self.anchors not in ANCHORS:
            raise ValueError(f'method {self.name}: anchors must be one of {ANCHORS}, '
                             f'got {self.anchors!r}')


METHODS = {
    'paper': Method('paper', 'world', 'insertion_arc',
                    'seed paper: needle DMPs in world coordinates, start/goal with the tip at '
                    'the entry/exit marker of the new pair'),
    'pair_frame': Method('pair_frame', 'arc', 'arc',
                         'needle DMPs in the frame of the needle circle through the pair, '
                         'start/goal with the tip at the entry/exit marker of the new pair, '
                         'weights fitted by least squares', regression='least_squares'),
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

    def arc_anchor(self, which, needle):
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
        needle : sim_bridge.scene.needle.NeedleGeometry
            Needle (radius, arc).

        Raises
        ------
        ValueError
            If the markers are not closer than the needle's diameter.

        """
        arc = ThrowArc(self, needle)
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


def training_data_from_demonstration(demo, segmentation, source=''):
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


def training_data(source):
    """
    Return the :class:`TrainingData` held by a segment file (or pass TrainingData through).

    Parameters
    ----------
    source : TrainingData, suture_lfd.segmentation.segments.SegmentFile, str or Path
        Learning input (a path is read with ``SegmentFile.load``).

    Returns
    -------
    TrainingData

    """
    if isinstance(source, TrainingData):
        return source
    from suture_lfd.segmentation.segments import SUBTASK_NAMES, SegmentFile

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


def _dmp_frame(method, pair, task, needle=None):
    """``T_world_dmp`` (4, 4) of a task's DMP coordinates on a pair, or None for ``world``."""
    if method.frame == 'world':
        return None
    if method.frame == 'suture':
        return pair.frame
    return pair.arc_anchor(_ARC_ANCHORS[task][0], default_needle() if needle is None else needle)


def _to_frame(method, pair, P, Q, task='ii', needle=None):
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

    def demonstrated(self, task, needle=None):
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

    def start_goal(self, task, pair, needle=None):
        """
        Return the needle start and goal (``world``, 7-vectors) of a task on another pair.

        Parameters
        ----------
        task : {'ii', 'iv'}
            Subtask.
        pair : MarkerPair or PairGeometry
            Target pair.
        needle : sim_bridge.scene.needle.NeedleGeometry, optional
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
            return tuple(transfer_pose(pose, self.pair.arc_anchor(end, needle),
                                       pair.arc_anchor(end, needle))
                         for pose, end in zip((start, goal), ends))
        if self.method.anchors in ('midpoint', 'insertion_arc'):
            return (transfer_pose(start, self.pair.frame, pair.frame),
                    transfer_pose(goal, self.pair.frame, pair.frame))
        return (transfer_pose(start, self.pair.anchor('entry'), pair.anchor('entry')),
                transfer_pose(goal, self.pair.anchor('exit'), pair.anchor('exit')))

    def rollout(self, task, pair, start=None, goal=None, n_pts=None, needle=None):
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
        needle : sim_bridge.scene.needle.NeedleGeometry, optional
            Needle of the throw, as :meth:`start_goal`.

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
        s0, g0 = self.start_goal(task, pair, needle=needle)
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
        arrays = {'meta': np.array(json.dumps(meta)), 'pair.entry': self.pair.entry,
                  'pair.exit': self.pair.exit, 'pair.normal': self.pair.normal}
        for task, dmp in self.dmps.items():
            arrays[f'{task}.duration'] = np.array(dmp.duration_)
            for key, value in dmp._arrays().items():
                arrays[f'{task}.{key}'] = value
        save_archive(path, arrays, SKILL_FORMAT, SKILL_FORMAT_VERSION)

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
        arrays = load_archive(path, SKILL_FORMAT, SKILL_FORMAT_VERSION, 'skill file')

        def need(key):
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
def default_needle():
    """Return the scene's needle geometry (``config/scene.yaml``), read once."""
    from sim_bridge.scene.scene_config import load_scene_config

    return load_scene_config().needle


def _pose7(pose, name):
    pose = np.asarray(pose, dtype=float)
    if pose.shape == (4, 4):
        return pose_from_transform(pose)
    pose = check_array(pose, name, shape=(7,))
    transform_from_pose(pose)  # validates the quaternion
    return pose


def learn_skill(segment_file, method='paper', params=None, needle=None):
    """
    Learn the DMPs of subtasks ii and iv from one segmented demonstration.

    Parameters
    ----------
    segment_file : suture_lfd.segmentation.segments.SegmentFile, str, Path or TrainingData
        The demonstration's segments (needle trajectories of ii and iv, pair, timing), or the
        path of a segment file.
    method : str or Method
        Name in :data:`METHODS` (``'paper'`` by default).
    params : DmpParams or dict of str to DmpParams, optional
        Hyper-parameters (one for both tasks, or per task); default: ``config/dmp.yaml``.
    needle : sim_bridge.scene.needle.NeedleGeometry, optional
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
