"""
Input devices that drive virtual MTMs, one small module per back-end behind one interface.

A device is polled once per cycle of the virtual MTMs (:meth:`InputDevice.poll`) and returns a
:class:`Reading`: per MTM either an absolute handle pose or a velocity, in the device's frame
(:attr:`InputDevice.frame_id`), and a gripper angle; and the console's pedals. Back-ends:

- ``browser`` (:mod:`.browser`): the viewer page's 6-DOF handles, gripper sliders and pedal
  buttons (poses in ``world``);
- ``gamepad`` (:mod:`.gamepad`): an SDL game controller through pygame (velocities in the
  camera frame);
- ``spacemouse`` (:mod:`.spacemouse`): a 3Dconnexion SpaceMouse through hidapi (velocities in
  the camera frame).
"""

from suture_lfd.teleop.devices.interface import (
    CAMERA_FRAME,
    PEDALS,
    ArmReading,
    InputDevice,
    Reading,
    open_device,
)

__all__ = ['CAMERA_FRAME', 'PEDALS', 'ArmReading', 'InputDevice', 'Reading', 'open_device']
