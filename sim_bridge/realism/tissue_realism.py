"""
The needle-in-tissue effects composed: what the physics calls once per step.

:class:`TissueRealism` joins :mod:`~sim_bridge.realism.needle_tissue` (forces),
:mod:`~sim_bridge.realism.grip` (the needle turning in the jaw),
:mod:`~sim_bridge.realism.pad_deflection` (the dimple under the tip, drawn by moving the
markers) and :mod:`~sim_bridge.realism.thread_drag`. The physics builds one only when some
level is above 0 (:func:`build_tissue_realism`), so at level 0 nothing of this runs.

Per step, while a PSM holds the needle near the tissue: before the puncture (the tip pressed
into the undeformed surface by less than the pad's deflection limit) the surface pushes the tip
back; after it, every occupied puncture resists the needle leaving its arc and rubs along the
wire, and between the exit and the extraction the thread pulls the tail. The grip holds the sum
up to its limits; past them the grasp itself turns (the needle stays slipped). A slip episode
(consecutive slipping steps) that turned or slid the needle more than the reporting thresholds
is reported when it ends, as ``on_slip(t, arm=, angle=, slide=, total_angle=, in_tissue=)``
(rad, m; ``total_angle`` since the grasp). Past ``break_angle`` or ``break_slide`` since the
grasp (the dVRK simulators' 30 deg and 10 mm) the grasp breaks: the episode is reported with
``broken=True`` and the jaw lets the needle go.

Frames: ``world`` unless named otherwise; SI units.
"""

from collections.abc import Callable
import math
from typing import Any

import numpy as np
from sim_bridge.realism.grip import Grip, slipped_grasp, wrench_at
from sim_bridge.realism.needle_tissue import puncture_contacts, puncture_push
from sim_bridge.realism.pad_deflection import PadDeflection
from sim_bridge.realism.thread_drag import thread_pull
from sim_bridge.realism.tissue_config import TissueRealismConfig


class TissueRealism:
    """
    Tissue forces, grip, pad deflection and thread drag, stepped with the physics.

    Parameters
    ----------
    config : TissueRealismConfig
        Levels and magnitudes.
    needle : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    phantom : sim_bridge.scene.phantom.Phantom
        The phantom (its pose gives the surface's normal).
    grasp_point : ndarray, shape (3,)
        Grasp point in the tool frame (m).

    Attributes
    ----------
    grip : Grip
    pad : PadDeflection
    slips : int
        Slip episodes reported since the simulation started.

    """

    def __init__(self, config: TissueRealismConfig, needle: Any, phantom: Any,
                 grasp_point: np.ndarray) -> None:
        self.config = config
        m = config.magnitudes
        self.needle = needle
        self.grasp_point = np.asarray(grasp_point, dtype=float)
        self._T_world_phantom = np.asarray(phantom.T_world_phantom, dtype=float)
        self.normal = self._T_world_phantom[:3, 2].copy()
        # Highest point of the tissue (world z) and how far below its centre the needle reaches:
        # a needle wholly above it cannot press the pad.
        self._tissue_top = float(phantom.mesh_world().vertices[:, 2].max())
        self._reach = needle.radius + needle.wire_diameter
        grip = config.grip
        self.grip = Grip(m.grip_torque / grip if grip > 0 else math.inf,
                         m.grip_force / grip if grip > 0 else math.inf, m.max_slip_step)
        limit = config.pad * m.puncture_force / m.pad_stiffness
        self.pad = PadDeflection(limit, m.deflection_spread, m.relax_time, self.normal)
        self._k_pad = config.needle_tissue * m.pad_stiffness
        self._k_lat = config.needle_tissue * m.lateral_stiffness
        self._friction = config.needle_tissue * m.friction_per_length * needle.length
        self._drag = config.thread_drag * m.thread_drag
        self._tail = needle.tail
        self._tail_tangent = needle.tangent_at(0.0)
        self._marker_rest: dict[int, tuple[np.ndarray, Any]] | None = None
        self._drawn = False
        self.slips = 0
        self.reset()

    def reset(self) -> None:
        """Start a new scene: no grasp followed, an untouched pad."""
        self._leader: str | None = None
        self._episode = [0.0, 0.0]  # turn and slide of the running slip episode
        self._n_punctures = 0
        self.grip.reset()
        self.pad.reset()

    # ------------------------------------------------------------------ step
    def step(self, t: float, dt: float, grasp: Any, tissue: Any,
             tool_pose: Callable[[str], np.ndarray], T_needle: np.ndarray,
             T_prev: np.ndarray, near: bool, listener: Any) -> np.ndarray:
        """
        Apply the tissue's forces for one physics step; return the needle pose after any slip.

        Parameters
        ----------
        t, dt : float
            Time at the step's end and the step (s).
        grasp : sim_bridge.scene.grasp.GraspManager
            Who holds the needle (a slip changes the leader's grasp).
        tissue : sim_bridge.scene.tissue.TissueTracker
            Punctures and depths (as of the last step).
        tool_pose : callable
            ``tool_pose(arm) -> T_world_tool`` (true pose).
        T_needle, T_prev : ndarray, shape (4, 4)
            Needle pose now (following the leader) and one step before.
        near : bool
            The needle is in or near the tissue.
        listener : object
            Gets ``on_slip(t, **data)`` when a slip episode ends.

        Returns
        -------
        ndarray, shape (4, 4)
            The needle pose (``T_needle`` itself when it did not slip).

        """
        n_punct = len(tissue.punctures)
        if n_punct < self._n_punctures:
            self.pad.reset()  # the tracker started a new throw
        self._n_punctures = n_punct
        leader = grasp.leader
        if leader != self._leader:
            self._end_episode(t, listener, tissue)
            self.grip.reset()
            self._leader = leader
        if leader is None or not near:
            self.pad.relax(dt)
            self._end_episode(t, listener, tissue)
            return T_needle
        contacts = []
        if not self.pad.punctured and T_needle[2, 3] - self._reach <= self._tissue_top:
            indentation = tissue.wire_depth(T_needle)
            tip = T_needle[:3, :3] @ self.needle.tip + T_needle[:3, 3]
            deflection = self.pad.press(tip, indentation)
            if deflection > 0.0 and self._k_pad > 0.0 and not self.pad.punctured:
                contacts.append(puncture_push(tip, self.normal, deflection, self._k_pad))
        else:
            self.pad.relax(dt)
        if n_punct and self.pad.punctured and self._k_lat > 0.0:
            occupied = [p.point for p in tissue.punctures if p.occupied]
            if occupied:
                pts = np.asarray(occupied) @ self._T_world_phantom[:3, :3].T \
                    + self._T_world_phantom[:3, 3]
                friction = self._friction * tissue.inside_fraction
                contacts += puncture_contacts(T_needle, T_prev, self.needle.radius, pts,
                                              self._k_lat, friction)
        if self._drag > 0.0 and tissue.had_exit and not tissue.extracted:
            contacts.append(thread_pull(T_needle, self._tail, self._tail_tangent, self._drag))
        if not contacts:
            self._end_episode(t, listener, tissue)
            return T_needle
        T_tool = tool_pose(leader)
        slip = self.grip.hold(wrench_at(contacts, T_tool, self.grasp_point))
        if not slip.moved:
            self._end_episode(t, listener, tissue)
            return T_needle
        G = slipped_grasp(grasp.relative_pose(leader), self.grasp_point, slip)
        grasp.attach(leader, G)
        self._episode[0] += slip.angle
        self._episode[1] += slip.slide
        m = self.config.magnitudes
        if abs(self.grip.angle) > m.break_angle or abs(self.grip.slide) > m.break_slide:
            # turned or slid too far: the jaw no longer holds the needle (dropped next step)
            self._end_episode(t, listener, tissue, broken=True)
            grasp.let_go(leader)
        return T_tool @ G

    def _end_episode(self, t: float, listener: Any, tissue: Any, broken: bool = False) -> None:
        angle, slide = self._episode
        if angle == 0.0 and slide == 0.0:
            return
        self._episode = [0.0, 0.0]
        m = self.config.magnitudes
        if broken or abs(angle) >= m.slip_event_angle or abs(slide) >= m.slip_event_slide:
            self.slips += 1
            listener.on_slip(t, arm=self._leader, angle=float(angle), slide=float(slide),
                             total_angle=float(self.grip.angle),
                             in_tissue=bool(tissue.in_tissue), broken=broken)

    # ------------------------------------------------------------------ drawing
    def surface_patch(self, rings: int = 4, per_ring: int = 12) -> np.ndarray:
        """
        Points of the pad's surface around the dimple, as deflected (for a viewer).

        Parameters
        ----------
        rings : int
            Circles around the dimple's centre, at 0.5, 1, 1.5 .. times its spread.
        per_ring : int
            Points per circle.

        Returns
        -------
        ndarray, shape (1 + rings * per_ring, 3) or (0, 3)
            ``world`` (m): the centre and the circles, each moved by the dimple; empty when the
            pad is at rest.

        """
        pad = self.pad
        if pad.depth == 0.0 or pad.centre is None:
            return np.zeros((0, 3))
        u = np.cross(self.normal, (1.0, 0.0, 0.0) if abs(self.normal[0]) < 0.9
                     else (0.0, 1.0, 0.0))
        u /= np.linalg.norm(u)
        v = np.cross(self.normal, u)
        angles = np.linspace(0.0, 2.0 * np.pi, per_ring, endpoint=False)
        radii = 0.5 * pad.spread * np.arange(1, rings + 1)
        ring = (radii[:, None, None] * (np.cos(angles)[None, :, None] * u
                                        + np.sin(angles)[None, :, None] * v)).reshape(-1, 3)
        rest = np.vstack([pad.centre, pad.centre + ring])
        return rest + pad.displacement(rest)

    def moved(self, points: np.ndarray) -> np.ndarray:
        """
        Return surface points ``(n, 3)`` (``world``, m) moved with the dimple.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Points of the undeformed surface (the markers' rest positions).

        Returns
        -------
        ndarray, shape (n, 3)

        """
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        return pts + self.pad.displacement(pts)

    def draw(self, world: Any) -> None:
        """
        Move the drawn markers with the dimple (their rest poses when it has relaxed).

        The pad's mesh is drawn undeformed, so a marker is pressed in by at most half its
        thickness (it would vanish under the mesh); it follows the surface's drag in full.

        Parameters
        ----------
        world : sim_bridge.scene.world.World
            The PyBullet world (its ``marker_bodies``).

        """
        c = world.client
        if self._marker_rest is None:
            self._marker_rest = {}
            for body in world.marker_bodies.values():
                pos, quat = c.getBasePositionAndOrientation(body)
                self._marker_rest[body] = (np.array(pos), quat)
        if self.pad.depth == 0.0 and not self._drawn:
            return
        bodies = list(self._marker_rest)
        rest = np.array([self._marker_rest[b][0] for b in bodies])
        cap = 0.5 * world.config.marker_thickness
        moved = rest + self.pad.displacement(rest, cap)
        for body, p in zip(bodies, moved):
            c.resetBasePositionAndOrientation(body, p.tolist(), self._marker_rest[body][1])
        self._drawn = self.pad.depth > 0.0


def build_tissue_realism(config: TissueRealismConfig | None, needle: Any, phantom: Any,
                         grasp_point: np.ndarray) -> TissueRealism | None:
    """
    Return the composed effects, or None when every level is 0 (the physics then skips them).

    Parameters
    ----------
    config : TissueRealismConfig or None
        Levels and magnitudes.
    needle : sim_bridge.common.needle.NeedleGeometry
    phantom : sim_bridge.scene.phantom.Phantom
    grasp_point : ndarray, shape (3,)
        Grasp point in the tool frame (m).

    Returns
    -------
    TissueRealism or None

    """
    if config is None or not config.active:
        return None
    return TissueRealism(config, needle, phantom, grasp_point)
