"""
The virtual MTMs' state_command intake, as the dVRK's teleoperation script uses it: real
processes over DDS on loopback.
"""

import time

from crtk_msgs.msg import OperatingState, StringStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

# as crtk publishes state_command: latched
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
READER = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)


def test_the_virtual_mtms_take_a_latched_state_command_sent_before_discovery(ros, launch):
    states = []
    node = ros.node('mtm_client')
    node.create_subscription(OperatingState, 'MTMR/operating_state', states.append, READER)
    pub = node.create_publisher(StringStamped, 'MTMR/state_command', LATCHED)
    mtms = launch('mtms', '--ros-args', '-p', 'device:=browser')
    time.sleep(0.1)
    for command in ('enable', 'home'):  # at once, as dvrk_teleoperation.py does
        pub.publish(StringStamped(string=command))
    assert ros.wait_for(lambda: states and states[-1].state == 'ENABLED'
                        and states[-1].is_homed, 60.0), mtms.log()
