"""
The gaps between state messages as the dVRK's teleoperation script receives them, per topic.

``dvrk_teleoperation.py`` reads, every 5 ms, the MTM's ``measured_cp``, ``setpoint_cp`` and
``gripper/measured_js`` and the PSM's ``setpoint_cp`` and ``jaw/setpoint_js``, and stops on data
older than four periods (20 ms). This benchmark starts ``simulator`` and ``mtms`` in their default
configuration (the README's commands), a client in its own process subscribed as crtk subscribes
(reliable, volatile, depth 10), enables and homes MTMR and PSM1 as the script does, then records
each message's arrival for ``--seconds`` twice: at rest (the MTM kept alive at 100 Hz, the
simulator at 100 Hz) and following (the client streams PSM1 ``servo_cp`` and ``jaw/servo_jp`` every
5 ms, as the script does while it follows), and prints per topic: the median and 99th percentile
gap, the largest, and how many gaps exceeded 20 ms (each one a getter that would have stopped the
script if the script had asked at the wrong moment), and each node's CPU per wall second (a node
that takes less leaves a two-core machine's scheduler room to run the others on time).
``--before REV`` runs the same with the code of git revision ``REV`` first (a temporary worktree
imported before this checkout's), so both are measured in one run on the same machine; the load
average is printed at the start and the end.

Run: ``.venv/bin/python bench/bench_state_gaps.py [--before main] [--seconds 20]``
"""

import argparse
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import threading
import time

from before_revision import code_env, measure_before

TOPICS = ('MTMR/measured_cp', 'MTMR/setpoint_cp', 'MTMR/gripper/measured_js',
          'PSM1/setpoint_cp', 'PSM1/jaw/setpoint_js')
LIMIT = 0.020


def client(seconds, out):
    """The client process: enable and home both arms, then record arrivals (one JSON file)."""
    from crtk_msgs.msg import OperatingState, StringStamped
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node('bench_state_gaps')
    volatile = QoSProfile(depth=10)
    latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    arrivals = {t: [] for t in TOPICS}
    for topic in TOPICS:
        kind = JointState if topic.endswith('_js') else PoseStamped
        node.create_subscription(kind, topic, lambda m, t=topic: arrivals[t].append(
            time.monotonic()), volatile)
    states = {}
    commands = {}
    for arm in ('MTMR', 'PSM1'):
        node.create_subscription(OperatingState, f'{arm}/operating_state',
                                 lambda m, a=arm: states.__setitem__(a, m), volatile)
        commands[arm] = node.create_publisher(StringStamped, f'{arm}/state_command', latched)
        commands[arm].publish(StringStamped(string='enable'))
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def spin_until(done, timeout):
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)
        return done()

    ready = True
    for arm in ('MTMR', 'PSM1'):
        ready &= spin_until(lambda a=arm: a in states and states[a].state == 'ENABLED', 30.0)
        commands[arm].publish(StringStamped(string='home'))
    for arm in ('MTMR', 'PSM1'):
        ready &= spin_until(lambda a=arm: states[a].is_homed and not states[a].is_busy, 30.0)
    spin_until(lambda: False, 1.0)                       # settled
    phases = {}
    for values in arrivals.values():
        values.clear()
    spin_until(lambda: False, seconds)
    phases['rest'] = {t: list(v) for t, v in arrivals.items()}
    # following: servo_cp (the PSM's own setpoint, so it holds) and the jaw every 5 ms
    setpoint = []
    node.create_subscription(PoseStamped, 'PSM1/setpoint_cp', setpoint.append, volatile)
    servo = node.create_publisher(PoseStamped, 'PSM1/servo_cp', volatile)
    jaw = node.create_publisher(JointState, 'PSM1/jaw/servo_jp', volatile)
    stop = threading.Event()

    def stream():
        next_at = time.monotonic()
        while not stop.is_set():
            if setpoint:
                servo.publish(setpoint[-1])
                jaw.publish(JointState(name=['jaw'], position=[0.5]))
            next_at += 0.005
            time.sleep(max(0.0, next_at - time.monotonic()))

    spin_until(lambda: bool(setpoint), 5.0)
    streamer = threading.Thread(target=stream, daemon=True)
    streamer.start()
    spin_until(lambda: False, 1.0)
    for values in arrivals.values():
        values.clear()
    spin_until(lambda: False, seconds)
    stop.set()
    streamer.join()
    phases['following'] = {t: list(v) for t, v in arrivals.items()}
    Path(out).write_text(json.dumps({'ready': ready, 'phases': phases}))
    node.destroy_node()
    rclpy.shutdown()


def measure(label, code, seconds, domain):
    """Run the nodes (code of ``code``, None: this checkout) and the client; return the gaps."""
    from sim_bridge.common.processes import popen, stop_group

    env = code_env(code, dict(os.environ, ROS_DOMAIN_ID=str(domain),
                              ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST'))
    bin_dir = Path(sys.executable).parent
    with tempfile.TemporaryDirectory() as tmp:
        procs = [popen([shutil.which(name, path=str(bin_dir))], env=env,
                       stdout=open(Path(tmp) / f'{name}.log', 'w'), stderr=subprocess.STDOUT)
                 for name in ('simulator', 'mtms')]
        out = Path(tmp) / 'arrivals.json'
        try:
            started = time.monotonic()
            subprocess.run([sys.executable, __file__, '--client', str(out),
                            '--seconds', str(seconds)], env=env, check=True, timeout=seconds + 120)
            wall = time.monotonic() - started
            cpu = {name: cpu_seconds(proc.pid) / wall for name, proc in
                   zip(('simulator', 'mtms'), procs)}
            data = json.loads(out.read_text())
        finally:
            for proc in procs:
                stop_group(proc, 10.0)
    gaps = {phase: {topic: [b - a for a, b in zip(times, times[1:])]
                    for topic, times in arrivals.items()}
            for phase, arrivals in data['phases'].items()}
    return {'label': label, 'ready': data['ready'], 'gaps': gaps, 'cpu': cpu}


def cpu_seconds(pid):
    """CPU seconds (user + system) a process has used so far (``/proc/PID/stat``)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def percentile(values, q):
    import numpy as np

    return float(np.percentile(values, q)) if values else float('nan')


def report(results):
    print(f'{"":<20}{"topic":<26}{"messages":>9}{"p50 ms":>8}{"p99 ms":>8}{"max ms":>8}'
          f'{"> 20 ms":>8}')
    for r in results:
        for phase, topic in [(p, t) for p in r['gaps'] for t in TOPICS]:
            g = r['gaps'][phase][topic]
            print(f'{r["label"] + " " + phase:<20}{topic:<26}{len(g) + 1 if g else 0:>9}'
                  f'{percentile(g, 50) * 1e3:>8.1f}{percentile(g, 99) * 1e3:>8.1f}'
                  f'{(max(g) if g else float("nan")) * 1e3:>8.1f}'
                  f'{sum(x > LIMIT for x in g):>8}')
        print(f'{r["label"]}: CPU per wall second while the client ran: ' + ', '.join(
            f'{name} {share:.2f}' for name, share in r['cpu'].items()))
        if not r['ready']:
            print(f'{r["label"]}: the arms did not become ready')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--before', default=None, help='git revision measured first')
    parser.add_argument('--seconds', type=float, default=20.0, help='s recorded at rest')
    parser.add_argument('--client', default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.client:
        client(args.seconds, args.client)
        return
    domain = int(os.environ.get('ROS_DOMAIN_ID', '57'))
    print(f'load average at the start: {Path("/proc/loadavg").read_text().split()[0]} '
          f'({os.cpu_count()} CPUs)')
    results = []
    if args.before:
        results.append(measure_before(
            args.before, lambda code: measure('before', code, args.seconds, domain + 1)))
    results.append(measure('now', None, args.seconds, domain))
    print(f'load average at the end: {Path("/proc/loadavg").read_text().split()[0]}')
    report(results)


if __name__ == '__main__':
    main()
