"""
Discovery on loopback: how long a new client waits before the simulator hears it.

A dVRK client (crtk) creates its node and sends ``state_command`` at once; the command reaches
the arm only once the simulator's reader has matched the client's writer. Measured for each of
``--clients`` fresh client processes started one after another against one running target:

- ``match``: from the client's node creation to its ``state_command`` publisher matching a
  subscription (the publisher's matched event);
- ``reply``: from node creation to the first ``operating_state`` that answers the ``enable`` it
  published latched right after creating the node (both directions discovered, the command
  applied).

Targets, each in the same run: the ``simulator`` (about 160 endpoints), and the anchor, a plain
rclpy node with the same two endpoints the client talks to (``PSM1/state_command`` in,
``PSM1/operating_state`` out, answering each command), so that the cost of discovery itself is
told from the cost of the simulator's many endpoints. Each target runs under the environment
variants given with ``--variants`` (``default``: Fast DDS's defaults, as before the project had
a profile; ``udp``: the same with ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``, no shared memory;
``profile``: the project's Fast DDS profile, ``config/fastdds.xml``, which every node of the
project loads), with the clients on Fast DDS's defaults as an unchanged dVRK script is;
``both``: the target and the clients load the profile.

Run: ``.venv/bin/python bench/bench_discovery.py [--clients 15] [--variants default,profile,both]``
"""

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
if '--role' not in sys.argv:
    os.environ['ROS_DOMAIN_ID'] = str(100 + os.getpid() % 100)

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
PROFILE = REPO / 'config' / 'fastdds.xml'
PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def variant_env(name, tmp):
    """The environment of a variant: this process's, with the variant's DDS settings."""
    env = {k: v for k, v in os.environ.items()
           if k not in ('FASTDDS_BUILTIN_TRANSPORTS', *PROFILE_VARIABLES)}
    # Fast DDS's own defaults: a profile file without profiles (our nodes load the project's
    # profile unless a file is named)
    plain = Path(tmp) / 'no_profile.xml'
    plain.write_text('<?xml version="1.0" encoding="UTF-8" ?>\n'
                     '<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">'
                     '<profiles/></dds>\n')
    for var in PROFILE_VARIABLES:
        env[var] = str(plain)
    if name == 'udp':
        env['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'
    elif name in ('profile', 'both'):
        for var in PROFILE_VARIABLES:
            env[var] = str(PROFILE)
    elif name != 'default':
        raise ValueError(f'unknown variant {name!r}; expected default, udp, profile or both')
    return env


def role_anchor():
    """A plain node with the client's two endpoints: answer each state command."""
    from crtk_msgs.msg import OperatingState, StringStamped
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    rclpy.init()
    node = rclpy.create_node('anchor')
    events = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
    commands = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    pub = node.create_publisher(OperatingState, 'PSM1/operating_state', events)

    def answer(msg):
        pub.publish(OperatingState(header=msg.header, state='ENABLED'))
    node.create_subscription(StringStamped, 'PSM1/state_command', answer, commands)
    node.create_subscription(StringStamped, 'PSM1/state_command', answer, events)
    print('ready', flush=True)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def role_client():
    """Create a node, send 'enable' latched at once; print match and reply times (JSON)."""
    from crtk_msgs.msg import OperatingState, StringStamped
    import rclpy
    from rclpy.event_handler import PublisherEventCallbacks
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    rclpy.init()
    times = {}
    t0 = time.monotonic()
    node = rclpy.create_node(f'client_{os.getpid()}')
    latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    volatile = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)

    def matched(info):
        if info.current_count > 0:
            times.setdefault('match', time.monotonic() - t0)

    def state(msg):
        times.setdefault('reply', time.monotonic() - t0)
    node.create_subscription(OperatingState, 'PSM1/operating_state', state, volatile)
    pub = node.create_publisher(StringStamped, 'PSM1/state_command', latched,
                                event_callbacks=PublisherEventCallbacks(matched=matched))
    pub.publish(StringStamped(string='enable'))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = t0 + 20.0
    while ('reply' not in times or 'match' not in times) and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.01)
    print(json.dumps(times), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def start(argv, env):
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env=env, start_new_session=True)


def stop(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(15.0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5.0)


def run_target(target, variant, clients, tmp):
    """Start the target under a variant, then ``clients`` clients one after another."""
    env = variant_env(variant, tmp)
    # an unchanged client: Fast DDS's defaults; with 'both' the client loads the profile too
    client_env = variant_env('both' if variant == 'both' else 'default', tmp)
    bin_dir = Path(sys.executable).parent
    if target == 'simulator':
        proc = start([str(bin_dir / 'simulator'), '--ros-args', '-p', 'power_up_time:=0.0'],
                     env)
        time.sleep(8.0)  # start-up (scene, PyBullet) over, the node spinning
    else:
        proc = start([sys.executable, __file__, '--role', 'anchor'], env)
        for line in proc.stdout:  # (Fast DDS prints profile errors on stdout)
            if line.strip() == 'ready':
                break
        else:
            raise RuntimeError('the anchor did not start')
        time.sleep(1.0)
    results = []
    try:
        for _ in range(clients):
            client = start([sys.executable, __file__, '--role', 'client'], client_env)
            out, _ = client.communicate(timeout=60.0)
            results.append(json.loads(out.strip().splitlines()[-1]))
            time.sleep(0.5)
    finally:
        stop(proc)
    return results


def summary(values):
    values = [v for v in values if v is not None]
    if not values:
        return 'none'
    a = np.array(values) * 1e3
    return (f'median {np.median(a):7.1f}  p90 {np.percentile(a, 90):7.1f}  '
            f'max {a.max():7.1f} ms')


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--clients', type=int, default=15, help='clients per target and variant')
    parser.add_argument('--variants', default='default,profile,both',
                        help='comma-separated: default, udp, profile, both')
    parser.add_argument('--role', choices=('anchor', 'client'), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == 'anchor':
        return role_anchor()
    if args.role == 'client':
        return role_client()
    rows = {}
    tmp = tempfile.mkdtemp(prefix='bench_discovery_')
    for variant in args.variants.split(','):
        for target in ('anchor', 'simulator'):
            res = run_target(target, variant, args.clients, tmp)
            rows[(variant, target)] = res
            lost = sum('reply' not in r for r in res)
            print(f'{variant:8s} {target:9s} match: {summary([r.get("match") for r in res])}'
                  f' | reply: {summary([r.get("reply") for r in res])}'
                  f'{f"  ({lost} no reply in 20 s)" if lost else ""}', flush=True)
    for variant in args.variants.split(','):
        a = [r['reply'] for r in rows[(variant, 'anchor')] if 'reply' in r]
        s = [r['reply'] for r in rows[(variant, 'simulator')] if 'reply' in r]
        if a and s:
            print(f'{variant:8s} simulator / anchor, median reply: '
                  f'{np.median(s) / np.median(a):.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
