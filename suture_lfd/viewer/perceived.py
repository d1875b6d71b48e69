"""
What perception sees, drawn beside the truth: the estimated needle and the perceived markers.

The perception node gives the needle's pose and the markers in the left camera's optical frame
(``ECM_left_optical``: x right, y down, z forward, m). :class:`PerceivedLayer` keeps the newest of
each (:meth:`PerceivedLayer.set_needle`, :meth:`PerceivedLayer.set_markers`, any thread) and, at
:meth:`PerceivedLayer.render`, places them in ``world`` through the camera frame of the scene's
:class:`~suture_lfd.viewer.scene.TransformTree` (the ECM's pose the viewer already draws). The
estimated needle is an orange arc (grey, at its last pose, while perception says "not found");
the perceived markers are small yellow spheres, a little smaller than the true red ones so that
both show where they coincide.
"""

import threading
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike
from suture_lfd.viewer.scene import segments_from_strip, wxyz_from_matrix

if TYPE_CHECKING:
    from suture_lfd.viewer.scene import TransformTree

NEEDLE_COLOR = (255, 140, 0)
LOST_COLOR = (140, 140, 140)
MARKER_COLOR = (255, 230, 0)
MARKER_SIZE = 0.0018  # m, diameter of a perceived marker's sphere


class PerceivedLayer:
    """
    The perceived needle and markers in a viser scene, posed through a transform tree.

    Parameters
    ----------
    scene : viser.SceneApi
        ``server.scene`` of the page.
    tf : suture_lfd.viewer.scene.TransformTree
        The scene's transforms (the camera frame's world pose comes from it).
    needle_points : array_like, shape (n, 3)
        The needle's arc in the ``needle`` frame (m).
    needle_diameter : float
        Wire diameter (m).

    """

    def __init__(self, scene: Any, tf: 'TransformTree', needle_points: ArrayLike,
                 needle_diameter: float = 0.001) -> None:
        self.scene = scene
        self.tf = tf
        self._lock = threading.Lock()
        # (frame, T_frame_needle) of the last pose found
        self._needle: tuple[str, np.ndarray] | None = None
        self._found = False
        self._residual: float | None = None
        self._markers: tuple[str, np.ndarray] | None = None  # (frame, points (n, 3)) in it
        self._drawn: dict[str, Any] = {}
        self.needle = scene.add_line_segments(
            '/perception/needle', segments_from_strip(needle_points), NEEDLE_COLOR,
            thickness=max(2.0 * needle_diameter, 0.0015), visible=False)
        self._n_segments = len(self.needle.points)
        self._marker_cloud: Any = None
        self._marker_world = np.zeros((0, 3))

    # --- inputs (any thread) -------------------------------------------------------------------

    def set_needle(self, frame: str, T_frame_needle: ArrayLike) -> None:
        """Take a needle pose found by perception (4x4, m, in ``frame``)."""
        with self._lock:
            self._needle = (frame, np.asarray(T_frame_needle, float))
            self._found = True

    def set_status(self, found: bool, residual_px: float | None = None) -> None:
        """Take perception's verdict: ``found`` and the fit's residual (px, None: unknown)."""
        with self._lock:
            self._found = bool(found)
            self._residual = None if residual_px is None else float(residual_px)

    def set_markers(self, frame: str, points: ArrayLike) -> None:
        """Take the perceived markers ``(n, 3)`` (m, in ``frame``; NaN rows: not seen)."""
        rows = np.asarray(points, float).reshape(-1, 3)
        with self._lock:
            self._markers = (frame, rows[np.isfinite(rows).all(axis=1)])

    # --- drawing (one thread) ------------------------------------------------------------------

    def status_text(self) -> str:
        """One markdown line for the page: found or not, and the residual."""
        with self._lock:
            found, residual, seen = self._found, self._residual, self._needle is not None
        if not seen and residual is None and not found:
            return '**perception**: no needle estimate yet'
        text = '**perception**: needle ' + ('found' if found else '_not found_')
        if residual is not None:
            text += f', residual {residual:.2f} px'
        return text

    def render(self) -> bool:
        """Send the perceived needle and markers where they moved; returns whether it sent."""
        with self._lock:
            needle, found, markers = self._needle, self._found, self._markers
        sent = False
        if needle is not None:
            T_world_frame = self.tf.world(needle[0])
            if T_world_frame is not None:
                sent |= self._draw_needle(T_world_frame @ needle[1], found)
        if markers is not None:
            T_world_frame = self.tf.world(markers[0])
            if T_world_frame is not None:
                world = markers[1] @ T_world_frame[:3, :3].T + T_world_frame[:3, 3]
                sent |= self._draw_markers(world)
        return sent

    def _draw_needle(self, T: np.ndarray, found: bool) -> bool:
        key = (T.round(7).tobytes(), found)
        if self._drawn.get('needle') == key:
            return False
        self._drawn['needle'] = key
        handle = self.needle
        handle.position = tuple(T[:3, 3].tolist())
        handle.wxyz = wxyz_from_matrix(T)
        color = NEEDLE_COLOR if found else LOST_COLOR
        handle.colors = np.broadcast_to(np.array(color, np.uint8),
                                        (self._n_segments, 2, 3)).copy()
        if not handle.visible:
            handle.visible = True
        return True

    def _draw_markers(self, world: np.ndarray) -> bool:
        key = world.round(7).tobytes()
        if self._drawn.get('markers') == key:
            return False
        self._drawn['markers'] = key
        self._marker_world = world
        if self._marker_cloud is not None and len(self._marker_cloud.points) == len(world):
            self._marker_cloud.points = world.astype(np.float32)
            return True
        if self._marker_cloud is not None:
            self._marker_cloud.remove()
        self._marker_cloud = self.scene.add_point_cloud(
            '/perception/markers', world.astype(np.float32), MARKER_COLOR,
            point_size=MARKER_SIZE, point_shape='circle', precision='float32')
        return True

    def summary(self) -> dict[str, Any]:
        """
        Return what the page shows of perception (for ``viewer/stats``).

        Returns
        -------
        dict
            ``needle``: None before a first estimate, else ``position`` (m, world), ``wxyz``
            of the drawn arc and ``found``; ``residual_px``; ``markers``: the drawn perceived
            markers (m, world).

        """
        with self._lock:
            residual = self._residual
        needle = None
        if self.needle.visible:
            needle = {'position': [float(v) for v in self.needle.position],
                      'wxyz': [float(v) for v in self.needle.wxyz],
                      'found': self._drawn['needle'][1]}
        return {'needle': needle, 'residual_px': residual,
                'markers': np.round(self._marker_world, 6).tolist()}
