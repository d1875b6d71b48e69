"""
The simulator node under a long dVRK client load, and stopped and restarted under it many times.

Processes (each its own rclpy process on loopback):

- the simulator (``real_time_factor`` 1, default configuration), started and stopped by this
  script: SIGINT, as a user's Ctrl-C or a launch file does, then SIGKILL only after 30 s;
- a *streamer* that enables and homes PSM1 and PSM2 (again after every restart of the
  simulator) and streams ``PSM1/servo_cp`` and ``PSM2/servo_cp`` at 1 kHz each, a 1 mm circle
  around the arms' home poses (around their measured pose until they are homed: goals an arm
  that is not ready answers with a throttled warning), also while the simulator restarts;
- a *client* subscribed to the full state of the three arms (what ``dvrk.psm('PSM1')``,
  ``dvrk.psm('PSM2')`` and ``dvrk.ecm('ECM')`` subscribe, about 4300 messages/s; the client role
  of ``bench_simulator_node.py``).

Two phases:

1. a soak of ``--minutes``: the real-time factor the simulator achieved (``sim/stats``, each
   second), gaps over 50 ms between ``PSM1/measured_js`` messages in the client (count and the
   longest), the simulator's resident memory (RSS, from ``/proc``) after the first 30 s and at
   the end, and its exit code after the SIGINT;
2. ``--stops`` rounds of start (until the node says it simulates), ``--round-seconds`` of
   streaming, SIGINT: the exit codes (130, or 0, is a
   clean stop; a negative code is the signal that killed it, -11 a SIGSEGV), the time each took
   to exit, and any line of a Python traceback or a fatal message in its log.

Run: ``.venv/bin/python bench/bench_soak.py [--minutes 10] [--stops 100] [--round-seconds 5]``.
The numbers depend on the machine's load; the script prints them, and asserts nothing.
"""

import argparse
import json
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
if '--role' not in sys.argv:  # role processes inherit the run's private domain
    os.environ['ROS_DOMAIN_ID'] = str(100 + os.getpid() % 100)

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_simulator_node as node_bench  # noqa: E402

STREAM_HZ = 1000.0
PSMS = ('PSM1', 'PSM2')
GAP_S = 0.05
WARMUP_S = 30.0
CLEAN_EXITS = (0, 130)   # a node stopped by SIGINT exits 130 (0 before nodes said so)


# -- the streamer role -----------------------------------------------------------------------

def role_stream(_args):
    """Keep PSM1 and PSM2 enabled and homed; stream servo_cp to both at 1 kHz until SIGINT."""
    from crtk_msgs.msg import OperatingState, StringStamped
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from rclpy.qos import QoSProfile

    rclpy.init()
    node = rclpy.create_node('bench_streamer')
    state_qos, event_qos = node_bench.qos_profiles()
    lock = threading.Lock()
    states, homes, latest = {}, {}, {}
    command = {a: node.create_publisher(StringStamped, f'{a}/state_command', 10) for a in PSMS}
    servo = {a: node.create_publisher(PoseStamped, f'{a}/servo_cp', QoSProfile(depth=10))
             for a in PSMS}

    def on_state(arm, msg):
        with lock:
            states[arm] = msg

    def on_cp(arm, msg):
        with lock:
            latest[arm] = msg
            if arm not in homes and arm in states and states[arm].is_homed \
                    and not states[arm].is_busy:
                homes[arm] = msg

    for a in PSMS:
        node.create_subscription(OperatingState, f'{a}/operating_state',
                                 lambda m, a=a: on_state(a, m), event_qos)
        node.create_subscription(PoseStamped, f'{a}/measured_cp',
                                 lambda m, a=a: on_cp(a, m), state_qos)

    def keep_ready():
        with lock:
            for a in PSMS:
                s = states.get(a)
                if s is None:
                    continue
                if s.state != 'ENABLED':
                    command[a].publish(StringStamped(string='enable'))
                elif not s.is_homed and not s.is_busy:
                    command[a].publish(StringStamped(string='home'))
    node.create_timer(0.5, keep_ready)
    executor, thread = node_bench.spin_in_thread(node)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print('ready', flush=True)
    sent, k, t0 = 0, 0, time.monotonic()
    period = 1.0 / STREAM_HZ
    while not stop.is_set():
        with lock:   # around the home pose once homed; until then where the arm is
            poses = {a: homes.get(a) or latest[a] for a in latest}
        angle = 2.0 * math.pi * 0.5 * k * period
        for a, home in poses.items():
            msg = PoseStamped()
            msg.header = home.header
            msg.pose.orientation = home.pose.orientation
            msg.pose.position.x = home.pose.position.x + 1e-3 * math.cos(angle)
            msg.pose.position.y = home.pose.position.y + 1e-3 * math.sin(angle)
            msg.pose.position.z = home.pose.position.z
            servo[a].publish(msg)
            sent += 1
        k += 1
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))
    node_bench.finish(executor, thread, node)
    print(json.dumps({'sent': sent, 'seconds': time.monotonic() - t0}), flush=True)


# -- the orchestrating process ------------------------------------------------------------------

def rss_bytes(pid):
    """Resident memory of a process (bytes), from /proc; None once it is gone."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


class Simulator:
    """The simulator node process, its log in a file."""

    def __init__(self, bin_dir, log_path):
        self.log_path = log_path
        self.log = open(log_path, 'w')
        self.proc = subprocess.Popen(
            [str(bin_dir / 'simulator'), '--ros-args', '-p', 'real_time_factor:=1.0'],
            stdout=self.log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            start_new_session=True)
        self.pid = self.proc.pid
        self.started = time.monotonic()

    def wait_running(self, timeout=180.0):
        """Wait until the node logs that it simulates (its start-up is over)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.proc.poll() is None:
            if 'simulating' in Path(self.log_path).read_text(errors='replace'):
                self.started = time.monotonic()
                return True
            time.sleep(0.1)
        return False

    def stop(self):
        """SIGINT, wait (SIGKILL after 30 s); return (exit code, seconds to exit, log problems)."""
        t = time.monotonic()
        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(30.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = f'hung, killed ({self.proc.wait(10.0)})'
        took = time.monotonic() - t
        self.log.close()
        text = Path(self.log_path).read_text(errors='replace')
        problems = [line for line in text.splitlines()
                    if 'Traceback' in line or 'FATAL' in line or 'Segmentation' in line
                    or 'RCLError' in line]
        return code, took, problems


def soak(bin_dir, tmp, minutes):
    client = node_bench.Proc.role('client', '--arms', ','.join(node_bench.ARMS), '--out',
                                  str(tmp / 'client_soak.json'), stdin=True)
    client.expect('ready', 120.0)
    sim = Simulator(bin_dir, tmp / 'soak.log')
    sim.wait_running()
    rss = []
    end = time.monotonic() + minutes * 60.0
    while time.monotonic() < end and sim.proc.poll() is None:
        rss.append((time.monotonic() - sim.started, rss_bytes(sim.pid)))
        time.sleep(min(5.0, max(0.0, end - time.monotonic())))
    rss.append((time.monotonic() - sim.started, rss_bytes(sim.pid)))
    code, took, problems = sim.stop()
    client.tell('stop')
    client.wait(60.0)
    log = json.loads((tmp / 'client_soak.json').read_text())
    t_start = sim.started + WARMUP_S
    achieved = [s['achieved'] for t, s in log['stats'] if t >= t_start and 'achieved' in s]
    arrivals = [t for t, _ in log['measured_js'] if t >= t_start]
    gaps = [b - a for a, b in zip(arrivals, arrivals[1:]) if b - a > GAP_S]
    warm = [r for t, r in rss if t >= WARMUP_S and r]
    return {
        'minutes': minutes,
        'rtf_mean': sum(achieved) / len(achieved) if achieved else None,
        'rtf_min': min(achieved) if achieved else None,
        'gaps_over_50ms': len(gaps), 'longest_gap_s': max(gaps, default=0.0),
        'measured_js_messages': len(arrivals),
        'rss_after_warmup_mb': warm[0] / 2**20 if warm else None,
        'rss_end_mb': warm[-1] / 2**20 if warm else None,
        'rss_growth_pct': 100.0 * (warm[-1] / warm[0] - 1.0) if len(warm) > 1 else None,
        'exit_code': code, 'exit_s': took, 'log_problems': problems,
    }


def rounds(bin_dir, tmp, stops, round_seconds):
    client = node_bench.Proc.role('client', '--arms', ','.join(node_bench.ARMS), '--out',
                                  str(tmp / 'client_rounds.json'), stdin=True)
    client.expect('ready', 120.0)
    results = []
    for k in range(stops):
        sim = Simulator(bin_dir, tmp / f'round{k:03d}.log')
        sim.wait_running()
        time.sleep(round_seconds)
        code, took, problems = sim.stop()
        results.append({'round': k, 'exit_code': code, 'exit_s': took, 'problems': problems})
        print(f'  stop {k + 1}/{stops}: exit {code} in {took:.2f} s'
              + (f'; {problems[:2]}' if problems else ''), flush=True)
        if code not in CLEAN_EXITS:
            os.replace(tmp / f'round{k:03d}.log', tmp / f'failed_round{k:03d}.log')
    client.tell('stop')
    client.wait(60.0)
    codes = {}
    for r in results:
        codes[str(r['exit_code'])] = codes.get(str(r['exit_code']), 0) + 1
    return {'stops': stops, 'round_seconds': round_seconds, 'exit_codes': codes,
            'crashes': sum(1 for r in results if r['exit_code'] not in CLEAN_EXITS),
            'exit_s_max': max((r['exit_s'] for r in results), default=None),
            'rounds_with_log_problems': [r for r in results if r['problems']]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--role', choices=('stream',), help=argparse.SUPPRESS)
    parser.add_argument('--minutes', type=float, default=10.0, help='soak length (min)')
    parser.add_argument('--stops', type=int, default=100, help='stop/start rounds')
    parser.add_argument('--round-seconds', type=float, default=5.0,
                        help='streaming time per stop/start round (s)')
    parser.add_argument('--keep', default='', help='folder to keep the logs in')
    args = parser.parse_args()
    if args.role == 'stream':
        return role_stream(args)
    bin_dir = Path(sys.executable).parent
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix='bench_soak_'))
    tmp.mkdir(parents=True, exist_ok=True)
    streamer = subprocess.Popen([sys.executable, __file__, '--role', 'stream'],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                start_new_session=True)
    print(f'machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; '
          f'logs in {tmp}', flush=True)
    report = {}
    try:
        if streamer.stdout.readline().strip() != 'ready':
            raise RuntimeError('the streamer did not start')
        if args.minutes > 0:
            report['soak'] = soak(bin_dir, tmp, args.minutes)
            print(json.dumps({'soak': report['soak']}, indent=1), flush=True)
        if args.stops > 0:
            report['rounds'] = rounds(bin_dir, tmp, args.stops, args.round_seconds)
    finally:
        streamer.send_signal(signal.SIGINT)
        try:
            out, _ = streamer.communicate(timeout=30.0)
            lines = out.strip().splitlines()
            report['streamer'] = json.loads(lines[-1]) if lines else None
        except (subprocess.TimeoutExpired, ValueError):
            streamer.kill()
    report['load_average_end'] = os.getloadavg()[0]
    print(json.dumps(report, indent=1, default=str), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
