"""
Learning from demonstration for autonomous suturing on the (simulated) dVRK.

Core modules never import rclpy or message packages; the ROS faces live in
``suture_lfd.nodes`` and the ROS layer ``sim_bridge.ros``. Conventions (units, quaternion order,
frames) are those stated in :mod:`sim_bridge`.
"""
