"""
Teleoperation without ROS.

The dVRK's MTM -> PSM mapping and state machine, the virtual MTM model, and the input devices
that drive virtual MTMs (``devices/``).
"""
