"""The ROS layer of the simulated dVRK: what its nodes share (the modules that import rclpy)."""
