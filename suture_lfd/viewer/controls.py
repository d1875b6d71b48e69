"""
The virtual MTMs' browser input: a 6-DOF handle and a gripper slider per MTM, the pedals.

A page panel (:meth:`suture_lfd.viewer.page.ViewerPage.add_panel`) that reports what the person
does through three callbacks and knows nothing of teleoperation or ROS:

- ``on_pose(mtm, T_world_handle)``: the handle's pose (4x4, ``world``, m) on every change
  (the page sends a dragged handle's pose at its frame rate);
- ``on_gripper(mtm, angle)``: gripper opening angle (rad, 0 ... :data:`GRIPPER_MAX`);
- ``on_pedals(clutch, coag)``: the pedal state (1 = pressed) on every change.

Each MTM's handle starts at the tool pose of its PSM (:data:`PSM_OF_MTM`: MTMR drives PSM1,
MTML PSM2) once :meth:`MtmControls.place` gives it. The pedals are toggles: a click on the
``Clutch`` or ``Coag`` button, or its key (:data:`HOTKEYS`, case-insensitive, also listed in
the page's command palette, Ctrl+K), presses a released pedal and releases a pressed one.
"""

import math
import threading

import numpy as np
from sim_bridge.geometry import matrix_from_quaternion
from suture_lfd.viewer.scene import wxyz_from_matrix

PSM_OF_MTM = {'MTMR': 'PSM1', 'MTML': 'PSM2'}
GRIPPER_MAX = math.radians(60.0)  # rad, the MTM gripper's opening range
HOTKEYS = {'clutch': 'C', 'coag': 'V'}
HANDLE_SCALE = 0.025  # m, size of the drawn handle


def _matrix(position, wxyz):
    T = np.eye(4)
    w, x, y, z = (float(v) for v in wxyz)
    T[:3, :3] = matrix_from_quaternion((x, y, z, w))
    T[:3, 3] = np.asarray(position, dtype=float)
    return T


class MtmControls:
    """
    Handles, gripper sliders and pedal buttons of the virtual MTMs on the page.

    Parameters
    ----------
    mtms : sequence of str
        MTM names (``MTML``, ``MTMR``); one handle and one slider each.
    on_pose, on_gripper, on_pedals : callable, optional
        Called from the page's threads, see the module docstring.

    Attributes
    ----------
    pedals : dict
        ``{'clutch': 0|1, 'coag': 0|1}``, the current state.

    """

    def __init__(self, mtms=('MTML', 'MTMR'), on_pose=None, on_gripper=None, on_pedals=None):
        unknown = [m for m in mtms if not m]
        if unknown or len(set(mtms)) != len(mtms):
            raise ValueError(f'mtms must be distinct non-empty names, got {list(mtms)}')
        self.mtms = tuple(mtms)
        self._on_pose = on_pose or (lambda mtm, T: None)
        self._on_gripper = on_gripper or (lambda mtm, angle: None)
        self._on_pedals = on_pedals or (lambda clutch, coag: None)
        self.pedals = {'clutch': 0, 'coag': 0}
        self._lock = threading.Lock()
        self.handles = {}
        self.sliders = {}
        self.buttons = {}
        self.commands = {}
        self._placed = set()
        self._moved = set()

    def attach(self, page):
        """Build the handles, sliders, buttons and key bindings on ``page``."""
        server = page.server
        with server.gui.add_folder('Virtual MTMs'):
            for mtm in self.mtms:
                handle = server.scene.add_transform_controls(
                    f'/mtm/{mtm}', scale=HANDLE_SCALE, line_width=2.0, depth_test=False,
                    visible=False)
                handle.on_update(self._pose_callback(mtm))
                self.handles[mtm] = handle
                slider = server.gui.add_slider(
                    f'{mtm} gripper (deg)', min=0.0, max=math.degrees(GRIPPER_MAX), step=0.5,
                    initial_value=0.0)
                slider.on_update(self._gripper_callback(mtm, slider))
                self.sliders[mtm] = slider
            for pedal, key in HOTKEYS.items():
                button = server.gui.add_button(f'{pedal.capitalize()} ({key})', color='gray')
                button.on_click(self._toggle_callback(pedal))
                self.buttons[pedal] = button
                command = server.gui.add_command(
                    f'Toggle {pedal}', description=f'press or release the {pedal} pedal',
                    hotkey=key)
                command.on_trigger(self._toggle_callback(pedal))
                self.commands[pedal] = command

    def place(self, mtm, T_world_tool):
        """Put ``mtm``'s handle at a PSM tool pose (4x4, ``world``) until the user moves it."""
        handle = self.handles.get(mtm)
        if handle is None or mtm in self._moved:
            return
        handle.position = tuple(np.asarray(T_world_tool, float)[:3, 3].tolist())
        handle.wxyz = wxyz_from_matrix(T_world_tool)
        handle.visible = True
        self._placed.add(mtm)

    def placed(self, mtm):
        """Whether ``mtm``'s handle has been placed (at its PSM or by the user)."""
        return mtm in self._placed or mtm in self._moved

    def _pose_callback(self, mtm):
        def callback(event):
            handle = event.target
            self._moved.add(mtm)
            self._on_pose(mtm, _matrix(handle.position, handle.wxyz))
        return callback

    def _gripper_callback(self, mtm, slider):
        def callback(_event):
            angle = min(max(math.radians(float(slider.value)), 0.0), GRIPPER_MAX)
            self._on_gripper(mtm, angle)
        return callback

    def _toggle_callback(self, pedal):
        def callback(_event):
            with self._lock:
                self.pedals[pedal] = 1 - self.pedals[pedal]
                state = dict(self.pedals)
            self.buttons[pedal].color = 'red' if state[pedal] else 'gray'
            self._on_pedals(state['clutch'], state['coag'])
        return callback
