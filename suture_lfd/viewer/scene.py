"""
The 3-D scene of the viewer: arms, needle, thread, phantom, markers, posed from a transform tree.

Frames are those of the simulator's ``/tf`` and ``/tf_static`` (``world`` z up, metres):
``world -> <ARM>_base`` (the arm's RCM frame), ``<ARM>_base -> <ARM>`` (its ``measured_cp``),
``world -> needle``, ``world -> phantom``, ``world -> <pair>_entry|exit`` and
``ECM -> ECM_left|right_optical``. A :class:`SceneView` keeps the newest transform of each
frame (:meth:`SceneView.set_transform`, cheap, any thread) and sends what changed to the page at
:meth:`SceneView.render` (the caller's frame rate). The arms are drawn as simple shapes: the
instrument shaft from 12 cm outside the RCM to the tool tip, the tool-tip axes and, for the ECM,
its camera frustum (with the left image when one arrives). A slip of the needle in a jaw
(:meth:`SceneView.mark_slip`, from a ``slip`` event on ``sim/events``) is marked at that arm's
tool tip by an orange ball and a label for a few seconds.
"""

import threading
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import quaternion_from_matrix
from sim_bridge.common.vocabulary import ARMS

WORLD = 'world'
ARM_COLORS = {'PSM1': (40, 170, 60), 'PSM2': (40, 90, 210), 'ECM': (120, 120, 130)}
SHAFT_OUTSIDE = 0.12  # m of instrument shaft drawn outside the RCM
SHAFT_DIAMETER = 0.008  # m (an 8 mm instrument)
NEEDLE_COLOR = (200, 200, 210)
MARKER_COLOR = (220, 15, 15)
PHANTOM_COLOR = (230, 170, 160)
SLIP_COLOR = (255, 140, 0)
SLIP_SHOWN = 3.0  # s (wall time) a slip stays marked at the jaw


def wxyz_from_matrix(T: ArrayLike) -> tuple[float, float, float, float]:
    """Return the viser quaternion ``(w, x, y, z)`` of a 4x4 or 3x3 matrix."""
    x, y, z, w = quaternion_from_matrix(np.asarray(T, dtype=float)[:3, :3])
    return (float(w), float(x), float(y), float(z))


def rotation_with_z(z: ArrayLike) -> np.ndarray:
    """Return a rotation (3x3) whose third column is the unit vector ``z``."""
    axis = np.asarray(z, dtype=float)
    helper = (1.0, 0.0, 0.0) if abs(axis[0]) < 0.9 else (0.0, 1.0, 0.0)
    x = np.cross(helper, axis)
    x /= np.linalg.norm(x)
    return np.column_stack((x, np.cross(axis, x), axis))


def segments_from_strip(points: ArrayLike) -> np.ndarray:
    """Return line segments ``(n - 1, 2, 3)`` joining consecutive points ``(n, 3)``."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) < 2:
        return np.zeros((0, 2, 3))
    return np.stack((points[:-1], points[1:]), axis=1)


def clip_segments(segments: ArrayLike, plane: tuple[ArrayLike, ArrayLike] | None) -> np.ndarray:
    """
    Return the parts of line segments ``(n, 2, 3)`` in front of a plane ``(point, normal)``.

    A segment wholly behind the plane is dropped; one that crosses it is cut at it. ``plane``
    None keeps every segment.
    """
    segs = np.asarray(segments, dtype=float).reshape(-1, 2, 3)
    if plane is None or not len(segs):
        return segs
    point, normal = (np.asarray(v, dtype=float) for v in plane)
    d = (segs - point) @ normal                           # (n, 2) signed distances
    keep = (d > 0.0).any(axis=1)
    segs, d = segs[keep].copy(), d[keep]
    for end in (0, 1):
        behind = d[:, end] <= 0.0
        if behind.any():
            other = 1 - end
            s = (d[behind, other] / (d[behind, other] - d[behind, end]))[:, None]
            a, b = segs[behind, other], segs[behind, end]
            segs[behind, end] = a + s * (b - a)
    return segs


def _rgb255(rgba: ArrayLike) -> tuple[int, ...]:
    return tuple(int(round(255 * min(max(float(c), 0.0), 1.0))) for c in np.asarray(rgba)[:3])


class TransformTree:
    """
    Newest transform of each frame relative to its parent; world poses by chaining.

    Thread-safe: subscriptions write, the render loop reads.
    """

    def __init__(self) -> None:
        self._parent: dict[str, tuple[str, np.ndarray]] = {}
        self._lock = threading.Lock()
        self.version = 0

    def set(self, parent: str, child: str, T: ArrayLike) -> None:
        """Store ``T_parent_child`` (4x4, m); the version moves only when it changed."""
        T = np.array(T, dtype=float)        # a copy: the caller may reuse its array
        with self._lock:
            old = self._parent.get(child)
            if old is not None and old[0] == parent and np.array_equal(old[1], T):
                return      # a scene at rest: nothing to draw again
            self._parent[child] = (parent, T)
            self.version += 1

    def has(self, frame: str) -> bool:
        """Whether ``frame`` reaches ``world``."""
        return self.world(frame) is not None

    def world(self, frame: str) -> np.ndarray | None:
        """``T_world_frame`` (4x4) or None when the chain to ``world`` is incomplete."""
        T = np.eye(4)
        seen = 0
        with self._lock:
            while frame != WORLD:
                link = self._parent.get(frame)
                if link is None or seen > 32:
                    return None
                frame, T_parent_child = link
                T = T_parent_child @ T
                seen += 1
        return T

    def frames(self) -> list[str]:
        """Names of the frames stored."""
        with self._lock:
            return list(self._parent)


class SceneView:
    """
    The scene graph of a viser page, posed from a :class:`TransformTree`.

    Parameters
    ----------
    scene : viser.SceneApi
        ``server.scene`` of the page.
    needle_points : array_like, shape (n, 3)
        The needle's arc (wire centre line) in the ``needle`` frame (m).
    needle_diameter : float
        Wire diameter (m).

    Attributes
    ----------
    tf : TransformTree
        Transforms to draw; write them with :meth:`set_transform`.
    frames_rendered : int
        Calls of :meth:`render` that sent something.

    """

    def __init__(self, scene: Any, needle_points: ArrayLike, needle_diameter: float = 0.001
                 ) -> None:
        self.scene = scene
        self.tf = TransformTree()
        self.frames_rendered = 0
        self._lock = threading.Lock()
        self._drawn_version = -1
        self._markers: dict[str, Any] = {}
        self._lines: dict[str, Any] = {}
        # key -> (points, colour, width): redrawn on a new clip
        self._line_data: dict[str, tuple[Any, Any, float]] = {}
        # (point, normal): lines behind this plane are cut
        self._clip: tuple[np.ndarray, np.ndarray] | None = None
        self._show_ecm = True           # False when the page looks through the ECM's camera
        self._reclip = False
        self._spheres: dict[str, Any] = {}
        self._phantom: Any = None
        self._image: Any = None
        self._image_version = 0
        self._image_drawn = 0
        self._pending_lines: dict[str, Any] = {}
        self._pending_spheres: dict[str, Any] = {}
        self._handles: dict[str, Any] = {}
        self._sent: dict[Any, Any] = {}
        scene.set_up_direction('+z')
        self.needle = scene.add_line_segments(
            '/needle', segments_from_strip(needle_points), NEEDLE_COLOR,
            thickness=max(2.0 * needle_diameter, 0.0015), visible=False)
        for arm in ARMS:
            color = ARM_COLORS[arm]
            # a solid cylinder, not a thick line: the shafts pass beside and behind the
            # endoscope's camera, and only a surface is clipped right at its near plane
            self._handles[arm + '/shaft'] = scene.add_cylinder(
                f'/arms/{arm}/shaft', radius=0.5 * (SHAFT_DIAMETER if arm != 'ECM' else 0.01),
                height=SHAFT_OUTSIDE, color=color, radial_segments=16, cast_shadow=False,
                receive_shadow=False, visible=False)
            self._handles[arm + '/tool'] = scene.add_frame(
                f'/arms/{arm}/tool', axes_length=0.012, axes_radius=0.0012, origin_radius=0.0025,
                origin_color=color, visible=False)
        self._frustum: Any = None
        # arm -> (label text, wall time until which it is shown)
        self._slips: dict[str, tuple[str, float]] = {}
        self._slip_handles: dict[str, tuple[Any, Any]] = {}
        self._slips_dirty = False

    # --- inputs (any thread) -------------------------------------------------------------------

    def mark_slip(self, arm: str, text: str, shown: float = SLIP_SHOWN) -> None:
        """
        Mark the needle's slip in ``arm``'s jaw: an orange ball and a label at its tool tip.

        Parameters
        ----------
        arm : str
            The arm whose jaw the needle turned in.
        text : str
            The label (e.g. ``'slip 4.2 deg'``).
        shown : float
            Wall seconds the mark stays (a newer slip of the arm replaces it).

        """
        with self._lock:
            self._slips[arm] = (text, time.monotonic() + float(shown))
            self._slips_dirty = True

    def clear_slips(self) -> None:
        """Remove every slip mark (a replay seeking backwards)."""
        with self._lock:
            for arm in self._slips:
                self._slips[arm] = (self._slips[arm][0], 0.0)
            self._slips_dirty = True

    def set_transform(self, parent: str, child: str, T: ArrayLike) -> None:
        """Store ``T_parent_child`` (4x4, m); drawn at the next :meth:`render`."""
        self.tf.set(parent, child, T)

    def set_phantom(self, vertices: ArrayLike, faces: ArrayLike,
                    T_world_phantom: ArrayLike | None = None, rgba: ArrayLike | None = None
                    ) -> None:
        """
        Draw the phantom mesh (vertices ``(n, 3)`` in the ``phantom`` frame, faces ``(m, 3)``).

        Posed by the ``phantom`` frame of the tree (or ``T_world_phantom`` until it arrives).
        """
        color = PHANTOM_COLOR if rgba is None else _rgb255(rgba)
        if T_world_phantom is not None and not self.tf.has('phantom'):
            self.tf.set(WORLD, 'phantom', T_world_phantom)
        self._phantom = self.scene.add_mesh_simple(
            '/phantom', np.asarray(vertices, np.float32), np.asarray(faces, np.uint32),
            color=color, flat_shading=False, side='double', visible=False)
        self._drawn_version = -1

    def set_marker_radius(self, radius: float) -> None:
        """Radius (m) of the entry/exit marker spheres (from the phantom configuration)."""
        self._marker_radius = float(radius)

    def set_line_strip(self, key: str, points: ArrayLike, rgba: ArrayLike, width: float) -> None:
        """Draw (or replace) a line strip ``(n, 3)`` in ``world`` (a visualization marker)."""
        with self._lock:
            self._pending_lines[key] = (np.asarray(points, float), _rgb255(rgba), float(width))

    def set_spheres(self, key: str, points: ArrayLike, rgba: ArrayLike, diameter: float) -> None:
        """Draw (or replace) spheres at points ``(n, 3)`` in ``world`` (a visualization marker)."""
        with self._lock:
            self._pending_spheres[key] = (np.asarray(points, float), _rgb255(rgba),
                                          float(diameter))

    def set_clip_plane(self, point: ArrayLike | None = None, normal: ArrayLike | None = None
                       ) -> None:
        """
        Cut the line markers behind a plane (``world``, m; None: no plane).

        The endoscope view sets its near plane: a line passing behind the camera (the thread
        on the table) would otherwise be drawn as a wedge across the image.
        """
        plane = None if point is None else (np.asarray(point, float), np.asarray(normal, float))
        with self._lock:
            same = (plane is None and self._clip is None) or (
                plane is not None and self._clip is not None
                and all(np.allclose(a, b, atol=1e-6) for a, b in zip(plane, self._clip)))
            if not same:
                self._clip = plane
                self._reclip = True

    def show_ecm(self, shown: bool) -> None:
        """Draw the ECM (its shaft, tip axes and frustum) or not (in the endoscope view)."""
        shown = bool(shown)
        if shown != self._show_ecm:
            self._show_ecm = shown
            self._drawn_version = -1
            self._sent.clear()

    def set_image(self, rgb: ArrayLike | None) -> None:
        """Show an ECM image ``(h, w, 3)`` uint8 in the ECM's camera frustum."""
        with self._lock:
            self._image = np.asarray(rgb, np.uint8)
            self._image_version += 1

    # --- drawing (one thread) ------------------------------------------------------------------

    def render(self) -> bool:
        """
        Send the poses and shapes that changed since the last call to the page.

        Returns
        -------
        bool
            Whether anything was sent.

        """
        with self._lock:
            lines, self._pending_lines = self._pending_lines, {}
            if self._reclip:
                lines = {**self._line_data, **lines}
                self._reclip = False
            self._line_data.update(lines)
            clip = self._clip
            spheres, self._pending_spheres = self._pending_spheres, {}
            image = self._image if self._image_version != self._image_drawn else None
            self._image_drawn = self._image_version
            now = time.monotonic()
            slips_due = self._slips_dirty or any(until <= now for _, until in
                                                 self._slips.values())
            self._slips_dirty = False
            slips = dict(self._slips)
            for arm in [a for a, (_, until) in slips.items() if until <= now]:
                del self._slips[arm]
        version = self.tf.version
        if (version == self._drawn_version and not lines and not spheres and image is None
                and not slips_due):
            return False
        self._drawn_version = version
        for key, (points, color, width) in lines.items():
            self._draw_lines(key, points, color, width, clip)
        for key, (points, color, diameter) in spheres.items():
            self._draw_spheres(key, points, color, diameter)
        self._pose('phantom', self._phantom)
        self._pose('needle', self.needle)
        self._draw_markers()
        for arm in ARMS:
            self._draw_arm(arm)
        self._draw_camera(image)
        self._draw_slips(slips, now)
        self.frames_rendered += 1
        return True

    def _set_pose(self, handle: Any, T: np.ndarray) -> None:
        """Pose a node (only what changed is sent)."""
        last = self._sent.get(id(handle))
        if last is not None and np.array_equal(last, T):
            return
        self._sent[id(handle)] = T.copy()
        position = tuple(T[:3, 3].tolist())
        if tuple(handle.position) != position:
            handle.position = position
        wxyz = wxyz_from_matrix(T)
        if not np.array_equal(handle.wxyz, wxyz):
            handle.wxyz = wxyz
        if not handle.visible:
            handle.visible = True

    def _pose(self, frame: str, handle: Any) -> None:
        if handle is None:
            return
        T = self.tf.world(frame)
        if T is not None:
            self._set_pose(handle, T)

    def _draw_markers(self) -> None:
        for frame in self.tf.frames():
            if not (frame.endswith('_entry') or frame.endswith('_exit')):
                continue
            T = self.tf.world(frame)
            if T is None:
                continue
            handle = self._markers.get(frame)
            if handle is None:
                radius = getattr(self, '_marker_radius', 0.0015)
                handle = self.scene.add_icosphere(f'/markers/{frame}', radius=radius,
                                                  color=MARKER_COLOR, subdivisions=2)
                self._markers[frame] = handle
            position = tuple(T[:3, 3].tolist())
            if tuple(handle.position) != position:
                handle.position = position

    def _draw_arm(self, arm: str) -> None:
        if arm == 'ECM' and not self._show_ecm:
            for part in ('/tool', '/shaft'):
                if self._handles[arm + part].visible:
                    self._handles[arm + part].visible = False
            return
        T_tool = self.tf.world(arm)
        T_rcm = self.tf.world(f'{arm}_base')
        if T_tool is None:
            return
        self._set_pose(self._handles[arm + '/tool'], T_tool)
        if T_rcm is None:
            return
        tip = T_tool[:3, 3]
        rcm = T_rcm[:3, 3]
        axis = tip - rcm
        length = float(np.linalg.norm(axis))
        if length < 1e-6:
            return
        shaft = self._handles[arm + '/shaft']
        height = length + SHAFT_OUTSIDE
        if shaft.height != height:
            shaft.height = height
        T = np.eye(4)
        T[:3, :3] = rotation_with_z(axis / length)
        T[:3, 3] = tip - 0.5 * height * axis / length
        self._set_pose(shaft, T)

    def _draw_camera(self, image: Any) -> None:
        T = self.tf.world('ECM_left_optical')
        if T is None:
            return
        if not self._show_ecm:
            if self._frustum is not None and self._frustum.visible:
                self._frustum.visible = False
            return
        if self._frustum is None or image is not None:
            if self._frustum is not None:
                self._frustum.remove()
            aspect = 4.0 / 3.0 if image is None else image.shape[1] / image.shape[0]
            self._sent.pop(id(self._frustum), None)
            self._frustum = self.scene.add_camera_frustum(
                '/arms/ECM/camera', fov=np.radians(60.0), aspect=aspect, scale=0.02,
                color=ARM_COLORS['ECM'], thickness=0.0006, image=image, format='jpeg')
        self._set_pose(self._frustum, T)

    def _draw_lines(self, key: str, points: Any, color: Any, width: float,
                    clip: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        handle = self._lines.get(key)
        segments = clip_segments(segments_from_strip(points), clip)
        # a segment of no length has no direction: the page would draw it as a wedge
        segments = segments[np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1) > 1e-6]
        segments = segments.astype(np.float32)
        if not len(segments):
            if handle is not None:
                handle.visible = False
            return
        if handle is not None and not handle.visible:
            handle.visible = True
        if handle is None or handle.thickness != width:
            if handle is not None:
                handle.remove()
            self._lines[key] = self.scene.add_line_segments(
                f'/visualization/{key}', segments, color, thickness=max(width, 0.0005))
        else:
            handle.points = segments
            handle.colors = np.broadcast_to(np.array(color, np.uint8), segments.shape).copy()

    def _draw_slips(self, slips: dict[str, tuple[str, float]], now: float) -> None:
        """Put each live slip mark at its arm's tool tip; remove the expired ones."""
        for arm in list(self._slip_handles):
            if arm not in slips or slips[arm][1] <= now:
                for handle in self._slip_handles.pop(arm):
                    handle.remove()
        for arm, (text, until) in slips.items():
            T = self.tf.world(arm)
            if until <= now or T is None:
                continue
            position = tuple(T[:3, 3].tolist())
            handles = self._slip_handles.get(arm)
            if handles is None:
                ball = self.scene.add_icosphere(f'/slips/{arm}', radius=0.003, color=SLIP_COLOR,
                                                subdivisions=2, position=position,
                                                cast_shadow=False, receive_shadow=False)
                label = self.scene.add_label(f'/slips/{arm}_label', text, position=position,
                                             anchor='bottom-left')
                self._slip_handles[arm] = (ball, label)
                continue
            ball, label = handles
            if tuple(ball.position) != position:
                ball.position = label.position = position
            if label.text != text:
                label.text = text

    def _draw_spheres(self, key: str, points: Any, color: Any, diameter: float) -> None:
        handle = self._spheres.get(key)
        if not len(points):  # nothing to draw (a pad at rest): hide what was drawn
            if handle is not None:
                handle.remove()
                del self._spheres[key]
            return
        if handle is not None and len(handle.points) == len(points):
            handle.points = points.astype(np.float32)
            return
        if handle is not None:
            handle.remove()
        self._spheres[key] = self.scene.add_point_cloud(
            f'/visualization/{key}', points.astype(np.float32), color, point_size=diameter,
            point_shape='circle', precision='float32')
