"""
The scene as a robot's perception outputs show it: markers and needle from messages, in ``world``.

On a physical dVRK (or the simulator in physical mode) a separate perception process reads the
endoscope's stereo pair and publishes the needle's pose and the markers in the left optical
frame. :class:`PerceptionFeed` keeps the newest of those outputs and the camera's pose as the
robot reports it, and answers the same questions as the in-process
:class:`suture_lfd.skill.perceived.PerceivedScene` (whose grasp bookkeeping it shares): the
target pair, where the needle lies, which arm holds it. So the one
:class:`suture_lfd.skill.executor.ThrowExecutor` runs on it as in-process, driven by
:meth:`PerceptionFeed.observe` from the arms' own reports. It never renders and never reads the
simulation: a node converts the messages and hands them over.

**Looks of a known stamp.** Each look is kept with the stamp of its image pair, and an
observation of the arms at time ``t`` is made only of looks stamped at or before ``t``: a look
taken after the arms' state (possible when the arms' messages queue behind the images' while
the robot's loop catches up) waits until the arms' state has reached its stamp, so the controller
never joins a tool pose to a needle seen later. The newest few looks are kept for that.

Frames: ``world`` (as the robot believes it: its bases' registration), ``camera`` (the left
optical frame, x right, y down, z forward); poses 4x4; metres, seconds (the messages' stamps).
"""

from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
import logging
import math
import re
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.control import Observation
from sim_bridge.scene.markers import MarkerPair
from suture_lfd.perception.markers import pair_normal
from suture_lfd.skill.perceived import NeedleView, PerceivedScene

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class NeedleStatus:
    """
    The perception's word on one look at the needle (its ``status`` message).

    Attributes
    ----------
    found : bool
    reason : str
        Why it was not found ('' when found).
    residual_px : float or None
        Mean reprojection residual of the fit (pixels).

    """

    found: bool
    reason: str = ''
    residual_px: float | None = None


def pair_index_from_name(name: str) -> int:
    """
    Return the 1-based position along the wound a pair name gives (``'synth3'`` -> 3).

    Parameters
    ----------
    name : str

    Raises
    ------
    ValueError
        If the name does not end in a positive number (name the index instead).

    """
    match = re.search(r'(\d+)$', str(name))
    if match is None or int(match.group(1)) < 1:
        raise ValueError(f'pair name {name!r} does not end in its position along the wound '
                         '(1, 2, ...): give the pair index as well')
    return int(match.group(1))


def normal_quaternion(normal: ArrayLike) -> tuple[float, float, float, float]:
    """
    Return the shortest rotation taking ``z`` to a unit ``normal``, ``(x, y, z, w)``.

    The marker messages carry the plane's normal as their poses' ``z`` axis.
    """
    n = [float(v) for v in np.asarray(normal, dtype=float).reshape(3)]
    w = 1.0 + n[2]
    if w < 1e-9:  # the normal points along -z: half a turn about x
        return 1.0, 0.0, 0.0, 0.0
    q = (-n[1], n[0], 0.0, w)  # z x n, 1 + z . n
    norm = math.sqrt(sum(c * c for c in q))
    return q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm


class PerceptionFeed(PerceivedScene):
    """
    Markers and needle from perception outputs, in the robot's ``world``.

    Parameters
    ----------
    pair_name : str
        Name the target pair is given (``'synth1'``).
    pair_index : int
        1-based position of the target pair along the wound, as the camera sees the pairs from
        left to right.
    needle_geometry : sim_bridge.common.needle.NeedleGeometry, optional
        The needle's shape (for deciding whether a closing jaw holds it).
    grasp_reach : float, optional
        Distance (m) from the needle's perceived wire within which a closing jaw holds it
        (default :attr:`GRASP_REACH`).

    Attributes
    ----------
    T_world_camera : ndarray, shape (4, 4) or None
        The camera's pose as the robot reports it (set with :meth:`camera_moved`).

    """

    #: m: the in-process reach (3 mm from the jaws' bite) assumes kinematics corrected by the
    #: per-arm registration; fed by messages, the arms run on their own kinematics, whose
    #: 1-3 mm-class error (and the needle last seen lying) add theirs. In a throw the jaws
    #: close only to grasp, so the wider reach takes no closing for a grasp that is none.
    GRASP_REACH = 0.010
    #: s: fed by messages, a look renders nothing: the newest output is taken at every sample
    look_period = 0.0

    def __init__(self, pair_name: str, pair_index: int, needle_geometry: Any = None,
                 grasp_reach: float | None = None) -> None:
        # let go, the needle is believed where the holder left it until a look taken after
        # the release comes (the newest look at that moment shows it before: still moving)
        super().__init__(pair_name, pair_index, needle_geometry, look_again=False)
        self._look_after: float | None = None  # stamp (s) of the last release while no look since
        reach = self.GRASP_REACH if grasp_reach is None else grasp_reach
        if not reach > 0:
            raise ValueError(f'grasp_reach must be > 0 m, got {reach}')
        self.grasp_reach = float(reach)
        self.T_world_camera: np.ndarray | None = None
        # the newest looks, oldest first; camera frame:
        # markers (stamp, entries (n, 3), exits (n, 3), normal (3,)),
        # needle (stamp, T_camera_needle or None, NeedleStatus)
        self._marker_looks: deque[tuple] = deque(maxlen=self.LOOKS_KEPT)
        self._needle_looks: deque[tuple] = deque(maxlen=self.LOOKS_KEPT)
        self._now: float | None = None  # stamp (s) of the arms' state observed; None: any look

    #: looks kept per kind for :meth:`observe` to choose one of a known stamp from
    LOOKS_KEPT = 8

    @staticmethod
    def _at(looks: 'deque[tuple]', now: float | None) -> tuple | None:
        """Return the newest look stamped at or before ``now`` (any when None), or None."""
        for look in reversed(looks):
            if now is None or look[0] <= now:
                return look
        return None

    @property
    def _markers_c(self) -> tuple | None:
        return self._at(self._marker_looks, self._now)

    @property
    def _needle_c(self) -> tuple | None:
        return self._at(self._needle_looks, self._now)

    # ------------------------------------------------------------------ inputs
    def camera_moved(self, T_world_camera: ArrayLike) -> None:
        """Take the camera's newest pose (``world``, from the ECM's report)."""
        self.T_world_camera = np.asarray(T_world_camera, dtype=float)

    def markers_seen(self, stamp: float, entries: ArrayLike, exits: ArrayLike,
                     normal: ArrayLike) -> None:
        """
        Take one look at the markers.

        Parameters
        ----------
        stamp : float
            Stamp of the image pair (s).
        entries, exits : array_like, shape (n, 3)
            Entry and exit dots of the pairs along the wound (``camera``), NaN where not seen.
        normal : array_like, shape (3,)
            Unit normal of the dots' plane (``camera``, towards the camera).

        """
        entries = np.asarray(entries, dtype=float).reshape(-1, 3)
        exits = np.asarray(exits, dtype=float).reshape(-1, 3)
        if entries.shape != exits.shape:
            raise ValueError(f'{len(entries)} entries but {len(exits)} exits: the marker '
                             'arrays must pair up')
        self._marker_looks.append((float(stamp), entries, exits, np.asarray(normal, dtype=float)))

    def needle_seen(self, stamp: float, T_camera_needle: ArrayLike | None,
                    status: NeedleStatus) -> None:
        """
        Take one look at the needle.

        Parameters
        ----------
        stamp : float
            Stamp of the image pair (s).
        T_camera_needle : array_like, shape (4, 4) or None
            The needle's pose (``camera``); None when it was not found.
        status : NeedleStatus

        """
        T = None if T_camera_needle is None else np.asarray(T_camera_needle, dtype=float)
        self._needle_looks.append((float(stamp), T, status))

    def needle_stamp(self) -> float | None:
        """
        Return the stamp (s) of the look at the needle the last observation uses, or None.

        The executor's ``frame_time``: a look at the grasp that falls due at ``t`` is taken once
        a look stamped at or after ``t`` has come (the perception's latency behind the arms).
        """
        look = self._needle_c
        return None if look is None else look[0]

    def seen_since(self, stamp: float) -> list[str]:
        """Return what was not seen at or after ``stamp`` (``'markers'``, ``'needle'``)."""
        missing = []
        if not self._marker_looks or self._marker_looks[-1][0] < stamp:
            missing.append('markers')
        if not self._needle_looks or self._needle_looks[-1][0] < stamp:
            missing.append('needle')
        return missing

    def markers_centre(self) -> np.ndarray | None:
        """Return the centre (``world``, shape (3,)) of every marker last seen, or None."""
        if self._markers_c is None or self.T_world_camera is None:
            return None
        _, entries, exits, _ = self._markers_c
        points = np.vstack([entries, exits])
        points = points[np.isfinite(points).all(axis=1)]
        if not len(points):
            return None
        T = self.T_world_camera
        return T[:3, :3] @ points.mean(axis=0) + T[:3, 3]

    # ------------------------------------------------------------------ looks
    def markers(self, sim: Any = None) -> MarkerPair | None:
        """
        Return the target pair as last seen (``world``), or None when it is not seen.

        Parameters
        ----------
        sim : None
            Unused (the looks come from messages).

        """
        if self._markers_c is None or self.T_world_camera is None:
            return None
        _, entries, exits, normal_c = self._markers_c
        i = self.pair_index - 1
        if not 0 <= i < len(entries):
            _LOG.warning('pair %s: %d marker pairs seen, pair %d is not among them',
                         self.pair_name, len(entries), self.pair_index)
            return None
        if not (np.isfinite(entries[i]).all() and np.isfinite(exits[i]).all()):
            _LOG.warning('pair %s: a marker is not seen', self.pair_name)
            return None
        T = self.T_world_camera
        R, p = T[:3, :3], T[:3, 3]
        normal = R @ pair_normal(entries, exits, i, normal_c)
        self._support_normal = normal_c
        self._pair = MarkerPair(name=self.pair_name, entry=R @ entries[i] + p,
                                exit=R @ exits[i] + p, normal=normal, entry_normal=normal,
                                exit_normal=normal, index=self.pair_index)
        return self._pair

    def needle(self, sim: Any = None, prior: Any = None, tools: Any = (),
               expected: Any = None) -> NeedleView:
        """
        Return the needle as last seen (``world``).

        Parameters
        ----------
        sim, prior, tools, expected
            Unused: the perception process tracks the needle on its own.

        Returns
        -------
        suture_lfd.skill.perceived.NeedleView

        """
        if self._needle_c is None or self.T_world_camera is None:
            return NeedleView(None, NeedleStatus(False, 'no perception output yet'))
        _, T_c, status = self._needle_c
        if T_c is None:
            _LOG.info('needle not found: %s', status.reason)
            return NeedleView(None, status)
        return NeedleView(self.T_world_camera @ T_c, status)

    def look_at_grasp(self, sim: Any, arm: str, tools: Mapping[str, ArrayLike],
                      joints: Mapping[str, Any] | None = None,
                      wrist: 'Callable[..., np.ndarray] | None' = None,
                      wrist_now: ArrayLike = (0.0, 0.0)) -> np.ndarray | None:
        """
        Measure the grasp of the needle ``arm`` holds again, from the newest look at it.

        The perception process tracks the needle in the jaw too; its newest look (stamped at or
        before the arms' state) against the arm's pose gives the grasp as it is now -- on tissue
        the needle can have turned in the jaw since it closed.

        Parameters
        ----------
        sim : None
            Unused (the looks come from messages).
        arm : str
            The holding arm.
        tools : dict of str to ndarray (4, 4)
            Tool poses (``world``) of the arms, as observed.
        joints, wrist, wrist_now
            Unused: the wrist's offsets are fitted in process only
            (:meth:`suture_lfd.skill.perceived.PerceivedScene.look_at_grasp`).

        Returns
        -------
        ndarray, shape (4, 4) or None
            The new grasp ``T_tool_needle``; None (the old one kept) when the arm does not hold
            the needle, the needle is not seen, or the look is more than
            :attr:`max_grasp_change` off the grasp held (a look at something else).

        """
        held = self._held_needle(tools, arm) if arm in self._holders else None
        seen = self.needle(sim).T_world_needle if held is not None else None
        if held is None or seen is None:
            return None
        if float(np.linalg.norm(seen[:3, 3] - held[:3, 3])) > self.max_grasp_change:
            _LOG.info('%s: the needle seen is %.1f mm off the one held, its grasp is kept', arm,
                      1e3 * float(np.linalg.norm(seen[:3, 3] - held[:3, 3])))
            return None
        grasp = np.linalg.inv(np.asarray(tools[arm], dtype=float)) @ seen
        self._grasps[arm] = grasp
        return grasp

    def _fresh_needle(self, after: float) -> np.ndarray | None:
        """Return the needle (``world``) of a look stamped after ``after`` (s), or None."""
        if self._needle_c is None or self.T_world_camera is None:
            return None
        stamp, T_c, _ = self._needle_c
        if stamp <= after or T_c is None:
            return None
        return self.T_world_camera @ T_c

    # ------------------------------------------------------------------ observer
    def observe(self, arms: Observation) -> Observation:
        """
        Return the controller's observation: the arms' reports plus the perceived scene.

        Parameters
        ----------
        arms : sim_bridge.control.Observation
            The arms' own reports (``T_world_tool`` through their believed bases, jaws,
            joints); its needle, holders and pair are ignored.

        When the last holder lets go, the needle is believed where it was let go until the
        first look stamped after the release finds it; then it is where that look saw it. Only
        looks stamped at or before ``arms.t`` are used (see the module's docstring).

        Returns
        -------
        sim_bridge.control.Observation
            ``T_world_needle`` None when the needle is not known; ``pair`` None when the markers
            are not seen.

        """
        held_before = bool(self._holders)
        self._now = arms.t
        needle, holders, pair = self.estimate(None, arms)
        if held_before and not holders:
            self._look_after = arms.t
        if not holders and self._look_after is not None:
            fresh = self._fresh_needle(self._look_after)
            if fresh is not None:
                self._free_needle = needle = fresh
                self._look_after = None
        return Observation(t=arms.t, T_world_tool=arms.T_world_tool, jaw=arms.jaw,
                           T_world_needle=needle, holders=tuple(holders), pair=pair,
                           T_world_base=arms.T_world_base, q=arms.q)
