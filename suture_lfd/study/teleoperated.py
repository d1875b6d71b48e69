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
command). A person does not see the error at once nor take it up whole: the subject acts on
the error ``E = T_seen @ inv(T_reported)`` as seen ``SEE_LATENCY`` ago (a visually guided
correction takes about two tenths of a second, Keele and Posner 1968, plus the endoscope's
frame delay) and takes it up gradually, with time constant ``CORRECTION_TIME`` (a gain of
``dt / CORRECTION_TIME`` per command): ``T_command = inv(C) @ T_target`` with ``C`` that
filtered error. Against a cable's dead band, whose error jumps when a joint reverses, an
instant and whole correction chases the jump on and on; a person's settles. What is recorded
is what a recorder on the robot gets (:class:`sim_bridge.observers.PhysicalObserver` with
:class:`suture_lfd.skill.perceived.PerceivedScene`): the arms' reports, the jaws, and the
needle, its holders and the markers as the endoscope's images give them (images are looked at
only when the estimator needs them).

As in a lab, the robot is registered before anything is recorded
(:func:`suture_lfd.skill.arm_registration.register_arms`, once per simulation, before the first
attempt resets the scene): the recorder judges each grasp against the corrected tool pose, as
the executor does, instead of the raw report, which at the 3 mm class is 5-10 mm off -- more
than a grasp's reach. The registration run resets the scene and moves the arms, so it must come
before the demonstration's episode starts, never between its start and its first sample.

Frames: ``world`` (the robot's believed one for what is recorded); poses 4x4; metres.
"""

from collections import deque
from dataclasses import replace
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from sim_bridge.common.geometry import invert_transform
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
#: How long ago (s) the tool's error the subject acts on was seen, and the time constant (s)
#: with which the subject takes it up (see the module's docstring).
SEE_LATENCY = 0.2
CORRECTION_TIME = 0.3
#: How far (m, rad) a tool may be from the subject's command for the subject to take it as
#: arrived: what a person sees of a tool in the endoscope, not a simulation's half millimetre
#: (a robot's own error, and a cable's dead band, never settle to that).
LAG_TOLERANCE = (0.002, 0.1)


def _blend(C: np.ndarray, E: np.ndarray, gain: float) -> np.ndarray:
    """Return ``C`` moved a share ``gain`` of the way to ``E`` (4x4 rigid transforms)."""
    out = np.array(C, dtype=float)
    out[:3, 3] += gain * (E[:3, 3] - C[:3, 3])
    R = C[:3, :3].T @ E[:3, :3]
    angle = math.acos(max(-1.0, min(1.0, 0.5 * (float(np.trace(R)) - 1.0))))
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    norm = float(np.linalg.norm(axis))
    if angle > 1e-9 and norm > 1e-12:
        axis /= norm
        a = gain * angle
        K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                      [-axis[1], axis[0], 0.0]])
        out[:3, :3] = C[:3, :3] @ (np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * K @ K)
    return out


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
        self.lag_tolerance = LAG_TOLERANCE
        # the subject's view of each tool's error: seen errors (t, E) and the one acted on
        self._seen: dict[str, deque[tuple[float, np.ndarray]]] = {}
        self._acted: dict[str, tuple[float, np.ndarray]] = {}
        # before any episode: the registration run resets the scene and moves the arms
        self.correction: KinematicCorrection | None = register_arms(sim) if register else None

    def start(self) -> None:
        """Begin an attempt: the recorder's perception forgets the needle and its grasps."""
        if self._perception is not None:
            self.renders += self._perception.renders
        self._seen, self._acted = {}, {}
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
        out: dict[str, Any] = {}
        for arm, T in targets.items():
            if T is None or arm not in PSMS:
                out[arm] = T
                continue
            out[arm] = invert_transform(self._error(arm, float(cmd.t))) @ np.asarray(
                T, dtype=float)
        return replace(cmd, T_world_tool=out)

    def _error(self, arm: str, t: float) -> np.ndarray:
        """Return the tool's error as the subject acts on it at ``t`` (seen late, taken slowly)."""
        sim = self._sim
        seen = self._seen.setdefault(arm, deque())
        seen.append((t, sim.tool_pose(arm) @ invert_transform(sim.reported_tool_pose(arm))))
        while len(seen) > 1 and seen[1][0] <= t - SEE_LATENCY:
            seen.popleft()
        E = seen[0][1]
        last = self._acted.get(arm)
        if last is None:
            C = E  # at the start the subject lines the tool up with what it sees
        else:
            C = _blend(last[1], E, min(1.0, max(0.0, t - last[0]) / CORRECTION_TIME))
        self._acted[arm] = (t, C)
        return C

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
