"""
Aiming the needle along its own arc inside the tissue, so it pushes the tissue less.

A circular needle cuts a path through the tissue that is its own circle: moved exactly about its
arc centre, the wire stays in the punctures it made; moved otherwise, it presses the tissue
sideways at each puncture it occupies (the tissue realism's lateral resistance,
:mod:`sim_bridge.realism.needle_tissue`, about 1 N per mm off the arc), and that push turns the
needle in the jaw. A DMP rollout reproduces the demonstrated needle motion only approximately,
so its small departures from a pure rotation push the tissue.

:func:`aim_along_arc` corrects a planned needle path (the executor's belief, never the true
needle): walking the samples in order, it notes where the planned tip crosses the pair's surface
(the entry and exit punctures it would make; a tip already below the surface at the first sample
punctured it straight above) and shifts every later pose so that the needle's circle passes
through the punctures it occupies (the least-squares shift per sample, accumulated, so the path
stays continuous, and no faster than ``speed``: the insertion starts with the needle lowered
straight onto the entry, its circle a few tenths of a millimetre off the puncture the tip made,
and the aim takes it there smoothly). What is left is the rollout's rotation about the needle's
own centre, carried through the punctures.

Frames: ``world``; poses 4x4 ``T_world_needle``; metres.
"""

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry


def circle_offsets(T_world_needle: np.ndarray, radius: float, points: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """
    From each point to the nearest point of the needle's circle, and the points' polar angles.

    Parameters
    ----------
    T_world_needle : ndarray, shape (4, 4)
        Needle pose.
    radius : float
        Needle radius (m).
    points : ndarray, shape (n, 3)
        Points (``world``, m).

    Returns
    -------
    offsets : ndarray, shape (n, 3)
        ``point - nearest circle point`` (``world``, m).
    phi : ndarray, shape (n,)
        Polar angles (rad) of the points in the needle frame.

    """
    R, t = T_world_needle[:3, :3], T_world_needle[:3, 3]
    q = (points - t) @ R
    phi = np.arctan2(q[:, 1], q[:, 0])
    on_circle = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.zeros_like(phi)], 1)
    return points - (on_circle @ R.T + t), phi


def aim_along_arc(times: np.ndarray, poses: np.ndarray, needle: 'NeedleGeometry',
                  entry: np.ndarray, exit_: np.ndarray, normal: np.ndarray,
                  punctures: Sequence[np.ndarray] = (), speed: float = 0.0005
                  ) -> tuple[np.ndarray, list[np.ndarray]]:
    """
    Shift planned needle poses so the needle's circle keeps through the punctures it occupies.

    Parameters
    ----------
    times : ndarray, shape (n,)
        Times of the samples (s).
    poses : ndarray, shape (n, 4, 4)
        Planned ``T_world_needle`` samples, in time order.
    needle : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    entry, exit_ : ndarray, shape (3,)
        Entry and exit markers (``world``, m): the surface an inward (outward) tip crossing
        passes is the plane through the entry (exit) marker across ``normal``.
    normal : ndarray, shape (3,)
        Outward unit normal of the pair's surface.
    punctures : sequence of ndarray, shape (3,)
        Punctures made before the first sample (the insertion's, for the extraction).
    speed : float
        Fastest the shift may grow (m/s).

    Returns
    -------
    poses : ndarray, shape (n, 4, 4)
        The aimed poses (the first one unchanged).
    punctures : list of ndarray, shape (3,)
        The punctures known after the last sample.

    """
    poses = np.array(poses, dtype=float)
    n = np.asarray(normal, dtype=float)
    entry, exit_ = np.asarray(entry, dtype=float), np.asarray(exit_, dtype=float)
    tip_local = needle.point_at(1.0)
    known = [np.asarray(p, dtype=float) for p in punctures]
    offset = np.zeros(3)
    prev_tip = None
    for k in range(len(poses)):
        T = poses[k]
        T[:3, 3] += offset
        tip = T[:3, :3] @ tip_local + T[:3, 3]
        below_entry = float((tip - entry) @ n)
        below_exit = float((tip - exit_) @ n)
        if prev_tip is None:
            if not known and below_entry < 0.0:
                known.append(tip - below_entry * n)  # punctured straight above, as lowered
        else:
            was_entry = float((prev_tip - entry) @ n)
            was_exit = float((prev_tip - exit_) @ n)
            if was_entry > 0.0 >= below_entry:
                u = was_entry / (was_entry - below_entry)
                known.append(prev_tip + u * (tip - prev_tip))
            elif was_exit < 0.0 <= below_exit:
                u = -was_exit / (below_exit - was_exit)
                known.append(prev_tip + u * (tip - prev_tip))
        prev_tip = tip
        if not known or k == 0:
            continue
        d, phi = circle_offsets(T, needle.radius, np.asarray(known))
        s = np.asarray(needle.s_of_angle(phi))
        occupied = (s >= 0.0) & (s <= 1.0)
        if occupied.any():
            shift = d[occupied].mean(axis=0)
            most = speed * float(times[k] - times[k - 1])
            size = float(np.linalg.norm(shift))
            if size > most:
                shift *= most / size
            T[:3, 3] += shift
            offset += shift
            prev_tip = prev_tip + shift
    return poses, known
