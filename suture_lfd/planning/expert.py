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

The expert's needle paths for ii and iv (:func:`expert_paths`) turn the needle about its circle
through the markers; the throw around them is planned by
:func:`suture_lfd.planning.throw.plan_throw` (minimum-jerk segments, grasps chosen by the
:class:`~suture_lfd.planning.grasps.GraspPlanner`) and followed in closed loop by a
:class:`~suture_lfd.planning.plan.PlanFollower`.

Frames: ``world``; poses 4x4 ``T_world_*``; metres, radians, seconds.
"""

import math
from typing import TYPE_CHECKING, cast

import numpy as np
from sim_bridge.control import ExpertConfig
from suture_lfd.planning.grasps import GraspPlanner
from suture_lfd.planning.plan import ARMS, LABELS, Gate, Plan, PlanFollower
from suture_lfd.planning.throw import Carry, ThrowPaths, drive_grasp_s, plan_throw
from suture_lfd.planning.throw_geometry import ThrowArc
from suture_lfd.planning.tracks import translated
from suture_lfd.planning.waypoints import ArcPath, RigidPath, rotation_exp

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.control import Command, Observation
    from sim_bridge.kinematics import PsmKinematics
    from sim_bridge.scene.phantom import MarkerPair

__all__ = ['ARMS', 'LABELS', 'Gate', 'Plan', 'ScriptedExpert', 'expert_paths']


def expert_paths(arc: ThrowArc, pair: 'MarkerPair', needle_geometry: 'NeedleGeometry',
                 config: ExpertConfig, next_pair: 'MarkerPair | None' = None) -> ThrowPaths:
    """
    Return the scripted expert's needle paths: turning about the throw circle.

    The tip starts ``pre_entry_angle_deg`` before the entry, ``pre_entry_lift`` above it, and
    goes in at the entry; the insertion ends when ``protrusion_deg`` of the tip is out while
    PSM2's grasp stays ``clearance_deg`` clear of the entry; the extraction turns the needle on
    until the tail is ``extract_margin_deg`` past the exit, then lifts it ``extract_lift``.

    Parameters
    ----------
    arc : suture_lfd.planning.throw_geometry.ThrowArc
        The throw circle (with the skill noise, if any).
    pair : sim_bridge.scene.phantom.MarkerPair
        Target pair (its normal sets the lifts).
    needle_geometry : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    config : sim_bridge.control.ExpertConfig
        Motion parameters.
    next_pair : sim_bridge.scene.phantom.MarkerPair, optional
        Pair of the next throw; the needle ends above its entry (default: above this pair's).

    Returns
    -------
    suture_lfd.planning.throw.ThrowPaths

    """
    c = config
    g = needle_geometry
    deg = math.radians
    s_g = drive_grasp_s(arc, g, c)
    a_pre = arc.alpha_entry + deg(c.pre_entry_angle_deg)
    a_entry = arc.alpha_entry
    a_ins = arc.alpha_tail_entry + s_g * g.arc + deg(c.clearance_deg)
    a_ins = min(a_ins, arc.alpha_exit - deg(4.0))
    a_out = arc.alpha_through - deg(c.extract_margin_deg)
    protrusion = arc.alpha_exit - a_ins
    s_1 = 1.0 - 0.5 * protrusion / g.arc

    normal = np.asarray(pair.normal, dtype=float)
    N_pre = arc.T_world_needle(a_pre)
    N_pre_hi = translated(N_pre, c.pre_entry_lift * normal)
    N_ins = arc.T_world_needle(a_ins)
    N_out = arc.T_world_needle(a_out)
    N_lift = translated(N_out, c.extract_lift * normal)
    if next_pair is not None:
        nxt = ThrowArc(next_pair, g)
        N_next = translated(nxt.T_world_needle(nxt.alpha_entry + deg(c.pre_entry_angle_deg)),
                            (c.pre_entry_lift + c.next_lift) * np.asarray(next_pair.normal))
    else:
        N_next = translated(N_pre_hi, c.next_lift * normal)
    drive = [arc.T_world_needle(a) for a in np.linspace(a_pre, a_ins, 7)]
    extract = [arc.T_world_needle(a) for a in np.linspace(a_ins, a_out, 9)]
    return ThrowPaths(
        above=N_pre_hi,
        approach=(Carry(RigidPath(N_pre_hi, N_pre)),
                  Carry(ArcPath(arc, a_pre, a_entry), drive=True)),
        insertion=(Carry(ArcPath(arc, a_entry, a_ins), drive=True),),
        insertion_reach=(RigidPath(N_pre_hi, N_pre), ArcPath(arc, a_pre, a_entry),
                         ArcPath(arc, a_entry, a_ins)),
        insertion_clear=tuple(drive), insertion_end=N_ins,
        extraction=(Carry(ArcPath(arc, a_ins, a_out), drive=True),
                    Carry(RigidPath(N_out, N_lift))),
        extraction_reach=(ArcPath(arc, a_ins, a_out), RigidPath(N_out, N_lift)),
        extraction_clear=tuple(extract[:1]), extraction_end=N_lift, next_pose=N_next,
        extract_s=s_1,
        alphas={'pre_entry': a_pre, 'entry': a_entry, 'exit': arc.alpha_exit,
                'insert_end': a_ins, 'through': arc.alpha_through, 'extract_end': a_out})


class ScriptedExpert:
    """
    Scripted suturing expert for one marker pair.

    Parameters
    ----------
    pair : sim_bridge.scene.phantom.MarkerPair
        Target pair (world frame).
    needle_geometry : sim_bridge.common.needle.NeedleGeometry
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

    def __init__(self, pair: 'MarkerPair', needle_geometry: 'NeedleGeometry',
                 config: ExpertConfig | None = None, rng: np.random.Generator | None = None,
                 kinematics: 'PsmKinematics | dict[str, PsmKinematics] | None' = None,
                 next_pair: 'MarkerPair | None' = None) -> None:
        self.pair = pair
        self.needle = needle_geometry
        self.config = ExpertConfig() if config is None else config
        self.rng = rng
        self.grasps = GraspPlanner(pair, needle_geometry, self.config, kinematics)
        self.kinematics = self.grasps.kinematics
        self.next_pair = next_pair
        self.plan_: Plan | None = None
        self.follower: PlanFollower | None = None

    def noisy_pair(self) -> 'MarkerPair':
        """Return the target pair moved and turned by the skill noise (the pair without it)."""
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
    def plan(self, obs: 'Observation') -> Plan:
        """
        Plan the whole throw from an observation.

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Start state (tool poses, jaws, needle pose, holders, arm bases).

        Returns
        -------
        suture_lfd.planning.plan.Plan
            Plan times start at 0 (= ``obs.t``).

        Raises
        ------
        ValueError
            If no grasp keeps a holding phase inside the arms' reach.

        """
        arc = ThrowArc(self.noisy_pair(), self.needle)
        paths = expert_paths(arc, self.pair, self.needle, self.config, self.next_pair)
        return plan_throw(obs, self.grasps, arc, paths, self.config)

    # ------------------------------------------------------------------ control
    def reset(self, obs: 'Observation') -> None:
        """
        Plan the throw from the observation and start its clock at ``obs.t``.

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Start state.

        """
        self.plan_ = self.plan(obs)
        self.follower = PlanFollower(self.plan_, obs.t, self.config.gate_timeout)

    @property
    def done(self) -> bool:
        """Whether the plan has run to its end."""
        return self.follower is not None and self.follower.done

    @property
    def plan_time(self) -> float:
        """Plan time (s) of the last command."""
        return 0.0 if self.follower is None else self.follower.plan_time

    def step(self, obs: 'Observation') -> 'Command':
        """Return the command for ``obs`` (planned at the first call; see PlanFollower.step)."""
        if self.plan_ is None:
            self.reset(obs)
        return cast(PlanFollower, self.follower).step(obs)  # set by reset
