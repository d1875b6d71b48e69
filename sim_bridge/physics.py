"""
The physics of the simulated dVRK suturing scene: world, arms, needle, grasps, tissue and thread.

One :meth:`ScenePhysics.step` is one fixed physics step (``world.physics_step``, 2 ms by default):

1. every arm's state machine advances (:class:`sim_bridge.arm.Arm`: trajectories, joint
   tracking within the dVRK velocity and acceleration limits);
2. the jaws are read and the needle is grasped or released (:mod:`sim_bridge.scene.grasp`);
3. the needle moves: held, it follows the leading tool exactly; free inside the tissue, it stays
   where it is (the tissue holds it); free outside, PyBullet moves it under gravity until it
   rests on the pad or the table (a fall of ``drop_distance`` is a drop, and so is letting go
   of a needle in the tissue);
4. the tissue tracker looks for surface crossings of the tip (:mod:`sim_bridge.scene.tissue`);
5. every ``thread_period`` the thread follows the needle tail (the step is queued and runs when
   the thread is next read: :meth:`sim_bridge.scene.thread.ThreadChain.follow`); every
   ``collision_period`` the instrument ends are tested against the tissue.

What happens (grasps and releases, drops, tissue crossings, collisions) goes to a
:class:`PhysicsListener` as it happens; the physics knows nothing of the task or its scoring
(:class:`sim_bridge.simulation.Simulation` listens, scores with :mod:`sim_bridge.task` and
records the events).

PyBullet holds the arms, needle and thread only for drawing and for the free needle's dynamics;
their poses are copied into it when an image is rendered (:meth:`ScenePhysics.render`) or when
:meth:`ScenePhysics.sync_world` is called, so a step costs no PyBullet calls unless the needle
is falling.

Frames: ``world`` (z up; phantom at the origin, see ``config/world.yaml``) unless a name says
otherwise; poses are 4x4 ``T_world_*``; SI units. The arms' own Cartesian poses
(:attr:`sim_bridge.arm.Arm.measured_cp`) follow ``world.frames``: ``cart`` (a patient cart) puts
each PSM's in the ECM camera frame ``ECM``, set again whenever the ECM moves, and the ECM's in
``world``; ``base`` leaves every arm in its RCM frame ``<ARM>_base``. Time is counted in whole
physics steps, and the same seed gives bit-identical runs.

Size: one physics step touches every part of the scene in a fixed order; the order is readable in
one file and the step is the simulator's hot path.
"""

from collections.abc import Callable, Mapping
from dataclasses import replace
import logging
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge import bullet
from sim_bridge.arm import Arm
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.vocabulary import ARMS, PSMS
from sim_bridge.control import Command
from sim_bridge.kinematic_errors import ArmError, draw_arm_errors
from sim_bridge.kinematics import EcmKinematics, PsmKinematics, ecm_kinematics, psm_kinematics
from sim_bridge.realism.calibration import (
    build_encoders,
    build_jaw_stall,
    draw_arm_realism,
    draw_ecm_error,
    draw_intrinsics_error,
    servo_config,
)
from sim_bridge.realism.frame_timing import Exposures
from sim_bridge.realism.tissue_realism import build_tissue_realism
from sim_bridge.scene.camera import StereoCamera, StereoFrame
from sim_bridge.scene.grasp import GraspEvent, GraspManager
from sim_bridge.scene.phantom import Phantom, PhantomConfig, build_phantom
from sim_bridge.scene.scene_config import phantom_from_argument
from sim_bridge.scene.thread import ThreadChain
from sim_bridge.scene.tissue import TissueEvent, TissueTracker
from sim_bridge.scene.world import World
from sim_bridge.simulation_config import SimulationConfig, steps_per_period

_LOG = logging.getLogger(__name__)

# Height (m) above the tissue's top within which the tissue tracker follows the needle.
_TRACK_MARGIN = 0.01
# A dropped needle that slides further than this (m) or tips its plane's normal below this
# cosine from world up is laid on the surface instead (see ScenePhysics._settled_needle_start).
_START_SLIDE = 0.003
_START_UPRIGHT = 0.9
# A resting needle's centre line may sit this much (m) closer to the tissue than its wire radius
# before it is raised onto the surface (physics settles it within a few micrometres of it).
_REST_TOLERANCE = 1e-4


class PhysicsListener(Protocol):
    """What the physics tells as it happens, at simulation time ``t`` (s)."""

    def on_grasp_event(self, t: float, ev: GraspEvent) -> None:
        """Take a grasp or release of the needle by a PSM (a grasp manager's event)."""

    def on_drop(self, t: float, **data: Any) -> None:
        """Take a drop of the needle: ``fall`` (m), and ``in_tissue`` when the tissue holds it."""

    def on_tissue_event(self, t: float, ev: TissueEvent) -> None:
        """Take a crossing of the tissue surface by the tip (a tissue tracker's event)."""

    def on_collision(self, t: float, arm: str, depth: float) -> None:
        """Take the start of an instrument's contact, ``depth`` (m) below the tissue surface."""

    def on_slip(self, t: float, **data: Any) -> None:
        """Take a slip of the needle in the jaw (:mod:`sim_bridge.realism.tissue_realism`)."""


class ScenePhysics:
    """
    The physical scene, stepped at a fixed rate: arms, needle, grasps, tissue and thread.

    Parameters
    ----------
    config : sim_bridge.simulation_config.SimulationConfig
        Configuration.
    listener : PhysicsListener
        Told of grasps, drops, tissue crossings and collisions as they happen.
    rng : numpy.random.Generator, optional
        Randomness of the scene (needle start pose); default ``default_rng(0)``.
    client : pybullet_utils.bullet_client.BulletClient, optional
        PyBullet client to use; default: a new DIRECT client, disconnected by :meth:`close`.
    phantom : str or Path or sim_bridge.scene.phantom.PhantomConfig
        The phantom (see :class:`sim_bridge.simulation.Simulation`).
    gui : bool
        Open a PyBullet GUI window instead of a DIRECT client (ignored with ``client``).
    kinematic_errors : dict of str to sim_bridge.kinematic_errors.ArmError, optional
        The PSMs' hidden kinematic errors; default: drawn from the configuration.

    Attributes
    ----------
    arms : dict of str to Arm
        ``'PSM1'``, ``'PSM2'``, ``'ECM'``; :meth:`reset` replaces the Arm objects in this dict.
    world : World
        PyBullet bodies (the arms where they truly are).
    phantom : sim_bridge.scene.phantom.Phantom
    grasp : GraspManager
    tissue : TissueTracker
    camera : StereoCamera
    thread : ThreadChain

    """

    def __init__(self, config: SimulationConfig, listener: PhysicsListener,
                 rng: np.random.Generator | None = None, client: Any = None,
                 phantom: str | Path | PhantomConfig = 'synthetic', gui: bool = False,
                 kinematic_errors: Mapping[str, ArmError] | None = None) -> None:
        self.config = config
        self.listener = listener
        cfg = config
        self._own_client = client is None
        if client is None:
            client = bullet.connect(gui=gui)
        self.client = client
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.needle_geometry = cfg.scene.needle
        self.thread_geometry = cfg.scene.thread
        self.phantom = self._build_phantom(phantom)
        psm = psm_kinematics(cfg.psm_tool) if cfg.psm_tool else psm_kinematics()
        self.kinematics: dict[str, PsmKinematics | EcmKinematics] = {
            'PSM1': psm, 'PSM2': psm, 'ECM': ecm_kinematics()}
        self.world = World(cfg.world, self.kinematics, self.phantom, self.needle_geometry,
                           self.thread_geometry, client)
        self.camera = StereoCamera(cfg.camera, client, lens=cfg.endoscope.lens)
        self.camera.make_shiny(self.world.needle_body)
        self.exposures = Exposures(cfg.endoscope.timing)
        self._dt = cfg.world.physics_step
        self._thread_every = steps_per_period(cfg.loop.thread_period, self._dt, 'thread_period')
        self._collision_every = steps_per_period(cfg.loop.collision_period, self._dt,
                                             'collision_period')
        self._rest_steps = max(1, int(round(cfg.loop.rest_time / self._dt)))
        # The joint encoders (None: the arms report their motor-side joints as they are).
        seed = int(cfg.kinematic_error_seed)
        self._encoders = ({} if cfg.arm_realism is None
                          else build_encoders(cfg.arm_realism, seed, ARMS))
        # What a jaw closed on the needle reads (None: every jaw reads its own angle).
        self._jaw_stall = None if cfg.arm_realism is None else build_jaw_stall(cfg.arm_realism)
        if cfg.arm_realism is not None:
            intrinsics = draw_intrinsics_error(cfg.arm_realism, seed)
            if intrinsics is not None:
                self.camera.report_calibration(*intrinsics)
        if kinematic_errors is None and cfg.arm_realism is not None:
            kinematic_errors = draw_arm_realism(
                cfg.arm_realism, np.random.default_rng(cfg.kinematic_error_seed), PSMS)
            ecm = draw_ecm_error(cfg.arm_realism, int(cfg.kinematic_error_seed))
            if ecm is not None:
                kinematic_errors = {**kinematic_errors, 'ECM': ecm}
        if kinematic_errors is None:
            kinematic_errors = draw_arm_errors(cfg.kinematic_error_level,
                                               np.random.default_rng(cfg.kinematic_error_seed),
                                               PSMS)
        # Only arms with a nonzero error take the slower path of a true pose of their own.
        self._errors = {k: e for k, e in kinematic_errors.items() if not e.is_zero}
        self._T_world_base_true = dict(self.world.T_world_base)
        # What the robot believes (its registration): the frames it reports and is commanded in.
        self._T_world_base = {k: (self._errors[k].T_believed_true @ T if k in self._errors
                                  else T) for k, T in self._T_world_base_true.items()}
        self._T_base_world = {k: invert_transform(v) for k, v in self._T_world_base.items()}
        self.grasp = GraspManager(cfg.grasp, self.needle_geometry, PSMS)
        self.tissue = TissueTracker(self.phantom, self.needle_geometry, cfg.scene.tissue)
        # The needle in tissue (forces, grip, pad, thread drag); None at level 0.
        self.realism = build_tissue_realism(cfg.tissue_realism, self.needle_geometry,
                                            self.phantom, self.grasp.jaw_point)
        # Highest point of the tissue (world z): far above it nothing can touch the tissue.
        self._tissue_top = float(self.phantom.mesh_world().vertices[:, 2].max())
        self._needle_reach = self.needle_geometry.radius + self.needle_geometry.wire_diameter
        self._needle_tail = self.needle_geometry.tail
        shape = cfg.world.instrument
        self._instrument_reach = shape.jaw_length + shape.shaft_radius
        self._thread_world = client.saveState()
        self.arms: dict[str, Arm] = {}

    # ------------------------------------------------------------------ construction
    def _build_phantom(self, phantom: str | Path | PhantomConfig) -> Phantom:
        name, config = phantom_from_argument(self.config.scene, phantom)
        return build_phantom(config, name=name)

    def close(self) -> None:
        """Disconnect the PyBullet client if the simulation created it."""
        if self._own_client and self.client is not None:
            self.client.disconnect()
            self.client = None

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None) -> None:
        """
        Start the physics again: arms DISABLED at rest, jaws at ``initial_jaw``, needle on the pad.

        The tissue tracker is aimed at no pair yet (:meth:`aim_tissue`) and the grasps are read
        after it is (:meth:`update_grasp`).

        Parameters
        ----------
        seed : int, optional
            Reseed the scene's random generator (the needle start pose); without it the
            generator continues.

        """
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        cfg = self.config
        self.client.restoreState(self._thread_world)
        arm_config = replace(cfg.arm, initial_jaw=cfg.loop.initial_jaw)
        ecm_config = replace(arm_config, initial_jaw=0.0)
        if cfg.arm_realism is not None:
            arm_config = replace(arm_config, servo=servo_config(cfg.arm_realism))
            ecm_config = replace(ecm_config, servo=servo_config(cfg.arm_realism, 'ECM'))
        self.arms.clear()
        for name in ARMS:
            config = arm_config if name in PSMS else ecm_config
            rest = cfg.psm_rest_jp if name in PSMS else cfg.ecm_rest_jp
            if rest is not None:
                config = replace(config, initial_jp=tuple(rest))
            self.arms[name] = Arm(name, self.kinematics[name], config)
        self._arm_list = [self.arms[n] for n in ARMS]
        self._tool_cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        # per arm with encoders: (step, motor-side pose, the reported pose) of the last reading
        self._reported_cache: dict[str, tuple[int, np.ndarray, np.ndarray]] = {}
        # ECM tool tip (RCM frame) the PSMs' frames were set from
        self._camera_local: np.ndarray | None = None
        if cfg.world.frames == 'cart':
            self.arms['ECM'].set_base_frame(self._T_world_base['ECM'], 'world')
            self._follow_camera()
        self._steps = 0
        self.grasp.reset()
        self.tissue.reset()
        if self.realism is not None:
            self.realism.reset()
        self._contact = dict.fromkeys(PSMS, False)
        self._contact_checked = dict.fromkeys(PSMS)  # joints and jaw of the last check
        self._collisions = 0
        self._needle_mode = 'resting'
        self._still_steps = 0
        self._release_height: float | None = None
        self._dropped = False
        self._T_needle = self._settled_needle_start()
        self._T_needle_prev = self._T_needle.copy()
        self.world.set_needle_collisions(False)
        thread_nodes = self.thread_geometry.rest_points(self.needle_geometry, self._T_needle)
        self.thread = ThreadChain(thread_nodes, self.thread_geometry.radius, cfg.thread)
        self.exposures.clear()
        for _ in range(int(round(cfg.loop.needle_start.settle_time / cfg.loop.thread_period))):
            self.thread.follow(cfg.loop.thread_period, thread_nodes[0], self.world.support_height)

    def update_grasp(self) -> None:
        """Read the jaws and update the grasps without reporting events (scene setup)."""
        self.grasp.update(self._jaws(), self._tool_pose, self._T_needle)

    def _settled_needle_start(self) -> np.ndarray:
        """Drop the needle flat onto the support at the seeded start pose and let it settle."""
        start = self.config.loop.needle_start
        xy = np.asarray(start.position, dtype=float)
        xy = xy + self.rng.uniform(-start.position_jitter, start.position_jitter, 2)
        yaw = start.yaw + self.rng.uniform(-start.yaw_jitter, start.yaw_jitter)
        c, s = np.cos(yaw), np.sin(yaw)
        T = np.eye(4)
        T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        T[:2, 3] = xy
        wire = self.needle_geometry.points_world(T, 24)
        top = float(self.world.support_height(wire[:, :2]).max())
        T[2, 3] = top + 0.5 * self.needle_geometry.wire_diameter + start.drop_height
        world = self.world
        world.set_needle_pose(T)
        world.set_needle_collisions(True)
        for _ in range(int(round(start.settle_time / self._dt))):
            world.step()
        world.set_needle_collisions(False)
        settled = world.needle_pose()
        moved = np.linalg.norm(settled[:2, 3] - T[:2, 3])
        if moved <= _START_SLIDE and settled[2, 2] >= _START_UPRIGHT:
            return self._resting_on_tissue(settled)
        # A curved or sloping pad lets the dropped needle slide off (or tunnel through a
        # coarse collision mesh): lay it on the surface where it was dropped instead.
        return self._resting_on_tissue(self._laid_on_support(T))

    def _resting_on_tissue(self, T: np.ndarray) -> np.ndarray:
        """
        Return the resting pose ``T``, raised so that the wire lies on the tissue, not in it.

        The collision mesh and the support height are coarser than the tissue surface the
        tracker follows; on the scanned pad a needle laid on them could start with its tip
        0.15 mm inside the tissue, and lifting it then counted as an exit and a puncture
        (trauma on every throw that started so).
        """
        gap = 0.5 * self.needle_geometry.wire_diameter
        for _ in range(3):  # the phantom is upright: its z is close to world z
            deepest = self.tissue.wire_depth(T)
            if deepest <= _REST_TOLERANCE - gap:
                break
            T = T.copy()
            T[2, 3] += deepest + gap
        self.world.set_needle_pose(T)
        return T

    def laid_on_support(self, T: np.ndarray) -> np.ndarray:
        """
        Return the flat needle pose ``T`` laid on the support, tilted to its local plane.

        Where a needle put down at ``T``'s position and yaw lies (touching), as the scene's
        layout tells it; the world is not changed.
        """
        return self._laid_on_support(T)

    def _laid_on_support(self, T: np.ndarray) -> np.ndarray:
        """Lay the flat needle pose ``T`` on the support, tilted to its local plane, touching."""
        geometry = self.needle_geometry
        wire = geometry.points_world(T, 24)
        heights = self.world.support_height(wire[:, :2])
        A = np.column_stack([wire[:, :2], np.ones(len(wire))])
        (a, b, _), *_ = np.linalg.lstsq(A, heights, rcond=None)
        normal = np.array([-a, -b, 1.0]) / np.sqrt(a * a + b * b + 1.0)
        axis = np.cross([0.0, 0.0, 1.0], normal)
        sin, cos = np.linalg.norm(axis), normal[2]
        R = np.eye(3)
        if sin > 1e-12:
            k = axis / sin
            K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
            R = np.eye(3) + sin * K + (1.0 - cos) * K @ K
        laid = T.copy()
        laid[:3, :3] = R @ T[:3, :3]
        wire = geometry.points_world(laid, 24)
        gap = wire[:, 2] - self.world.support_height(wire[:, :2])
        laid[2, 3] += 0.5 * geometry.wire_diameter - gap.min()
        return laid

    # ------------------------------------------------------------------ small helpers
    def _jaws(self) -> dict[str, float]:
        return {name: self.arms[name].jaw_measured_jp for name in PSMS}

    def _tool_pose(self, name: str) -> np.ndarray:
        """Return the true tool-tip pose in ``world`` (read-only), new only when the arm moved."""
        local = self.arms[name].local_measured_cp_view  # the same array while the arm is still
        cached = self._tool_cache.get(name)
        if cached is not None and cached[0] is local:
            return cached[1]
        if name in self._errors:
            # the arm's own valid joints plus offsets of a few degrees: scalar, unchecked
            q = self._true_jp(name, self.arms[name])
            T = self._T_world_base_true[name] @ self.kinematics[name].fk_unchecked(q.tolist())
        else:
            T = self._T_world_base[name] @ local
        T.flags.writeable = False
        self._tool_cache[name] = (local, T)
        return T

    def reported_tool_pose(self, name: str) -> np.ndarray:
        """
        Tool-tip pose of an arm in ``world`` as the robot reports it (its own kinematics).

        ``T_world_base_believed @ local_measured_cp``: what ``measured_cp`` says, consistent
        with the arm's commands; the true pose (:meth:`tool_pose`) differs by the hidden
        kinematic error. With encoders, the forward kinematics of what they read
        (:meth:`reported_jp`).

        Parameters
        ----------
        name : str
            Arm name.

        Returns
        -------
        ndarray, shape (4, 4)

        """
        if name in self._encoders:
            # the encoders read once a step: within one, the same reading's pose (a copy)
            local = self.arms[name].local_measured_cp_view
            hit = self._reported_cache.get(name)
            if hit is None or hit[0] != self._steps or hit[1] is not local:
                hit = (self._steps, local, self._T_world_base[name] @ self.kinematics[
                    name].fk_unchecked(self.reported_jp(name).tolist()))
                self._reported_cache[name] = hit
            return hit[2].copy()
        if name not in self._errors:
            return self._tool_pose(name).copy()
        return self._T_world_base[name] @ self.arms[name].local_measured_cp_view

    def reported_jaw(self, name: str) -> tuple[float, float]:
        """
        Return a PSM's jaw as ``jaw/measured_js`` reports it: angle (rad), velocity (rad/s).

        A jaw that holds the needle reads where its motors stalled on the wire
        (:mod:`sim_bridge.realism.jaw`), not its command; any other jaw, and every jaw at
        ``jaw_level`` 0, reads its own angle.
        """
        arm = self.arms[name]
        angle, velocity = arm.jaw_measured_jp, arm.jaw_measured_jv
        stall = self._jaw_stall
        if stall is None or name not in self.grasp.holders:
            return angle, velocity
        return stall.read(angle), stall.read_velocity(angle, velocity)

    @property
    def has_jaw_stall(self) -> bool:
        """Whether a jaw closed on the needle reads short of its command (``jaw_level`` > 0)."""
        return self._jaw_stall is not None

    @property
    def has_encoders(self) -> bool:
        """Whether the arms read their joints through encoders (``encoder_level`` above 0)."""
        return bool(self._encoders)

    def reported_jp(self, name: str) -> np.ndarray:
        """
        Joints of an arm as its encoders report them (``measured_js``).

        The motor-side joints on the encoders' counts plus their noise, sampled once a physics
        step; without encoders (level 0) the motor-side joints themselves.

        Parameters
        ----------
        name : str
            Arm name.

        Returns
        -------
        ndarray, shape (n,)
            A new array (rad / m).

        """
        q = self.arms[name].measured_jp
        encoder = self._encoders.get(name)
        return np.array(q, dtype=float) if encoder is None else encoder.read(q, self._steps)

    def _true_jp(self, name: str, arm: Arm) -> np.ndarray:
        """Joints where an arm truly is: its measured joints plus its hidden offsets."""
        error = self._errors.get(name)
        q = arm.measured_jp
        return q if error is None else error.true_jp(q)

    def _follow_camera(self) -> None:
        """
        Patient-cart frames: put each PSM's reference frame on the ECM's camera frame ``ECM``.

        Computed again only when the ECM has moved (its tool-tip array is replaced then).
        """
        local = self.arms['ECM'].local_measured_cp_view
        if local is self._camera_local:
            return
        self._camera_local = local
        # the camera as the ECM reports it (its believed base, its kinematics): a PSM's pose in
        # the camera frame is off by the ECM's error as on a robot
        T = (self._T_world_base['ECM'] @ local if 'ECM' in self._errors
             else self._tool_pose('ECM'))
        T_camera_world = np.eye(4)
        R_t = T[:3, :3].T
        T_camera_world[:3, :3] = R_t
        T_camera_world[:3, 3] = -(R_t @ T[:3, 3])
        for name in PSMS:
            self.arms[name].set_base_frame(T_camera_world @ self._T_world_base[name], 'ECM',
                                           checked=True)

    # ------------------------------------------------------------------ time
    @property
    def dt(self) -> float:
        """Physics step (s)."""
        return self._dt

    @property
    def time(self) -> float:
        """Simulation time (s): whole physics steps since :meth:`reset`."""
        return self._steps * self._dt

    def step(self, after_arms: Callable[[], object] | None = None) -> None:
        """
        Advance the scene by one physics step (see the module docstring for the order).

        Parameters
        ----------
        after_arms : callable, optional
            Called with no argument once the arms have moved, before the rest of the scene (grasp,
            needle, tissue, thread, contacts), which never moves an arm: the simulator node
            publishes the arms' state there, so that a command's effect is not held up by the
            scene's work. :attr:`time` is already the step's end.

        """
        dt = self._dt
        if self._steps == 0 and self.exposures.active:
            self._expose(0.0)  # the endoscope's first frame: the scene as it was set up
        self._steps += 1
        t = self._steps * dt
        for arm in self._arm_list:
            arm.step(dt)
        if self._camera_local is not None:
            self._follow_camera()
        if after_arms is not None:
            after_arms()
        ev: GraspEvent | TissueEvent
        for ev in self.grasp.update(self._jaws(), self._tool_pose, self._T_needle):
            self._on_grasp_event(t, ev)
        self._move_needle()
        if self.realism is not None:
            self._T_needle = self.realism.step(t, dt, self.grasp, self.tissue, self._tool_pose,
                                               self._T_needle, self._T_needle_prev,
                                               self._needle_near_tissue(), self.listener)
        if self._needle_near_tissue():
            for ev in self.tissue.update(t, self._T_needle):
                self.listener.on_tissue_event(t, ev)
        if self._steps % self._thread_every == 0:
            tail = self._T_needle[:3, :3] @ self._needle_tail + self._T_needle[:3, 3]
            self.thread.follow(self._thread_every * dt, tail, self.world.support_height)
        if self._steps % self._collision_every == 0:
            self._check_contacts(t)
        if self.exposures.active and self.exposures.due(t, dt):
            self._expose(t)

    # ------------------------------------------------------------------ grasp and needle
    def _on_grasp_event(self, t: float, ev: GraspEvent) -> None:
        if ev.kind == 'grasp':
            self._needle_mode = 'held'
            self._release_height = None
            self._dropped = False
            self.world.set_needle_collisions(False)
        self.listener.on_grasp_event(t, ev)

    def _move_needle(self) -> None:
        leader = self.grasp.leader
        self._T_needle_prev = self._T_needle
        if leader is not None:
            self._T_needle = self.grasp.needle_pose(self._tool_pose(leader))
            return
        if self._needle_mode == 'held':
            # just released by every arm
            if self.tissue.in_tissue:
                # the tissue holds it where it is, but no instrument does: a dropped needle
                self._needle_mode = 'tissue'
                self.listener.on_drop(self.time, fall=0.0, in_tissue=True)
            else:
                self._start_falling()
        if self._needle_mode != 'free':
            return
        world = self.world
        world.step()
        self._T_needle = world.needle_pose()
        fall = self._release_height - self._T_needle[2, 3]
        if not self._dropped and fall > self.config.loop.drop_distance:
            self._dropped = True
            self.listener.on_drop(self.time, fall=float(fall))
        linear, angular = world.needle_speed()
        slow = linear < self.config.loop.rest_speed and angular * self.needle_geometry.radius \
            < self.config.loop.rest_speed
        self._still_steps = self._still_steps + 1 if slow else 0
        if self._still_steps >= self._rest_steps:
            self._needle_mode = 'resting'
            world.set_needle_collisions(False)

    def _start_falling(self) -> None:
        """Hand the released needle to PyBullet with the velocity it had in the jaw."""
        dt = self._dt
        T0, T1 = self._T_needle_prev, self._T_needle
        v = (T1[:3, 3] - T0[:3, 3]) / dt
        dR = T1[:3, :3] @ T0[:3, :3].T
        angle_axis = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
        w = 0.5 * angle_axis / dt
        self.world.set_needle_pose(T1, v, w)
        self.world.set_needle_collisions(True)
        self._needle_mode = 'free'
        self._still_steps = 0
        self._release_height = float(T1[2, 3])

    def _needle_near_tissue(self) -> bool:
        """
        Whether the tissue tracker must look: the needle is in or within ~1 cm of the tissue.

        A needle entirely higher than ``margin`` above the tissue's highest point cannot cross
        the surface within a step, so the tracker (which only reacts to crossings and to
        punctures it holds) has nothing to see.
        """
        lowest = self._T_needle[2, 3] - self._needle_reach
        return self.tissue.in_tissue or lowest < self._tissue_top + _TRACK_MARGIN

    def _check_contacts(self, t: float) -> None:
        depth_limit = self.config.loop.collision_depth
        for name in PSMS:
            arm = self.arms[name]
            if self._tool_pose(name)[2, 3] - self._instrument_reach > self._tissue_top:
                self._contact[name] = False
                self._contact_checked[name] = None
                continue
            q, jaw = self._true_jp(name, arm), arm.jaw_measured_jp
            checked = (q.tobytes(), jaw)
            if checked == self._contact_checked[name]:
                continue  # the instrument has not moved since the last check: same contact
            self._contact_checked[name] = checked
            points = self.world.instrument_points(name, q, jaw)
            depth = float(self.phantom.penetration(points).max())
            touching = depth > depth_limit
            if touching and not self._contact[name]:
                self._collisions += 1
                self.listener.on_collision(t, name, depth)
            self._contact[name] = touching

    # ------------------------------------------------------------------ commands
    def apply(self, command: Command) -> None:
        """
        Send a controller's command to the arms.

        Tool targets ``T_world_tool`` become each PSM's ``servo_cp`` (expressed in the arm's
        RCM frame ``<ARM>_base``), jaw targets its ``jaw_servo_jp``; None entries are skipped.
        Invalid targets (NaN, inf, unreachable) are rejected by the arm as ``error`` events.

        Parameters
        ----------
        command : sim_bridge.control.Command
            Targets per arm (``world`` frame).

        """
        for name, T in (command.T_world_tool or {}).items():
            if T is None:
                continue
            arm = self.arms[name]
            T = np.asarray(T, dtype=float)
            if T.shape == (4, 4) and np.isfinite(T).all():
                T = self._T_base_world[name] @ T
            arm.servo_cp(T, local=True)  # the arm rejects malformed goals with an error event
        for name, jaw in (command.jaw or {}).items():
            if jaw is not None:
                self.arms[name].jaw_servo_jp(jaw)

    def aim_tissue(self, name: str) -> None:
        """
        Let the tissue tracker follow the marker pair ``name`` afresh.

        Parameters
        ----------
        name : str
            Pair name (``'synth1'``).

        """
        self.tissue.reset()
        self.tissue.set_target_pair(name)
        self.tissue.update(self.time, self._T_needle)

    def attach_needle(self, arm: str, T_tool_needle: ArrayLike | None = None) -> None:
        """
        Put the needle in a PSM's jaw (scene setup): closes the jaw, no grasp event.

        Parameters
        ----------
        arm : str
            ``'PSM1'`` or ``'PSM2'``.
        T_tool_needle : array_like, shape (4, 4), optional
            Grasp; default: the needle's canonical grasp.

        """
        if arm not in PSMS:
            raise ValueError(f'attach_needle needs a PSM, got {arm!r}')
        G = self.needle_geometry.T_tool_needle if T_tool_needle is None else T_tool_needle
        self.grasp.attach(arm, G)
        self._needle_mode = 'held'
        self._T_needle = self.grasp.needle_pose(self._tool_pose(arm))
        self._T_needle_prev = self._T_needle.copy()
        self.tissue.update(self.time, self._T_needle)

    # ------------------------------------------------------------------ state
    @property
    def needle_mode(self) -> str:
        """``'held'``, ``'tissue'`` (free, held by the tissue), ``'free'`` or ``'resting'``."""
        return self._needle_mode

    @property
    def arm_list(self) -> list[Arm]:
        """The arms in the order of :data:`sim_bridge.common.vocabulary.ARMS` (stepped so)."""
        return self._arm_list

    @property
    def T_needle(self) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """The needle's true pose in ``world``, (4, 4): the physics' own array (read only)."""
        return self._T_needle

    @property
    def T_world_base_true(self) -> dict[str, np.ndarray]:  # noqa: N802 (the project names poses T_a_b)
        """Each arm's true RCM frame in ``world`` (dict of str to (4, 4)): the physics' own."""
        return self._T_world_base_true

    @property
    def errors(self) -> dict[str, ArmError]:
        """The arms' nonzero hidden kinematic errors (dict of str to ``ArmError``)."""
        return self._errors

    def needle_tip(self) -> np.ndarray:
        """Needle tip position (m, ``world``), shape (3,)."""
        return self._T_needle[:3, :3] @ self.needle_geometry.tip + self._T_needle[:3, 3]

    def thread_points(self) -> np.ndarray:
        """Thread node positions (m, ``world``), shape (n_segments + 1, 3), node 0 at the tail."""
        return self.thread.nodes

    def T_world_base(self, arm: str) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """
        RCM frame ``<ARM>_base`` of an arm in ``world``, where it truly is.

        Parameters
        ----------
        arm : str
            ``'PSM1'``, ``'PSM2'`` or ``'ECM'``.

        Returns
        -------
        ndarray, shape (4, 4)

        """
        return self._T_world_base_true[arm].copy()

    def believed_base(self, arm: str) -> np.ndarray:
        """
        RCM frame of ``arm`` in ``world`` as the robot believes it (after its registration).

        The arms report their poses (``measured_cp``) and take Cartesian commands in this frame;
        it differs from :meth:`T_world_base` (same argument, same shape) by the arm's hidden
        registration error.
        """
        return self._T_world_base[arm].copy()

    def tool_pose(self, arm: str) -> np.ndarray:
        """
        Tool-tip pose of an arm in ``world``, where it truly is.

        Parameters
        ----------
        arm : str
            Arm name.

        Returns
        -------
        ndarray, shape (4, 4)
            A copy (the observation's poses are shared, read-only arrays).

        """
        return self._tool_pose(arm).copy()

    # ------------------------------------------------------------------ drawing
    def sync_world(self) -> None:
        """Copy arm joints, jaw angles, needle pose and thread into PyBullet (for drawing)."""
        world = self.world
        for name, arm in self.arms.items():
            world.set_arm_joints(name, self._true_jp(name, arm),
                                 arm.jaw_measured_jp if name in PSMS else None)
        if self._needle_mode != 'free':
            world.set_needle_pose(self._T_needle)
        world.set_thread_points(self.thread.nodes)
        if self.realism is not None:
            self.realism.draw(world)

    def camera_pose(self) -> np.ndarray:
        """ECM tool-tip (stereo rig centre) pose in ``world``, shape (4, 4) (a copy)."""
        return self._tool_pose('ECM').copy()

    def render(self, window: tuple[int, int, int, int] | None = None) -> StereoFrame:
        """
        Render the stereo endoscope images of the scene as it is now.

        Parameters
        ----------
        window : tuple of int, optional
            ``(u0, v0, width, height)``: only this region of both images
            (:meth:`sim_bridge.scene.camera.StereoCamera.render`).

        Returns
        -------
        sim_bridge.scene.camera.StereoFrame
            Left/right colour and metric depth images and camera poses.

        """
        self.sync_world()
        return self.camera.render(self.camera_pose(), window=window)

    def _expose(self, t: float) -> None:
        """Keep what the endoscope's frame at ``t`` shows: the drawn state of the scene."""
        arms = {name: (np.array(self._true_jp(name, arm), dtype=float),
                       arm.jaw_measured_jp if name in PSMS else None)
                for name, arm in self.arms.items()}
        self.exposures.add(t, (arms, self._T_needle.copy(), np.array(self.thread.nodes),
                               self.camera_pose()))

    def delivered_frame(self) -> float | None:
        """
        Return the scene time of the newest frame the endoscope has delivered now.

        None for an ideal camera (an image of any instant, :meth:`render`).
        """
        if not self.exposures.active:
            return None
        if self._steps == 0:
            self._expose(0.0)  # the scene as set up: the first frame
        frame = self.exposures.delivered(self.time)
        return None if frame is None else frame[0]

    def render_delivered(self, window: tuple[int, int, int, int] | None = None
                         ) -> tuple[float, StereoFrame]:
        """
        Render the newest frame the endoscope has delivered: the scene as it was exposed.

        The drawn state kept at the frame's exposure (arms, needle, thread, camera pose) is put
        back for the render and the scene's present restored after it (a falling needle's pose
        and velocity as PyBullet had them). What the realism draws (a pad's deflection) is drawn as
        it is now.

        Parameters
        ----------
        window : tuple of int, optional
            ``(u0, v0, width, height)``: only this region of both images.

        Returns
        -------
        t_scene : float
            The scene time the frame shows (its stamp is ``t_scene`` plus the latency).
        frame : sim_bridge.scene.camera.StereoFrame

        Raises
        ------
        ValueError
            For an ideal camera (no frame timing: use :meth:`render`).

        """
        if self.delivered_frame() is None:
            raise ValueError('an ideal camera delivers no frames: render() gives the scene now')
        delivered = self.exposures.delivered(self.time)
        assert delivered is not None
        t_scene, state = delivered
        arms, T_needle, thread, T_camera = cast(tuple[Any, ...], state)
        world, client, body = self.world, self.client, self.world.needle_body
        free = self._needle_mode == 'free'
        if free:  # the falling needle is PyBullet's own: its pose and velocity put back
            saved = client.getBasePositionAndOrientation(body), client.getBaseVelocity(body)
        for name, (q, jaw) in arms.items():
            world.set_arm_joints(name, q, jaw)
        world.set_needle_pose(T_needle)
        world.set_thread_points(thread)
        if self.realism is not None:
            self.realism.draw(world)
        frame = self.camera.render(T_camera, window=window)
        if free:
            client.resetBasePositionAndOrientation(body, *saved[0])
            client.resetBaseVelocity(body, *saved[1])
        self.sync_world()
        return t_scene, frame
