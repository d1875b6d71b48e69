"""
The browser back-end: the viewer page's handles drive the virtual MTMs.

The viewer node publishes, in ``world``, ``viewer/input/<MTM>/pose`` (the handle),
``viewer/input/<MTM>/gripper`` (opening angle, rad, 0..1.047) and ``viewer/input/pedals``
(``buttons = [clutch, coag, camera]``, 1 pressed); the virtual MTMs' ROS layer hands each
message to this device (:meth:`BrowserDevice.set_pose`, :meth:`set_gripper`,
:meth:`set_pedals`), which holds the latest of each for the next poll. A pedal pressed and
released between two polls (a click on the page's record control) is still seen pressed by
one poll, then released by the next. No hardware: the page works over SSH port forwarding.
"""

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike
from suture_lfd.teleop.devices import ArmReading, InputDevice, Reading

PEDAL_BUTTONS = ('clutch', 'coag', 'camera')


class BrowserDevice(InputDevice):
    """
    The viewer page's inputs.

    Parameters
    ----------
    mtms : sequence of str
        MTM names.

    """

    frame_id = 'world'

    def __init__(self, mtms: Sequence[str]) -> None:
        self.mtms = tuple(mtms)
        self._poses: dict[str, np.ndarray] = {}
        self._grippers: dict[str, float] = {}
        self._pedals: dict[str, bool] = {}
        self._pressed: set[str] = set()  # pedals pressed since the last poll

    def set_pose(self, mtm: str, T_world_handle: ArrayLike) -> None:
        """Take a handle pose (4x4, ``world``) of ``mtm``."""
        if mtm in self.mtms:
            self._poses[mtm] = np.array(T_world_handle, dtype=float)

    def set_gripper(self, mtm: str, angle: float) -> None:
        """Take a gripper angle (rad) of ``mtm``."""
        if mtm in self.mtms:
            self._grippers[mtm] = float(angle)

    def set_pedals(self, buttons: Sequence[float]) -> None:
        """
        Take the pedal buttons ``[clutch, coag]`` or ``[clutch, coag, camera]`` (1 pressed).

        Raises
        ------
        ValueError
            If there are not 2 or 3 buttons.

        """
        if len(buttons) not in (2, len(PEDAL_BUTTONS)):
            raise ValueError(f'viewer/input/pedals must have buttons [clutch, coag, camera], '
                             f'got {list(buttons)}')
        for name, b in zip(PEDAL_BUTTONS, buttons):
            self._pedals[name] = bool(b)
            if b:
                self._pressed.add(name)

    def poll(self, t: float) -> Reading:
        arms = {m: ArmReading(pose=self._poses.get(m), gripper=self._grippers.get(m))
                for m in self.mtms}
        pedals = {name: pressed or name in self._pressed for name, pressed in self._pedals.items()}
        self._pressed.clear()
        return Reading(arms=arms, pedals=pedals)
