"""
Simulated da Vinci Research Kit: PyBullet physics behind the dVRK CRTK interface.

Core modules in this package never import rclpy or message packages; the ROS face lives in
``sim_bridge.nodes`` and ``sim_bridge.ros.conversions``.

Conventions (stated once for the whole project)
-----------------------------------------------
- Units: SI (metres, radians, seconds, kilograms).
- Quaternions: ``(x, y, z, w)``, as geometry_msgs, PyBullet and SciPy use them.
- Poses: 4x4 homogeneous matrices ``T_a_b`` that map coordinates in frame ``b`` into frame ``a``.
- Frames: ``world``; ``<ARM>_base`` is the remote-centre-of-motion (RCM) frame of each arm, the
  dVRK default frame of ``measured_cp``; ground truth (needle, markers, phantom) is in ``world``.
"""
