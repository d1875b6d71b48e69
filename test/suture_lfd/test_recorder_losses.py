"""The recorder's loss count: what it wrote plus what it says it lost is what was published."""

import json
from pathlib import Path
import subprocess
import sys
import textwrap

from harness import wait_for
from suture_lfd import bags
from test_recorder import call, launch_recorder

TOPICS = ('/loss/PSM1/servo_cp', '/loss/PSM2/servo_cp')
SECONDS = 10.0
RATE_HZ = 1000.0

# A separate publisher process: both topics at 1 kHz, paced on the monotonic clock, with the
# QoS the nodes stream their commands with; it prints how many messages it published.
PUBLISHER = textwrap.dedent("""
    import json, sys, time
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from sim_bridge.ros.qos import SERVO_STREAM
    topics, seconds, rate = json.loads(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    rclpy.init()
    node = rclpy.create_node('loss_source')
    pubs = [node.create_publisher(PoseStamped, t, SERVO_STREAM) for t in topics]
    deadline = time.monotonic() + 60
    while not all(p.get_subscription_count() for p in pubs) and time.monotonic() < deadline:
        time.sleep(0.01)
    msg = PoseStamped()
    msg.header.frame_id = 'PSM1_base'
    msg.pose.orientation.w = 1.0
    sent = dict.fromkeys(topics, 0)
    t0, tick = time.monotonic(), 0
    while tick < seconds * rate:
        msg.pose.position.x = tick * 1e-6
        for topic, pub in zip(topics, pubs):
            pub.publish(msg)
            sent[topic] += 1
        tick += 1
        time.sleep(max(0.0, t0 + tick / rate - time.monotonic()))
    for p in pubs:
        p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
    print(json.dumps({'sent': sent, 'seconds': time.monotonic() - t0}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
""")


def test_bag_count_plus_reported_losses_is_what_was_published_beside_a_cpu_hog(
        ros, launch, tmp_path):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    types = ','.join(f"'{t}=geometry_msgs/msg/PoseStamped'" for t in TOPICS)
    proc = launch_recorder(launch, tmp_path, 'arms:=[""]', 'topics:=[' + ','.join(TOPICS) + ']',
                           'patterns:=[""]', 'carry_over:=[""]', f'types:=[{types}]',
                           'toggle_pedal:=""', 'status_period:=0.5')
    node = ros.node('loss_observer')
    statuses = []
    node.create_subscription(
        String, '/recorder/status', lambda m: statuses.append(json.loads(m.data)),
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    started = call(ros, node, '/recorder/start')
    assert started.success, started.message + proc.log()
    hog = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    try:
        source = subprocess.run(
            [sys.executable, '-c', PUBLISHER, json.dumps(TOPICS), str(SECONDS), str(RATE_HZ)],
            capture_output=True, text=True, timeout=300)
    finally:
        hog.kill()
        hog.wait()
    assert source.returncode == 0, source.stderr
    published = json.loads(source.stdout.strip().splitlines()[-1])['sent']
    assert published == dict.fromkeys(TOPICS, int(SECONDS * RATE_HZ))

    def accounted():
        last = statuses[-1] if statuses else {}
        per = last.get('topics', {})
        return all(per.get(t, {}).get('received', 0) + per.get(t, {}).get('missed', 0)
                   >= published[t] for t in TOPICS)

    wait_for(accounted, 30.0)
    stopped = call(ros, node, '/recorder/stop')
    assert stopped.success, stopped.message
    counts = json.loads(stopped.message)
    bag = Path(counts['bag'])
    stored = bags.bag_summary(bag).topics
    custom = bags.bag_custom_data(bag)
    in_meta = json.loads(custom['suture_lfd.counts'])
    for topic in TOPICS:
        mine = counts['topics'][topic]
        assert stored[topic].count == mine['written'] == mine['received']
        assert stored[topic].count + mine['missed'] == published[topic], (topic, mine)
        assert in_meta[topic] == mine
    assert counts['lost'] == sum(counts['topics'][t]['missed'] for t in TOPICS)
    assert int(custom['suture_lfd.lost']) == counts['lost']
    print(f'recorded beside a CPU hog: {counts["written"]} written, {counts["lost"]} lost '
          f'of {sum(published.values())} published')
