"""
The ROS 2 layer of the project, shared by the nodes of both packages.

- :mod:`~sim_bridge.ros.qos`: the QoS profiles of every topic, each with its reason.
- :mod:`~sim_bridge.ros.conversions`: messages <-> arrays, the one place that knows both.
- :mod:`~sim_bridge.ros.client`: :class:`~sim_bridge.ros.client.SimClient`, a client node's
  view of the simulator (arms' state, ground truth, events; enable/home, servo commands).
- :mod:`~sim_bridge.ros.params`: :func:`~sim_bridge.ros.params.declare_config`, a node's
  parameters from ``config/<node>.yaml``.
- :mod:`~sim_bridge.ros.entry`: :func:`~sim_bridge.ros.entry.run_node`, the ``main`` of every
  node executable (help, arguments, signals, exit codes).

Only nodes (``sim_bridge.nodes``, ``suture_lfd.nodes``) and this layer import rclpy or message
packages; the core modules never do.
"""
