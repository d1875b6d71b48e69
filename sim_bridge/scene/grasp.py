"""
Needle grasping by the PSM jaws: attach on closing, release on opening, handover between arms.

Rule (the attach-on-close rule of the AMBF Surgical Robotics Challenge and JHU's dvrk_pybullet,
with hysteresis):

- Each jaw is *closed* once its angle falls to ``close_angle`` or below and *open* once it rises
  to ``release_angle`` or above; in between it keeps its state.
- At the moment a jaw becomes closed, it grasps the needle if the needle's wire passes within
  ``capture_radius`` of the jaw's grasp point, ``jaw_depth`` along the tool ``z`` axis (the jaw
  direction) from the hinge (default: the needle's canonical ``grasp_depth``). The needle is
  then held at its *current*
  pose relative to the tool (``T_tool_needle`` recorded at that instant). A jaw that closes away
  from the needle, or that is moved onto the needle already closed, holds nothing.
- At the moment a holding jaw becomes open, it releases the needle.
- Both arms may hold the needle. The first to grasp leads: the needle follows its tool. When the
  leader releases, the next holder leads, holding the needle where it is at that instant (its
  relative pose is re-recorded, so the needle pose is continuous through a handover even if the
  arms drifted while both held it).

Frames: tool poses are ``T_world_tool`` (the PSM tool-tip frame, ``measured_cp``, in ``world``),
needle poses ``T_world_needle`` (the needle frame of :mod:`sim_bridge.common.needle`); 4x4, metres.
"""

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.needle import NeedleGeometry
from sim_bridge.common.validation import check_positive


@dataclass(frozen=True)
class GraspConfig:
    """
    Jaw thresholds and grasp region.

    Attributes
    ----------
    close_angle : float
        Jaw angle (rad) at or below which the jaw counts as closed (tries to grasp).
    release_angle : float
        Jaw angle (rad) at or above which the jaw counts as open (releases); above close_angle.
    jaw_depth : float or None
        Grasp point along tool ``z`` (m from the jaw hinge, the tool-tip frame origin); None
        uses the needle's ``grasp_depth``.
    capture_radius : float
        Largest distance (m) from the needle's wire centre line to the grasp point for a grasp.
    wire_samples : int
        Points sampled along the needle arc for the distance test.

    """

    close_angle: float = 0.05
    release_angle: float = 0.15
    jaw_depth: float | None = None
    capture_radius: float = 0.002
    wire_samples: int = 61

    def __post_init__(self) -> None:
        if not self.release_angle > self.close_angle:
            raise ValueError(
                f'grasp release_angle ({self.release_angle}) must be greater than close_angle '
                f'({self.close_angle})')
        if self.jaw_depth is not None and not self.jaw_depth >= 0.0:
            raise ValueError(f'grasp jaw_depth must be >= 0 m, got {self.jaw_depth}')
        check_positive(self.capture_radius, 'grasp capture_radius (m)')
        if self.wire_samples < 2:
            raise ValueError(f'grasp wire_samples must be >= 2, got {self.wire_samples}')


@dataclass(frozen=True)
class GraspEvent:
    """
    A change of who holds the needle.

    Attributes
    ----------
    kind : str
        ``'grasp'`` or ``'release'``.
    arm : str
        Arm whose jaw grasped or released.
    distance : float
        For a grasp, distance (m) from the wire to the jaw's grasp point; else 0.
    leader : str or None
        Arm that leads (the needle follows it) after the event.

    """

    kind: str
    arm: str
    distance: float
    leader: str | None


class GraspManager:
    """
    Tracks the jaws of the PSMs and who holds the needle.

    Parameters
    ----------
    config : GraspConfig
        Thresholds and grasp region.
    needle : sim_bridge.common.needle.NeedleGeometry
        Needle geometry (its arc is sampled for the distance test).
    arms : sequence of str
        Names of the arms with jaws, in the order ties are resolved.

    """

    def __init__(self, config: GraspConfig, needle: NeedleGeometry, arms: Iterable[str]) -> None:
        self.config = config
        self.arms = tuple(arms)
        self._wire = needle.arc_points(config.wire_samples)
        depth = needle.grasp_depth if config.jaw_depth is None else config.jaw_depth
        self.jaw_point = np.array([0.0, 0.0, depth])
        self._closed = dict.fromkeys(self.arms)
        self._holders: list[str] = []  # arm names in grasp order; the first leads
        self._relative: dict[str, np.ndarray] = {}  # arm -> T_tool_needle

    # ------------------------------------------------------------------ state
    @property
    def holders(self) -> tuple[str, ...]:
        """Arms holding the needle, in grasp order (the first leads); tuple of str."""
        return tuple(self._holders)

    @property
    def leader(self) -> str | None:
        """Arm the needle follows, or None when no arm holds it."""
        return self._holders[0] if self._holders else None

    def is_closed(self, arm: str) -> bool | None:
        """
        Whether ``arm``'s jaw currently counts as closed (None before the first update).

        Parameters
        ----------
        arm : str
            Arm name.

        Returns
        -------
        bool or None
            Hysteresis state of the jaw.

        """
        return self._closed[arm]

    def relative_pose(self, arm: str) -> np.ndarray:
        """
        Return the recorded ``T_tool_needle`` (4x4) of a holding arm.

        Parameters
        ----------
        arm : str
            A holding arm.

        Returns
        -------
        ndarray, shape (4, 4)
            Needle frame in the arm's tool-tip frame.

        """
        if arm not in self._relative:
            raise ValueError(f'arm {arm!r} does not hold the needle; holders are {self.holders}')
        return self._relative[arm].copy()

    def reset(self) -> None:
        """Forget all jaw states and holders (the next update re-reads the jaws)."""
        self._closed = dict.fromkeys(self.arms)
        self._holders = []
        self._relative = {}

    def release_all(self) -> None:
        """Drop the needle from every jaw without events (used when resetting a scene)."""
        self._holders = []
        self._relative = {}

    def let_go(self, arm: str) -> None:
        """
        Make ``arm`` stop holding the needle with its jaw still closed (the grasp broke).

        No event; the next holder, if any, leads (its recorded grasp is kept).

        Parameters
        ----------
        arm : str
            A holding arm.

        """
        if arm in self._holders:
            self._holders.remove(arm)
            del self._relative[arm]

    def attach(self, arm: str, T_tool_needle: ArrayLike) -> None:
        """
        Make ``arm`` hold the needle at ``T_tool_needle`` (used to set up a scene).

        The jaw is marked closed so that it releases when it next opens.

        Parameters
        ----------
        arm : str
            Arm name.
        T_tool_needle : array_like, shape (4, 4)
            Needle frame in the arm's tool-tip frame.

        """
        if arm not in self._closed:
            raise ValueError(f'unknown arm {arm!r}; expected one of {self.arms}')
        if arm not in self._holders:
            self._holders.append(arm)
        self._relative[arm] = np.array(T_tool_needle, dtype=float)
        self._closed[arm] = True

    # ------------------------------------------------------------------ geometry
    def wire_distance(self, T_world_tool: ArrayLike, T_world_needle: ArrayLike) -> float:
        """
        Distance (m) from the needle's wire centre line to a jaw's grasp point.

        Parameters
        ----------
        T_world_tool : array_like, shape (4, 4)
            Tool-tip pose in ``world``.
        T_world_needle : array_like, shape (4, 4)
            Needle pose in ``world``.

        Returns
        -------
        float
            Smallest distance over the sampled wire points (m).

        """
        T = invert_transform(T_world_tool) @ np.asarray(T_world_needle, dtype=float)
        d = self._wire @ T[:3, :3].T + (T[:3, 3] - self.jaw_point)
        return float(np.sqrt(np.einsum('ij,ij->i', d, d).min()))

    def needle_pose(self, T_world_tool: ArrayLike) -> np.ndarray:
        """
        Needle pose implied by the leader's tool pose.

        Parameters
        ----------
        T_world_tool : array_like, shape (4, 4)
            Leader's tool-tip pose in ``world``.

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_world_needle``.

        """
        if not self._holders:
            raise ValueError('no arm holds the needle')
        return np.asarray(T_world_tool, dtype=float) @ self._relative[self._holders[0]]

    # ------------------------------------------------------------------ update
    def update(self, jaw_angles: Mapping[str, float], tool_pose: Callable[[str], ArrayLike],
               T_world_needle: ArrayLike) -> list[GraspEvent]:
        """
        Read the jaws and change who holds the needle.

        Parameters
        ----------
        jaw_angles : mapping of str to float
            Measured jaw angle (rad) per arm.
        tool_pose : callable
            ``tool_pose(arm) -> T_world_tool`` (4x4, ``world``); called only for arms whose jaw
            just closed or that take the lead.
        T_world_needle : array_like, shape (4, 4)
            Current needle pose in ``world``.

        Returns
        -------
        list of GraspEvent
            Grasps and releases in arm order.

        """
        cfg = self.config
        events = []
        for arm in self.arms:
            angle = jaw_angles[arm]
            closed = self._closed[arm]
            if closed is None:
                self._closed[arm] = angle <= cfg.close_angle
                continue
            if not closed and angle <= cfg.close_angle:
                self._closed[arm] = True
                if arm in self._holders:
                    continue
                T_world_tool = tool_pose(arm)
                distance = self.wire_distance(T_world_tool, T_world_needle)
                if distance <= cfg.capture_radius:
                    self._relative[arm] = (invert_transform(T_world_tool)
                                           @ np.asarray(T_world_needle, dtype=float))
                    self._holders.append(arm)
                    events.append(GraspEvent('grasp', arm, distance, self.leader))
            elif closed and angle >= cfg.release_angle:
                self._closed[arm] = False
                if arm not in self._holders:
                    continue
                was_leader = self._holders[0] == arm
                self._holders.remove(arm)
                del self._relative[arm]
                if was_leader and self._holders:
                    # The next holder leads from the needle's pose at this instant.
                    new = self._holders[0]
                    self._relative[new] = (invert_transform(tool_pose(new))
                                           @ np.asarray(T_world_needle, dtype=float))
                events.append(GraspEvent('release', arm, 0.0, self.leader))
        return events
