"""
Objective scores of one demonstration, from its record (bag) and its segment file.

The measures of the suturing-skill literature the seed paper cites for its future work:

- time: the whole throw and each subtask i .. v (Moorthy et al. 2004; Vedula et al. 2016);
- per instrument (PSM1, PSM2): path length, economy of motion, jerk, velocity peaks, spectral
  arc length, idle time, number of movements (:mod:`suture_lfd.assessment.motion`;
  Moorthy 2004 counts the movements and the path of each hand, Vedula 2016 adds idle time);
- idle time of the whole team: both instruments at rest together;
- inside the tissue (subtasks ii to iv): how far the needle strays from the path it cut, the
  distance from each puncture to the needle's circle while the needle occupies it (the
  simulator's trauma measure, :mod:`sim_bridge.scene.tissue`, recomputed from the recorded needle),
  and the tilt of the needle plane from the plane through the wound's perpendicular suture
  line and the surface normal (Frischknecht et al. 2013 measure the suture's angle to the
  incision);
- entry / exit accuracy: where the needle tip crossed the surface against the entry and exit
  markers (Frischknecht 2013: bite placement);
- grasps: how often each arm closed on the needle, and the regrasps beyond the one grasp a
  throw needs of each arm.

The surface at a marker is the plane through it with the pair's surface normal; a crossing is
where the tip's height over that plane changes sign, interpolated between samples.

Frames: ``world``; lengths in m in the arrays and in mm / deg in the table (``_mm``,
``_deg``), times in s.
"""

from collections.abc import Mapping
from dataclasses import asdict, dataclass
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from sim_bridge.common.geometry import transform_from_pose
from sim_bridge.common.vocabulary import PSMS, SUBTASKS
from suture_lfd.assessment.motion import MotionConfig, motion_metrics, rests, speed_profile

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from suture_lfd.demos.demonstration import Demonstration
    from suture_lfd.demos.segment_file import SegmentFile
    from suture_lfd.segmentation import Segmentation

ARMS = tuple(psm.lower() for psm in PSMS)  # the demonstration's field prefixes
MOTION_FIELDS = ('path_length_m', 'economy', 'rms_jerk', 'log_dimensionless_jerk',
                 'velocity_peaks', 'sparc', 'idle_s', 'movements')


@dataclass(frozen=True)
class Crossing:
    """
    Where the needle tip crossed the surface plane at a marker.

    Attributes
    ----------
    t : float
        Time, s.
    point : ndarray, shape (3,)
        Crossing point, m (``world``).
    error_m : float
        Distance to the marker, m.

    """

    t: float
    point: np.ndarray
    error_m: float


def tip_positions(needle_pose: np.ndarray, needle: 'NeedleGeometry') -> np.ndarray:
    """
    Return the needle tip (n, 3) of needle poses (n, 7), ``world``.

    Parameters
    ----------
    needle_pose : ndarray, shape (n, 7)
        Needle poses ``(x, y, z, qx, qy, qz, qw)``.
    needle : sim_bridge.common.needle.NeedleGeometry
        The needle (the tip in its frame).

    """
    T = transform_from_pose(np.asarray(needle_pose, dtype=float))
    return np.einsum('nij,j->ni', T[:, :3, :3], needle.tip) + T[:, :3, 3]


def surface_crossings(t: np.ndarray, tips: np.ndarray, marker: np.ndarray, normal: np.ndarray,
                      inward: bool) -> list['Crossing']:
    """
    Return every crossing of the surface plane at ``marker`` in one direction.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Times, s.
    tips : ndarray, shape (n, 3)
        Tip positions, m.
    marker : ndarray, shape (3,)
        Marker (a point of the plane), m.
    normal : ndarray, shape (3,)
        Outward unit normal of the surface.
    inward : bool
        The tip going in (height turning from > 0 to <= 0), else coming out.

    Returns
    -------
    list of Crossing
        In time order.

    """
    h = (tips - marker) @ normal
    if inward:
        ks = np.flatnonzero((h[:-1] > 0.0) & (h[1:] <= 0.0)) + 1
    else:
        ks = np.flatnonzero((h[:-1] < 0.0) & (h[1:] >= 0.0)) + 1
    out = []
    for k in ks:
        a, b = h[k - 1], h[k]
        w = a / (a - b) if a != b else 1.0
        point = tips[k - 1] + w * (tips[k] - tips[k - 1])
        point = point - ((point - marker) @ normal) * normal
        out.append(Crossing(float(t[k - 1] + w * (t[k] - t[k - 1])), point,
                            float(np.linalg.norm(point - marker))))
    return out


def arc_deviation(t: np.ndarray, needle_pose: np.ndarray, punctures: list['Crossing'],
                  needle: 'NeedleGeometry', end_time: float) -> tuple[float, float]:
    """
    Return the distance from the punctures to the needle's circle while the needle holds them.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Times, s.
    needle_pose : ndarray, shape (n, 7)
        Needle poses (``world``).
    punctures : list of Crossing
        Punctures, each occupied from its time on.
    needle : sim_bridge.common.needle.NeedleGeometry
    end_time : float
        Last time (s) looked at (the end of the extraction).

    Returns
    -------
    max_m, mean_m : float
        Largest and mean (over the samples with an occupied puncture) of the largest
        puncture-to-circle distance, m; 0 without an occupied puncture.

    """
    T = transform_from_pose(np.asarray(needle_pose, dtype=float))
    R, c = T[:, :3, :3], T[:, :3, 3]
    worst = np.full(len(t), -1.0)
    for puncture in punctures:
        k = (t >= puncture.t) & (t <= end_time)
        if not np.any(k):
            continue
        local = np.einsum('nji,nj->ni', R[k], puncture.point - c[k])  # R^T (p - c)
        s = needle.s_of_angle(np.arctan2(local[:, 1], local[:, 0]))
        held = (s >= 0.0) & (s <= 1.0)
        d = np.where(held, needle.distance_to_circle(local), -1.0)
        worst[k] = np.maximum(worst[k], d)
    held = worst >= 0.0
    if not np.any(held):
        return 0.0, 0.0
    return float(worst[held].max()), float(worst[held].mean())


def plane_tilt_deg(needle_pose: np.ndarray, entry: np.ndarray, exit_: np.ndarray,
                   normal: np.ndarray) -> np.ndarray:
    """
    Return the angles (deg) between the needle plane and the ideal suture plane.

    The ideal plane holds the suture line (entry to exit) and the surface normal; the needle
    plane is the plane of its circle (normal: the needle frame's ``z``).

    Returns
    -------
    ndarray, shape (n,)
        Angles in [0, 90] deg.

    """
    line = np.asarray(exit_, float) - np.asarray(entry, float)
    ideal = np.cross(line, normal)
    ideal = ideal / np.linalg.norm(ideal)
    z = transform_from_pose(np.asarray(needle_pose, dtype=float))[:, :3, 2]
    cos = np.clip(np.abs(z @ ideal), 0.0, 1.0)
    return np.degrees(np.arccos(cos))


def _rising_edges(flags: np.ndarray) -> int:
    flags = np.asarray(flags, bool)
    return int(np.count_nonzero(flags[1:] & ~flags[:-1]) + (1 if flags.size and flags[0] else 0))


def assess_demonstration(demo: 'Demonstration', segments: 'SegmentFile | Segmentation',
                         needle: 'NeedleGeometry | None' = None,
                         config: MotionConfig | None = None) -> dict[str, Any]:
    """
    Return the objective scores of one demonstration.

    Parameters
    ----------
    demo : suture_lfd.demos.demonstration.Demonstration
        The record (read from its bag with :func:`suture_lfd.demo_bag.demonstration_from_bag`).
    segments : suture_lfd.demos.segment_file.SegmentFile or suture_lfd.segmentation.Segmentation
        Its subtasks (a segment file, or the segmenter's result).
    needle : sim_bridge.common.needle.NeedleGeometry, optional
        The needle (default: the scene's).
    config : MotionConfig, optional
        Thresholds of the motion metrics.

    Returns
    -------
    dict
        One flat row (str -> float or int or str): ``pair``, ``task_time_s``,
        ``t_<subtask>_s``, ``<arm>_<motion metric>`` (arms ``psm1``, ``psm2``;
        :data:`MOTION_FIELDS`), ``idle_s`` (both arms resting), ``entry_error_mm``,
        ``exit_error_mm`` (NaN when the tip never crossed there), ``arc_deviation_max_mm``,
        ``arc_deviation_mean_mm``, ``tilt_mean_deg``, ``tilt_max_deg`` (during the insertion),
        ``<arm>_grasps``, ``regrasps``.

    """
    if needle is None:
        from suture_lfd.skill import default_needle

        needle = default_needle()
    config = MotionConfig() if config is None else config
    times = (np.asarray(segments.subtask_times, float) if hasattr(segments, 'subtask_times')
             else segments.boundaries())
    t = demo.t
    row = {'pair': demo.pair, 'task_time_s': float(t[-1] - t[0])}
    for name, (a, b) in zip(SUBTASKS, times):
        row[f't_{name}_s'] = float(b - a)
    poses = {'psm1': demo.psm1_pose, 'psm2': demo.psm2_pose}
    still = np.ones(len(t), bool)
    for arm in ARMS:
        metrics = asdict(motion_metrics(t, poses[arm][:, :3], config))
        for key in MOTION_FIELDS:
            row[f'{arm}_{key}'] = metrics[key]
        grid, speed = speed_profile(t, poses[arm][:, :3], config, config.idle_cutoff_hz)
        if grid.size != still.size:
            speed = np.interp(t, grid, speed)
        still &= speed < config.idle_speed
    dt = float(np.median(np.diff(t)))
    row['idle_s'] = float(sum(b - a for a, b in rests(
        np.arange(len(t)) * dt, (~still).astype(float), 0.5, config.min_idle_s)) * dt)
    # the needle in the tissue: from the start of ii to the end of iv
    t_ii, t_iv_end = float(times[1, 0]), float(times[3, 1])
    tips = tip_positions(demo.needle_pose, needle)
    normal = np.asarray(demo.normal, float)
    # the puncture is the last entry before the insertion ends (a subject may touch down at
    # the end of i, or back out and enter again); the exit the first emergence after it
    t_ii_end = float(times[1, 1])
    entries = [c for c in surface_crossings(t, tips, demo.entry, normal, inward=True)
               if c.t <= t_ii_end]
    entry = entries[-1] if entries else None
    exit_ = None
    if entry is not None:
        exit_ = next((c for c in surface_crossings(t, tips, demo.exit, normal, inward=False)
                      if c.t > entry.t), None)
    row['entries'] = len(entries)
    row['entry_error_mm'] = entry.error_m * 1e3 if entry else float('nan')
    row['exit_error_mm'] = exit_.error_m * 1e3 if exit_ else float('nan')
    punctures = [p for p in (entry, exit_) if p is not None]
    dev_max, dev_mean = arc_deviation(t, demo.needle_pose, punctures, needle, t_iv_end)
    row['arc_deviation_max_mm'] = dev_max * 1e3
    row['arc_deviation_mean_mm'] = dev_mean * 1e3
    inserting = (t >= t_ii) & (t <= float(times[1, 1]))
    tilt = plane_tilt_deg(demo.needle_pose[inserting], demo.entry, demo.exit, normal)
    row['tilt_mean_deg'] = float(tilt.mean()) if tilt.size else float('nan')
    row['tilt_max_deg'] = float(tilt.max()) if tilt.size else float('nan')
    grasps = {'psm1': _rising_edges(demo.psm1_holds), 'psm2': _rising_edges(demo.psm2_holds)}
    for arm in ARMS:
        row[f'{arm}_grasps'] = grasps[arm]
    # a throw needs one grasp of PSM1 (iii) and two of PSM2 (i and the hand-over of v)
    row['regrasps'] = max(0, grasps['psm1'] - 1) + max(0, grasps['psm2'] - 2)
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in row.items()}


def finite(value: object) -> bool:
    """Return whether a table value is a finite number."""
    return isinstance(value, (int, float)) and math.isfinite(value)


def write_score_table(path: str | Path, row: Mapping[str, Any]) -> None:
    """
    Write one demonstration's scores as a two-column CSV table (``score,value``).

    Parameters
    ----------
    path : str or Path
        Output file.
    row : dict
        Scores (:func:`assess_demonstration`, possibly with the verdict's columns).

    """
    import csv

    with open(path, 'w', newline='') as f:
        writer = csv.writer(f, lineterminator='\n')
        writer.writerow(('score', 'value'))
        for key, value in row.items():
            if isinstance(value, float):
                value = '' if math.isnan(value) else repr(round(value, 6))
            writer.writerow((key, value))


def read_score_table(path: str | Path) -> dict[str, Any]:
    """Read a table written by :func:`write_score_table` back into a dict (numbers parsed)."""
    import csv

    out: dict[str, Any] = {}
    with open(path, newline='') as f:
        for rec in csv.DictReader(f):
            value = rec['value']
            try:
                value = int(value) if value.lstrip('-').isdigit() else float(value or 'nan')
            except ValueError:
                pass
            out[rec['score']] = value
    return out


def assess_bag(bag: str | Path, segments: str | Path | None = None, pair: str | None = None,
               needle: 'NeedleGeometry | None' = None,
               config: MotionConfig | None = None) -> dict[str, Any]:
    """
    Score the demonstration recorded in a bag.

    Parameters
    ----------
    bag : str or Path
        Demonstration bag (rosbag2 directory).
    segments : str or Path, optional
        Its segment file; without it the demonstration is segmented here, as the segmenter
        does.
    pair : str, optional
        Pair name when the bag does not say it.
    needle, config
        As :func:`assess_demonstration`.

    Returns
    -------
    dict
        The scores of :func:`assess_demonstration`.

    """
    from suture_lfd.demos.demo_bag import demonstration_from_bag

    demo = demonstration_from_bag(bag, pair=pair)
    seg: 'SegmentFile | Segmentation'
    if segments is None:
        from suture_lfd.segmentation import segment_demonstration

        seg = segment_demonstration(demo)
    else:
        from suture_lfd.demos.segment_file import SegmentFile

        seg = SegmentFile.load(segments)
    return assess_demonstration(demo, seg, needle=needle, config=config)
