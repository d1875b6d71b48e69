"""
The dVRK console's foot pedals, for a simulated console.

Publishes the pedal topics a dVRK 2.3 console publishes (``/footpedals/clutch``, ``/coag``,
``/camera``, ``/console/clutch``, ``/console/camera``, ``/console/operator_present``;
sensor_msgs/Joy with ``buttons=[v]``, v = 1 pressed, 0 released, 2 quick tap; reliable,
transient-local events) and lets any client emulate presses through the console's
``/console/emulate_clutch``, ``/console/emulate_camera`` and
``/console/emulate_operator_present`` topics, or through ``/footpedals/<name>/emulate``.
As on the dVRK console, the operator-present pedal is the coag pedal.
"""

import sys

from rclpy.node import Node
from sensor_msgs.msg import Joy
from sim_bridge.nodes import executables
from sim_bridge.ros import qos

# pedal name -> console topic that mirrors it (None: pedal topic only)
PEDALS = {'clutch': 'clutch', 'coag': 'operator_present', 'camera': 'camera'}


class FootPedals(Node):
    """Foot-pedal events of a dVRK console, with emulated presses."""

    def __init__(self):
        super().__init__('footpedals')
        self._pedal_pubs = {}
        self._console_pubs = {}
        for pedal, console in PEDALS.items():
            self._pedal_pubs[pedal] = self.create_publisher(
                Joy, f'/footpedals/{pedal}', qos.EVENTS)
            self._console_pubs[pedal] = self.create_publisher(
                Joy, f'/console/{console}', qos.EVENTS)
            self.create_subscription(
                Joy, f'/footpedals/{pedal}/emulate',
                lambda msg, p=pedal: self._on_emulate(p, msg), qos.COMMANDS)
            self.create_subscription(
                Joy, f'/console/emulate_{console}',
                lambda msg, p=pedal: self._on_emulate(p, msg), qos.COMMANDS)

    def _on_emulate(self, pedal, msg):
        if len(msg.buttons) != 1 or msg.buttons[0] not in (0, 1, 2):
            self.get_logger().warning(
                f'/footpedals/{pedal}: emulated press must have buttons=[0|1|2], '
                f'got buttons={list(msg.buttons)}; ignored')
            return
        out = Joy()
        out.header.stamp = self.get_clock().now().to_msg()
        out.buttons = [int(msg.buttons[0])]
        self._pedal_pubs[pedal].publish(out)
        self._console_pubs[pedal].publish(out)


def main(args=None):
    return executables.footpedals(args)


if __name__ == '__main__':
    sys.exit(main())
