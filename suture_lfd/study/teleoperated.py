"""
A subject demonstrating on a robot with hidden kinematic errors, recorded as the robot sees it.

A person teleoperating a dVRK does not command absolute tool poses: the MTM moves the tool
*relative to where it is seen* in the endoscope's image, and the person keeps moving until the
tool is where they want it. Kinematic errors (:mod:`sim_bridge.kinematic_errors`) therefore do
not stop a person; they only make the robot's reports (``measured_cp``) differ from where the
tool is. :class:`TeleoperatedRobot` models exactly that for a synthetic subject
(:func:`suture_lfd.demos.demonstrator.run_demonstration` with ``link=``): the subject keeps
watching the scene, and each of its targets is sent through the arm's own frame,

    T_command = T_reported @ inv(T_seen) @ T_target,

the displacement the subject wants from where it sees the tool, applied to where the robot
believes the tool is (a person's visual loop: the arm's error is taken up command after
command). What is recorded is what a recorder on the robot gets
(:class:`sim_bridge.observers.PhysicalObserver` with :class:`suture_lfd.skill.perceived.
PerceivedScene`): the arms' reports, the jaws, and the needle, its holders and the markers as the
endoscope's images give them (images are looked at only when the estimator needs them).

As in a lab, the robot is registered before anything is recorded
(:func:`suture_lfd.skill.arm_registration.register_arms`, once per simulation, before the first
attempt resets the scene): the recorder judges each grasp against the corrected tool pose, as
the executor does, instead of the raw report, which at the 3 mm class is 5-10 mm off -- more
than a grasp's reach. The registration run resets the scene and moves the arms, so it must come
before the demonstration's episode starts, never between its start and its first sample.

Frames: ``world`` (the robot's believed one for what is recorded); poses 4x4; metres.
"""

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.observers import PhysicalObserver
from suture_lfd.skill.arm_registration import KinematicCorrection, register_arms
from suture_lfd.skill.perceived import PerceivedScene

if TYPE_CHECKING:
    from sim_bridge.control import Command, Observation
    from sim_bridge.simulation import Simulation


#: The recorder looks at the carried needle again when it faces the camera this squarely
#: (:class:`suture_lfd.skill.perceived.PerceivedScene` ``refit_facing``): turned from how it
#: lay, its tilt shows (the executor looks at about the same facing, 0.6, chosen from its plan).
REFIT_FACING = 0.7


class TeleoperatedRobot:
    """
    The link between a subject and a simulated robot in physical mode.

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
        The scene (its kinematic errors hidden in it).
    pair_name : str
        The target pair (``'synth1'``); the recorder perceives its markers.
    register : bool
        Register the arms against the endoscope now (kept for ``sim``) and record the tool
        poses the correction gives; False records the raw reports.
    refit_facing : float or None
        The recorder's second look at a needle picked up from where it lay
        (:class:`suture_lfd.skill.perceived.PerceivedScene` ``refit_facing``; None: none).

    Attributes
    ----------
    renders : int
        Stereo pairs the recorder's perception looked at so far.
    correction : suture_lfd.skill.arm_registration.KinematicCorrection or None
        The arms' registration the recorder sees the tools through (None: raw reports).

    """

    def __init__(self, sim: 'Simulation', pair_name: str, register: bool = True,
                 refit_facing: float | None = REFIT_FACING) -> None:
        if pair_name not in sim.phantom.markers:
            raise ValueError(f'unknown marker pair {pair_name!r}; the phantom has '
                             f'{sorted(sim.phantom.markers)}')
        self._sim = sim
        self._pair_name = str(pair_name)
        self._refit_facing = refit_facing
        self._index = int(sim.phantom.markers[pair_name].index)
        self._observer: PhysicalObserver | None = None
        self._perception: PerceivedScene | None = None
        self.renders = 0
        # before any episode: the registration run resets the scene and moves the arms
        self.correction: KinematicCorrection | None = register_arms(sim) if register else None

    def start(self) -> None:
        """Begin an attempt: the recorder's perception forgets the needle and its grasps."""
        if self._perception is not None:
            self.renders += self._perception.renders
        self._perception = PerceivedScene(self._pair_name, self._index,
                                          self._sim.needle_geometry,
                                          refit_facing=self._refit_facing)
        self._observer = PhysicalObserver(self._sim, self._perception,
                                          correction=self.correction)

    def command(self, cmd: 'Command') -> 'Command':
        """
        Return the subject's command as the arms get it through a teleoperation.

        Parameters
        ----------
        cmd : sim_bridge.control.Command
            Targets where the subject wants the tools (``world`` as seen).

        Returns
        -------
        sim_bridge.control.Command
            The same jaws; each tool target moved into the arm's own believed frame.

        """
        targets = cmd.T_world_tool or {}
        if not targets:
            return cmd
        sim = self._sim
        out: dict[str, Any] = {}
        for arm, T in targets.items():
            if T is None or arm not in PSMS:
                out[arm] = T
                continue
            T_seen = sim.tool_pose(arm)
            T_reported = sim.reported_tool_pose(arm)
            out[arm] = T_reported @ np.linalg.solve(T_seen, np.asarray(T, dtype=float))
        return replace(cmd, T_world_tool=out)

    def record(self) -> 'Observation':
        """
        Return what the recorder gets now.

        Returns
        -------
        sim_bridge.control.Observation
            Reported tool poses and jaws, the believed arm bases, and the perceived needle
            (None when not seen), holders and target pair.

        """
        if self._observer is None:
            raise RuntimeError('TeleoperatedRobot.record() before start()')
        return self._observer.observe()

    @property
    def images_seen(self) -> int:
        """Stereo pairs looked at by the recorder's perception, over every attempt so far."""
        current = self._perception.renders if self._perception is not None else 0
        return self.renders + current
