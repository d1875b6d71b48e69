"""ROS 2 faces of the simulated dVRK (the only modules here that import rclpy)."""
