"""
The simulated dVRK suturing scene: physics, task and loop, behind one face.

The scene is split as dm_control splits an environment:

- the physics (:class:`sim_bridge.physics.ScenePhysics`): world, arms, needle, grasps, tissue
  and thread, stepped at a fixed rate (the order of one step is in :mod:`sim_bridge.physics`);
- the task (:class:`sim_bridge.task.SuturingTask`): the target pair, the ground truth and the
  throw's scoring;
- the loop (:class:`Simulation`, this module): the control period (:meth:`Simulation.run`), the
  observer that says what a controller sees (:mod:`sim_bridge.observers`) and the scene's
  events, which it hears from the physics, scores with the task and records.

:class:`Simulation` is the face callers use: its attributes and methods are those the scene
always had, each delegating to the part that owns it.

Events (:class:`SimEvent`, stamped with simulation time): ``grasp``, ``release``, ``drop``,
``entry``, ``exit``, ``withdrawn``, ``extracted``, ``trauma``, ``collision``, ``score``.

Frames: ``world`` (z up; phantom at the origin, see ``config/world.yaml``) unless a name says
otherwise; poses are 4x4 ``T_world_*``; SI units. Controllers speak ``world`` only
(:meth:`Simulation.observation` and :meth:`Simulation.apply`). Time is simulation time in
seconds, counted in whole physics steps, and the same seed gives bit-identical runs.

Size: one face over the physics and the task: a typed one-line delegation for each attribute
callers have always used, which splitting would only scatter.
"""

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.arm import Arm
from sim_bridge.common.needle import NeedleGeometry, ThreadGeometry
from sim_bridge.common.vocabulary import ARMS, PSMS
from sim_bridge.control import Command, CommandSource, Observation
from sim_bridge.kinematic_errors import ArmError
from sim_bridge.kinematics import EcmKinematics, PsmKinematics
from sim_bridge.observers import GroundTruthObserver, PhysicalObserver
from sim_bridge.physics import ScenePhysics
from sim_bridge.scene.camera import StereoCamera, StereoFrame
from sim_bridge.scene.grasp import GraspEvent, GraspManager
from sim_bridge.scene.phantom import MarkerPair, Phantom, PhantomConfig
from sim_bridge.scene.scoring import ThrowScore, ThrowScorer
from sim_bridge.scene.thread import ThreadChain
from sim_bridge.scene.tissue import TissueEvent, TissueTracker
from sim_bridge.scene.world import World
from sim_bridge.simulation_config import (
    LoopConfig,
    NeedleStart,
    SimulationConfig,
    load_simulation_config,
    steps_per_period,
)
from sim_bridge.task import SuturingTask

__all__ = ['ARMS', 'EVENT_KINDS', 'PSMS', 'LoopConfig', 'NeedleStart', 'SimEvent', 'Simulation',
           'SimulationConfig', 'load_simulation_config']

EVENT_KINDS = ('grasp', 'release', 'drop', 'entry', 'exit', 'withdrawn', 'extracted', 'trauma',
               'collision', 'score', 'slip')


@dataclass(frozen=True, eq=False)
class SimEvent:
    """
    Something that happened in the scene.

    Attributes
    ----------
    t : float
        Simulation time (s).
    kind : str
        One of :data:`EVENT_KINDS`.
    data : dict
        Details: ``arm`` (grasp, release, collision), ``leader`` (grasp, release),
        ``point`` (ndarray (3,), world m), ``distance_to_marker`` (m), ``marker`` (tissue
        events), ``deviation`` (m, trauma/extracted), ``depth`` (m, collision), ``fall`` (m,
        drop), ``score`` (ThrowScore, score).

    """

    t: float
    kind: str
    data: dict


class Simulation:
    """
    The simulated dVRK suturing scene, stepped at a fixed rate.

    Parameters
    ----------
    config : SimulationConfig, optional
        Configuration; default: :func:`load_simulation_config`.
    rng : numpy.random.Generator, optional
        Randomness of the scene (needle start pose); default ``default_rng(0)``.
    client : pybullet_utils.bullet_client.BulletClient, optional
        PyBullet client to use (reset and owned by the simulation while it runs); default: a
        new DIRECT client, disconnected by :meth:`close`.
    phantom : str or Path or sim_bridge.scene.phantom.PhantomConfig
        ``'synthetic'``, ``'scanned'`` (phantoms of the scene), the path of an STL/OBJ/PLY mesh
        (metres, z up; markers laid on its top surface along its longest flat-enough line), a
        phantom file (``.yaml``: mesh, scale, pose, wound line or markers; see
        :func:`sim_bridge.scene.scene_config.load_phantom_file`) or a phantom configuration.
    gui : bool
        Open a PyBullet GUI window instead of a DIRECT client (ignored with ``client``).
    kinematic_errors : dict of str to sim_bridge.kinematic_errors.ArmError, optional
        The PSMs' hidden kinematic errors; default: drawn at ``kinematic_error_level`` of the
        configuration from ``default_rng(kinematic_error_seed)``.

    Attributes
    ----------
    physics : sim_bridge.physics.ScenePhysics
        World, arms, needle, grasps, tissue and thread; the attributes below up to ``thread``
        are its own.
    arms : dict of str to Arm
        ``'PSM1'``, ``'PSM2'``, ``'ECM'``; :meth:`reset` replaces the Arm objects in this dict.
    world : World
        PyBullet bodies (the arms where they truly are).
    phantom : sim_bridge.scene.phantom.Phantom
    grasp : GraspManager
    tissue : TissueTracker
    camera : StereoCamera
    thread : ThreadChain
    task : sim_bridge.task.SuturingTask
        Target pair, ground truth and scoring.
    observer : object
        What :meth:`observation` asks (``observe() -> Observation``); default:
        :class:`sim_bridge.observers.GroundTruthObserver`.

    """

    def __init__(self, config: SimulationConfig | None = None,
                 rng: np.random.Generator | None = None, client: Any = None,
                 phantom: str | Path | PhantomConfig = 'synthetic', gui: bool = False,
                 kinematic_errors: dict[str, ArmError] | None = None) -> None:
        self.config = config or load_simulation_config()
        self.physics = ScenePhysics(self.config, self, rng=rng, client=client, phantom=phantom,
                                    gui=gui, kinematic_errors=kinematic_errors)
        self._events: list[SimEvent] = []
        self.task = SuturingTask(self.physics.phantom, self.config.scene.scoring, self._emit,
                                 lambda: self.physics.T_needle)
        self.observer: GroundTruthObserver | PhysicalObserver = GroundTruthObserver(self)
        self.reset()

    # ------------------------------------------------------------------ the physics' parts
    @property
    def arms(self) -> dict[str, Arm]:
        """Dict of str to Arm: ``'PSM1'``, ``'PSM2'``, ``'ECM'``."""
        return self.physics.arms

    @property
    def world(self) -> World:
        """World: the PyBullet bodies."""
        return self.physics.world

    @property
    def phantom(self) -> Phantom:
        """sim_bridge.scene.phantom.Phantom: the phantom with its marker pairs."""
        return self.physics.phantom

    @property
    def grasp(self) -> GraspManager:
        """GraspManager: who holds the needle."""
        return self.physics.grasp

    @property
    def tissue(self) -> TissueTracker:
        """TissueTracker: the needle's punctures of the tissue."""
        return self.physics.tissue

    @property
    def camera(self) -> StereoCamera:
        """StereoCamera: the endoscope's stereo camera."""
        return self.physics.camera

    @property
    def thread(self) -> ThreadChain:
        """ThreadChain: the suture thread (replaced by :meth:`reset`)."""
        return self.physics.thread

    @property
    def kinematics(self) -> dict[str, PsmKinematics | EcmKinematics]:
        """Dict of str to the arms' kinematics (PSM and ECM chains)."""
        return self.physics.kinematics

    @property
    def needle_geometry(self) -> NeedleGeometry:
        """sim_bridge.common.needle.NeedleGeometry: the needle's shape."""
        return self.physics.needle_geometry

    @property
    def thread_geometry(self) -> ThreadGeometry:
        """The thread's shape (``thread`` of the scene)."""
        return self.physics.thread_geometry

    @property
    def client(self) -> Any:
        """The PyBullet client (None once closed)."""
        return self.physics.client

    @property
    def rng(self) -> np.random.Generator:
        """numpy.random.Generator: the scene's randomness (the needle start pose)."""
        return self.physics.rng

    def close(self) -> None:
        """Disconnect the PyBullet client if the simulation created it."""
        self.physics.close()

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None) -> None:
        """
        Start the scene again: arms DISABLED at rest, jaws at ``initial_jaw``, needle on the pad.

        Parameters
        ----------
        seed : int, optional
            Reseed the scene's random generator (the needle start pose); without it the
            generator continues.

        """
        self._events = []
        self.physics.reset(seed)
        target = self.config.loop.target_pair
        if target is None:
            target = next(iter(self.phantom.markers))
        self.set_target_pair(target)
        self.physics.update_grasp()

    # ------------------------------------------------------------------ time and the loop
    @property
    def dt(self) -> float:
        """Physics step (s)."""
        return self.physics.dt

    @property
    def time(self) -> float:
        """Simulation time (s): whole physics steps since :meth:`reset`."""
        return self.physics.time

    def step(self, after_arms: Callable[[], object] | None = None) -> None:
        """
        Advance the scene by one physics step (:meth:`sim_bridge.physics.ScenePhysics.step`).

        Parameters
        ----------
        after_arms : callable, optional
            Called with no argument once the arms have moved, before the rest of the scene (grasp,
            needle, tissue, thread, contacts), which never moves an arm: the simulator node
            publishes the arms' state there, so that a command's effect is not held up by the
            scene's work. :attr:`time` is already the step's end.

        """
        self.physics.step(after_arms)

    def run(self, seconds: float, controller: CommandSource | None = None,
            control_period: float | None = None) -> None:
        """
        Step for ``seconds`` of simulated time, optionally under a controller.

        Parameters
        ----------
        seconds : float
            Duration (s); rounded to whole physics steps.
        controller : sim_bridge.control.CommandSource, optional
            Its ``step(observation) -> Command`` is called every ``control_period`` and the
            command applied with :meth:`apply` (e.g.
            :class:`suture_lfd.planning.expert.ScriptedExpert`).
        control_period : float, optional
            Time (s) between controller calls (default: every physics step); a multiple of the
            physics step.

        """
        n = int(round(seconds / self.dt))
        every = 1 if control_period is None else steps_per_period(control_period, self.dt,
                                                               'control_period')
        for k in range(n):
            if controller is not None and k % every == 0:
                self.apply(controller.step(self.observation()))
            self.step()

    def enable_and_home_all(self, timeout: float = 30.0) -> None:
        """
        Enable and home every arm, stepping until all are homed and idle.

        Parameters
        ----------
        timeout : float
            Longest simulated time (s) to wait.

        """
        for arm in self.physics.arm_list:
            arm.state_command('enable')
            if arm.operating_state.state == 'ENABLED':
                arm.state_command('home')
        for _ in range(int(round(timeout / self.dt))):
            states = [arm.operating_state for arm in self.physics.arm_list]
            if all(s.state == 'ENABLED' and s.is_homed and not s.is_busy for s in states):
                return
            for arm, s in zip(self.physics.arm_list, states):
                if s.state == 'ENABLED' and not s.is_homed and not s.is_busy:
                    arm.state_command('home')  # powered up after a power-up time
            self.step()
        raise RuntimeError(f'arms not homed after {timeout} s: ' + ', '.join(
            f'{a.name} {a.operating_state}' for a in self.physics.arm_list))

    # ------------------------------------------------------------------ the physics' events
    def on_grasp_event(self, t: float, ev: GraspEvent) -> None:
        """Score and record a grasp or release of the needle."""
        if ev.kind == 'grasp':
            self.task.scorer.on_grasp(t, ev.arm)
        else:
            self.task.scorer.on_release(t, ev.arm)
        self._emit(ev.kind, arm=ev.arm, leader=ev.leader, distance=ev.distance)
        self._report_score()

    def on_drop(self, t: float, **data: Any) -> None:
        """Score and record a drop of the needle (``fall``, ``in_tissue``)."""
        self.task.scorer.on_drop(t)
        self._emit('drop', **data)
        self._report_score()

    def on_tissue_event(self, t: float, ev: TissueEvent) -> None:
        """Score and record a crossing of the tissue surface by the needle tip."""
        self.task.scorer.on_tissue_event(ev)
        self._emit(ev.kind, point=ev.point, distance_to_marker=ev.distance_to_marker,
                   marker=ev.marker_name, deviation=ev.deviation)
        self._report_score()

    def on_collision(self, t: float, arm: str, depth: float) -> None:
        """Score and record the start of an instrument's contact with the tissue."""
        self.task.scorer.on_collision(t, arm)
        self._emit('collision', arm=arm, depth=depth)
        self._report_score()

    def on_slip(self, t: float, **data: Any) -> None:
        """Record a slip of the needle in the jaw: ``arm``, ``angle`` (rad), ``slide`` (m)."""
        self._emit('slip', **data)

    def _emit(self, kind: str, **data: Any) -> None:
        self._events.append(SimEvent(self.time, kind, data))

    def _report_score(self) -> None:
        self.task.report_score(self.time)

    # ------------------------------------------------------------------ commands
    def apply(self, command: Command) -> None:
        """
        Send a controller's command to the arms (:meth:`sim_bridge.physics.ScenePhysics.apply`).

        Parameters
        ----------
        command : sim_bridge.control.Command
            Targets per arm (``world`` frame).

        """
        self.physics.apply(command)

    def set_target_pair(self, name: str) -> None:
        """
        Aim the next throw at a marker pair: the tissue tracker and the scorer start afresh.

        Parameters
        ----------
        name : str
            Pair name (``'synth1'`` .. ``'synth4'``, ``'scan1'`` ..).

        """
        self.task.start(name, self.time, self.grasp.holders)
        self.physics.aim_tissue(name)

    def attach_needle(self, arm: str, T_tool_needle: ArrayLike | None = None) -> None:
        """
        Put the needle in a PSM's jaw and score the grasp from now on, without a grasp event.

        The arguments are those of :meth:`sim_bridge.physics.ScenePhysics.attach_needle`.
        """
        self.physics.attach_needle(arm, T_tool_needle)
        self.task.scorer.on_grasp(self.time, arm)

    # ------------------------------------------------------------------ observation and state
    @property
    def target_pair(self) -> MarkerPair | None:
        """The target :class:`~sim_bridge.scene.phantom.MarkerPair` (world frame)."""
        return self.task.pair

    @property
    def scorer(self) -> ThrowScorer | None:
        """The current throw's :class:`~sim_bridge.scene.scoring.ThrowScorer` (the task's)."""
        return self.task.scorer

    @property
    def needle_mode(self) -> str:
        """``'held'``, ``'tissue'`` (free, held by the tissue), ``'free'`` or ``'resting'``."""
        return self.physics.needle_mode

    def observation(self) -> Observation:
        """
        Return what a controller sees now: what :attr:`observer` makes of the scene.

        Returns
        -------
        sim_bridge.control.Observation
            With the default ground-truth observer: tool poses and jaws of both PSMs, needle
            pose, holders, target pair, arm bases, all true. The tool poses are read-only
            arrays shared with the simulation (kept until an arm moves): copy one to change it.

        """
        return self.observer.observe()

    def score(self) -> ThrowScore:
        """
        Score of the current throw as it stands now.

        Returns
        -------
        sim_bridge.scene.scoring.ThrowScore

        """
        return self.task.score(self.time)

    def pop_events(self) -> list[SimEvent]:
        """
        Return and clear the scene events since the last call, oldest first.

        Returns
        -------
        list of SimEvent

        """
        events, self._events = self._events, []
        return events

    # ------------------------------------------------------------------ ground truth
    def needle_pose(self) -> np.ndarray:
        """Needle frame in ``world``, shape (4, 4)."""
        return self.task.needle_pose()

    def needle_tip(self) -> np.ndarray:
        """Needle tip position (m, ``world``), shape (3,)."""
        return self.physics.needle_tip()

    def thread_points(self) -> np.ndarray:
        """Thread node positions (m, ``world``), shape (n_segments + 1, 3), node 0 at the tail."""
        return self.physics.thread_points()

    def T_world_base(self, arm: str) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """RCM frame ``<ARM>_base`` of ``arm`` in ``world``, where it truly is, (4, 4)."""
        return self.physics.T_world_base(arm)

    def believed_base(self, arm: str) -> np.ndarray:
        """RCM frame of ``arm`` in ``world`` as the robot believes it (its registration)."""
        return self.physics.believed_base(arm)

    def phantom_pose(self) -> np.ndarray:
        """Phantom frame in ``world``, shape (4, 4)."""
        return self.task.phantom_pose()

    def marker_poses(self) -> dict[str, np.ndarray]:
        """
        Frames of the red markers in ``world`` (:meth:`sim_bridge.task.SuturingTask.marker_poses`).

        Returns
        -------
        dict of str to ndarray, shape (4, 4)

        """
        return self.task.marker_poses()

    def tool_pose(self, arm: str) -> np.ndarray:
        """Tool-tip pose of ``arm`` in ``world``, where it truly is: a (4, 4) copy."""
        return self.physics.tool_pose(arm)

    def reported_tool_pose(self, name: str) -> np.ndarray:
        """Tool-tip pose of an arm in ``world`` as the robot reports it (its kinematics)."""
        return self.physics.reported_tool_pose(name)

    def reported_jp(self, name: str) -> np.ndarray:
        """Joints of an arm as its encoders report them (``measured_js``): a new array."""
        return self.physics.reported_jp(name)

    def reported_jaw(self, name: str) -> tuple[float, float]:
        """Return a PSM's jaw angle and velocity as ``jaw/measured_js`` reports them."""
        return self.physics.reported_jaw(name)

    # what the ground-truth observer (sim_bridge.observers) reads of the scene: the physics' own
    def _tool_pose(self, name: str) -> np.ndarray:
        return self.physics._tool_pose(name)

    @property
    def _T_needle(self) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        return self.physics.T_needle

    @property
    def _T_world_base_true(self) -> dict[str, np.ndarray]:  # noqa: N802 (the project names poses T_a_b)
        return self.physics.T_world_base_true

    @property
    def _errors(self) -> dict[str, ArmError]:
        return self.physics.errors

    # ------------------------------------------------------------------ drawing
    def sync_world(self) -> None:
        """Copy arm joints, jaw angles, needle pose and thread into PyBullet (for drawing)."""
        self.physics.sync_world()

    def camera_pose(self) -> np.ndarray:
        """ECM tool-tip (stereo rig centre) pose in ``world``, shape (4, 4) (a copy)."""
        return self.physics.camera_pose()

    def render(self, window: tuple[int, int, int, int] | None = None) -> StereoFrame:
        """
        Render the stereo endoscope images of the scene as it is now.

        Parameters
        ----------
        window : tuple of int, optional
            ``(u0, v0, width, height)``: only this region of both images.

        Returns
        -------
        sim_bridge.scene.camera.StereoFrame
            Left/right colour and metric depth images and camera poses.

        """
        return self.physics.render(window)

    def delivered_frame(self) -> float | None:
        """Scene time of the newest frame the endoscope has delivered (None: ideal camera)."""
        return self.physics.delivered_frame()

    def render_delivered(self, window: tuple[int, int, int, int] | None = None
                         ) -> tuple[float, StereoFrame]:
        """
        Render the newest frame the endoscope has delivered: ``(scene time, frame)``.

        :meth:`sim_bridge.physics.ScenePhysics.render_delivered`; an ideal camera has no frames.
        """
        return self.physics.render_delivered(window)

    def endoscope_frame(self, window: tuple[int, int, int, int] | None = None
                        ) -> tuple[float, StereoFrame]:
        """
        Return what the endoscope gives a look now: ``(scene time, frame)``.

        The newest delivered frame (:meth:`render_delivered`) of an endoscope with a frame
        timing; for an ideal camera, the scene now (:meth:`render`).
        """
        if self.physics.delivered_frame() is None:
            return self.time, self.physics.render(window)
        return self.physics.render_delivered(window)
