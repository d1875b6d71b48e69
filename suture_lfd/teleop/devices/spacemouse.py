"""
The SpaceMouse back-end: 3Dconnexion 6-DOF devices through hidapi drive the virtual MTMs.

As jhu-dvrk's PyBullet dVRK uses two SpaceNavigators as non-haptic MTMs: the device's velocity
(after a ``deadband`` of full scale, 0.03) is integrated into the MTM's pose, and the two
buttons close (left) and open (right) the gripper; both held together is the clutch; a third
button (SpaceMouse Pro and others) is the camera pedal. The operator is taken as present (coag
held) while the device is open. The first device found
drives MTMR, a second one MTML.

HID reports (little-endian int16, full scale about +-350): report 1 carries the translation
``x, y, z`` (6 bytes; 12 bytes on newer devices, with the rotation after it), report 2 the
rotation ``rx, ry, rz``, report 3 the buttons (bit i = button i). The device's axes: x right,
y towards the user, z down; in the camera frame (optical: x right, y down, z ahead) a push
away moves the tool deeper into the image, a press moves it down.

On Linux the hidraw node must be readable: the README gives the udev rule.
"""

from collections.abc import Sequence
import struct
from typing import Any

import numpy as np
from suture_lfd.teleop.devices import ArmReading, InputDevice, Reading
from suture_lfd.teleop.virtual_mtm import deadband

VENDOR_IDS = (0x046D, 0x256F)             # Logitech (older 3Dconnexion), 3Dconnexion
PRODUCT_IDS = {0xC626, 0xC627, 0xC628, 0xC62B, 0xC629, 0xC62E, 0xC62F, 0xC631, 0xC632,
               0xC635, 0xC652}
FULL_SCALE = 350.0
DEVICE_TO_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


class SpaceMouseState:
    """
    The latest axes and buttons of one device, updated report by report.

    Attributes
    ----------
    translation, rotation : ndarray, shape (3,)
        Raw device values (device axes).
    buttons : int
        Bit mask.

    """

    def __init__(self) -> None:
        self.translation = np.zeros(3)
        self.rotation = np.zeros(3)
        self.buttons = 0

    def update(self, report: bytes | Sequence[int]) -> None:
        """
        Take one HID report (bytes or list of ints, report id first).

        Raises
        ------
        ValueError
            If the report is too short for its id, or the id is unknown.

        """
        data = bytes(report)
        if not data:
            raise ValueError('empty SpaceMouse report')
        kind, body = data[0], data[1:]
        if kind == 1:
            if len(body) >= 12:
                values = struct.unpack_from('<6h', body)
                self.translation = np.array(values[:3], dtype=float)
                self.rotation = np.array(values[3:], dtype=float)
            elif len(body) >= 6:
                self.translation = np.array(struct.unpack_from('<3h', body), dtype=float)
            else:
                raise ValueError(f'SpaceMouse translation report has {len(body)} bytes, '
                                 'expected 6 or 12')
        elif kind == 2:
            if len(body) < 6:
                raise ValueError(f'SpaceMouse rotation report has {len(body)} bytes, '
                                 'expected 6')
            self.rotation = np.array(struct.unpack_from('<3h', body), dtype=float)
        elif kind == 3:
            self.buttons = int.from_bytes(body[:4], 'little') if body else 0
        else:
            raise ValueError(f'SpaceMouse report id {kind} is not 1, 2 or 3')

    def button(self, i: int) -> bool:
        """Whether button ``i`` is held."""
        return bool(self.buttons >> i & 1)

    def twist(self, linear_speed: float, angular_speed: float,
              threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(v, w)`` (m/s, rad/s) in the camera frame, after the deadband."""
        t = deadband(np.clip(self.translation / FULL_SCALE, -1, 1), threshold)
        r = deadband(np.clip(self.rotation / FULL_SCALE, -1, 1), threshold)
        return (linear_speed * (DEVICE_TO_CAMERA @ t), angular_speed * (DEVICE_TO_CAMERA @ r))


def find_devices(hid: Any) -> list[bytes]:
    """Return the hidraw paths of the 3Dconnexion devices found."""
    return [d['path'] for d in hid.enumerate()
            if d['vendor_id'] in VENDOR_IDS and d['product_id'] in PRODUCT_IDS]


class SpaceMouseDevice(InputDevice):
    """
    One or two SpaceMice driving MTMs.

    Parameters
    ----------
    mtms : sequence of str
    path : str
        hidraw path of the one device to use (``''``: all found, MTMR first).
    linear_speed, angular_speed, deadband, gripper_speed : float
        As :class:`suture_lfd.teleop.devices.gamepad.GamepadDevice`.
    gripper_start, gripper_max : float
        Gripper angle (rad) at start and its upper end (lower end: 0).

    Raises
    ------
    OSError
        If no device is found or one cannot be opened (permissions: see the README).

    """

    def __init__(self, mtms: Sequence[str], path: str | bytes = '', linear_speed: float = 0.05,
                 angular_speed: float = 1.0, deadband: float = 0.03,
                 gripper_speed: float = 1.5, gripper_start: float = 0.5,
                 gripper_max: float = 1.0471976) -> None:
        import hid
        paths = [path.encode() if isinstance(path, str) else path] if path \
            else find_devices(hid)
        if not paths:
            raise OSError('no 3Dconnexion SpaceMouse found (is it plugged in, and may this '
                          'user read its hidraw node? see the udev rule in the README)')
        order = [m for m in ('MTMR', 'MTML') if m in mtms] + \
            [m for m in mtms if m not in ('MTMR', 'MTML')]
        self.devices: dict[str, tuple[Any, SpaceMouseState]] = {}
        for mtm, p in zip(order, paths):
            dev = hid.device()
            try:
                dev.open_path(p)
            except OSError as exc:
                raise OSError(f'cannot open SpaceMouse {p!r}: {exc} (see the udev rule in '
                              'the README)') from exc
            dev.set_nonblocking(1)
            self.devices[mtm] = (dev, SpaceMouseState())
        self.mtms = tuple(mtms)
        self.linear_speed, self.angular_speed = float(linear_speed), float(angular_speed)
        self.deadband, self.gripper_speed = float(deadband), float(gripper_speed)
        self.gripper_max = float(gripper_max)
        self.grippers = {m: float(gripper_start) for m in self.mtms}
        self._t: float | None = None

    def poll(self, t: float) -> Reading:
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        arms, clutch, camera = {}, False, False
        for mtm, (dev, state) in self.devices.items():
            for _ in range(64):                   # every report waiting, newest last
                report = dev.read(64)
                if not report:
                    break
                try:
                    state.update(report)
                except ValueError:
                    continue                      # other reports (LEDs, battery) are skipped
            close, open_ = state.button(0), state.button(1)
            clutch = clutch or (close and open_)
            camera = camera or state.button(2)
            if close != open_:
                rate = self.gripper_speed if open_ else -self.gripper_speed
                g = self.grippers[mtm] + rate * dt
                self.grippers[mtm] = min(self.gripper_max, max(0.0, g))
            arms[mtm] = ArmReading(twist=state.twist(self.linear_speed, self.angular_speed,
                                                     self.deadband),
                                   gripper=self.grippers[mtm])
        return Reading(arms=arms, pedals={'clutch': clutch, 'coag': True, 'camera': camera})

    def close(self) -> None:
        for dev, _ in self.devices.values():
            dev.close()
