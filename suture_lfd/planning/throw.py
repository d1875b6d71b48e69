"""
The plan of a whole throw around given needle paths for subtasks ii and iv.

:func:`plan_throw` is the one throw planner. Subtasks i, iii and v are always scripted the same
way (paper Sec. III-C; world layout of ``config/world.yaml``: PSM2 right, PSM1 left):

i.   PSM2 opens its jaw, approaches the needle along its tool ``z``, grasps it, lifts it and
     carries it to the pose ``above`` the insertion, then along the ``approach`` legs.
ii.  PSM2 carries the needle along the ``insertion`` legs; meanwhile PSM1 moves to a pre-grasp
     pose.
iii. PSM1 approaches the needle part out of the exit, grasps it, PSM2 opens its jaw and backs
     away.
iv.  PSM1 carries the needle along the ``extraction`` legs.
v.   PSM2 grasps the needle near the tail, PSM1 releases it and returns to its start pose,
     PSM2 carries the needle to the next initial pose.

What differs between the scripted expert and the DMP executor is only the :class:`ThrowPaths`
they pass: the expert's needle turns about its circle through the markers
(:func:`suture_lfd.planning.expert.expert_paths`), the executor's follows the DMP rollouts
(:mod:`suture_lfd.skill.executor`). Every grasp is chosen by the
:class:`~suture_lfd.planning.grasps.GraspPlanner`; the plan's gates make the follower wait for
each grasp and release (:class:`~suture_lfd.planning.plan.PlanFollower`).

Frames: ``world``; poses 4x4 ``T_world_*``; metres, radians, seconds.
"""

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
import math
from typing import TYPE_CHECKING

import numpy as np
from sim_bridge.common.geometry import invert_transform
from suture_lfd.planning.grasps import GraspPhase
from suture_lfd.planning.plan import Gate, Plan
from suture_lfd.planning.tracks import Track, backed_off, translated
from suture_lfd.planning.waypoints import ArcPath, NeedlePath, PoseInterpolator, RigidPath

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.control import ExpertConfig, Observation
    from suture_lfd.planning.grasps import GraspPlanner
    from suture_lfd.planning.throw_geometry import ThrowArc


@dataclass(frozen=True, eq=False)
class Carry:
    """
    A leg carrying the held needle along ``path``, minimum-jerk timed.

    Attributes
    ----------
    path : callable
        Needle path (poses of ``sigma`` in [0, 1], with ``A``, ``B``, ``angle``).
    drive : bool
        Timed by the needle's drive speed (turning about its arc centre).
    min_duration : float or None
        Shortest duration (s) of the leg.

    """

    path: PoseInterpolator | ArcPath
    drive: bool = False
    min_duration: float | None = None


@dataclass(frozen=True, eq=False)
class Follow:
    """A leg carrying the held needle along ``path`` with the path's own timing (a rollout)."""

    path: NeedlePath
    duration: float


@dataclass(frozen=True)
class Hold:
    """A leg keeping still for ``duration`` seconds."""

    duration: float


@dataclass(frozen=True, eq=False)
class ThrowPaths:
    """
    The needle paths of a throw: where subtask i ends, subtasks ii and iv, where v ends.

    Attributes
    ----------
    above : ndarray (4, 4)
        Needle pose above the insertion start that subtask i carries the needle to.
    approach : tuple of Carry, Follow or Hold
        Legs of PSM2 from ``above`` to the start of the insertion (the end of subtask i).
    insertion : tuple of Carry, Follow or Hold
        Legs of PSM2 in subtask ii.
    insertion_reach : tuple of callable
        Needle paths from ``above`` to the end of the insertion that PSM2's grasp must keep
        reachable.
    insertion_clear : tuple of ndarray (4, 4)
        Needle poses of the insertion where PSM2's closed jaw keeps off the tissue.
    insertion_end : ndarray (4, 4)
        Needle pose at the end of the insertion (PSM1 grasps it there).
    extraction : tuple of Carry, Follow or Hold
        Legs of PSM1 in subtask iv.
    extraction_reach : tuple of callable
        Needle paths of the extraction that PSM1's grasp must keep reachable.
    extraction_clear : tuple of ndarray (4, 4)
        Needle poses where PSM1's closed jaw keeps off the tissue.
    extraction_end : ndarray (4, 4)
        Needle pose at the end of the extraction (PSM2 takes it over there).
    next_pose : ndarray (4, 4)
        Needle pose PSM2 carries the needle to at the end (above the next pair's entry).
    extract_s : float
        Preferred arc parameter of PSM1's grasp.
    extract_span : tuple of float or None
        ``(lo, hi)`` arc parameters PSM1's grasp may move to when ``extract_s`` is out of
        reach (None: only ``extract_s``).
    handover_gap : float or None
        With a value, PSM2's hand-over grasp may move along the needle up to this arc span
        short of PSM1's grasp (None: only the preferred one).
    handover_fallback : bool
        When no hand-over grasp carries the needle to ``next_pose``, lift it straight up
        instead.
    alphas : dict of str to float
        Key angles (rad) of the needle circle, kept in the plan (empty when not on a circle).

    """

    above: np.ndarray
    approach: tuple
    insertion: tuple
    insertion_reach: tuple
    insertion_clear: tuple
    insertion_end: np.ndarray
    extraction: tuple
    extraction_reach: tuple
    extraction_clear: tuple
    extraction_end: np.ndarray
    next_pose: np.ndarray
    extract_s: float
    extract_span: tuple | None = None
    handover_gap: float | None = None
    handover_fallback: bool = False
    alphas: dict = field(default_factory=dict)


def drive_grasp_s(arc: 'ThrowArc', needle_geometry: 'NeedleGeometry',
                  config: 'ExpertConfig') -> float:
    """
    Return the arc parameter of PSM2's grasp for the insertion.

    The grasp stays ``clearance_deg`` clear of the entry when ``protrusion_deg`` of the tip is
    out of the exit, within ``[grasp_s_min, grasp_s_max]``.

    Parameters
    ----------
    arc : suture_lfd.planning.throw_geometry.ThrowArc
        The throw circle.
    needle_geometry : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    config : sim_bridge.control.ExpertConfig
        Motion parameters.

    Returns
    -------
    float
        Arc parameter (0 tail, 1 tip).

    """
    c = config
    deg = math.radians
    s_g = 1.0 - (deg(c.clearance_deg) + arc.inside_angle + deg(c.protrusion_deg)) \
        / needle_geometry.arc
    return min(c.grasp_s_max, max(c.grasp_s_min, s_g))


def _run(track: Track, legs: Iterable[Carry | Follow | Hold]) -> None:
    for leg in legs:
        if isinstance(leg, Hold):
            track.hold(leg.duration)
        elif isinstance(leg, Follow):
            track.follow(leg.path, leg.duration)
        else:
            track.carry(leg.path, drive=leg.drive, min_duration=leg.min_duration)


def plan_throw(obs: 'Observation', grasps: 'GraspPlanner', arc: 'ThrowArc', paths: ThrowPaths,
               config: 'ExpertConfig') -> Plan:
    """
    Plan a whole throw around the given needle paths.

    Parameters
    ----------
    obs : sim_bridge.control.Observation
        Start state (tool poses, jaws, needle pose, holders, arm bases).
    grasps : suture_lfd.planning.grasps.GraspPlanner
        Grasp choice on the target pair.
    arc : suture_lfd.planning.throw_geometry.ThrowArc
        The throw circle (PSM2's grasp; kept in the plan).
    paths : ThrowPaths
        The needle paths of the throw.
    config : sim_bridge.control.ExpertConfig
        Motion parameters.

    Returns
    -------
    suture_lfd.planning.plan.Plan
        Plan times start at 0 (= ``obs.t``).

    Raises
    ------
    ValueError
        If no grasp keeps a holding phase inside the arms' reach.

    """
    c = config
    up = np.array([0.0, 0.0, 1.0])
    bases = obs.T_world_base
    above, N_ins, N_lift, N_next = (paths.above, paths.insertion_end, paths.extraction_end,
                                    paths.next_pose)
    s_g = drive_grasp_s(arc, grasps.needle, c)
    N0 = np.array(obs.T_world_needle, dtype=float)
    N_up = translated(N0, c.pick_lift * up)
    picked = 'PSM2' in tuple(obs.holders)
    reach2 = list(paths.insertion_reach)
    if picked:
        G2, roll2 = grasps.held_grasp('PSM2', obs, [RigidPath(N0, above)] + reach2,
                                      'the insertion')
    else:
        G2, roll2 = grasps.choose_grasp('PSM2', s_g, GraspPhase(
            start=obs.T_world_tool['PSM2'], roll0=grasps.start_roll('PSM2', obs), grasp_at=N0,
            paths=[RigidPath(N0, N_up), RigidPath(N_up, above)] + reach2,
            clear=paths.insertion_clear, bases=bases), 'the pick-up and insertion')
    extraction = GraspPhase(
        start=obs.T_world_tool['PSM1'], roll0=grasps.start_roll('PSM1', obs), grasp_at=N_ins,
        paths=list(paths.extraction_reach), clear=paths.extraction_clear, bases=bases)
    if paths.extract_span is None:
        s_1 = paths.extract_s
        G1, _ = grasps.choose_grasp('PSM1', s_1, extraction, 'the extraction')
    else:
        G1, _, s_1 = grasps.choose_grasp_along('PSM1', paths.extract_s, paths.extract_span,
                                               extraction, 'the extraction')
    park2 = translated(backed_off(N_ins @ invert_transform(G2), c.retreat_distance),
                       c.retreat_distance * up)
    handover = GraspPhase(start=park2, roll0=roll2, grasp_at=N_lift,
                          paths=[RigidPath(N_lift, N_next)], clear=(), bases=bases)
    if paths.handover_gap is None:
        Gh, _ = grasps.choose_grasp('PSM2', s_g, handover, 'the handover')
    else:
        span_h = (c.grasp_s_min, s_1 - paths.handover_gap)
        try:
            Gh, _, _ = grasps.choose_grasp_along('PSM2', s_g, span_h, handover, 'the handover')
        except ValueError:
            if not paths.handover_fallback:
                raise
            # No grasp of the extracted needle also carries it to the next start (the
            # extraction may end turned far from it): the hand-over completes and PSM2 lifts
            # the needle straight up instead.
            N_next = translated(N_lift, c.next_lift * up)
            Gh, _, _ = grasps.choose_grasp_along(
                'PSM2', s_g, span_h, replace(handover, paths=[RigidPath(N_lift, N_next)]),
                'the handover')

    t1 = Track('PSM1', obs.T_world_tool['PSM1'], obs.jaw['PSM1'], c)
    t2 = Track('PSM2', obs.T_world_tool['PSM2'], obs.jaw['PSM2'], c)
    labels = [(0.0, 'i')]
    gates = []

    # i: pick with PSM2, carry the needle above the insertion start, approach it.
    if not picked:
        grasp_pose = N0 @ invert_transform(G2)
        t2.move(backed_off(grasp_pose, c.approach_distance), jaw=c.jaw_open)
        t2.move(grasp_pose)
        t2.set_jaw(c.jaw_closed)
        gates.append(Gate(t2.t, 'PSM2', 'grasp'))
        t2.grab(N0, G2)
        t2.hold(c.settle_time)
        t2.carry(RigidPath(N0, N_up))
        t2.carry(RigidPath(N_up, above))
    else:
        t2.grab(N0, G2)
        t2.carry(RigidPath(N0, above))
    _run(t2, paths.approach)

    # ii: insertion with PSM2; PSM1 gets ready.
    labels.append((t2.t, 'ii'))
    t1.hold_until(t2.t)
    pre1 = backed_off(N_ins @ invert_transform(G1), c.approach_distance)
    t1.move(pre1, jaw=c.jaw_open_near_tissue)
    _run(t2, paths.insertion)

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

    # iv: extraction with PSM1; PSM2 backs away meanwhile.
    labels.append((t2.t, 'iv'))
    t1.hold_until(t2.t)
    t2.move(backed_off(t2.pose, c.retreat_distance))
    t2.move(translated(t2.pose, c.retreat_distance * up))
    _run(t1, paths.extraction)

    # v: hand over to PSM2, PSM1 releases and parks, PSM2 goes to the next initial pose.
    labels.append((max(t1.t, t2.t), 'v'))
    t1.hold_until(t2.t)
    grasp_h = N_lift @ invert_transform(Gh)
    t2.move(backed_off(grasp_h, c.approach_distance), jaw=c.jaw_open)
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
    t1.move(backed_off(t1.pose, c.retreat_distance))
    t1.move(np.array(obs.T_world_tool['PSM1'], dtype=float))
    t2.carry(RigidPath(N_lift, N_next))
    end = max(t1.t, t2.t)
    t1.hold_until(end)
    t2.hold_until(end)
    labels.append((end, 'done'))
    return Plan(segments={'PSM1': t1.segments, 'PSM2': t2.segments}, labels=tuple(labels),
                gates=tuple(sorted(gates, key=lambda gt: gt.t)),
                grasps={'PSM2_drive': G2, 'PSM1_extract': G1, 'PSM2_handover': Gh},
                arc=arc, alphas=dict(paths.alphas))
