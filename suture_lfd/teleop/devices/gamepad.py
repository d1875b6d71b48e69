"""
The gamepad back-end: an SDL game controller through pygame drives the virtual MTMs.

SDL's game controller mapping gives every supported pad the same layout (Xbox names), so the
controls are the same on any of them:

- left stick: the active MTM moves right/left and down/up in the camera image (x, y);
- right stick: up/down moves it away from / towards the camera (z), left/right rolls it about
  the view axis; d-pad: pitch (up/down) and yaw (left/right);
- right trigger closes the active MTM's gripper, left trigger opens it (at ``gripper_speed``
  rad/s at full pull);
- left/right shoulder: make MTML / MTMR the active MTM (MTMR at start);
- A held: the clutch pedal; B: the coag pedal (operator present) on/off; Y held: the camera
  pedal (the recorder's start/stop).

Velocities are in the camera frame (optical: x right, y down, z ahead), the sticks' dead zone
is ``deadband`` of full deflection. pygame needs no window: ``SDL_VIDEODRIVER=dummy`` is set
when there is no display. :func:`attach_virtual_controller` makes an SDL virtual game
controller (no hardware), as the tests use it.
"""

from collections.abc import Sequence
import ctypes
import glob
import os
from typing import Any

import numpy as np
from suture_lfd.teleop.devices import ArmReading, InputDevice, Reading
from suture_lfd.teleop.virtual_mtm import deadband

AXIS_MAX = 32767.0


def _pygame() -> tuple[Any, Any]:
    """Import pygame headless: no window, no sound, no greeting."""
    os.environ.setdefault('PYGAME_HIDE_SUPPORT_PROMPT', '1')
    if not os.environ.get('DISPLAY') and not os.environ.get('WAYLAND_DISPLAY'):
        os.environ.setdefault('SDL_VIDEODRIVER', 'dummy')
    os.environ.setdefault('SDL_AUDIODRIVER', 'dummy')
    import pygame
    import pygame._sdl2.controller as controller
    pygame.display.init()
    pygame.joystick.init()
    controller.init()
    return pygame, controller


class GamepadDevice(InputDevice):
    """
    A game controller driving MTMs.

    Parameters
    ----------
    mtms : sequence of str
        MTM names; ``MTML``/``MTMR`` are chosen with the shoulder buttons.
    index : int
        SDL joystick index.
    linear_speed, angular_speed : float
        m/s and rad/s at full deflection.
    deadband : float
        Fraction of full deflection ignored.
    gripper_speed : float
        rad/s of the gripper at full trigger.
    gripper_start, gripper_max : float
        Gripper angle (rad) at start and its upper end (lower end: 0).

    Raises
    ------
    OSError
        If there is no game controller at ``index``.

    """

    def __init__(self, mtms: Sequence[str], index: int = 0, linear_speed: float = 0.05,
                 angular_speed: float = 1.0, deadband: float = 0.03,
                 gripper_speed: float = 1.5, gripper_start: float = 0.5,
                 gripper_max: float = 1.0471976) -> None:
        self._pg, self._ctl = _pygame()
        self._pg.event.pump()
        count = self._ctl.get_count()
        if index >= count or not self._ctl.is_controller(index):
            raise OSError(f'no SDL game controller at index {index} ({count} joysticks found; '
                          'is the pad connected, and is it one SDL maps?)')
        self.pad = self._ctl.Controller(index)
        self.mtms = tuple(mtms)
        self.active = 'MTMR' if 'MTMR' in self.mtms else self.mtms[0]
        self.linear_speed = float(linear_speed)
        self.angular_speed = float(angular_speed)
        self.deadband = float(deadband)
        self.gripper_speed = float(gripper_speed)
        self.gripper_max = float(gripper_max)
        self.grippers = {m: float(gripper_start) for m in self.mtms}
        self.coag = False
        self._b_was = False
        self._t: float | None = None

    def _axis(self, axis: int) -> float:
        return self.pad.get_axis(axis) / AXIS_MAX

    def poll(self, t: float) -> Reading:
        pg = self._pg
        pg.event.pump()
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        button = self.pad.get_button
        if button(pg.CONTROLLER_BUTTON_LEFTSHOULDER) and 'MTML' in self.mtms:
            self.active = 'MTML'
        if button(pg.CONTROLLER_BUTTON_RIGHTSHOULDER) and 'MTMR' in self.mtms:
            self.active = 'MTMR'
        b = bool(button(pg.CONTROLLER_BUTTON_B))
        if b and not self._b_was:
            self.coag = not self.coag
        self._b_was = b
        sticks = deadband([self._axis(pg.CONTROLLER_AXIS_LEFTX),
                           self._axis(pg.CONTROLLER_AXIS_LEFTY),
                           -self._axis(pg.CONTROLLER_AXIS_RIGHTY),
                           self._axis(pg.CONTROLLER_AXIS_RIGHTX)], self.deadband)
        v = self.linear_speed * sticks[:3]
        pitch = float(button(pg.CONTROLLER_BUTTON_DPAD_UP)) - \
            float(button(pg.CONTROLLER_BUTTON_DPAD_DOWN))
        yaw = float(button(pg.CONTROLLER_BUTTON_DPAD_RIGHT)) - \
            float(button(pg.CONTROLLER_BUTTON_DPAD_LEFT))
        w = self.angular_speed * np.array([pitch, yaw, sticks[3]])
        squeeze = self._axis(pg.CONTROLLER_AXIS_TRIGGERRIGHT) - \
            self._axis(pg.CONTROLLER_AXIS_TRIGGERLEFT)
        g = self.grippers[self.active] - self.gripper_speed * squeeze * dt
        self.grippers[self.active] = min(self.gripper_max, max(0.0, g))
        arms: dict[str, ArmReading] = {}
        for m in self.mtms:
            if m == self.active:
                arms[m] = ArmReading(twist=(v, w), gripper=self.grippers[m])
            else:
                arms[m] = ArmReading(twist=(np.zeros(3), np.zeros(3)), gripper=self.grippers[m])
        pedals = {'clutch': bool(button(pg.CONTROLLER_BUTTON_A)), 'coag': self.coag,
                  'camera': bool(button(pg.CONTROLLER_BUTTON_Y))}
        return Reading(arms=arms, pedals=pedals)

    def close(self) -> None:
        self.pad.quit()


class VirtualController:
    """
    An SDL virtual game controller (no hardware), set through SDL's joystick API.

    Axes and buttons are numbered as SDL's game controller enums (``pygame.CONTROLLER_*``):
    a virtual joystick of the game-controller type gets SDL's standard mapping.
    """

    def __init__(self) -> None:
        pg, ctl = _pygame()
        libs = glob.glob(os.path.join(os.path.dirname(pg.__file__), '..', 'pygame.libs',
                                      'libSDL2-2*'))
        self._sdl = ctypes.CDLL(libs[0]) if libs else ctypes.CDLL('libSDL2-2.0.so.0')
        sdl = self._sdl
        sdl.SDL_JoystickAttachVirtual.restype = ctypes.c_int
        sdl.SDL_JoystickOpen.restype = ctypes.c_void_p
        sdl.SDL_JoystickSetVirtualAxis.argtypes = [ctypes.c_void_p, ctypes.c_int,
                                                   ctypes.c_int16]
        sdl.SDL_JoystickSetVirtualButton.argtypes = [ctypes.c_void_p, ctypes.c_int,
                                                     ctypes.c_uint8]
        sdl.SDL_JoystickDetachVirtual.argtypes = [ctypes.c_int]
        sdl.SDL_JoystickClose.argtypes = [ctypes.c_void_p]
        self.index = sdl.SDL_JoystickAttachVirtual(1, 6, 15, 0)   # 1: GAMECONTROLLER
        if self.index < 0:
            raise OSError('SDL could not attach a virtual joystick')
        self._joystick = sdl.SDL_JoystickOpen(self.index)
        self._pg = pg
        pg.event.pump()

    def set_axis(self, axis: int, value: float) -> None:
        """Set a stick axis to ``value`` in [-1, 1]."""
        raw = int(max(-32768, min(32767, round(value * AXIS_MAX))))
        self._sdl.SDL_JoystickSetVirtualAxis(self._joystick, axis, raw)

    def set_trigger(self, axis: int, value: float) -> None:
        """Pull a trigger axis by ``value`` in [0, 1] (SDL maps the raw range onto it)."""
        raw = int(max(-32768, min(32767, round(-32768 + value * 65535))))
        self._sdl.SDL_JoystickSetVirtualAxis(self._joystick, axis, raw)

    def set_button(self, button: int, pressed: bool) -> None:
        """Press or release a button."""
        self._sdl.SDL_JoystickSetVirtualButton(self._joystick, button, 1 if pressed else 0)

    def close(self) -> None:
        self._sdl.SDL_JoystickClose(self._joystick)
        self._sdl.SDL_JoystickDetachVirtual(self.index)
