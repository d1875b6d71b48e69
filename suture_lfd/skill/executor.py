"""
DMP executor: performs a whole throw on a marker pair from a learnt :class:`ThrowSkill`.

Subtasks i, iii and v are scripted as in the seed paper ("we grasp the needle using a script
and utilize a simple trajectory planning technique to move the PSMs"), with the planning pieces
of :class:`suture_lfd.planning.expert.ScriptedExpert` (reachable grasps, minimum-jerk motions,
grasp and release gates). Subtasks ii (insertion, PSM2) and iv (extraction, PSM1) come from the
skill's DMPs: the needle start and goal on the target pair are derived from the demonstrated pair's
(:meth:`ThrowSkill.start_goal`), the DMP rollout is the needle trajectory, and the tool targets
streamed to the arm are ``T_world_needle(t) @ inv(T_tool_needle)`` with the grasp
``T_tool_needle`` **measured** when the arm took the needle. With phase stopping on, the plan
clock of a DMP subtask slows by ``1 + k_p |e_p|^2 + k_o e_o^2`` (Ijspeert et al. 2013) when the
measured needle pose lags the rollout.

:class:`ThrowExecutor` is a controller (``reset(obs)``, ``step(obs) -> Command``, ``done``) for
:meth:`sim_bridge.simulation.Simulation.run` or for a ROS node; :func:`execute_throw` runs one
throw in-process and returns a :class:`ThrowOutcome`.

Frames: ``world``; poses 4x4 ``T_world_*`` or 7-vectors ``(x, y, z, qx, qy, qz, qw)``; SI units.
"""

from dataclasses import dataclass, field, replace
import math

import numpy as np
from sim_bridge.control import Command, ExpertConfig
from sim_bridge.geometry import matrix_from_quaternion, pose_from_transform
from sim_bridge.scene.needle import invert_transform
from suture_lfd.planning.expert import (  # planning pieces of the script
    Gate,
    Plan,
    ScriptedExpert,
    _backed_off,
    _Track,
    _translated,
)
from suture_lfd.planning.throw_geometry import ThrowArc
from suture_lfd.planning.waypoints import NeedleMove, RigidPath, rotation_exp, rotation_log
from suture_lfd.skill import (
    METHODS,
    Method,
    PairGeometry,
    ThrowSkill,
    TrainingData,
    learn_skill,
    training_data_from_demonstration,
)

__all__ = ['METHODS', 'Method', 'ThrowSkill', 'TrainingData', 'learn_skill',
           'training_data_from_demonstration', 'ExecutorConfig', 'ThrowExecutor',
           'ThrowOutcome', 'execute_throw', 'SUBTASKS']

SUBTASKS = ('i', 'ii', 'iii', 'iv', 'v')

# Grasp search along the needle (arc parameter: 0 tail, 1 tip): arc parameters tried besides
# the preferred one, the span kept between the two jaws (about 2.5 mm of wire), and the
# highest parameter (the jaw keeps off the point).
_GRASP_CANDIDATES = 9
_JAW_GAP_S = 0.15
_TIP_MARGIN_S = 0.97
# Part of the insertion (fraction of its duration) over which the start press fades out.
_PRESS_FADE = 0.25


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
    final_approach_time : float
        Shortest time (s) of lowering the needle from ``start_lift`` onto the DMP ii start
        (the tip onto the entry marker): slow, so a lagging arm does not overshoot into the
        tissue.
    resend_unchanged : bool
        Send a tool target every step even when it equals the last one sent (False: send
        None, so a resting arm is not asked to solve its inverse kinematics again).

    """

    script: ExpertConfig = field(default_factory=ExpertConfig)
    phase_stopping: bool = False
    phase_stop_position: float = 1.0e6
    phase_stop_orientation: float = 100.0
    start_lift: float = 0.005
    start_press: float = 0.0003
    final_approach_time: float = 1.0
    resend_unchanged: bool = False


class SampledPath:
    """
    Needle path through sampled poses (a DMP rollout), linear in the sample index.

    Parameters
    ----------
    poses : ndarray, shape (n, 4, 4)
        ``T_world_needle`` samples, evenly spaced in time.

    """

    def __init__(self, poses):
        poses = np.asarray(poses, dtype=float)
        if poses.ndim != 3 or poses.shape[0] < 2 or poses.shape[1:] != (4, 4):
            raise ValueError(f'a sampled path needs (n >= 2, 4, 4) poses, got {poses.shape}')
        self.poses = poses
        self._p = poses[:, :3, 3]
        self._R = poses[:, :3, :3]
        self._w = np.array([rotation_log(self._R[k].T @ self._R[k + 1])
                            for k in range(len(poses) - 1)])

    @property
    def A(self):  # noqa: N802 (pose names follow the project's T_a_b style)
        """First pose (4, 4)."""
        return self.poses[0].copy()

    @property
    def B(self):  # noqa: N802
        """Last pose (4, 4)."""
        return self.poses[-1].copy()

    @property
    def angle(self):
        """Summed rotation angle (rad)."""
        return float(np.linalg.norm(self._w, axis=1).sum())

    @property
    def distance(self):
        """Path length of the needle origin (m)."""
        return float(np.linalg.norm(np.diff(self._p, axis=0), axis=1).sum())

    def pieces(self, n):
        """Split into ``n`` consecutive paths (callables of ``sigma`` in [0, 1])."""
        edges = np.linspace(0.0, 1.0, n + 1)
        return [_SubPath(self, a, b) for a, b in zip(edges[:-1], edges[1:])]

    def __call__(self, sigma):
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

    def __init__(self, path, a, b):
        self.path, self.a, self.b = path, float(a), float(b)

    def __call__(self, sigma):
        return self.path(self.a + sigma * (self.b - self.a))


class DmpMove(NeedleMove):
    """A tool carrying the needle along a DMP rollout, with the rollout's own timing."""

    def sigma(self, t):
        """Path parameter: linear in time (the DMP sets the speed profile)."""
        if self.t1 <= self.t0:
            return 1.0
        return min(1.0, max(0.0, (t - self.t0) / (self.t1 - self.t0)))


def _transforms(P, Q):
    T = np.zeros((len(P), 4, 4))
    T[:, :3, :3] = matrix_from_quaternion(Q)
    T[:, :3, 3] = P
    T[:, 3, 3] = 1.0
    return T


def _carry_rollout(track, path, duration):
    """Append a DMP-timed needle carry to an expert track."""
    grasp = track.held[1]
    seg = DmpMove(track.t, track.t + duration, path, grasp, track.jaw)
    track.segments.append(seg)
    track.t = seg.t1
    track.pose = path.B @ invert_transform(grasp)
    track.held = (path.B, grasp)


def _carry_timed(track, path, duration):
    """Append a minimum-jerk needle carry of at least ``duration`` seconds to a track."""
    start = len(track.segments)
    track.carry(path)
    seg = track.segments[start]
    if seg.t1 - seg.t0 < duration:
        seg.t1 = seg.t0 + duration
        track.t = seg.t1


def _emerged_s(needle, N, pair):
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


class ThrowExecutor(ScriptedExpert):
    """
    Controller of one throw: scripted i, iii, v and DMP-driven ii, iv.

    Parameters
    ----------
    skill : ThrowSkill
        The learnt skill.
    pair : sim_bridge.scene.phantom.MarkerPair
        Target pair (``world``).
    needle_geometry : sim_bridge.scene.needle.NeedleGeometry
        Needle geometry.
    kinematics : sim_bridge.kinematics.PsmKinematics or dict, optional
        PSM kinematics used to choose reachable grasps.
    config : ExecutorConfig, optional
        Settings.
    next_pair : sim_bridge.scene.phantom.MarkerPair, optional
        Pair of the next throw (PSM2 ends above it).

    Attributes
    ----------
    rollouts : dict of str to tuple
        After :meth:`reset`: ``'ii'``, ``'iv'`` -> ``(T, P, Q)`` planned needle trajectories
        (times from the subtask start, s; ``world``; ii with its start pressed
        ``start_press`` into the tissue).
    targets : dict of str to tuple
        ``'ii'``, ``'iv'`` -> ``(start, goal)`` needle poses (7-vectors) on the target pair.

    """

    def __init__(self, skill, pair, needle_geometry, kinematics=None, config=None,
                 next_pair=None):
        self.executor_config = ExecutorConfig() if config is None else config
        super().__init__(pair, needle_geometry, config=self.executor_config.script,
                         kinematics=kinematics, next_pair=next_pair)
        if not isinstance(skill, ThrowSkill):
            raise ValueError(f'skill must be a ThrowSkill, got {type(skill).__name__}')
        self.skill = skill
        self.rollouts = {}
        self.targets = {}

    # ------------------------------------------------------------------ grasp choice
    def _choose_grasp_along(self, arm, s, span, phase, what):
        """
        Reachable grasp at arc parameter ``s`` or, failing that, at the nearest one in ``span``.

        Parameters
        ----------
        arm : str
            Arm.
        s : float
            Preferred arc parameter (0 tail, 1 tip).
        span : tuple of float
            ``(lo, hi)``: arc parameters the grasp may move to.
        phase : dict
            As :meth:`suture_lfd.planning.expert.ScriptedExpert._choose_grasp`.
        what : str
            Phase name for error messages.

        Returns
        -------
        grasp : ndarray, shape (4, 4)
            ``T_tool_needle``.
        roll : float
            Roll joint (rad) at the end of the phase.
        s : float
            Arc parameter of the chosen grasp.

        Raises
        ------
        ValueError
            If no arc parameter of the span gives a reachable grasp (the message names the span).

        """
        lo, hi = float(span[0]), float(span[1])
        others = np.linspace(lo, hi, _GRASP_CANDIDATES) if hi > lo else np.array([])
        candidates = [float(s)] + sorted((float(x) for x in others
                                          if abs(x - s) > 1e-6), key=lambda x: abs(x - s))
        first = None
        for x in candidates:
            try:
                G, roll = self._choose_grasp(arm, x, phase, what)
            except ValueError as exc:
                first = exc if first is None else first
                continue
            return G, roll, x
        raise ValueError(f'{first}; no arc parameter in [{lo:.2f}, {hi:.2f}] is reachable '
                         f'either') from first

    # ------------------------------------------------------------------ planning
    def plan(self, obs):
        """
        Plan the whole throw from an observation (DMP rollouts included).

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Start state.

        Returns
        -------
        suture_lfd.planning.expert.Plan

        Raises
        ------
        ValueError
            If no grasp keeps a holding phase inside the arms' reach.

        """
        c = self.config
        g = self.needle
        pair = self.pair
        skill = self.skill
        arc = ThrowArc(pair, g)
        deg = math.radians
        normal = np.asarray(pair.normal, dtype=float)
        up = np.array([0.0, 0.0, 1.0])
        bases = obs.T_world_base

        # ii from the DMP: start/goal on this pair, rollout in world.
        start2, goal2 = skill.start_goal('ii', pair, needle=g)
        T2, P2, Q2 = skill.rollout('ii', pair, start=start2, goal=goal2, needle=g)
        # The demonstrated insertion starts with the tip barely in the tissue; pressed a little
        # deeper, the rollout's own small deviations from the demonstration cannot lift the tip
        # back out through its puncture. The press fades out over the first part of the
        # insertion, so the needle crosses the exit and ends it where the rollout does.
        fade = np.clip(1.0 - np.linspace(0.0, 1.0, len(P2)) / _PRESS_FADE, 0.0, 1.0)[:, None]
        P2 = P2 - self.executor_config.start_press * fade * normal
        R2 = _transforms(P2, Q2)
        S2 = R2[0]
        S2_hi = _translated(S2, self.executor_config.start_lift * normal)
        N_ins = R2[-1]
        start4, goal4 = skill.start_goal('iv', pair, needle=g)
        T4, P4, Q4 = skill.rollout('iv', pair, start=pose_from_transform(N_ins), goal=goal4,
                                   needle=g)
        R4 = _transforms(P4, Q4)
        N_lift = R4[-1]
        self.rollouts = {'ii': (T2, P2, Q2), 'iv': (T4, P4, Q4)}
        self.targets = {'ii': (start2, goal2), 'iv': (pose_from_transform(N_ins), goal4)}
        path2, path4 = SampledPath(R2), SampledPath(R4)
        if self.next_pair is not None:
            nxt = PairGeometry.of(self.next_pair)
            start_next = skill.start_goal('ii', nxt, needle=g)[0]
            S_next = _transforms(start_next[None, :3], start_next[None, 3:])[0]
            N_next = _translated(S_next, (self.executor_config.start_lift + c.next_lift)
                                 * np.asarray(self.next_pair.normal))
        else:
            N_next = _translated(S2_hi, c.next_lift * normal)

        s_g = 1.0 - (deg(c.clearance_deg) + arc.inside_angle + deg(c.protrusion_deg)) / g.arc
        s_g = min(c.grasp_s_max, max(c.grasp_s_min, s_g))
        s_out = _emerged_s(g, N_ins, pair)
        if s_out is None:
            s_1 = 1.0 - 0.5 * deg(c.protrusion_deg) / g.arc
        else:
            s_1 = 0.5 * (1.0 + s_out)

        N0 = np.array(obs.T_world_needle, dtype=float)
        N_up = _translated(N0, c.pick_lift * up)
        holders = tuple(obs.holders)
        picked = 'PSM2' in holders
        clear2 = [path2(x) for x in np.linspace(0.0, 1.0, 9)]
        drive_paths = [RigidPath(S2_hi, S2)] + path2.pieces(3)
        if picked:
            G2 = invert_transform(obs.T_world_tool['PSM2']) @ N0
            _, roll2 = self._path_cost(
                'PSM2', bases, self._start_roll('PSM2', obs),
                [N @ invert_transform(G2) for p in [RigidPath(N0, S2_hi)] + drive_paths
                 for N in (p(x) for x in np.linspace(0.0, 1.0, 12))])
            if roll2 is None:
                raise ValueError(f'PSM2 cannot carry the needle it holds through the insertion '
                                 f'of pair {pair.name}; regrasp it first')
        else:
            G2, roll2 = self._choose_grasp('PSM2', s_g, {
                'start': obs.T_world_tool['PSM2'], 'roll0': self._start_roll('PSM2', obs),
                'grasp_at': N0, 'paths': [RigidPath(N0, N_up), RigidPath(N_up, S2_hi)]
                + drive_paths, 'clear': clear2, 'bases': bases}, 'the pick-up and insertion')
        # The extraction grasp closes on the part of the needle out of the exit, the hand-over
        # grasp anywhere on the needle off PSM1's jaw: the preferred arc parameter first, then
        # the others of that span (a rollout on another pair can put the preferred one out of
        # the arm's reach).
        lo_1 = s_g + _JAW_GAP_S if s_out is None else s_out + 0.25 * (1.0 - s_out)
        G1, _, s_1 = self._choose_grasp_along('PSM1', s_1, (lo_1, _TIP_MARGIN_S), {
            'start': obs.T_world_tool['PSM1'], 'roll0': self._start_roll('PSM1', obs),
            'grasp_at': N_ins, 'paths': path4.pieces(4), 'clear': [N_ins], 'bases': bases},
            'the extraction')
        park2 = _translated(_backed_off(N_ins @ invert_transform(G2), c.retreat_distance),
                            c.retreat_distance * up)
        handover = {'start': park2, 'roll0': roll2, 'grasp_at': N_lift,
                    'paths': [RigidPath(N_lift, N_next)], 'clear': (), 'bases': bases}
        span_h = (c.grasp_s_min, s_1 - _JAW_GAP_S)
        try:
            Gh, _, _ = self._choose_grasp_along('PSM2', s_g, span_h, handover, 'the handover')
        except ValueError:
            # No grasp of the extracted needle also carries it to the next start (the
            # extraction may end turned far from it): the hand-over completes and PSM2 lifts
            # the needle straight up instead.
            N_next = _translated(N_lift, c.next_lift * up)
            Gh, _, _ = self._choose_grasp_along(
                'PSM2', s_g, span_h, {**handover, 'paths': [RigidPath(N_lift, N_next)]},
                'the handover')

        t1 = _Track('PSM1', obs.T_world_tool['PSM1'], obs.jaw['PSM1'], c)
        t2 = _Track('PSM2', obs.T_world_tool['PSM2'], obs.jaw['PSM2'], c)
        labels = [(0.0, 'i')]
        gates = []

        # i (scripted): pick with PSM2, carry the needle above the DMP start, lower it there.
        if not picked:
            grasp_pose = N0 @ invert_transform(G2)
            t2.move(_backed_off(grasp_pose, c.approach_distance), jaw=c.jaw_open)
            t2.move(grasp_pose)
            t2.set_jaw(c.jaw_closed)
            gates.append(Gate(t2.t, 'PSM2', 'grasp'))
            t2.grab(N0, G2)
            t2.hold(c.settle_time)
            t2.carry(RigidPath(N0, N_up))
            t2.carry(RigidPath(N_up, S2_hi))
        else:
            t2.grab(N0, G2)
            t2.carry(RigidPath(N0, S2_hi))
        _carry_timed(t2, RigidPath(S2_hi, S2), self.executor_config.final_approach_time)
        t2.hold(c.settle_time)

        # ii (DMP): insertion; PSM1 gets ready.
        labels.append((t2.t, 'ii'))
        t1.hold_until(t2.t)
        pre1 = _backed_off(N_ins @ invert_transform(G1), c.approach_distance)
        t1.move(pre1, jaw=c.jaw_open_near_tissue)
        _carry_rollout(t2, path2, skill.duration('ii'))

        # iii (scripted): regrasp with PSM1, PSM2 lets go.
        labels.append((t2.t, 'iii'))
        t1.hold_until(t2.t)
        t1.move(N_ins @ invert_transform(G1))
        t1.set_jaw(c.jaw_closed)
        gates.append(Gate(t1.t, 'PSM1', 'grasp'))
        t1.grab(N_ins, G1)
        t1.hold(c.settle_time)
        t2.hold_until(t1.t)
        t2.set_jaw(c.jaw_open)
        gates.append(Gate(t2.t, 'PSM2', 'release'))
        t2.let_go()

        # iv (DMP): extraction with PSM1; PSM2 backs away meanwhile.
        labels.append((t2.t, 'iv'))
        t1.hold_until(t2.t)
        t2.move(_backed_off(t2.pose, c.retreat_distance))
        t2.move(_translated(t2.pose, c.retreat_distance * up))
        _carry_rollout(t1, path4, skill.duration('iv'))

        # v (scripted): hand over to PSM2, PSM1 releases and parks, PSM2 moves on.
        labels.append((max(t1.t, t2.t), 'v'))
        t1.hold_until(t2.t)
        grasp_h = N_lift @ invert_transform(Gh)
        t2.move(_backed_off(grasp_h, c.approach_distance), jaw=c.jaw_open)
        t2.hold_until(t1.t)
        t2.move(grasp_h)
        t2.set_jaw(c.jaw_closed)
        gates.append(Gate(t2.t, 'PSM2', 'grasp'))
        t2.grab(N_lift, Gh)
        t2.hold(c.settle_time)
        t1.hold_until(t2.t)
        t1.set_jaw(c.jaw_open)
        gates.append(Gate(t1.t, 'PSM1', 'release'))
        t1.let_go()
        t2.hold_until(t1.t)
        t1.move(_backed_off(t1.pose, c.retreat_distance))
        t1.move(np.array(obs.T_world_tool['PSM1'], dtype=float))
        t2.carry(RigidPath(N_lift, N_next))
        end = max(t1.t, t2.t)
        t1.hold_until(end)
        t2.hold_until(end)
        labels.append((end, 'done'))
        return Plan(segments={'PSM1': t1.segments, 'PSM2': t2.segments}, labels=tuple(labels),
                    gates=tuple(sorted(gates, key=lambda gt: gt.t)),
                    grasps={'PSM2_drive': G2, 'PSM1_extract': G1, 'PSM2_handover': Gh},
                    arc=arc, alphas={})

    # ------------------------------------------------------------------ control
    def reset(self, obs):
        """
        Plan the throw from ``obs``; its clock starts at the next :meth:`step`.

        Planning takes a while; where the scene runs on meanwhile (a simulator node), starting
        the clock at the first command keeps the plan from starting part-way through.
        """
        super().reset(obs)
        self._t0 = None
        self._sent = {}

    def step(self, obs):
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
        if self._t0 is None:
            self._t0 = self._last_t = float(obs.t)
        cfg = self.executor_config
        dt = float(obs.t) - self._last_t
        self._last_t = float(obs.t)
        if cfg.phase_stopping and dt > 0.0:
            tau = obs.t - self._t0 - self._offset
            label = self.plan_.label(tau)
            if label in ('ii', 'iv'):
                arm = 'PSM2' if label == 'ii' else 'PSM1'
                seg = self.plan_._segment(arm, tau)
                if isinstance(seg, DmpMove) and arm in obs.holders:
                    N = seg.needle(tau)
                    M = np.asarray(obs.T_world_needle)
                    e_p = float(np.sum((M[:3, 3] - N[:3, 3]) ** 2))
                    c_ang = 0.5 * (float(np.sum(M[:3, :3] * N[:3, :3])) - 1.0)
                    e_o = math.acos(max(-1.0, min(1.0, c_ang))) ** 2
                    slow = 1.0 + cfg.phase_stop_position * e_p + cfg.phase_stop_orientation * e_o
                    self._offset += dt * (1.0 - 1.0 / slow)
        cmd = super().step(obs)
        if not cfg.resend_unchanged:
            tools = dict(cmd.T_world_tool)
            for arm, T in tools.items():
                last = self._sent.get(arm)
                if last is not None and np.array_equal(last, T):
                    tools[arm] = None
                else:
                    self._sent[arm] = T
            cmd = Command(t=cmd.t, T_world_tool=tools, jaw=cmd.jaw, subtask=cmd.subtask)
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

    def __init__(self, controller):
        self.controller = controller
        self.t0 = None
        self.samples = {}
        self.spans = {}

    def step(self, obs):
        cmd = self.controller.step(obs)
        if self.t0 is None:
            self.t0 = float(obs.t)
        t = float(obs.t) - self.t0
        label = cmd.subtask
        span = self.spans.get(label)
        self.spans[label] = (t, t) if span is None else (span[0], t)
        if label in ('ii', 'iv'):
            self.samples.setdefault(label, []).append((t, np.asarray(obs.T_world_needle)))
        return cmd

    def executed(self):
        out = {}
        for label, rows in self.samples.items():
            t0 = self.spans[label][0]
            t = np.array([r[0] for r in rows]) - t0
            poses = pose_from_transform(np.array([r[1] for r in rows]))
            out[label] = (t, poses)
        return out


def _event_dict(ev):
    data = {}
    for key, value in ev.data.items():
        if isinstance(value, np.ndarray):
            value = value.tolist()
        elif hasattr(value, 'score') and hasattr(value, 'subtasks'):
            value = {'score': value.score, 'subtasks': dict(value.subtasks),
                     'failure': value.failure}
        data[key] = value
    return {'t': float(ev.t), 'kind': ev.kind, **data}


def execute_throw(sim, skill, pair_name, seed=0, timeout=60.0, config=None, control_period=0.01,
                  next_pair=None):
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
    sim.reset(seed)
    sim.enable_and_home_all()
    sim.set_target_pair(pair_name)
    sim.pop_events()
    pair = sim.target_pair
    if config is None:
        config = ExecutorConfig(script=sim.config.scene.expert)
    nxt = sim.phantom.markers[next_pair] if next_pair is not None else None
    executor = ThrowExecutor(skill, pair, sim.needle_geometry, kinematics=sim.kinematics['PSM1'],
                             config=config, next_pair=nxt)
    recorder = _Recorder(executor)
    t_start = sim.time
    try:
        executor.reset(sim.observation())
    except ValueError as exc:
        # No reachable grasp carries the needle along the rollouts on this pair: the throw
        # cannot be executed (score 0, the reason kept).
        return ThrowOutcome(pair=pair_name, score=0.0, subtasks=dict.fromkeys(SUBTASKS, False),
                            duration=0.0, failure=f'unreachable: {exc}',
                            entry_error_mm=math.nan, exit_error_mm=math.nan, executed={},
                            rollouts=dict(executor.rollouts), targets=dict(executor.targets),
                            subtask_times={}, events=[], score_detail=None)
    chunk = 0.5
    while not executor.done and sim.time - t_start < timeout:
        sim.run(min(chunk, timeout - (sim.time - t_start)), recorder, control_period)
    if executor.done:
        sim.run(0.2, recorder, control_period)
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


def replace_script(config, **changes):
    """Return ``config`` (ExecutorConfig) with its script settings changed."""
    return replace(config, script=replace(config.script, **changes))
