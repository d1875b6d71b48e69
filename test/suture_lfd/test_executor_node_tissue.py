"""
The executor node on tissue, over real processes: the preset reaches it and a throw completes.

The simulator node runs the ``tissue`` preset (the needle can turn in the jaw, the pad gives);
the executor node, told the same preset, watches the grasp during ii and iv as the in-process
executor does. The slips the simulator reports on ``sim/events`` are collected beside the score.
"""

import json
import time

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
THROW_TIMEOUT = 600.0   # s of wall time for a whole throw on a loaded 2-core machine


def test_an_unknown_tissue_preset_is_named_and_the_node_exits(launch, tmp_path):
    proc = launch('executor', '--ros-args', '-p', f'segments:={tmp_path / "unused.npz"}',
                  '-p', 'tissue:=jelly')
    assert proc.popen.wait(120) == 2
    # the preset asked for, and the presets there are
    assert "'jelly'" in proc.log() and 'tissue' in proc.log().split("'jelly'")[-1]


def test_the_executor_node_on_tissue_completes_a_throw(launch, ros, simulation, tmp_path):
    from crtk_msgs.msg import StringStamped

    demo, _, score = record_scripted_demonstration(simulation, 'synth1', seed=0)
    assert score.score == 1.0, score.failure
    segments = tmp_path / 'synth1_segments.npz'
    make_segment_file(demo, segment_demonstration(demo), source='scripted expert').save(segments)
    sim = launch('simulator', '--ros-args', '-p', 'real_time_factor:=0.25',
                 '-p', 'tissue:=tissue')
    executor = launch('executor', '--ros-args', '-p', f'segments:={segments}',
                      '-p', 'tissue:=tissue')
    node = ros.node('tissue_watcher')
    status, results, events = [], [], []
    node.create_subscription(String, 'executor/status',
                             lambda m: status.append(json.loads(m.data)), LATCHED)
    node.create_subscription(String, 'executor/result',
                             lambda m: results.append(json.loads(m.data)), LATCHED)
    node.create_subscription(StringStamped, 'sim/events',
                             lambda m: events.append(json.loads(m.string)), EVENTS)
    execute = node.create_publisher(String, 'executor/execute', 10)
    assert ros.wait_for(lambda: status and status[-1]['state'] == 'idle', timeout=120.0), \
        executor.log()
    deadline = time.monotonic() + 60.0
    while status[-1]['state'] == 'idle' and time.monotonic() < deadline:
        execute.publish(String(data='synth2'))
        time.sleep(0.5)
    assert ros.wait_for(lambda: results, timeout=THROW_TIMEOUT), executor.log()[-3000:]
    result = results[-1]
    slips = [e for e in events if e.get('kind') == 'slip']
    assert result['state'] == 'done' and result['pair'] == 'synth2', result
    assert result['score'] == 1.0, (result, slips)
    assert not any(e['broken'] for e in slips), slips
    assert executor.running() and sim.running()
