"""
A timed throw plan (:class:`Plan`) and the controller that follows it (:class:`PlanFollower`).

A plan holds, per arm, contiguous minimum-jerk motion segments
(:mod:`suture_lfd.planning.waypoints`) in plan time (s from the start), the subtask labels, and
the grasp and release gates. It is built by :func:`suture_lfd.planning.throw.plan_throw`; the
scripted expert, the demonstrator and the DMP executor all use it.

Frames: ``world``; poses 4x4 ``T_world_*``; metres, radians, seconds.
"""

from collections.abc import Mapping
from dataclasses import dataclass, field
import logging
from typing import cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.vocabulary import PSMS as ARMS
from sim_bridge.control import Command, Observation
from suture_lfd.planning.throw_geometry import ThrowArc
from suture_lfd.planning.waypoints import ToolMove

_LOG = logging.getLogger(__name__)

LABELS = ('i', 'ii', 'iii', 'iv', 'v', 'done')


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
        Per arm, contiguous motion segments (:class:`~suture_lfd.planning.waypoints.ToolMove` /
        :class:`~suture_lfd.planning.waypoints.NeedleMove`) covering
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
    def duration(self) -> float:
        """Plan length (s)."""
        return max(seg[-1].t1 for seg in self.segments.values())

    def segment_at(self, arm: str, t: float) -> ToolMove:
        """
        Return the motion segment of ``arm`` at plan time ``t`` (s) (the last one after it).

        Parameters
        ----------
        arm : str
            ``'PSM1'`` or ``'PSM2'``.
        t : float
            Plan time (s).

        Returns
        -------
        suture_lfd.planning.waypoints.ToolMove or suture_lfd.planning.waypoints.NeedleMove

        """
        segs = self.segments[arm]
        for seg in segs:
            if t <= seg.t1:
                return seg
        return segs[-1]

    def label(self, t: float) -> str:
        """Subtask label at plan time ``t`` (s)."""
        current = self.labels[0][1]
        for t0, name in self.labels:
            if t >= t0:
                current = name
        return current

    def sample(self, t: float, grasps: Mapping[str, np.ndarray] | None = None) -> Command:
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
        return Command(float(t), *self.targets(t, grasps))

    def targets(self, t: float, grasps: Mapping[str, np.ndarray] | None = None
                ) -> tuple[dict[str, np.ndarray], dict[str, float], str]:
        """
        Return the targets of :meth:`sample` at plan time ``t`` (s), without a Command.

        Returns
        -------
        tools : dict of str to ndarray (4, 4)
        jaws : dict of str to float
        subtask : str

        """
        grasps = grasps or {}
        tools: dict[str, np.ndarray]
        jaws: dict[str, float]
        tools, jaws = {}, {}
        for arm in self.segments:
            seg = self.segment_at(arm, t)
            tools[arm] = seg.tool(t, grasps.get(arm) if seg.carries_needle else None)
            jaws[arm] = seg.jaw(t)
        return tools, jaws, self.label(t)

    def needle(self, t: float) -> np.ndarray | None:
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
            seg = self.segment_at(arm, t)
            if seg.carries_needle:
                return seg.needle(t)
        return None

    def knots(self, arm: str) -> list[tuple[float, np.ndarray, float]]:
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

    def sampled(self, dt: float) -> dict[str, np.ndarray]:
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


def track_grasps(grasps: dict[str, np.ndarray], obs: Observation,
                 holders: set[str] | None = None) -> None:
    """
    Keep the grasps of the needle in step with the PSMs that hold it in ``obs``.

    An arm that has just grasped the needle gets its grasp ``T_tool_needle`` at the moment it
    is first seen holding; an arm that no longer holds it loses its grasp.

    Parameters
    ----------
    grasps : dict of str to ndarray, shape (4, 4)
        Arm -> ``T_tool_needle``; updated in place.
    obs : sim_bridge.control.Observation
        Current state (``world`` frame).
    holders : set of str, optional
        ``set(obs.holders)``, when the caller has it already.

    """
    holders = set(obs.holders) if holders is None else holders
    for arm in ARMS:
        if arm in holders:
            if arm not in grasps:
                grasps[arm] = (invert_transform(obs.T_world_tool[arm])
                               @ np.asarray(obs.T_world_needle, dtype=float))
        else:
            grasps.pop(arm, None)


class PlanFollower:
    """
    Follow a :class:`Plan` in closed loop: the controller part of the scripted expert.

    The plan's clock waits (up to ``gate_timeout``) at each grasp or release gate until the
    observation confirms it. While an arm holds the needle the follower measures the actual
    grasp (``inv(T_world_tool) @ T_world_needle``) and moves the tool so that the *needle*
    follows the planned path.

    Parameters
    ----------
    plan : Plan
        The plan.
    t0 : float or None
        Simulation time (s) of plan time 0; None: the time of the first :meth:`step`.
    gate_timeout : float
        Longest wait (s) for a gate.

    Attributes
    ----------
    offset : float
        Time (s) the plan clock has been held back (gates; a caller may add to it, e.g. phase
        stopping).
    plan_time : float
        Plan time (s) of the last command.

    """

    def __init__(self, plan: Plan, t0: float | None, gate_timeout: float) -> None:
        self.plan = plan
        self.t0 = None if t0 is None else float(t0)
        self.gate_timeout = gate_timeout
        self.offset = 0.0
        self.plan_time = 0.0
        self._gate = 0
        self._waited = 0.0
        self._grasps: dict[str, np.ndarray] = {}

    @property
    def done(self) -> bool:
        """Whether the plan has run to its end."""
        return self.plan_time >= self.plan.duration

    def set_grasp(self, arm: str, grasp: ArrayLike) -> None:
        """
        Take ``grasp`` (``T_tool_needle``, 4x4) as ``arm``'s grasp from now on (measured again).

        The tool then moves so that the needle, as this grasp puts it, follows the plan.
        """
        self._grasps[arm] = np.asarray(grasp, dtype=float)

    def grasp(self, arm: str) -> np.ndarray | None:
        """
        Return the grasp ``T_tool_needle`` (4x4) followed for ``arm``, or None.

        Parameters
        ----------
        arm : str
            Arm name.

        Returns
        -------
        ndarray, shape (4, 4) or None

        """
        return self._grasps.get(arm)

    def tau(self, t: float) -> float:
        """Plan time (s) at simulation time ``t`` before gates are considered."""
        return t - cast(float, self.t0) - self.offset  # t0 is set by the first step

    def step(self, obs: Observation) -> Command:
        """
        Command for the observation.

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Current state.

        Returns
        -------
        sim_bridge.control.Command
            Targets at ``obs.t``.

        """
        if self.t0 is None:
            self.t0 = float(obs.t)
        plan = self.plan
        tau = obs.t - self.t0 - self.offset
        holders = set(obs.holders)
        while self._gate < len(plan.gates) and plan.gates[self._gate].t <= tau:
            gate = plan.gates[self._gate]
            held = gate.arm in holders
            if held == (gate.kind == 'grasp'):
                self._gate += 1
                self._waited = 0.0
                continue
            late = tau - gate.t
            if self._waited + late <= self.gate_timeout:
                self._waited += late
                self.offset += late
                tau = gate.t
                break
            _LOG.warning('%s %s not confirmed after %.2f s; going on', gate.arm, gate.kind,
                         self._waited)
            self._gate += 1
            self._waited = 0.0
        track_grasps(self._grasps, obs, holders)
        self.plan_time = tau
        return Command(float(obs.t), *plan.targets(tau, self._grasps))
