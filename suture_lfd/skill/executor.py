"""
DMP executor: performs a whole throw on a marker pair from a learnt :class:`ThrowSkill`.

Subtasks i, iii and v are scripted as in the seed paper ("we grasp the needle using a script
and utilize a simple trajectory planning technique to move the PSMs") by the one throw planner,
:func:`suture_lfd.planning.throw.plan_throw` (reachable grasps, minimum-jerk motions, grasp and
release gates), which the scripted expert uses too: the two differ only in the needle paths they
pass for ii and iv. Subtasks ii (insertion, PSM2) and iv (extraction, PSM1) come from the
skill's DMPs: the needle start and goal on the target pair are derived from the demonstrated pair's
(:meth:`ThrowSkill.start_goal`), the DMP rollout is the needle trajectory, and the tool targets
streamed to the arm are ``T_world_needle(t) @ inv(T_tool_needle)`` with the grasp
``T_tool_needle`` **measured** when the arm took the needle. With phase stopping on, the plan
clock of a DMP subtask slows by ``1 + k_p |e_p|^2 + k_o e_o^2`` (Ijspeert et al. 2013) when the
measured needle pose lags the rollout. On tissue the rollouts are aimed along the needle's
arc (:mod:`suture_lfd.skill.arc_aim`) so the needle pushes the tissue less sideways.

:class:`ThrowExecutor` is a controller (``reset(obs)``, ``step(obs) -> Command``, ``done``) for
:meth:`sim_bridge.simulation.Simulation.run` or for a ROS node; :func:`execute_throw` runs one
throw in-process and returns a :class:`ThrowOutcome`.

Frames: ``world``; poses 4x4 ``T_world_*`` or 7-vectors ``(x, y, z, qx, qy, qz, qw)``; SI units.

Size: the executor's controller and the in-process throw it runs share one plan and its recorder;
it is on the per-throw path being made faster, so it stays one file.
"""

from collections.abc import Callable
from dataclasses import dataclass, field, replace
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import matrix_from_quaternion, pose_from_transform
from sim_bridge.common.vocabulary import SUBTASKS, TASKS
from sim_bridge.control import ExpertConfig
from sim_bridge.observers import PhysicalObserver
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.grasps import GraspPlanner
from suture_lfd.planning.plan import PlanFollower
from suture_lfd.planning.throw import Carry, Follow, Hold, ThrowPaths, drive_grasp_s, plan_throw
from suture_lfd.planning.throw_geometry import ThrowArc
from suture_lfd.planning.tracks import TimedNeedleMove, translated
from suture_lfd.planning.waypoints import RigidPath, rotation_exp, rotation_log
from suture_lfd.skill import PairGeometry, ThrowSkill
from suture_lfd.skill.arc_aim import aim_along_arc
from suture_lfd.skill.arm_registration import CorrectedController, register_arms
from suture_lfd.skill.perceived import PerceivedScene, SceneLayout
from suture_lfd.skill.slip_watch import TISSUE_LOOKS, SlipWatch, holding_arm, slip_checkpoints
from suture_lfd.skill.tool_tracking import ToolTracking

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.control import Command, Observation
    from sim_bridge.scene.markers import MarkerPair
    from sim_bridge.simulation import Simulation
    from suture_lfd.planning.plan import Plan
    from suture_lfd.skill.arm_registration import KinematicCorrection

__all__ = ['ExecutorConfig', 'ThrowExecutor', 'ThrowOutcome', 'execute_throw']


# Grasp search along the needle (arc parameter: 0 tail, 1 tip): the span kept between the two
# jaws (about 2.5 mm of wire), and the highest parameter (the jaw keeps off the point).
_JAW_GAP_S = 0.15
_TIP_MARGIN_S = 0.97
# Part of the insertion (fraction of its duration) over which the start press fades out.
_PRESS_FADE = 0.25
# How squarely (|cos| of the plane normal to the line of sight) the carried needle should face
# the camera when the grasp is looked at again, and the range a look is taken in at all: seen
# face on, as it lay, the pair adds little; edge-on, little of the wire shows.
_LOOK_FACING = 0.6
_LOOK_FACING_RANGE = (0.3, 0.85)
_LOOK_STEP = 0.05  # s between the planned instants whose facing is compared


@dataclass(frozen=True)
class ExecutorConfig:
    """
    Settings of the scripted parts and of the DMP streaming.

    Attributes
    ----------
    script : sim_bridge.control.ExpertConfig
        Motion parameters of the scripted subtasks i, iii, v (speeds, grasps, lifts);
        :func:`execute_throw` uses the scene's ``expert`` section (``config/scene.yaml``)
        unless a config is given.
    phase_stopping : bool
        Slow the DMP clock while the measured needle lags the rollout (off by default: with
        exact tracking in-process it changes nothing, and over DDS, where every measurement
        lags the command by the transport latency, it stretches and jerks the insertion enough
        to back the tip out of its puncture).
    phase_stop_position : float
        Gain on the squared position error, 1/m^2.
    phase_stop_orientation : float
        Gain on the squared orientation error, 1/rad^2.
    start_lift : float
        Height (m, along the pair normal) above the DMP ii start from which the needle is
        lowered onto it.
    start_press : float
        Depth (m, against the pair normal) by which the start of the insertion is moved into
        the tissue, fading linearly to 0 over its first quarter: the demonstrated start has
        the tip only just in, so the rollout's small deviations from the demonstration (or a
        curved surface) could pull it back out.
    physical_start_press : float
        ``start_press`` (m) in physical mode: the tool and the grasp are known there to a few
        tenths of a millimetre only (the registration's residual, the needle seen lying), so
        the tip lowered onto the entry can already be in when the insertion starts and backed
        out by the rollout's first motion; pressed this deep, such an error leaves it in.
    hold_press : bool
        Keep the start press until the rollout's own tip has gone that deep below its start,
        instead of fading it out over the first quarter of the insertion (physical mode: a
        skill learnt on what a robot saw can start its tip a few tenths of a millimetre high
        and go down slowly, and a grasp known to a few tenths adds as much; faded by time,
        the press left the tip in the puncture's mouth and the first turn pulled it out).
    final_approach_time : float
        Shortest time (s) of lowering the needle from ``start_lift`` onto the DMP ii start
        (the tip onto the entry marker): slow, so a lagging arm does not overshoot into the
        tissue.
    carry_lift : float
        Height (m, along the pair normal) above ``start_lift`` at which subtask i's carry
        ends; the needle is then lowered to ``start_lift`` before the slow final approach (0:
        the carry ends at ``start_lift``). The carry turns the needle from where it lay into
        the insertion's pose on a straight path, its tip sweeping low on the way; ending it
        higher keeps the tip off a pad it passes over.
    physical_carry_lift : float
        ``carry_lift`` (m) in physical mode: a tool known to a few millimetres across the
        workspace (a ``dvrk``-like arm away from where it was registered) let the turning tip
        graze a curved pad mid-carry, an entry far from the marker.
    resend_unchanged : bool
        Send a tool target every step even when it equals the last one sent (False: send
        None, so a resting arm is not asked to solve its inverse kinematics again).
    slip_turn, slip_shift : float
        During the DMP subtasks, a grasp observed to differ from the one followed by more than
        this turn (rad) or shift (m) means the needle slipped in the jaw: the observed grasp is
        followed from then on, so the needle -- not the tool -- keeps to the rollout (ground
        truth: the grasp is observed every step; taken once the slip is over; see
        :mod:`suture_lfd.skill.slip_watch`).
    slip_corrections : int
        Most grasps taken again so per DMP subtask in ground truth.
    arc_aim : bool
        Aim the needle along its own arc inside the tissue: the planned insertion and
        extraction are shifted so the needle's circle keeps through the punctures the planned
        tip makes (:mod:`suture_lfd.skill.arc_aim`; on the executor's belief of the pair and of
        the rollout), so the needle pushes the tissue less sideways.
    aim_on_tissue : bool
        Switch ``arc_aim`` on for throws on tissue (:meth:`on_tissue`): off, a throw without
        tissue realism is planned as before.
    slip_looks : int
        In physical mode, how many times the holding arm's grasp is looked at again during each
        DMP subtask (evenly spread; 0: never; on tissue the needle can turn in the jaw).
    fit_wrist : bool
        In physical mode with the registration, fit the carrying arm's wrist roll and pitch
        offsets with its grasp (:meth:`suture_lfd.skill.perceived.PerceivedScene.
        look_at_grasp`), from the needle seen lying and held at two wrist poses of the carry
        (a second look where the wrist has turned furthest from the first), and correct the
        arm with them from then on: the registration sees the wrist too weakly to fit them, and
        a grasp alone takes them up at the wrist pose it was seen at only. Off by default: at
        the ``dvrk`` preset it did not raise the score (``doc/explanation/realism_arm.md``).
    track_tool : bool
        In physical mode with the registration, bring each tool onto its targets during the
        DMP subtasks from where it is seen (:class:`suture_lfd.skill.tool_tracking.
        ToolTracking`: an integral loop on the corrected tool pose). Off by default.

    """

    script: ExpertConfig = field(default_factory=ExpertConfig)
    phase_stopping: bool = False
    phase_stop_position: float = 1.0e6
    phase_stop_orientation: float = 100.0
    start_lift: float = 0.005
    start_press: float = 0.0003
    physical_start_press: float = 0.0008
    hold_press: bool = False
    final_approach_time: float = 1.0
    carry_lift: float = 0.0
    physical_carry_lift: float = 0.007
    resend_unchanged: bool = False
    slip_turn: float = 0.0035
    slip_shift: float = 0.0001
    slip_looks: int = 0
    slip_corrections: int = 1
    arc_aim: bool = False
    aim_on_tissue: bool = True
    fit_wrist: bool = False
    track_tool: bool = False

    def in_physical_mode(self) -> 'ExecutorConfig':
        """
        Return these settings as a controller on what a robot shows runs them.

        The one place physical mode changes the executor's settings (in-process and in the
        executor node alike): ``start_press`` becomes ``physical_start_press``, held
        (``hold_press``), and ``carry_lift`` becomes ``physical_carry_lift``.
        """
        return replace(self, start_press=self.physical_start_press, hold_press=True,
                       carry_lift=self.physical_carry_lift)

    def on_tissue(self) -> 'ExecutorConfig':
        """
        Return these settings for a throw on tissue, where the needle can turn in the jaw.

        The one place the tissue realism changes the executor's settings (in-process and in the
        executor node alike): in physical mode the grasp is looked at again
        :data:`~suture_lfd.skill.slip_watch.TISSUE_LOOKS` times per DMP subtask, unless
        ``slip_looks`` already asks for looks; with ``aim_on_tissue`` the needle is aimed along
        its arc (``arc_aim``).
        """
        return replace(self, slip_looks=self.slip_looks or TISSUE_LOOKS,
                       arc_aim=self.arc_aim or self.aim_on_tissue)


class SampledPath:
    """
    Needle path through sampled poses (a DMP rollout), linear in the sample index.

    Parameters
    ----------
    poses : ndarray, shape (n, 4, 4)
        ``T_world_needle`` samples, evenly spaced in time.

    """

    def __init__(self, poses: ArrayLike) -> None:
        poses = np.asarray(poses, dtype=float)
        if poses.ndim != 3 or poses.shape[0] < 2 or poses.shape[1:] != (4, 4):
            raise ValueError(f'a sampled path needs (n >= 2, 4, 4) poses, got {poses.shape}')
        self.poses = poses
        self._p = poses[:, :3, 3]
        self._R = poses[:, :3, :3]
        self._w = np.array([rotation_log(self._R[k].T @ self._R[k + 1])
                            for k in range(len(poses) - 1)])

    @property
    def A(self) -> np.ndarray:  # noqa: N802 (pose names follow the project's T_a_b style)
        """First pose (4, 4)."""
        return self.poses[0].copy()

    @property
    def B(self) -> np.ndarray:  # noqa: N802
        """Last pose (4, 4)."""
        return self.poses[-1].copy()

    @property
    def angle(self) -> float:
        """Summed rotation angle (rad)."""
        return float(np.linalg.norm(self._w, axis=1).sum())

    @property
    def distance(self) -> float:
        """Path length of the needle origin (m)."""
        return float(np.linalg.norm(np.diff(self._p, axis=0), axis=1).sum())

    def pieces(self, n: int) -> list['_SubPath']:
        """Split into ``n`` consecutive paths (callables of ``sigma`` in [0, 1])."""
        edges = np.linspace(0.0, 1.0, n + 1)
        return [_SubPath(self, a, b) for a, b in zip(edges[:-1], edges[1:])]

    def __call__(self, sigma: float) -> np.ndarray:
        """Needle pose (4, 4) at path parameter ``sigma`` in [0, 1]."""
        x = min(1.0, max(0.0, float(sigma))) * (len(self.poses) - 1)
        k = min(int(x), len(self.poses) - 2)
        u = x - k
        T = np.eye(4)
        T[:3, :3] = self._R[k] @ rotation_exp(u * self._w[k])
        T[:3, 3] = (1.0 - u) * self._p[k] + u * self._p[k + 1]
        return T


class _SubPath:
    """The part ``[a, b]`` of a path, re-parametrised to [0, 1]."""

    def __init__(self, path: SampledPath, a: float, b: float) -> None:
        self.path, self.a, self.b = path, float(a), float(b)

    def __call__(self, sigma: float) -> np.ndarray:
        return self.path(self.a + sigma * (self.b - self.a))


DmpMove = TimedNeedleMove  # a segment of a plan that follows a DMP rollout


def _transforms(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    T = np.zeros((len(P), 4, 4))
    T[:, :3, :3] = matrix_from_quaternion(Q)
    T[:, :3, 3] = P
    T[:, 3, 3] = 1.0
    return T


def _emerged_s(needle: 'NeedleGeometry', N: np.ndarray, pair: 'MarkerPair') -> float | None:
    """Smallest arc parameter of the tip part beyond the exit (outside the tissue), or None."""
    s = np.linspace(0.0, 1.0, 61)
    pts = needle.point_at(s) @ N[:3, :3].T + N[:3, 3]
    outside = (pts - pair.midpoint) @ pair.normal > 0.0
    beyond = (pts - pair.midpoint) @ (pair.exit - pair.entry) > 0.0
    ok = outside & beyond
    if not ok[-1]:
        return None
    k = len(s) - 1
    while k > 0 and ok[k - 1]:
        k -= 1
    return float(s[k])


class ThrowExecutor:
    """
    Controller of one throw: scripted i, iii, v and DMP-driven ii, iv.

    Parameters
    ----------
    skill : ThrowSkill
        The learnt skill.
    pair : sim_bridge.scene.phantom.MarkerPair
        Target pair (``world``).
    needle_geometry : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    kinematics : sim_bridge.kinematics.PsmKinematics or dict, optional
        PSM kinematics used to choose reachable grasps.
    config : ExecutorConfig, optional
        Settings.
    next_pair : sim_bridge.scene.phantom.MarkerPair, optional
        Pair of the next throw (PSM2 ends above it).
    look : callable, optional
        ``look(arm, obs) -> T_tool_needle or None``: look at the needle ``arm`` holds and
        return its grasp as seen. Given, the executor closes its loop where the skill needs
        it: while PSM2 carries the needle towards the insertion start, the grasp is measured
        again and the rest of the approach brings the needle -- its tip onto the entry marker
        -- where the rollout starts, as seen.
    facing : callable, optional
        ``facing(T_world_needle) -> float``: how squarely a needle pose faces the camera
        (``|cos|``, 1 face on). Given with ``look``, the look is taken at the planned instant
        of the carry where the needle faces the camera nearest ``0.6`` (turned from how it lay,
        its tilt shows); without it, or when no instant is in ``0.3``-``0.85``, above the
        insertion start.
    frame_time : callable, optional
        ``frame_time() -> float or None``: the scene time (s, the observations' clock) of the
        newest frame the endoscope has delivered; None for a camera whose images are of now.
        Given, a look falls due at its planned instant and is taken once a frame of that
        instant or later has arrived (an endoscope's latency later), so that the images show
        the needle as planned for the look, not as it was a few frames before.

    Attributes
    ----------
    rollouts : dict of str to tuple
        After :meth:`reset`: ``'ii'``, ``'iv'`` -> ``(T, P, Q)`` planned needle trajectories
        (times from the subtask start, s; ``world``; ii with its start pressed
        ``start_press`` into the tissue).
    targets : dict of str to tuple
        ``'ii'``, ``'iv'`` -> ``(start, goal)`` needle poses (7-vectors) on the target pair.

    """

    def __init__(self, skill: ThrowSkill, pair: Any, needle_geometry: 'NeedleGeometry',
                 kinematics: Any = None, config: 'ExecutorConfig | None' = None,
                 next_pair: 'MarkerPair | None' = None,
                 look: 'Callable[[str, Observation], np.ndarray | None] | None' = None,
                 facing: 'Callable[[np.ndarray], float] | None' = None,
                 frame_time: 'Callable[[], float | None] | None' = None) -> None:
        self.executor_config = ExecutorConfig() if config is None else config
        self.config = self.executor_config.script
        if not isinstance(skill, ThrowSkill):
            raise ValueError(f'skill must be a ThrowSkill, got {type(skill).__name__}')
        self.skill = skill
        self.pair = pair
        self.needle = needle_geometry
        self.next_pair = next_pair
        self.grasps = GraspPlanner(pair, needle_geometry, self.config, kinematics)
        self.kinematics = self.grasps.kinematics
        self.rollouts: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.targets: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.plan_: 'Plan | None' = None
        self.follower: PlanFollower | None = None
        self.look = look
        self.facing = facing
        self.frame_time = frame_time
        self._due: float | None = None  # when the next look fell due (observations' clock)
        self._above: np.ndarray | None = None
        self._checks: list[tuple[float, str]] = []
        cfg = self.executor_config
        self.slip_watch = SlipWatch(cfg.slip_turn, cfg.slip_shift, cfg.slip_corrections)

    # ------------------------------------------------------------------ planning
    def rollout_paths(self) -> ThrowPaths:
        """
        Roll the skill's DMPs out on the target pair and return the throw's needle paths.

        Sets :attr:`rollouts` and :attr:`targets`.

        Returns
        -------
        suture_lfd.planning.throw.ThrowPaths
            The insertion (ii) and extraction (iv) follow the rollouts with their own timing;
            subtask i lowers the needle onto the insertion start (at least
            ``final_approach_time``) and settles.

        Raises
        ------
        ValueError
            If a rollout diverges.

        """
        c = self.config
        g = self.needle
        pair = self.pair
        skill = self.skill
        arc = ThrowArc(pair, g)
        deg = math.radians
        normal = np.asarray(pair.normal, dtype=float)

        # ii from the DMP: start/goal on this pair, rollout in world.
        start2, goal2 = skill.start_goal('ii', pair, needle=g)
        T2, P2, Q2 = skill.rollout('ii', pair, start=start2, goal=goal2, needle=g,
                                   targets=(start2, goal2))
        # The demonstrated insertion starts with the tip barely in the tissue; pressed a little
        # deeper, the rollout's own small deviations from the demonstration cannot lift the tip
        # back out through its puncture. The press fades out over the first part of the
        # insertion, so the needle crosses the exit and ends it where the rollout does.
        press = self.executor_config.start_press
        if self.executor_config.hold_press and press > 0.0:
            # held until the rollout's tip has gone as deep itself
            tips = np.einsum('kij,j->ki', matrix_from_quaternion(Q2), g.point_at(1.0)) + P2
            descent = np.maximum.accumulate(np.maximum(0.0, (tips[0] - tips) @ normal))
            fade = np.clip(1.0 - descent / press, 0.0, 1.0)[:, None]
        else:
            fade = np.clip(1.0 - np.linspace(0.0, 1.0, len(P2)) / _PRESS_FADE, 0.0,
                           1.0)[:, None]
        P2 = P2 - press * fade * normal
        R2 = _transforms(P2, Q2)
        aim = self.executor_config.arc_aim
        if aim:
            R2, punctures = aim_along_arc(T2, R2, g, pair.entry, pair.exit, normal)
            P2 = R2[:, :3, 3].copy()
        S2 = R2[0]
        S2_hi = translated(S2, self.executor_config.start_lift * normal)
        N_ins = R2[-1]
        start4, goal4 = skill.start_goal('iv', pair, needle=g)
        T4, P4, Q4 = skill.rollout('iv', pair, start=pose_from_transform(N_ins), goal=goal4,
                                   needle=g, targets=(start4, goal4))
        R4 = _transforms(P4, Q4)
        if aim:
            R4, _ = aim_along_arc(T4, R4, g, pair.entry, pair.exit, normal, punctures)
            P4 = R4[:, :3, 3].copy()
        N_lift = R4[-1]
        self.rollouts = {'ii': (T2, P2, Q2), 'iv': (T4, P4, Q4)}
        self.targets = {'ii': (start2, goal2), 'iv': (pose_from_transform(N_ins), goal4)}
        path2, path4 = SampledPath(R2), SampledPath(R4)
        if self.next_pair is not None:
            nxt = PairGeometry.of(self.next_pair)
            start_next = skill.start_goal('ii', nxt, needle=g)[0]
            S_next = _transforms(start_next[None, :3], start_next[None, 3:])[0]
            N_next = translated(S_next, (self.executor_config.start_lift + c.next_lift)
                                 * np.asarray(self.next_pair.normal))
        else:
            N_next = translated(S2_hi, c.next_lift * normal)

        s_g = drive_grasp_s(arc, g, c)
        s_out = _emerged_s(g, N_ins, pair)
        if s_out is None:
            s_1 = 1.0 - 0.5 * deg(c.protrusion_deg) / g.arc
        else:
            s_1 = 0.5 * (1.0 + s_out)
        # The extraction grasp closes on the part of the needle out of the exit, the hand-over
        # grasp anywhere on the needle off PSM1's jaw: the preferred arc parameter first, then
        # the others of that span (a rollout on another pair can put the preferred one out of
        # the arm's reach).
        lo_1 = s_g + _JAW_GAP_S if s_out is None else s_out + 0.25 * (1.0 - s_out)
        lowered = Carry(RigidPath(S2_hi, S2),
                        min_duration=self.executor_config.final_approach_time)
        above, reach = S2_hi, [RigidPath(S2_hi, S2)]
        approach: tuple[Carry | Hold, ...] = (lowered, Hold(c.settle_time))
        carry_lift = self.executor_config.carry_lift
        if carry_lift > 0.0:
            above = translated(S2_hi, carry_lift * normal)
            approach = (Carry(RigidPath(above, S2_hi)),) + approach
            reach = [RigidPath(above, S2_hi)] + reach
        return ThrowPaths(
            above=above,
            approach=approach,
            insertion=(Follow(path2, skill.duration('ii')),),
            insertion_reach=tuple(reach + path2.pieces(3)),
            insertion_clear=tuple(path2(x) for x in np.linspace(0.0, 1.0, 9)),
            insertion_end=N_ins,
            extraction=(Follow(path4, skill.duration('iv')),),
            extraction_reach=tuple(path4.pieces(4)), extraction_clear=(N_ins,),
            extraction_end=N_lift, next_pose=N_next,
            extract_s=s_1, extract_span=(lo_1, _TIP_MARGIN_S), handover_gap=_JAW_GAP_S,
            handover_fallback=True)

    def plan(self, obs: 'Observation') -> 'Plan':
        """
        Plan the whole throw from an observation (DMP rollouts included).

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Start state.

        Returns
        -------
        suture_lfd.planning.plan.Plan

        Raises
        ------
        ValueError
            If no grasp keeps a holding phase inside the arms' reach.

        """
        paths = self.rollout_paths()
        self._above = paths.above
        return plan_throw(obs, self.grasps, ThrowArc(self.pair, self.needle), paths, self.config)

    # ------------------------------------------------------------------ control
    def reset(self, obs: 'Observation') -> None:
        """
        Plan the throw from ``obs``; its clock starts at the next :meth:`step`.

        Planning takes a while; where the scene runs on meanwhile (a simulator node), starting
        the clock at the first command keeps the plan from starting part-way through.
        """
        self.plan_ = self.plan(obs)
        self.follower = PlanFollower(self.plan_, None, self.config.gate_timeout)
        self._sent: dict[str, np.ndarray] = {}
        self._checks = [] if self.look is None else self._checkpoints()
        self._due = None
        looks = self.executor_config.slip_looks
        if self.look is not None and looks > 0:
            looks_at = slip_checkpoints(list(self.plan_.labels), looks)
            self._checks = sorted(self._checks + looks_at)
        self.slip_watch.reset()

    @property
    def slips_noticed(self) -> int:
        """Grasps taken again this throw because the needle turned in the jaw (ground truth)."""
        return self.slip_watch.noticed

    def _notice_slip(self, obs: 'Observation', tau: float) -> None:
        """Follow the grasp observed once the needle turned in the jaw (:class:`SlipWatch`)."""
        assert self.plan_ is not None and self.follower is not None
        label = self.plan_.label(tau)
        if label not in TASKS or obs.T_world_needle is None:
            return
        arm = holding_arm(label)
        if arm not in obs.holders:
            return
        grasp = self.slip_watch.notice(label, self.follower.grasp(arm), obs.T_world_tool[arm],
                                       obs.T_world_needle)
        if grasp is not None:
            self.follower.set_grasp(arm, grasp)

    def _checkpoints(self) -> list[tuple[float, str]]:
        """Plan time (s) and arm at which to look at the held needle (see ``facing``)."""
        assert self.plan_ is not None and self._above is not None  # set by plan()
        segments = [seg for seg in self.plan_.segments['PSM2']
                    if seg.carries_needle and seg.t0 > 0.0]
        above = next((seg.t0 for seg in segments
                      if np.allclose(seg.needle(seg.t0), self._above, atol=1e-9)), None)
        if above is None:
            return []
        if self.facing is None:
            return [(above, 'PSM2')]
        lo, hi = _LOOK_FACING_RANGE
        best: tuple[float, float] | None = None
        seen = []  # the instants the needle can be looked at
        for seg in segments:
            for t in np.arange(seg.t0, min(seg.t1, above), _LOOK_STEP):
                f = self.facing(seg.needle(float(t)))
                if lo <= f <= hi:
                    seen.append(float(t))
                    if best is None or abs(f - _LOOK_FACING) < best[0]:
                        best = (abs(f - _LOOK_FACING), float(t))
        if best is None:
            return [(above, 'PSM2')]
        looks = [(best[1], 'PSM2')]
        if self.executor_config.fit_wrist:
            # a second look where the wrist has turned furthest from the first: the wrist's
            # offsets show between the two
            far = max(seen, key=lambda t: abs(t - best[1]))
            if abs(far - best[1]) >= 2 * _LOOK_STEP:
                looks = sorted(looks + [(far, 'PSM2')])
        return looks

    def _shown(self, obs: 'Observation') -> bool:
        """Whether the endoscope has delivered a frame of the instant the due look fell due."""
        if self._due is None:
            self._due = float(obs.t)
        shown = None if self.frame_time is None else self.frame_time()
        return shown is None or shown >= self._due - 1e-9

    @property
    def done(self) -> bool:
        """Whether the plan has run to its end."""
        return self.follower is not None and self.follower.done

    def step(self, obs: 'Observation') -> 'Command':
        """
        Command for the observation (phase stopping during the DMP subtasks).

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Current state.

        Returns
        -------
        sim_bridge.control.Command

        """
        if self.plan_ is None:
            self.reset(obs)
        assert self.follower is not None and self.plan_ is not None  # set by reset()
        follower = self.follower
        if follower.t0 is None:
            follower.t0 = self._last_t = float(obs.t)
        cfg = self.executor_config
        dt = float(obs.t) - self._last_t
        self._last_t = float(obs.t)
        if cfg.phase_stopping and dt > 0.0:
            tau = follower.tau(obs.t)
            label = self.plan_.label(tau)
            if label in TASKS:
                arm = holding_arm(label)
                seg = self.plan_.segment_at(arm, tau)
                if isinstance(seg, DmpMove) and arm in obs.holders:
                    N = seg.needle(tau)
                    M = np.asarray(obs.T_world_needle)
                    e_p = float(np.sum((M[:3, 3] - N[:3, 3]) ** 2))
                    c_ang = 0.5 * (float(np.sum(M[:3, :3] * N[:3, :3])) - 1.0)
                    e_o = math.acos(max(-1.0, min(1.0, c_ang))) ** 2
                    slow = 1.0 + cfg.phase_stop_position * e_p + cfg.phase_stop_orientation * e_o
                    follower.offset += dt * (1.0 - 1.0 / slow)
        if self.look is None:
            self._notice_slip(obs, follower.tau(obs.t))
        if self._checks and follower.tau(obs.t) >= self._checks[0][0] and self._shown(obs):
            _, arm = self._checks.pop(0)
            self._due = None
            assert self.look is not None  # checkpoints are set only with look
            grasp = self.look(arm, obs) if arm in obs.holders else None
            if grasp is not None:
                follower.set_grasp(arm, grasp)
        cmd = follower.step(obs)
        if not cfg.resend_unchanged:
            tools = cmd.T_world_tool  # the follower's new dict, this command's own
            for arm, T in tools.items():
                last = self._sent.get(arm)
                if last is not None and (last == T).all():  # both (4, 4)
                    tools[arm] = None
                else:
                    self._sent[arm] = T
        return cmd


@dataclass(frozen=True, eq=False)
class ThrowOutcome:
    """
    Result of one executed throw.

    Attributes
    ----------
    pair : str
        Target pair.
    score : float
        The paper's generality score (1, 0.8, 0.4, 0).
    subtasks : dict of str to bool
        Success of ``'i'`` .. ``'v'``.
    duration : float
        Time (s) from the start of the throw to the completed hand-over (or to the end of the
        run if it did not complete).
    failure : str
        Failure reasons (empty when the throw is complete); ``'unreachable: ...'`` when the
        throw cannot be planned: no reachable grasp carries the needle along the rollouts, or
        a rollout diverges (nothing was executed).
    entry_error_mm, exit_error_mm : float
        Tip crossing distances from the markers (NaN when missing).
    executed : dict of str to tuple
        ``'ii'``, ``'iv'`` -> ``(t (n,), poses (n, 7))``: measured needle poses (``world``)
        while the plan was in that subtask; times from the start of the subtask, s.
    rollouts : dict of str to tuple
        ``'ii'``, ``'iv'`` -> ``(T, P, Q)`` DMP rollouts (``world``).
    targets : dict of str to tuple
        ``'ii'``, ``'iv'`` -> desired ``(start, goal)`` needle poses (7-vectors).
    subtask_times : dict of str to tuple
        ``'i'`` .. ``'v'`` -> ``(start, end)`` of the executed subtasks (s from the start).
    events : list of dict
        Scene events ``{'t', 'kind', ...}`` (score events carry the score as a dict).
    score_detail : object
        The simulator's :class:`sim_bridge.scene.scoring.ThrowScore`.

    """

    pair: str
    score: float
    subtasks: dict
    duration: float
    failure: str
    entry_error_mm: float
    exit_error_mm: float
    executed: dict
    rollouts: dict
    targets: dict
    subtask_times: dict
    events: list
    score_detail: object = None


class _Recorder:
    """Wraps a controller and records the needle pose per subtask label."""

    def __init__(self, controller: Any, observer: Callable[[], object] | None = None) -> None:
        self.controller = controller
        self.observer = observer
        self.t0: float | None = None
        self.samples: dict[str, list[tuple[float, np.ndarray]]] = {}
        self.spans: dict[str, tuple[float, float]] = {}

    def step(self, obs: 'Observation') -> 'Command':
        cmd = self.controller.step(obs)
        if self.observer is not None:
            self.observer()
        if self.t0 is None:
            self.t0 = float(obs.t)
        t = float(obs.t) - self.t0
        label = cmd.subtask
        span = self.spans.get(label)
        self.spans[label] = (t, t) if span is None else (span[0], t)
        if label in TASKS:
            self.samples.setdefault(label, []).append((t, np.asarray(obs.T_world_needle)))
        return cmd

    def executed(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for label, rows in self.samples.items():
            t0 = self.spans[label][0]
            t = np.array([r[0] for r in rows]) - t0
            poses = pose_from_transform(np.array([r[1] for r in rows]))
            out[label] = (t, poses)
        return out


def _event_dict(ev: Any) -> dict[str, Any]:
    data = {}
    for key, value in ev.data.items():
        if isinstance(value, np.ndarray):
            value = value.tolist()
        elif hasattr(value, 'score') and hasattr(value, 'subtasks'):
            value = {'score': value.score, 'subtasks': dict(value.subtasks),
                     'failure': value.failure}
        data[key] = value
    return {'t': float(ev.t), 'kind': ev.kind, **data}


def execute_throw(sim: 'Simulation', skill: ThrowSkill, pair_name: str, seed: int = 0,
                  timeout: float = 60.0, config: 'ExecutorConfig | None' = None,
                  control_period: float = 0.01, next_pair: str | None = None,
                  observer: Callable[[], object] | None = None, physical: bool = False,
                  correction: bool = True) -> 'ThrowOutcome':
    """
    Execute one throw of a skill on a marker pair of an in-process simulation.

    The scene is reset with ``seed``, the arms are enabled and homed, the pair is made the
    target, and the :class:`ThrowExecutor` runs until its plan is done (plus a short settle) or
    ``timeout`` seconds of simulated time have passed.

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
        The scene (its phantom must have the pair).
    skill : ThrowSkill
        Learnt skill.
    pair_name : str
        Target pair (``'synth1'`` ..).
    seed : int
        Scene seed (needle start pose).
    timeout : float
        Longest simulated time (s) of the throw.
    config : ExecutorConfig, optional
        Executor settings (default: scripted parts as the scene's expert).
    control_period : float
        Time (s) between controller steps (a multiple of the physics step).
    next_pair : str, optional
        Pair of the next throw (PSM2 ends above it).
    observer : callable, optional
        Called without arguments at every controller step, after the command is chosen (a
        replay sampler reads the scene then).
    physical : bool
        Execute on what a physical dVRK provides (:class:`sim_bridge.observers.PhysicalObserver`
        with :class:`suture_lfd.skill.perceived.PerceivedScene`): the arms' reported poses, the
        markers and the needle from the stereo pair, each grasp measured when a jaw closes.
        A throw whose markers or needle cannot be seen at the start is not pushed: score 0,
        ``failure`` says what was not seen.
    correction : bool
        In physical mode, close the loop on what the camera sees
        (:mod:`suture_lfd.skill.arm_registration`: each PSM registered against the endoscope
        once per simulation, its tool seen where it truly is and commanded there; the needle
        looked at again whenever the arms let go of it). False: open loop on the arms' own
        kinematics, the scene perceived at the start only. Ignored in ground-truth mode.

    Returns
    -------
    ThrowOutcome

    Raises
    ------
    ValueError
        If the pair is unknown (the message lists the phantom's pairs).

    """
    if pair_name not in sim.phantom.markers:
        raise ValueError(f'unknown marker pair {pair_name!r}; the phantom has '
                         f'{sorted(sim.phantom.markers)}')
    kinematic = register_arms(sim) if physical and correction else None
    pair = start_episode(sim, pair_name, seed)
    sim.pop_events()
    if physical:
        previous = sim.observer
        perception = PerceivedScene(pair_name, pair.index, sim.needle_geometry,
                                    look_again=correction, layout=scene_layout(sim))
        sim.observer = PhysicalObserver(sim, perception, correction=kinematic)
        try:
            return _execute_on_what_is_seen(sim, skill, pair_name, perception, timeout, config,
                                            control_period, next_pair, observer, kinematic)
        finally:
            sim.observer = previous
    return _execute(sim, skill, pair_name, pair, timeout, config, control_period, next_pair,
                    observer)


def scene_layout(sim: 'Simulation') -> SceneLayout:
    """
    Return the scene's layout by design: the phantom's markers, the needle's nominal start.

    The needle is put at the start's position and yaw (``loop.needle_start``, without the
    seed's jitter), on the support under it, tilted as its surface is there (the phantom's
    shape); a physical set-up knows as much of where its operator lays the needle.
    """
    start = sim.config.loop.needle_start
    c, s = math.cos(start.yaw), math.sin(start.yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:2, 3] = np.asarray(start.position, dtype=float)
    T = sim.physics.laid_on_support(T)
    pairs = sorted(sim.phantom.markers.values(), key=lambda m: m.index)
    return SceneLayout(T_world_needle=T,
                       markers=np.array([[m.entry, m.exit] for m in pairs], dtype=float))


def _not_executed(pair_name: str, failure: str,
                  executor: ThrowExecutor | None = None) -> 'ThrowOutcome':
    """Outcome of a throw that could not start (score 0, the reason kept)."""
    return ThrowOutcome(pair=pair_name, score=0.0, subtasks=dict.fromkeys(SUBTASKS, False),
                        duration=0.0, failure=failure, entry_error_mm=math.nan,
                        exit_error_mm=math.nan, executed={},
                        rollouts={} if executor is None else dict(executor.rollouts),
                        targets={} if executor is None else dict(executor.targets),
                        subtask_times={}, events=[], score_detail=None)


def _execute_on_what_is_seen(sim: 'Simulation', skill: ThrowSkill, pair_name: str,
                             perception: PerceivedScene, timeout: float,
                             config: 'ExecutorConfig | None', control_period: float,
                             next_pair: str | None, observer: Callable[[], object] | None,
                             kinematic: 'KinematicCorrection | None') -> 'ThrowOutcome':
    """Check that the markers and the needle are seen, then execute on the perceived pair."""
    seen = perception.markers(sim)
    if seen is None:
        return _not_executed(pair_name, f'not seen: the markers of pair {pair_name}')
    if sim.observation().T_world_needle is None:
        return _not_executed(pair_name, 'not seen: the needle')
    return _execute(sim, skill, pair_name, seen, timeout, config, control_period, next_pair,
                    observer, kinematic, perception if kinematic is not None else None,
                    physical=True)


def _execute(sim: 'Simulation', skill: ThrowSkill, pair_name: str, pair: 'MarkerPair',
             timeout: float, config: 'ExecutorConfig | None', control_period: float,
             next_pair: str | None, observer: Callable[[], object] | None,
             kinematic: 'KinematicCorrection | None' = None,
             perception: PerceivedScene | None = None,
             physical: bool = False) -> 'ThrowOutcome':
    """Execute a throw on ``pair`` (as the controller sees it) from the started episode."""
    if config is None:
        config = ExecutorConfig(script=sim.config.scene.expert)
    if physical:
        config = config.in_physical_mode()
    tissue = sim.config.tissue_realism
    if tissue is not None and tissue.active:
        config = config.on_tissue()
    nxt = sim.phantom.markers[next_pair] if next_pair is not None else None
    look = facing = None
    if perception is not None:
        def look(arm: str, obs: 'Observation') -> np.ndarray | None:
            fit = None if kinematic is None or not config.fit_wrist else kinematic.arms.get(arm)
            if fit is None:
                return perception.look_at_grasp(sim, arm, obs.T_world_tool)
            grasp = perception.look_at_grasp(sim, arm, obs.T_world_tool, obs.q,
                                             fit.wrist_change, fit.joint_offset[3:5])
            offsets = perception.wrist_offsets(arm)
            # the grasp is against the tool so corrected
            if offsets is not None and kinematic is not None:
                kinematic.set_arm(fit.with_wrist_offset(offsets))
            return grasp

        def facing(T_world_needle: np.ndarray) -> float:
            return perception.facing(sim, T_world_needle)
    executor = ThrowExecutor(skill, pair, sim.needle_geometry, kinematics=sim.kinematics['PSM1'],
                             config=config, next_pair=nxt, look=look, facing=facing,
                             frame_time=None if perception is None else sim.delivered_frame)
    tracked = (ToolTracking(executor) if config.track_tool and kinematic is not None
               else executor)
    controller = executor if kinematic is None else CorrectedController(tracked, kinematic)
    recorder = _Recorder(controller, observer)
    t_start = sim.time
    try:
        executor.reset(sim.observation())
    except ValueError as exc:
        # No reachable grasp carries the needle along the rollouts on this pair: the throw
        # cannot be executed (score 0, the reason kept).
        return _not_executed(pair_name, f'unreachable: {exc}', executor)
    run_episode(sim, executor, control_period, stepper=recorder, timeout=timeout, reset=False)
    result = sim.score()
    events = [_event_dict(ev) for ev in sim.pop_events()]
    complete = not result.failures
    duration = float(result.time_s) if complete else float(sim.time - t_start)
    spans = {k: v for k, v in recorder.spans.items() if k in SUBTASKS}
    return ThrowOutcome(pair=pair_name, score=float(result.score),
                        subtasks=dict(result.subtasks), duration=duration,
                        failure=result.failure, entry_error_mm=float(result.entry_error_mm),
                        exit_error_mm=float(result.exit_error_mm),
                        executed=recorder.executed(), rollouts=dict(executor.rollouts),
                        targets=dict(executor.targets), subtask_times=spans, events=events,
                        score_detail=result)


def replace_script(config: 'ExecutorConfig', **changes: Any) -> 'ExecutorConfig':
    """Return ``config`` (ExecutorConfig) with its script settings changed."""
    return replace(config, script=replace(config.script, **changes))
