"""
The virtual MTMs at rest: a hand nobody moves costs few cycles (the idle rate; the keep-alive
rate once a client has enabled the MTM, fresh enough for the dVRK's 20 ms age check), and the
next input is taken
(a real ``mtms`` process, browser back-end, beside the simulator whose ECM places the browser's
handles in the display frame, over DDS on loopback).

Samples are counted by their stamps, the node's clock when it published them, not by when this
process received them: on a machine short of CPU the probe takes the samples the node published
at its full rate during start-up seconds late, all at once, and a count by arrival would
measure the probe's lag, not the node's rate. Each window is counted once its last samples have
had time to arrive.
"""

import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS, wait_for
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sim_bridge.ros import conversions as cv
from std_msgs.msg import Float64

RATE, IDLE_RATE, KEEP_ALIVE_RATE = 200.0, 10.0, 100.0    # config/mtms.yaml
LATCHED = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,   # as crtk's
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
START_TIMEOUT = 120.0            # s for a node to start on a loaded 2-core machine


def test_a_virtual_mtm_nobody_moves_slows_to_its_idle_or_keep_alive_rate_and_wakes_at_input(
        ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    proc = launch('mtms', '--ros-args', '-p', 'device:=browser', '-p', f'rate:={RATE}',
                  '-p', f'idle_rate:={IDLE_RATE}', '-p', 'idle_after:=0.5',
                  '-p', f'keep_alive_rate:={KEEP_ALIVE_RATE}')
    node = ros.node('idle_probe')
    seen = []                    # (stamp in s, position of MTMR's measured_cp)
    node.create_subscription(PoseStamped, 'MTMR/measured_cp',
                             lambda m: seen.append((
                                 m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, np.array(
                                     [m.pose.position.x, m.pose.position.y, m.pose.position.z]))),
                             QoSProfile(depth=1000))

    def published_during(seconds, during=None):
        """How many samples the node stamped in the next ``seconds`` (its clock: the wall's)."""
        t0 = time.time()
        if during is None:
            time.sleep(seconds)
        else:
            during(t0 + seconds)
        t1 = time.time()
        time.sleep(1.0)                               # the window's last samples arrive
        return [p for t, p in list(seen) if t0 <= t < t1]
    hand = node.create_publisher(PoseStamped, 'viewer/input/MTMR/pose', QoSProfile(depth=10))
    grip = node.create_publisher(Float64, 'viewer/input/MTMR/gripper', QoSProfile(depth=10))
    assert wait_for(lambda: hand.get_subscription_count() > 0, START_TIMEOUT), proc.log()

    def put(x):
        T = np.eye(4)
        T[:3, 3] = (x, 0.0, 0.15)
        hand.publish(cv.pose_stamped(T, 'world', node.get_clock().now().to_msg()))
        grip.publish(Float64(data=0.5))

    # a hand is given, then left alone
    assert wait_for(lambda: put(0.01) or seen, START_TIMEOUT, period=0.1), \
        proc.log() + sim.log()[-2000:]
    # the hand poses the probe sent until it saw a sample may reach the node late (the probe
    # short of CPU), each one an input that wakes the node again: rest starts once they have
    # all been taken, seen as a second the node stamped at no more than its idle rate
    assert wait_for(lambda: len(published_during(1.0)) <= IDLE_RATE * 1.5, 30.0), \
        'the MTM never slowed to its idle rate'
    at_rest = len(published_during(3.0))
    # at most the idle rate (a busy machine only lowers it); the full rate would give 600
    assert 0 < at_rest <= 3.0 * IDLE_RATE * 1.5, at_rest
    # enabled by a client, as the dVRK's teleoperation script does: the keep-alive rate, well
    # above the idle rate and below the full rate (which would give 600)
    states = []
    node.create_subscription(OperatingState, 'MTMR/operating_state', states.append,
                             QoSProfile(depth=100))
    command = node.create_publisher(StringStamped, 'MTMR/state_command', LATCHED)
    assert wait_for(lambda: command.publish(StringStamped(string='enable'))
                    or (states and states[-1].state == 'ENABLED'), 60.0, period=0.5), proc.log()
    time.sleep(1.0)
    window = published_during(3.0)
    kept_alive = len(window)
    assert 3.0 * IDLE_RATE * 1.5 < kept_alive <= 3.0 * KEEP_ALIVE_RATE * 1.5, kept_alive
    # the same pose, kept fresh (within the encoders' noise of the dVRK preset)
    assert np.linalg.norm(window[-1] - window[0]) < 1e-4
    rest = seen[-1][1]
    # an input is taken: the MTM's pose follows the hand again
    put(0.02)
    assert wait_for(lambda: np.linalg.norm(seen[-1][1] - rest) > 0.005, 30.0), proc.log()
    # and while the hand moves, the full rate is back: more samples than the idle rate allows
    x = [0.02]

    def move(until):
        while time.time() < until:
            x[0] += 1e-5
            put(x[0])
            time.sleep(1.0 / RATE)

    moving = len(published_during(2.0, move))
    assert moving > 2.0 * IDLE_RATE * 1.5, moving
    assert proc.running()
