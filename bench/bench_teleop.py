"""
The demonstration graph's CPU at rest and while following, and the teleoperation latency.

Anchors: the dVRK runs its MTM -> PSM teleoperation every 1 ms (the C++ teleop component) to
5 ms (``dvrk_teleoperation.py``, ``--interval 0.005``); its arm state is published at 100 Hz.
Targets: the whole graph at rest at most 0.5 of a core; input -> ``PSM1/setpoint_cp`` p99 at
most 20 ms.

The graph is ``scripts/demonstrate.sh --device browser``'s, each node its own process on
loopback: the simulator (``real_time_factor`` 1), the viewer, the virtual MTMs (browser
back-end), two teleop nodes (MTMR -> PSM1, MTML -> PSM2), the recorder (not recording) and the
``footpedals`` node. Phases:

1. **at rest**: everything started and settled (arms homed, the teleops waiting for a hand),
   nobody moves: CPU of each node over ``--rest`` s (``/proc/<pid>/stat`` user + system time
   over wall time: 100 % is one core);
2. **following**: this probe presses coag, pinches both grippers until both teleops follow,
   then streams both handles (``viewer/input/<MTM>/pose``, 200 Hz, sleep pacing as a
   teleoperation client does): MTML held still, MTMR moving along a straight line at constant
   speed for ``--seconds`` s; CPU of each node over that time.

Latency. Every sample of MTMR's handle has its own position ``s`` on the line; the teleop maps it
to a tool position on a line (a fifth of it). For each message a stage publishes, the probe
finds the sample it shows (from its position, after a still second that fixes the line's origin
at each stage) and records its age: receive time minus the time that sample was sent. Only the
first message showing a sample counts. Stages: input -> ``MTMR/measured_cp`` (the MTM node's
period and one hop), -> ``PSM1/servo_cp`` (plus the teleop's period and a hop), ->
``PSM1/setpoint_cp`` (plus the simulator taking the goal, its physics step and its 100 Hz state
publication).

``--before REV`` runs the same phases first with the code of git revision ``REV`` (checked out in
a temporary worktree, imported before this checkout's), then with this checkout's, and prints
both side by side with their ratios. Run it on a quiet machine: CPU shares and latencies move with
the machine's load.

Run: ``.venv/bin/python bench/bench_teleop.py [--before main] [--rest 10] [--seconds 20]``
"""

import argparse
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import threading
import time

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(10 + os.getpid() % 80))
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ['PYTHONUNBUFFERED'] = '1'

from before_revision import code_env, measure_before  # noqa: E402
import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

RATE = 200.0
SPEED = 0.01          # m/s of the handle (a calm hand): 50 um between samples
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATE = QoSProfile(depth=100)
STAGES = ('MTMR/measured_cp', 'PSM1/servo_cp', 'PSM1/setpoint_cp')
TELEOPS = ('MTMR_PSM1', 'MTML_PSM2')


def graph(out_dir):
    """Return ``(label, argv)`` of every node of the demonstration graph."""
    return [
        ('simulator', ['simulator', '--ros-args', '-p', 'real_time_factor:=1.0',
                       '-p', 'footpedals:=false']),
        ('viewer', ['viewer', '--ros-args', '-p', 'port:=18080']),
        ('mtms', ['mtms', '--ros-args', '-p', 'device:=browser']),
        ('teleop MTMR_PSM1', ['teleop', '--ros-args', '-r', '__node:=MTMR_PSM1', '-p',
                              'mtm:=MTMR', '-p', 'psm:=PSM1']),
        ('teleop MTML_PSM2', ['teleop', '--ros-args', '-r', '__node:=MTML_PSM2', '-p',
                              'mtm:=MTML', '-p', 'psm:=PSM2']),
        ('recorder', ['recorder', '--ros-args', '-p', f'output_dir:={out_dir}',
                      '-p', 'use_sim_time:=true']),
        ('footpedals', ['footpedals']),
    ]


def start(argv, log_dir, label, env):
    exe = shutil.which(argv[0], path=str(Path(sys.executable).parent))
    log = open(Path(log_dir) / f'{label.replace(" ", "_")}.log', 'w')
    from sim_bridge.common.processes import popen
    return popen([exe, *argv[1:]], stdout=log, stderr=subprocess.STDOUT, env=env)


def stop(proc):
    from sim_bridge.common.processes import stop_group
    stop_group(proc, 10.0)


def cpu_seconds(pid):
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def cpu_shares(procs, seconds, during=None):
    """Return each process's CPU (fraction of a core) over ``seconds`` of wall time."""
    c0 = {label: cpu_seconds(p.pid) for label, p in procs.items()}
    t0 = time.monotonic()
    if during is None:
        time.sleep(seconds)
    else:
        during()
    wall = time.monotonic() - t0
    return {label: (cpu_seconds(p.pid) - c0[label]) / wall for label, p in procs.items()}


class Stage:
    """Positions seen by one stage (world frame, m) with their receive times."""

    def __init__(self, gain):
        self.gain = gain          # handle metres per metre shown at this stage
        self.origin = None
        self.seen = []            # (receive time, position)
        self.lock = threading.Lock()


def measure(label, code, args, domain_id):
    """Run the phases with the code of ``code`` (None: this checkout); return the numbers."""
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Joy
    from sim_bridge.ros import conversions as cv
    from std_msgs.msg import Float64, String

    log_dir = tempfile.mkdtemp(prefix='bench-teleop-')
    env = code_env(code, {**os.environ, 'ROS_DOMAIN_ID': str(domain_id)})
    procs = {name: start(argv, log_dir, name, env) for name, argv in graph(log_dir + '/bags')}
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('bench_teleop', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    state = {'base': None, 'tool': {}, 'camera': None}
    teleop_state = {}
    stages = {'MTMR/measured_cp': Stage(1.0), 'PSM1/servo_cp': Stage(5.0),
              'PSM1/setpoint_cp': Stage(5.0)}

    def on_stage(name):
        def callback(msg):
            # every stage is in the camera frame (the MTM's display frame, the PSM's ECM on a
            # patient cart) or in PSM1_base (an arm on its own): seen in world here
            t = time.monotonic()
            T = cv.matrix_from_pose(msg.pose)
            to_world = state['base'] if msg.header.frame_id == 'PSM1_base' else state['camera']
            if to_world is None:
                return
            st = stages[name]
            with st.lock:
                st.seen.append((t, (to_world @ T)[:3, 3].copy()))
        return callback

    for name in STAGES:
        node.create_subscription(PoseStamped, name, on_stage(name), STATE)
    for name in TELEOPS:
        node.create_subscription(String, f'/{name}/current_state',
                                 lambda m, n=name: teleop_state.__setitem__(n, m.data), LATCHED)
    bases = {}
    for arm in ('PSM1', 'PSM2'):
        node.create_subscription(PoseStamped, f'sim/{arm}/base_frame',
                                 lambda m, a=arm: bases.__setitem__(a, cv.matrix_from_pose(
                                     m.pose)), LATCHED)
        node.create_subscription(PoseStamped, f'{arm}/local/measured_cp',   # in its base
                                 lambda m, a=arm: state['tool'].__setitem__(
                                     a, cv.matrix_from_pose(m.pose)), STATE)
    node.create_subscription(PoseStamped, 'ECM/measured_cp',  # in world on a patient cart
                             lambda m: state.__setitem__('camera', cv.matrix_from_pose(m.pose)),
                             STATE)
    pubs = {m: (node.create_publisher(PoseStamped, f'viewer/input/{m}/pose', STATE),
                node.create_publisher(Float64, f'viewer/input/{m}/gripper', STATE))
            for m in ('MTMR', 'MTML')}
    pedal_pub = node.create_publisher(Joy, 'viewer/input/pedals', STATE)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    result = {'label': label, 'rest': {}, 'following': {}, 'latency': {}}
    sent = []            # (send time, handle position s along the line)
    try:
        deadline = time.monotonic() + 300
        while (len(bases) < 2 or len(state['tool']) < 2 or len(teleop_state) < 2
               or state['camera'] is None) and time.monotonic() < deadline:
            if any(p.poll() is not None for p in procs.values()):
                sys.exit(f'a node exited at start-up; logs in {log_dir}')
            time.sleep(0.1)
        if len(bases) < 2 or len(state['tool']) < 2:
            sys.exit('the simulator did not start; logs in ' + log_dir)
        state['base'] = bases['PSM1']
        time.sleep(args.settle)      # the arms power up and home; the teleops wait for hands
        result['load'] = [_loadavg()]
        result['rest'] = cpu_shares(procs, args.rest)
        result['rest_states'] = dict(teleop_state)
        hands0 = {'MTMR': bases['PSM1'] @ state['tool']['PSM1'],
                  'MTML': bases['PSM2'] @ state['tool']['PSM2']}
        u = np.array([1.0, 0.0, 0.0])

        def publish(s, gripper, coag):
            stamp = node.get_clock().now().to_msg()
            for mtm, T0 in hands0.items():
                T = T0.copy()
                if mtm == 'MTMR':
                    T[:3, 3] += s * u
                pubs[mtm][0].publish(cv.pose_stamped(T, 'world', stamp))
                pubs[mtm][1].publish(Float64(data=gripper))
            joy = Joy()
            joy.buttons = [0, int(coag)]
            pedal_pub.publish(joy)

        # sit down, pinch the grippers, wait for both teleops to follow
        t0 = time.monotonic()
        k = 0
        while any(teleop_state.get(n) != 'FOLLOWING' for n in TELEOPS):
            if time.monotonic() - t0 > 120:
                sys.exit(f'the teleops did not follow ({teleop_state}); logs in {log_dir}')
            publish(0.0, 0.6 + 0.15 * (k // 40 % 2), time.monotonic() - t0 > 1)
            k += 1
            time.sleep(1 / RATE)
        # a still second and a half fixes each stage's origin, then MTMR moves at SPEED
        t_still = time.monotonic()
        while time.monotonic() - t_still < 1.5:
            publish(0.0, 0.6, True)
            time.sleep(1 / RATE)
        for st in stages.values():
            with st.lock:
                st.origin = st.seen[-1][1].copy() if st.seen else None
                st.seen = []

        def follow():
            start_t = time.monotonic()
            i = 0
            while i / RATE < args.seconds:
                delay = start_t + i / RATE - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                s = SPEED * i / RATE
                sent.append((time.monotonic(), s))
                publish(s, 0.6, True)
                i += 1
            time.sleep(0.5)

        result['following'] = cpu_shares(procs, args.seconds, during=follow)
        result['load'].append(_loadavg())
    finally:
        executor.shutdown(timeout_sec=2)
        spin.join(60.0)              # its last wait ends before the node's handles go (a
                                     # loaded machine takes seconds to end it)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        for p in reversed(list(procs.values())):
            stop(p)
    send_t = np.array([t for t, _ in sent])
    send_s = np.array([s for _, s in sent])
    step = SPEED / RATE
    for name, st in stages.items():
        ages, shown = [], set()
        if st.origin is not None:
            for t, p in st.seen:
                s = float(u @ (p - st.origin)) * st.gain
                k = int(round(s / step))
                if k < 0 or k >= len(send_s) or abs(send_s[k] - s) > 0.25 * step or k in shown:
                    continue
                shown.add(k)
                if t >= send_t[k]:
                    ages.append(t - send_t[k])
        a = np.array(ages) * 1000
        result['latency'][name] = ((float(np.percentile(a, 50)), float(np.percentile(a, 99)),
                                    len(a)) if len(a) else None)
    result['samples'] = len(send_s)
    shutil.rmtree(log_dir, ignore_errors=True)
    return result


def _loadavg():
    return Path('/proc/loadavg').read_text().split()[0]


def _verdict(value, target):
    return 'meets' if value <= target else 'misses'


def report(results):
    """Print the CPU and latency tables, each run side by side (ratios: last / first)."""
    labels = [r['label'] for r in results]
    print(f'\n{os.cpu_count()} CPUs; 1-minute load average at the start of the rest phase and '
          'at the end of the following phase: '
          + ', '.join(f'{r["label"]} {" -> ".join(r.get("load", []))}' for r in results))
    print('A load above 1 means other work shared the CPUs: the figures, not only the ratios, '
          'then move with it; the targets are for a quiet machine (load below 1).')
    ratio = len(results) == 2
    head = ''.join(f'{x:>18}' for x in labels) + (f'{"ratio":>8}' if ratio else '')
    for phase in ('rest', 'following'):
        print(f'\nCPU {"at rest" if phase == "rest" else "while following"} '
              f'(% of one core){"" if phase != "rest" else " - target: whole graph <= 50 %"}')
        print(f'{"node":<20}{head}')
        nodes = list(results[0][phase])
        for name in [*nodes, 'whole graph']:
            values = [100 * (sum(r[phase].values()) if name == 'whole graph' else r[phase][name])
                      for r in results]
            verdict = f'  {_verdict(values[-1], 50.0)} the target' \
                if phase == 'rest' and name == 'whole graph' else ''
            print(f'{name:<20}' + ''.join(f'{v:>18.1f}' for v in values)
                  + (f'{values[1] / values[0]:>8.2f}' if ratio and values[0] else '') + verdict)
    print('\nteleop latency, handle input at 200 Hz -> stage, p50 / p99 ms '
          '- anchor: the dVRK teleop period 1 ms (C++) .. 5 ms (Python); target p99 <= 20 ms')
    print(f'{"input ->":<20}{head}')
    for name in STAGES:
        cells, p99 = [], []
        for r in results:
            lat = r['latency'][name]
            cells.append(f'{lat[0]:.1f} / {lat[1]:.1f}' if lat else 'none')
            p99.append(lat[1] if lat else None)
        verdict = f'  {_verdict(p99[-1], 20.0)} the target' \
            if name == 'PSM1/setpoint_cp' and p99[-1] is not None else ''
        print(f'{name:<20}' + ''.join(f'{c:>18}' for c in cells)
              + (f'{p99[1] / p99[0]:>8.2f}' if ratio and all(p99) else '') + verdict)
    for r in results:
        lat = r['latency']['PSM1/setpoint_cp']
        if lat:
            print(f'{r["label"]}: setpoint_cp p50 = {lat[0] / 5:.1f} x 5 ms, {lat[0]:.0f} x 1 ms; '
                  f'{lat[2]} samples shown of {r["samples"]}; teleops at rest: '
                  f'{r["rest_states"]}')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--before', default=None,
                        help='git revision whose code runs the same phases first')
    parser.add_argument('--rest', type=float, default=10.0, help='s measured at rest')
    parser.add_argument('--settle', type=float, default=8.0,
                        help='s after start-up before measuring at rest')
    parser.add_argument('--seconds', type=float, default=20.0, help='s measured following')
    args = parser.parse_args()
    domain = int(os.environ['ROS_DOMAIN_ID'])
    print(f'load average at the start: {_loadavg()} ({os.cpu_count()} CPUs)')
    results = []
    if args.before:
        results.append(measure_before(
            args.before, lambda code: measure(f'before ({args.before})', code, args, domain + 1)))
    results.append(measure('now', None, args, domain))
    print(f'load average at the end: {_loadavg()}')
    report(results)


if __name__ == '__main__':
    main()
