"""
Teleoperation latency: a hand's motion on the virtual MTM's input -> PSM1's state, through the
``mtms`` and ``teleop`` nodes and the simulator, against the dVRK's own teleop period.

Anchor: the dVRK runs its MTM -> PSM teleoperation every 1 ms (the C++ teleop component) to
5 ms (``dvrk_teleoperation.py``, ``--interval 0.005``); its arm state is published at 100 Hz.

Processes (each its own rclpy process on loopback): the simulator (``real_time_factor`` 1), the
virtual MTMs (browser back-end) and one teleop node (MTMR -> PSM1, 200 Hz); this probe streams
the viewer's handle pose ``viewer/input/MTMR/pose`` at 200 Hz from its own thread (sleep
pacing, as a teleoperation client does) and subscribes to ``MTMR/measured_cp`` (the virtual MTM),
``PSM1/servo_cp`` (the teleop's command) and ``PSM1/setpoint_cp`` (the simulated arm's goal).

Metric. The handle moves along a straight line at constant speed, so every sample has its own
position ``s`` on it; the teleop maps it to a tool position on a line (a fifth of it). For each
message a stage publishes, the probe finds the sample it shows (from its position, after a
still second that fixes the line's origin at each stage) and records its age: receive time
minus the time that sample was sent. Only the first message showing a sample counts. Stages:
input -> ``MTMR/measured_cp`` (the MTM node's period and one hop), -> ``PSM1/servo_cp`` (plus the
teleop's period and a hop), -> ``PSM1/setpoint_cp`` (plus the simulator taking the goal, its
physics step and its 100 Hz state publication). Also the teleop node's CPU per cycle
(``/proc/<pid>/stat`` user + system time over the run).

The machine is shared with other work: numbers vary with its load; CPU time is steadier than
wall time.

Run: ``.venv/bin/python bench/bench_teleop.py [--seconds 20]``
"""

import argparse
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import threading
import time

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', str(10 + os.getpid() % 90))
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ['PYTHONUNBUFFERED'] = '1'

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

RATE = 200.0
SPEED = 0.01          # m/s of the handle (a calm hand): 50 um between samples
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATE = QoSProfile(depth=100)


def start(name, *args, log_dir):
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    log = open(Path(log_dir) / f'{name}.log', 'w')
    return subprocess.Popen([exe, *args], stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)


def stop(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def cpu_seconds(pid):
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class Stage:
    """Positions seen by one stage, projected on the handle's line (metres of handle motion)."""

    def __init__(self, gain):
        self.gain = gain          # handle metres per metre shown at this stage
        self.origin = None
        self.seen = []            # (receive time, position on the line, m of handle)
        self.lock = threading.Lock()

    def add(self, t, p_world, u):
        with self.lock:
            self.seen.append((t, p_world.copy(), u))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--seconds', type=float, default=20.0)
    args = parser.parse_args()
    import tempfile

    from crtk_msgs.msg import OperatingState  # noqa: F401 (the interfaces are built)
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Joy
    from sim_bridge.ros import conversions as cv
    from std_msgs.msg import Float64, String
    log_dir = tempfile.mkdtemp(prefix='bench-teleop-')
    procs = [start('simulator', '--ros-args', '-p', 'footpedals:=false', log_dir=log_dir),
             start('mtms', '--ros-args', '-p', 'device:=browser', log_dir=log_dir),
             start('teleop', '--ros-args', '-r', '__node:=MTMR_PSM1', log_dir=log_dir)]
    rclpy.init()
    node = rclpy.create_node('bench_teleop')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    state = {'teleop': None, 'base': None, 'tool': None, 'camera': None}
    stages = {'MTMR/measured_cp': Stage(1.0), 'PSM1/servo_cp': Stage(5.0),
              'PSM1/setpoint_cp': Stage(5.0)}

    def on_stage(name):
        def callback(msg):
            # every stage is in the camera frame (the MTM's display frame HRSV, the PSM's ECM
            # on a patient cart) or in PSM1_base (an arm on its own): seen in world here
            T = cv.matrix_from_pose(msg.pose)
            frame = msg.header.frame_id
            to_world = state['base'] if frame == 'PSM1_base' else state['camera']
            if to_world is None:
                return
            stages[name].add(time.monotonic(), (to_world @ T)[:3, 3], None)
        return callback

    for name in stages:
        node.create_subscription(PoseStamped, name, on_stage(name), STATE)
    node.create_subscription(String, '/MTMR_PSM1/current_state',
                             lambda m: state.__setitem__('teleop', m.data), LATCHED)
    node.create_subscription(PoseStamped, 'sim/PSM1/base_frame',
                             lambda m: state.__setitem__('base', cv.matrix_from_pose(m.pose)),
                             LATCHED)
    node.create_subscription(PoseStamped, 'PSM1/local/measured_cp',
                             lambda m: state.__setitem__('tool', cv.matrix_from_pose(m.pose)),
                             STATE)
    node.create_subscription(PoseStamped, 'ECM/measured_cp',  # in world on a patient cart
                             lambda m: state.__setitem__('camera', cv.matrix_from_pose(m.pose)),
                             STATE)
    pose_pub = node.create_publisher(PoseStamped, 'viewer/input/MTMR/pose', STATE)
    grip_pub = node.create_publisher(Float64, 'viewer/input/MTMR/gripper', STATE)
    pedal_pub = node.create_publisher(Joy, 'viewer/input/pedals', STATE)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    sent = []            # (send time, handle position s along the line)
    try:
        deadline = time.monotonic() + 90
        while (state['tool'] is None or state['base'] is None or state['camera'] is None) \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        if state['tool'] is None:
            sys.exit('the simulator did not start; logs in ' + log_dir)
        hand0 = state['base'] @ state['tool']
        u = np.array([1.0, 0.0, 0.0])

        def publish(s, gripper, coag):
            T = hand0.copy()
            T[:3, 3] += s * u
            pose_pub.publish(cv.pose_stamped(T, 'world', node.get_clock().now().to_msg()))
            grip_pub.publish(Float64(data=gripper))
            joy = Joy()
            joy.buttons = [0, int(coag)]
            pedal_pub.publish(joy)

        # sit down, pinch the gripper, wait for following
        t0 = time.monotonic()
        k = 0
        while state['teleop'] != 'FOLLOWING':
            if time.monotonic() - t0 > 120:
                sys.exit(f'the teleop did not follow ({state["teleop"]}); logs in {log_dir}')
            publish(0.0, 0.6 + 0.15 * (k // 40 % 2), time.monotonic() - t0 > 3)
            k += 1
            time.sleep(1 / RATE)
        # a still second fixes each stage's origin, then the handle moves at SPEED
        t_still = time.monotonic()
        while time.monotonic() - t_still < 1.5:
            publish(0.0, 0.6, True)
            time.sleep(1 / RATE)
        for st in stages.values():
            with st.lock:
                st.origin = st.seen[-1][1].copy() if st.seen else None
                st.seen = []
        teleop_pid = procs[2].pid
        cpu0, wall0 = cpu_seconds(teleop_pid), time.monotonic()
        start_t = time.monotonic()
        i = 0
        while True:
            t_next = start_t + i / RATE
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            s = SPEED * i / RATE
            sent.append((time.monotonic(), s))
            publish(s, 0.6, True)
            i += 1
            if i / RATE >= args.seconds:
                break
        time.sleep(0.5)
        cpu1, wall1 = cpu_seconds(teleop_pid), time.monotonic()
    finally:
        executor.shutdown(timeout_sec=2)
        node.destroy_node()
        rclpy.try_shutdown()
        for p in reversed(procs):
            stop(p)
    send_t = np.array([t for t, _ in sent])
    send_s = np.array([s for _, s in sent])
    step = SPEED / RATE
    print(f'teleop latency, handle input at {RATE:.0f} Hz for {args.seconds:.0f} s '
          '(machine shared with other work)')
    print('anchor: the dVRK teleop period, 1 ms (C++ component) .. 5 ms (Python script)')
    for name, st in stages.items():
        if st.origin is None:
            print(f'  {name}: nothing received')
            continue
        ages, shown = [], set()
        for t, p, _ in st.seen:
            s = float(u @ (p - st.origin)) * st.gain
            k = int(round(s / step))
            if k < 0 or k >= len(send_s) or abs(send_s[k] - s) > 0.25 * step or k in shown:
                continue
            shown.add(k)
            if t >= send_t[k]:
                ages.append(t - send_t[k])
        if not ages:
            print(f'  {name}: no sample identified')
            continue
        a = np.array(ages) * 1000
        p50, p99 = np.percentile(a, 50), np.percentile(a, 99)
        print(f'  input -> {name:17s} p50 {p50:6.1f} ms  p99 {p99:6.1f} ms  '
              f'({len(a)} samples shown of {len(send_s)}; p50 = {p50 / 5:.1f} x 5 ms, '
              f'{p50:.0f} x 1 ms)')
    cycles = (wall1 - wall0) * RATE
    print(f'  teleop node CPU: {(cpu1 - cpu0) / (wall1 - wall0) * 100:.0f} % of a core, '
          f'{(cpu1 - cpu0) / cycles * 1e3:.2f} ms per 5 ms cycle')


if __name__ == '__main__':
    main()
