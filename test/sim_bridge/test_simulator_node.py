"""
The simulator node as a dVRK client sees it: a real process, real DDS on loopback.

The contract tables below are taken from the dVRK 2.x facts (dvrk_crtk.md §1, §3, §5): what a
``dvrk.psm`` / ``dvrk.ecm`` client publishes, subscribes and calls, with the dVRK's types and QoS.
"""

from dataclasses import replace
import json
import math
import threading
import time

from crtk_msgs.msg import OperatingState, StringStamped
from crtk_msgs.srv import QueryForwardKinematics
from geometry_msgs.msg import PoseStamped
from harness import FAST_ARMS, SIGINT_EXIT
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState, Joy
from sim_bridge.arm import Arm, ArmConfig
from sim_bridge.common.geometry import invert_transform
from sim_bridge.kinematics import psm_kinematics
from sim_bridge.ros import conversions as cv
from sim_bridge.scene.scene_config import load_scene_config
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

TL = DurabilityPolicy.TRANSIENT_LOCAL
VOL = DurabilityPolicy.VOLATILE
LATCHED = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=TL)
STREAM = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=VOL)
COMMAND = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=VOL)

JS, CP, CV, CF = ('sensor_msgs/msg/JointState', 'geometry_msgs/msg/PoseStamped',
                  'geometry_msgs/msg/TwistStamped', 'geometry_msgs/msg/WrenchStamped')
ARRAY, F64, STR, BOOL, EMPTY = ('std_msgs/msg/Float64MultiArray', 'std_msgs/msg/Float64',
                                'std_msgs/msg/String', 'std_msgs/msg/Bool', 'std_msgs/msg/Empty')
OPSTATE, SSTAMPED = 'crtk_msgs/msg/OperatingState', 'crtk_msgs/msg/StringStamped'

# dvrk_crtk.md §5 (what dvrk.psm checks) + §1 events; durability per §3 (state volatile,
# events transient-local); everything RELIABLE.
PUBLISHED = {
    'operating_state': (OPSTATE, TL), 'setpoint_js': (JS, VOL), 'setpoint_cp': (CP, VOL),
    'measured_js': (JS, VOL), 'measured_cp': (CP, VOL), 'measured_cv': (CV, VOL),
    'trajectory_j/ratio': (F64, TL), 'spatial/measured_cf': (CF, VOL),
    'spatial/jacobian': (ARRAY, VOL), 'body/measured_cf': (CF, VOL),
    'body/jacobian': (ARRAY, VOL), 'local/measured_cp': (CP, VOL),
    'local/setpoint_cp': (CP, VOL), 'goal_reached': (BOOL, TL), 'error': (STR, TL),
    'warning': (STR, TL), 'status': (STR, TL),
}
PSM_PUBLISHED = {'jaw/measured_js': (JS, VOL), 'jaw/setpoint_js': (JS, VOL)}
SUBSCRIBED = {
    'state_command': SSTAMPED, 'hold': EMPTY, 'free': EMPTY, 'servo_jp': JS, 'servo_jr': JS,
    'servo_cp': CP, 'servo_jf': JS, 'move_jp': JS, 'move_jr': JS, 'move_cp': CP,
    'spatial/servo_cf': CF, 'body/servo_cf': CF, 'body/set_cf_orientation_absolute': BOOL,
    'use_gravity_compensation': BOOL, 'trajectory_j/set_ratio': F64,
}
PSM_SUBSCRIBED = {'jaw/servo_jp': JS, 'jaw/move_jp': JS, 'jaw/servo_jf': JS,
                  'emulate_tool_present': BOOL}
SERVICES = {'operating_state': 'crtk_msgs/srv/TriggerOperatingState',
            'crtk_version': 'std_srvs/srv/Trigger',
            'forward_kinematics': 'crtk_msgs/srv/QueryForwardKinematics',
            'local/forward_kinematics': 'crtk_msgs/srv/QueryForwardKinematics',
            'inverse_kinematics': 'crtk_msgs/srv/QueryInverseKinematics'}
ARMS = ('PSM1', 'PSM2', 'ECM')
JAW_CLOSED, JAW_OPEN = -0.349066, math.radians(60.0)  # dvrk-py jaw.close() / jaw.open()


def expected_contract(ns=''):
    """(kind, topic) -> (type, durability or None) for every arm, from the tables above."""
    table = {}
    for arm in ARMS:
        pubs = {**PUBLISHED, **(PSM_PUBLISHED if arm != 'ECM' else {})}
        subs = {**SUBSCRIBED, **(PSM_SUBSCRIBED if arm != 'ECM' else {})}
        for topic, (msgtype, durability) in pubs.items():
            table[('pub', f'{ns}/{arm}/{topic}')] = (msgtype, 'RELIABLE', durability.name)
        for topic, msgtype in subs.items():
            # state_command: a volatile and a transient-local reader (sim_bridge.ros.intake)
            durability = 'TRANSIENT_LOCAL+VOLATILE' if topic == 'state_command' else 'VOLATILE'
            table[('sub', f'{ns}/{arm}/{topic}')] = (msgtype, 'RELIABLE', durability)
    return table


def observed_contract(node, table):
    """The same table as the graph shows it (endpoints of the node named 'simulator')."""
    seen = {}
    for kind, topic in table:
        infos = (node.get_publishers_info_by_topic(topic) if kind == 'pub'
                 else node.get_subscriptions_info_by_topic(topic))
        durabilities = set()
        for info in infos:
            if info.node_name == 'simulator':
                q = info.qos_profile
                durabilities.add(q.durability.name)
                seen[(kind, topic)] = (info.topic_type, q.reliability.name,
                                       '+'.join(sorted(durabilities)))
    return seen


def stamp_s(msg):
    return cv.seconds_from_stamp(msg.header.stamp)


class ArmClient:
    """What a dVRK client holds for one arm: subscriptions with receive times, publishers."""

    def __init__(self, ros, arm, ns=''):
        self.ros = ros
        self.arm = arm
        self.node = node = ros.node(f'client_{arm.lower()}_{id(self) % 100000}')
        self.lock = threading.Lock()
        self.msgs = {}
        base = f'{ns}/{arm}'
        for topic, msgtype, qos in (
                ('operating_state', OperatingState, STREAM),  # volatile, as crtk-py
                ('goal_reached', Bool, STREAM), ('error', String, STREAM),
                ('warning', String, STREAM), ('measured_js', JointState, STREAM),
                ('setpoint_js', JointState, STREAM), ('measured_cp', PoseStamped, STREAM),
                ('setpoint_cp', PoseStamped, STREAM), ('local/measured_cp', PoseStamped, STREAM),
                ('jaw/measured_js', JointState, STREAM)):
            self.msgs[topic] = []
            node.create_subscription(msgtype, f'{base}/{topic}',
                                     lambda m, t=topic: self._store(t, m), qos)
        self.pubs = {}
        for topic, msgtype in (('state_command', StringStamped), ('servo_jp', JointState),
                               ('servo_cp', PoseStamped), ('move_jp', JointState),
                               ('move_cp', PoseStamped), ('jaw/move_jp', JointState),
                               ('jaw/servo_jp', JointState)):
            self.pubs[topic] = node.create_publisher(msgtype, f'{base}/{topic}', COMMAND)

    def _store(self, topic, msg):
        with self.lock:
            self.msgs[topic].append((time.monotonic(), msg))

    def get(self, topic, since=0.0):
        with self.lock:
            return [m for t, m in self.msgs[topic] if t >= since]

    def last(self, topic):
        with self.lock:
            return self.msgs[topic][-1][1] if self.msgs[topic] else None

    def connected(self):
        """Every command matched and state flowing (as ``check_connections`` + first data)."""
        return all(p.get_subscription_count() > 0 for p in self.pubs.values()) \
            and self.last('measured_js') is not None and self.last('setpoint_cp') is not None

    def send(self, topic, msg):
        self.pubs[topic].publish(msg)

    def state_command(self, command, until, timeout=15.0):
        """Send a state command, wait for an operating_state satisfying ``until``."""
        start = time.monotonic()
        self.send('state_command', StringStamped(string=command))
        ok = self.ros.wait_for(lambda: any(until(m) for m in self.get('operating_state', start)),
                               timeout)
        assert ok, f'{self.arm}: no operating_state after {command!r}: ' \
                   f'{self.get("operating_state", start)}'

    def move(self, topic, msg, timeout=30.0):
        """Send a move_* and wait as crtk-py does: busy=True after the start, then busy=False."""
        start = time.monotonic()
        self.send(topic, msg)

        def done():
            states = self.get('operating_state', start)
            busy = [i for i, m in enumerate(states) if m.is_busy]
            return busy and any(not m.is_busy for m in states[busy[0]:])
        assert self.ros.wait_for(done, timeout), f'{self.arm}: no busy pulse for {topic}'
        assert self.ros.wait_for(lambda: self.get('goal_reached', start), 5.0)
        return [m.data for m in self.get('goal_reached', start)]

    def enable_and_home(self):
        self.state_command('enable', lambda m: m.state == 'ENABLED')
        self.state_command('home', lambda m: m.is_homed and not m.is_busy)


def joints(q):
    return JointState(position=[float(v) for v in q])


def pose_msg(T, frame=''):
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose = cv.pose_from_matrix(T)
    return msg


def test_graph_matches_the_dvrk_contract_headless_from_any_directory(ros, launch, tmp_path):
    sim = launch('simulator', cwd=tmp_path)  # no arguments, not the source folder
    node = ros.node('graph_probe')
    table = expected_contract()
    assert ros.wait_for(lambda: observed_contract(node, table) == table, 40.0), \
        sim.log()
    wanted = {f'/{arm}/{name}' for arm in ARMS for name in SERVICES}
    assert ros.wait_for(lambda: wanted <= set(dict(node.get_service_names_and_types())), 20.0)
    # every topic of the contract, with the dVRK's type, reliability and durability
    assert observed_contract(node, table) == table
    services = dict(node.get_service_names_and_types())
    for arm in ARMS:
        for name, srvtype in SERVICES.items():
            assert services.get(f'/{arm}/{name}') == [srvtype], (arm, name)

    # ground truth is latched in world; the dVRK version answers
    got = {}
    for topic in ('sim/markers/synth1/entry', 'sim/PSM1/base_frame', 'sim/phantom/measured_cp'):
        node.create_subscription(PoseStamped, f'/{topic}',
                                 lambda m, t=topic: got.setdefault(t, m), LATCHED)
    assert ros.wait_for(lambda: len(got) == 3, 10.0)
    assert {m.header.frame_id for m in got.values()} == {'world'}
    version = node.create_client(Trigger, '/PSM1/crtk_version')
    assert version.wait_for_service(10.0)
    answer = version.call_async(Trigger.Request())
    assert ros.wait_for(answer.done, 10.0)
    assert answer.result().success and answer.result().message == '1.1.0'

    # foot pedals: a client emulates a clutch press, the console pedal topic reports it
    presses = []
    node.create_subscription(Joy, '/footpedals/clutch', presses.append, LATCHED)
    emulate = node.create_publisher(Joy, '/console/emulate_clutch', COMMAND)
    assert ros.wait_for(lambda: emulate.get_subscription_count() > 0, 10.0)
    emulate.publish(Joy(buttons=[1]))
    assert ros.wait_for(lambda: [list(p.buttons) for p in presses] == [[1]], 10.0)

    assert sim.running()
    assert sim.stop() == SIGINT_EXIT  # stopped by SIGINT, cleanly
    assert 'Traceback' not in sim.log_path.read_text()


def test_a_client_runs_the_dvrk_arm_test_sequence(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    psm = ArmClient(ros, 'PSM1')
    clock = []
    psm.node.create_subscription(Clock, '/clock', lambda m: clock.append(m.clock), STREAM)
    assert ros.wait_for(psm.connected, 40.0), sim.log()

    # state keeps publishing while DISABLED, at 100 Hz of simulation time, with current stamps
    assert psm.last('operating_state') is None or psm.last('operating_state').state == 'DISABLED'
    t0 = time.monotonic()
    assert ros.wait_for(lambda: len(psm.get('measured_js', t0)) >= 150, 20.0)
    stamps = np.array([stamp_s(m) for m in psm.get('measured_js', t0)])
    assert np.all(stamps > 0) and np.all(np.diff(stamps) > 0)
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert rate == pytest.approx(100.0, rel=0.02)
    # current: within 0.1 s of /clock. The client takes one message per topic in turn, so on a
    # starved CPU its /clock queue (2x the state rate) falls behind; compare once it caught up.
    assert ros.wait_for(lambda: abs(stamp_s(psm.last('measured_js'))
                                    - cv.seconds_from_stamp(clock[-1])) < 0.1, 10.0)

    psm.enable_and_home()
    setpoint = np.array(psm.last('setpoint_js').position)
    # move_jp(setpoint).wait() twice: zero-length moves still pulse busy and reach the goal
    assert psm.move('move_jp', joints(setpoint)) == [True]
    assert psm.move('move_jp', joints(setpoint)) == [True]
    # a real move, and a move that arrives while another runs
    goal = setpoint + [0.2, -0.1, 0.0, 0.0, 0.0, 0.0]
    psm.send('move_jp', joints(setpoint + [0.4, 0.0, 0.0, 0.0, 0.0, 0.0]))
    assert psm.move('move_jp', joints(goal))[-1] is True
    assert ros.wait_for(lambda: np.allclose(psm.last('measured_js').position, goal, atol=1e-4),
                        10.0)
    # jaw and arm trajectories run concurrently: jaw close, insertion, both reach their goals
    start = time.monotonic()
    psm.send('jaw/move_jp', joints([JAW_CLOSED]))
    inserted = goal + [0.0, 0.0, 0.01, 0.0, 0.0, 0.0]
    assert psm.move('move_jp', joints(inserted))[-1] is True
    assert ros.wait_for(lambda: [m.data for m in psm.get('goal_reached', start)]
                        == [True, True], 10.0)
    assert ros.wait_for(lambda: abs(psm.last('jaw/measured_js').position[0] - JAW_CLOSED)
                        < 1e-3, 10.0)
    assert psm.move('jaw/move_jp', joints([JAW_OPEN])) == [True]

    # prepare_cartesian, then servo_jp sine +-5 deg on joints 0 and 1 at 100 Hz
    psm.move('move_jp', joints([0.0, 0.0, 0.12, 0.0, 0.0, 0.0]))
    start = time.monotonic()
    for k in range(100):
        s = math.radians(5.0) * math.sin(2 * math.pi * k / 100)
        psm.send('servo_jp', joints([s, s, 0.12, 0.0, 0.0, 0.0]))
        time.sleep(0.01)
    psm.send('servo_jp', joints([0.0, 0.0, 0.12, 0.0, 0.0, 0.0]))
    assert ros.wait_for(lambda: np.allclose(psm.last('measured_js').position,
                                            [0, 0, 0.12, 0, 0, 0], atol=1e-4), 10.0)
    assert not any(m.is_busy for m in psm.get('operating_state', start))
    for topic in ('setpoint_js', 'measured_js'):
        assert all(stamp_s(m) > 0 for m in psm.get(topic, start))
    # the setpoint follows the sine; the measured joints follow within the joint limits
    for joint in (0, 1):
        sent = [m.position[joint] for m in psm.get('setpoint_js', start)]
        assert max(sent) > math.radians(4.0) and min(sent) < -math.radians(4.0)
        assert max(abs(m.position[joint]) for m in psm.get('measured_js', start)) > 1e-3

    # servo_cp circle of 2 cm amplitude: every setpoint_cp is one of the goals within 0.1 mm
    T0 = cv.matrix_from_pose(psm.last('setpoint_cp').pose)
    goals = []
    start = time.monotonic()
    for k in range(120):
        a = 2 * math.pi * k / 120
        T = T0.copy()
        T[:2, 3] += 0.02 * np.array([math.cos(a) - 1.0, math.sin(a)])
        goals.append(T[:3, 3])
        psm.send('servo_cp', pose_msg(T))
        time.sleep(0.01)
    goals = np.array(goals)
    assert ros.wait_for(lambda: np.linalg.norm(cv.matrix_from_pose(
        psm.last('setpoint_cp').pose)[:3, 3] - goals[-1]) < 1e-4, 10.0)
    sampled = [cv.matrix_from_pose(m.pose)[:3, 3] for m in psm.get('setpoint_cp', start + 0.05)]
    assert len(sampled) > 10
    errors = [np.linalg.norm(goals - p, axis=1).min() for p in sampled]
    assert max(errors) < 1e-4
    # the tool follows (within the joint velocity and acceleration limits) and arrives
    moved = np.array([cv.matrix_from_pose(m.pose)[:3, 3] for m in psm.get('measured_cp', start)])
    assert np.linalg.norm(moved - moved[0], axis=1).max() > 0.005
    assert ros.wait_for(lambda: np.linalg.norm(cv.matrix_from_pose(
        psm.last('measured_cp').pose)[:3, 3] - goals[-1]) < 1e-4, 10.0)

    # move_cp +-2 cm
    for dx in (0.02, -0.02):
        T = T0.copy()
        T[0, 3] += dx
        assert psm.move('move_cp', pose_msg(T)) == [True]
        assert ros.wait_for(lambda: np.linalg.norm(cv.matrix_from_pose(
            psm.last('setpoint_cp').pose)[:3, 3] - T[:3, 3]) < 1e-4, 10.0)  # noqa: B023
        assert ros.wait_for(lambda: np.linalg.norm(cv.matrix_from_pose(
            psm.last('measured_cp').pose)[:3, 3] - T[:3, 3]) < 1e-4, 10.0)  # noqa: B023

    # frames: measured_cp in the camera frame (a patient cart), local/measured_cp in the RCM
    # frame and equal to the local forward kinematics of the measured joints
    assert psm.last('measured_cp').header.frame_id == 'ECM'
    assert psm.last('local/measured_cp').header.frame_id == 'PSM1_base'
    fk = psm.node.create_client(QueryForwardKinematics, '/PSM1/local/forward_kinematics')
    assert fk.wait_for_service(10.0)
    local = psm.last('local/measured_cp')  # and the joints sampled with it (same stamp)
    js = next(m for m in reversed(psm.get('measured_js')) if m.header.stamp == local.header.stamp)
    answer = fk.call_async(QueryForwardKinematics.Request(jp=list(js.position)))
    assert ros.wait_for(answer.done, 10.0) and answer.result().result
    T_fk = cv.matrix_from_pose(answer.result().cp)
    assert np.allclose(T_fk, cv.matrix_from_pose(local.pose), atol=1e-9)

    # every operating_state had a non-zero, strictly increasing stamp
    stamps = [cv.nanoseconds_from_stamp(m.header.stamp) for m in psm.get('operating_state')]
    assert len(stamps) > 10 and stamps[0] > 0 and np.all(np.diff(stamps) > 0)
    assert sim.running()


def test_commands_take_effect_in_the_order_they_were_sent(ros, launch):
    # The node takes servo_* goals at each stepping round (as the dVRK applies them in its
    # control loop) and every other command first takes the servo goals that came before it,
    # so a client's sequence holds: the command sent last wins.
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    psm = ArmClient(ros, 'PSM1')
    assert ros.wait_for(psm.connected, 40.0), sim.log()
    psm.enable_and_home()
    base = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
    psm.move('move_jp', joints(base))
    a, b, c = (base + [d0, d1, 0.0, 0.0, 0.0, 0.0]
               for d0, d1 in ((0.05, 0.0), (-0.05, 0.0), (-0.05, 0.03)))

    def settles_at(q):
        return ros.wait_for(lambda: np.allclose(psm.last('setpoint_js').position, q, atol=1e-9)
                            and np.allclose(psm.last('measured_js').position, q, atol=1e-4),
                            15.0)

    # servo goals, then a move: the move runs to its goal
    for _ in range(5):
        psm.send('servo_jp', joints(a))
    assert psm.move('move_jp', joints(b))[-1] is True
    assert settles_at(b), (psm.last('setpoint_js').position, sim.log())
    # a move, then a servo goal: the servo goal stops the move and holds
    start = time.monotonic()
    psm.send('move_jp', joints(a))
    psm.send('servo_jp', joints(c))
    assert settles_at(c), (psm.last('setpoint_js').position, sim.log())
    time.sleep(0.5)
    assert np.allclose(psm.last('measured_js').position, c, atol=1e-4)
    assert not any(m.is_busy for m in psm.get('operating_state', start)[-1:])


def test_a_second_home_leaves_a_homed_arm_homed_where_it_is(ros, launch):
    # A dVRK arm takes `home` as a desired state: HOMED when it is HOMED already changes nothing
    # (dvrk_crtk.md §2: the state is published again, is_homed stays true, nothing moves).
    # dvrk_teleoperation.py homes both arms at its start and stops on any operating_state with
    # is_homed false ("puppet (PSM1) is not homed anymore"), so a second home must not unhome.
    sim = launch('simulator', '--ros-args', '-p', 'power_up_time:=0.0')
    psm = ArmClient(ros, 'PSM1')
    assert ros.wait_for(psm.connected, 40.0), sim.log()
    psm.enable_and_home()  # from the rest pose: a homing motion of seconds
    homed = time.monotonic()
    goal = np.array(psm.last('setpoint_js').position) + [0.1, -0.05, 0.0, 0.2, 0.0, 0.0]
    assert psm.move('move_jp', joints(goal)) == [True]
    # the setpoint stream's newest sample at the goal (the move's last one may still be on its way)
    assert ros.wait_for(lambda: np.allclose(psm.last('setpoint_js').position, goal,
                                            atol=1e-9), 10.0)
    held = np.array(psm.last('setpoint_js').position)
    sent = time.monotonic()
    psm.send('state_command', StringStamped(string='home'))
    time.sleep(2.5)  # longer than the homing motion back would take
    states = [(m.state, m.is_homed, m.is_busy) for m in psm.get('operating_state', homed)]
    after = psm.get('operating_state', sent)
    assert after and (after[0].state, after[0].is_homed) == ('ENABLED', True), states
    assert all(is_homed for _, is_homed, _ in states), states
    np.testing.assert_allclose(psm.last('setpoint_js').position, held, atol=1e-9)
    assert sim.running()


def test_bad_commands_are_reported_and_the_arm_holds(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    psm = ArmClient(ros, 'PSM2')
    assert ros.wait_for(psm.connected, 40.0), sim.log()

    def says(topic, text, since):
        return ros.wait_for(lambda: any(text in m.data for m in psm.get(topic, since)), 10.0)

    home = [0.0, 0.0, 0.12, 0.0, 0.0, 0.0]
    t = time.monotonic()
    psm.send('servo_jp', joints(home))  # DISABLED
    assert says('warning', 'servo_jp, arm not ready', t)
    psm.state_command('enable', lambda m: m.state == 'ENABLED')
    t = time.monotonic()
    psm.send('move_jp', joints(home))  # enabled, not homed
    assert says('warning', 'move_jp, arm not ready', t)
    t = time.monotonic()
    psm.send('state_command', StringStamped(string='fly'))
    assert says('error', "unknown state command 'fly'", t)
    psm.state_command('home', lambda m: m.is_homed and not m.is_busy)
    held = np.array(psm.last('measured_js').position)
    T = cv.matrix_from_pose(psm.last('measured_cp').pose)

    bad_pose = pose_msg(T)
    bad_pose.pose.position.x = math.nan
    t = time.monotonic()
    psm.send('servo_cp', bad_pose)
    assert says('error', 'NaN or infinite', t)
    for field, value, text in (('x', math.inf, 'NaN or infinite'),
                               ('w', 0.0, 'not a unit quaternion (norm 0')):
        msg = pose_msg(T)
        if field == 'w':
            msg.pose.orientation.x = msg.pose.orientation.y = 0.0
            msg.pose.orientation.z = msg.pose.orientation.w = 0.0
        else:
            msg.pose.position.x = value
        t = time.monotonic()
        assert psm.move('move_cp', msg) == [False]
        assert says('error', text, t)
    msg = pose_msg(T)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = 2.0 * o.x, 2.0 * o.y, 2.0 * o.z, 2.0 * o.w  # norm 2
    t = time.monotonic()
    assert psm.move('move_cp', msg) == [False]
    assert says('error', 'not a unit quaternion', t)
    far = T.copy()
    far[:3, 3] += [1.0, 1.0, -1.0]
    t = time.monotonic()
    assert psm.move('move_cp', pose_msg(far)) == [False]
    assert says('error', 'unreachable', t)
    t = time.monotonic()
    psm.send('servo_jp', joints(home[:5]))
    assert says('error', 'must have 6 joint values', t)
    t = time.monotonic()
    assert psm.move('move_jp', joints(home + [0.0])) == [False]
    assert says('error', 'must have 6 joint values', t)
    t = time.monotonic()
    psm.send('jaw/servo_jp', joints([0.1, 0.2]))
    assert says('error', 'needs one finite angle', t)
    # the arm held through all of it
    time.sleep(0.2)
    assert np.allclose(psm.last('measured_js').position, held, atol=1e-9)
    # a goal outside the joint limits is clipped, as the dVRK does
    t = time.monotonic()
    psm.send('servo_jp', joints([0.0, 0.0, 5.0, 0.0, 0.0, 0.0]))
    assert says('warning', 'clipped to the joint limits (insertion)', t)
    k = psm_kinematics()
    assert ros.wait_for(lambda: psm.last('setpoint_js').position[2] == pytest.approx(
        k.upper[2]), 10.0)
    assert sim.running()
    n = len(psm.get('measured_js'))
    assert ros.wait_for(lambda: len(psm.get('measured_js')) > n + 20, 10.0)


def test_cartesian_goals_are_read_in_the_frame_they_name_and_other_frames_are_refused(
        ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    psm = ArmClient(ros, 'PSM2')
    node = psm.node
    got = {}
    node.create_subscription(PoseStamped, '/sim/PSM2/base_frame',
                             lambda m: got.__setitem__('base', m), LATCHED)
    node.create_subscription(PoseStamped, '/PSM2/local/setpoint_cp',
                             lambda m: got.__setitem__('local', m), STREAM)
    assert ros.wait_for(lambda: psm.connected() and 'base' in got, 40.0), sim.log()
    psm.enable_and_home()
    T_world_base = cv.matrix_from_pose(got['base'].pose)
    local = cv.matrix_from_pose(psm.last('local/measured_cp').pose)
    camera = cv.matrix_from_pose(psm.last('measured_cp').pose)
    T_camera_base = camera @ invert_transform(local)
    view = np.diag([-1.0, -1.0, 1.0, 1.0])  # ECM_view: x left, y up
    t = time.monotonic()
    for k, frame in enumerate(('', 'ECM', 'ECM_view', 'PSM2_base', 'world')):
        goal = local.copy()
        goal[:3, 3] += 0.002 * np.array([k % 2, k // 2 % 2, -1.0])  # in PSM2_base
        in_frame = {'': T_camera_base @ goal, 'ECM': T_camera_base @ goal,
                    'ECM_view': view @ T_camera_base @ goal, 'PSM2_base': goal,
                    'world': T_world_base @ goal}[frame]
        assert psm.move('move_cp', pose_msg(in_frame, frame)) == [True], frame
        assert ros.wait_for(lambda g=goal: np.allclose(cv.matrix_from_pose(
            got['local'].pose), g, atol=1e-9), 10.0), frame
    setpoint = got['local']
    msg = pose_msg(local, 'PSM1_base')
    for _ in range(50):                # a stream of them: one warning, throttled, none applied
        psm.send('servo_cp', msg)
        time.sleep(0.002)
    assert psm.move('move_cp', pose_msg(local, 'camera')) == [False]
    assert ros.wait_for(lambda: len(psm.get('warning', t)) == 2, 10.0)
    time.sleep(0.5)
    warnings = [m.data for m in psm.get('warning', t)]
    assert len(warnings) == 2, warnings
    assert "servo_cp stamped in frame 'PSM1_base' ignored" in warnings[0]
    assert "move_cp stamped in frame 'camera' ignored" in warnings[1]
    assert cv.matrix_from_pose(got['local'].pose) == pytest.approx(
        cv.matrix_from_pose(setpoint.pose))


def test_a_state_snapshot_gives_the_arm_properties():
    from sim_bridge.kinematics import ecm_kinematics
    from sim_bridge.nodes.crtk_arm import ArmSnapshot
    names = ('measured_jp', 'setpoint_jp', 'local_measured_cp', 'local_setpoint_cp',
             'measured_cp', 'setpoint_cp', 'jacobian_spatial', 'jacobian_body', 'measured_cv',
             'local_measured_cv')
    for arm in (Arm('PSM1', psm_kinematics(), ArmConfig()),
                Arm('ECM', ecm_kinematics(), ArmConfig(initial_jp=(0.2, 0.1, 0.05, 0.0)))):
        arm.state_command('enable')
        arm.state_command('home')
        for _ in range(400):
            arm.step(0.005)
        T = np.eye(4)
        T[:3, 3] = (0.01, -0.02, 0.03)
        arm.set_base_frame(T, 'ECM')
        goal = arm.setpoint_jp
        goal[:2] += (0.2, -0.1)
        arm.move_jp(goal)
        for _ in range(20):  # mid-move: the joints have speed
            arm.step(0.005)
        snapshot = ArmSnapshot(arm)
        assert np.any(arm.measured_jv != 0) and snapshot.reference_frame == 'ECM'
        for name in names:
            np.testing.assert_array_equal(getattr(snapshot, name), getattr(arm, name), name)


def reachable_grasp(chain, needle, T_world_base, T_world_needle, s=1.0 / 3.0):
    """World tool pose grasping the needle at arc parameter s, with the smallest wrist angles."""
    T_base_world = invert_transform(T_world_base)
    best, best_cost = None, np.inf
    for flip in (False, True):
        for roll in np.radians(np.arange(-180.0, 180.0, 15.0)):
            T_tool = T_world_needle @ invert_transform(
                needle.grasp_transform(s, roll=roll, flip=flip))
            Q, ok = chain.ik_batch((T_base_world @ T_tool)[None])
            if ok[0] and np.abs(Q[0, 4:]).max() < best_cost:
                best, best_cost = T_tool, np.abs(Q[0, 4:]).max()
    assert best is not None
    return best


def test_a_grasp_through_the_crtk_topics_is_an_event_and_the_scene_resets(ros, launch):
    sim = launch('simulator', '--ros-args', *FAST_ARMS)
    psm = ArmClient(ros, 'PSM2')
    node = psm.node
    events, truth = [], {}
    node.create_subscription(StringStamped, '/sim/events',
                             lambda m: events.append(cv.event_from_message(m)),
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=TL))
    node.create_subscription(PoseStamped, '/sim/needle/measured_cp',
                             lambda m: truth.__setitem__('needle', m), STREAM)
    node.create_subscription(PoseStamped, '/sim/PSM2/base_frame',
                             lambda m: truth.__setitem__('base', m), LATCHED)
    tf, tf_static = [], []
    node.create_subscription(TFMessage, '/tf', lambda m: tf.extend(m.transforms), STREAM)
    node.create_subscription(TFMessage, '/tf_static', lambda m: tf_static.extend(m.transforms),
                             QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=TL))
    assert ros.wait_for(lambda: psm.connected() and len(truth) == 2, 40.0), sim.log()
    # /tf: each arm's measured_cp under its reference frame, the needle under world; /tf_static
    # places the arm bases (what sim/<ARM>/base_frame says) in world
    assert ros.wait_for(lambda: tf and tf_static, 10.0)
    frames = {(t.header.frame_id, t.child_frame_id) for t in tf}
    assert {('ECM', 'PSM1'), ('ECM', 'PSM2'), ('world', 'ECM'),
            ('world', 'needle')} <= frames
    base = next(t.transform for t in tf_static if t.child_frame_id == 'PSM2_base')
    assert [base.translation.x, base.translation.y, base.translation.z] == pytest.approx(
        cv.matrix_from_pose(truth['base'].pose)[:3, 3].tolist())
    assert ros.wait_for(lambda: any(e['kind'] == 'target_pair' for _, e in events), 10.0)
    psm.enable_and_home()

    T_world_base = cv.matrix_from_pose(truth['base'].pose)
    T_world_needle = cv.matrix_from_pose(truth['needle'].pose)
    T_grasp = reachable_grasp(psm_kinematics(), load_scene_config().needle, T_world_base,
                              T_world_needle)
    T_base_world = invert_transform(T_world_base)
    above = T_grasp.copy()
    above[2, 3] += 0.01
    assert psm.move('jaw/move_jp', joints([0.8])) == [True]
    assert psm.move('move_cp', pose_msg(T_base_world @ above, 'PSM2_base')) == [True]
    assert psm.move('move_cp', pose_msg(T_base_world @ T_grasp, 'PSM2_base')) == [True]
    assert psm.move('jaw/move_jp', joints([-0.35])) == [True]
    assert ros.wait_for(lambda: any(e['kind'] == 'grasp' for _, e in events), 10.0)
    stamp, grasp = next((s, e) for s, e in events if e['kind'] == 'grasp')
    assert grasp['arm'] == 'PSM2' and grasp['t'] > 0 and stamp > 0
    # the needle follows the tool when it lifts
    lifted = T_grasp.copy()
    lifted[2, 3] += 0.02
    before = cv.matrix_from_pose(truth['needle'].pose)[2, 3]
    assert psm.move('move_cp', pose_msg(T_base_world @ lifted, 'PSM2_base')) == [True]
    assert ros.wait_for(lambda: cv.matrix_from_pose(truth['needle'].pose)[2, 3] - before
                        > 0.015, 10.0)

    # target pair selection and its refusal, both as events
    pair = node.create_publisher(String, '/sim/target_pair', COMMAND)
    assert ros.wait_for(lambda: pair.get_subscription_count() > 0, 10.0)
    pair.publish(String(data='synth3'))
    pair.publish(String(data='nowhere'))
    assert ros.wait_for(lambda: [e.get('pair') for _, e in events
                                 if e['kind'] == 'target_pair'][-2:] == ['synth3', 'nowhere'],
                        10.0)
    assert 'error' in [e for _, e in events if e['kind'] == 'target_pair'][-1]

    # reset: arms DISABLED again, the needle back on the pad, the clock goes on
    reset = node.create_client(Trigger, '/sim/reset')
    assert reset.wait_for_service(10.0)
    t = time.monotonic()
    answer = reset.call_async(Trigger.Request())
    assert ros.wait_for(answer.done, 10.0) and answer.result().success
    assert ros.wait_for(lambda: any(m.state == 'DISABLED' and not m.is_homed
                                    for m in psm.get('operating_state', t)), 10.0)
    assert ros.wait_for(lambda: any(e['kind'] == 'reset' for _, e in events), 10.0)
    reset_stamp = next(s for s, e in events if e['kind'] == 'reset')
    assert reset_stamp > stamp
    assert ros.wait_for(lambda: stamp_s(truth['needle']) > reset_stamp, 10.0)
    assert cv.matrix_from_pose(truth['needle'].pose)[2, 3] < before + 0.005
    stamps = [cv.nanoseconds_from_stamp(m.header.stamp) for m in psm.get('operating_state')]
    assert np.all(np.diff(stamps) > 0)


def move_duration_in_core(start_q, goal_q, dt):
    """Simulated time the core arm needs for a move_jp (steps of dt)."""
    arm = Arm('PSM1', psm_kinematics(), replace(ArmConfig(), initial_jp=tuple(start_q)))
    arm.state_command('enable')
    arm.state_command('home')
    while arm.operating_state.is_busy or not arm.operating_state.is_homed:
        arm.step(dt)
    arm.pop_events()
    arm.move_jp(goal_q)
    t = 0.0
    while True:
        arm.step(dt)
        t += dt
        if any(e.kind == 'goal_reached' for e in arm.pop_events()):
            return t


def test_faster_than_real_time_under_a_namespace_with_remaps(ros, launch):
    sim = launch('simulator', '--ros-args', '-r', '__ns:=/bench', '-r',
                 'PSM1/measured_js:=/left/measured_js', '-p', 'real_time_factor:=2.0',
                 '-p', 'clock_start:=1000.0', '-p', 'camera_rate:=2.0')
    client = ros.node('sim_time_client',
                      parameter_overrides=[Parameter('use_sim_time', value=True)])
    clock, stats = [], []
    client.create_subscription(Clock, '/clock',
                               lambda m: clock.append((time.monotonic(), m.clock)), STREAM)
    client.create_subscription(String, '/bench/sim/stats',
                               lambda m: stats.append((time.monotonic(), json.loads(m.data))),
                               STREAM)
    psm = ArmClient(ros, 'PSM2', ns='/bench')
    assert ros.wait_for(lambda: psm.connected() and len(clock) > 10, 40.0), sim.log()

    # remapping: everything under /bench, one topic moved elsewhere
    topics = dict(client.get_topic_names_and_types())
    assert topics.get('/left/measured_js') == ['sensor_msgs/msg/JointState']
    assert '/bench/PSM1/measured_js' not in topics and '/PSM1/measured_js' not in topics
    assert topics.get('/bench/sim/events') == ['crtk_msgs/msg/StringStamped']

    # /clock runs at twice the wall clock, from clock_start, less any backlog the loop had to
    # skip on a loaded machine (sim/stats reports it; bench/bench_simulator_node.py measures it)
    t = time.monotonic()
    assert ros.wait_for(lambda: len([w for w, _ in stats if w > t]) >= 3, 15.0)
    (w0, s0), (w1, s1) = [(w, s) for w, s in stats if w > t][-3::2]
    assert s1['real_time_factor'] == 2.0
    # the ECM stereo camera, at camera_rate, stamped on the simulator clock
    images, infos = [], []
    client.create_subscription(Image, '/bench/ECM/left/image_raw', images.append, STREAM)
    client.create_subscription(CameraInfo, '/bench/ECM/right/camera_info', infos.append, STREAM)
    advanced = s1['clock'] - s0['clock']
    ratio = (advanced + s1['skipped'] - s0['skipped']) / (w1 - w0)
    assert ratio == pytest.approx(2.0, rel=0.15)
    assert 1000.0 < cv.seconds_from_stamp(clock[-1][1]) < s1['clock'] + 1.0
    assert ros.wait_for(lambda: images and infos, 30.0)
    image, info = images[0], infos[0]
    assert (image.encoding, image.header.frame_id) == ('rgb8', 'ECM_left_optical')
    assert len(image.data) == image.height * image.step == image.height * image.width * 3
    assert (info.width, info.height) == (image.width, image.height)
    assert info.p[3] < 0 and stamp_s(image) > 1000.0  # right camera: P[0, 3] = -fx * baseline
    # a use_sim_time client's clock is the simulator's
    now = client.get_clock().now().nanoseconds * 1e-9
    assert 1000.0 < now < s1['clock'] + 5.0

    # the same move takes the same simulated time as in the core, whatever the factor
    psm.enable_and_home()
    start_q = np.array(psm.last('setpoint_js').position)
    goal_q = start_q + [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]
    t = time.monotonic()
    assert psm.move('move_jp', joints(goal_q)) == [True]
    states = psm.get('operating_state', t)
    busy = next(stamp_s(m) for m in states if m.is_busy)
    idle = next(stamp_s(m) for m in states if not m.is_busy and stamp_s(m) > busy)
    expected = move_duration_in_core(start_q, goal_q, 0.002)
    assert idle - busy == pytest.approx(expected, abs=0.005)
    assert sim.stop() == SIGINT_EXIT
    assert 'Traceback' not in sim.log_path.read_text()


def test_a_bad_parameter_stops_the_node_with_a_message_naming_it(launch):
    sim = launch('simulator', '--ros-args', '-p', 'real_time_factor:=-1.0')
    assert sim.popen.wait(30.0) == 2
    log = sim.log_path.read_text()
    assert 'real_time_factor must be >= 0' in log and 'Traceback' not in log


def test_at_the_dvrk_preset_measured_js_is_what_the_encoders_read(ros, launch):
    sim = launch('simulator', '--ros-args', '-p', 'arm_realism:=dvrk')
    psm = ArmClient(ros, 'PSM1')
    assert ros.wait_for(lambda: psm.connected(), 40.0), sim.log()
    t = time.monotonic()
    assert ros.wait_for(lambda: len(psm.get('measured_js', t)) >= 20, 20.0)
    # the arm at rest: its motor-side joints are its setpoint; what it reports is within a few
    # encoder counts (1e-4 rad, 2 um) of them and changes from one message to the next
    setpoint = np.array(psm.last('setpoint_js').position)
    measured = np.array([m.position for m in psm.get('measured_js', t)])
    count = np.array([1e-4, 1e-4, 2e-6, 1e-4, 1e-4, 1e-4])
    off = np.abs(measured - setpoint) / count
    assert np.all(off < 4.0), off.max(axis=0)
    assert np.any(off > 0.0) and np.any(measured[1:] != measured[:-1])
    # a jaw that holds nothing reads its own angle, initial_jaw (the preset's jaw stall is for
    # a held needle)
    assert ros.wait_for(lambda: psm.get('jaw/measured_js', t), 10.0)
    jaw = psm.last('jaw/measured_js')
    assert list(jaw.position) == [0.0] and list(jaw.velocity) == [0.0]
    assert sim.stop() == SIGINT_EXIT
    assert 'Traceback' not in sim.log_path.read_text()


def test_the_presets_levels_are_node_parameters(ros, launch):
    sim = launch('simulator', '--ros-args', '-p', 'arm_realism:=dvrk',
                 '-p', 'arm_realism_levels:=encoder_level=0, servo_level=0')
    psm = ArmClient(ros, 'PSM1')
    assert ros.wait_for(lambda: psm.connected(), 40.0), sim.log()
    t = time.monotonic()
    assert ros.wait_for(lambda: len(psm.get('measured_js', t)) >= 5, 20.0)
    # no encoders: the arm at rest reports its motor-side joints, its setpoint, exactly
    setpoint = psm.last('setpoint_js').position
    assert all(list(m.position) == list(setpoint) for m in psm.get('measured_js', t))
    assert sim.stop() == SIGINT_EXIT
    bad = launch('simulator', '--ros-args', '-p', 'arm_realism:=dvrk',
                 '-p', 'arm_realism_levels:=encoders=1')
    assert bad.popen.wait(30.0) == 2
    log = bad.log_path.read_text()
    assert 'arm_realism_levels must be key=level' in log and 'Traceback' not in log
