"""
Surface shapes of the generated suture phantoms and the geometry of wound lines.

Phantom frame: ``x`` along the pad's length (the wound direction), ``y`` across it, ``z`` up;
the origin is on the top surface at the pad centre. Lengths are metres.

- :func:`synthetic_height`: the flat synthetic pad (top at ``z = 0``).
- :func:`scanned_height`: a curved, irregular pad like an MRI scan of a moulded suture pad:
  a crown across the wound, a saddle along it, a slight twist, seeded low bumps and rolled
  edges, shifted so the wound centre lies at ``z = 0``.
- :class:`WoundLine`: a smooth wound curve in the x-y plane (spline through control points),
  with arc-length lookup and the slit region around it.
"""

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import make_interp_spline
from sim_bridge.common.validation import check_positive


@dataclass(frozen=True)
class ScannedShape:
    """
    Shape parameters of the generated "scanned" pad (all heights in metres).

    Attributes
    ----------
    crown : float
        Drop of the surface from the wound line to the long edges (convex across the wound).
    sag : float
        Rise of the surface from the centre to the short ends (saddle along the wound).
    twist : float
        Height of a ``u * v`` twist term at the corners.
    bump_count : int
        Number of seeded Gaussian bumps and dents.
    bump_height : float
        Largest bump amplitude.
    bump_sigma : float
        Typical bump width (standard deviation, m); each bump draws 0.6-1.4 times this.
    edge_width : float
        Width (m) of the rolled border.
    edge_drop : float
        Drop of the surface at the very border.

    """

    crown: float = 0.003
    sag: float = 0.0015
    twist: float = 0.0005
    bump_count: int = 8
    bump_height: float = 0.0005
    bump_sigma: float = 0.004
    edge_width: float = 0.004
    edge_drop: float = 0.0015

    def __post_init__(self) -> None:
        if self.bump_count < 0:
            raise ValueError(f'shape bump_count must be >= 0, got {self.bump_count}')
        for name in ('bump_sigma', 'edge_width'):
            check_positive(getattr(self, name), f'shape {name} (m)')


def synthetic_height(xy: np.ndarray, size: Sequence[float]) -> np.ndarray:
    """
    Top surface of the flat synthetic pad (``z = 0`` everywhere).

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Positions (m) in the phantom frame.
    size : tuple of float
        ``(length, width, thickness)`` (m); unused except for the signature shared with
        :func:`scanned_height`.

    Returns
    -------
    ndarray, shape (...)
        Heights (m).

    """
    del size
    xy = np.asarray(xy, dtype=float)
    return np.zeros(xy.shape[:-1])


def _raw_scanned(x: np.ndarray, y: np.ndarray, size: Sequence[float], shape: 'ScannedShape',
                 bumps: np.ndarray) -> np.ndarray:
    length, width = size[0], size[1]
    u = 2.0 * x / length
    v = 2.0 * y / width
    z = -shape.crown * v * v + shape.sag * u * u + shape.twist * u * v
    for cx, cy, amp, sig in bumps:
        z = z + amp * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * sig * sig))
    edge = np.minimum(0.5 * length - np.abs(x), 0.5 * width - np.abs(y))
    roll = np.clip(1.0 - edge / shape.edge_width, 0.0, 1.0)
    return z - shape.edge_drop * roll * roll


def scanned_bumps(size: Sequence[float], shape: 'ScannedShape', seed: int) -> np.ndarray:
    """
    Seeded bumps of the scanned pad.

    Parameters
    ----------
    size : tuple of float
        ``(length, width, thickness)`` (m).
    shape : ScannedShape
        Shape parameters.
    seed : int
        Seed of the generator (the same seed always gives the same pad).

    Returns
    -------
    ndarray, shape (bump_count, 4)
        Rows ``(x, y, amplitude, sigma)`` (m).

    """
    rng = np.random.default_rng(seed)
    n = shape.bump_count
    cx = rng.uniform(-0.45, 0.45, n) * size[0]
    cy = rng.uniform(-0.45, 0.45, n) * size[1]
    amp = rng.uniform(-1.0, 1.0, n) * shape.bump_height
    sig = rng.uniform(0.6, 1.4, n) * shape.bump_sigma
    return np.column_stack([cx, cy, amp, sig])


def scanned_height(xy: ArrayLike, size: Sequence[float], shape: 'ScannedShape', seed: int,
                   origin_xy: Sequence[float] | np.ndarray = (0.0, 0.0)) -> np.ndarray:
    """
    Top surface of the generated "scanned" pad.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Positions (m) in the phantom frame.
    size : tuple of float
        ``(length, width, thickness)`` (m).
    shape : ScannedShape
        Shape parameters.
    seed : int
        Bump seed.
    origin_xy : sequence of float or ndarray, shape (2,)
        Position whose height is shifted to ``z = 0`` (the wound centre).

    Returns
    -------
    ndarray, shape (...)
        Heights (m).

    """
    xy = np.asarray(xy, dtype=float)
    bumps = scanned_bumps(size, shape, seed)
    z = _raw_scanned(xy[..., 0], xy[..., 1], size, shape, bumps)
    z0 = _raw_scanned(np.float64(origin_xy[0]), np.float64(origin_xy[1]), size, shape, bumps)
    return z - z0


class WoundLine:
    """
    Smooth wound curve in the phantom's x-y plane.

    Parameters
    ----------
    control_points : array_like, shape (k, 2)
        Points (m) the curve passes through, in order (k >= 2). Two points give a straight
        segment; more give an interpolating spline (cubic for k >= 4).
    samples : int
        Number of dense samples kept for lookups.

    """

    def __init__(self, control_points: ArrayLike, samples: int = 400) -> None:
        pts = np.asarray(control_points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError(f'wound line needs at least two (x, y) points, got shape '
                             f'{pts.shape}')
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        if np.any(seg <= 0.0):
            raise ValueError('wound line control points must be distinct')
        u = np.concatenate([[0.0], np.cumsum(seg)])
        u /= u[-1]
        k = min(3, len(pts) - 1)
        spline = make_interp_spline(u, pts, k=k)
        dense = spline(np.linspace(0.0, 1.0, samples))
        d = np.linalg.norm(np.diff(dense, axis=0), axis=1)
        self.points = dense
        self.arclength = np.concatenate([[0.0], np.cumsum(d)])
        self.length = float(self.arclength[-1])
        self.straight = len(pts) == 2

    def point(self, s: float) -> np.ndarray:
        """
        Point at arc length ``s`` (m) from the start, clamped to the line.

        Parameters
        ----------
        s : float
            Arc length (m).

        Returns
        -------
        ndarray, shape (2,)
            Position (m).

        """
        s = float(np.clip(s, 0.0, self.length))
        return np.array([np.interp(s, self.arclength, self.points[:, 0]),
                         np.interp(s, self.arclength, self.points[:, 1])])

    def tangent(self, s: float) -> np.ndarray:
        """
        Return the unit tangent (start to end) at arc length ``s`` (m).

        Parameters
        ----------
        s : float
            Arc length (m).

        Returns
        -------
        ndarray, shape (2,)
            Unit vector.

        """
        h = max(1e-4, 1e-3 * self.length)
        a = self.point(max(0.0, s - h))
        b = self.point(min(self.length, s + h))
        d = b - a
        return d / np.linalg.norm(d)

    def left(self, s: float) -> np.ndarray:
        """
        Return the unit normal left of the tangent (``z x tangent``) at arc length ``s``.

        Parameters
        ----------
        s : float
            Arc length (m).

        Returns
        -------
        ndarray, shape (2,)
            Unit vector.

        """
        t = self.tangent(s)
        return np.array([-t[1], t[0]])

    def slit_mask(self, xy: ArrayLike, half_width: float) -> np.ndarray:
        """
        Tell which x-y positions lie in the slit around the curve.

        The slit is the band within ``half_width`` of the curve, cut square at its end points.

        Parameters
        ----------
        xy : array_like, shape (n, 2)
            Positions (m).
        half_width : float
            Half the slit width (m).

        Returns
        -------
        ndarray of bool, shape (n,)

        """
        p = np.asarray(xy, dtype=float)
        a = self.points[:-1]
        d = self.points[1:] - a
        L2 = np.einsum('ij,ij->i', d, d)
        mask = np.zeros(len(p), dtype=bool)
        for start in range(0, len(a), 64):
            aa = a[start:start + 64]
            dd = d[start:start + 64]
            ll = L2[start:start + 64]
            rel = p[:, None, :] - aa[None, :, :]
            t = np.einsum('nkj,kj->nk', rel, dd) / ll
            tc = np.clip(t, 0.0, 1.0)
            perp = rel - tc[..., None] * dd[None, :, :]
            dist = np.linalg.norm(perp, axis=-1)
            ok = dist <= half_width
            if start == 0:
                ok[:, 0] &= t[:, 0] >= 0.0
            if start + 64 >= len(a):
                ok[:, -1] &= t[:, -1] <= 1.0
            mask |= ok.any(axis=1)
        return mask


def breakpoints(lo: float, hi: float, spacing: float, extra: Iterable[float] = ()) -> np.ndarray:
    """
    Sorted grid coordinates from ``lo`` to ``hi`` at about ``spacing``, plus extra values.

    Parameters
    ----------
    lo, hi : float
        Range (m).
    spacing : float
        Target spacing (m).
    extra : iterable of float
        Additional coordinates (kept when inside the range).

    Returns
    -------
    ndarray
        Increasing coordinates (m), duplicates closer than 1 um removed.

    """
    n = max(1, int(math.ceil((hi - lo) / spacing)))
    xs = np.concatenate([np.linspace(lo, hi, n + 1),
                         [e for e in extra if lo < e < hi]])
    xs = np.sort(xs)
    keep = np.concatenate([[True], np.diff(xs) > 1e-6])
    return xs[keep]
