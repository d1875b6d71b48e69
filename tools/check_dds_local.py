"""
Check that the project's DDS traffic stays on this machine.

Capture every non-loopback interface while the simulator and a client talk, and count the RTPS
packets that left.

    sudo .venv/bin/python tools/check_dds_local.py [--seconds 20]

The tests cannot show this: they run in a network namespace that has only a loopback interface.
This check runs in the machine's own namespace, starts ``scripts/simulator.sh`` (which sets
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and loads ``config/fastdds.xml``) and a client node
subscribed to an arm's state, and reads raw frames (``AF_PACKET``, needs root or CAP_NET_RAW) on
every interface but ``lo``. Exit status 0 when no RTPS packet left the machine, 1 when some did,
2 when the capture could not run.
"""

import argparse
import os
from pathlib import Path
import signal
import socket
import struct
import subprocess
import sys
import time

REPO = Path(__file__).resolve().parent.parent
ETH_P_ALL = 0x0003
CLIENT = """
import rclpy
from sensor_msgs.msg import JointState
rclpy.init()
node = rclpy.create_node('dds_local_check_client')
seen = []
node.create_subscription(JointState, '/PSM1/measured_js', seen.append, 10)
end = node.get_clock().now().nanoseconds + int(float(__import__('sys').argv[1]) * 1e9)
while node.get_clock().now().nanoseconds < end:
    rclpy.spin_once(node, timeout_sec=0.1)
print(len(seen))
"""


def interfaces():
    """Return the names of the machine's interfaces that are up, other than loopback."""
    up = []
    for _, name in socket.if_nameindex():
        state = Path('/sys/class/net') / name / 'operstate'
        if name != 'lo' and (not state.exists() or state.read_text().strip() != 'down'):
            up.append(name)
    return up


def rtps_payload(frame):
    """
    Return ``(source, destination, port)`` of an Ethernet frame carrying RTPS, else None.

    IPv4 and IPv6 over Ethernet, UDP only; RTPS packets start with the bytes ``RTPS``.
    """
    if len(frame) < 14:
        return None
    ethertype = struct.unpack('!H', frame[12:14])[0]
    if ethertype == 0x0800 and len(frame) >= 34:
        ihl = (frame[14] & 0x0F) * 4
        if frame[23] != 17:
            return None
        udp = 14 + ihl
        src, dst = socket.inet_ntoa(frame[26:30]), socket.inet_ntoa(frame[30:34])
    elif ethertype == 0x86DD and len(frame) >= 62:
        if frame[20] != 17:
            return None
        udp = 54
        src = socket.inet_ntop(socket.AF_INET6, frame[22:38])
        dst = socket.inet_ntop(socket.AF_INET6, frame[38:54])
    else:
        return None
    if frame[udp + 8:udp + 12] != b'RTPS':
        return None
    return src, dst, struct.unpack('!H', frame[udp + 2:udp + 4])[0]


def main(argv=None):
    """Run the check; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0, help='capture time (s)')
    parser.add_argument('--range', default='LOCALHOST', choices=('LOCALHOST', 'SUBNET'),
                        help='ROS_AUTOMATIC_DISCOVERY_RANGE to run with; SUBNET is the control '
                             'that shows the capture sees DDS traffic when it does leave')
    args = parser.parse_args(argv)
    names = interfaces()
    sockets = []
    try:
        for name in names:
            s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
            s.bind((name, 0))
            s.setblocking(False)
            sockets.append((name, s))
    except PermissionError:
        print('cannot open a raw socket: run as root (or with CAP_NET_RAW)', file=sys.stderr)
        return 2
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': args.range,
           'ROS_DOMAIN_ID': os.environ.get('ROS_DOMAIN_ID', str(os.getpid() % 90 + 10))}
    sim = subprocess.Popen([str(REPO / 'scripts' / 'simulator.sh')], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           start_new_session=True)
    client = subprocess.Popen([sys.executable, '-c', CLIENT, str(args.seconds)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    frames, leaks = 0, {}
    end = time.monotonic() + args.seconds + 15.0
    try:
        while time.monotonic() < end and client.poll() is None:
            for _, s in sockets:
                while True:
                    try:
                        frame = s.recv(65536)
                    except BlockingIOError:
                        break
                    frames += 1
                    found = rtps_payload(frame)
                    if found:
                        leaks[found] = leaks.get(found, 0) + 1
            time.sleep(0.005)
        received = client.communicate(timeout=30)[0].strip() if client.poll() is not None else '?'
    finally:
        client.kill()
        os.killpg(sim.pid, signal.SIGINT)
        sim.wait(timeout=30)
    print(f'ROS_AUTOMATIC_DISCOVERY_RANGE={args.range}')
    print(f'interfaces captured: {", ".join(names) or "none"}; frames seen: {frames}')
    print(f'client received {received} PSM1/measured_js messages over DDS')
    if not leaks:
        print('RTPS packets that left the machine: 0')
        return 0
    print(f'RTPS packets that left the machine: {sum(leaks.values())}')
    for (src, dst, port), count in sorted(leaks.items()):
        print(f'  {src} -> {dst}:{port}  {count}')
    return 1


if __name__ == '__main__':
    sys.exit(main())
