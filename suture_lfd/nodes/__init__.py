"""
ROS 2 faces of the learning-from-demonstration pipeline (the only modules here that import rclpy).

Shared by the nodes: :func:`run_until_finished` is the ``main`` of a node that ends by itself;
node parameters come from :func:`sim_bridge.ros.params.declare_config`.
"""

import rclpy
from rclpy.executors import ExternalShutdownException


def run_until_finished(make_node, name, args=None, interrupted_code=1):
    """
    Run a node that ends by itself: spin it until ``node.finished``, return ``node.exit_code``.

    Parameters
    ----------
    make_node : callable
        Builds the node (after ``rclpy.init``); a ValueError or OSError it raises (a bad
        parameter or file) is logged as fatal and gives exit code 2.
    name : str
        Logger name for that message.
    args : list of str, optional
        Command-line arguments for ``rclpy.init``.
    interrupted_code : int
        Exit code after Ctrl-C or an external shutdown.

    Returns
    -------
    int
        Process exit code.

    """
    rclpy.init(args=args)
    try:
        node = make_node()
    except (ValueError, OSError) as exc:
        rclpy.logging.get_logger(name).fatal(str(exc))
        rclpy.try_shutdown()
        return 2
    code = 1
    try:
        while rclpy.ok() and not node.finished:
            rclpy.spin_once(node, timeout_sec=0.05)
        code = node.exit_code
    except (KeyboardInterrupt, ExternalShutdownException):
        code = interrupted_code
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return code
