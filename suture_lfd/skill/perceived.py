"""
The scene as the robot sees it: markers and needle from the ECM's stereo pair, in ``world``.

A physical dVRK knows its camera's pose from the ECM's own kinematics, and the needle and the
markers only from the endoscope's images. :class:`PerceivedScene` renders the in-process
simulation's stereo pair (only when asked: rendering is the costly part), runs
:mod:`suture_lfd.perception` on it and expresses the results in ``world`` through the ECM's
reported pose -- never through the simulation's ground truth. It is the estimator of a
:class:`sim_bridge.observers.PhysicalObserver`.

Size: the looks share one frame cache, the arms' history a delayed frame is paired with, and
each grasp's pairs (lying and held) its fits return to; split, each part would need all three.

Frames: ``world`` (as the robot believes it), the camera's left optical frame ``camera``; poses
4x4; metres.
"""

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import logging
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.scene.camera import StereoFrame
from sim_bridge.scene.markers import MarkerPair
from suture_lfd.perception import HeldView, NeedleTracker, detect_markers, stereo_from_camera_info
from suture_lfd.perception.arc_poses import kabsch
from suture_lfd.perception.markers import pair_normal
from suture_lfd.perception.window import Window, crop, in_frame, points_window, window_stereo

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.control import Observation

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class NeedleView:
    """
    One look at the needle.

    Attributes
    ----------
    T_world_needle : ndarray, shape (4, 4) or None
        The estimated needle pose; None when it cannot be seen well enough.
    estimate : suture_lfd.perception.NeedleEstimate
        The perception's full answer (residual, visible share, reason).

    """

    T_world_needle: np.ndarray | None
    estimate: object


@dataclass(frozen=True, eq=False)
class SceneLayout:
    """
    Where a throw's scene is laid out by design (``world``): the markers, and the needle.

    At a throw's start the needle lies where it was put, within a millimetre or two of its
    layout. Placed on the markers seen (the rigid fit of ``markers`` onto them, so that the
    camera's reported pose does not enter), that place is the first look's prior: the needle
    is tracked in the window around it instead of searched for in the whole frame.

    Attributes
    ----------
    T_world_needle : ndarray, shape (4, 4)
        The needle's pose as laid out (the start's nominal position and yaw, on the support).
    markers : ndarray, shape (n, 2, 3)
        Entry and exit of each pair, in the order of their index (1, 2, ...).

    """

    T_world_needle: np.ndarray
    markers: np.ndarray


def _reported_camera(sim: Any) -> np.ndarray:
    """Return the left camera's pose as the robot reports it (``T_world_camera``: the ECM's)."""
    return sim.reported_tool_pose('ECM') @ sim.camera.T_tip_left


class PerceivedScene:
    """
    Markers and needle from the simulated endoscope, in the robot's ``world``.

    Parameters
    ----------
    pair_name : str
        Name the target pair is given (``'synth1'``).
    pair_index : int
        1-based position of the target pair along the wound, as the camera sees the pairs
        from left to right (the operator's "pair 1").
    needle_geometry : sim_bridge.common.needle.NeedleGeometry, optional
        The needle's shape (default: perception's).
    look_again : bool
        Look at the needle again when the arms let go of it (False: only at the start; a
        dropped needle is then believed where it was let go).
    refit_facing : float, optional
        A recorder's second look: once a needle taken from where it lay is held facing the
        camera this squarely or less (:meth:`facing`, at least :attr:`min_facing`), look at
        it once more and fit its grasp to both pairs (:meth:`look_at_grasp`), so that what
        is recorded from then on carries the grasp as seen turned, not only as seen lying.
        None (default): only when :meth:`look_at_grasp` is called (the executor chooses the
        instant from its plan).
    layout : SceneLayout, optional
        Where the scene is laid out: the first look at the needle tracks it from there (in the
        window around it) and searches the whole frame only when it is not found so. None:
        searched for.

    """

    def __init__(self, pair_name: str, pair_index: int,
                 needle_geometry: 'NeedleGeometry | None' = None,
                 look_again: bool = True, refit_facing: float | None = None,
                 layout: SceneLayout | None = None) -> None:
        self.pair_name = str(pair_name)
        self.layout = layout
        self._markers_seen: tuple[np.ndarray, np.ndarray] | None = None  # entries, exits seen
        self.pair_index = int(pair_index)
        self.look_again = bool(look_again)
        self.refit_facing = None if refit_facing is None else float(refit_facing)
        self._tracker = NeedleTracker(needle_geometry)
        self._stereo: Any = None
        # the frame looked at last: its scene time, its renders by window, T_world_camera
        self._frame: tuple[float, dict[Window | None, Any], np.ndarray] | None = None
        self._last_window: Window | None = None
        # the tools as observed at the latest control steps: (t, {arm: T_world_tool}), to pair a
        # delayed frame with the arms as they were when it was exposed (its stamp)
        self._tool_history: deque[tuple[float, Mapping[str, Any], Any]] = deque(maxlen=64)
        self._pair: MarkerPair | None = None
        self._support_normal: np.ndarray | None = None
        self._support_point: np.ndarray | None = None
        self.renders = 0
        self._next_look = -np.inf  # s: when an unseen lying needle is looked for again
        self.reset()

    # ------------------------------------------------------------------ images
    def _look(self, sim: Any, window: Window | None = None
              ) -> tuple[Any, np.ndarray, Any]:
        """
        Return the endoscope's images now, ``T_world_camera`` from the ECM's report, the camera.

        The images are the endoscope's
        (:meth:`sim_bridge.simulation.Simulation.endoscope_frame`): with a frame timing the
        newest delivered frame, never the scene now. Looked at twice in the same frame (the
        markers, then the needle) it is rendered once; a window of a frame (or of a larger
        window) already rendered is cut from it. ``window``: only that region of both images
        (:mod:`suture_lfd.perception.window`), with its camera.
        """
        if self._stereo is None:
            self._look_setup(sim)
        key = sim.delivered_frame()
        key = sim.time if key is None else key
        if self._frame is None or self._frame[0] != key:
            T_world_camera = _reported_camera(sim)
            self._frame = (key, {}, T_world_camera)
        _, views, T_world_camera = self._frame
        frame = views.get(window)
        if frame is None and window is not None:
            for held, view in views.items():
                part = _within(window, held)
                if part is not None:
                    frame = StereoFrame(left_rgb=crop(view.left_rgb, part), left_depth=None,
                                        right_rgb=crop(view.right_rgb, part), right_depth=None,
                                        T_world_left=view.T_world_left,
                                        T_world_right=view.T_world_right)
                    break
        if frame is None:
            _, frame = sim.endoscope_frame(window)
            self.renders += 1
        views[window] = frame
        self._last_window = window
        stereo = self._stereo if window is None else window_stereo(self._stereo, window)
        return frame, T_world_camera, stereo

    def _needle_window(self, sim: Any, T_world_needle: ArrayLike) -> Window | None:
        """Return the window of the images around a needle expected at ``T_world_needle``."""
        if self._stereo is None:
            self._look_setup(sim)
        T = _reported_camera(sim)
        points = self._tracker.geometry.points_world(
            np.linalg.inv(T) @ np.asarray(T_world_needle, dtype=float), 24)
        return points_window(self._stereo, points, self.window_margin)

    def _tools_then(self, sim: Any, tools: Mapping[str, ArrayLike]
                    ) -> Mapping[str, ArrayLike]:
        """
        Return the tools as they were when the frame a look gets now was exposed.

        A delayed frame (an endoscope's latency) shows the arms as they were at its scene time:
        the grasp it measures is taken against the tool poses observed then (the newest control
        step at or before it), as a robot pairs an image with its state at the image's stamp.
        An ideal camera's frame is of now: ``tools``.
        """
        t_scene = sim.delivered_frame()
        if t_scene is None or t_scene >= sim.time:
            return tools
        for t, then, _ in reversed(self._tool_history):
            if t <= t_scene + 1e-9:
                return {arm: then.get(arm, T) for arm, T in tools.items()}
        return tools

    def _joints_then(self, sim: Any, joints: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
        """Return the arms' reported joints when the frame a look gets now was exposed."""
        t_scene = sim.delivered_frame()
        if t_scene is None or t_scene >= sim.time:
            return joints
        for t, _, then in reversed(self._tool_history):
            if t <= t_scene + 1e-9:
                return then
        return joints

    def _look_setup(self, sim: Any) -> None:
        """Read the camera's calibration (once)."""
        camera = sim.camera
        self._stereo = stereo_from_camera_info(camera.camera_info('left'),
                                               camera.camera_info('right'))

    # ------------------------------------------------------------------ markers
    def markers(self, sim: Any) -> MarkerPair | None:
        """
        Look for the target pair's markers.

        Parameters
        ----------
        sim : sim_bridge.simulation.Simulation

        Returns
        -------
        sim_bridge.scene.markers.MarkerPair or None
            The perceived pair in ``world``; None when it is not seen.

        """
        window = self._layout_window(sim)
        frame, T, stereo = self._look(sim, window)
        found = detect_markers(frame.left_rgb, frame.right_rgb, stereo)
        laid = 0 if self.layout is None else len(self.layout.markers)
        if window is not None and found.n_pairs < laid:
            # a pair cut off would number the others wrong (a dot hidden under the needle or
            # the thread is hidden in the whole frame as well)
            _LOG.info('markers not all where the layout puts them: the whole frame looked at')
            frame, T, stereo = self._look(sim)
            found = detect_markers(frame.left_rgb, frame.right_rgb, stereo)
        i = self.pair_index - 1
        if not 0 <= i < found.n_pairs:
            _LOG.warning('pair %s: %d marker pairs seen, pair %d is not among them',
                         self.pair_name, found.n_pairs, self.pair_index)
            return None
        entry_c, exit_c = found.entries[i], found.exits[i]
        if not (np.isfinite(entry_c).all() and np.isfinite(exit_c).all()):
            _LOG.warning('pair %s: a marker is not seen', self.pair_name)
            return None
        R, p = T[:3, :3], T[:3, 3]
        normal = R @ pair_normal(found.entries, found.exits, i, found.normal)
        self._support_normal = found.normal
        self._support_point = found.points.mean(axis=0)
        self._markers_seen = (found.entries, found.exits)
        self._pair = MarkerPair(name=self.pair_name, entry=R @ entry_c + p, exit=R @ exit_c + p,
                                normal=normal, entry_normal=normal, exit_normal=normal,
                                index=self.pair_index)
        return self._pair

    # ------------------------------------------------------------------ needle
    def needle(self, sim: Any, prior: ArrayLike | None = None,
               tools: Sequence[ArrayLike] = (), expected: ArrayLike | None = None
               ) -> NeedleView:
        """
        Look for the needle.

        Parameters
        ----------
        sim : sim_bridge.simulation.Simulation
        prior : array_like, shape (4, 4), optional
            Where it is thought to be (``T_world_needle``).
        tools : sequence of array_like, shape (4, 4)
            Reported tool-tip poses (``world``) of the arms near it.
        expected : array_like, shape (4, 4), optional
            Without a prior, where it is expected to lie (``T_world_needle``, a layout's): it is
            detected from the blobs near there only, in the window around it
            (``NeedleTracker.estimate``'s ``expected``).

        Returns
        -------
        NeedleView
            A detection the tracker calls ambiguous between poses closer than
            :attr:`close_ambiguity` is taken (the better fit): either is within a jaw's reach,
            and the grasp is fitted again once the needle is held and turned.

        With a prior the needle is tracked in the window of the images around it
        (:attr:`window_margin`); without one it is searched for in the whole frame.

        """
        near = prior if prior is not None else expected
        window = None if near is None else self._needle_window(sim, near)
        frame, T, stereo = self._look(sim, window)
        T_camera_world = np.linalg.inv(T)
        prior_c = None if prior is None else T_camera_world @ np.asarray(prior, dtype=float)
        expected_c = None if expected is None or prior is not None \
            else T_camera_world @ np.asarray(expected, dtype=float)
        tools_c = [T_camera_world @ np.asarray(t, dtype=float) for t in tools]
        estimate = self._tracker.estimate(frame.left_rgb, frame.right_rgb, stereo,
                                          prior=prior_c, tools=tools_c,
                                          support_normal=self._support_normal,
                                          support_point=self._support_point,
                                          expected=expected_c)
        close = estimate.rival_distance <= self.close_ambiguity
        if not estimate.found and not close:
            _LOG.info('needle not found: %s', estimate.reason)
            return NeedleView(None, estimate)
        if close:
            _LOG.info('needle taken from a close tie: %s', estimate.reason)
        return NeedleView(T @ estimate.pose_camera, estimate)

    # ------------------------------------------------------------------ observer protocol
    def reset(self) -> None:
        """Forget the needle, its holders and their grasps (a new throw)."""
        self._holders: list[str] = []
        self._grasps: dict[str, np.ndarray] = {}
        self._closed: dict[str, bool] = {}
        self._free_needle: np.ndarray | None = None
        # the pair the free needle was last seen in: (left, right, T_world_camera, tools)
        self._free_view: tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]] | None \
            = None
        # per holder that took the needle from where it lay: that pair, its tool and its
        # reported joints at the grasp; the pairs it was seen held in since (a grasp fitted
        # with the wrist's offsets), the offsets fitted so far (rad)
        self._grasp_views: dict[str, tuple[tuple[Any, ...], np.ndarray, Any]] = {}
        self._held_views: dict[str, list[tuple[Any, ...]]] = {}
        self._wrist_fitted: dict[str, np.ndarray] = {}
        # per arm, the wrist offsets (rad) a look has fitted and not yet taken (wrist_offsets)
        self._wrist_new: dict[str, np.ndarray] = {}
        self._next_look = -np.inf
        self._laid_look = True  # the first look at the free needle may start from the layout

    def _layout_window(self, sim: Any) -> Window | None:
        """
        Return the window around the layout's markers and needle, or None (the whole frame).

        Placed through the camera's reported pose, widened by :attr:`layout_margin` (the
        reported pose's error and the needle's jitter); the markers' look is taken in it, and
        taken again in the whole frame when not every pair of the layout is seen.
        """
        if self.layout is None:
            return None
        if self._stereo is None:
            self._look_setup(sim)
        T = _reported_camera(sim)
        inv = np.linalg.inv(T)
        points = np.vstack([np.asarray(self.layout.markers, dtype=float).reshape(-1, 3),
                            self._tracker.geometry.points_world(
                                np.asarray(self.layout.T_world_needle, dtype=float), 24)])
        return points_window(self._stereo, points @ inv[:3, :3].T + inv[:3, 3],
                             self.layout_margin)

    def _laid_prior(self, sim: Any) -> np.ndarray | None:
        """
        Return where the layout puts the needle (``world``, through the camera's report), or None.

        The layout's markers are fitted rigidly onto those seen (camera frame) and the needle's
        laid pose carried along; None without a layout, with fewer than three markers seen, or
        when the markers seen are more than :attr:`layout_misfit` (rms) off the layout's shape
        (a pair missed, the pairs numbered otherwise).
        """
        if self.layout is None or self._markers_seen is None:
            return None
        entries, exits = self._markers_seen
        laid = np.asarray(self.layout.markers, dtype=float)
        n = min(len(laid), len(entries))
        model = np.vstack([laid[:n, 0], laid[:n, 1]])
        seen = np.vstack([entries[:n], exits[:n]])
        ok = np.isfinite(seen).all(axis=1)
        if ok.sum() < 3:
            return None
        T_camera_world = kabsch(model[ok], seen[ok])
        moved = model[ok] @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
        if float(np.sqrt(np.mean(np.sum((moved - seen[ok]) ** 2, axis=1)))) > self.layout_misfit:
            return None
        T_world_camera = _reported_camera(sim)
        return T_world_camera @ T_camera_world @ np.asarray(self.layout.T_world_needle, float)

    def _first_look(self, sim: Any, tools: Mapping[str, ArrayLike]) -> NeedleView:
        """Look for the free needle: near the layout's at a throw's first look, else anywhere."""
        expected = self._laid_prior(sim) if self._laid_look else None
        self._laid_look = False
        if expected is not None:
            view = self.needle(sim, tools=list(tools.values()), expected=expected)
            if view.T_world_needle is not None:
                return view
            _LOG.info('needle not near where the layout puts it: searched for')
        return self.needle(sim, tools=list(tools.values()))

    def estimate(self, sim: Any, arm_state: 'Observation'
                 ) -> tuple[np.ndarray | None, tuple[str, ...], MarkerPair | None]:
        """
        Needle, holders and pair for a :class:`sim_bridge.observers.PhysicalObserver`.

        The images are looked at only when something changes: at the first call (the markers
        and the needle where it lies) and when the last holder lets go (where the needle lies
        now). While the needle is free and not seen it is looked for again every
        :attr:`look_period` (simulated s), not at every sample. When a jaw closes near the
        needle's last known pose the arm holds it, its grasp ``T_tool_needle`` measured
        against the arm's pose as observed (the reported pose, or the registered one when the
        observer corrects it). Meanwhile a held needle is where the holder's pose and grasp
        put it.

        Returns
        -------
        tuple
            ``(T_world_needle or None, holders, MarkerPair or None)``.

        """
        if self._pair is None:
            self.markers(sim)
        tools = arm_state.T_world_tool
        if self._tool_history and self._tool_history[-1][0] > arm_state.t:
            self._tool_history.clear()  # a scene reset turns time back
        self._tool_history.append((arm_state.t, tools, arm_state.q))
        # due unless a look failed less than look_period ago (a scene reset turns time back)
        due = not arm_state.t < self._next_look <= arm_state.t + self.look_period
        if not self._holders and self._free_needle is None and due:
            self._free_needle = self._first_look(sim, tools).T_world_needle
            self._free_view = self._seen_view(tools, self._free_needle)
            if self._free_needle is None:
                self._next_look = arm_state.t + self.look_period
        for arm, jaw in arm_state.jaw.items():
            closed = jaw < self.closed_below
            was = self._closed.get(arm, closed)
            self._closed[arm] = closed
            if closed and not was and arm not in self._holders:
                self._check_grasp(sim, arm, tools, (arm_state.q or {}).get(arm))
            elif not closed and arm in self._holders:
                held = self._held_needle(tools, arm)
                self._holders.remove(arm)
                self._grasps.pop(arm, None)
                self._grasp_views.pop(arm, None)
                self._held_views.pop(arm, None)
                self._wrist_fitted.pop(arm, None)
                self._free_view = None
                if not self._holders and self.look_again:
                    view = self.needle(sim, prior=held, tools=list(tools.values()))
                    self._free_needle = held if view.T_world_needle is None \
                        else view.T_world_needle
                    self._free_view = self._seen_view(tools, view.T_world_needle)
                elif not self._holders:
                    self._free_needle = held
        if self.refit_facing is not None:
            for arm in [a for a in self._holders if a in self._grasp_views]:
                held = self._held_needle(tools, arm)
                facing = self.facing(sim, held) if held is not None else 0.0
                if self.min_facing <= facing <= self.refit_facing:
                    self.look_at_grasp(sim, arm, tools)
                    self._grasp_views.pop(arm, None)  # once per grasp
        needle = self._free_needle
        if self._holders:
            needle = self._held_needle(tools, self._holders[0])
        return needle, tuple(self._holders), self._pair

    def look_at_grasp(self, sim: Any, arm: str, tools: Mapping[str, ArrayLike],
                      joints: Mapping[str, Any] | None = None,
                      wrist: 'Callable[..., np.ndarray] | None' = None,
                      wrist_now: ArrayLike = (0.0, 0.0)) -> np.ndarray | None:
        """
        Look at the needle ``arm`` holds and measure its grasp again.

        The grasp taken when the jaw closed is the needle's last pose seen lying, against the
        tool; seen in the jaw, the needle gives the grasp as it really is (the tool's pose is
        the corrected report). With ``wrist``, the wrist's roll and pitch offsets are fitted
        with the grasp to every pair of this grasp (lying, and each earlier look that was
        trusted): a grasp alone takes up a wrist offset at the wrist pose it was seen at only.
        The offsets fitted are then :meth:`wrist_offsets`'s.

        Parameters
        ----------
        sim : sim_bridge.simulation.Simulation
        arm : str
            The holding arm.
        tools : dict of str to ndarray (4, 4)
            Tool poses (``world``) of the arms, as observed.
        joints : dict of str to ndarray (6,), optional
            The arms' reported joints now (needed with ``wrist``).
        wrist : callable, optional
            ``wrist(q, offsets) -> (4, 4)``: the tool-frame change of the arm's wrist joints
            4 and 5 ``offsets`` (rad) further than the correction puts them at reported joints
            ``q`` (:meth:`suture_lfd.skill.arm_registration.ArmCorrection.wrist_change`).
        wrist_now : array_like, shape (2,)
            The wrist offsets (rad) the arm's correction has now: the fit's prior is about
            none at all (a fit that drifts is pulled back, not built on).

        Returns
        -------
        ndarray, shape (4, 4) or None
            The new grasp ``T_tool_needle``; None (the old one kept) when the arm does not hold
            the needle or the needle is not seen well enough.

        """
        held = self._held_needle(tools, arm) if arm in self._holders else None
        if held is None:
            return None
        facing = self.facing(sim, held)
        if facing < self.min_facing:
            # edge-on to the camera, a few percent of the wire shows: not worth a render
            _LOG.info('%s: the held needle is edge-on to the camera (%.2f), its grasp is kept',
                      arm, facing)
            return None
        lying = self._grasp_views.get(arm)
        tools = self._tools_then(sim, tools)  # the arms as the frame shows them
        held = self._held_needle(tools, arm)
        assert held is not None  # the arm holds it: its grasp is known
        if lying is not None:
            q_now = self._joints_then(sim, joints)
            q_now = None if q_now is None else q_now.get(arm)
            if wrist is not None and q_now is not None and lying[2] is not None:
                grasp = self._fit_grasp(sim, arm, tools, lying, (wrist, q_now, wrist_now))
                if grasp is not None:
                    return grasp
            return self._fit_grasp(sim, arm, tools, lying)
        view = self.needle(sim, prior=held, tools=list(tools.values()))
        if view.T_world_needle is None:
            _LOG.info('%s: the held needle is not seen, its grasp is kept', arm)
            return None
        grasp = np.linalg.inv(np.asarray(tools[arm], dtype=float)) @ view.T_world_needle
        self._grasps[arm] = grasp
        return grasp

    def wrist_offsets(self, arm: str) -> np.ndarray | None:
        """
        Return the wrist offsets (rad, joints 4 and 5) the last look fitted, once.

        They are to be added to the arm's correction before its next observation: the grasp
        the look returned is against the tool so corrected. None when the look fitted none.
        """
        return self._wrist_new.pop(arm, None)

    def _fit_grasp(self, sim: Any, arm: str, tools: Mapping[str, ArrayLike],
                   lying: tuple[tuple[Any, ...], np.ndarray, Any],
                   wrist: tuple[Any, Any, Any] | None = None) -> np.ndarray | None:
        """
        Fit the grasp to the pair of the needle lying and the pair seen now, together.

        The lying needle, seen nearly face on, leaves its tilt open (on a sloping pad 10-15
        degrees, 2 mm at the tip); carried and turned, the same grasp shows it. The fit is kept
        when the needle is seen well enough in the new pair and the grasp moved less than
        :attr:`max_grasp_change`. With ``wrist`` (the wrist's change and the joints now), the
        wrist's offsets are fitted too, to these pairs and the held ones trusted before, and
        kept within :attr:`max_wrist_offset`.
        """
        (left, right, T_world_camera0, tools0), T_world_tool0, q0 = lying
        held = self._held_needle(tools, arm)
        window = None if held is None else self._needle_window(sim, held)
        frame, T_world_camera, _ = self._look(sim, window)
        left_now, right_now = frame.left_rgb, frame.right_rgb
        if window is not None:  # one camera for both pairs: the window in its frame
            left_now = in_frame(left_now, window, self._stereo)
            right_now = in_frame(right_now, window, self._stereo)
        inv0, inv = np.linalg.inv(T_world_camera0), np.linalg.inv(T_world_camera)
        T_tool = np.asarray(tools[arm], dtype=float)
        now = (left_now, right_now, T_world_camera, T_tool,
               [np.asarray(T, dtype=float) for T in tools.values()])
        if wrist is None:
            views = [HeldView(left, right, inv0 @ T_world_tool0, tuple(inv0 @ T for T in tools0)),
                     HeldView(left_now, right_now, inv @ T_tool, tuple(inv @ T for T in now[4]))]
        else:
            change, q_now, wrist_now = wrist
            fitted = self._wrist_fitted.get(arm, np.zeros(2))
            pairs = [((left, right, T_world_camera0, T_world_tool0, tools0), q0, np.zeros(2))]
            pairs += self._held_views.get(arm, [])
            pairs.append((now, np.asarray(q_now, dtype=float), fitted))
            views = [_wrist_view(seen, q, then - fitted, change) for seen, q, then in pairs]
        old = self._grasps[arm]
        # the offsets only from two held pairs on: with the lying pair alone, seen face on, a
        # roll of the wrist and a tilt of the needle in the jaw look alike
        offsets = 2 if wrist is not None and self._held_views.get(arm) else 0
        fit = self._tracker.fit_grasp(
            views, self._stereo, old, offsets=offsets,
            offset_prior=None if wrist is None else -np.asarray(wrist_now, dtype=float))
        c = self._tracker.config
        residual, share = fit.residual_px[-1], fit.visible_share[-1]
        moved = self._tracker.arc_distance(old, fit.T_tool_needle)
        if share < c.min_visible or residual > c.max_residual or moved > self.max_grasp_change:
            _LOG.info('%s: the grasp fitted to the lying and the held needle is not trusted '
                      '(seen %.0f %%, residual %.2f px, moved %.1f mm), it is kept', arm,
                      100.0 * share, residual, 1e3 * moved)
            return None
        if wrist is not None:
            total = self._wrist_fitted.get(arm, np.zeros(2)) + np.resize(fit.offsets, 2)
            if np.any(np.abs(np.asarray(wrist_now) + np.resize(fit.offsets, 2))
                      > self.max_wrist_offset):
                _LOG.info('%s: wrist offsets %s deg fitted with the grasp are not plausible',
                          arm, np.round(np.degrees(total), 1))
                return None
            self._wrist_fitted[arm] = total
            if offsets:
                self._wrist_new[arm] = fit.offsets
            self._held_views.setdefault(arm, []).append((now, np.asarray(q_now, dtype=float),
                                                        total))
        self._grasps[arm] = fit.T_tool_needle
        return fit.T_tool_needle

    def facing(self, sim: Any, T_world_needle: ArrayLike) -> float:
        """
        How squarely the needle at ``T_world_needle`` faces the left camera, without a render.

        Parameters
        ----------
        sim : sim_bridge.simulation.Simulation
        T_world_needle : array_like, shape (4, 4)
            The needle's pose as believed (``world``).

        Returns
        -------
        float
            ``|cos|`` of the angle between the needle's plane normal and the line of sight
            to its origin: 1 seen face on, 0 edge-on.

        """
        N = np.asarray(T_world_needle, dtype=float)
        T = _reported_camera(sim)
        sight = N[:3, 3] - T[:3, 3]
        norm = float(np.linalg.norm(sight))
        return abs(float(N[:3, 2] @ sight)) / norm if norm > 0.0 else 0.0

    #: m: how far a tracked needle may be from where it is expected (a grasp's error, a few
    #: millimetres of fall when let go): the window of the images looked at is widened by it.
    window_margin = 0.005
    #: m (rms): the markers seen fit the layout's within this, or its needle is not a prior
    layout_misfit = 0.002
    #: m: the layout's markers and needle are looked for in the window widened by this
    layout_margin = 0.010
    #: A held needle facing the camera less than this (:meth:`facing`) is not looked at: edge
    #: on, 2-3 % of its wire shows, far below what the tracker needs.
    min_facing = 0.2
    #: s (simulated): an unseen free needle is looked for again at this period -- the rate
    #: learning needs (the recorder's perception rate, 2 Hz), not every control sample.
    look_period = 0.5
    #: m: a lying needle's detection tied with another pose at most this far away (mean of
    #: tail, middle and tip) is taken, the better fit: both lie within a jaw's reach of the wire
    #: (:attr:`grasp_reach`); seen face on, a tilt 1.6-1.8 mm away can tie with the truth.
    close_ambiguity = 0.002
    #: m: a grasp fitted to the lying and the held needle together is kept only when it moved
    #: the arc (mean of its tail, middle and tip) less than this from the grasp taken lying.
    max_grasp_change = 0.005
    #: rad: wrist offsets fitted with a grasp beyond this are a fit of pairs seen wrong (a
    #: dVRK instrument's homing leaves a few degrees).
    max_wrist_offset = 0.12
    closed_below = 0.15  # rad: a jaw closed this far holds whatever is between its halves
    grasp_reach = 0.003  # m: a jaw closed with its bite this close to the wire holds it

    def _held_needle(self, tools: Mapping[str, ArrayLike], arm: str) -> np.ndarray | None:
        grasp = self._grasps.get(arm)
        return None if grasp is None else np.asarray(tools[arm]) @ grasp

    def _check_grasp(self, sim: Any, arm: str, tools: Mapping[str, ArrayLike],
                     q: ArrayLike | None = None) -> None:
        """
        Decide whether the jaw that just closed holds the needle, and measure its grasp.

        The needle is where it was last known (seen lying, or carried by the other holder):
        the closing jaw hides most of it from the camera. A jaw closed with its bite
        (``grasp_depth`` along the jaws) within :attr:`grasp_reach` of its wire holds it, with
        the grasp ``T_tool_needle`` taken against the arm's pose as observed (corrected).
        Without a last known pose the images are looked at.
        """
        prior = self._held_needle(tools, self._holders[0]) if self._holders else self._free_needle
        if prior is None:
            prior = self.needle(sim, tools=list(tools.values())).T_world_needle
            self._free_view = self._seen_view(tools, prior)
        if prior is None:
            _LOG.warning('%s closed its jaw but the needle is not seen', arm)
            return
        T_tool = np.asarray(tools[arm], dtype=float)
        geometry = self._tracker.geometry
        wire = geometry.points_world(prior, 48)
        # the point between the jaws that closes on the wire, grasp_depth along the jaws
        bite = T_tool[:3, 3] + geometry.grasp_depth * T_tool[:3, 2]
        gap = float(np.linalg.norm(wire - bite, axis=1).min())
        if gap > self.grasp_reach:
            _LOG.info('%s closed %.1f mm from the needle: not holding it', arm, 1e3 * gap)
            return
        if not self._holders and self._free_view is not None:
            self._grasp_views[arm] = (self._free_view, T_tool.copy(),
                                      None if q is None else np.array(q, dtype=float))
        self._holders.append(arm)
        self._grasps[arm] = np.linalg.inv(T_tool) @ prior

    def _seen_view(self, tools: Mapping[str, ArrayLike], seen: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]] | None:
        """Return the pair just looked at and the tools then in view, if the needle was seen."""
        if seen is None or self._frame is None:
            return None
        _, views, T_world_camera = self._frame
        window = self._last_window
        left, right = views[window].left_rgb, views[window].right_rgb
        if window is not None:  # kept in the whole frame's camera
            left = in_frame(left, window, self._stereo)
            right = in_frame(right, window, self._stereo)
        return (left, right, T_world_camera, [np.asarray(T, dtype=float) for T in tools.values()])


def _within(window: Window, held: Window | None) -> Window | None:
    """Return ``window`` in the pixels of a view ``held`` (None: whole) holding it, or None."""
    if held is None:
        return window
    u, v, w, h = window
    U, V, W, H = held
    if U <= u and V <= v and u + w <= U + W and v + h <= V + H:
        return u - U, v - V, w, h
    return None


def _wrist_view(seen: tuple[Any, ...], q: np.ndarray, behind: np.ndarray,
                change: 'Callable[[Any, np.ndarray], np.ndarray]') -> HeldView:
    """
    Return a pair of a grasp, its holding tool's pose a function of the wrist offsets to fit.

    ``seen``: the images, ``T_world_camera``, the holding tool's pose as observed then, the
    tools in view; ``q``: the reported joints then; ``behind``: the wrist offsets (rad) the
    correction then had minus the ones it has now (the tool observed then is
    ``inv(change(q, behind))`` of where the present correction puts it).
    """
    left, right, T_world_camera, T_world_tool, tools = seen
    inv = np.linalg.inv(T_world_camera)
    T_now = inv @ np.asarray(T_world_tool, dtype=float) @ np.linalg.inv(change(q, behind))

    def tool_at(offsets: np.ndarray) -> np.ndarray:
        return T_now @ change(q, offsets)

    return HeldView(left, right, T_now, tuple(inv @ np.asarray(T, dtype=float) for T in tools),
                    tool_at=tool_at)
