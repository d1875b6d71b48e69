"""
What every input device gives and how one is opened: :class:`Reading`, :class:`InputDevice`.

A device is polled once per cycle of the virtual MTMs (:meth:`InputDevice.poll`) and returns a
:class:`Reading`: per MTM (:class:`ArmReading`) either an absolute handle pose or a velocity, in
the device's frame (:attr:`InputDevice.frame_id`), and a gripper angle; and the console's pedals.
:func:`open_device` opens a back-end by name.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

PEDALS = ('clutch', 'coag', 'camera')
CAMERA_FRAME = 'ECM'       # the ECM tip frame: optical convention, x right, y down, z ahead


@dataclass
class ArmReading:
    """
    One MTM's input in one cycle.

    Attributes
    ----------
    pose : ndarray (4, 4) or None
        Absolute handle pose (frame of the device), or None.
    twist : tuple of ndarray (3,) or None
        ``(v, w)``: linear (m/s) and angular (rad/s) velocity (frame of the device), or None.
    gripper : float or None
        Gripper opening angle (rad), or None if unchanged.

    """

    pose: Optional[np.ndarray] = None
    twist: Optional[tuple] = None
    gripper: Optional[float] = None


@dataclass
class Reading:
    """A device's input in one cycle: per MTM, and the pedals (name -> pressed)."""

    arms: dict = field(default_factory=dict)
    pedals: dict = field(default_factory=dict)


class InputDevice:
    """
    The interface of an input back-end.

    Attributes
    ----------
    frame_id : str
        Frame of the poses and velocities it gives (the MTMs' ``measured_cp`` frame).

    """

    frame_id = CAMERA_FRAME

    def poll(self, t: float) -> 'Reading':
        """Return the :class:`Reading` at time ``t`` (s)."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the device."""


def open_device(kind: str, mtms: Sequence[str], **options: Any) -> InputDevice:
    """
    Open the back-end ``kind`` (``browser``, ``gamepad`` or ``spacemouse``) for ``mtms``.

    Raises
    ------
    ValueError
        If ``kind`` is unknown.
    OSError
        If the device cannot be opened (named in the message).

    """
    if kind == 'browser':
        from suture_lfd.teleop.devices.browser import BrowserDevice
        return BrowserDevice(mtms)
    if kind == 'gamepad':
        from suture_lfd.teleop.devices.gamepad import GamepadDevice
        return GamepadDevice(mtms, **options)
    if kind == 'spacemouse':
        from suture_lfd.teleop.devices.spacemouse import SpaceMouseDevice
        return SpaceMouseDevice(mtms, **options)
    raise ValueError(f'unknown device {kind!r}; expected browser, gamepad or spacemouse')
