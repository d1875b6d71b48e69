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
import math
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
    # plain floats: a few hundred samples, one or two punctures, on every throw's plan
    raw = np.einsum('kij,j->ki', poses[:, :3, :3], needle.point_at(1.0)) + poses[:, :3, 3]
    entry_depth = ((raw - np.asarray(entry, dtype=float)) @ n).tolist()
    exit_depth = ((raw - np.asarray(exit_, dtype=float)) @ n).tolist()
    tips, rots, origins = raw.tolist(), poses[:, :3, :3].tolist(), poses[:, :3, 3].tolist()
    nx, ny, nz = n.tolist()
    radius, arc = needle.radius, needle.arc
    mid = math.pi - 0.5 * arc
    known = [np.asarray(p, dtype=float).tolist() for p in punctures]
    ox = oy = oz = 0.0
    prev: tuple[list[float], float, float] | None = None
    shifts = np.zeros((len(poses), 3))
    for k in range(len(poses)):
        lift = ox * nx + oy * ny + oz * nz
        tip = [tips[k][0] + ox, tips[k][1] + oy, tips[k][2] + oz]
        below_entry, below_exit = entry_depth[k] + lift, exit_depth[k] + lift
        if prev is None:
            if not known and below_entry < 0.0:  # punctured straight above, as lowered
                known.append([tip[0] - below_entry * nx, tip[1] - below_entry * ny,
                              tip[2] - below_entry * nz])
        else:
            was, was_entry, was_exit = prev
            u = None
            if was_entry > 0.0 >= below_entry:
                u = was_entry / (was_entry - below_entry)
            elif was_exit < 0.0 <= below_exit:
                u = -was_exit / (below_exit - was_exit)
            if u is not None:
                known.append([was[i] + u * (tip[i] - was[i]) for i in range(3)])
        if known and k > 0:
            (r00, r01, _), (r10, r11, _), (r20, r21, _) = rots[k]
            t0, t1, t2 = origins[k][0] + ox, origins[k][1] + oy, origins[k][2] + oz
            sx = sy = sz = 0.0
            m = 0
            for p in known:
                d0, d1, d2 = p[0] - t0, p[1] - t1, p[2] - t2
                phi = math.atan2(r01 * d0 + r11 * d1 + r21 * d2, r00 * d0 + r10 * d1 + r20 * d2)
                s = 0.5 - (math.fmod(phi - mid + 3.0 * math.pi, 2.0 * math.pi) - math.pi) / arc
                if 0.0 <= s <= 1.0:  # the wire occupies it
                    c, sn = radius * math.cos(phi), radius * math.sin(phi)
                    sx += d0 - (r00 * c + r01 * sn)
                    sy += d1 - (r10 * c + r11 * sn)
                    sz += d2 - (r20 * c + r21 * sn)
                    m += 1
            if m:
                sx, sy, sz = sx / m, sy / m, sz / m
                most = speed * float(times[k] - times[k - 1])
                size = math.sqrt(sx * sx + sy * sy + sz * sz)
                if size > most:
                    sx, sy, sz = sx * most / size, sy * most / size, sz * most / size
                ox, oy, oz = ox + sx, oy + sy, oz + sz
                tip = [tip[0] + sx, tip[1] + sy, tip[2] + sz]
                lift = ox * nx + oy * ny + oz * nz
                below_entry, below_exit = entry_depth[k] + lift, exit_depth[k] + lift
        shifts[k] = ox, oy, oz
        prev = (tip, below_entry, below_exit)
    poses[:, :3, 3] += shifts
    return poses, [np.array(p) for p in known]
