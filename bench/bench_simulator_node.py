"""
The simulator node under a dVRK client's load: latency, state rate and jitter, CPU, pace.

Anchors, measured in the same run with the same process layout and the same probe:

- a plain rclpy echo between two processes: the probe process publishes PoseStamped at 1 kHz on
  ``echo/in`` and an echo process republishes each on ``echo/out``; the round trip time (RTT) is
  what two DDS hops between rclpy processes cost here (reference figures: RTT p50 0.5 ms, p99
  3 ms at 1 kHz, ros2_ecosystem.md section 5);
- the dVRK publishes arm state at 100 Hz (from a 1.5 kHz control loop); the issue's target is
  ``servo_cp`` latency p99 <= 3 ms end to end.

Processes (each its own rclpy process on loopback, so that no measuring process is the bottleneck
of another's measurement):

- the simulator (``real_time_factor`` 1, default configuration);
- a *client* that subscribes to the state of all three arms, what ``dvrk.psm('PSM1')``,
  ``dvrk.psm('PSM2')`` and ``dvrk.ecm('ECM')`` objects subscribe (dvrk_crtk.md section 5: 15
  topics per PSM, 13 for the ECM, about 4300 messages/s), spun by a ``SingleThreadedExecutor``
  as crtk-py does; it only counts what it receives (and the 100 Hz ``measured_js`` of PSM1);
- a light *probe* that streams ``PSM1/servo_cp`` at 1 kHz (sleep pacing from its own thread, as
  a teleoperation client does) and subscribes to ``PSM1/setpoint_cp``, ``PSM1/measured_cp`` and
  ``PSM1/measured_js`` only.

The simulator phase runs twice: with the probe alone (what the node adds to the anchor's round
trip) and with the probe and the full client (the issue's load; on a two-core machine the three
processes then compete for the cores, and the client's ~4000 messages/s in one rclpy process are
most of the load).

Latency metric. Each goal the probe sends carries a unique ``y`` coordinate. The dVRK applies a
servo goal in its control loop and shows it in the state it publishes next (100 Hz); the
simulator does the same with its physics step. For every ``setpoint_cp`` the probe receives, it
looks up the goal that message shows and records its *age*: receive time minus the time that goal
was sent. Since goals change every 1 ms and the state every 10 ms, each goal is shown at most
once, so the age is also the delay from sending a command to the first state message reflecting
it. The age holds two DDS hops (command, state: one round trip, the anchor's RTT), the wait for
the node to take the command and for the physics step that applies it, and how old the newest
goal already is when the state is sampled (0..1 ms at 1 kHz). Only the first message showing a
goal counts (after the stream ends the last goal stays shown). ``measured_cp`` is sampled at the
same instant from the same physics step, but the simulated arm tracks its setpoint under the
dVRK joint speed and acceleration limits (like the physical arm's PID), so it shows the goal up
to a tracking error rather than exactly: the probe reports its distance to the goal shown in the
``setpoint_cp`` of the same publication (same stamp) instead of an age.

Also measured:

- in-process, first: the cost of one physics step of the bare core, of the node's stepping round
  with no subscribers, and with every state topic subscribed (what publishing the state of
  three arms costs), i.e. the node's overhead and the real-time factor one free core allows;
- the rate and inter-arrival jitter ``|dt - 10 ms|`` of ``PSM1/measured_js`` in the probe and in
  the client, and the share of the expected state messages the client received;
- CPU use (share of one core) of the simulator, the client and the probe while streaming, and
  the real-time factor the simulator achieved (``sim/stats``);
- the factor reached at ``real_time_factor`` 0 (as fast as it goes) with no state subscribers,
  and with the full client.

Gaps (``--gaps``): the dVRK's teleoperation script reads each arm's state in a 5 ms loop and
raises when it is older than 20 ms; the dVRK publishes every 10 ms. With the full client running,
the gaps between consecutive ``measured_cp``, ``setpoint_cp`` and ``measured_js`` messages of
each arm as the client receives them (median, p99, max, and how many exceed 20 ms), idle and
with ``--load`` busy processes competing for the cores, for this tree and, with ``--before
REV``, the simulator of another revision in the same run.

Run: ``.venv/bin/python bench/bench_simulator_node.py [--seconds 10]``; gaps:
``.venv/bin/python bench/bench_simulator_node.py --gaps --before main [--seconds 20]``
"""

import argparse
import json
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

import numpy as np  # noqa: E402

ANCHOR_STATE_HZ = 100.0
TARGET_P99_S = 3e-3
STREAM_HZ = 1000.0
ARMS = ('PSM1', 'PSM2', 'ECM')
# what dvrk.psm / dvrk.ecm objects subscribe (dvrk_crtk.md section 5); jaw/* for PSMs only
STATE_TOPICS = ('setpoint_js', 'setpoint_cp', 'measured_js', 'measured_cp', 'measured_cv',
                'spatial/measured_cf', 'spatial/jacobian', 'body/measured_cf', 'body/jacobian',
                'local/measured_cp', 'local/setpoint_cp', 'jaw/measured_js', 'jaw/setpoint_js')
EVENT_TOPICS = ('operating_state', 'trajectory_j/ratio')
# the state whose age the dVRK's teleoperation script checks (its getters raise on data older
# than 20 ms: 4 periods of its 5 ms loop)
GAP_TOPICS = ('measured_cp', 'setpoint_cp', 'measured_js')
AGE_LIMIT_S = 0.020


def state_topics(arm):
    return [t for t in STATE_TOPICS if arm != 'ECM' or not t.startswith('jaw/')]


def message_types():
    from crtk_msgs.msg import OperatingState
    from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Float64MultiArray
    return {'setpoint_js': JointState, 'measured_js': JointState, 'jaw/measured_js': JointState,
            'jaw/setpoint_js': JointState, 'setpoint_cp': PoseStamped,
            'measured_cp': PoseStamped, 'local/measured_cp': PoseStamped,
            'local/setpoint_cp': PoseStamped, 'measured_cv': TwistStamped,
            'spatial/measured_cf': WrenchStamped, 'body/measured_cf': WrenchStamped,
            'spatial/jacobian': Float64MultiArray, 'body/jacobian': Float64MultiArray,
            'operating_state': OperatingState, 'trajectory_j/ratio': Float64}


def qos_profiles():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    state = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
    event = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return state, event


# -- role processes -----------------------------------------------------------------------------

def spin_in_thread(node):
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    return executor, thread


def finish(executor, thread, node):
    import rclpy
    executor.shutdown()
    thread.join(2.0)
    node.destroy_node()
    rclpy.try_shutdown()


def wait_for(predicate, timeout, what='benchmark setup'):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f'{what} timed out')
        time.sleep(0.005)


def role_echo(_args):
    """The anchor's far end: republish every PoseStamped of ``echo/in`` on ``echo/out``."""
    from geometry_msgs.msg import PoseStamped
    import rclpy
    rclpy.init()
    node = rclpy.create_node('bench_echo')
    qos, _ = qos_profiles()
    pub = node.create_publisher(PoseStamped, 'echo/out', qos)
    node.create_subscription(PoseStamped, 'echo/in', pub.publish, qos)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def stream(pub, make, rate, seconds):
    """Publish ``make(k)`` at ``rate`` Hz (sleep pacing) for ``seconds``; return send log."""
    period = 1.0 / rate
    sent = []
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < seconds:
        msg, key = make(k)
        sent.append((key, time.monotonic()))
        pub.publish(msg)
        k += 1
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))
    return sent


def role_probe(args):
    """
    Stream PoseStamped goals at 1 kHz and log the replies (``--target echo`` or ``sim``).

    Prints ``streaming`` when it starts and ``done`` when it has written its log (JSON) to
    ``--out``.
    """
    from crtk_msgs.msg import StringStamped
    from geometry_msgs.msg import PoseStamped
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    rclpy.init()
    node = rclpy.create_node('bench_probe')
    state_qos, event_qos = qos_profiles()
    lock = threading.Lock()
    log = {'echo': [], 'setpoint_cp': [], 'measured_cp': [], 'measured_js': [],
           'error': []}

    def keep(name, item):
        with lock:
            log[name].append(item)

    if args.target == 'echo':
        out = node.create_publisher(PoseStamped, 'echo/in', state_qos)
        node.create_subscription(PoseStamped, 'echo/out',
                                 lambda m: keep('echo', (time.monotonic(), m.pose.position.x)),
                                 state_qos)
        executor, thread = spin_in_thread(node)
        wait_for(lambda: out.get_subscription_count() > 0
                 and node.count_publishers('echo/out') > 0, 30.0)
        time.sleep(1.0)

        def make(k):
            msg = PoseStamped()
            msg.pose.position.x = float(k)
            msg.pose.orientation.w = 1.0
            return msg, float(k)
    else:
        from crtk_msgs.msg import OperatingState
        states = []
        homes = []

        def pose(topic, msg):
            p, stamp = msg.pose.position, msg.header.stamp
            keep(topic, (time.monotonic(), p.y, stamp.sec + stamp.nanosec * 1e-9, p.x, p.z))
            if topic == 'setpoint_cp':
                homes[:] = [msg.pose]
        for topic in ('setpoint_cp', 'measured_cp'):
            node.create_subscription(PoseStamped, f'PSM1/{topic}',
                                     lambda m, t=topic: pose(t, m), state_qos)
        node.create_subscription(String, 'PSM1/error', lambda m: keep('error', m.data),
                                 event_qos)
        node.create_subscription(
            JointState, 'PSM1/measured_js',
            lambda m: keep('measured_js', (time.monotonic(),
                                           m.header.stamp.sec + m.header.stamp.nanosec * 1e-9)),
            state_qos)
        node.create_subscription(OperatingState, 'PSM1/operating_state', states.append,
                                 event_qos)
        command = node.create_publisher(StringStamped, 'PSM1/state_command', 1)
        out = node.create_publisher(PoseStamped, 'PSM1/servo_cp', 1)
        executor, thread = spin_in_thread(node)
        wait_for(lambda: out.get_subscription_count() > 0 and log['setpoint_cp'], 60.0)
        for word, ready in (('enable', lambda s: s.state == 'ENABLED'),
                            ('home', lambda s: s.is_homed and not s.is_busy)):
            command.publish(StringStamped(string=word))
            wait_for(lambda r=ready: states and r(states[-1]), 30.0, word)
        time.sleep(0.5)
        home = homes[-1]

        def make(k):
            # tiny side-to-side motion around home, home orientation; y identifies the goal
            y = home.position.y + 0.005 * np.sin(2 * np.pi * k / 2000.0) + (k + 1) * 1e-9
            msg = PoseStamped()
            msg.pose.position.x, msg.pose.position.z = home.position.x, home.position.z
            msg.pose.position.y = float(y)
            msg.pose.orientation = home.orientation
            return msg, float(y)

    with lock:
        for items in log.values():
            items.clear()
    print('streaming', flush=True)
    t0 = time.monotonic()
    sent = stream(out, make, STREAM_HZ, args.seconds)
    t1 = time.monotonic()
    time.sleep(0.3)
    with lock:
        result = {name: list(items) for name, items in log.items()}
    result.update(sent=sent, window=[t0, t1])
    finish(executor, thread, node)
    Path(args.out).write_text(json.dumps(result))
    print('done', flush=True)


def role_client(args):
    """
    Subscribe to what a dVRK client of all three arms subscribes; log until a line on stdin.

    ``--arms ''`` subscribes to ``sim/stats`` only. Writes its log (JSON) to ``--out``.
    """
    import rclpy
    from std_msgs.msg import String
    rclpy.init()
    node = rclpy.create_node('bench_client')
    state_qos, event_qos = qos_profiles()
    types = message_types()
    lock = threading.Lock()
    counts = {}
    log = {'measured_js': [], 'stats': [], 'received': [], 'viewer': [], 'arrivals': {}}

    def count(name):
        def callback(_msg):
            with lock:
                counts[name] = counts.get(name, 0) + 1
        return callback

    def measured_js(msg):
        with lock:
            counts['PSM1/measured_js'] = counts.get('PSM1/measured_js', 0) + 1
            log['measured_js'].append((time.monotonic(), msg.header.stamp.sec
                                       + msg.header.stamp.nanosec * 1e-9))

    def arrival(name, then):
        times = log['arrivals'].setdefault(name, [])

        def callback(msg):
            times.append(time.monotonic())  # (list.append is atomic)
            then(msg)
        return callback

    arms = [a for a in args.arms.split(',') if a]
    for arm in arms:
        for topic in state_topics(arm):
            name = f'{arm}/{topic}'
            callback = measured_js if name == 'PSM1/measured_js' else count(name)
            if topic in GAP_TOPICS:
                callback = arrival(name, callback)
            node.create_subscription(types[topic], name, callback, state_qos)
        for topic in EVENT_TOPICS:
            node.create_subscription(types[topic], f'{arm}/{topic}', count(f'{arm}/{topic}'),
                                     event_qos)

    def stats(msg):
        with lock:
            log['stats'].append((time.monotonic(), json.loads(msg.data)))
            # total state messages received so far, sampled once per second
            log['received'].append((time.monotonic(), sum(counts.values())))
    node.create_subscription(String, 'sim/stats', stats, state_qos)

    def viewer_stats(msg):
        with lock:
            log['viewer'].append((time.monotonic(), json.loads(msg.data)))
    node.create_subscription(String, 'viewer/stats', viewer_stats, event_qos)
    executor, thread = spin_in_thread(node)
    print('ready', flush=True)
    sys.stdin.readline()
    with lock:
        result = dict(log, counts=dict(counts))
    finish(executor, thread, node)
    Path(args.out).write_text(json.dumps(result))


# -- the orchestrating process --------------------------------------------------------------------

class Proc:
    """A role process (this script with ``--role``) or the simulator, in its own session."""

    def __init__(self, argv, stdin=False, env=None):
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                                     text=True, start_new_session=True, env=env)
        self.pid = self.proc.pid

    @classmethod
    def role(cls, role, *extra, stdin=False):
        return cls([sys.executable, __file__, '--role', role, *extra], stdin=stdin)

    def expect(self, word, timeout):
        """Wait for a line ``word`` on the process's stdout (the role protocol)."""
        box = []
        reader = threading.Thread(target=lambda: box.append(self.proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(timeout)
        if not box or box[0].strip() != word:
            raise RuntimeError(f'expected {word!r} from {self.proc.args[-3:]}, got {box}')

    def url(self, timeout):
        """The page address the viewer prints (``viewer: open URL``)."""
        box = []

        def read():
            for line in self.proc.stdout:
                if line.startswith('viewer: open'):
                    box.append(line.split('open', 1)[1].strip())
                    return
        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        reader.join(timeout)
        if not box:
            raise RuntimeError(f'the viewer printed no URL in {timeout} s')
        return box[0]

    def tell(self, line):
        self.proc.stdin.write(line + '\n')
        self.proc.stdin.flush()

    def wait(self, timeout):
        self.proc.wait(timeout)

    def stop(self):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(10.0)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5.0)


def cpu_seconds(pid):
    """User + system CPU seconds of a process (Linux /proc)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def pct(values, q):
    return float(np.percentile(values, q)) if len(values) else float('nan')


def loop_capacity(steps=1000):
    """
    Seconds per physics step: bare core, node round without and with every state subscriber.

    The node adds event flushing, publishing checks and, with subscribers, building and publishing
    the state of three arms every 1/rate s of simulation time. ``dt / seconds`` is the real-time
    factor one free core could sustain.
    """
    import rclpy
    from sim_bridge.nodes.simulator import Simulator

    rclpy.init()
    node = Simulator()
    listener = rclpy.create_node('bench_capacity_listener')
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
        state_qos, _ = qos_profiles()
        types = message_types()
        for arm in ARMS:
            for topic in state_topics(arm):
                listener.create_subscription(types[topic], f'{arm}/{topic}', lambda m: None,
                                             state_qos)
        subscribed = sum(len(state_topics(arm)) for arm in ARMS)
        wait_for(lambda: sum(face._state[t][0].get_subscription_count() > 0
                             for face in node.arms.values() for t in state_topics(face.name))
                 >= subscribed, 30.0, 'in-process subscription matching')
        t = time.perf_counter()
        for _ in range(steps):
            node._step()
        full = (time.perf_counter() - t) / steps
        return bare, wrapped, full, node.sim.dt
    finally:
        listener.destroy_node()
        node.destroy_node()
        node.close()
        rclpy.shutdown()


def read_json(path):
    return json.loads(Path(path).read_text())


def ages(sent, received):
    """
    Age (s) of each goal when the first received message shows it (goals never shown skipped).
    """
    if not sent or not received:
        return np.array([])
    keys = np.array([k for k, _ in sent])
    times = np.array([t for _, t in sent])
    order = np.argsort(keys)
    keys, times = keys[order], times[order]
    got_t = np.array([r[0] for r in received])
    got_y = np.array([r[1] for r in received])
    i = np.clip(np.searchsorted(keys, got_y), 1, len(keys) - 1)
    nearest = np.where(np.abs(keys[i - 1] - got_y) <= np.abs(keys[i] - got_y), i - 1, i)
    exact = np.abs(keys[nearest] - got_y) < 1e-10  # the message shows exactly this goal
    # the first message showing each goal (after the stream ends, the last goal stays shown)
    goal, first = np.unique(nearest[exact], return_index=True)
    return got_t[exact][first] - times[goal]


def rate_and_jitter(samples, window):
    """Wall rate (Hz), sim-stamp rate (Hz) and |dt - 10 ms| (s) of (arrival, stamp) samples."""
    s = np.array([x for x in samples if window[0] <= x[0] <= window[1]])
    if len(s) < 3:
        return float('nan'), float('nan'), np.array([])
    wall = (len(s) - 1) / (s[-1, 0] - s[0, 0])
    sim = (len(s) - 1) / (s[-1, 1] - s[0, 1])
    return wall, sim, np.abs(np.diff(s[:, 0]) - 1.0 / ANCHOR_STATE_HZ)


def fast_phase(bin_dir, tmp, seconds, arms):
    """Simulator at real_time_factor 0 with a client of ``arms``; return the factor reached."""
    sim = Proc([str(bin_dir / 'simulator'), '--ros-args', '-p', 'real_time_factor:=0.0'])
    out = str(Path(tmp) / f'fast_{arms or "none"}.json')
    client = Proc.role('client', '--arms', arms, '--out', out, stdin=True)
    try:
        client.expect('ready', 60.0)
        time.sleep(seconds + 3.0)
        client.tell('stop')
        client.wait(30.0)
    finally:
        client.stop()
        sim.stop()
    stats = [s for _, s in read_json(out)['stats']]
    return float(np.mean([s['achieved'] for s in stats[2:]])) if len(stats) > 2 else float('nan')


def open_browser(url):
    """A headless Chromium on ``url`` (the browser tests' driver), or None without chromium."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test' / 'suture_lfd'
                           / 'viewer'))
    from browser import Chromium, find_chromium
    if find_chromium() is None:
        return None
    browser = Chromium(find_chromium())
    browser.open(url)
    wait_for(lambda: browser.element_center('Clutch') is not None, 300.0, 'the viewer page')
    return browser


def live_phase(bin_dir, tmp, seconds, arms, viewer=False):
    """
    Simulator at real time, the probe streaming servo_cp, a client of ``arms`` ('' = none).

    ``viewer``: the viewer node runs too, with a headless Chromium on its page when chromium is
    installed. Returns the measurements over the probe's streaming window.
    """
    name = (arms.replace(',', '_') or 'none') + ('_viewer' if viewer else '')
    sim = Proc([str(bin_dir / 'simulator')])
    view = browser = None
    if viewer:
        view = Proc([str(bin_dir / 'viewer'), '--port', '0'])
        browser = open_browser(view.url(120.0))
    client = Proc.role('client', '--arms', arms, '--out', str(Path(tmp) / f'client_{name}.json'),
                       stdin=True)
    probe = Proc.role('probe', '--target', 'sim', '--seconds', str(seconds),
                      '--out', str(Path(tmp) / f'probe_{name}.json'))
    try:
        client.expect('ready', 60.0)
        probe.expect('streaming', 90.0)
        pids = {'simulator': sim.pid, 'client': client.pid, 'probe': probe.pid}
        if view is not None:
            pids['viewer'] = view.pid
        cpu0 = {k: cpu_seconds(p) for k, p in pids.items()}
        wall0 = time.monotonic()
        probe.expect('done', seconds + 30.0)
        # the probe stops streaming 0.3 s before 'done': about its streaming window
        wall = time.monotonic() - wall0
        cpu = {k: (cpu_seconds(p) - cpu0[k]) / wall for k, p in pids.items()}
        client.tell('stop')
        client.wait(30.0)
    finally:
        probe.stop()
        client.stop()
        if browser is not None:
            browser.close()
        if view is not None:
            view.stop()
        sim.stop()
    live = read_json(Path(tmp) / f'probe_{name}.json')
    seen = read_json(Path(tmp) / f'client_{name}.json')
    window = live['window']
    setpoints = {r[2]: np.array([r[3], r[1], r[4]]) for r in live['setpoint_cp']}
    tracking = np.array([np.linalg.norm(np.array([r[3], r[1], r[4]]) - setpoints[r[2]])
                         for r in live['measured_cp'] if r[2] in setpoints])
    probe_rate, sim_rate, probe_jitter = rate_and_jitter(live['measured_js'], window)
    client_rate, _, client_jitter = rate_and_jitter(seen['measured_js'], window)
    achieved = [s['achieved'] for t, s in seen['stats'] if window[0] + 1.0 <= t <= window[1]]
    received = [(t, n) for t, n in seen['received'] if window[0] <= t <= window[1]]
    expected = ANCHOR_STATE_HZ * sum(len(state_topics(a)) for a in arms.split(',') if a)
    msg_rate = ((received[-1][1] - received[0][1]) / (received[-1][0] - received[0][0])
                if expected and len(received) > 1 else float('nan'))
    return {'age': ages(live['sent'], live['setpoint_cp']),
            'setpoint_messages': len(live['setpoint_cp']), 'tracking': tracking,
            'errors': live['error'], 'probe_rate': probe_rate, 'probe_jitter': probe_jitter,
            'client_rate': client_rate, 'client_jitter': client_jitter, 'sim_rate': sim_rate,
            'achieved': float(np.mean(achieved)) if achieved else float('nan'),
            'client_msg_rate': msg_rate, 'expected_rate': expected, 'cpu': cpu,
            'viewer': [v for t, v in seen['viewer'] if window[0] + 1.0 <= t <= window[1]],
            'browser': browser is not None}


def checkout(rev, tmp):
    """Export git revision ``rev`` of this repository into ``tmp``; return the folder."""
    out = Path(tmp) / f'rev_{rev.replace("/", "_")}'
    out.mkdir()
    repo = Path(__file__).resolve().parent.parent
    archive = subprocess.run(['git', '-C', str(repo), 'archive', rev], check=True,
                             capture_output=True).stdout
    subprocess.run(['tar', '-x', '-C', str(out)], input=archive, check=True)
    return out


def gaps_phase(bin_dir, tmp, seconds, load, arms, source=None, sim_args=()):
    """
    The simulator at real time with the full client; the gaps between state messages there.

    ``load``: that many busy processes compete for the cores meanwhile. ``source``: run the
    simulator from that source folder (another revision). Returns the gaps (s) between
    consecutive ``GAP_TOPICS`` messages of each arm at the client, all pooled.
    """
    env = dict(os.environ)
    if source is not None:
        env['PYTHONPATH'] = str(source)
    sim = Proc([str(bin_dir / 'simulator'), *(('--ros-args', *sim_args) if sim_args else ())],
               env=env)
    out = Path(tmp) / f'gaps_{time.monotonic_ns()}.json'
    client = Proc.role('client', '--arms', arms, '--out', str(out), stdin=True)
    burners = []
    try:
        client.expect('ready', 60.0)
        time.sleep(8.0)  # the simulator up and streaming
        burners = [subprocess.Popen([sys.executable, '-c', 'while True: pass'],
                                    start_new_session=True) for _ in range(load)]
        time.sleep(1.0)
        t0 = time.monotonic()
        time.sleep(seconds)
        t1 = time.monotonic()
        client.tell('stop')
        client.wait(30.0)
    finally:
        for b in burners:
            b.kill()
            b.wait()
        client.stop()
        sim.stop()
    gaps = []
    for times in read_json(out)['arrivals'].values():
        t = np.array([x for x in times if t0 <= x <= t1])
        gaps.extend(np.diff(t).tolist())
    return np.array(gaps)


def gaps_report(args, bin_dir, tmp):
    """Print the state gaps with the full client, idle and loaded, before and after."""
    runs = [('this tree', None)]
    if args.before:
        runs.insert(0, (f'before ({args.before})', checkout(args.before, tmp)))
    sim_args = tuple(args.sim_args.split()) if args.sim_args else ()
    ms = 1e3
    print(f'gaps between consecutive {"/".join(GAP_TOPICS)} messages of each arm at a dVRK '
          f'client of {args.arms} (every state topic of a dvrk.psm / dvrk.ecm; '
          f"{args.seconds:g} s per phase; the dVRK: 10 ms; the dVRK teleoperation script's "
          f"limit {AGE_LIMIT_S * ms:.0f} ms); this tree's simulator: "
          f'{args.sim_args or "defaults"}')
    for load in (0, args.load):
        for title, source in runs:
            gaps = gaps_phase(bin_dir, tmp, args.seconds, load, args.arms, source,
                              sim_args if source is None else ())
            over = int(np.sum(gaps > AGE_LIMIT_S))
            print(f'  {title:24s} {"idle" if not load else f"{load} busy processes":18s} '
                  f'median {pct(gaps, 50) * ms:5.1f}  p99 {pct(gaps, 99) * ms:5.1f}  '
                  f'max {pct(gaps, 100) * ms:5.1f} ms  over {AGE_LIMIT_S * ms:.0f} ms: {over} '
                  f'of {len(gaps)}; p99 / 20 ms = {pct(gaps, 99) / AGE_LIMIT_S:.2f}',
                  flush=True)
    print(f'load average (1 min) after: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=10.0, help='length of each phase (s)')
    parser.add_argument('--viewer', action='store_true',
                        help='also run the full-client phase with the viewer connected (its node '
                             'and a headless Chromium on its page)')
    parser.add_argument('--gaps', action='store_true',
                        help='measure only the gaps between state messages at a client, idle '
                             'and under a CPU load')
    parser.add_argument('--load', type=int, default=2,
                        help='--gaps: busy processes of the loaded phase (default 2)')
    parser.add_argument('--before', help='--gaps: also run the simulator of this git revision')
    parser.add_argument('--sim-args', default='',
                        help='--gaps: parameters of this tree\'s simulator ("-p rate:=200")')
    parser.add_argument('--role', choices=('echo', 'probe', 'client'), help=argparse.SUPPRESS)
    parser.add_argument('--target', choices=('echo', 'sim'), help=argparse.SUPPRESS)
    parser.add_argument('--arms', default=None,
                        help='--gaps: the arms the client subscribes to (default PSM1, as '
                             'dvrk_teleoperation.py -p PSM1)')
    parser.add_argument('--out', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role:
        {'echo': role_echo, 'probe': role_probe, 'client': role_client}[args.role](args)
        return
    bin_dir = Path(sys.executable).parent
    tmp = tempfile.mkdtemp(prefix='bench_simulator_node_')
    seconds = str(args.seconds)
    if args.gaps:
        args.arms = args.arms or 'PSM1'
        gaps_report(args, bin_dir, tmp)
        return
    args.arms = args.arms if args.arms is not None else ','.join(ARMS)

    load_before = os.getloadavg()[0]
    bare, wrapped, full, dt = loop_capacity()

    # -- anchor: probe <-> plain rclpy echo, 1 kHz PoseStamped round trips --------------------
    echo = Proc.role('echo')
    probe = Proc.role('probe', '--target', 'echo', '--seconds', seconds,
                      '--out', str(Path(tmp) / 'echo.json'))
    try:
        probe.expect('streaming', 60.0)
        probe.expect('done', args.seconds + 30.0)
    finally:
        probe.stop()
        echo.stop()
    anchor = read_json(Path(tmp) / 'echo.json')
    sent_at = dict(anchor['sent'])
    rtt = np.array([t - sent_at[k] for t, k in anchor['echo'] if k in sent_at])
    anchor_lost = 1.0 - len(rtt) / max(1, len(anchor['sent']))

    # -- the simulator at real time, probe streaming servo_cp: alone, then with a full client --
    alone = live_phase(bin_dir, tmp, args.seconds, '')
    loaded = live_phase(bin_dir, tmp, args.seconds, ','.join(ARMS))
    phases = [('probe only (PSM1: servo_cp in, 3 state topics out)', alone),
              ('probe + a dVRK client of all three arms', loaded)]
    if args.viewer:
        phases.append(('probe + the client + the viewer (node and a browser on its page)',
                       live_phase(bin_dir, tmp, args.seconds, ','.join(ARMS), viewer=True)))

    # -- the simulator as fast as it goes --------------------------------------------------------
    flat_out = fast_phase(bin_dir, tmp, args.seconds / 2, '')
    flat_out_client = fast_phase(bin_dir, tmp, args.seconds / 2, ','.join(ARMS))

    ms = 1e3
    print(f'stepping cost per {dt * ms:.0f} ms physics step: core {bare * ms:.3f} ms, node '
          f'{wrapped * ms:.3f} ms without subscribers (node / core = {wrapped / bare:.2f}), '
          f'{full * ms:.3f} ms with every state topic of three arms subscribed; one free core '
          f'sustains {dt / wrapped:.1f} x real time without, {dt / full:.1f} x with them')
    print(f'anchor echo RTT (two rclpy processes, 1 kHz): p50 {pct(rtt, 50) * ms:.2f} ms, '
          f'p99 {pct(rtt, 99) * ms:.2f} ms ({len(rtt)} samples, {anchor_lost:.1%} lost)')
    for title, r in phases:
        print(f'-- simulator at real_time_factor 1, {title}:')
        if r['errors']:
            print(f'   warning: the simulator rejected goals: {len(r["errors"])} errors, first: '
                  f'{r["errors"][0]}')
        age = r['age']
        print(f'   servo_cp -> setpoint_cp age: p50 {pct(age, 50) * ms:.2f} ms, '
              f'p99 {pct(age, 99) * ms:.2f} ms, max {pct(age, 100) * ms:.2f} ms '
              f'({len(age)} samples of {r["setpoint_messages"]} messages); '
              f'p50 / anchor RTT p50 = {pct(age, 50) / pct(rtt, 50):.2f}, '
              f'p99 / anchor RTT p99 = {pct(age, 99) / pct(rtt, 99):.2f}, '
              f'p99 / target 3 ms = {pct(age, 99) / TARGET_P99_S:.2f}')
        tracking = r['tracking']
        print(f'   measured_cp - setpoint_cp of the same publication (tracking error): '
              f'p50 {pct(tracking, 50) * 1e6:.1f} um, p99 {pct(tracking, 99) * 1e6:.1f} um')
        for who in ('probe', 'client'):
            rate, jitter = r[f'{who}_rate'], r[f'{who}_jitter']
            if len(jitter):
                print(f'   PSM1/measured_js at the {who}: {rate:.1f} Hz wall '
                      f'({rate / ANCHOR_STATE_HZ:.3f} x the dVRK 100 Hz); inter-arrival jitter '
                      f'|dt - 10 ms| p50 {pct(jitter, 50) * ms:.2f} ms, '
                      f'p99 {pct(jitter, 99) * ms:.2f} ms')
        if np.isfinite(r['client_msg_rate']):
            print(f'   the client received {r["client_msg_rate"]:.0f} state messages/s of '
                  f'{r["expected_rate"]:.0f} published '
                  f'({r["client_msg_rate"] / r["expected_rate"]:.3f})')
        cpu = r['cpu']
        print(f'   state stamps advance at {r["sim_rate"]:.2f} Hz of simulator clock; CPU (share '
              f'of one core) while streaming: simulator {cpu["simulator"] * 100:.0f} %, client '
              f'{cpu["client"] * 100:.0f} %, probe {cpu["probe"] * 100:.0f} %'
              + (f', viewer {cpu["viewer"] * 100:.0f} %' if 'viewer' in cpu else '')
              + f'; real-time factor achieved {r["achieved"]:.3f} (asked 1.0)')
        if 'viewer' in cpu:
            frames = [v['frame_rate'] for v in r['viewer']]
            tf = [v['tf_rate'] for v in r['viewer']]
            print(f'   the viewer sent {np.mean(frames) if frames else float("nan"):.1f} frames/s '
                  f'to its page (asked 30; min {min(frames, default=float("nan")):.1f}), took '
                  f'{np.mean(tf) if tf else float("nan"):.1f} /tf messages/s (published 50), '
                  f'browser connected: {r["browser"]}')
    print(f'as fast as it goes (real_time_factor 0): {flat_out:.2f} x real time with no state '
          f'subscribers, {flat_out_client:.2f} x with the full client')
    print(f'load average (1 min): {load_before:.1f} before the run, {os.getloadavg()[0]:.1f} '
          f'after, on {os.cpu_count()} cores (the probe, client and simulator need about 1.5 '
          f'cores: numbers from a busier machine are not comparable)')


if __name__ == '__main__':
    main()
