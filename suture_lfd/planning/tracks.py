"""
Building blocks of a throw plan: one arm's timeline (:class:`Track`) and pose helpers.

Frames: ``world``; poses 4x4 ``T_world_*``; metres, radians, seconds.
"""

import math
from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import invert_transform
from suture_lfd.planning.waypoints import (
    ArcPath,
    NeedleMove,
    NeedlePath,
    PoseInterpolator,
    RigidPath,
    ToolMove,
)

if TYPE_CHECKING:
    from sim_bridge.control import ExpertConfig


def translated(T: ArrayLike, v: ArrayLike) -> np.ndarray:
    """Return a copy of pose ``T`` (4, 4) moved by ``v`` (3,) in its parent frame."""
    out = np.array(T, dtype=float)
    out[:3, 3] = out[:3, 3] + v
    return out


def backed_off(T: ArrayLike, distance: float) -> np.ndarray:
    """Move a pose ``distance`` along its own minus ``z`` axis."""
    return translated(T, -distance * np.asarray(T)[:3, 2])


def dense_poses(A: ArrayLike, B: ArrayLike, step: float = 0.1,
                spacing: float = 0.002) -> list[np.ndarray]:
    """Poses from A towards B (B excluded), about ``step`` rad and ``spacing`` m apart."""
    path = RigidPath(A, B)
    n = max(2, int(math.ceil(max(path.angle / step, path.distance / spacing))))
    return list(path.many(np.linspace(0.0, 1.0, n, endpoint=False)))


class TimedNeedleMove(NeedleMove):
    """A tool carrying the needle along a path with the path's own timing (a DMP rollout)."""

    def sigma(self, t: float) -> float:
        """Path parameter: linear in time (the path sets the speed profile)."""
        if self.t1 <= self.t0:
            return 1.0
        return min(1.0, max(0.0, (t - self.t0) / (self.t1 - self.t0)))


class Track:
    """
    One arm's timeline under construction: plan time, current pose, jaw, held needle.

    Each call appends minimum-jerk segments (:mod:`suture_lfd.planning.waypoints`) timed by the
    expert's speeds and accelerations (:class:`sim_bridge.control.ExpertConfig`).

    Parameters
    ----------
    arm : str
        ``'PSM1'`` or ``'PSM2'``.
    pose : array_like, shape (4, 4)
        Start tool pose ``T_world_tool``.
    jaw : float
        Start jaw angle (rad).
    config : sim_bridge.control.ExpertConfig
        Motion parameters.

    Attributes
    ----------
    t : float
        Plan time (s) of the end of the track.
    pose : ndarray, shape (4, 4)
        Tool pose at that time.
    jaw : float
        Jaw angle at that time.
    segments : list
        The segments so far.
    held : tuple or None
        ``(T_world_needle, T_tool_needle)`` while the arm holds the needle.

    """

    def __init__(self, arm: str, pose: ArrayLike, jaw: float, config: 'ExpertConfig') -> None:
        self.arm = arm
        self.t = 0.0
        self.pose = np.array(pose, dtype=float)
        self.jaw = float(jaw)
        self.cfg = config
        self.segments: list[ToolMove] = []
        # (needle pose, grasp) while the arm holds the needle
        self.held: tuple[np.ndarray, np.ndarray] | None = None

    def move_time(self, distance: float, angle: float,
                  angular_speed: float | None = None) -> float:
        """Return the time (s) of a minimum-jerk motion over ``distance`` (m), ``angle`` (rad)."""
        c = self.cfg
        w = c.tool_angular_speed if angular_speed is None else angular_speed
        # minimum jerk: peak speed 1.875 d / T, peak acceleration 5.7735 d / T^2
        return max(c.min_move_time, 1.875 * distance / c.tool_speed, 1.875 * angle / w,
                   math.sqrt(5.7735 * distance / c.tool_acceleration),
                   math.sqrt(5.7735 * angle / c.tool_angular_acceleration)) / c.speed_scale

    def _still(self, t1: float, jaw: float) -> None:
        if self.held is None:
            seg = ToolMove(self.t, t1, self.pose, self.pose, self.jaw, jaw)
        else:
            N, G = self.held
            seg = NeedleMove(self.t, t1, RigidPath(N, N), G, self.jaw, jaw)
        self.segments.append(seg)
        self.t, self.jaw = t1, float(jaw)

    def hold_until(self, t: float) -> None:
        """Keep still until plan time ``t`` (s)."""
        if t > self.t + 1e-12:
            self._still(t, self.jaw)

    def hold(self, duration: float) -> None:
        """Keep still for ``duration`` (s)."""
        self.hold_until(self.t + duration)

    def set_jaw(self, jaw: float) -> None:
        """Open or close the jaw to ``jaw`` (rad) in ``jaw_time``."""
        self._still(self.t + self.cfg.jaw_time / self.cfg.speed_scale, jaw)

    def grab(self, needle_pose: ArrayLike, grasp: ArrayLike) -> None:
        """From now on the arm holds the needle (after its jaw closed on it)."""
        self.held = (np.array(needle_pose, dtype=float), np.array(grasp, dtype=float))

    def let_go(self) -> None:
        """From now on the arm holds nothing (after its jaw opened)."""
        self.held = None

    def move(self, B: ArrayLike, jaw: float | None = None) -> None:
        """Move the free tool to pose ``B`` (and the jaw to ``jaw``), minimum-jerk timed."""
        if self.held is not None:
            raise RuntimeError(f'{self.arm} holds the needle: use carry()')
        jaw = self.jaw if jaw is None else float(jaw)
        seg = ToolMove(self.t, self.t, self.pose, B, self.jaw, jaw)
        duration = self.move_time(seg.path.distance, seg.path.angle)
        if jaw != self.jaw:
            duration = max(duration, self.cfg.jaw_time / self.cfg.speed_scale)
        seg.t1 = self.t + duration
        self.segments.append(seg)
        self.t, self.pose, self.jaw = seg.t1, np.array(B, dtype=float), jaw

    def carry(self, path: PoseInterpolator | ArcPath, drive: bool = False,
              min_duration: float | None = None) -> None:
        """
        Carry the held needle along ``path`` (a needle path), minimum-jerk timed.

        ``drive``: timed by the needle's drive speed (turning about its arc); ``min_duration``:
        the segment lasts at least this long (s).
        """
        if self.held is None:
            raise RuntimeError(f'{self.arm} does not hold the needle')
        grasp = self.held[1]
        inv = invert_transform(grasp)
        A, B = path.A @ inv, path.B @ inv
        if isinstance(path, ArcPath):
            centre = path.arc.centre
            reach = max(np.linalg.norm(A[:3, 3] - centre), np.linalg.norm(B[:3, 3] - centre))
            distance = reach * path.angle
        else:
            distance = float(np.linalg.norm(B[:3, 3] - A[:3, 3]))
        w = self.cfg.drive_speed if drive else None
        duration = self.move_time(distance, path.angle, w)
        seg = NeedleMove(self.t, self.t + duration, path, grasp, self.jaw)
        if min_duration is not None and seg.t1 - seg.t0 < min_duration:
            seg.t1 = seg.t0 + min_duration
        self.segments.append(seg)
        self.t, self.pose = seg.t1, B
        self.held = (path.B, grasp)

    def follow(self, path: NeedlePath, duration: float) -> None:
        """
        Carry the held needle along ``path`` with the path's own timing (a DMP rollout).

        Parameters
        ----------
        path : callable
            Needle path of ``sigma`` in [0, 1] with poses ``A`` and ``B``; ``sigma`` is linear
            in time (:class:`TimedNeedleMove`).
        duration : float
            Duration (s).

        """
        # a rollout carries the needle the arm holds (cast: typing only)
        grasp = cast('tuple[np.ndarray, np.ndarray]', self.held)[1]
        seg = TimedNeedleMove(self.t, self.t + duration, path, grasp, self.jaw)
        self.segments.append(seg)
        self.t = seg.t1
        self.pose = path.B @ invert_transform(grasp)
        self.held = (path.B, grasp)
