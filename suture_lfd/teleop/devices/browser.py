"""
The browser back-end: the viewer page's handles drive the virtual MTMs.

The viewer node publishes, in ``world``, ``viewer/input/<MTM>/pose`` (the 6-DOF handle),
``viewer/input/<MTM>/gripper`` (opening angle, rad, 0..1.047) and ``viewer/input/pedals``
(``buttons = [clutch, coag]``); the virtual MTMs' ROS layer hands each message to this device
(:meth:`BrowserDevice.set_pose`, :meth:`set_gripper`, :meth:`set_pedals`), which holds the
latest of each for the next poll. No hardware: the page works over SSH port forwarding.
"""

import numpy as np
from suture_lfd.teleop.devices import ArmReading, InputDevice, Reading

PEDAL_BUTTONS = ('clutch', 'coag')


class BrowserDevice(InputDevice):
    """
    The viewer page's inputs.

    Parameters
    ----------
    mtms : sequence of str
        MTM names.

    """

    frame_id = 'world'

    def __init__(self, mtms):
        self.mtms = tuple(mtms)
        self._poses = {}
        self._grippers = {}
        self._pedals = {}

    def set_pose(self, mtm, T_world_handle):
        """Take a handle pose (4x4, ``world``) of ``mtm``."""
        if mtm in self.mtms:
            self._poses[mtm] = np.array(T_world_handle, dtype=float)

    def set_gripper(self, mtm, angle):
        """Take a gripper angle (rad) of ``mtm``."""
        if mtm in self.mtms:
            self._grippers[mtm] = float(angle)

    def set_pedals(self, buttons):
        """
        Take the pedal buttons ``[clutch, coag]`` (1 pressed, 0 released).

        Raises
        ------
        ValueError
            If there are not 2 buttons.

        """
        if len(buttons) != len(PEDAL_BUTTONS):
            raise ValueError(f'viewer/input/pedals must have buttons [clutch, coag], got '
                             f'{list(buttons)}')
        self._pedals = {name: bool(b) for name, b in zip(PEDAL_BUTTONS, buttons)}

    def poll(self, t):
        arms = {m: ArmReading(pose=self._poses.get(m), gripper=self._grippers.get(m))
                for m in self.mtms}
        return Reading(arms=arms, pedals=dict(self._pedals))
