"""
The console on the page: a handle and a gripper slider per virtual MTM, the pedals, the state.

A page panel (:meth:`suture_lfd.viewer.page.ViewerPage.add_panel`) that reports what the person
does through callbacks and knows nothing of ROS:

- ``on_pose(mtm, T_world_handle)``: the handle's pose (4x4, ``world``, m) on every change and
  whenever the handle is put back at its tool;
- ``on_gripper(mtm, angle)``: gripper opening angle (rad, 0 ... :data:`GRIPPER_MAX`);
- ``on_pedals(clutch, coag, camera)``: the pedal state (1 = pressed) on every change.

Handles. Each MTM's handle sits at the tool of the PSM it drives (``psm_of_mtm``, MTMR drives
PSM2 and MTML PSM1 by default: each hand on its side of the endoscope image) once
:meth:`MtmControls.place` puts it there: the viewer does when the arms are homed and at every
clutch. In the default mode (``move in image``) a handle is a ball of a fixed size on screen
(:data:`GRAB_PX` radius, rescaled by :meth:`MtmControls.tick` from the page's camera) with
nothing else to catch: a drag that starts anywhere on it moves the handle in the plane of the
page's image (the endoscope's in the surgeon's view) by the pointer's motion, and never turns
or pushes it (:meth:`MtmControls.drag`). The ``Handle`` control (keys :data:`MODE_KEYS`)
switches to ``depth`` (an arrow along the view) or ``rotate`` (rings), gizmos of
:data:`HANDLE_PX` on screen shown in place of the ball. The pose sent keeps the orientation the
person gave in ``rotate`` mode whatever the mode shows.

Pedals. ``Clutch`` is pressed only while held: the button held down with the mouse, or key C
held (key repeat ignored; a page script turns key down and up into the button's press and
release); if the page stops saying it is held for :data:`HOLD_TIMEOUT` s (a lost pointer), it
is released. The page sends its controls' messages at most once per 50 ms and keeps only the
latest, so a tap (press and release within 50 ms) may arrive as its release alone: a release
with no press before it counts as a tap, the clutch pressed and released at once. The page's
clutch callbacks run on the page server's event loop, in the order the page sent them.

``Coag`` (key V) toggles the operator's presence; ``Record`` (key R) presses the camera pedal
once (the recorder starts or stops a bag).

Size: the handles, the clutch and the status share one lock, the placed handles and the
pedal state; split apart, each part would reach into the others' state.
"""

from collections.abc import Callable, Iterable, Sequence
import json
import math
import threading
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import matrix_from_quaternion
from suture_lfd.viewer.scene import wxyz_from_matrix

PSM_OF_MTM = {'MTMR': 'PSM2', 'MTML': 'PSM1'}
GRIPPER_MAX = math.radians(60.0)  # rad, the MTM gripper's opening range
HANDLE_PX = 110.0  # px, length of a handle's arrows on screen (depth and rotate modes)
GRAB_PX = 28.0  # px, radius on screen of a handle's ball (the default mode)
GRAB_COLOR = (250, 200, 40)  # the balls' colour, unlike the tools' (green PSM1, blue PSM2)
GRAB_OPACITY = 0.6
GRAB_RADIUS = 0.003  # m, a ball's radius until the page reports its camera
RESCALE_PERIOD = 0.25  # s between two sizings of the balls from the page's camera
HOLD_HZ = 20.0  # Hz at which a held clutch button reports it is held
HOLD_TIMEOUT = 3.0  # s without a report before a held clutch counts as released (a busy page
# can go quiet for over a second while the key is still held)
MODES = ('move in image', 'depth', 'rotate')
MODE_KEYS = {'move in image': 'M', 'depth': 'Z', 'rotate': 'T'}
HOTKEYS = {'clutch': 'C', 'coag': 'V', 'record': 'R'}
CLUTCH_LABEL = 'Clutch (hold C)'
# What to do next, per teleop state (ALIGNING depends on the coag pedal).
NEXT_ACTION = {
    None: 'start its teleop node',
    'SETTING_ARMS': 'wait: the arms are being enabled and homed',
    'ALIGNING': 'press Coag (V) and pinch the gripper (move its slider), in either order',
    'FOLLOWING': 'drag the handle (the yellow ball); hold C to clutch and bring it back',
    'CLUTCHED': 'release C to follow again',
    'DISABLED': 'the teleop is disabled',
}
NEXT_ACTION_PRESENT = 'pinch the gripper: move its slider by 5 deg or more'

# Key C held -> the clutch button held: key down (not a repeat) presses it, key up releases it,
# through the button's own pointer events (viser sends key presses only, not releases). Run once
# per page by an image that fails to load (the only way the page's HTML runs code).
_KEY_SCRIPT = (
    "if(!window.__sutureClutchKey){window.__sutureClutchKey=1;let held=false;"
    "const btn=()=>[...document.querySelectorAll('button')].find("
    "b=>b.innerText&&b.innerText.includes(LABEL));"
    "const form=e=>{const t=e.target;return t&&(t.tagName==='INPUT'||t.tagName==='TEXTAREA');};"
    "const opts=()=>({bubbles:true,cancelable:true,button:0,buttons:1,pointerId:77,"
    "pointerType:'mouse',isPrimary:true});"
    "window.addEventListener('keydown',e=>{if(e.code!=='KeyC'||e.ctrlKey||e.metaKey||form(e))"
    "return;e.preventDefault();if(e.repeat||held)return;const b=btn();if(!b)return;held=true;"
    "b.dispatchEvent(new PointerEvent('pointerdown',opts()));},true);"
    "const up=()=>{if(!held)return;held=false;const b=btn();if(!b)return;"
    "b.dispatchEvent(new PointerEvent('pointerup',{...opts(),buttons:0}));"
    "b.dispatchEvent(new MouseEvent('click',{bubbles:true,cancelable:true,button:0}));};"
    "window.addEventListener('keyup',e=>{if(e.code==='KeyC')up();},true);"
    "window.addEventListener('blur',up);}"
)


def key_script_html() -> str:
    """Return the HTML of the page element that installs the clutch key's script."""
    script = _KEY_SCRIPT.replace('LABEL', json.dumps(CLUTCH_LABEL).replace('"', "'"))
    return (f'<img alt="" src="data:image/png;base64,AA==" style="display:none" '
            f'onerror="{script}">')


def _matrix(position: ArrayLike, wxyz: Iterable[float]) -> np.ndarray:
    T = np.eye(4)
    w, x, y, z = (float(v) for v in wxyz)
    T[:3, :3] = matrix_from_quaternion((x, y, z, w))
    T[:3, 3] = np.asarray(position, dtype=float)
    return T


def next_action(state: str | None, coag: int | bool) -> str:
    """Return what the person should do next for a teleop in ``state`` (None: none seen)."""
    if state == 'ALIGNING' and coag:
        return NEXT_ACTION_PRESENT
    return NEXT_ACTION.get(state, f'teleop state {state}')


class MtmControls:
    """
    Handles, gripper sliders, pedal and record controls and the console's state on the page.

    Parameters
    ----------
    mtms : sequence of str
        MTM names (``MTML``, ``MTMR``); one handle and one slider each.
    on_pose, on_gripper, on_pedals : callable, optional
        Called from the page's threads, see the module docstring.
    psm_of_mtm : dict, optional
        The PSM each MTM drives (default :data:`PSM_OF_MTM`).
    clock : callable, optional
        Monotonic time (s), for the held clutch's timeout.

    Attributes
    ----------
    pedals : dict
        ``{'clutch': 0|1, 'coag': 0|1}``, the current state.
    mode : str
        The handles' mode, one of :data:`MODES`.

    """

    def __init__(self, mtms: Sequence[str] = ('MTML', 'MTMR'),
                 on_pose: Callable[[str, np.ndarray], None] | None = None,
                 on_gripper: Callable[[str, float], None] | None = None,
                 on_pedals: Callable[[int, int, int], None] | None = None,
                 psm_of_mtm: dict[str, str] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        unknown = [m for m in mtms if not m]
        if unknown or len(set(mtms)) != len(mtms):
            raise ValueError(f'mtms must be distinct non-empty names, got {list(mtms)}')
        self.mtms = tuple(mtms)
        self.psm_of_mtm = dict(PSM_OF_MTM if psm_of_mtm is None else psm_of_mtm)
        self._on_pose: Callable[[str, np.ndarray], None] = on_pose or (lambda mtm, T: None)
        self._on_gripper: Callable[[str, float], None] = on_gripper or (
            lambda mtm, angle: None)
        self._on_pedals: Callable[[int, int, int], None] = on_pedals or (
            lambda clutch, coag, camera: None)
        self._clock = clock
        self.pedals = {'clutch': 0, 'coag': 0}
        self.mode = MODES[0]
        self._lock = threading.RLock()
        self._last_hold = -math.inf
        self._hold_open = False     # a press seen and its release not yet (even if timed out)
        self.handles: dict[str, Any] = {}   # viser transform controls
        self.balls: dict[str, Any] = {}     # each handle's ball (the default mode)
        self._positions: dict[str, np.ndarray] = {}   # each handle's position (world, m)
        # drag under way: (handle's position, point grabbed)
        self._grabs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._radii: dict[str, float] = {}  # each ball's radius (m)
        self._rescaled = -math.inf      # when the balls were last sized (clock, s)
        self._page: Any = None
        self.sliders: dict[str, Any] = {}
        self.buttons: dict[str, Any] = {}
        self.commands: dict[str, Any] = {}
        self._R_image = np.eye(3)       # the handles' frame when not rotating: the image plane
        self._R_shown: dict[str, np.ndarray] = {}   # orientation each handle shows (world)
        self._R_user: dict[str, np.ndarray] = {}    # orientation each handle sends (world)
        self._placed: set[str] = set()
        self._states: dict[str, str] = {}           # teleop state of each MTM
        self._recording = ''
        self._status: Any = None
        self._mode_input: Any = None

    # --- building the page ---------------------------------------------------------------------

    def attach(self, page: Any) -> None:
        """Build the handles, sliders, buttons and key bindings on ``page``."""
        server = page.server
        self._page = page
        with server.gui.add_folder('Console'):
            clutch = server.gui.add_button(CLUTCH_LABEL, color='gray',
                                           hint='pressed while held (mouse or key C)')
            clutch.on_hold(self._on_clutch_hold, callback_hz=HOLD_HZ)
            clutch.on_click(self._on_clutch_click)
            self.buttons['clutch'] = clutch
            coag = server.gui.add_button(f'Coag ({HOTKEYS["coag"]})', color='gray',
                                         hint='operator present: press once, again to leave')
            coag.on_click(self._on_coag)
            self.buttons['coag'] = coag
            record = server.gui.add_button(f'Record ({HOTKEYS["record"]})', color='gray',
                                           hint='the camera pedal: starts and stops a bag')
            record.on_click(self._on_record)
            self.buttons['record'] = record
            for name, callback in (('coag', self._on_coag), ('record', self._on_record)):
                command = server.gui.add_command(
                    f'Press {name}', description=f'the {name} control', hotkey=HOTKEYS[name])
                command.on_trigger(callback)
                self.commands[name] = command
            self._mode_input = server.gui.add_dropdown('Handle', MODES, initial_value=self.mode)
            self._mode_input.on_update(lambda _event: self.set_mode(self._mode_input.value))
            for mode, key in MODE_KEYS.items():
                command = server.gui.add_command(f'Handle: {mode}', hotkey=key)
                command.on_trigger(lambda _event, m=mode: self._select_mode(m))
                self.commands[mode] = command
            for mtm in self.mtms:
                slider = server.gui.add_slider(
                    f'{mtm} gripper (deg)', min=0.0, max=math.degrees(GRIPPER_MAX), step=0.5,
                    initial_value=0.0)
                slider.on_update(self._gripper_callback(mtm, slider))
                self.sliders[mtm] = slider
            server.gui.add_html(key_script_html())
            # last: its lines change, the controls above it stay where the mouse found them
            self._status = server.gui.add_markdown(self._status_text())
        for mtm in self.mtms:
            handle = server.scene.add_transform_controls(
                f'/mtm/{mtm}', scale=HANDLE_PX, fixed=True, line_width=3.0, depth_test=False,
                visible=False, **self._mode_props(self.mode))
            handle.on_update(self._pose_callback(mtm))
            self.handles[mtm] = handle
            self.balls[mtm] = server.scene.add_icosphere(
                f'/mtm_grab/{mtm}', radius=1.0, color=GRAB_COLOR, subdivisions=2,
                scale=GRAB_RADIUS, opacity=GRAB_OPACITY, cast_shadow=False,
                receive_shadow=False, visible=False)
            self._bind_ball(mtm)

    @staticmethod
    def _mode_props(mode: str) -> dict[str, object]:
        """Return the gizmo's properties in ``mode`` (none to catch in the default mode)."""
        if mode == 'depth':
            return {'active_axes': (False, False, True), 'disable_axes': False,
                    'disable_sliders': True, 'disable_rotations': True}
        if mode == 'rotate':
            return {'active_axes': (True, True, True), 'disable_axes': True,
                    'disable_sliders': True, 'disable_rotations': False}
        return {'active_axes': (False, False, False), 'disable_axes': True,
                'disable_sliders': True, 'disable_rotations': True}

    def _bind_ball(self, mtm: str) -> None:
        """Show ``mtm``'s ball and take its drags in the default mode, the gizmo in the others."""
        ball, handle = self.balls.get(mtm), self.handles[mtm]
        placed = mtm in self._placed
        default = self.mode == MODES[0]
        handle.visible = placed and not default
        if ball is None:
            return
        ball.remove_drag_callback()
        if default:
            ball.on_drag('left')(self._drag_callback(mtm))
        ball.visible = placed and default

    def _drag_callback(self, mtm: str) -> Callable[[Any], Any]:
        async def callback(event: Any) -> None:  # async: the page's events handled in order
            self.drag(mtm, event.phase, event.start_position, event.end_position)
        return callback

    # --- what the viewer tells it --------------------------------------------------------------

    def set_image_rotation(self, R_world_image: ArrayLike) -> None:
        """Orient the handles' arrows along the endoscope image (3x3: x right, y down, z ahead)."""
        with self._lock:
            self._R_image = np.array(R_world_image, dtype=float)[:3, :3]
            if self.mode == 'rotate':
                return
            for mtm, handle in self.handles.items():
                shown = self._R_shown.get(mtm)
                if mtm in self._placed and (shown is None
                                            or not np.allclose(shown, self._R_image)):
                    self._R_shown[mtm] = self._R_image.copy()
                    handle.wxyz = wxyz_from_matrix(self._R_image)

    def place(self, mtm: str, T_world_tool: ArrayLike) -> None:
        """
        Put ``mtm``'s handle at a PSM tool pose (4x4, ``world``) and send that pose.

        The orientation sent stays the one the person gave (the tool's at the first placing).
        """
        handle = self.handles.get(mtm)
        if handle is None:
            return
        T_world_tool = np.asarray(T_world_tool, float)
        with self._lock:
            if mtm not in self._R_user:
                self._R_user[mtm] = T_world_tool[:3, :3].copy()
            self._R_shown[mtm] = self._R_image.copy() if self.mode != 'rotate' \
                else self._R_user[mtm].copy()
            self._grabs.pop(mtm, None)
            self._move_to(mtm, T_world_tool[:3, 3])
            handle.wxyz = wxyz_from_matrix(self._R_shown[mtm])
            self._placed.add(mtm)
            self._bind_ball(mtm)
            T = np.eye(4)
            T[:3, :3] = self._R_user[mtm]
            T[:3, 3] = T_world_tool[:3, 3]
        self._on_pose(mtm, T)

    def _move_to(self, mtm: str, position: ArrayLike) -> None:
        """Put ``mtm``'s gizmo and ball at ``position`` (world, m)."""
        p = self._positions[mtm] = np.array(position, dtype=float)
        xyz = (float(p[0]), float(p[1]), float(p[2]))
        self.handles[mtm].position = xyz
        ball = self.balls.get(mtm)
        if ball is not None:
            ball.position = xyz

    def drag(self, mtm: str, phase: str, grabbed: ArrayLike, pointer: ArrayLike) -> None:
        """
        Move ``mtm``'s handle by a drag of its ball, in the plane of the page's image.

        Parameters
        ----------
        mtm : str
            The MTM whose handle is dragged.
        phase : str
            ``start``, ``update`` or ``end`` (viser's drag phases).
        grabbed : array_like, shape (3,)
            The point of the ball grabbed (world, m); read at ``start``.
        pointer : array_like, shape (3,)
            The pointer on the plane through ``grabbed`` parallel to the page's image (world,
            m): the handle moves by the pointer's motion since ``start``, wherever the ball was
            grabbed, and keeps its orientation and its depth in the view.

        """
        with self._lock:
            if mtm not in self._placed or self.mode != MODES[0]:
                return
            if phase == 'start':
                self._grabs[mtm] = (self._positions[mtm].copy(),
                                    np.array(grabbed, dtype=float))
            grab = self._grabs.get(mtm)
            if grab is None:
                return
            if phase == 'end':
                del self._grabs[mtm]
            position = grab[0] + (np.array(pointer, dtype=float) - grab[1])
            self._move_to(mtm, position)
            T = np.eye(4)
            T[:3, :3] = self._R_user[mtm]
            T[:3, 3] = position
        self._on_pose(mtm, T)

    def _rescale_balls(self) -> None:
        """Keep each ball :data:`GRAB_PX` in radius on the page's screen."""
        cameras = self._page.client_cameras() if self._page is not None else []
        if not cameras:
            return
        camera = cameras[0]
        focal = 0.5 * camera['height'] / math.tan(0.5 * camera['fov'])   # px
        eye = np.asarray(camera['position'], dtype=float)
        for mtm, ball in self.balls.items():
            position = self._positions.get(mtm)
            if position is None or focal <= 0:
                continue
            radius = GRAB_PX * float(np.linalg.norm(position - eye)) / focal
            if radius > 0 and abs(radius / self._radii.get(mtm, GRAB_RADIUS) - 1.0) > 0.05:
                self._radii[mtm] = radius
                ball.scale = radius

    def placed(self, mtm: str) -> bool:
        """Whether ``mtm``'s handle has been placed at its tool."""
        return mtm in self._placed

    def set_teleop_state(self, mtm: str, state: str) -> None:
        """Show the teleop state of ``mtm``'s pair (``FOLLOWING``, ...) and the next action."""
        with self._lock:
            self._states[mtm] = state
        self._show_status()

    def set_recording(self, text: str) -> None:
        """Show the recorder's state (markdown, e.g. the bag's path)."""
        with self._lock:
            self._recording = text
        self._show_status()

    def tick(self) -> None:
        """Release a held clutch whose page stopped reporting it; size the balls (each frame)."""
        with self._lock:
            now = self._clock()
            lost = self.pedals['clutch'] and now - self._last_hold > HOLD_TIMEOUT
            if now - self._rescaled >= RESCALE_PERIOD:
                self._rescaled = now
                self._rescale_balls()
        if lost:
            self._time_out_hold()

    # --- page callbacks ------------------------------------------------------------------------

    def _status_text(self) -> str:
        lines = []
        for mtm in self.mtms:
            state = self._states.get(mtm)
            lines.append(f'**{mtm} → {self.psm_of_mtm.get(mtm, "?")}**: {state or "no teleop"}'
                         f' — {next_action(state, self.pedals["coag"])}')
        lines.append(self._recording or 'Record (R): press to start a bag')
        return '  \n'.join(lines)

    def _show_status(self) -> None:
        if self._status is not None:
            text = self._status_text()
            if self._status.content != text:
                self._status.content = text

    def _select_mode(self, mode: str) -> None:
        if self._mode_input is not None and self._mode_input.value != mode:
            self._mode_input.value = mode   # its callback sets the mode
        else:
            self.set_mode(mode)

    def set_mode(self, mode: str) -> None:
        """Switch the handles to ``mode`` (one of :data:`MODES`)."""
        if mode not in MODES:
            raise ValueError(f'handle mode must be one of {MODES}, got {mode!r}')
        with self._lock:
            if mode == self.mode:
                return
            self.mode = mode
            for mtm, handle in self.handles.items():
                for key, value in self._mode_props(mode).items():
                    setattr(handle, key, value)
                self._grabs.pop(mtm, None)
                self._bind_ball(mtm)
                if mtm not in self._placed:
                    continue
                self._R_shown[mtm] = self._R_user[mtm].copy() if mode == 'rotate' \
                    else self._R_image.copy()
                handle.wxyz = wxyz_from_matrix(self._R_shown[mtm])

    def _pose_callback(self, mtm: str) -> Callable[[Any], None]:
        def callback(event: Any) -> None:
            handle = event.target
            with self._lock:
                T = _matrix(handle.position, handle.wxyz)
                if mtm not in self._R_user:
                    self._R_user[mtm] = T[:3, :3].copy()
                if self.mode == 'rotate':
                    self._R_user[mtm] = T[:3, :3].copy()
                    self._R_shown[mtm] = T[:3, :3].copy()
                T[:3, :3] = self._R_user[mtm]
                self._positions[mtm] = T[:3, 3].copy()
                ball = self.balls.get(mtm)
                if ball is not None:
                    ball.position = tuple(float(v) for v in T[:3, 3])
                if mtm not in self._placed:
                    self._placed.add(mtm)
                    self._bind_ball(mtm)
            self._on_pose(mtm, T)
        return callback

    def _gripper_callback(self, mtm: str, slider: Any) -> Callable[[Any], None]:
        def callback(_event: Any) -> None:
            angle = min(max(math.radians(float(slider.value)), 0.0), GRIPPER_MAX)
            self._on_gripper(mtm, angle)
        return callback

    def _send_pedals(self, camera: int = 0) -> None:
        self._on_pedals(self.pedals['clutch'], self.pedals['coag'], camera)

    async def _on_clutch_hold(self, event: Any) -> None:
        # a coroutine: viser runs it on its event loop in the page's order (a thread would not)
        self.clutch_held(event)

    async def _on_clutch_click(self, event: Any) -> None:
        self.clutch_released(event)

    def clutch_held(self, _event: Any = None) -> None:
        """Press the clutch: the page says it is held (at press, then at :data:`HOLD_HZ`)."""
        with self._lock:
            self._last_hold = self._clock()
            self._hold_open = True
            if self.pedals['clutch']:
                return
            self.pedals['clutch'] = 1
            self._send_pedals()
        self.buttons['clutch'].color = 'red'

    def clutch_released(self, _event: Any = None) -> None:
        """
        Release the clutch: the page says it was let go (the click at pointer up).

        A release with no press before it is a tap whose press the page did not send: the
        clutch is pressed and released at once. The release that ends a hold already timed out
        (:meth:`tick`) changes nothing.
        """
        with self._lock:
            if not self.pedals['clutch']:
                if self._hold_open:     # the hold timed out before this release
                    self._hold_open = False
                    return
                self.pedals['clutch'] = 1
                self._send_pedals()
            self._hold_open = False
            self.pedals['clutch'] = 0
            self._send_pedals()
        self.buttons['clutch'].color = 'gray'

    def _time_out_hold(self) -> None:
        with self._lock:
            if not self.pedals['clutch']:
                return
            self.pedals['clutch'] = 0
            self._send_pedals()
        self.buttons['clutch'].color = 'gray'

    def _on_coag(self, _event: Any) -> None:
        with self._lock:
            self.pedals['coag'] = 1 - self.pedals['coag']
            self._send_pedals()
            pressed = self.pedals['coag']
        self.buttons['coag'].color = 'red' if pressed else 'gray'
        self._show_status()

    def _on_record(self, _event: Any) -> None:
        with self._lock:
            self._send_pedals(camera=1)
            self._send_pedals(camera=0)
