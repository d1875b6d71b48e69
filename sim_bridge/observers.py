"""
Observers: what a controller of the simulated scene is allowed to see.

A controller (the scripted expert, the demonstrator, the DMP executor) reads an
:class:`~sim_bridge.control.Observation` made by an observer, never the scene itself:

- :class:`GroundTruthObserver`: the scene's truth (true tool poses, the needle, which arm holds
  it, the target pair, the true arm bases) -- the simulation's results as they always were;
- :class:`PhysicalObserver`: what a physical dVRK provides -- the arms' own reports
  (``measured_js/cp`` through their believed bases, jaws) and, for the needle, the markers and
  the grasp, an estimator working on the ECM's stereo images (perception), asked only when the
  controller needs it.

Frames: ``world``; poses 4x4 ``T_world_*``; SI units.
"""

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.control import Observation

if TYPE_CHECKING:
    from sim_bridge.arm import Arm
    from sim_bridge.scene.grasp import GraspManager
    from sim_bridge.task import SuturingTask


class ObservedScene(Protocol):
    """
    What an observer reads of the scene: :class:`sim_bridge.simulation.Simulation` has it.

    Declared here rather than imported, since the simulation imports its observers. Frames:
    ``world``; poses 4x4; time in s.
    """

    @property
    def time(self) -> float:
        """Simulation time (s)."""

    @property
    def arms(self) -> 'dict[str, Arm]':
        """The arms by name."""

    @property
    def grasp(self) -> 'GraspManager':
        """Who holds the needle."""

    @property
    def task(self) -> 'SuturingTask':
        """The target pair and the scoring."""

    @property
    def _T_needle(self) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """The needle's true pose."""

    @property
    def _T_world_base_true(self) -> dict[str, np.ndarray]:  # noqa: N802
        """The arms' true bases."""

    def _tool_pose(self, name: str) -> np.ndarray:
        """Return the true tool-tip pose (read-only)."""

    def reported_tool_pose(self, name: str) -> np.ndarray:
        """Return the tool-tip pose the arm reports, through its believed base."""

    def believed_base(self, arm: str) -> np.ndarray:
        """Return the arm's base as the robot believes it (its registration)."""

    def reported_jp(self, name: str) -> np.ndarray:
        """Return the joints the arm's encoders report (``measured_js``)."""

    def reported_jaw(self, name: str) -> tuple[float, float]:
        """Return a PSM's jaw angle and velocity as ``jaw/measured_js`` reports them."""


class GroundTruthObserver:
    """
    The scene's ground truth, as a controller with perfect knowledge would see it.

    Parameters
    ----------
    sim : ObservedScene
        The scene (a :class:`sim_bridge.simulation.Simulation`).

    """

    def __init__(self, sim: ObservedScene) -> None:
        self._sim = sim

    def observe(self) -> Observation:
        """
        Return the observation now.

        Returns
        -------
        sim_bridge.control.Observation
            True tool poses (read-only arrays shared with the simulation, kept until an arm
            moves) and jaws of both PSMs, the true needle pose, its holders, the target pair
            and the true arm bases.

        """
        sim = self._sim
        return Observation(t=sim.time,
                           T_world_tool={n: sim._tool_pose(n) for n in PSMS},
                           jaw={n: sim.arms[n].jaw_measured_jp for n in PSMS},
                           T_world_needle=sim._T_needle.copy(),
                           holders=sim.grasp.holders, pair=sim.task.pair,
                           T_world_base=dict(sim._T_world_base_true))


class SceneEstimator(Protocol):
    """
    What a physical observer asks about the scene: estimates from the robot's own sensors.

    Methods
    -------
    estimate(sim, arm_state)
        Return ``(T_world_needle, holders, pair)``: the needle's estimated pose (ndarray (4, 4),
        or None when it cannot be seen well enough), the arms believed to hold it, and the
        target pair as perceived (a :class:`~sim_bridge.scene.phantom.MarkerPair`-like object).
        ``arm_state`` is the observation's arm part (reported tool poses, jaws, joints).

    """

    def estimate(self, sim: ObservedScene, arm_state: Observation
                 ) -> tuple[np.ndarray | None, Iterable[str], Any]:
        """Estimate the needle, its holders and the target pair."""


class PhysicalObserver:
    """
    What a physical dVRK provides: the arms' own reports and estimates from the endoscope.

    Parameters
    ----------
    sim : ObservedScene
        The scene (a :class:`sim_bridge.simulation.Simulation`).
    estimator : SceneEstimator
        Needle, holders and target pair from the stereo images (rendered by the estimator
        through ``sim.render()`` only when it needs them).
    correction : object, optional
        The arms' kinematic correction (``observe(obs) -> Observation``, e.g.
        :class:`suture_lfd.skill.arm_registration.KinematicCorrection`): the tool poses the
        estimator and the controller see are where it puts the reported joints.

    """

    def __init__(self, sim: ObservedScene, estimator: SceneEstimator,
                 correction: Any = None) -> None:
        self._sim = sim
        self._estimator = estimator
        self._correction = correction
        # the believed bases (a robot's registration does not change while it runs): read
        # once, shared read-only by every observation
        self._bases: dict[str, np.ndarray] | None = None

    def arm_state(self) -> Observation:
        """
        Return the arms' reports: an :class:`Observation` without needle, holders or pair.

        Returns
        -------
        sim_bridge.control.Observation
            ``T_world_tool``: each PSM's ``measured_cp`` through its believed base (moved by
            the correction, when there is one);
            ``T_world_base``: the believed bases (read-only arrays); ``q``: the measured
            joints (as the encoders report them).

        """
        sim = self._sim
        if self._bases is None:
            self._bases = {n: sim.believed_base(n) for n in sim.arms}
            for T in self._bases.values():
                T.flags.writeable = False
        obs = Observation(t=sim.time,
                          T_world_tool={n: sim.reported_tool_pose(n) for n in PSMS},
                          jaw={n: sim.reported_jaw(n)[0] for n in PSMS},
                          T_world_needle=None, holders=(), pair=None,
                          T_world_base=dict(self._bases),
                          q={n: sim.reported_jp(n) for n in PSMS})
        return obs if self._correction is None else self._correction.observe(obs)

    def observe(self) -> Observation:
        """
        Return the observation now: arm reports plus the estimator's needle, holders and pair.

        Returns
        -------
        sim_bridge.control.Observation
            ``T_world_needle`` is None when the estimator cannot see the needle.

        """
        arms = self.arm_state()
        needle, holders, pair = self._estimator.estimate(self._sim, arms)
        return Observation(t=arms.t, T_world_tool=arms.T_world_tool, jaw=arms.jaw,
                           T_world_needle=needle, holders=tuple(holders), pair=pair,
                           T_world_base=arms.T_world_base, q=arms.q)
