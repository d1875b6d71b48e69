"""
Velocity-based segmentation of a demonstration into the five suturing subtasks.

Motion keypoints (after Iturrate et al. 2017, as the seed paper's preprocessing): the tool's
activity ``|v| + k |omega|`` is low-pass filtered (zero-phase Butterworth), a motion starts
where it exceeds ``threshold * peak`` and lasts until it falls below
``threshold * hysteresis * peak``; motions shorter than ``min_motion_s`` are dropped and rests
shorter than ``min_rest_s`` are bridged. Because a smooth movement leaves rest gently, the
onset (and offset) is extrapolated from the flank: between the levels ``a`` and ``4a`` of the
peak the speed of a minimum-jerk-like movement grows as ``(t - t0)^2``, so ``sqrt`` of the
speed is linear in time and is extended back to zero.

Subtasks (seed paper, after Schwaner et al. 2021), cut with the grasp signals:

i    PSM2 picks the needle and brings its tip to the entry: the PSM2 motions before ii.
ii   PSM2 inserts the needle to the exit: the PSM2 motions before PSM1 grasps the needle, from
     the one in which the needle tip went into the tissue for the last time before that grasp
     (from ``surface_depth`` to deeper than ``entered_depth`` below the pair's surface, entry
     marker and normal), or the last one if the tip never went that deep: a person who
     pauses during the insertion makes it of several motions, and the insertion starts where
     the tip was still at the surface, however many motions follow it in the tissue or once
     the tip is out of the exit.
iii  PSM1 regrasps: from PSM1's first motion after ii to the moment PSM2 releases the needle.
iv   PSM1 extracts the needle: PSM1's motions after PSM2 released it, before PSM2 grasps again.
v    hand-over to PSM2 and move on: from the first motion after iv to the last motion.

Times in s, positions in m, quaternions (x, y, z, w).
"""

from dataclasses import dataclass, field
import math

import numpy as np
from scipy.signal import butter, sosfiltfilt
from sim_bridge.common.geometry import (
    quaternion_conjugate,
    quaternion_product,
    quaternion_rotate,
    quaternion_sign_continuous,
    rotvec_from_quaternion,
)
from sim_bridge.common.needle import NeedleGeometry
from sim_bridge.common.validation import (
    check_array,
    check_positive,
    check_quaternions,
    check_times,
)
from suture_lfd.demos.demonstration import Demonstration

SUBTASKS = (
    ('i', 'PSM2', 'pick the needle and bring its tip to the entry point'),
    ('ii', 'PSM2', 'insert the needle through the tissue to the exit point'),
    ('iii', 'PSM1', 'regrasp the needle with PSM1'),
    ('iv', 'PSM1', 'extract the needle, completing the throw'),
    ('v', 'PSM2', 'hand the needle over to PSM2 and move to the next initial pose'),
)


@dataclass(frozen=True)
class SegmentationConfig:
    """
    Parameters of the velocity-based keypoint detector.

    Attributes
    ----------
    cutoff_hz : float
        Cut-off of the zero-phase low-pass filter on the activity, Hz.
    threshold : float
        A motion starts where the filtered activity exceeds this fraction of its peak.
    hysteresis : float
        ... and continues while it stays above ``threshold * hysteresis`` of the peak.
    onset_level : float
        Lower level ``a`` (fraction of the peak) of the flank used to extrapolate onsets and
        offsets; the upper level is ``4 a``. Raised to ``noise_factor`` times the rest level.
    noise_factor : float
        Multiple of the median activity at rest kept clear of by the flank levels.
    min_motion_s : float
        Shorter motions are dropped, s.
    min_rest_s : float
        Shorter rests between motions are bridged, s.
    angular_weight_m : float
        Weight of the angular speed in the activity, m/rad (``|v| + k |omega|``, m/s).
    jaw_closed_rad : float
        Jaw angle below which an arm counts as holding the needle when the recording has no
        grasp flags (all false), rad.
    entered_depth : float
        Depth of the needle tip below the pair's surface (m) from which the tip counts as
        inserted (subtask ii then starts where it went in). The scripted cohort brings the tip
        to 0.1 mm at the entry; 0.5 mm is five times that.
    surface_depth : float
        Depth (m) down to which the tip counts as at the surface, looking back for where it
        went in: twice the cohort's 0.1 mm, below ``entered_depth`` (a hysteresis).
    needle : NeedleGeometry
        The needle whose tip is followed (the demonstration records its pose only).

    """

    cutoff_hz: float = 5.0
    threshold: float = 0.1
    hysteresis: float = 0.5
    onset_level: float = 0.05
    noise_factor: float = 3.0
    min_motion_s: float = 0.2
    min_rest_s: float = 0.1
    angular_weight_m: float = 0.01
    jaw_closed_rad: float = 0.1
    entered_depth: float = 0.0005
    surface_depth: float = 0.0002
    needle: NeedleGeometry = field(default_factory=NeedleGeometry)

    def __post_init__(self):
        for name in ('cutoff_hz', 'threshold', 'hysteresis', 'onset_level', 'noise_factor'):
            check_positive(getattr(self, name), f'SegmentationConfig.{name}')
        if self.threshold >= 1.0 or self.hysteresis > 1.0 or self.onset_level >= 0.25:
            raise ValueError('SegmentationConfig needs threshold < 1, hysteresis <= 1 and '
                             f'onset_level < 0.25, got {self.threshold}, {self.hysteresis}, '
                             f'{self.onset_level}')
        for name in ('min_motion_s', 'min_rest_s', 'angular_weight_m', 'jaw_closed_rad',
                     'entered_depth', 'surface_depth'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'SegmentationConfig.{name} must be >= 0, got {value!r}')
        if self.surface_depth > self.entered_depth:
            raise ValueError('SegmentationConfig.surface_depth must be <= entered_depth, got '
                             f'{self.surface_depth} > {self.entered_depth}')
        if not isinstance(self.needle, NeedleGeometry):
            raise ValueError('SegmentationConfig.needle must be a NeedleGeometry, got '
                             f'{type(self.needle).__name__}')


@dataclass(frozen=True)
class Segment:
    """
    A time interval of a demonstration.

    Attributes
    ----------
    name : str
        Subtask (``'i'`` .. ``'v'``) or ``'motion'``.
    start_index, end_index : int
        First and last sample (inclusive).
    start_time, end_time : float
        Start and end, s (estimated onset/offset; may fall between samples).

    """

    name: str
    start_index: int
    end_index: int
    start_time: float
    end_time: float

    @property
    def duration(self):
        """float: ``end_time - start_time``, s."""
        return self.end_time - self.start_time


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

    def __getitem__(self, name):
        """Return the subtask called ``name`` (``'i'`` .. ``'v'``)."""
        for subtask in self.subtasks:
            if subtask.name == name:
                return subtask
        raise KeyError(f'no subtask {name!r}; expected one of {[s.name for s in self.subtasks]}')

    def boundaries(self):
        """
        Return the start and end times of the subtasks.

        Returns
        -------
        ndarray, shape (5, 2)
            ``[start_time, end_time]`` per subtask, s.

        """
        return np.array([[s.start_time, s.end_time] for s in self.subtasks])


def angular_velocity(T, Q):
    """
    Return the angular velocity of an orientation trajectory (frame of the quaternions).

    Parameters
    ----------
    T : array_like, shape (n,)
        Strictly increasing times, s.
    Q : array_like, shape (n, 4)
        Unit quaternions (x, y, z, w); sign flips allowed.

    Returns
    -------
    ndarray, shape (n, 3)
        ``omega``, rad/s (interval rates averaged onto the samples).

    """
    T = check_times(T, 'T')
    Q = quaternion_sign_continuous(check_quaternions(check_array(Q, 'Q', shape=(T.size, 4)), 'Q'))
    turns = rotvec_from_quaternion(quaternion_product(Q[1:], quaternion_conjugate(Q[:-1])))
    rates = turns / np.diff(T)[:, None]
    out = np.empty((T.size, 3))
    out[0], out[-1] = rates[0], rates[-1]
    out[1:-1] = 0.5 * (rates[1:] + rates[:-1])
    return out


def _low_pass(T, X, cutoff_hz):
    """Zero-phase low-pass of the columns of X sampled at T (resampled to a uniform grid)."""
    dt = float(np.median(np.diff(T)))
    grid = np.arange(T[0], T[-1] + 0.5 * dt, dt)
    uniform = np.column_stack([np.interp(grid, T, x) for x in X.T])
    if cutoff_hz < 0.5 / dt and grid.size > 9:
        sos = butter(2, cutoff_hz, fs=1.0 / dt, output='sos')
        uniform = sosfiltfilt(sos, uniform, axis=0, padlen=min(grid.size - 1, 12))
    return np.column_stack([np.interp(T, grid, u) for u in uniform.T])


def activity(T, P, Q=None, config=None):
    """
    Return the tool activity ``|v| + k |omega|`` from low-pass filtered velocities.

    The velocity vectors are filtered before their norms are taken, so zero-mean tracking
    noise averages out instead of adding a positive floor.

    Parameters
    ----------
    T : array_like, shape (n,)
        Strictly increasing times, s.
    P : array_like, shape (n, 3)
        Positions, m.
    Q : array_like, shape (n, 4), optional
        Orientations (x, y, z, w); adds the weighted angular speed.
    config : SegmentationConfig, optional
        Filter cut-off and angular weight.

    Returns
    -------
    ndarray, shape (n,)
        Activity, m/s (non-negative).

    """
    config = SegmentationConfig() if config is None else config
    T = check_times(T, 'T', min_points=3)
    P = check_array(P, 'P', shape=(T.size, 3))
    rates = np.gradient(P, T, axis=0)
    if Q is not None:
        rates = np.hstack((rates, angular_velocity(T, Q)))
    rates = _low_pass(T, rates, config.cutoff_hz)
    out = np.linalg.norm(rates[:, :3], axis=1)
    if Q is not None:
        out += config.angular_weight_m * np.linalg.norm(rates[:, 3:], axis=1)
    return out


def _runs(mask):
    """Return (starts, ends) inclusive index pairs of the True runs of a boolean vector."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1


def _crossing(T, a, i, j, level):
    """Return the time where ``a`` crosses ``level`` between samples i and j (linear)."""
    if a[j] == a[i]:
        return float(T[j])
    u = (level - a[i]) / (a[j] - a[i])
    return float(T[i] + min(max(u, 0.0), 1.0) * (T[j] - T[i]))


def _flank_time(T, a, start, outer, outward, low, high):
    """
    Return the extrapolated zero-activity time of one flank of a motion.

    ``start`` is where the motion was detected, ``outer`` the farthest sample the flank may
    reach (the previous or next motion, or the end of the record) and ``outward`` -1 for an
    onset, +1 for an offset. ``sqrt(activity)`` is taken as linear in time between the
    crossings of ``low`` and ``high`` and extended to zero.
    """
    inward = -outward
    last = a.size - 1
    k = start
    while a[k] < low and 0 < k < last:          # into the motion, up to the low level
        k += inward
    while a[k] >= low:                          # out of it, down below the low level
        if k == outer:
            return float(T[outer])
        k += outward
    k_low = k
    t_low = _crossing(T, a, k_low, k_low + inward, low)
    k = k_low + inward
    while a[k] < high:                          # back in, up to the high level
        if not 0 < k < last:
            return t_low
        k += inward
    t_high = _crossing(T, a, k - inward, k, high)
    root_low, root_high = math.sqrt(low), math.sqrt(high)
    t_zero = t_low - (t_high - t_low) * root_low / (root_high - root_low)
    bound_a, bound_b = sorted((float(T[outer]), t_low))
    return min(max(t_zero, bound_a), bound_b)


def _nearest_index(T, t):
    k = int(np.searchsorted(T, t))
    if k >= T.size:
        return T.size - 1
    if k > 0 and t - T[k - 1] <= T[k] - t:
        return k - 1
    return k


def velocity_keypoints(T, P, Q=None, config=None):
    """
    Return the motions of one tool: onsets and offsets from its filtered activity.

    Parameters
    ----------
    T : array_like, shape (n,)
        Strictly increasing times, s.
    P : array_like, shape (n, 3)
        Tool positions, m.
    Q : array_like, shape (n, 4), optional
        Tool orientations (x, y, z, w); rotations in place count as motion.
    config : SegmentationConfig, optional
        Detector parameters.

    Returns
    -------
    list of Segment
        Motions in time order (``name = 'motion'``); empty if the tool never moves.

    """
    config = SegmentationConfig() if config is None else config
    T = check_times(T, 'T', min_points=3)
    a = activity(T, P, Q, config)
    peak = float(a.max())
    if peak <= 0.0:
        return []
    high = config.threshold * peak
    low = high * config.hysteresis
    above = a >= low
    starts, ends = _runs(above)
    keep = [k for k in range(starts.size) if a[starts[k]:ends[k] + 1].max() > high]
    starts, ends = starts[keep], ends[keep]
    rest = a[~above]
    noise = float(np.median(rest)) if rest.size else 0.0
    level = min(max(config.onset_level, config.noise_factor * noise / peak), 0.2)
    flank_low, flank_high = level * peak, 4.0 * level * peak
    spans = []
    for k, (s, e) in enumerate(zip(starts, ends)):
        before = ends[k - 1] if k else 0
        after = starts[k + 1] if k + 1 < starts.size else T.size - 1
        spans.append([_flank_time(T, a, s, before, -1, flank_low, flank_high),
                      _flank_time(T, a, e, after, +1, flank_low, flank_high)])
    merged = []
    for t0, t1 in spans:
        if merged and t0 - merged[-1][1] < config.min_rest_s:
            merged[-1][1] = max(merged[-1][1], t1)
        else:
            merged.append([t0, t1])
    return [Segment('motion', _nearest_index(T, t0), _nearest_index(T, t1), t0, t1)
            for t0, t1 in merged if t1 - t0 >= config.min_motion_s]


def _grasp(holds, jaw, closed):
    return holds if holds.any() else jaw < closed


def _edge(flags, T, after, rising, name, meaning):
    """Return the first time after ``after`` where ``flags`` rises (or falls)."""
    change = np.flatnonzero(np.diff(flags.astype(np.int8)) == (1 if rising else -1)) + 1
    change = change[T[change] > after]
    if change.size == 0:
        raise ValueError(f'{name} never {"becomes true" if rising else "becomes false"} after '
                         f't = {after:.3f} s: {meaning}')
    return float(T[change[0]])


def _tip_depths(demo, config):
    """Depth (m) of the needle tip below the pair's surface plane at each sample (< 0 above)."""
    pose = demo.needle_pose
    tip = pose[:, :3] + quaternion_rotate(pose[:, 3:], config.needle.tip)
    return -((tip - demo.entry) @ np.asarray(demo.normal, float))


def _insertion_start(inserting, T, depth, t_regrasp, config):
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


def segment_demonstration(demo, config=None):
    """
    Cut one demonstration into the five suturing subtasks.

    Parameters
    ----------
    demo : Demonstration
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
    if not isinstance(demo, Demonstration):
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

    def make(k, start_time, end_time):
        return Segment(SUBTASKS[k][0], _nearest_index(T, start_time),
                       _nearest_index(T, end_time), float(start_time), float(end_time))

    subtasks = (
        make(0, i_start.start_time if i_start else T[0],
             i_end.end_time if i_end else ii.start_time),
        make(1, ii.start_time, ii.end_time),
        make(2, regrasp[0].start_time if regrasp else t_regrasp, t_release),
        make(3, max(extract[0].start_time, t_release), last_iv.end_time),
        make(4, later[0].start_time, last_motion.end_time),
    )
    return Segmentation(subtasks, tuple(m1), tuple(m2))
