"""
The executables of the simulated dVRK (``setup.py`` console scripts): name, node, help example.

Each is a :class:`sim_bridge.ros.entry.Executable`: ``--help`` is answered before the node's
module is imported or ROS is initialised.
"""

from sim_bridge.ros.entry import Executable

simulator = Executable(
    'simulator', 'sim_bridge.nodes.simulator:Simulator', config_file='simulator.yaml',
    example='simulator --ros-args -p phantom:=scanned -p real_time_factor:=2.0')
footpedals = Executable(
    'footpedals', 'sim_bridge.nodes.footpedals:FootPedals',
    example='footpedals   # then press: ros2 topic pub --once /footpedals/camera/emulate '
            'sensor_msgs/msg/Joy "{buttons: [1]}"')
