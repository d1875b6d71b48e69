"""
Rendered scenes with their ground truth, and the errors that measure perception against it.

This module is the examiner, not the examinee: it drives a
:class:`sim_bridge.simulation.Simulation` to put the needle somewhere (lying free, held by PSM2
in a varied grasp, partly inserted along a pair's needle arc, held by both arms as in a regrasp),
renders the ECM's pair and keeps the truth
beside the images. Perception (:mod:`suture_lfd.perception.markers`,
:mod:`suture_lfd.perception.needle`) gets only the images, the ``camera_info`` model and, for a
held needle, the tool poses the arms report (kinematics) and a grasp.

Errors follow the AMBF Surgical Robotics Challenge, Challenge 1: the sum of the position errors
(m) at the needle's base (tail), middle and tip; and the rotation angle (rad) between the
estimated and the true needle frame. Frames: the camera frame (left optical frame), metres.
"""

from dataclasses import dataclass, replace
import math
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.needle import NeedleGeometry
from sim_bridge.control import Command
from sim_bridge.realism.endoscope import endoscope_preset
from sim_bridge.scene.camera import CameraConfig
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.perception.stereo import StereoModel, stereo_from_camera_info
from suture_lfd.planning.throw_geometry import ThrowArc

KINDS = ('free', 'held', 'inserted', 'handover')


@dataclass(frozen=True, eq=False)
class RenderedScene:
    """
    A rendered stereo pair and what was really there.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    phantom : str
        Phantom name or mesh path.
    left, right : ndarray, shape (h, w, 3), uint8
        The rectified RGB pair.
    camera_info : tuple of sim_bridge.scene.camera.CameraInfo
        Left and right calibration.
    T_camera_needle : ndarray, shape (4, 4)
        The needle's true pose (camera frame).
    tools : dict of str to ndarray (4, 4)
        Tool-tip poses (camera frame) of the arms holding the needle, as their kinematics
        report them.
    grasps : dict of str to ndarray (4, 4)
        True ``T_tool_needle`` of each holding arm.
    entries, exits : ndarray, shape (n, 3)
        True marker positions (camera frame), pair ``i`` in row ``i`` along the wound.
    history : tuple of RenderedScene
        Earlier frames of the same grasp, the needle held in the air (for
        :func:`suture_lfd.perception.grasp.estimate_grasp`).

    """

    kind: str
    phantom: str
    left: np.ndarray
    right: np.ndarray
    camera_info: tuple
    T_camera_needle: np.ndarray
    tools: dict
    grasps: dict
    entries: np.ndarray
    exits: np.ndarray
    history: tuple = ()

    @property
    def stereo(self) -> StereoModel:
        """The camera model perception gets (:func:`stereo_from_camera_info`)."""
        return stereo_from_camera_info(*self.camera_info)


def needle_errors(T_estimate: ArrayLike, T_true: ArrayLike,
                  geometry: NeedleGeometry) -> tuple[float, float, float]:
    """
    Return the SRC Challenge 1 error of a needle estimate: summed and largest point error, angle.

    Parameters
    ----------
    T_estimate, T_true : array_like, shape (4, 4)
        Estimated and true ``T_camera_needle``.
    geometry : sim_bridge.common.needle.NeedleGeometry

    Returns
    -------
    tuple of float
        ``(sum (m) of the base, middle and tip errors, the largest of them (m), angle (rad))``.

    """
    p = geometry.point_at(np.array([0.0, 0.5, 1.0]))
    a = p @ np.asarray(T_estimate)[:3, :3].T + np.asarray(T_estimate)[:3, 3]
    b = p @ np.asarray(T_true)[:3, :3].T + np.asarray(T_true)[:3, 3]
    d = np.linalg.norm(a - b, axis=1)
    angle = Rotation.from_matrix(np.asarray(T_estimate)[:3, :3].T @ np.asarray(T_true)[:3, :3])
    return float(d.sum()), float(d.max()), float(angle.magnitude())


def perturbed(T: ArrayLike, rng: np.random.Generator, position: float,
              angle: float) -> np.ndarray:
    """
    Return ``T`` (4, 4) moved by a random translation and rotation of the given sizes.

    Parameters
    ----------
    T : array_like, shape (4, 4)
    rng : numpy.random.Generator
    position : float
        Length (m) of the translation, in a uniform random direction.
    angle : float
        Angle (rad) of the rotation, about a uniform random axis (applied in ``T``'s frame).

    """
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    out = np.array(T, dtype=float)
    out[:3, :3] = out[:3, :3] @ Rotation.from_rotvec(angle * axis).as_matrix()
    out[:3, 3] += position * direction
    return out


class SceneMaker:
    """
    Renders scenes of one phantom with the needle placed as each kind wants.

    Parameters
    ----------
    phantom : str or Path
        ``'synthetic'``, ``'scanned'``, or a mesh / phantom file.
    camera : sim_bridge.scene.camera.CameraConfig, optional
        Camera settings (default: ``world.yaml``'s, without depth).
    physics_step : float, optional
        Physics step (s) of the simulation (default: ``world.yaml``'s); the needle's resting
        pose after a reset depends on it (the study runs at 10 ms).
    kinematic_errors : (float, int), optional
        Hidden dVRK kinematic errors ``(level mm class, seed)`` of the arms
        (:mod:`sim_bridge.kinematic_errors`): the instruments then stand elsewhere in view.
    endoscope : str
        Preset of ``config/realism_camera.yaml`` (:mod:`sim_bridge.realism.endoscope`): the
        scenes are seen through its lens and rectified; ``''``: an ideal camera.

    """

    def __init__(self, phantom: str | Path = 'synthetic',
                 camera: CameraConfig | None = None,
                 physics_step: float | None = None,
                 kinematic_errors: tuple[float, int] | None = None,
                 endoscope: str = '') -> None:
        cfg = replace(load_simulation_config(), endoscope=endoscope_preset(endoscope))
        camera = camera or replace(cfg.camera, depth=False)
        cfg = replace(cfg, arm=replace(cfg.arm, tracking='exact'), camera=camera)
        if physics_step is not None:
            step = float(physics_step)
            cfg = replace(cfg, world=replace(cfg.world, physics_step=step),
                          loop=replace(cfg.loop, collision_period=max(cfg.loop.collision_period,
                                                                      step)))
        if kinematic_errors is not None:
            level, seed = kinematic_errors
            cfg = replace(cfg, kinematic_error_level=float(level),
                          kinematic_error_seed=int(seed))
        self.phantom = str(phantom)
        self.sim = Simulation(cfg, phantom=phantom)
        self.geometry = self.sim.needle_geometry

    def close(self) -> None:
        """Release the simulation."""
        self.sim.close()

    # ------------------------------------------------------------------ placing things
    def _start(self, rng: np.random.Generator) -> None:
        sim = self.sim
        sim.reset(seed=int(rng.integers(1 << 30)))
        sim.enable_and_home_all()
        sim.pop_events()

    def _reachable(self, arm: str, T_world_needle: np.ndarray, s_range: tuple[float, float],
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
        """Return a tool pose (world) grasping the needle in ``s_range`` that the arm reaches."""
        sim = self.sim
        chain = sim.kinematics[arm]
        T_base_world = invert_transform(sim.T_world_base(arm))
        best, best_cost = None, math.inf
        to_camera = _unit(sim.camera_pose()[:3, 3] - T_world_needle[:3, 3])
        for _ in range(24):
            s = rng.uniform(*s_range)
            roll = rng.uniform(-math.pi, math.pi)
            flip = bool(rng.integers(2))
            G = self.geometry.grasp_transform(s, roll=roll, flip=flip)
            T_tool = T_world_needle @ invert_transform(G)
            if -T_tool[:3, 2] @ to_camera > 0.6:
                continue  # the shaft between the camera and the needle: nothing to see
            Q, ok = chain.ik_batch((T_base_world @ T_tool)[None])
            if ok[0] and np.abs(Q[0, 4:]).max() < best_cost:
                best, best_cost = (T_tool, G), float(np.abs(Q[0, 4:]).max())
        return best if best_cost < math.radians(70.0) else None

    def _hold(self, arm: str, T_tool: np.ndarray, G: np.ndarray) -> None:
        sim = self.sim
        sim.apply(_command(arm, T_tool, -0.3))
        sim.run(0.01)
        sim.attach_needle(arm, G)
        sim.run(0.01)

    def _free_needle_pose(self, rng: np.random.Generator) -> np.ndarray:
        """Return a needle pose in the air above the pad, its plane turned towards the camera."""
        sim = self.sim
        T_world_camera = sim.camera_pose()
        centre = np.array([rng.uniform(-0.012, 0.016), rng.uniform(-0.012, 0.006),
                           rng.uniform(0.008, 0.02)])
        to_camera = T_world_camera[:3, 3] - centre
        to_camera /= np.linalg.norm(to_camera)
        tilt = Rotation.from_rotvec(rng.uniform(0.0, math.radians(55.0))
                                    * _unit(np.cross(to_camera, rng.normal(size=3))))
        z = tilt.apply(to_camera)
        spin = Rotation.from_rotvec(rng.uniform(-math.pi, math.pi) * z)
        x = spin.apply(_unit(np.cross(z, [0.0, 0.0, 1.0]) + 1e-9))
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        T[:3, 3] = centre
        return T

    def _above_tissue(self, T_world_needle: np.ndarray, margin: float = 0.001) -> bool:
        points = self.geometry.points_world(T_world_needle, 24)
        lowered = points - np.array([0.0, 0.0, margin])
        return float(self.sim.phantom.penetration(lowered).max()) == 0.0

    def _grasp_history(self, G: np.ndarray, n: int,
                       rng: np.random.Generator) -> tuple['RenderedScene', ...] | None:
        """``n`` frames of PSM2 holding the needle with grasp ``G`` in the air (or None)."""
        frames: list[RenderedScene] = []
        for _ in range(8 * n):
            if len(frames) == n:
                break
            T_needle = self._free_needle_pose(rng)
            if not self._above_tissue(T_needle):
                continue
            T_tool = T_needle @ invert_transform(G)
            to_camera = _unit(self.sim.camera_pose()[:3, 3] - T_needle[:3, 3])
            if -T_tool[:3, 2] @ to_camera > 0.6:
                continue  # the shaft between the camera and the needle
            T_base_world = invert_transform(self.sim.T_world_base('PSM2'))
            _, ok = self.sim.kinematics['PSM2'].ik_batch((T_base_world @ T_tool)[None])
            if ok[0]:
                self._hold('PSM2', T_tool, G)
                frames.append(self._render('held'))
        return tuple(frames) if len(frames) == n else None

    def scene(self, kind: str, rng: np.random.Generator,
              grasp_frames: int = 0) -> 'RenderedScene | None':
        """
        Place the needle as ``kind`` wants and render the pair.

        Parameters
        ----------
        kind : str
            One of :data:`KINDS`.
        rng : numpy.random.Generator
        grasp_frames : int
            Also render this many earlier frames of PSM2's grasp, the needle in the air
            (``held``, ``inserted`` and ``handover``): :attr:`RenderedScene.history`.

        Returns
        -------
        RenderedScene or None
            None when the drawn placement cannot be reached by the arms (draw again).

        """
        if kind not in KINDS:
            raise ValueError(f'scene kind must be one of {KINDS}, got {kind!r}')
        self._start(rng)
        sim = self.sim
        holders = {}
        if kind in ('held', 'handover'):
            T_needle = self._free_needle_pose(rng)
            if not self._above_tissue(T_needle):
                return None
            grasp = self._reachable('PSM2', T_needle, (0.12, 0.45), rng)
            if grasp is None:
                return None
            holders['PSM2'] = grasp
            if kind == 'handover':
                other = self._reachable('PSM1', T_needle, (0.7, 0.9), rng)
                if other is None:
                    return None
                holders['PSM1'] = other
        elif kind == 'inserted':
            pair = list(sim.phantom.markers.values())[int(rng.integers(len(sim.phantom.markers)))]
            arc = ThrowArc(pair, self.geometry)
            u = rng.uniform(0.15, 0.85)
            T_needle = arc.T_world_needle(arc.alpha_entry + u * (arc.alpha_exit - arc.alpha_entry))
            grasp = self._reachable('PSM2', T_needle, (0.05, 0.2), rng)
            if grasp is None:
                return None
            holders['PSM2'] = grasp
        history: tuple[RenderedScene, ...] = ()
        if grasp_frames and holders:
            frames = self._grasp_history(holders['PSM2'][1], grasp_frames, rng)
            if frames is None:
                return None
            history = frames
            self.sim.attach_needle('PSM2', holders['PSM2'][1])
        for arm, (T_tool, G) in holders.items():
            self._hold(arm, T_tool, G)
        return replace(self._render(kind), history=history)

    def resting(self, seed: int) -> 'RenderedScene':
        """
        Render the needle where the reset with ``seed`` leaves it on the pad (arms homed).

        Parameters
        ----------
        seed : int
            Scene seed of the reset (a study's throw or demonstration seed).

        Returns
        -------
        RenderedScene
            Of kind ``free``.

        """
        sim = self.sim
        sim.reset(seed=int(seed))
        sim.enable_and_home_all()
        sim.pop_events()
        return self._render('free')

    def pick(self, rng: np.random.Generator) -> np.ndarray | None:
        """
        Draw a grasp PSM2 reaches on the needle where it now lies (after :meth:`resting`).

        Nothing moves; :meth:`held_frames` then shows the needle held with it.

        Returns
        -------
        ndarray, shape (4, 4) or None
            The grasp ``T_tool_needle``; None when no drawn grasp is reachable.

        """
        picked = self._reachable('PSM2', self.sim.needle_pose(), (0.12, 0.45), rng)
        return None if picked is None else picked[1]

    def held_frames(self, G: ArrayLike, n: int,
                    rng: np.random.Generator) -> tuple['RenderedScene', ...] | None:
        """
        Render ``n`` pairs of PSM2 holding the needle with grasp ``G``, turned in the air.

        Returns
        -------
        tuple of RenderedScene or None
            Of kind ``held`` (the needle faces the camera within 55 degrees); None when the
            arm cannot reach enough such poses.

        """
        return self._grasp_history(np.asarray(G, dtype=float), n, rng)

    def carry(self, translation: ArrayLike, arm: str = 'PSM2') -> 'RenderedScene':
        """
        Move the arm holding the needle by ``translation`` and render the pair again.

        Parameters
        ----------
        translation : array_like, shape (3,)
            Displacement (m, world frame) of the tool, the grasp kept.
        arm : str
            The holding arm (it must hold the needle: after a ``held`` scene).

        Returns
        -------
        RenderedScene
            Kind ``held``.

        """
        sim = self.sim
        if arm not in sim.grasp.holders:
            raise ValueError(f'{arm} does not hold the needle: render a held scene first')
        T_tool = sim.tool_pose(arm)
        G = invert_transform(T_tool) @ sim.needle_pose()
        moved = T_tool.copy()
        moved[:3, 3] += np.asarray(translation, dtype=float).reshape(3)
        self._hold(arm, moved, G)
        return self._render('held')

    def _render(self, kind: str) -> 'RenderedScene':
        sim = self.sim
        frame = sim.render()
        T_left_world = invert_transform(frame.T_world_left)
        holders = sim.grasp.holders
        tools = {a: T_left_world @ sim.tool_pose(a) for a in holders}
        grasps = {a: invert_transform(sim.tool_pose(a)) @ sim.needle_pose() for a in holders}
        pairs = sorted(sim.phantom.markers.values(), key=lambda p: p.index)
        entries = np.array([T_left_world[:3, :3] @ p.entry + T_left_world[:3, 3] for p in pairs])
        exits = np.array([T_left_world[:3, :3] @ p.exit + T_left_world[:3, 3] for p in pairs])
        camera = sim.camera
        return RenderedScene(kind=kind, phantom=self.phantom, left=frame.left_rgb,
                             right=frame.right_rgb,
                             camera_info=(camera.camera_info('left'), camera.camera_info('right')),
                             T_camera_needle=T_left_world @ sim.needle_pose(), tools=tools,
                             grasps=grasps, entries=entries, exits=exits)


def _unit(v: ArrayLike) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _command(arm: str, T: np.ndarray, jaw: float) -> Command:
    return Command(t=0.0, T_world_tool={arm: T}, jaw={arm: jaw}, subtask='')
