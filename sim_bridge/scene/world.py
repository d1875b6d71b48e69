"""
The PyBullet world: arms built from their DH chains, needle, thread, phantom, table, markers.

Everything lives in one injected PyBullet client (``pybullet_utils.bullet_client.BulletClient``),
in SI units without world scaling, with a fixed physics step.

Arms are kinematic multibodies: each DH joint becomes a PyBullet joint whose frame in its parent
link is the fixed part of the modified-DH transform (``SerialChain.joint_placements``:
``RotX(alpha) TransX(a) RotZ(theta0) TransZ(d0)``, offsets included), and which turns about
(revolute) or slides along (prismatic) its local ``z``; the PyBullet link frame of joint ``i`` is
therefore the DH frame ``i`` and the multibody's base frame is the arm's RCM frame
``<ARM>_base``. A fixed ``tip`` link carries the tooltip offset (its frame is ``measured_cp``);
PSMs add two jaw links hinged about tool ``x``, each turned by half the jaw angle. Joint values
are set with ``resetJointStatesMultiDof``; the arms never move under physics.

Link indices (``World.link_index``): PSM ``yaw, pitch, insertion, roll, wrist_pitch, wrist_yaw,
tip, jaw_a, jaw_b`` = 0..8; ECM ``yaw, pitch, insertion, roll, tip`` = 0..4.

The needle is one rigid body of capsules along its arc; its inertial frame sits at the arc's
centre of mass on its principal axes. Collision groups keep the needle touching only the table
and the phantom (when it is free and dynamic); arms, thread and markers take part in no contacts.
The thread's capsules are drawn only (its dynamics are :mod:`sim_bridge.scene.thread`).

Size: every body lives in one PyBullet client whose per-step calls are batched here (the
simulator's hot path), so the bodies are built and moved in one file.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import tempfile
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation
from sim_bridge.bullet import pybullet
from sim_bridge.common.configfile import dataclass_from_mapping, load_yaml, section
from sim_bridge.common.geometry import invert_transform, quaternion_from_matrix
from sim_bridge.common.needle import NeedleGeometry, ThreadGeometry
from sim_bridge.common.paths import config_path
from sim_bridge.common.validation import check_positive

if TYPE_CHECKING:
    from sim_bridge.scene.phantom import Phantom
    import trimesh

# Frames of the arms' Cartesian poses (WorldConfig.frames): a patient cart (PSMs in the camera
# frame) or each arm in its own base.
FRAMES = ('cart', 'base')

# Collision groups (bit masks).
GROUP_ENVIRONMENT = 1
GROUP_NEEDLE = 2
GROUP_NONE = 0

# PyBullet's limits for meshes passed as vertex arrays (SharedMemoryPublic.h).
_MAX_MESH_VERTICES = 8192
_MAX_MESH_INDICES = 32768

PSM_LINKS = ('yaw', 'pitch', 'insertion', 'roll', 'wrist_pitch', 'wrist_yaw', 'tip', 'jaw_a',
             'jaw_b')
ECM_LINKS = ('yaw', 'pitch', 'insertion', 'roll', 'tip')


@dataclass(frozen=True)
class Placement:
    """
    Pose of an arm's RCM frame ``<ARM>_base`` in ``world``.

    Attributes
    ----------
    position : (x, y, z)
        RCM position (m).
    rpy : (roll, pitch, yaw)
        Orientation (rad): ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    """

    position: tuple[float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def T(self) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """``T_world_base``, shape (4, 4)."""
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler('xyz', self.rpy).as_matrix()
        T[:3, 3] = self.position
        return T


@dataclass(frozen=True)
class InstrumentShape:
    """
    Simple shapes of the instruments (m) and their colours.

    Attributes
    ----------
    shaft_radius, shaft_length : float
        PSM tool shaft capsule, from the wrist-pitch axis back along the shaft.
    wrist_radius : float
        Wrist (pitch-to-yaw clevis) capsule radius.
    jaw_length, jaw_width, jaw_thickness : float
        Each jaw is a box from the hinge along tool ``z``.
    endoscope_radius, endoscope_length : float
        ECM endoscope capsule, ending ``endoscope_gap`` behind the camera.
    endoscope_gap : float
        Distance from the endoscope's end to the camera frame.
    shaft_rgba, wrist_rgba, jaw_rgba, endoscope_rgba : (r, g, b, a)
        Colours.

    """

    shaft_radius: float = 0.0042
    shaft_length: float = 0.45
    wrist_radius: float = 0.0025
    jaw_length: float = 0.009
    jaw_width: float = 0.0025
    jaw_thickness: float = 0.001
    endoscope_radius: float = 0.005
    endoscope_length: float = 0.35
    endoscope_gap: float = 0.002
    shaft_rgba: tuple[float, float, float, float] = (0.15, 0.15, 0.17, 1.0)
    wrist_rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.62, 1.0)
    jaw_rgba: tuple[float, float, float, float] = (0.78, 0.78, 0.8, 1.0)
    endoscope_rgba: tuple[float, float, float, float] = (0.2, 0.2, 0.22, 1.0)


#: Tiles a side of the drawn table top is cut into (small triangles rasterise faster).
_DRAPE_TILES = 8


@dataclass(frozen=True)
class WorldConfig:
    """
    Physics and scene settings of the PyBullet world.

    Attributes
    ----------
    physics_step : float
        Fixed physics time step (s).
    solver_iterations : int
        Constraint solver iterations per step.
    gravity : float
        Gravitational acceleration along world ``-z`` (m/s^2).
    table_height : float or None
        Height (m) of the table plane; None puts it at the phantom's lowest point.
    table_size : (x, y)
        Size (m) of the drawn table top.
    table_rgba : (r, g, b, a)
        Table colour (a surgical drape).
    arms : dict of Placement
        RCM frame of each arm (``PSM1``, ``PSM2``, ``ECM``) in ``world``.
    frames : str
        Frames of the arms' Cartesian poses: ``'cart'`` (a patient cart with set-up joints:
        PSM poses in the ECM camera frame ``ECM``, the ECM in ``world``) or ``'base'`` (each
        arm in its own RCM frame ``<ARM>_base``, as a single arm on a table).
    instrument : InstrumentShape
        Instrument shapes and colours.
    needle_segments : int
        Capsules along the needle arc.
    needle_rgba, thread_rgba : (r, g, b, a)
        Colours.
    needle_friction, needle_restitution : float
        Contact properties of the needle.
    marker_thickness : float
        Thickness (m) of the drawn marker discs.
    phantom_collision_margin : float
        Contact margin (m) of the phantom's collision mesh; the mesh is lowered by it so that a
        needle rests on the visible surface (smaller margins let the thin wire sink in).

    """

    physics_step: float = 0.002
    solver_iterations: int = 30
    gravity: float = 9.81
    table_height: float | None = None
    table_size: tuple[float, float] = (0.5, 0.5)
    table_rgba: tuple[float, float, float, float] = (0.22, 0.42, 0.48, 1.0)
    arms: dict[str, Placement] = field(default_factory=dict)
    instrument: InstrumentShape = field(default_factory=InstrumentShape)
    needle_segments: int = 16
    needle_rgba: tuple[float, float, float, float] = (0.82, 0.82, 0.86, 1.0)
    thread_rgba: tuple[float, float, float, float] = (0.45, 0.2, 0.65, 1.0)
    needle_friction: float = 0.6
    needle_restitution: float = 0.0
    marker_thickness: float = 0.0002
    phantom_collision_margin: float = 0.001
    frames: str = 'cart'

    def __post_init__(self) -> None:
        check_positive(self.physics_step, 'world physics_step (s)')
        if self.frames not in FRAMES:
            raise ValueError(f"world frames must be 'cart' (PSM poses in the camera frame) or "
                             f"'base' (each arm in <ARM>_base), got {self.frames!r}")
        if self.solver_iterations < 1:
            raise ValueError(
                f'world solver_iterations must be >= 1, got {self.solver_iterations}')
        if self.needle_segments < 1:
            raise ValueError(f'world needle_segments must be >= 1, got {self.needle_segments}')


def read_world_config(path: str | Path | None = None) -> 'WorldConfig':
    """
    Read the ``world`` section of ``config/world.yaml`` into a :class:`WorldConfig`.

    Parameters
    ----------
    path : str or Path, optional
        File to read; default: the package's ``config/world.yaml``.

    Returns
    -------
    WorldConfig

    """
    path = config_path('world.yaml') if path is None else path
    data = section(load_yaml(path), 'world', source=str(path))
    return dataclass_from_mapping(WorldConfig, data, source=str(path), prefix='world')


def transform_from_bullet(position: ArrayLike, quaternion: ArrayLike) -> np.ndarray:
    """
    Return the 4x4 pose of a PyBullet position and quaternion ``(x, y, z, w)``.

    Parameters
    ----------
    position : array_like, shape (3,)
        Translation (m).
    quaternion : array_like, shape (4,)
        Rotation ``(x, y, z, w)``.

    Returns
    -------
    ndarray, shape (4, 4)

    """
    T = np.eye(4)
    T[:3, :3] = np.reshape(pybullet.getMatrixFromQuaternion(quaternion), (3, 3))
    T[:3, 3] = position
    return T


def _wire_mesh(needle: NeedleGeometry, n_arc: int = 48, n_ring: int = 12
               ) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """
    Return the needle's wire as a closed triangle mesh in the needle frame, for drawing.

    A tube of the wire's radius along the arc with flat ends (PyBullet's CPU renderer draws
    capsules in shape arrays far thicker than their radius, so the drawn needle is a mesh).

    Returns
    -------
    vertices : ndarray, shape (n, 3)
    normals : ndarray, shape (n, 3)
    indices : list of int
        Counter-clockwise triangles seen from outside.

    """
    r = 0.5 * needle.wire_diameter
    s = np.linspace(0.0, 1.0, n_arc + 1)
    centre = needle.point_at(s)
    radial = centre / needle.radius
    theta = np.linspace(0.0, 2.0 * math.pi, n_ring, endpoint=False)
    z = np.array([0.0, 0.0, 1.0])
    ring = (np.cos(theta)[None, :, None] * radial[:, None, :]
            + np.sin(theta)[None, :, None] * z[None, None, :])  # (n_arc + 1, n_ring, 3)
    vertices = (centre[:, None, :] + r * ring).reshape(-1, 3)
    normals = ring.reshape(-1, 3)
    indices = []
    for i in range(n_arc):
        for j in range(n_ring):
            a, b = i * n_ring + j, i * n_ring + (j + 1) % n_ring
            c, d = a + n_ring, b + n_ring
            indices += [a, c, b, b, c, d]
    tangent = needle.tangent_at(np.array([0.0, 1.0]))
    caps: list[tuple[np.ndarray, np.ndarray]] = []
    for k, (row, direction) in enumerate(((0, -tangent[0]), (n_arc, tangent[1]))):
        first = len(vertices) + sum(len(c[0]) for c in caps)
        ring_vertices = vertices[row * n_ring:(row + 1) * n_ring]
        cap_vertices = np.vstack([centre[row], ring_vertices])
        caps.append((cap_vertices, np.tile(direction, (n_ring + 1, 1))))
        for j in range(n_ring):
            a, b = first + 1 + j, first + 1 + (j + 1) % n_ring
            indices += [first, b, a] if k == 0 else [first, a, b]
    vertices = np.vstack([vertices] + [c[0] for c in caps])
    normals = np.vstack([normals] + [c[1] for c in caps])
    return vertices, normals, indices


def _arc_mass_properties(points: np.ndarray, mass: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre of mass, principal axes and inertias of a wire through ``points`` (n, 3)."""
    mid = 0.5 * (points[1:] + points[:-1])
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    m = mass * seg / seg.sum()
    com = (m[:, None] * mid).sum(axis=0) / mass
    r = mid - com
    inertia = (m * (r ** 2).sum(axis=1)).sum() * np.eye(3) - (m[:, None, None] * (
        r[:, :, None] * r[:, None, :])).sum(axis=0)
    values, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0.0:
        axes[:, 2] = -axes[:, 2]
    # A thin wire's inertia about its own axis is not zero; keep every moment positive.
    values = np.maximum(values, 1e-3 * values.max())
    return com, axes, values


class World:
    """
    PSM1, PSM2 and the ECM, the needle with its thread, the phantom and the table in PyBullet.

    Parameters
    ----------
    config : WorldConfig
        Physics and scene settings (arm placements included).
    kinematics : mapping of str to SerialChain
        Kinematics per arm name; ``PsmKinematics`` arms get jaws. (Annotated ``Any``: the
        scene package does not import the kinematics package.)
    phantom : sim_bridge.scene.phantom.Phantom
        The phantom (mesh in its frame, markers in ``world``).
    needle : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    thread : sim_bridge.common.needle.ThreadGeometry
        Thread geometry (segment count and radius of the drawn capsules).
    client : pybullet_utils.bullet_client.BulletClient
        The PyBullet client; the world resets it and owns its contents.

    """

    def __init__(self, config: 'WorldConfig', kinematics: Mapping[str, Any],
                 phantom: 'Phantom', needle: NeedleGeometry, thread: ThreadGeometry,
                 client: Any) -> None:
        self.config = config
        self.client = client
        self.kinematics = dict(kinematics)
        self.phantom = phantom
        self.needle = needle
        self.thread = thread
        missing = sorted(set(self.kinematics) - set(config.arms))
        if missing:
            raise ValueError(f'world config has no placement (arms.<name>) for {missing}')
        self.T_world_base = {name: config.arms[name].T for name in self.kinematics}
        if config.table_height is None:
            self.table_height = float(phantom.mesh_world().vertices[:, 2].min())
        else:
            self.table_height = float(config.table_height)
        c = client
        c.resetSimulation()
        c.setPhysicsEngineParameter(fixedTimeStep=config.physics_step,
                                    numSolverIterations=config.solver_iterations,
                                    numSubSteps=0, deterministicOverlappingPairs=1)
        c.setGravity(0.0, 0.0, -config.gravity)
        self.arm_body: dict[str, int] = {}
        self.link_index: dict[str, dict[str, int]] = {}
        self._dof: dict[str, list[int]] = {}
        for name, chain in self.kinematics.items():
            self._build_arm(name, chain)
        self.table_body = self._build_table()
        self.phantom_body = self._build_phantom()
        self.marker_bodies = self._build_markers()
        self.needle_body = self._build_needle()
        self.thread_bodies = self._build_thread()
        self.drape_body = self._build_drape()  # drawn last: see _build_drape

    # ------------------------------------------------------------------ construction
    def _build_arm(self, name: str, chain: Any) -> None:
        c = self.client
        shape = self.config.instrument
        is_psm = hasattr(chain, 'jaw_lower')
        frames = list(chain.joint_placements())
        types = [pybullet.JOINT_REVOLUTE if j.is_revolute else pybullet.JOINT_PRISMATIC
                 for j in chain.joints]
        axes = [[0.0, 0.0, 1.0]] * len(frames)
        frames.append(np.array(chain.tooltip_offset))
        types.append(pybullet.JOINT_FIXED)
        axes.append([0.0, 0.0, 1.0])
        n_dh = chain.n_joints
        visuals = [-1] * len(frames)
        collisions = [-1] * len(frames)
        roll_link = 3
        up_z = Rotation.from_euler('y', 90.0, degrees=True).as_quat().tolist()
        if is_psm:
            half = 0.5 * shape.shaft_length
            visuals[roll_link], collisions[roll_link] = self._build_compound(
                [(pybullet.GEOM_CAPSULE, {'radius': shape.shaft_radius,
                                          'height': shape.shaft_length},
                  [0.0, 0.0, -half - shape.wrist_radius], [0, 0, 0, 1])], shape.shaft_rgba)
            a6 = chain.joints[5].a
            visuals[4], collisions[4] = self._build_compound(
                [(pybullet.GEOM_CAPSULE, {'radius': shape.wrist_radius, 'height': abs(a6)},
                  [0.5 * a6, 0.0, 0.0], up_z)], shape.wrist_rgba)
            jaw_half = [0.5 * shape.jaw_width, 0.5 * shape.jaw_thickness, 0.5 * shape.jaw_length]
            for side in (-1.0, 1.0):
                frames.append(np.eye(4))
                types.append(pybullet.JOINT_REVOLUTE)
                axes.append([1.0, 0.0, 0.0])
                v, col = self._build_compound(
                    [(pybullet.GEOM_BOX, {'halfExtents': jaw_half},
                      [0.0, side * jaw_half[1], jaw_half[2]], [0, 0, 0, 1])], shape.jaw_rgba)
                visuals.append(v)
                collisions.append(col)
            link_names: tuple[str, ...] = PSM_LINKS
        else:
            half = 0.5 * shape.endoscope_length
            visuals[roll_link], collisions[roll_link] = self._build_compound(
                [(pybullet.GEOM_CAPSULE, {'radius': shape.endoscope_radius,
                                          'height': shape.endoscope_length},
                  [0.0, 0.0, -half - shape.endoscope_radius - shape.endoscope_gap],
                  [0, 0, 0, 1])], shape.endoscope_rgba)
            link_names = ECM_LINKS
        n_links = len(frames)
        parents = list(range(n_dh + 1)) + [n_dh + 1] * (n_links - n_dh - 1)
        T_base = self.T_world_base[name]
        body = c.createMultiBody(
            baseMass=0.0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=-1,
            basePosition=T_base[:3, 3].tolist(),
            baseOrientation=quaternion_from_matrix(T_base[:3, :3]).tolist(),
            linkMasses=[0.0] * n_links, linkCollisionShapeIndices=collisions,
            linkVisualShapeIndices=visuals,
            linkPositions=[F[:3, 3].tolist() for F in frames],
            linkOrientations=[quaternion_from_matrix(F[:3, :3]).tolist() for F in frames],
            linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n_links,
            linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n_links,
            linkParentIndices=parents, linkJointTypes=types, linkJointAxis=axes)
        for link in range(-1, n_links):
            c.setCollisionFilterGroupMask(body, link, GROUP_NONE, GROUP_NONE)
        self.arm_body[name] = body
        self.link_index[name] = {n: i for i, n in enumerate(link_names)}
        dof = list(range(n_dh))
        if is_psm:
            dof += [n_links - 2, n_links - 1]
        self._dof[name] = dof
        self.set_arm_joints(name, chain.home, 0.0 if is_psm else None)

    def _build_compound(self, parts: Sequence[tuple[int, dict, Sequence[float], Sequence[float]]],
                        rgba: Sequence[float]) -> tuple[int, int]:
        """Visual and collision shape ids of a list of (kind, kwargs, position, quaternion)."""
        c = self.client
        kinds = [p[0] for p in parts]
        radii = [p[1].get('radius', 0.0) for p in parts]
        heights = [p[1].get('height', 0.0) for p in parts]
        halves = [p[1].get('halfExtents', [0.0, 0.0, 0.0]) for p in parts]
        positions = [list(p[2]) for p in parts]
        orientations = [list(p[3]) for p in parts]
        visual = c.createVisualShapeArray(
            shapeTypes=kinds, radii=radii, lengths=heights, halfExtents=halves,
            rgbaColors=[list(rgba)] * len(parts), visualFramePositions=positions,
            visualFrameOrientations=orientations)
        collision = c.createCollisionShapeArray(
            shapeTypes=kinds, radii=radii, lengths=heights, halfExtents=halves,
            collisionFramePositions=positions, collisionFrameOrientations=orientations)
        return visual, collision

    def _build_table(self) -> int:
        c = self.client
        cfg = self.config
        col = c.createCollisionShape(pybullet.GEOM_PLANE)
        # drawn by the drape (_build_drape); a body without a visual would be drawn as its
        # collision plane, so this one's is a speck under the drape's top
        vis = c.createVisualShape(pybullet.GEOM_BOX, halfExtents=[1e-4] * 3,
                                  rgbaColor=list(cfg.table_rgba),
                                  visualFramePosition=[0.0, 0.0, -0.001])
        centre = self.phantom.T_world_phantom[:3, 3]
        body = c.createMultiBody(0.0, col, vis, [float(centre[0]), float(centre[1]),
                                                self.table_height])
        c.setCollisionFilterGroupMask(body, -1, GROUP_ENVIRONMENT, GROUP_NEEDLE)
        return body

    def _build_drape(self) -> int:
        """
        Draw the table's top (a drape): a body of its own, built after every other one.

        The drape fills the endoscope's background, and the renderer pays for every triangle
        across all the pixels it spans: the top alone (the endoscope never sees the sides or
        the underside), cut into tiles and drawn after the other bodies, renders a full view
        in about 0.07 s of CPU where the table's box took 0.09 s, the colour images the same
        pixel for pixel (depth within 1e-6 m).
        """
        c = self.client
        cfg = self.config
        n = _DRAPE_TILES
        xs = np.linspace(-0.5 * cfg.table_size[0], 0.5 * cfg.table_size[0], n + 1)
        ys = np.linspace(-0.5 * cfg.table_size[1], 0.5 * cfg.table_size[1], n + 1)
        vertices = [[float(x), float(y), 0.0] for y in ys for x in xs]
        indices = []
        for j in range(n):
            for i in range(n):
                k = j * (n + 1) + i
                indices += [k, k + 1, k + n + 2, k, k + n + 2, k + n + 1]
        vis = c.createVisualShape(pybullet.GEOM_MESH, vertices=vertices, indices=indices,
                                  normals=[[0.0, 0.0, 1.0]] * len(vertices),
                                  rgbaColor=list(cfg.table_rgba))
        centre = self.phantom.T_world_phantom[:3, 3]
        return c.createMultiBody(0.0, -1, vis, [float(centre[0]), float(centre[1]),
                                                self.table_height])

    def _mesh_shapes(self, mesh: 'trimesh.Trimesh', rgba: Sequence[float],
                     collision_offset: Sequence[float]) -> tuple[int, int]:
        c = self.client
        offset = list(collision_offset)
        vertices = np.asarray(mesh.vertices, dtype=float)
        faces = np.asarray(mesh.faces, dtype=np.int64)
        if len(vertices) <= _MAX_MESH_VERTICES and faces.size <= _MAX_MESH_INDICES:
            indices = faces.reshape(-1).tolist()
            col = c.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices.tolist(),
                                         indices=indices, collisionFramePosition=offset,
                                         flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH)
            vis = c.createVisualShape(pybullet.GEOM_MESH, vertices=vertices.tolist(),
                                      indices=indices,
                                      normals=np.asarray(mesh.vertex_normals).tolist(),
                                      rgbaColor=list(rgba), specularColor=[0.1, 0.1, 0.1])
            return vis, col
        # Large meshes go through a temporary OBJ file (vertex arrays are size-limited).
        handle, path = tempfile.mkstemp(suffix='.obj')
        os.close(handle)
        try:
            mesh.export(path)
            col = c.createCollisionShape(pybullet.GEOM_MESH, fileName=path,
                                         collisionFramePosition=offset,
                                         flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH)
            vis = c.createVisualShape(pybullet.GEOM_MESH, fileName=path, rgbaColor=list(rgba),
                                      specularColor=[0.1, 0.1, 0.1])
        finally:
            os.remove(path)
        return vis, col

    def _build_phantom(self) -> int:
        c = self.client
        margin = self.config.phantom_collision_margin
        # Bullet keeps concave meshes ``margin`` apart from what touches them; lowering the
        # collision mesh by the margin puts resting objects on the visible top surface.
        vis, col = self._mesh_shapes(self.phantom.mesh, self.phantom.rgba, (0.0, 0.0, -margin))
        T = self.phantom.T_world_phantom
        body = c.createMultiBody(0.0, col, vis, T[:3, 3].tolist(),
                                 quaternion_from_matrix(T[:3, :3]).tolist())
        c.changeDynamics(body, -1, collisionMargin=margin)
        c.setCollisionFilterGroupMask(body, -1, GROUP_ENVIRONMENT, GROUP_NEEDLE)
        return body

    def _build_markers(self) -> dict[str, int]:
        c = self.client
        r = self.phantom.marker_radius
        thick = self.config.marker_thickness
        vis = c.createVisualShape(pybullet.GEOM_CYLINDER, radius=r, length=thick,
                                  rgbaColor=list(self.phantom.marker_rgba))
        bodies: dict[str, int] = {}
        for pair in self.phantom.markers.values():
            for which, point, normal in (('entry', pair.entry, pair.entry_normal),
                                         ('exit', pair.exit, pair.exit_normal)):
                z = normal / np.linalg.norm(normal)
                R = Rotation.align_vectors([z], [[0.0, 0.0, 1.0]])[0].as_matrix()
                centre = point + 0.5 * thick * z
                bodies[f'{pair.name}.{which}'] = c.createMultiBody(
                    0.0, -1, vis, centre.tolist(), quaternion_from_matrix(R).tolist())
        return bodies

    def _build_needle(self) -> int:
        c = self.client
        cfg = self.config
        g = self.needle
        pts = g.arc_points(cfg.needle_segments + 1)
        r = 0.5 * g.wire_diameter
        parts = []
        for a, b in zip(pts[:-1], pts[1:]):
            axis = b - a
            length = float(np.linalg.norm(axis))
            R = Rotation.align_vectors([axis / length], [[0.0, 0.0, 1.0]])[0]
            parts.append((pybullet.GEOM_CAPSULE, {'radius': r, 'height': length},
                          (0.5 * (a + b)).tolist(), R.as_quat().tolist()))
        _, col = self._build_compound(parts, cfg.needle_rgba)
        vertices, normals, indices = _wire_mesh(g)
        vis = c.createVisualShape(pybullet.GEOM_MESH, vertices=vertices.tolist(),
                                  indices=indices, normals=normals.tolist(),
                                  rgbaColor=list(cfg.needle_rgba))
        com, axes, moments = _arc_mass_properties(g.arc_points(64), g.mass)
        self._T_needle_com = np.eye(4)
        self._T_needle_com[:3, :3] = axes
        self._T_needle_com[:3, 3] = com
        self._T_com_needle = invert_transform(self._T_needle_com)
        body = c.createMultiBody(g.mass, col, vis, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0],
                                 baseInertialFramePosition=com.tolist(),
                                 baseInertialFrameOrientation=quaternion_from_matrix(axes).tolist())
        c.changeDynamics(body, -1, localInertiaDiagonal=moments.tolist(),
                         lateralFriction=cfg.needle_friction, restitution=cfg.needle_restitution,
                         linearDamping=0.0, angularDamping=0.0,
                         ccdSweptSphereRadius=0.8 * r, contactProcessingThreshold=0.0)
        self.set_needle_collisions(False)
        return body

    def _build_thread(self) -> list[int]:
        c = self.client
        t = self.thread
        n = t.n_segments
        seg = t.length / n
        vis = c.createVisualShape(pybullet.GEOM_CAPSULE, radius=t.radius,
                                  length=max(seg - 2.0 * t.radius, 1e-5),
                                  rgbaColor=list(self.config.thread_rgba))
        positions = [[0.0, 0.0, -1.0 - 0.01 * i] for i in range(n)]
        ids = c.createMultiBody(0.0, -1, vis, batchPositions=positions)
        return list(ids) if isinstance(ids, (list, tuple)) else [ids]

    # ------------------------------------------------------------------ arms
    @property
    def arm_names(self) -> tuple[str, ...]:
        """Arm names, tuple of str."""
        return tuple(self.arm_body)

    def set_arm_joints(self, name: str, q: Sequence[float] | np.ndarray,
                       jaw: float | None = None) -> None:
        """
        Place an arm at joint values ``q`` (and jaw angle ``jaw`` for a PSM).

        Parameters
        ----------
        name : str
            Arm name.
        q : array_like, shape (n,)
            DH joint values (rad / m).
        jaw : float, optional
            Full jaw opening angle (rad); each jaw link turns by half of it.

        """
        dof = self._dof[name]
        values = [[float(v)] for v in q]
        if len(dof) > len(values):
            half = 0.5 * float(jaw or 0.0)
            values += [[half], [-half]]
        self.client.resetJointStatesMultiDof(self.arm_body[name], dof, values)

    def link_poses(self, name: str) -> np.ndarray:
        """
        World poses of every link of an arm, as PyBullet computes them.

        Parameters
        ----------
        name : str
            Arm name.

        Returns
        -------
        ndarray, shape (n_links, 4, 4)
            Link frames in ``world``, in :attr:`link_index` order.

        """
        body = self.arm_body[name]
        n = self.client.getNumJoints(body)
        states = self.client.getLinkStates(body, list(range(n)), computeForwardKinematics=1)
        return np.stack([transform_from_bullet(s[4], s[5]) for s in states])

    def tool_tip_pose(self, name: str) -> np.ndarray:
        """
        World pose of an arm's tool tip (``measured_cp`` frame) from PyBullet.

        Parameters
        ----------
        name : str
            Arm name.

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_world_tip``.

        """
        s = self.client.getLinkState(self.arm_body[name], self.link_index[name]['tip'],
                                     computeForwardKinematics=1)
        return transform_from_bullet(s[4], s[5])

    def instrument_points(self, name: str, q: ArrayLike, jaw: float) -> np.ndarray:
        """
        Points on a PSM instrument's end that can touch tissue, from the DH chain (no PyBullet).

        Parameters
        ----------
        name : str
            PSM name.
        q : array_like, shape (6,)
            Joint values (rad / m).
        jaw : float
            Jaw opening angle (rad).

        Returns
        -------
        ndarray, shape (7, 3)
            ``world`` points (m): the two jaw tips, the jaw middles, the hinge (tool tip), the
            wrist-pitch axis point and the shaft end one shaft radius behind it.

        """
        chain = self.kinematics[name]
        shape = self.config.instrument
        link4, tip = chain.fk_wrist_and_tip(q, 4)
        T_world_base = self.T_world_base[name]
        link4 = T_world_base @ link4
        tip = T_world_base @ tip
        R = tip[:3, :3]
        hinge = tip[:3, 3]
        half = 0.5 * float(jaw)
        c, s = math.cos(half), math.sin(half)
        # each jaw turns by half the opening about tool x, towards -y (jaw_a) and +y (jaw_b)
        dir_a = R @ np.array([0.0, -s, c])
        dir_b = R @ np.array([0.0, s, c])
        L = shape.jaw_length
        wrist = link4[:3, 3]
        shaft_end = wrist - shape.shaft_radius * link4[:3, 2]
        return np.array([hinge + L * dir_a, hinge + L * dir_b, hinge + 0.5 * L * dir_a,
                         hinge + 0.5 * L * dir_b, hinge, wrist, shaft_end])

    # ------------------------------------------------------------------ needle
    def set_needle_collisions(self, enabled: bool) -> None:
        """
        Let the needle touch the table and phantom (a free needle) or nothing (held, in tissue).

        Parameters
        ----------
        enabled : bool
            Whether the needle collides.

        """
        body = getattr(self, 'needle_body', None)
        if body is None:
            return
        mask = GROUP_ENVIRONMENT if enabled else GROUP_NONE
        self.client.setCollisionFilterGroupMask(body, -1, GROUP_NEEDLE, mask)

    def set_needle_pose(self, T_world_needle: ArrayLike,
                        linear_velocity: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
                        angular_velocity: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0)
                        ) -> None:
        """
        Place the needle (and set its velocity, used when it becomes free).

        Parameters
        ----------
        T_world_needle : array_like, shape (4, 4)
            Needle frame in ``world``.
        linear_velocity : array_like, shape (3,)
            Velocity (m/s, world) of the needle frame origin.
        angular_velocity : array_like, shape (3,)
            Angular velocity (rad/s, world).

        """
        T = np.asarray(T_world_needle, dtype=float) @ self._T_needle_com
        c = self.client
        c.resetBasePositionAndOrientation(self.needle_body, T[:3, 3].tolist(),
                                          quaternion_from_matrix(T[:3, :3]).tolist())
        wx, wy, wz = (float(x) for x in angular_velocity)
        rx, ry, rz = (T[:3, 3] - np.asarray(T_world_needle, dtype=float)[:3, 3]).tolist()
        vx, vy, vz = (float(x) for x in linear_velocity)
        # v + w x r, written out (the products and differences np.cross forms)
        c.resetBaseVelocity(self.needle_body,
                            [vx + (wy * rz - wz * ry), vy + (wz * rx - wx * rz),
                             vz + (wx * ry - wy * rx)], [wx, wy, wz])

    def needle_pose(self) -> np.ndarray:
        """
        Needle frame in ``world`` as PyBullet has it.

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_world_needle``.

        """
        pos, quat = self.client.getBasePositionAndOrientation(self.needle_body)
        return transform_from_bullet(pos, quat) @ self._T_com_needle

    def needle_speed(self) -> tuple[float, float]:
        """
        Linear (m/s) and angular (rad/s) speed of the needle body.

        Returns
        -------
        tuple of float
            ``(linear, angular)``.

        """
        v, w = self.client.getBaseVelocity(self.needle_body)
        return float(np.linalg.norm(v)), float(np.linalg.norm(w))

    # ------------------------------------------------------------------ thread
    def set_thread_points(self, points: ArrayLike) -> None:
        """
        Draw the thread capsules between consecutive points.

        Parameters
        ----------
        points : array_like, shape (n_segments + 1, 3)
            Thread node positions (m, ``world``).

        """
        p = np.asarray(points, dtype=float)
        a, b = p[:-1], p[1:]
        mid = 0.5 * (a + b)
        d = b - a
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        # Shortest-arc quaternion taking +z to d (x, y, z, w).
        w = 1.0 + d[:, 2]
        quat = np.column_stack([-d[:, 1], d[:, 0], np.zeros(len(d)), w])
        flip = w < 1e-9
        quat[flip] = [1.0, 0.0, 0.0, 0.0]
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
        c = self.client
        for body, pos, q in zip(self.thread_bodies, mid.tolist(), quat.tolist()):
            c.resetBasePositionAndOrientation(body, pos, q)

    # ------------------------------------------------------------------ physics
    def step(self) -> None:
        """Advance the physics by one fixed step (only the free needle moves)."""
        self.client.stepSimulation()

    def support_height(self, xy: ArrayLike) -> np.ndarray:
        """
        Height (m, world) of the support below world x-y points: phantom top or table.

        Parameters
        ----------
        xy : array_like, shape (n, 2)
            World x-y positions (m).

        Returns
        -------
        ndarray, shape (n,)
            Support heights (m, world).

        """
        xy = np.asarray(xy, dtype=float)
        pts = np.column_stack([xy, np.full(len(xy), self.table_height)])
        local = self.phantom.to_phantom(pts)
        surface = self.phantom.surface
        top = surface.height(local[:, :2])
        inside = surface.contains(np.column_stack([local[:, :2], top - 1e-9]))
        T = self.phantom.T_world_phantom
        # Phantom top in world z (the phantom is upright: its z is close to world z).
        top_world = (local[:, :2] @ T[2, :2]) + top * T[2, 2] + T[2, 3]
        return np.where(inside, np.maximum(top_world, self.table_height), self.table_height)
