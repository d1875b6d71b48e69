"""
Suture needle and thread geometry: the one place that defines the needle frame, tip and tail.

Needle frame (``needle``)
-------------------------
- Origin at the centre of the needle's circular arc.
- The arc lies in the frame's x-y plane; z is the arc normal.
- A point of the arc at polar angle ``phi`` (about +z, from +x) is
  ``R (cos phi, sin phi, 0)``.
- The **tail** (where the thread is attached) is at ``phi = 180 deg``: ``(-R, 0, 0)``.
- The **tip** is at ``phi = 180 deg - arc_deg``; for the 120 deg needle ``phi = 60 deg``:
  ``R (0.5, 0.866, 0)``. The arc passes through ``+y`` (``phi = 90 deg ... 120 deg``).
- Arc parameter ``s`` in [0, 1] runs from the tail (``s = 0``) to the tip (``s = 1``):
  ``phi(s) = pi - s * arc``.
- The tip leads when the needle rotates about **-z** of its own frame (clockwise seen from +z):
  driving a needle through tissue is a rotation about ``-z_needle`` through the arc centre.

This follows the needle frame of the AMBF Surgical Robotics Challenge (tail at ``(-R, 0)``,
tip at ``R (cos 60 deg, sin 60 deg)``) so recorded needle poses are comparable.

Tool-tip frame and canonical grasp
----------------------------------
The dVRK tool-tip frame (``measured_cp`` of a PSM with a Large Needle Driver) has its origin on
the wrist-yaw (jaw hinge) axis; tool ``z`` points along the jaws away from the shaft (the
approach direction; at the simulated home pose ``R = [[0,1,0],[1,0,0],[0,0,-1]]`` in the RCM
frame, so tool ``z`` points down along the insertion axis); tool ``x`` is the jaw hinge axis, so
the jaws open and close in the tool ``y``-``z`` plane.

A grasp holds the wire between the jaws at depth ``grasp_depth`` along tool ``z``, with the wire
running along tool ``x`` (the jaws close across the wire). At arc parameter ``s`` with unit tangent
``t`` (tail to tip), outward radial ``r`` and needle normal ``z_n``, the canonical grasp
(``roll = 0``) is::

    x_tool = t,   y_tool = -r,   z_tool = -z_n

i.e. the instrument approaches perpendicular to the needle plane from the needle's ``+z`` side
(the way a needle lying on a surface with ``z_n`` up is picked from above), the jaws close along
the radial direction, and the hinge sits ``grasp_depth`` above the needle plane. ``roll`` turns
the jaw about the wire (about tool ``x``): ``roll = +90 deg`` gives ``z_tool = +r`` (approach from
the inside of the arc), ``roll = -90 deg`` gives ``z_tool = -r`` (approach from the outside, the
needle in the tool ``x``-``z`` plane). ``flip=True`` turns the grasp 180 deg about tool ``z``
(``x_tool = -t``).

All lengths are metres, angles radians unless a name ends in ``_deg``.
"""

from dataclasses import dataclass
import math

import numpy as np
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.validation import check_positive


def _rot_x(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class NeedleGeometry:
    """
    Circular suture needle (defaults: the paper's 10.18 mm, 120 deg needle, wire 1 mm).

    Attributes
    ----------
    radius : float
        Arc radius (m), measured to the wire centre line.
    arc_deg : float
        Arc angle (deg) from tail to tip.
    wire_diameter : float
        Wire diameter (m).
    grasp_s : float
        Arc parameter of the canonical grasp (0 tail, 1 tip); 1/3 holds the needle a third of
        the arc from the tail.
    grasp_depth : float
        Distance (m) along tool ``z`` from the jaw hinge (tool-tip frame origin) to the wire
        centre of a grasp.
    mass : float
        Needle mass (kg), for the physics body.

    """

    radius: float = 0.01018
    arc_deg: float = 120.0
    wire_diameter: float = 0.001
    grasp_s: float = 1.0 / 3.0
    grasp_depth: float = 0.006
    mass: float = 0.0005

    def __post_init__(self):
        check_positive(self.radius, 'needle radius (m)')
        if not 0.0 < self.arc_deg < 360.0:
            raise ValueError(f'needle arc_deg must be in (0, 360), got {self.arc_deg}')
        if not 0.0 < self.wire_diameter < self.radius:
            raise ValueError(
                f'needle wire_diameter must be in (0, radius), got {self.wire_diameter}')
        if not 0.0 <= self.grasp_s <= 1.0:
            raise ValueError(f'needle grasp_s must be in [0, 1], got {self.grasp_s}')
        if not self.grasp_depth >= 0.0:
            raise ValueError(f'needle grasp_depth must be >= 0 m, got {self.grasp_depth}')
        check_positive(self.mass, 'needle mass (kg)')

    # ------------------------------------------------------------------ angles and parameters
    @property
    def arc(self):
        """Arc angle (rad)."""
        return math.radians(self.arc_deg)

    @property
    def tail_angle(self):
        """Polar angle (rad) of the tail in the needle frame (pi)."""
        return math.pi

    @property
    def tip_angle(self):
        """Polar angle (rad) of the tip in the needle frame (pi - arc)."""
        return math.pi - self.arc

    @property
    def length(self):
        """Arc length (m) of the needle centre line."""
        return self.radius * self.arc

    @property
    def chord(self):
        """Straight tail-to-tip distance (m): ``2 R sin(arc / 2)`` (17.63 mm by default)."""
        return 2.0 * self.radius * math.sin(self.arc / 2.0)

    def angle_at(self, s):
        """
        Polar angle (rad) in the needle frame of arc parameter ``s``.

        Parameters
        ----------
        s : float or array_like
            Arc parameter, 0 at the tail and 1 at the tip.

        Returns
        -------
        float or ndarray
            ``pi - s * arc``, same shape as ``s``.

        """
        phi = math.pi - np.asarray(s, dtype=float) * self.arc
        return float(phi) if phi.ndim == 0 else phi

    def s_of_angle(self, phi):
        """
        Arc parameter of the polar angle ``phi`` (rad), unwrapped about the arc middle.

        Angles are wrapped into the interval centred on the arc middle, so points on the far
        side of the circle give ``s`` well outside [0, 1] (``< 0`` behind the tail, ``> 1``
        beyond the tip).

        Parameters
        ----------
        phi : float or array_like
            Polar angle(s) (rad) in the needle frame.

        Returns
        -------
        float or ndarray
            Arc parameter(s), same shape as ``phi``.

        """
        mid = math.pi - 0.5 * self.arc
        d = np.mod(np.asarray(phi, dtype=float) - mid + math.pi, 2.0 * math.pi) - math.pi
        s = 0.5 - d / self.arc
        return float(s) if np.ndim(s) == 0 else s

    # ------------------------------------------------------------------ points in the needle frame
    def point_at(self, s):
        """
        Point(s) of the arc centre line in the needle frame.

        Parameters
        ----------
        s : float or array_like, shape (n,)
            Arc parameter(s): 0 tail, 1 tip.

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Positions (m) in the needle frame.

        """
        phi = math.pi - np.asarray(s, dtype=float) * self.arc
        pts = np.stack([self.radius * np.cos(phi), self.radius * np.sin(phi),
                        np.zeros_like(phi)], axis=-1)
        return pts

    def tangent_at(self, s):
        """
        Return unit tangent(s) of the arc, pointing from tail towards tip, in the needle frame.

        Parameters
        ----------
        s : float or array_like, shape (n,)
            Arc parameter(s).

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Unit vectors (needle frame).

        """
        phi = math.pi - np.asarray(s, dtype=float) * self.arc
        return np.stack([np.sin(phi), -np.cos(phi), np.zeros_like(phi)], axis=-1)

    def arc_points(self, n=24):
        """
        Evenly spaced points of the arc centre line, tail to tip, in the needle frame.

        Parameters
        ----------
        n : int
            Number of points (>= 2).

        Returns
        -------
        ndarray, shape (n, 3)
            Positions (m); row 0 is the tail, row ``n - 1`` the tip.

        """
        if n < 2:
            raise ValueError(f'arc_points needs n >= 2, got {n}')
        return self.point_at(np.linspace(0.0, 1.0, n))

    @property
    def tip(self):
        """Tip position (m) in the needle frame, shape (3,)."""
        return self.point_at(1.0)

    @property
    def tail(self):
        """Tail position (m) in the needle frame, shape (3,)."""
        return self.point_at(0.0)

    @property
    def tip_direction(self):
        """Unit direction (needle frame) in which the tip points (tangent at s = 1)."""
        return self.tangent_at(1.0)

    @property
    def tail_direction(self):
        """Unit direction (needle frame) leaving the tail away from the needle (-tangent at 0)."""
        return -self.tangent_at(0.0)

    def points_world(self, T_world_needle, n=24):
        """
        Arc points in the world frame.

        Parameters
        ----------
        T_world_needle : array_like, shape (4, 4)
            Needle pose in the world frame.
        n : int
            Number of points, tail to tip.

        Returns
        -------
        ndarray, shape (n, 3)
            Positions (m) in the world frame.

        """
        T = np.asarray(T_world_needle, dtype=float)
        return self.arc_points(n) @ T[:3, :3].T + T[:3, 3]

    # ------------------------------------------------------------------ distances to the arc
    def distance_to_circle(self, points_needle):
        """
        Distance from points to the needle's full circle (centre line), needle frame.

        Parameters
        ----------
        points_needle : array_like, shape (n, 3)
            Points (m) in the needle frame.

        Returns
        -------
        ndarray, shape (n,)
            Distances (m).

        """
        p = np.asarray(points_needle, dtype=float)
        rho = np.hypot(p[..., 0], p[..., 1])
        return np.hypot(rho - self.radius, p[..., 2])

    def distance_to_arc(self, points_needle):
        """
        Distance from points to the needle arc (the 120 deg segment, not the full circle).

        Parameters
        ----------
        points_needle : array_like, shape (n, 3)
            Points (m) in the needle frame.

        Returns
        -------
        ndarray, shape (n,)
            Distances (m) to the nearest point of the arc centre line.

        """
        p = np.asarray(points_needle, dtype=float)
        s = self.s_of_angle(np.arctan2(p[..., 1], p[..., 0]))
        inside = (s >= 0.0) & (s <= 1.0)
        d_circle = self.distance_to_circle(p)
        d_tail = np.linalg.norm(p - self.tail, axis=-1)
        d_tip = np.linalg.norm(p - self.tip, axis=-1)
        return np.where(inside, d_circle, np.minimum(d_tail, d_tip))

    # ------------------------------------------------------------------ grasps
    def grasp_transform(self, s=None, roll=0.0, flip=False, depth=None):
        """
        Tool-tip pose of a grasp, ``T_tool_needle`` (tool-tip frame <- needle frame).

        Parameters
        ----------
        s : float, optional
            Arc parameter of the grasped point (default ``grasp_s``).
        roll : float
            Rotation (rad) of the jaw about the wire (tool ``x``); 0 is the canonical grasp
            with tool ``z = -z_needle``.
        flip : bool
            Turn the grasp 180 deg about tool ``z`` (tool ``x`` along the tip-to-tail tangent).
        depth : float, optional
            Hinge-to-wire distance (m) along tool ``z`` (default ``grasp_depth``).

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_tool_needle``: maps needle-frame coordinates into the tool-tip frame.

        """
        s = self.grasp_s if s is None else float(s)
        depth = self.grasp_depth if depth is None else float(depth)
        p = self.point_at(s)
        t = self.tangent_at(s)
        r = p / self.radius
        zn = np.array([0.0, 0.0, 1.0])
        R_needle_tool = np.column_stack([t, -r, -zn]) @ _rot_x(roll)
        if flip:
            R_needle_tool = R_needle_tool @ np.diag([-1.0, -1.0, 1.0])
        T_needle_tool = np.eye(4)
        T_needle_tool[:3, :3] = R_needle_tool
        T_needle_tool[:3, 3] = p - depth * R_needle_tool[:, 2]
        return invert_transform(T_needle_tool)

    @property
    def T_tool_needle(self):  # noqa: N802 (the project names poses T_a_b)
        """Canonical grasp ``T_tool_needle`` (4, 4): ``grasp_transform(grasp_s, roll=0)``."""
        return self.grasp_transform()


@dataclass(frozen=True)
class ThreadGeometry:
    """
    Suture thread as a chain of capsules fixed to the needle tail.

    Attributes
    ----------
    segment_length : float
        Length (m) of one capsule segment.
    radius : float
        Capsule radius (m).
    length : float
        Total thread length (m).
    joint_limit_deg : float
        Bending limit (deg) between neighbouring segments.
    mass : float
        Total thread mass (kg).

    """

    segment_length: float = 0.0025
    radius: float = 0.0002
    length: float = 0.100
    joint_limit_deg: float = 30.0
    mass: float = 0.0002

    def __post_init__(self):
        check_positive(self.segment_length, 'thread segment_length (m)')
        if not 0.0 < self.radius < self.segment_length:
            raise ValueError(
                f'thread radius must be in (0, segment_length), got {self.radius}')
        if not self.length >= self.segment_length:
            raise ValueError(
                f'thread length must be >= segment_length, got {self.length}')
        if not 0.0 < self.joint_limit_deg <= 180.0:
            raise ValueError(
                f'thread joint_limit_deg must be in (0, 180], got {self.joint_limit_deg}')
        check_positive(self.mass, 'thread mass (kg)')

    @property
    def n_segments(self):
        """Number of capsule segments (``round(length / segment_length)``, at least 1)."""
        return max(1, int(round(self.length / self.segment_length)))

    def rest_points(self, needle, T_world_needle):
        """
        Joint positions of a straight thread leaving the needle tail, world frame.

        The thread continues the arc's tangent backwards from the tail.

        Parameters
        ----------
        needle : NeedleGeometry
            Needle the thread is attached to.
        T_world_needle : array_like, shape (4, 4)
            Needle pose in the world.

        Returns
        -------
        ndarray, shape (n_segments + 1, 3)
            Segment end points (m) in the world frame; row 0 is the needle tail.

        """
        T = np.asarray(T_world_needle, dtype=float)
        tail = T[:3, :3] @ needle.tail + T[:3, 3]
        direction = T[:3, :3] @ needle.tail_direction
        step = self.length / self.n_segments
        return tail + np.outer(np.arange(self.n_segments + 1) * step, direction)
