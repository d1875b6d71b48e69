"""
The executor node in physical mode: a throw on CRTK topics and the perception node alone.

Real processes on loopback: the simulator node with ``physical:=true`` and hidden kinematic
errors (its truth only under ``/evaluation/``), the perception node on the simulated endoscope,
and the executor node with ``physical:=true``, which registers the arms against the endoscope
on the camera's images before the throw. The throw's score is read from the evaluation's
``/evaluation/sim/events``; what the executor reads is checked from the ROS graph (its
subscriptions), not from its code.
"""

import json
import time

from crtk_msgs.msg import StringStamped
from harness import FAST_ARMS
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
THROW_TIMEOUT = 900.0  # s of wall time for a whole throw with rendering on a loaded 2-core machine
ERROR_LEVEL = 3.0      # mm class of the hidden kinematic errors
# a tenth of real time: at a quarter the throw scored 1.0 in 3 runs at a load of 8-17 on 2 cores
# but 0 (trauma 2.5 mm) in 1 of 2 with two busy loops added
REAL_TIME_FACTOR = 0.1
# what the executor may read besides the arms' CRTK topics and the perception node's outputs
ALLOWED_SIM = {'/sim/process'}


@pytest.fixture(scope='module')
def segments(simulation, tmp_path_factory):
    demo, _, score = record_scripted_demonstration(simulation, 'synth1', seed=0)
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('executor_physical') / 'synth1_segments.npz'
    make_segment_file(demo, segment_demonstration(demo), source='scripted expert').save(path)
    return path


def test_in_physical_mode_the_executor_runs_a_throw_on_crtk_and_perception_alone(
        launch, ros, segments, tmp_path):
    sim = launch('simulator', '--ros-args', *FAST_ARMS,
                 '-p', f'real_time_factor:={REAL_TIME_FACTOR}',
                 '-p', 'physical:=true', '-p', f'kinematic_error_level:={ERROR_LEVEL}',
                 '-p', 'camera_rate:=1.0', '-p', 'max_lag:=10.0',
                 '-p', 'visualization_rate:=0.0')
    # Rendering holds the simulator's loop up (a second or more on a loaded machine): images
    # once a simulated second, and the loop catches up afterwards instead of skipping ahead.
    perception = launch('perception', '--ros-args', '-p', 'rate:=2.0')
    # after a render the simulator's loop catches up in a burst, in which /clock may run a few
    # state periods ahead of the arms' queued measured_cp: a silent arm takes 1 s here
    # the outcome also goes to a file: the node exits after the throw, maybe before its last
    # message has reached this probe
    outcome = tmp_path / 'outcome.json'
    executor = launch('executor', '--ros-args', '-p', f'segments:={segments}',
                      '-p', 'method:=pair_frame', '-p', 'physical:=true', '-p', 'pair:=synth1',
                      '-p', 'stale_timeout:=1.0',
                      '-p', f'result_file:={outcome}')
    probe = ros.node('physical_executor_probe')
    scores, results, every = [], [], []

    def on_event(msg):
        data = json.loads(msg.string)
        every.append(data)
        if data.get('kind') == 'score':
            scores.append(data)

    probe.create_subscription(StringStamped, '/evaluation/sim/events', on_event, EVENTS)
    probe.create_subscription(String, '/executor/result',
                              lambda m: results.append(json.loads(m.data)), LATCHED)

    def subscriptions():
        try:
            return dict(probe.get_subscriber_names_and_types_by_node('executor', '/'))
        except Exception:  # noqa: BLE001 (the node is not in the graph yet)
            return {}

    def logs():
        return sim.log()[-3000:], perception.log()[-3000:], executor.log()[-6000:]

    inputs = {'/PSM1/measured_cp', '/PSM2/local/measured_cp', '/ECM/local/measured_cp',
              '/tf_static', '/perception/needle/measured_cp', '/perception/markers/entries',
              '/perception/markers/exits', '/perception/needle/status', '/ECM/left/image_raw',
              '/ECM/right/camera_info'}
    assert ros.wait_for(lambda: inputs <= set(subscriptions()), 120.0), \
        (sorted(subscriptions()), logs())
    subs = subscriptions()
    truth = [t for t in subs if t.startswith('/evaluation/')
             or (t.startswith('/sim/') and t not in ALLOWED_SIM)]
    assert not truth, sorted(subs)
    topics = dict(probe.get_topic_names_and_types())
    assert '/sim/needle/measured_cp' not in topics and '/sim/events' not in topics

    assert ros.wait_for(lambda: results or outcome.exists(), THROW_TIMEOUT), logs()
    result = results[-1] if results else json.loads(outcome.read_text())
    assert result['state'] == 'done', (result, logs())
    assert 'registration done' in executor.log(), logs()
    # the evaluation scored the throw: the last score event is the throw's
    assert ros.wait_for(lambda: scores, 60.0), logs()
    time.sleep(2.0)
    score = scores[-1]['score']
    print('physical node throw:', json.dumps(score), flush=True)
    if score['score'] < 0.8:
        print('executor log:', executor.log()[-12000:], sep='\n', flush=True)
        for ev in every:  # the evaluation's scene events, for the reader of a failure
            if ev.get('kind') != 'score':
                print('EVENT', json.dumps(ev)[:300], flush=True)
    assert score['score'] >= 0.8, (score, logs())
    # the whole throw long, it read none of the truth
    subs = subscriptions() or subs
    assert not [t for t in subs if t.startswith('/evaluation/')], sorted(subs)


def test_in_physical_mode_the_demonstrator_reads_no_truth(launch, ros):
    sim = launch('simulator', '--ros-args', *FAST_ARMS, '-p', 'physical:=true',
                 '-p', 'visualization_rate:=0.0')
    demonstrator = launch('demonstrator', '--ros-args', '-p', 'physical:=true',
                          '-p', 'recorder_status:=""', '-p', 'startup_timeout:=600.0')
    probe = ros.node('physical_demonstrator_probe')

    def subscriptions():
        try:
            return dict(probe.get_subscriber_names_and_types_by_node('demonstrator', '/'))
        except Exception:  # noqa: BLE001 (the node is not in the graph yet)
            return {}

    inputs = {'/PSM1/local/measured_cp', '/tf_static', '/perception/needle/measured_cp',
              '/perception/markers/exits'}
    assert ros.wait_for(lambda: inputs <= set(subscriptions()), 120.0), \
        (sim.log()[-2000:], demonstrator.log()[-4000:])
    subs = subscriptions()
    truth = [t for t in subs if t.startswith('/evaluation/')
             or (t.startswith('/sim/') and t not in ALLOWED_SIM)]
    assert not truth, sorted(subs)
    assert demonstrator.running(), demonstrator.log()
