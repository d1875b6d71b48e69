"""
The simulator node in physical mode, over DDS: the ground truth only for the evaluation.

A real simulator process with ``physical:=true`` and hidden kinematic errors, read from the
ROS graph (not from the code): every ground-truth topic is under ``/evaluation/``, none in the
pipeline's ``sim/`` names, ``/tf`` has no needle and ``/tf_static`` no phantom or markers; the
arms' CRTK topics are there as on a dVRK, and the truth is still there for the evaluation.
"""

import threading

from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STREAM = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
TRUTH = ('sim/needle/measured_cp', 'sim/phantom/measured_cp', 'sim/markers/synth1/entry',
         'sim/markers/synth1/exit', 'sim/PSM1/base_frame', 'sim/ECM/base_frame', 'sim/events',
         'sim/visualization')


def test_in_physical_mode_the_truth_is_published_only_for_the_evaluation(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS, '-p', 'physical:=true',
                 '-p', 'kinematic_error_level:=3.0', '-p', 'tf_rate:=50.0')
    node = ros.node('physical_probe')
    lock = threading.Lock()
    frames = {'/tf': set(), '/tf_static': set()}
    got = {}

    def on_tf(topic, msg):
        with lock:
            frames[topic].update(t.child_frame_id for t in msg.transforms)

    node.create_subscription(TFMessage, '/tf', lambda m: on_tf('/tf', m), STREAM)
    node.create_subscription(TFMessage, '/tf_static', lambda m: on_tf('/tf_static', m), LATCHED)
    node.create_subscription(PoseStamped, '/evaluation/sim/markers/synth1/entry',
                             lambda m: got.__setitem__('entry', m), LATCHED)

    def topics():
        return dict(node.get_topic_names_and_types())

    def ready():
        names = topics()
        with lock:
            seen = 'PSM1' in frames['/tf'] and 'PSM1_base' in frames['/tf_static']
        return seen and 'entry' in got and '/PSM1/measured_cp' in names and all(
            f'/evaluation/{t}' in names for t in TRUTH)

    assert ros.wait_for(ready, 60.0), (sorted(topics()), frames, sim.log())
    names = topics()
    for topic in TRUTH:
        assert f'/{topic}' not in names, topic
    pipeline_visible = [n for n in names if n.startswith('/sim/')]
    assert set(pipeline_visible) <= {'/sim/target_pair', '/sim/stats', '/sim/process',
                                     '/sim/reset'}, pipeline_visible
    # the robot's face: CRTK topics of every arm, the stereo camera's
    for topic in ('/PSM1/measured_cp', '/PSM2/measured_js', '/ECM/measured_cp',
                  '/PSM1/local/measured_cp', '/ECM/left/image_raw', '/ECM/right/camera_info'):
        assert topic in names, topic
    ros.wait_for(lambda: False, 0.5)  # a few more /tf messages
    with lock:
        assert 'needle' not in frames['/tf'], frames['/tf']
        static = set(frames['/tf_static'])
    assert not static & {'phantom', 'synth1_entry', 'synth1_exit'}, static
    # the evaluation still gets the truth
    assert got['entry'].header.frame_id == 'world'


def test_a_negative_error_level_stops_the_node_with_a_message_naming_it(launch):
    sim = launch('simulator', '--ros-args', '-p', 'kinematic_error_level:=-1.0')
    assert sim.popen.wait(60.0) == 2
    log = sim.log_path.read_text()
    assert 'kinematic_error_level must be >= 0' in log and 'Traceback' not in log
