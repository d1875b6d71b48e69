"""
The interface between the simulation and a controller of the two PSMs.

A :class:`Controller` (the scripted expert, the demonstrator, the DMP executor) is called with
an :class:`Observation` every control period and answers with a :class:`Command`;
:meth:`sim_bridge.simulation.Simulation.run` and the ROS nodes pass these along.
:class:`ExpertConfig` holds the motion parameters of the scene's scripted expert (the ``expert``
section of ``config/scene.yaml``); the planner itself is :mod:`suture_lfd.planning`.

Frames: ``world``; poses 4x4 ``T_world_*``; metres, radians, seconds.
"""

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from sim_bridge.common.validation import check_positive


@dataclass(frozen=True)
class ExpertConfig:
    """
    Motion parameters of the scripted expert.

    Attributes
    ----------
    tool_speed : float
        Peak speed (m/s) of free tool motions.
    tool_angular_speed : float
        Peak angular speed (rad/s) of tool and needle motions.
    tool_acceleration : float
        Peak acceleration (m/s^2) of a minimum-jerk tool motion (5.77 d / T^2); kept below the
        dVRK's joint acceleration limits (insertion 0.2 m/s^2, yaw/pitch 90 deg/s^2 at the
        insertion depth) so the arms track the plan without overshooting it.
    tool_angular_acceleration : float
        Peak angular acceleration (rad/s^2) of a minimum-jerk tool rotation.
    drive_speed : float
        Peak angular speed (rad/s) of the needle turning about its arc centre.
    min_move_time : float
        Shortest motion segment (s).
    jaw_time : float
        Time (s) to open or close a jaw.
    settle_time : float
        Pause (s) after a grasp.
    jaw_open : float
        Open jaw angle (rad) away from the tissue.
    jaw_open_near_tissue : float
        Open jaw angle (rad) when grasping the needle next to the tissue.
    jaw_closed : float
        Closed jaw angle (rad).
    approach_distance : float
        Distance (m) along minus tool ``z`` of the pre-grasp pose.
    retreat_distance : float
        Distance (m) a releasing tool backs away along minus tool ``z``.
    pick_lift : float
        Lift (m, world up) after picking the needle.
    pre_entry_angle_deg : float
        The tip starts this far (deg along the needle circle) before the entry.
    pre_entry_lift : float
        Height (m, along the pair normal) of the pose above the pre-entry pose.
    clearance_deg : float
        Arc (deg) kept between the PSM2 grasp and the entry at the end of the insertion.
    protrusion_deg : float
        Arc (deg) of the tip out of the exit at the end of the insertion.
    grasp_s_max, grasp_s_min : float
        Range of the PSM2 grasp's arc parameter (0 tail, 1 tip).
    extract_margin_deg : float
        Arc (deg) the tail is pulled past the exit.
    extract_lift : float
        Lift (m, along the pair normal) after the extraction.
    next_lift : float
        Height (m) of the next initial pose above the next pre-entry pose.
    roll_step_deg : float
        Step (deg) of the jaw rolls tried when choosing a grasp.
    jaw_length, jaw_half_width : float
        Closed jaw outline (m) along and across tool ``z``, for keeping it off the tissue.
    jaw_clearance : float
        Height (m) the closed jaw keeps above the surface plane of the pair while the needle
        is in the tissue, where a grasp allows it.
    gate_timeout : float
        Longest wait (s) for a grasp or release to be confirmed.
    aim_std : float
        Standard deviation (m) of a random offset of the planned throw circle in the surface
        plane (skill noise; 0 for the expert).
    tilt_std_deg : float
        Standard deviation (deg) of a random turn of the needle plane about the pair normal.
    speed_scale : float
        Factor on every speed (1: nominal).

    """

    tool_speed: float = 0.04
    tool_angular_speed: float = 2.0
    tool_acceleration: float = 0.1
    tool_angular_acceleration: float = 6.0
    drive_speed: float = 1.0
    min_move_time: float = 0.2
    jaw_time: float = 0.2
    settle_time: float = 0.1
    jaw_open: float = 0.8
    jaw_open_near_tissue: float = 0.6
    jaw_closed: float = -0.2
    approach_distance: float = 0.008
    retreat_distance: float = 0.010
    pick_lift: float = 0.010
    pre_entry_angle_deg: float = 20.0
    pre_entry_lift: float = 0.005
    clearance_deg: float = 12.0
    protrusion_deg: float = 24.0
    grasp_s_max: float = 1.0 / 3.0
    grasp_s_min: float = 0.06
    extract_margin_deg: float = 15.0
    extract_lift: float = 0.015
    next_lift: float = 0.010
    roll_step_deg: float = 15.0
    jaw_length: float = 0.009
    jaw_half_width: float = 0.00125
    jaw_clearance: float = 0.0003
    gate_timeout: float = 1.0
    aim_std: float = 0.0
    tilt_std_deg: float = 0.0
    speed_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ('tool_speed', 'tool_angular_speed', 'tool_acceleration',
                     'tool_angular_acceleration', 'drive_speed', 'speed_scale', 'roll_step_deg'):
            check_positive(getattr(self, name), f'expert {name}')
        if not 0.0 <= self.grasp_s_min <= self.grasp_s_max <= 1.0:
            raise ValueError('expert needs 0 <= grasp_s_min <= grasp_s_max <= 1')
        if self.aim_std < 0.0 or self.tilt_std_deg < 0.0:
            raise ValueError('expert aim_std and tilt_std_deg must be >= 0')


@dataclass(frozen=True, eq=False)
class Observation:
    """
    What the expert sees at one instant (world frame).

    Attributes
    ----------
    t : float
        Simulation time (s).
    T_world_tool : dict of str to ndarray (4, 4)
        Tool-tip poses (``measured_cp`` in ``world``) of ``'PSM1'`` and ``'PSM2'``.
    jaw : dict of str to float
        Jaw angles (rad).
    T_world_needle : ndarray, shape (4, 4) or None
        Needle pose; None when an estimator cannot see the needle.
    holders : tuple of str
        Arms holding the needle.
    pair : sim_bridge.scene.phantom.MarkerPair
        Target marker pair.
    T_world_base : dict of str to ndarray (4, 4)
        RCM frame of each arm.
    q : dict of str to ndarray (6,) or None
        Joint positions of each PSM (rad, m), if known; they tell the roll joint's turn count
        (otherwise taken from the inverse kinematics nearest the home configuration).

    """

    t: float
    T_world_tool: dict
    jaw: dict
    T_world_needle: np.ndarray | None
    holders: tuple
    pair: object
    T_world_base: dict
    q: dict | None = None


@dataclass(frozen=True, eq=False)
class Command:
    """
    Targets for the arms at one instant (world frame).

    Attributes
    ----------
    t : float
        Time (s) the command is for.
    T_world_tool : dict of str to ndarray (4, 4) or None
        Tool-tip pose target per arm (None: no new target).
    jaw : dict of str to float or None
        Jaw angle target (rad) per arm (None: no new target).
    subtask : str
        ``'i'`` .. ``'v'`` or ``'done'``.

    """

    t: float
    T_world_tool: dict
    jaw: dict
    subtask: str


class CommandSource(Protocol):
    """What a control loop asks for commands: a controller, or a wrapper of one (a recorder)."""

    def step(self, obs: Observation) -> Command:
        """Return the command for the next control period, given the latest observation."""


@runtime_checkable
class Controller(Protocol):
    """
    What drives the two PSMs for a control loop: reset once, then one command per observation.

    The scripted expert (:class:`suture_lfd.planning.expert.ScriptedExpert`), the demonstrator
    and the DMP executor are controllers; :func:`suture_lfd.planning.episode.run_episode` and
    the ROS nodes drive them alike.
    """

    def reset(self, obs: Observation) -> None:
        """Start over from the observation ``obs`` (the first of the episode)."""

    def step(self, obs: Observation) -> Command:
        """Return the command for the next control period, given the latest observation."""

    @property
    def done(self) -> bool:
        """Whether the controller has finished its task (the loop may stop)."""
