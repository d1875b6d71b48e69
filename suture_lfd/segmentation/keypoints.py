"""
Motion keypoints of one tool: where it moves and where it rests, from its velocity.

After Iturrate et al. 2017, as the seed paper's preprocessing: the tool's activity
``|v| + k |omega|`` is low-pass filtered (zero-phase Butterworth), a motion starts where it
exceeds ``threshold * peak`` and lasts until it falls below ``threshold * hysteresis * peak``;
motions shorter than ``min_motion_s`` are dropped and rests shorter than ``min_rest_s`` are
bridged. Because a smooth movement leaves rest gently, the onset (and offset) is extrapolated
from the flank: between the levels ``a`` and ``4a`` of the peak the speed of a minimum-jerk-like
movement grows as ``(t - t0)^2``, so ``sqrt`` of the speed is linear in time and is extended back
to zero.

Times in s, positions in m, quaternions (x, y, z, w).
"""

from dataclasses import dataclass, field
import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import butter, sosfiltfilt
from sim_bridge.common.geometry import (
    quaternion_conjugate,
    quaternion_product,
    quaternion_sign_continuous,
    rotvec_from_quaternion,
)
from sim_bridge.common.needle import NeedleGeometry
from sim_bridge.common.validation import (
    FloatArray,
    check_array,
    check_positive,
    check_quaternions,
    check_times,
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

    def __post_init__(self) -> None:
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
    def duration(self) -> float:
        """float: ``end_time - start_time``, s."""
        return self.end_time - self.start_time


def angular_velocity(T: ArrayLike, Q: ArrayLike) -> FloatArray:
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


def _low_pass(T: FloatArray, X: FloatArray, cutoff_hz: float) -> FloatArray:
    """Zero-phase low-pass of the columns of X sampled at T (resampled to a uniform grid)."""
    dt = float(np.median(np.diff(T)))
    grid = np.arange(T[0], T[-1] + 0.5 * dt, dt)
    uniform = np.column_stack([np.interp(grid, T, x) for x in X.T])
    if cutoff_hz < 0.5 / dt and grid.size > 9:
        sos = butter(2, cutoff_hz, fs=1.0 / dt, output='sos')
        uniform = sosfiltfilt(sos, uniform, axis=0, padlen=min(grid.size - 1, 12))
    return np.column_stack([np.interp(T, grid, u) for u in uniform.T])


def activity(T: ArrayLike, P: ArrayLike, Q: ArrayLike | None = None,
             config: SegmentationConfig | None = None) -> FloatArray:
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


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (starts, ends) inclusive index pairs of the True runs of a boolean vector."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1


def _crossing(T: FloatArray, a: FloatArray, i: int, j: int, level: float) -> float:
    """Return the time where ``a`` crosses ``level`` between samples i and j (linear)."""
    if a[j] == a[i]:
        return float(T[j])
    u = (level - a[i]) / (a[j] - a[i])
    return float(T[i] + min(max(u, 0.0), 1.0) * (T[j] - T[i]))


def _flank_time(T: FloatArray, a: FloatArray, start: int, outer: int, outward: int, low: float,
                high: float) -> float:
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


def nearest_index(T: FloatArray, t: float) -> int:
    k = int(np.searchsorted(T, t))
    if k >= T.size:
        return T.size - 1
    if k > 0 and t - T[k - 1] <= T[k] - t:
        return k - 1
    return k


def velocity_keypoints(T: ArrayLike, P: ArrayLike, Q: ArrayLike | None = None,
                       config: SegmentationConfig | None = None) -> list[Segment]:
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
    merged: list[list[float]] = []
    for t0, t1 in spans:
        if merged and t0 - merged[-1][1] < config.min_rest_s:
            merged[-1][1] = max(merged[-1][1], t1)
        else:
            merged.append([t0, t1])
    return [Segment('motion', nearest_index(T, t0), nearest_index(T, t1), t0, t1)
            for t0, t1 in merged if t1 - t0 >= config.min_motion_s]
