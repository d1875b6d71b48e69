"""
Geometry of an ideal throw: the needle circle through an entry/exit marker pair.

A needle driven without tearing tissue turns about its own arc centre, so its tip runs along a
fixed circle of the needle's radius. For a marker pair that circle lies in the plane containing
the entry, the exit and the pair's surface normal, passes through both markers, and has its
centre above the surface on the perpendicular bisector of the entry-exit chord.

:class:`ThrowArc` gives the needle pose along that motion as a function of one angle ``alpha``:
``T_world_needle(alpha) = [R0 Rz(alpha), C]``. With the needle frame of
:mod:`sim_bridge.common.needle` (tip leads about ``-z``), the tip sits at polar angle
``(pi - arc) + alpha`` of the base frame ``R0``; *decreasing* ``alpha`` drives the needle
forwards (tip from entry towards exit, then the tail through).

Base frame ``R0`` (columns): ``x`` = unit chord entry -> exit, ``y`` = minus the in-plane
normal (pointing from the circle centre down towards the tissue), ``z = x cross y``.
World frame, metres, radians.
"""

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.scene.phantom import MarkerPair


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class ThrowArc:
    """
    Ideal needle motion through a marker pair.

    Parameters
    ----------
    pair : sim_bridge.scene.phantom.MarkerPair
        Entry/exit markers (world frame).
    needle : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.

    Attributes
    ----------
    centre : ndarray, shape (3,)
        Circle centre (m), world frame.
    R0 : ndarray, shape (3, 3)
        Base orientation of the needle frame (``alpha = 0``).
    alpha_entry, alpha_exit : float
        ``alpha`` (rad) with the tip at the entry and at the exit marker.
    alpha_tail_entry, alpha_through : float
        ``alpha`` (rad) with the tail at the entry, and at the exit (needle pulled through).
    depth : float
        Deepest point of the circle below the chord midpoint (m).

    """

    def __init__(self, pair: 'MarkerPair', needle: 'NeedleGeometry') -> None:
        entry = np.asarray(pair.entry, dtype=float)
        exit_ = np.asarray(pair.exit, dtype=float)
        chord = exit_ - entry
        c = float(np.linalg.norm(chord))
        R = needle.radius
        if not 0.0 < c < 2.0 * R:
            raise ValueError(f'marker pair {pair.name}: entry-exit distance {c * 1e3:.2f} mm '
                             f'must be in (0, {2e3 * R:.2f}) mm for this needle')
        u = chord / c
        n = np.asarray(pair.normal, dtype=float)
        n = n - np.dot(n, u) * u
        norm = np.linalg.norm(n)
        if norm < 1e-9:
            raise ValueError(f'marker pair {pair.name}: the surface normal is parallel to '
                             f'the entry-exit chord')
        n /= norm
        h = math.sqrt(R * R - 0.25 * c * c)
        self.pair = pair
        self.needle = needle
        self.chord = c
        self.centre = 0.5 * (entry + exit_) + h * n
        y = -n
        self.R0 = np.column_stack([u, y, np.cross(u, y)])
        tip0 = math.pi - needle.arc
        phi_entry = math.atan2(h, -0.5 * c)
        phi_exit = math.atan2(h, 0.5 * c)
        self.alpha_entry = phi_entry - tip0
        self.alpha_exit = phi_exit - tip0
        self.alpha_tail_entry = phi_entry - math.pi
        self.alpha_through = phi_exit - math.pi
        self.depth = R - h

    @property
    def inside_angle(self) -> float:
        """Angle (rad) of the circle inside the tissue: ``2 asin(chord / 2R)``."""
        return 2.0 * math.asin(0.5 * self.chord / self.needle.radius)

    @property
    def plane_normal(self) -> np.ndarray:
        """Unit normal (world) of the needle plane; the needle turns about its negative."""
        return self.R0[:, 2].copy()

    def rotation(self, alpha: float) -> np.ndarray:
        """
        Needle orientation at ``alpha``.

        Parameters
        ----------
        alpha : float
            Rotation (rad) about the needle's ``z`` from the base frame.

        Returns
        -------
        ndarray, shape (3, 3)
            ``R_world_needle``.

        """
        return self.R0 @ _rot_z(alpha)

    def T_world_needle(self, alpha: float) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """
        Needle pose at ``alpha``.

        Parameters
        ----------
        alpha : float
            Rotation (rad) about the needle's ``z``; decreasing drives the needle forwards.

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_world_needle``.

        """
        T = np.eye(4)
        T[:3, :3] = self.rotation(alpha)
        T[:3, 3] = self.centre
        return T

    def alpha_for_s_at_entry(self, s: float) -> float:
        """
        ``alpha`` (rad) at which the needle point of arc parameter ``s`` is at the entry.

        Parameters
        ----------
        s : float
            Arc parameter (0 tail, 1 tip).

        Returns
        -------
        float

        """
        return self.alpha_tail_entry + s * self.needle.arc

    def alpha_for_s_at_exit(self, s: float) -> float:
        """
        ``alpha`` (rad) at which the needle point of arc parameter ``s`` is at the exit.

        Parameters
        ----------
        s : float
            Arc parameter (0 tail, 1 tip).

        Returns
        -------
        float

        """
        return self.alpha_through + s * self.needle.arc
