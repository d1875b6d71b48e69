"""
Each arm's robot model on ``<ARM>/robot_description``, the way the dVRK's own model is offered.

The dVRK's launch files (dvrk_model ``arm_state_publishers.launch.py``) run a
``robot_state_publisher`` in each arm's namespace, so a dVRK user finds the URDF of PSM1 on
``/PSM1/robot_description``: std_msgs/String, RELIABLE, TRANSIENT_LOCAL, depth 1 (what
robot_state_publisher offers and RViz's RobotModel display asks for). The simulator publishes the
same topic per arm (names relative, so a node namespace moves it) with the URDF of
:mod:`sim_bridge.robot_model`, made from the kinematics chains the simulation runs. Its joints are
named as in ``measured_js`` and ``jaw/measured_js``: ``joint_state_publisher`` with
``source_list: [measured_js, jaw/measured_js]`` and ``robot_state_publisher`` in the arm's
namespace take them as they are and put the arm's links on ``/tf`` under ``<ARM>_base``, which
the simulator places in ``world`` on ``/tf_static``.
"""

from sim_bridge.robot_model import arm_urdf
from sim_bridge.ros import qos
from std_msgs.msg import String


class RobotDescriptions:
    """
    Latched ``<ARM>/robot_description`` publishers, one per arm, published once at start-up.

    Parameters
    ----------
    node : rclpy.node.Node
    sim : sim_bridge.simulation.Simulation
        Its ``kinematics`` and ``config.world.instrument`` make the models.

    """

    def __init__(self, node, sim):
        shape = sim.config.world.instrument
        self.urdf = {arm: arm_urdf(arm, chain, shape) for arm, chain in sim.kinematics.items()}
        self._pubs = {arm: node.create_publisher(String, f'{arm}/robot_description', qos.LATCHED)
                      for arm in self.urdf}
        for arm, pub in self._pubs.items():
            pub.publish(String(data=self.urdf[arm]))
