"""
ROS 2 faces of the learning-from-demonstration pipeline (the only modules here that import rclpy).

Shared by the nodes: every node's ``main`` is :func:`sim_bridge.ros.entry.run_node`, through
its :mod:`~suture_lfd.nodes.executables` entry; node parameters come from
:func:`sim_bridge.ros.params.declare_config`.
"""

