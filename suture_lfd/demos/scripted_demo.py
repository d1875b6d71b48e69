"""
Demonstrations by the scripted expert, recorded in-process from the simulation.

The scripted expert (:class:`suture_lfd.planning.expert.ScriptedExpert`) moves without rests
between its motion segments, so a velocity-based segmenter would merge the pick-up, the carry and
the insertion into one motion. :class:`PausingExpert` holds the plan still for ``pause`` seconds
where a subtask starts (as a person does before inserting, after regrasping), and
:func:`record_scripted_demonstration` records one throw as a
:class:`~suture_lfd.demos.demonstration.Demonstration` (``world`` frame, SI units) together with
the expert's own subtask labels.
"""

from typing import TYPE_CHECKING, Any, cast

import numpy as np
from sim_bridge.common.geometry import pose_from_transform
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ScriptedExpert
from suture_lfd.planning.plan import PlanFollower

if TYPE_CHECKING:
    from sim_bridge.control import Command, ExpertConfig, Observation
    from sim_bridge.scene.scoring import ThrowScore
    from sim_bridge.simulation import Simulation
    from suture_lfd.planning.plan import Plan


class PausingExpert:
    """
    Scripted expert that rests ``pause`` seconds at the start of subtasks ii, iii, iv and v.

    It drives a :class:`suture_lfd.planning.expert.ScriptedExpert` and holds that expert's plan
    clock still during each rest.

    Parameters
    ----------
    *args, **kwargs
        As :class:`suture_lfd.planning.expert.ScriptedExpert`.
    pause : float
        Rest (s) before each of those subtasks.

    Attributes
    ----------
    expert : suture_lfd.planning.expert.ScriptedExpert
        The expert whose plan is followed.

    """

    def __init__(self, *args: Any, pause: float = 0.3, **kwargs: Any) -> None:
        self.expert = ScriptedExpert(*args, **kwargs)
        self.pause = float(pause)
        self._rests: list[float] = []
        self._rest_end: float | None = None

    @property
    def plan_(self) -> 'Plan | None':
        """suture_lfd.planning.plan.Plan or None: The expert's plan (after :meth:`reset`)."""
        return self.expert.plan_

    @property
    def done(self) -> bool:
        """Whether the plan has run to its end."""
        return self.expert.done

    @property
    def plan_time(self) -> float:
        """Plan time (s) of the last command."""
        return self.expert.plan_time

    def reset(self, obs: 'Observation') -> None:
        """Plan the throw and start its clock at ``obs.t``."""
        self.expert.reset(obs)
        plan = cast('Plan', self.plan_)  # planned by the reset just above
        self._rests = [t for t, name in plan.labels if name in ('ii', 'iii', 'iv', 'v')]
        self._rest_end = None

    def step(self, obs: 'Observation') -> 'Command':
        """Command for ``obs``; the plan clock stops for ``pause`` at each subtask start."""
        if self.plan_ is None:
            self.reset(obs)
        clock = cast(PlanFollower, self.expert.follower)  # set by the reset
        tau = clock.tau(obs.t)
        if self._rest_end is None and self._rests and tau >= self._rests[0]:
            self._rest_end = obs.t + self.pause
            clock.offset += tau - self._rests.pop(0)
        if self._rest_end is not None:
            if obs.t < self._rest_end:
                clock.offset = obs.t - cast(float, clock.t0) - clock.plan_time  # set by a step
            else:
                self._rest_end = None
        return self.expert.step(obs)


def record_scripted_demonstration(sim: 'Simulation', pair_name: str, seed: int = 0,
                                  config: 'ExpertConfig | None' = None, pause: float = 0.3,
                                  sample_period: float = 0.01, timeout: float = 60.0
                                  ) -> tuple[Demonstration, np.ndarray, 'ThrowScore']:
    """
    Run the pausing scripted expert for one throw and record it.

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
        The scene.
    pair_name : str
        Target pair.
    seed : int
        Scene seed.
    config : sim_bridge.control.ExpertConfig, optional
        Expert settings (default: the scene's ``expert`` section).
    pause : float
        Rest (s) at the start of subtasks ii .. v.
    sample_period : float
        Control and sampling period (s).
    timeout : float
        Longest simulated time (s).

    Returns
    -------
    demo : Demonstration
        The record (tool, jaw, needle, grasp flags, pair).
    labels : ndarray of str, shape (n,)
        The expert's subtask label at every sample.
    score : sim_bridge.scene.scoring.ThrowScore
        The simulator's score of the throw.

    """
    pair = start_episode(sim, pair_name, seed)
    config = sim.config.scene.expert if config is None else config
    expert = PausingExpert(pair, sim.needle_geometry, config=config,
                           kinematics=sim.kinematics['PSM1'], pause=pause)
    rows = []

    class _Recorder:
        def step(self, obs: 'Observation') -> 'Command':
            cmd = expert.step(obs)
            rows.append((obs.t, obs.T_world_tool['PSM1'], obs.T_world_tool['PSM2'],
                         obs.jaw['PSM1'], obs.jaw['PSM2'], obs.T_world_needle,
                         'PSM1' in obs.holders, 'PSM2' in obs.holders, cmd.subtask))
            return cmd

    run_episode(sim, expert, sample_period, stepper=_Recorder(), timeout=timeout,
                always_settle=True)
    cols = list(zip(*rows))
    demo = Demonstration(
        t=np.array(cols[0]), psm1_pose=pose_from_transform(np.array(cols[1])),
        psm2_pose=pose_from_transform(np.array(cols[2])), psm1_jaw=np.array(cols[3]),
        psm2_jaw=np.array(cols[4]), needle_pose=pose_from_transform(np.array(cols[5])),
        psm1_holds=np.array(cols[6]), psm2_holds=np.array(cols[7]), entry=pair.entry,
        exit=pair.exit, normal=pair.normal, pair=pair.name)
    return demo, np.array(cols[8]), sim.score()
