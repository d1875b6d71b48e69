"""
Scripted expert: performs the five suturing subtasks on a marker pair with clean motions.

The expert is a controller: :meth:`ScriptedExpert.reset` plans the whole throw from a first
:class:`Observation`, and :meth:`ScriptedExpert.step` turns each later observation into a
:class:`Command` (tool-tip pose targets ``T_world_tool`` and jaw angles per arm, plus the
subtask label). :meth:`ScriptedExpert.plan` returns the timed plan itself, so a demonstration
can also be generated open-loop (:meth:`Plan.sample`, :meth:`Plan.knots`).

The throw (paper Sec. III-C; world layout of ``config/world.yaml``: PSM2 right, PSM1 left):

i.   PSM2 opens its jaw, approaches the needle along its tool ``z``, grasps it near the tail,
     lifts it, carries it above the entry marker and lowers the tip onto the entry: the needle
     plane then contains entry, exit and the surface normal (:class:`ThrowArc`).
ii.  PSM2 turns the needle about its arc centre: the tip goes in at the entry and comes out at
     the exit, until ``protrusion_deg`` of the tip is out while the grasp stays
     ``clearance_deg`` clear of the entry. Meanwhile PSM1 moves to a pre-grasp pose.
iii. PSM1 approaches the emerged tip part, grasps it, PSM2 opens its jaw and backs away.
iv.  PSM1 turns the needle on along its arc until the tail is ``extract_margin_deg`` past the
     exit, then lifts it (pulling the thread).
v.   PSM2 grasps the needle near the tail, PSM1 releases it and returns to its start pose,
     PSM2 carries the needle to the next initial pose (above the next pair's entry).

All motions are minimum-jerk segments (:mod:`suture_lfd.planning.waypoints`). The grasp of each
holding phase (arc parameter and jaw roll about the wire, :meth:`NeedleGeometry.grasp_transform`)
is chosen so that every planned tool pose of the phase, and its approach pose, is reachable by the
arm's closed-form inverse kinematics with the smallest wrist angles. While an arm holds the
needle the expert measures the actual grasp (``inv(T_world_tool) @ T_world_needle``) and moves
the tool so that the *needle* follows the planned path. The plan pauses (up to
``gate_timeout``) at each grasp or release until the observation confirms it.

Frames: ``world``; poses 4x4 ``T_world_*``; metres, radians, seconds.
"""

from dataclasses import dataclass, field
import logging
import math

import numpy as np
from sim_bridge.control import Command, ExpertConfig
from sim_bridge.scene.needle import invert_transform
from suture_lfd.planning.throw_geometry import ThrowArc
from suture_lfd.planning.waypoints import ArcPath, NeedleMove, RigidPath, ToolMove, rotation_exp

_LOG = logging.getLogger(__name__)

ARMS = ('PSM1', 'PSM2')
LABELS = ('i', 'ii', 'iii', 'iv', 'v', 'done')


# What decides whether the arms reach a throw, and where a user changes it.
UNREACHABLE_ADVICE = ('try another needle start (the simulator parameter seed), or bring the '
                      'pair between the arms: move the phantom (its position and quaternion in '
                      'the phantom file) or the arm bases (world.arms.<ARM> in world.yaml)')


@dataclass(frozen=True)
class Gate:
    """
    A point of the plan that waits for a grasp or release.

    Attributes
    ----------
    t : float
        Plan time (s).
    arm : str
        Arm.
    kind : str
        ``'grasp'`` (the arm must hold the needle) or ``'release'`` (it must not).

    """

    t: float
    arm: str
    kind: str


@dataclass(frozen=True, eq=False)
class Plan:
    """
    A timed throw plan.

    Attributes
    ----------
    segments : dict of str to list
        Per arm, contiguous motion segments (:class:`ToolMove` / :class:`NeedleMove`) covering
        ``[0, duration]`` in plan time (s from the start).
    labels : tuple of (float, str)
        Subtask start times (s) and labels, in order, ending with ``'done'``.
    gates : tuple of Gate
        Grasp and release confirmations, in time order.
    grasps : dict of str to ndarray (4, 4)
        Planned grasps ``T_tool_needle``: ``'PSM2_drive'``, ``'PSM1_extract'``,
        ``'PSM2_handover'``.
    arc : ThrowArc
        The throw circle.
    alphas : dict of str to float
        Key angles (rad) of the needle rotation: ``pre_entry``, ``entry``, ``exit``,
        ``insert_end``, ``through``, ``extract_end``.

    """

    segments: dict
    labels: tuple
    gates: tuple
    grasps: dict
    arc: ThrowArc
    alphas: dict = field(default_factory=dict)

    @property
    def duration(self):
        """Plan length (s)."""
        return max(seg[-1].t1 for seg in self.segments.values())

    def _segment(self, arm, t):
        segs = self.segments[arm]
        for seg in segs:
            if t <= seg.t1:
                return seg
        return segs[-1]

    def label(self, t):
        """Subtask label at plan time ``t`` (s)."""
        current = self.labels[0][1]
        for t0, name in self.labels:
            if t >= t0:
                current = name
        return current

    def sample(self, t, grasps=None):
        """
        Command at plan time ``t`` (s).

        Parameters
        ----------
        t : float
            Plan time (s).
        grasps : dict of str to ndarray (4, 4), optional
            Measured grasps ``T_tool_needle`` per holding arm; the tool then moves so that the
            needle follows the planned path.

        Returns
        -------
        Command

        """
        grasps = grasps or {}
        tools, jaws = {}, {}
        for arm in self.segments:
            seg = self._segment(arm, t)
            tools[arm] = seg.tool(t, grasps.get(arm) if seg.carries_needle else None)
            jaws[arm] = seg.jaw(t)
        return Command(t=float(t), T_world_tool=tools, jaw=jaws, subtask=self.label(t))

    def needle(self, t):
        """
        Planned needle pose at plan time ``t`` (s), or None while no arm carries it.

        Parameters
        ----------
        t : float
            Plan time (s).

        Returns
        -------
        ndarray, shape (4, 4) or None

        """
        for arm in self.segments:
            seg = self._segment(arm, t)
            if seg.carries_needle:
                return seg.needle(t)
        return None

    def knots(self, arm):
        """
        List the timed waypoints of one arm: the segment boundaries.

        Parameters
        ----------
        arm : str
            ``'PSM1'`` or ``'PSM2'``.

        Returns
        -------
        list of (float, ndarray (4, 4), float)
            ``(t, T_world_tool, jaw)`` at the start of every segment and at the end.

        """
        segs = self.segments[arm]
        out = [(s.t0, s.tool(s.t0), s.jaw(s.t0)) for s in segs]
        last = segs[-1]
        out.append((last.t1, last.tool(last.t1), last.jaw(last.t1)))
        return out

    def sampled(self, dt):
        """
        Sample the plan every ``dt`` seconds (an open-loop demonstration).

        Parameters
        ----------
        dt : float
            Sample period (s).

        Returns
        -------
        dict
            ``'t'`` (m,), ``'<ARM>'`` tool poses (m, 4, 4), ``'<ARM>_jaw'`` (m,),
            ``'needle'`` (m, 4, 4) (NaN while nothing carries it), ``'subtask'`` (m,) str.

        """
        ts = np.arange(0.0, self.duration + 0.5 * dt, dt)
        out = {'t': ts, 'needle': np.full((len(ts), 4, 4), np.nan),
               'subtask': np.empty(len(ts), dtype=object)}
        for arm in self.segments:
            out[arm] = np.empty((len(ts), 4, 4))
            out[f'{arm}_jaw'] = np.empty(len(ts))
        for k, t in enumerate(ts):
            cmd = self.sample(t)
            for arm in self.segments:
                out[arm][k] = cmd.T_world_tool[arm]
                out[f'{arm}_jaw'][k] = cmd.jaw[arm]
            n = self.needle(t)
            if n is not None:
                out['needle'][k] = n
            out['subtask'][k] = cmd.subtask
        return out


def _translated(T, v):
    out = np.array(T, dtype=float)
    out[:3, 3] = out[:3, 3] + v
    return out


def _backed_off(T, distance):
    """Move a pose ``distance`` along its own minus ``z`` axis."""
    return _translated(T, -distance * np.asarray(T)[:3, 2])


def _dense(A, B, step=0.1, spacing=0.002):
    """Poses from A towards B (B excluded), about ``step`` rad and ``spacing`` m apart."""
    path = RigidPath(A, B)
    n = max(2, int(math.ceil(max(path.angle / step, path.distance / spacing))))
    return list(path.many(np.linspace(0.0, 1.0, n, endpoint=False)))


class _Track:
    """One arm's timeline under construction (plan time, current pose, jaw, held needle)."""

    def __init__(self, arm, pose, jaw, config):
        self.arm = arm
        self.t = 0.0
        self.pose = np.array(pose, dtype=float)
        self.jaw = float(jaw)
        self.cfg = config
        self.segments = []
        self.held = None          # (needle pose, grasp) while the arm holds the needle

    def _duration(self, distance, angle, angular_speed=None):
        c = self.cfg
        w = c.tool_angular_speed if angular_speed is None else angular_speed
        # minimum jerk: peak speed 1.875 d / T, peak acceleration 5.7735 d / T^2
        return max(c.min_move_time, 1.875 * distance / c.tool_speed, 1.875 * angle / w,
                   math.sqrt(5.7735 * distance / c.tool_acceleration),
                   math.sqrt(5.7735 * angle / c.tool_angular_acceleration)) / c.speed_scale

    def _still(self, t1, jaw):
        if self.held is None:
            seg = ToolMove(self.t, t1, self.pose, self.pose, self.jaw, jaw)
        else:
            N, G = self.held
            seg = NeedleMove(self.t, t1, RigidPath(N, N), G, self.jaw, jaw)
        self.segments.append(seg)
        self.t, self.jaw = t1, float(jaw)

    def hold_until(self, t):
        if t > self.t + 1e-12:
            self._still(t, self.jaw)

    def hold(self, duration):
        self.hold_until(self.t + duration)

    def set_jaw(self, jaw):
        self._still(self.t + self.cfg.jaw_time / self.cfg.speed_scale, jaw)

    def grab(self, needle_pose, grasp):
        """From now on the arm holds the needle (after its jaw closed on it)."""
        self.held = (np.array(needle_pose, dtype=float), np.array(grasp, dtype=float))

    def let_go(self):
        """From now on the arm holds nothing (after its jaw opened)."""
        self.held = None

    def move(self, B, jaw=None):
        if self.held is not None:
            raise RuntimeError(f'{self.arm} holds the needle: use carry()')
        jaw = self.jaw if jaw is None else float(jaw)
        seg = ToolMove(self.t, self.t, self.pose, B, self.jaw, jaw)
        duration = self._duration(seg.path.distance, seg.path.angle)
        if jaw != self.jaw:
            duration = max(duration, self.cfg.jaw_time / self.cfg.speed_scale)
        seg.t1 = self.t + duration
        self.segments.append(seg)
        self.t, self.pose, self.jaw = seg.t1, np.array(B, dtype=float), jaw

    def carry(self, path, drive=False):
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
        duration = self._duration(distance, path.angle, w)
        seg = NeedleMove(self.t, self.t + duration, path, grasp, self.jaw)
        self.segments.append(seg)
        self.t, self.pose = seg.t1, B
        self.held = (path.B, grasp)


class ScriptedExpert:
    """
    Scripted suturing expert for one marker pair.

    Parameters
    ----------
    pair : sim_bridge.scene.phantom.MarkerPair
        Target pair (world frame).
    needle_geometry : sim_bridge.scene.needle.NeedleGeometry
        Needle geometry.
    config : ExpertConfig, optional
        Motion parameters.
    rng : numpy.random.Generator, optional
        Randomness of the skill noise (``aim_std``, ``tilt_std_deg``); needed only when they
        are non-zero.
    kinematics : sim_bridge.kinematics.PsmKinematics or dict, optional
        PSM kinematics (one for both arms or one per arm) used to choose reachable grasps;
        default: :func:`sim_bridge.kinematics.psm_kinematics`.
    next_pair : sim_bridge.scene.phantom.MarkerPair, optional
        Pair of the next throw; PSM2 ends above its entry (default: above this pair's).

    """

    def __init__(self, pair, needle_geometry, config=None, rng=None, kinematics=None,
                 next_pair=None):
        self.pair = pair
        self.needle = needle_geometry
        self.config = ExpertConfig() if config is None else config
        self.rng = rng
        if kinematics is None:
            from sim_bridge.kinematics import psm_kinematics
            kinematics = psm_kinematics()
        self.kinematics = (dict(kinematics) if isinstance(kinematics, dict)
                           else dict.fromkeys(ARMS, kinematics))
        self.next_pair = next_pair
        self.plan_ = None
        self._t0 = 0.0

    # ------------------------------------------------------------------ grasp choice
    def _path_cost(self, arm, T_world_base, roll0, tools):
        """
        Cost of a dense tool path for an arm whose roll joint starts at ``roll0``.

        The path must be reachable everywhere, must not switch IK branches between samples,
        and its continuous roll (as an arm servoing along it reaches it) must stay inside the
        roll limits. Returns ``(largest wrist angle (rad), final roll)``, or ``(inf, None)``.
        """
        chain = self.kinematics[arm]
        T_base_world = invert_transform(T_world_base[arm])
        Q, ok = chain.ik_batch(np.einsum('ij,njk->nik', T_base_world, np.asarray(tools)))
        return self._joint_path_cost(chain, Q, ok, roll0)

    @staticmethod
    def _joint_path_cost(chain, Q, ok, roll0):
        """:meth:`_path_cost` of a path already solved (joints ``Q``, ``ok`` where reachable)."""
        if not ok.all():
            return math.inf, None
        roll = np.unwrap(Q[:, 3])
        roll += 2.0 * math.pi * round((roll0 - roll[0]) / (2.0 * math.pi))
        margin = 0.2
        if roll.max() > chain.upper[3] - margin or roll.min() < chain.lower[3] + margin:
            return math.inf, None
        if len(Q) > 1 and np.abs(np.diff(Q[:, [0, 1, 2, 4, 5]], axis=0)).max() > 0.3:
            return math.inf, None
        return float(np.abs(Q[:, 4:6]).max()), float(roll[-1])

    def _start_roll(self, arm, obs):
        q = getattr(obs, 'q', None)
        if q is not None and arm in q:
            return float(np.asarray(q[arm])[3])
        chain = self.kinematics[arm]
        T = invert_transform(obs.T_world_base[arm]) @ np.asarray(obs.T_world_tool[arm])
        return float(chain.ik(T)[3])

    def _jaw_clearance(self, tools):
        """Lowest height (m) of the closed jaw's outline above the pair's surface plane."""
        c = self.config
        L, w = c.jaw_length, c.jaw_half_width
        outline = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, L, 1.0], [w, 0.0, L, 1.0],
                            [-w, 0.0, L, 1.0], [w, 0.0, 0.0, 1.0], [-w, 0.0, 0.0, 1.0]])
        pts = np.einsum('nij,kj->nki', np.asarray(tools), outline)[..., :3]
        return float(((pts - self.pair.midpoint) @ self.pair.normal).min())

    def _choose_grasp(self, arm, s, phase, what):
        """
        Grasp at arc parameter ``s`` that keeps a holding phase reachable.

        Parameters
        ----------
        arm : str
            Arm.
        s : float
            Arc parameter of the grasp.
        phase : dict
            ``start`` (tool pose the arm comes from, or None if it already holds the needle),
            ``roll0`` (its roll joint), ``grasp_at`` (needle pose where the grasp closes),
            ``paths`` (needle paths carried afterwards), ``clear`` (needle poses where the jaw
            must keep ``jaw_clearance`` off the surface plane), ``bases``.
        what : str
            Phase name for error messages.

        Returns
        -------
        grasp : ndarray, shape (4, 4)
            ``T_tool_needle``.
        roll : float
            Roll joint (rad) at the end of the phase.

        """
        c = self.config
        needles = np.array([path(x) for path in phase['paths'] for x in np.linspace(0.0, 1.0, 12)])
        best, best_cost, best_roll = None, math.inf, None
        step = math.radians(c.roll_step_deg)
        rolls = sorted(np.arange(-math.pi, math.pi - 1e-9, step), key=abs)
        # Every candidate's carrying path first, in one batch: a candidate with one unreachable
        # pose there costs inf whatever its approach. Then the approaches of the others, in one
        # batch. The IK of a pose does not depend on the other poses of a batch, so this is
        # the cost of solving every whole path at once.
        chain = self.kinematics[arm]
        T_base_world = invert_transform(phase['bases'][arm])
        grasps = [(flip, roll, self.needle.grasp_transform(s, roll=roll, flip=flip))
                  for flip in (False, True) for roll in rolls]
        invs = [invert_transform(G) for _, _, G in grasps]
        carried = (needles[None] @ np.asarray(invs)[:, None]).reshape(-1, 4, 4)
        Qc, okc = chain.ik_batch(np.einsum('ij,njk->nik', T_base_world, carried))
        n_c = len(needles)
        alive = [k for k in range(len(grasps)) if okc[k * n_c:(k + 1) * n_c].all()]
        approach = {}
        if phase['start'] is not None and alive:
            tools, spans, size = [], {}, 0
            for k in alive:
                grasp_pose = phase['grasp_at'] @ invs[k]
                pre = _backed_off(grasp_pose, c.approach_distance)
                path = _dense(phase['start'], pre) + _dense(pre, grasp_pose)
                spans[k] = (size, size + len(path))
                tools += path
                size += len(path)
            Qa, oka = chain.ik_batch(np.einsum('ij,njk->nik', T_base_world, np.asarray(tools)))
            approach = {k: (Qa[a:b], oka[a:b]) for k, (a, b) in spans.items()}
        for k in alive:
            G, inv = grasps[k][2], invs[k]
            Q, ok = Qc[k * n_c:(k + 1) * n_c], okc[k * n_c:(k + 1) * n_c]
            if k in approach:
                Q, ok = np.concatenate((approach[k][0], Q)), np.concatenate((approach[k][1], ok))
            cost, end_roll = self._joint_path_cost(chain, Q, ok, phase['roll0'])
            if phase['clear'] and math.isfinite(cost):
                low = self._jaw_clearance([N @ inv for N in phase['clear']])
                cost += 1000.0 * max(0.0, c.jaw_clearance - low)
            if cost < best_cost - 1e-9:
                best, best_cost, best_roll = G, cost, end_roll
        if best is None:
            raise ValueError(f'{arm} cannot reach a grasp at arc parameter {s:.2f} for '
                             f'{what} of pair {self.pair.name}; {UNREACHABLE_ADVICE}')
        return best, best_roll

    def _noisy_pair(self):
        c = self.config
        pair = self.pair
        if c.aim_std == 0.0 and c.tilt_std_deg == 0.0:
            return pair
        if self.rng is None:
            raise ValueError('ScriptedExpert needs rng when aim_std or tilt_std_deg is set')
        F = pair.frame
        offset = c.aim_std * (self.rng.normal() * F[:3, 0] + self.rng.normal() * F[:3, 1])
        tilt = math.radians(c.tilt_std_deg) * self.rng.normal()
        T = np.eye(4)
        T[:3, :3] = rotation_exp(tilt * pair.normal)
        T[:3, 3] = pair.midpoint - T[:3, :3] @ pair.midpoint + offset
        return pair.transformed(T)

    # ------------------------------------------------------------------ planning
    def plan(self, obs):
        """
        Plan the whole throw from an observation.

        Parameters
        ----------
        obs : Observation
            Start state (tool poses, jaws, needle pose, holders, arm bases).

        Returns
        -------
        Plan
            Plan times start at 0 (= ``obs.t``).

        Raises
        ------
        ValueError
            If no grasp keeps a holding phase inside the arms' reach.

        """
        c = self.config
        g = self.needle
        arc = ThrowArc(self._noisy_pair(), g)
        deg = math.radians
        s_g = 1.0 - (deg(c.clearance_deg) + arc.inside_angle + deg(c.protrusion_deg)) / g.arc
        s_g = min(c.grasp_s_max, max(c.grasp_s_min, s_g))
        a_pre = arc.alpha_entry + deg(c.pre_entry_angle_deg)
        a_entry = arc.alpha_entry
        a_ins = arc.alpha_tail_entry + s_g * g.arc + deg(c.clearance_deg)
        a_ins = min(a_ins, arc.alpha_exit - deg(4.0))
        a_out = arc.alpha_through - deg(c.extract_margin_deg)
        protrusion = arc.alpha_exit - a_ins
        s_1 = 1.0 - 0.5 * protrusion / g.arc

        normal = np.asarray(self.pair.normal, dtype=float)
        up = np.array([0.0, 0.0, 1.0])
        N0 = np.array(obs.T_world_needle, dtype=float)
        N_pre = arc.T_world_needle(a_pre)
        N_pre_hi = _translated(N_pre, c.pre_entry_lift * normal)
        N_ins = arc.T_world_needle(a_ins)
        N_out = arc.T_world_needle(a_out)
        N_lift = _translated(N_out, c.extract_lift * normal)
        if self.next_pair is not None:
            nxt = ThrowArc(self.next_pair, g)
            N_next = _translated(nxt.T_world_needle(nxt.alpha_entry + deg(c.pre_entry_angle_deg)),
                                 (c.pre_entry_lift + c.next_lift) * np.asarray(
                                     self.next_pair.normal))
        else:
            N_next = _translated(N_pre_hi, c.next_lift * normal)
        drive = [arc.T_world_needle(a) for a in np.linspace(a_pre, a_ins, 7)]
        extract = [arc.T_world_needle(a) for a in np.linspace(a_ins, a_out, 9)]

        holders = tuple(obs.holders)
        bases = obs.T_world_base
        picked = 'PSM2' in holders
        N_up = _translated(N0, c.pick_lift * up)
        drive_paths = [RigidPath(N_pre_hi, N_pre), ArcPath(arc, a_pre, a_entry),
                       ArcPath(arc, a_entry, a_ins)]
        if picked:
            G2 = invert_transform(obs.T_world_tool['PSM2']) @ N0
            _, roll2 = self._path_cost(
                'PSM2', bases, self._start_roll('PSM2', obs),
                [N @ invert_transform(G2) for path in [RigidPath(N0, N_pre_hi)] + drive_paths
                 for N in (path(x) for x in np.linspace(0.0, 1.0, 12))])
            if roll2 is None:
                raise ValueError(f'PSM2 cannot carry the needle it holds through the insertion '
                                 f'of pair {self.pair.name}; regrasp it first')
        else:
            G2, roll2 = self._choose_grasp('PSM2', s_g, {
                'start': obs.T_world_tool['PSM2'], 'roll0': self._start_roll('PSM2', obs),
                'grasp_at': N0, 'paths': [RigidPath(N0, N_up), RigidPath(N_up, N_pre_hi)]
                + drive_paths, 'clear': drive, 'bases': bases}, 'the pick-up and insertion')
        G1, _ = self._choose_grasp('PSM1', s_1, {
            'start': obs.T_world_tool['PSM1'], 'roll0': self._start_roll('PSM1', obs),
            'grasp_at': N_ins, 'paths': [ArcPath(arc, a_ins, a_out), RigidPath(N_out, N_lift)],
            'clear': extract[:1], 'bases': bases}, 'the extraction')
        park2 = _translated(_backed_off(N_ins @ invert_transform(G2), c.retreat_distance),
                            c.retreat_distance * up)
        Gh, _ = self._choose_grasp('PSM2', s_g, {
            'start': park2, 'roll0': roll2, 'grasp_at': N_lift,
            'paths': [RigidPath(N_lift, N_next)], 'clear': (), 'bases': bases}, 'the handover')

        t1 = _Track('PSM1', obs.T_world_tool['PSM1'], obs.jaw['PSM1'], c)
        t2 = _Track('PSM2', obs.T_world_tool['PSM2'], obs.jaw['PSM2'], c)
        labels = [(0.0, 'i')]
        gates = []

        # i: pick with PSM2 and reach the entry.
        if not picked:
            grasp_pose = N0 @ invert_transform(G2)
            t2.move(_backed_off(grasp_pose, c.approach_distance), jaw=c.jaw_open)
            t2.move(grasp_pose)
            t2.set_jaw(c.jaw_closed)
            gates.append(Gate(t2.t, 'PSM2', 'grasp'))
            t2.grab(N0, G2)
            t2.hold(c.settle_time)
            t2.carry(RigidPath(N0, N_up))
            t2.carry(RigidPath(N_up, N_pre_hi))
        else:
            t2.grab(N0, G2)
            t2.carry(RigidPath(N0, N_pre_hi))
        t2.carry(RigidPath(N_pre_hi, N_pre))
        t2.carry(ArcPath(arc, a_pre, a_entry), drive=True)

        # ii: insert to the exit; PSM1 gets ready.
        labels.append((t2.t, 'ii'))
        t1.hold_until(t2.t)
        pre1 = _backed_off(N_ins @ invert_transform(G1), c.approach_distance)
        t1.move(pre1, jaw=c.jaw_open_near_tissue)
        t2.carry(ArcPath(arc, a_entry, a_ins), drive=True)

        # iii: regrasp with PSM1, PSM2 lets go.
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

        # iv: extract with PSM1 along the arc, then lift; PSM2 backs away meanwhile.
        labels.append((t2.t, 'iv'))
        t1.hold_until(t2.t)
        t2.move(_backed_off(t2.pose, c.retreat_distance))
        t2.move(_translated(t2.pose, c.retreat_distance * up))
        t1.carry(ArcPath(arc, a_ins, a_out), drive=True)
        t1.carry(RigidPath(N_out, N_lift))

        # v: hand over to PSM2, PSM1 releases and parks, PSM2 goes to the next initial pose.
        labels.append((t1.t, 'v'))
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

        alphas = {'pre_entry': a_pre, 'entry': a_entry, 'exit': arc.alpha_exit,
                  'insert_end': a_ins, 'through': arc.alpha_through, 'extract_end': a_out}
        return Plan(segments={'PSM1': t1.segments, 'PSM2': t2.segments}, labels=tuple(labels),
                    gates=tuple(sorted(gates, key=lambda gt: gt.t)),
                    grasps={'PSM2_drive': G2, 'PSM1_extract': G1, 'PSM2_handover': Gh},
                    arc=arc, alphas=alphas)

    # ------------------------------------------------------------------ control
    def reset(self, obs):
        """
        Plan the throw from the observation and start its clock at ``obs.t``.

        Parameters
        ----------
        obs : Observation
            Start state.

        """
        self.plan_ = self.plan(obs)
        self._t0 = float(obs.t)
        self._offset = 0.0
        self._gate = 0
        self._waited = 0.0
        self._grasps = {}
        self._plan_time = 0.0

    @property
    def done(self):
        """Whether the plan has run to its end."""
        return self.plan_ is not None and self._plan_time >= self.plan_.duration

    def step(self, obs):
        """
        Command for the observation.

        Parameters
        ----------
        obs : Observation
            Current state.

        Returns
        -------
        Command
            Targets at ``obs.t``.

        """
        if self.plan_ is None:
            self.reset(obs)
        plan = self.plan_
        tau = obs.t - self._t0 - self._offset
        holders = set(obs.holders)
        while self._gate < len(plan.gates) and plan.gates[self._gate].t <= tau:
            gate = plan.gates[self._gate]
            held = gate.arm in holders
            if held == (gate.kind == 'grasp'):
                self._gate += 1
                self._waited = 0.0
                continue
            late = tau - gate.t
            if self._waited + late <= self.config.gate_timeout:
                self._waited += late
                self._offset += late
                tau = gate.t
                break
            _LOG.warning('%s %s not confirmed after %.2f s; going on', gate.arm, gate.kind,
                         self._waited)
            self._gate += 1
            self._waited = 0.0
        for arm in ARMS:
            if arm in holders:
                if arm not in self._grasps:
                    self._grasps[arm] = (invert_transform(obs.T_world_tool[arm])
                                         @ np.asarray(obs.T_world_needle, dtype=float))
            else:
                self._grasps.pop(arm, None)
        self._plan_time = tau
        cmd = plan.sample(tau, self._grasps)
        return Command(t=float(obs.t), T_world_tool=cmd.T_world_tool, jaw=cmd.jaw,
                       subtask=cmd.subtask)
