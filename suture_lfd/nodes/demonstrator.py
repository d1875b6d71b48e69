"""
Demonstrator node: a synthetic study subject teleoperating the simulated dVRK for one throw.

Drives the ``simulator`` node the way an MTM teleoperation does: reads ``<ARM>/measured_cp``,
``<ARM>/measured_js``, ``<ARM>/jaw/measured_js``, ``<ARM>/operating_state`` of PSM1 and PSM2
and the simulator's ground truth (``sim/<ARM>/base_frame``, ``sim/needle/measured_cp``,
``sim/markers/<pair>/entry|exit``, ``sim/events``), and streams ``<ARM>/servo_cp`` (in the
``measured_cp`` frame) and ``<ARM>/jaw/servo_jp`` at ``rate`` from the core
:class:`suture_lfd.demos.demonstrator.Demonstrator` of the configured subject.

Sequence: wait for the topics; enable and home the arms if needed; press the record pedal (the
recorder's toggle, ``/footpedals/camera`` through its ``emulate`` topic) and wait until
``recorder_status`` says it records; hold the operator-present pedal (coag); select the pair on
``sim/target_pair``; perform the throw; after ``settle_time`` release the coag pedal, press the
record pedal again and wait until the recorder has closed its bag; publish the result on
``~/result`` (std_msgs/String JSON, latched: subject, pair, duration, score, bag) and exit (exit
code 0 for a throw scored 1.0; ``published`` counts the commands sent per topic).
Parameters: ``config/demonstrator.yaml``.
"""

from dataclasses import dataclass
import json
import sys
import time

from crtk_msgs.msg import OperatingState, StringStamped
from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState, Joy
from sim_bridge.control import Observation
from sim_bridge.ros import conversions as cv
from sim_bridge.ros.params import declare_config
from sim_bridge.scene.phantom import MarkerPair
from sim_bridge.scene.scene_config import load_scene_config
from std_msgs.msg import String
from suture_lfd.demos.cohort import load_cohort
from suture_lfd.demos.demonstrator import Demonstrator
from suture_lfd.nodes import executables

PSMS = ('PSM1', 'PSM2')
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
EVENTS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATE = QoSProfile(depth=10)
# The servo streams: the arm takes only the newest goal, but a recorder takes every one, and a
# publisher's history is all a reader that stalls for a moment can catch up from; 1000 goals
# cover a second at 1 kHz (depth 10 lost 16 % of a demonstration's goals on a busy machine).
COMMAND_STREAM = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)


@dataclass(frozen=True)
class DemonstratorConfig:
    """Parameters of the demonstrator node (names as in ``config/demonstrator.yaml``)."""

    subject: str = 'S01'
    cohort_seed: int = 0
    cohort_file: str = ''
    pair: str = 'synth1'
    next_pair: str = ''
    seed: int = 0
    rate: float = 100.0
    lag_tolerance: float = 0.001
    lag_tolerance_rad: float = 0.1
    home: bool = True
    record_pedal: str = '/footpedals/camera/emulate'
    recorder_status: str = '/recorder/status'
    operator_pedal: str = '/footpedals/coag/emulate'
    settle_time: float = 0.5
    timeout: float = 120.0
    startup_timeout: float = 60.0
    exit_when_done: bool = True

    def __post_init__(self):
        for name in ('rate', 'lag_tolerance', 'lag_tolerance_rad', 'timeout',
                     'startup_timeout'):
            if not getattr(self, name) > 0:
                raise ValueError(f'parameter {name} must be > 0, got {getattr(self, name)}')
        if self.settle_time < 0:
            raise ValueError(f'parameter settle_time must be >= 0, got {self.settle_time}')


class DemonstratorNode(Node):
    """One subject's throw over the CRTK topics of the simulator."""

    def __init__(self):
        super().__init__('demonstrator')
        cfg = self.config = declare_config(self, DemonstratorConfig, 'demonstrator.yaml',
                                           'demonstrator')
        subjects = load_cohort(cfg.cohort_file or None, seed=cfg.cohort_seed)
        named = {s.name: s for s in subjects}
        if cfg.subject not in named:
            raise ValueError(f'parameter subject: unknown subject {cfg.subject!r}; the cohort '
                             f'has {sorted(named)}')
        self.subject = named[cfg.subject]
        self.finished = False
        self.exit_code = 1
        self._tools, self._q, self._jaw, self._state = {}, {}, {}, {}
        self._bases, self._markers = {}, {}
        self._needle = None
        self._holders = set()
        self._score = None
        self._pair_confirmed = False
        self._recording = None
        self._bag = ''
        self._stage = 'waiting'
        self._stage_wall = time.monotonic()
        self._t_start = self._t_done = None
        self._dem = None
        self._last_command = -1e9
        self._commanded_on = None  # arm states when enable/home were last sent
        self._published = {}
        self._scene = load_scene_config()
        self._servo = {a: self.create_publisher(PoseStamped, f'{a}/servo_cp', COMMAND_STREAM)
                       for a in PSMS}
        self._jaw_pub = {a: self.create_publisher(JointState, f'{a}/jaw/servo_jp', COMMAND_STREAM)
                         for a in PSMS}
        self._command = {a: self.create_publisher(StringStamped, f'{a}/state_command', STATE)
                         for a in PSMS}
        self._target = self.create_publisher(String, 'sim/target_pair', STATE)
        self._result = self.create_publisher(String, '~/result', LATCHED)
        self._pedals = {}
        self._pressed = 0.0
        for name in (cfg.record_pedal, cfg.operator_pedal):
            if name:
                self._pedals[name] = self.create_publisher(Joy, name, STATE)
        for a in PSMS:
            self.create_subscription(PoseStamped, f'{a}/measured_cp',
                                     lambda m, a=a: self._on_cp(a, m), STATE)
            self.create_subscription(JointState, f'{a}/measured_js',
                                     lambda m, a=a: self._q.__setitem__(a, m), STATE)
            self.create_subscription(JointState, f'{a}/jaw/measured_js',
                                     lambda m, a=a: self._jaw.__setitem__(a, m), STATE)
            self.create_subscription(OperatingState, f'{a}/operating_state',
                                     lambda m, a=a: self._state.__setitem__(a, m), LATCHED)
            self.create_subscription(PoseStamped, f'sim/{a}/base_frame',
                                     lambda m, a=a: self._bases.__setitem__(
                                         a, cv.matrix_from_pose(m.pose)), LATCHED)
        for which in ('entry', 'exit'):
            self.create_subscription(PoseStamped, f'sim/markers/{cfg.pair}/{which}',
                                     lambda m, w=which: self._markers.__setitem__(
                                         w, cv.matrix_from_pose(m.pose)), LATCHED)
        if cfg.next_pair:
            for which in ('entry', 'exit'):
                self.create_subscription(PoseStamped, f'sim/markers/{cfg.next_pair}/{which}',
                                         lambda m, w=which: self._markers.__setitem__(
                                             'next_' + w, cv.matrix_from_pose(m.pose)), LATCHED)
        self.create_subscription(PoseStamped, 'sim/needle/measured_cp', self._on_needle, STATE)
        self.create_subscription(StringStamped, 'sim/events', self._on_event, EVENTS)
        if cfg.recorder_status:
            self.create_subscription(String, cfg.recorder_status, self._on_recorder, LATCHED)
        self.create_timer(1.0 / cfg.rate, self._on_timer)
        self.get_logger().info(f'subject {self.subject.name} ({self.subject.group}) will suture '
                               f'{cfg.pair}')

    # --- inputs -----------------------------------------------------------------------------

    def _on_cp(self, arm, msg):
        self._tools[arm] = (cv.seconds_from_stamp(msg.header.stamp), msg.header.frame_id,
                            cv.matrix_from_pose(msg.pose))

    def _on_needle(self, msg):
        self._needle = cv.matrix_from_pose(msg.pose)

    def _on_event(self, msg):
        try:
            _, data = cv.event_from_message(msg)
        except ValueError as exc:
            self.get_logger().warning(f'sim/events: {exc}')
            return
        kind, arm = data.get('kind'), data.get('arm')
        if kind == 'grasp' and arm in PSMS:
            self._holders.add(arm)
        elif kind == 'release' and arm in PSMS:
            self._holders.discard(arm)
        elif kind == 'reset':
            self._holders.clear()
        elif kind == 'target_pair' and data.get('pair') == self.config.pair \
                and self._stage == 'target':
            if data.get('error'):
                self.get_logger().error(f'the simulator refused pair {self.config.pair}: '
                                        f'{data["error"]}')
                self._finish(False, f'pair refused: {data["error"]}')
            self._pair_confirmed = True
        elif kind == 'score':
            self._score = data.get('score')

    def _on_recorder(self, msg):
        try:
            status = json.loads(msg.data)
        except json.JSONDecodeError:
            return
        self._recording = bool(status.get('recording'))
        if status.get('bag'):
            self._bag = status['bag']

    # --- helpers ----------------------------------------------------------------------------

    def _world_tool(self, arm):
        _, frame, T = self._tools[arm]
        return T if frame == 'world' else self._bases[arm] @ T

    def _pair(self, prefix=''):
        m = self._markers
        entry, exit_ = m[prefix + 'entry'], m[prefix + 'exit']
        n = entry[:3, 2] + exit_[:3, 2]
        name = self.config.next_pair if prefix else self.config.pair
        return MarkerPair(name=name, entry=entry[:3, 3].copy(), exit=exit_[:3, 3].copy(),
                          normal=n / np.linalg.norm(n), entry_normal=entry[:3, 2].copy(),
                          exit_normal=exit_[:3, 2].copy())

    def _ready(self):
        need = len(self._markers) >= (4 if self.config.next_pair else 2)
        return (need and self._needle is not None and all(
            a in self._tools and a in self._bases and a in self._jaw and a in self._state
            for a in PSMS))

    def _press(self, topic, value):
        self._pressed = time.monotonic()
        if topic in self._pedals:
            msg = Joy()
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.buttons = [int(value)]
            self._pedals[topic].publish(msg)

    def _state_command(self, arm, command):
        msg = StringStamped()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.string = command
        self._command[arm].publish(msg)

    def _enter(self, stage):
        self._stage = stage
        self._stage_wall = time.monotonic()

    def _waited(self):
        return time.monotonic() - self._stage_wall

    def _observation(self):
        q = {a: np.asarray(self._q[a].position, dtype=float) for a in PSMS
             if a in self._q and len(self._q[a].position) >= 6}
        return Observation(
            t=max(self._tools[a][0] for a in PSMS),
            T_world_tool={a: self._world_tool(a) for a in PSMS},
            jaw={a: float(self._jaw[a].position[0]) if len(self._jaw[a].position) else 0.0
                 for a in PSMS},
            T_world_needle=self._needle, holders=tuple(sorted(self._holders)),
            pair=self._pair(), T_world_base=dict(self._bases), q=q or None)

    def _count(self, publisher):
        topic = publisher.topic_name
        self._published[topic] = self._published.get(topic, 0) + 1

    def _send(self, command):
        stamp = self.get_clock().now().to_msg()
        for arm in PSMS:
            T = command.T_world_tool.get(arm)
            if T is not None:
                _, frame, _ = self._tools[arm]
                T_cmd = T if frame == 'world' else np.linalg.solve(self._bases[arm], T)
                self._servo[arm].publish(cv.pose_stamped(T_cmd, frame, stamp))
                self._count(self._servo[arm])
            jaw = command.jaw.get(arm)
            if jaw is not None:
                self._jaw_pub[arm].publish(cv.joint_state(['jaw'], stamp, position=[jaw]))
                self._count(self._jaw_pub[arm])

    def _finish(self, ok, why='', outcome=None):
        score = self._score
        value = score.get('score') if isinstance(score, dict) else score
        outcome = outcome or ('completed' if ok else 'failed')
        result = {'subject': self.subject.name, 'group': self.subject.group,
                  'pair': self.config.pair, 'completed': bool(ok), 'outcome': outcome,
                  'reason': why,
                  'score': value, 'score_detail': score if isinstance(score, dict) else None,
                  'bag': self._bag, 'published': dict(self._published),
                  'duration': (None if self._t_done is None or self._t_start is None
                               else self._t_done - self._t_start)}
        line = json.dumps(result, sort_keys=True)
        self._result.publish(String(data=line))
        print(line, flush=True)  # the result line on stdout; progress goes to the log (stderr)
        self.exit_code = 0 if ok and value == 1.0 else 1
        log = self.get_logger().info if self.exit_code == 0 else self.get_logger().error
        log(f'throw on {self.config.pair} by {self.subject.name} {outcome}'
            f'{": " + why if why else ""} (score {value})')
        self._enter('finished')
        if self.config.exit_when_done:
            self.finished = True

    def on_interrupt(self, signal_name):
        """Stop commanding (the arms hold their setpoints) and report the throw interrupted."""
        if self._stage != 'finished':
            self._finish(False, f'stopped by {signal_name}', outcome='interrupted')

    # --- the sequence -----------------------------------------------------------------------

    def _on_timer(self):  # noqa: C901 (one stage per branch)
        cfg = self.config
        stage = self._stage
        if stage == 'finished':
            return
        if stage == 'waiting':
            if self._ready():
                self._enter('homing')
            elif self._waited() > cfg.startup_timeout:
                self._finish(False, 'simulator topics missing (is the simulator running?)')
            return
        if stage == 'homing':
            states = [self._state[a] for a in PSMS]
            if all(s.state == 'ENABLED' and s.is_homed and not s.is_busy for s in states):
                pedal = self._pedals.get(cfg.record_pedal)
                if (pedal is not None and cfg.recorder_status
                        and pedal.get_subscription_count() == 0
                        and self._waited() < cfg.startup_timeout):
                    return  # a press nobody hears yet would be lost: wait for the recorder
                self._press(cfg.record_pedal, 1)
                self._press(cfg.record_pedal, 0)
                self._enter('recording' if cfg.record_pedal and cfg.recorder_status
                            else 'target')
                if self._stage == 'target':
                    self._target.publish(String(data=cfg.pair))
                return
            if not cfg.home or self._waited() > cfg.startup_timeout:
                self._finish(False, 'arms not enabled and homed')
                return
            # at once when an arm's state changes (a dVRK arm powers up for a while, then
            # homes in a motion of seconds), and again every 2 s
            seen = [(s.state, s.is_homed, s.is_busy) for s in states]
            if seen != self._commanded_on or time.monotonic() - self._last_command > 2.0:
                self._last_command, self._commanded_on = time.monotonic(), seen
                for a in PSMS:
                    s = self._state[a]
                    if s.state != 'ENABLED':
                        self._state_command(a, 'enable')
                    elif not s.is_homed and not s.is_busy:
                        self._state_command(a, 'home')
            return
        if stage == 'recording':
            if not self._recording and time.monotonic() - self._pressed > 2.0 \
                    and self._waited() < 9.0:
                # the recorder reports no recording: the press went unheard (its subscription
                # was not matched yet, so DDS dropped it rather than delaying it); press again
                self._press(cfg.record_pedal, 1)
                self._press(cfg.record_pedal, 0)
            if self._recording or self._waited() > 10.0:
                if not self._recording:
                    self.get_logger().warning(f'{cfg.recorder_status} does not report a '
                                              'recording; going on')
                self._press(cfg.operator_pedal, 1)
                self._target.publish(String(data=cfg.pair))
                self._enter('target')
            return
        if stage == 'target':
            if self._pair_confirmed or self._waited() > 5.0:
                obs = self._observation()
                self._dem = Demonstrator(
                    self.subject, obs.pair, self._scene.needle,
                    rng=np.random.default_rng([self.subject.trial_seed(cfg.pair), cfg.seed]),
                    next_pair=self._pair('next_') if cfg.next_pair else None,
                    expert_config=self._scene.expert, lag_tolerance=cfg.lag_tolerance,
                    lag_tolerance_rad=cfg.lag_tolerance_rad)
                self._dem.reset(obs)
                self._t_start = obs.t
                self._enter('running')
            return
        obs = self._observation()
        if stage == 'running':
            self._send(self._dem.step(obs))
            if self._dem.done:
                self._t_done = obs.t
                self._enter('settling')
            elif obs.t - self._t_start > cfg.timeout:
                self._t_done = obs.t
                self._finish(False, f'throw not done after {cfg.timeout} s '
                                    f'(subtask {self._dem.subtask})')
            return
        if stage == 'settling':
            if obs.t - self._t_done >= cfg.settle_time:
                self._press(cfg.operator_pedal, 0)
                self._press(cfg.record_pedal, 1)
                self._press(cfg.record_pedal, 0)
                self._enter('closing' if cfg.record_pedal and cfg.recorder_status else 'done')
            return
        if stage == 'closing' and not (self._recording is False or self._waited() > 20.0):
            return
        self._finish(True)


def main(args=None):
    return executables.demonstrator(args)


if __name__ == '__main__':
    sys.exit(main())
