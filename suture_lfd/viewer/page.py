"""
The viewer's page: a viser server with the scene, an events panel and plug-in panels.

:class:`ViewerPage` owns the :class:`viser.ViserServer` (bound to ``127.0.0.1`` unless told
otherwise: the page accepts control input) and the :class:`~suture_lfd.viewer.scene.SceneView`.
Panels that are not the scene (the virtual MTMs' input, the replay controls) plug in through
:meth:`ViewerPage.add_panel`: a panel is any object with ``attach(page)``; it builds its own
GUI elements and callbacks and never touches the scene code.

Two views, one click apart (the ``View`` button): ``free``, an orbit camera starting front right
of the pad, and ``endoscope``, the surgeon's view: the page's camera at the ECM's left camera
(:meth:`ViewerPage.set_endoscope`: its optical frame and vertical field of view), following it
as it moves and put back there when the mouse orbits away from it.
"""

from collections.abc import Iterable
import json
import logging
import math
import threading
import time
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import matrix_from_quaternion
from suture_lfd.viewer.scene import SceneView
import viser

if TYPE_CHECKING:
    from sim_bridge.scene.phantom import Phantom

LOG = logging.getLogger(__name__)
DEFAULT_HOST = '127.0.0.1'
DEFAULT_PORT = 8080
EVENT_LINES = 12  # events shown in the side panel, newest first
NEAR = 0.002  # m, the page camera's near plane (the scene is a few cm across)
# The page's first view (world, m, rad): front right, above the pad, clear of the ECM's shaft.
CAMERA_POSITION = (0.09, -0.10, 0.10)
CAMERA_LOOK_AT = (0.0, 0.0, 0.0)
CAMERA_FOV = np.radians(45.0)
VIEWS = ('endoscope', 'free')
LOOK_DISTANCE = 0.08  # m, the orbit centre ahead of the endoscope (its working distance)
REASSERT_PERIOD = 0.5  # s between two checks that a page still looks through the endoscope
CLIP_AHEAD = 0.003  # m ahead of the endoscope where the lines are cut in its view
Vec3 = tuple[float, float, float]  # viser's type of a camera's position and directions


def page_url(host: str, port: int) -> str:
    """Return the address a local browser opens for a server bound to ``host``:``port``."""
    shown = '127.0.0.1' if host in ('0.0.0.0', '', '::') else host
    if ':' in shown:
        shown = f'[{shown}]'
    return f'http://{shown}:{port}/'


def format_event(t: float, event: dict[str, Any]) -> str:
    """One line (markdown) of the events panel: ``"12.34 s **grasp** arm=PSM2"``."""
    extra = '  '.join(f'{k}={_short(v)}' for k, v in event.items() if k not in ('kind', 't'))
    return f'{t:.2f} s **{event.get("kind", "?")}** {extra}'.rstrip()


def slip_label(event: dict[str, Any]) -> str:
    """Return the label of a slip event at the jaw: ``"slip 4.2 deg"`` (``", grasp broken"``)."""
    text = f'slip {math.degrees(abs(float(event.get("angle", 0.0)))):.1f} deg'
    slide = abs(float(event.get('slide', 0.0)))
    if slide >= 1e-4:
        text += f', {1e3 * slide:.1f} mm'
    return text + (', grasp broken' if event.get('broken') else '')


def _short(value: object) -> str:
    if isinstance(value, float):
        return f'{value:.3g}'
    if isinstance(value, (list, dict)):
        text = json.dumps(value)
        return text if len(text) <= 40 else text[:37] + '...'
    return str(value)


class Panel(Protocol):
    """A page panel: builds its own GUI elements and callbacks when attached to the page."""

    def attach(self, page: 'ViewerPage') -> None:
        """Build the panel's GUI elements on ``page``."""


PanelT = TypeVar('PanelT', bound=Panel)


class ViewerPage:
    """
    A viser page with the 3-D scene and a side panel of scene events.

    Parameters
    ----------
    needle_points : array_like, shape (n, 3)
        Needle arc in the ``needle`` frame (m).
    needle_diameter : float
        Needle wire diameter (m).
    host : str
        Interface to bind (``127.0.0.1``: this machine only).
    port : int
        TCP port (0: any free port).
    title : str
        Title shown in the page's title bar.
    view : str
        The first view, ``free`` or ``endoscope`` (:data:`VIEWS`).

    Attributes
    ----------
    server : viser.ViserServer
    scene : SceneView
    url : str
        Address to open in a browser on this machine.

    """

    def __init__(self, needle_points: ArrayLike, needle_diameter: float = 0.001,
                 host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 title: str = 'suture_lfd viewer', view: str = 'free') -> None:
        if view not in VIEWS:
            raise ValueError(f'view must be one of {VIEWS}, got {view!r}')
        if port == 0:
            port = _free_port(host)
        self.server = viser.ViserServer(host=host, port=port, label=title, verbose=False)
        self.host = host
        self.port = self.server.get_port()
        self.url = page_url(host, self.port)
        self.server.gui.configure_theme(control_width='medium',
                                        show_logo=False, show_share_button=False,
                                        titlebar_content=None)
        self.scene = SceneView(self.server.scene, needle_points, needle_diameter)
        self.view = view
        # (position, look_at, up, fov) of the ECM's left camera
        self._endoscope: tuple[Any, Any, Any, float] | None = None
        self._checked = 0.0
        self.set_camera()
        self._view_button = self.server.gui.add_button(self._view_label(), color='blue')
        self._view_button.on_click(lambda _event: self.set_view(
            'free' if self.view == 'endoscope' else 'endoscope'))
        self.server.scene.add_grid('/grid', width=0.4, height=0.4, cell_size=0.02,
                                   section_size=0.1, position=(0.0, 0.0, -0.0005))
        self._events: list[str] = []
        self._events_lock = threading.Lock()
        self._events_dirty = False
        # below the panels: a growing list must not move the controls under the mouse
        with self.server.gui.add_folder('Scene events', order=1e6):
            self._events_md = self.server.gui.add_markdown('_no event yet_')
        self.status = self.server.gui.add_markdown('')
        self.panels: list[Panel] = []

    def show_phantom(self, phantom: 'Phantom') -> None:
        """Draw a :class:`sim_bridge.phantom.Phantom` (mesh, colour, marker size)."""
        self.scene.set_phantom(phantom.mesh.vertices, phantom.mesh.faces,
                               phantom.T_world_phantom, phantom.rgba)
        self.scene.set_marker_radius(phantom.marker_radius)

    def set_camera(self, position: Iterable[float] = CAMERA_POSITION,
                   look_at: Iterable[float] = CAMERA_LOOK_AT,
                   up: Iterable[float] = (0.0, 0.0, 1.0),
                   fov: float = CAMERA_FOV) -> None:
        """Camera of every page opened from now on (and of the open ones): world, m, rad."""
        camera = self.server.initial_camera
        camera.position = cast(Vec3, tuple(map(float, position)))
        camera.look_at = cast(Vec3, tuple(map(float, look_at)))
        camera.up = cast(Vec3, tuple(map(float, up)))
        camera.fov = float(fov)
        camera.near = NEAR
        for client in self.server.get_clients().values():
            client.camera.position = cast(Vec3, tuple(map(float, position)))
            client.camera.look_at = cast(Vec3, tuple(map(float, look_at)))
            client.camera.up_direction = cast(Vec3, tuple(map(float, up)))
            client.camera.fov = float(fov)

    def _view_label(self) -> str:
        return 'View: free 3-D' if self.view == 'endoscope' else 'View: endoscope'

    def set_view(self, view: str) -> None:
        """Look through the endoscope (``endoscope``) or orbit freely (``free``)."""
        if view not in VIEWS:
            raise ValueError(f'view must be one of {VIEWS}, got {view!r}')
        self.view = view
        self._view_button.label = self._view_label()
        if view == 'free':
            self.scene.set_clip_plane(None)
            self.scene.show_ecm(True)
            self.set_camera()
        elif self._endoscope is not None:
            self.set_camera(*self._endoscope)

    def set_endoscope(self, T_world_optical: ArrayLike, fov: float) -> None:
        """
        Take the ECM's left camera: its optical frame (4x4, ``world``; x right, y down, z ahead).

        ``fov`` is the camera model's vertical field of view (rad). In the ``endoscope`` view
        every page looks through it; call it again whenever the ECM moves.
        """
        T = np.asarray(T_world_optical, float)
        position = T[:3, 3]
        pose: tuple[Any, Any, Any, float] = (
            position, position + LOOK_DISTANCE * T[:3, 2], -T[:3, 1], float(fov))
        moved = self._endoscope is None or not all(
            np.allclose(a, b, atol=1e-6) for a, b in zip(pose, self._endoscope))
        self._endoscope = pose
        if self.view != 'endoscope':
            return
        self.scene.set_clip_plane(position + CLIP_AHEAD * T[:3, 2], T[:3, 2])
        self.scene.show_ecm(False)      # the camera does not see itself
        now = time.monotonic()
        if moved:
            self.set_camera(*pose)
            self._checked = now
        elif now - self._checked >= REASSERT_PERIOD:
            self._checked = now
            self._reassert()

    def _reassert(self) -> None:
        """Put back a page whose camera left the endoscope (an orbit with the mouse)."""
        assert self._endoscope is not None  # set by set_endoscope() before it calls this
        position, look_at, up, fov = self._endoscope
        for client in self.server.get_clients().values():
            try:
                off = np.linalg.norm(np.asarray(client.camera.position) - position)
                R = np.asarray(matrix_from_quaternion(_xyzw(client.camera.wxyz)))
            except AssertionError:  # no camera message from this browser yet
                continue
            if off > 1e-4 or float(R[:, 2] @ (look_at - position)) < 0.999 * LOOK_DISTANCE:
                client.camera.position = cast(Vec3, tuple(map(float, position)))
                client.camera.look_at = cast(Vec3, tuple(map(float, look_at)))
                client.camera.up_direction = cast(Vec3, tuple(map(float, up)))
                client.camera.fov = fov

    def add_panel(self, panel: PanelT) -> PanelT:
        """Plug a panel (an object with ``attach(page)``) into the page; returns the panel."""
        panel.attach(self)
        self.panels.append(panel)
        return panel

    def add_event(self, t: float, event: dict[str, Any]) -> None:
        """Record a scene event ``(t s, {"kind": ...})`` for the side panel (any thread)."""
        with self._events_lock:
            self._events.append(format_event(t, event))
            del self._events[:-200]
            self._events_dirty = True
        if event.get('kind') == 'slip' and event.get('arm'):
            self.scene.mark_slip(str(event['arm']), slip_label(event))

    def clear_events(self) -> None:
        """Empty the events panel (a replay seeking backwards)."""
        with self._events_lock:
            self._events = []
            self._events_dirty = True
        self.scene.clear_slips()

    def render(self) -> bool:
        """Send what changed (scene and events panel); returns whether the scene changed."""
        with self._events_lock:
            text = None
            if self._events_dirty:
                lines = self._events[-EVENT_LINES:][::-1]
                text = '  \n'.join(lines) if lines else '_no event yet_'
                self._events_dirty = False
        if text is not None:
            self._events_md.content = text
        return self.scene.render()

    def connected_clients(self) -> int:
        """Return the number of browsers connected."""
        return len(self.server.get_clients())

    def client_cameras(self) -> list[dict[str, Any]]:
        """
        Return the camera of each connected browser (what it reported last).

        Returns
        -------
        list of dict
            ``position`` (m, world), ``wxyz`` (OpenCV convention: +z forward, +y down),
            ``fov`` (vertical, rad), ``width``, ``height`` (px of the 3-D view).

        """
        cameras = []
        for client in self.server.get_clients().values():
            camera = client.camera
            try:
                cameras.append({'position': [float(v) for v in camera.position],
                                'wxyz': [float(v) for v in camera.wxyz],
                                'fov': float(camera.fov), 'width': int(camera.image_width),
                                'height': int(camera.image_height)})
            except AssertionError:  # no camera message from this browser yet
                continue
        return cameras

    def close(self) -> None:
        """Stop the server."""
        self.server.stop()


def _xyzw(wxyz: Iterable[float]) -> tuple[float, float, float, float]:
    w, x, y, z = (float(v) for v in wxyz)
    return (x, y, z, w)


def _free_port(host: str) -> int:
    import socket
    with socket.socket() as sock:
        sock.bind((host if host not in ('', '::') else '127.0.0.1', 0))
        return sock.getsockname()[1]


class FrameClock:
    """Counts rendered frames; :meth:`rate` gives frames per second over the last period."""

    def __init__(self) -> None:
        self._t0 = time.monotonic()
        self._n0 = 0
        self.frames = 0
        self.last_rate = 0.0

    def tick(self, rendered: bool) -> None:
        """Count one render call (``rendered``: whether it sent something)."""
        if rendered:
            self.frames += 1

    def rate(self) -> float:
        """Frames per second since the previous call."""
        now = time.monotonic()
        dt = now - self._t0
        if dt > 0:
            self.last_rate = (self.frames - self._n0) / dt
        self._t0, self._n0 = now, self.frames
        return self.last_rate
