"""
The simulator offers each arm's URDF on ``/<ARM>/robot_description`` as the dVRK's
robot_state_publisher does, with joint states a robot_state_publisher takes as they are: a real
simulator process, real DDS on loopback, the model read back by pinocchio.
"""

import threading
from xml.etree import ElementTree as ET

from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS, SIGINT_EXIT
import numpy as np
import pinocchio as pin
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from sim_bridge.robot_model import simulation_urdfs
from sim_bridge.ros import conversions as cv
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

ARMS = ('PSM1', 'PSM2', 'ECM')
# what robot_state_publisher offers and RViz's RobotModel display asks for
DESCRIPTION = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATIC_TF = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.VOLATILE)


def moving_joints(urdf):
    """The joints a joint state must name: every joint neither fixed nor mimicking another."""
    robot = ET.fromstring(urdf)
    return {j.get('name') for j in robot.findall('joint')
            if j.get('type') != 'fixed' and j.find('mimic') is None}


def stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_each_arm_offers_its_urdf_and_joint_states_that_fit_it(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    node = ros.node('robot_model_probe')
    lock = threading.Lock()
    got = {}
    static = []
    node.create_subscription(TFMessage, '/tf_static', static.append, STATIC_TF)
    for arm in ARMS:  # subscribed after the simulator started: a late joiner, as RViz is
        node.create_subscription(String, f'/{arm}/robot_description',
                                 lambda m, a=arm: got.setdefault(a, []).append(m.data),
                                 DESCRIPTION)
    assert ros.wait_for(lambda: len(got) == 3, 60.0), sim.log()
    # the topic carries the models `suture-lfd urdf` writes, once per arm
    assert {arm: texts[0] for arm, texts in got.items()} == simulation_urdfs()
    assert all(len(texts) == 1 for texts in got.values())
    # each model's root is a frame the simulator puts on /tf_static: RViz places the arms in it
    roots = {ET.fromstring(text[0]).find('link').get('name') for text in got.values()}
    assert roots == {f'{arm}_base' for arm in ARMS}
    assert ros.wait_for(lambda: roots <= {t.child_frame_id for m in static for t in m.transforms},
                        30.0)
    for arm in ARMS:
        infos = node.get_publishers_info_by_topic(f'/{arm}/robot_description')
        assert [(i.node_name, i.topic_type, i.qos_profile.durability.name) for i in infos] == [
            ('simulator', 'std_msgs/msg/String', 'TRANSIENT_LOCAL')]

    # measured_js + jaw/measured_js name exactly the model's moving joints; the model's tool tip
    # at those joint values is local/measured_cp of the same state
    states = {}

    def keep(key, msg):
        with lock:
            states.setdefault(key, {})[stamp_ns(msg)] = msg

    for arm in ARMS:
        for topic, msgtype in (('measured_js', JointState), ('jaw/measured_js', JointState),
                               ('local/measured_cp', PoseStamped)):
            if topic.startswith('jaw') and arm == 'ECM':
                continue
            node.create_subscription(msgtype, f'/{arm}/{topic}',
                                     lambda m, k=(arm, topic): keep(k, m), STATE)

    def common_stamp(arm):
        with lock:
            keys = [k for k in states if k[0] == arm]
            if len(keys) < (3 if arm != 'ECM' else 2):
                return None
            shared = set.intersection(*(set(states[k]) for k in keys))
        return max(shared) if shared else None

    assert ros.wait_for(lambda: all(common_stamp(a) for a in ARMS), 60.0), sim.log()
    for arm in ARMS:
        t = common_stamp(arm)
        with lock:
            js = states[(arm, 'measured_js')][t]
            jaw = states.get((arm, 'jaw/measured_js'), {}).get(t)
            cp = states[(arm, 'local/measured_cp')][t]
        names = list(js.name) + (list(jaw.name) if jaw is not None else [])
        positions = list(js.position) + (list(jaw.position) if jaw is not None else [])
        urdf = got[arm][0]
        assert set(names) == moving_joints(urdf) and len(names) == len(set(names)), arm
        model = pin.buildModelFromXML(urdf, mimic=True)
        data = model.createData()
        values = dict(zip(names, positions))
        q = np.zeros(model.nq)
        for j in range(1, model.njoints):
            if model.joints[j].nq:
                q[model.joints[j].idx_q] = values[model.names[j]]
        pin.framesForwardKinematics(model, data, q)
        tip = data.oMf[model.getFrameId(f'{arm}_tool_tip_link')].homogeneous
        assert cp.header.frame_id == f'{arm}_base'
        assert np.abs(tip - cv.matrix_from_pose(cp.pose)).max() < 1e-9, arm
    assert sim.stop() == SIGINT_EXIT
