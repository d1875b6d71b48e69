"""
The simulator node under a dVRK client's load: latency, state rate and jitter, CPU, pace.

Anchors:

- the dVRK publishes arm state at 100 Hz (from a 1.5 kHz control loop);
- a plain rclpy echo between two processes on this machine, measured in the same run (the
  reference figures are RTT p50 0.5 ms, p99 3 ms at 1 kHz, ros2_ecosystem.md §5); the issue's
  target is p99 <= 3 ms end to end.

Measured, with the simulator at ``real_time_factor`` 1 and a client subscribed to the state of all
three arms (what ``dvrk.psm``/``dvrk.ecm`` objects subscribe) while it streams ``servo_cp`` to PSM1
at 1 kHz:

- ``servo_cp -> setpoint_cp`` latency: for each ``setpoint_cp`` the client receives, the age of
  the goal it shows (time since the client sent that goal). The state is sampled at 100 Hz, so the
  age is bounded below by how old the newest goal is at the sampling instant (0..1 ms at 1 kHz);
- the state rate and inter-arrival jitter of ``measured_js`` against the 100 Hz anchor;
- in-process, first: the cost of one physics step of the bare core and of the node's stepping
  round (no subscribers), i.e. the node's overhead and the real-time factor one free core allows;
- the simulator's CPU use (share of one core) and the real-time factor it achieved
  (``sim/stats``); then, with nobody listening, the factor it reaches at ``real_time_factor`` 0
  (as fast as it goes).

Run: ``.venv/bin/python bench/bench_simulator_node.py [--seconds 10]``
"""

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = str(100 + os.getpid() % 100)

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402

ANCHOR_STATE_HZ = 100.0
TARGET_P99_S = 3e-3
ECHO = """
import rclpy
from geometry_msgs.msg import PoseStamped
rclpy.init()
node = rclpy.create_node('echo')
pub = node.create_publisher(PoseStamped, 'echo/out', 100)
node.create_subscription(PoseStamped, 'echo/in', pub.publish, 100)
try:
    rclpy.spin(node)
except KeyboardInterrupt:
    pass
finally:
    node.destroy_node()
    rclpy.try_shutdown()
"""


def start(argv):
    return subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def stop(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5.0)


def cpu_seconds(pid):
    """User + system CPU seconds of a process (Linux /proc)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def wait_for(predicate, timeout):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError('benchmark setup timed out')
        time.sleep(0.01)


def stream(pub, make, rate, seconds, sent):
    """Publish ``make(k)`` at ``rate`` Hz (sleep pacing) for ``seconds``; log send times."""
    period = 1.0 / rate
    t0 = time.monotonic()
    k = 0
    while True:
        now = time.monotonic()
        if now - t0 > seconds:
            return
        msg, key = make(k)
        sent[key] = time.monotonic()
        pub.publish(msg)
        k += 1
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))


def pct(values, q):
    return float(np.percentile(values, q)) if len(values) else float('nan')


def loop_capacity(steps=1000):
    """
    Seconds per physics step of the bare core and of the node's stepping round, same process.

    The node (no subscribers) adds event flushing and publishing checks to
    ``Simulation.step``; the ratio is the node's overhead, and ``dt / seconds`` the real-time
    factor one free core could sustain.
    """
    from sim_bridge.nodes.simulator import Simulator

    node = Simulator()
    try:
        node.sim.enable_and_home_all()
        t = time.perf_counter()
        for _ in range(steps):
            node.sim.step()
        bare = (time.perf_counter() - t) / steps
        t = time.perf_counter()
        for _ in range(steps):
            node._step()
        wrapped = (time.perf_counter() - t) / steps
        return bare, wrapped, node.sim.dt
    finally:
        node.destroy_node()
        node.close()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=10.0, help='length of each phase (s)')
    args = parser.parse_args()
    bin_dir = Path(sys.executable).parent

    from crtk_msgs.msg import StringStamped
    from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
    from sensor_msgs.msg import JointState
    from sim_bridge import conversions as cv
    from std_msgs.msg import Float64MultiArray, String

    rclpy.init()
    capacity = loop_capacity()
    node = rclpy.create_node('bench_client')
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    qos = QoSProfile(depth=100)
    lock = threading.Lock()
    log = {'setpoint_cp': [], 'measured_js': [], 'echo': [], 'stats': []}

    def keep(name, value):
        with lock:
            log[name].append(value)

    # -- anchor: a plain rclpy echo process, 1 kHz PoseStamped round trip --------------------
    echo = start([sys.executable, '-c', ECHO])
    echo_pub = node.create_publisher(PoseStamped, 'echo/in', qos)
    node.create_subscription(PoseStamped, 'echo/out',
                             lambda m: keep('echo', (time.monotonic(), m.pose.position.x)), qos)
    wait_for(lambda: echo_pub.get_subscription_count() > 0
             and node.count_publishers('echo/out') > 0, 30.0)
    time.sleep(1.0)
    echo_sent = {}

    def echo_msg(k):
        msg = PoseStamped()
        msg.pose.position.x = float(k)
        msg.pose.orientation.w = 1.0
        return msg, float(k)
    stream(echo_pub, echo_msg, 1000.0, args.seconds / 2, echo_sent)
    time.sleep(0.5)
    stop(echo)
    with lock:
        rtt = [t - echo_sent[x] for t, x in log['echo'] if x in echo_sent]

    # -- the simulator at real time under a full client --------------------------------------
    sim = start([str(bin_dir / 'simulator')])
    # what dvrk.psm / dvrk.ecm objects subscribe, for all three arms
    types = {'measured_js': JointState, 'setpoint_js': JointState, 'measured_cp': PoseStamped,
             'setpoint_cp': PoseStamped, 'local/measured_cp': PoseStamped,
             'local/setpoint_cp': PoseStamped, 'measured_cv': TwistStamped,
             'body/measured_cf': WrenchStamped, 'spatial/measured_cf': WrenchStamped,
             'body/jacobian': Float64MultiArray, 'spatial/jacobian': Float64MultiArray,
             'jaw/measured_js': JointState, 'jaw/setpoint_js': JointState}
    special = {
        ('PSM1', 'setpoint_cp'): lambda m: keep('setpoint_cp',
                                                (time.monotonic(), m.pose.position.y)),
        ('PSM1', 'measured_js'): lambda m: keep('measured_js', (
            time.monotonic(), cv.seconds_from_stamp(m.header.stamp))),
    }
    for arm in ('PSM1', 'PSM2', 'ECM'):
        for topic, msgtype in types.items():
            if arm == 'ECM' and topic.startswith('jaw/'):
                continue
            node.create_subscription(msgtype, f'{arm}/{topic}',
                                     special.get((arm, topic), lambda m: None), qos)
    node.create_subscription(String, 'sim/stats', lambda m: keep('stats', json.loads(m.data)),
                             qos)
    state = node.create_publisher(StringStamped, 'PSM1/state_command', 10)
    servo = node.create_publisher(PoseStamped, 'PSM1/servo_cp', 10)
    wait_for(lambda: servo.get_subscription_count() > 0 and log['setpoint_cp'], 60.0)
    for command in ('enable', 'home'):
        state.publish(StringStamped(string=command))
        time.sleep(1.0)
    with lock:
        T0 = log['setpoint_cp'][-1]
    home_y = T0[1]

    def goal(k):
        # tiny side-to-side motion; y identifies the goal (unique per k)
        y = home_y + 0.005 * np.sin(2 * np.pi * k / 2000.0) + k * 1e-9
        msg = PoseStamped()
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = 0.0, float(y), -0.1135
        msg.pose.orientation.x = msg.pose.orientation.y = 2 ** -0.5
        return msg, float(y)

    with lock:
        for name in ('setpoint_cp', 'measured_js', 'stats'):
            log[name].clear()
    cpu0, wall0 = cpu_seconds(sim.pid), time.monotonic()
    sent = {}
    stream(servo, goal, 1000.0, args.seconds, sent)
    cpu = (cpu_seconds(sim.pid) - cpu0) / (time.monotonic() - wall0)
    time.sleep(0.3)
    with lock:
        received = list(log['setpoint_cp'])
        arrivals = np.array([t for t, _ in log['measured_js']])
        stamps = np.array([s for _, s in log['measured_js']])
        live = [s['achieved'] for s in log['stats']]
    stop(sim)

    # -- the simulator as fast as it goes, nobody listening ----------------------------------
    fast = start([str(bin_dir / 'simulator'), '--ros-args', '-p', 'real_time_factor:=0.0'])
    with lock:
        log['stats'].clear()
    wait_for(lambda: len(log['stats']) >= 2, 60.0)
    time.sleep(args.seconds / 2)
    with lock:
        flat_out = [s['achieved'] for s in log['stats'][1:]]
    stop(fast)
    executor.shutdown()
    spinner.join(2.0)
    node.destroy_node()
    rclpy.shutdown()

    sent_y = np.array(list(sent))
    sent_t = np.array(list(sent.values()))
    ages = []
    for t, y in received:
        i = int(np.argmin(np.abs(sent_y - y)))
        if abs(sent_y[i] - y) < 1e-10:  # the setpoint shows exactly this goal
            ages.append(t - sent_t[i])
    gaps = np.diff(arrivals)
    wall_rate = (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])
    sim_rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    bare, wrapped, dt = capacity
    print(f'stepping cost per {dt * 1e3:.0f} ms physics step: core {bare * 1e3:.3f} ms, node '
          f'{wrapped * 1e3:.3f} ms (node / core = {wrapped / bare:.2f}); one free core sustains '
          f'{dt / wrapped:.1f} x real time')
    print(f'anchor echo RTT (rclpy, 1 kHz): p50 {pct(rtt, 50) * 1e3:.2f} ms, '
          f'p99 {pct(rtt, 99) * 1e3:.2f} ms ({len(rtt)} samples)')
    print(f'servo_cp -> setpoint_cp age: p50 {pct(ages, 50) * 1e3:.2f} ms, '
          f'p99 {pct(ages, 99) * 1e3:.2f} ms ({len(ages)} samples); '
          f'p50 / anchor p50 = {pct(ages, 50) / pct(rtt, 50):.1f}, '
          f'p99 / target 3 ms = {pct(ages, 99) / TARGET_P99_S:.2f}')
    print(f'measured_js rate: {wall_rate:.1f} Hz wall ({wall_rate / ANCHOR_STATE_HZ:.3f} x the '
          f'dVRK 100 Hz), {sim_rate:.2f} Hz of sim time; inter-arrival jitter |dt - 10 ms| '
          f'p50 {pct(abs(gaps - 0.01), 50) * 1e3:.2f} ms, '
          f'p99 {pct(abs(gaps - 0.01), 99) * 1e3:.2f} ms')
    print(f'simulator CPU with three arms at 100 Hz and a 1 kHz servo_cp stream: '
          f'{cpu * 100:.0f} % of one core; real-time factor achieved '
          f'{np.mean(live) if live else float("nan"):.3f} (asked 1.0)')
    print(f'as fast as it goes (real_time_factor 0, no subscribers): '
          f'{np.mean(flat_out) if flat_out else float("nan"):.2f} x real time')
    print(f'load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores')


if __name__ == '__main__':
    main()
