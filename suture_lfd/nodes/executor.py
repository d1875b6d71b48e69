"""
Executor node: learns a throw from a segment file and executes it on the simulator on command.

At start-up the node learns the skill (:func:`suture_lfd.skill.learn_skill`, parameter
``segments`` and ``method``, or loads a saved skill from ``skill``). A pair name on
``~/execute`` (std_msgs/String) starts a throw on that pair: the node enables and homes PSM1
and PSM2 if needed, selects the pair on ``sim/target_pair``, and runs the core
:class:`suture_lfd.skill.executor.ThrowExecutor` at ``rate`` Hz (wall clock): subtasks i, iii, v
scripted, ii and iv from the DMPs through the measured grasp, streamed as ``<ARM>/servo_cp``
(in the ``measured_cp`` frame) and ``<ARM>/jaw/servo_jp``. It reads ``<ARM>/measured_cp``,
``<ARM>/measured_js``, ``<ARM>/jaw/measured_js``, ``<ARM>/operating_state``,
``sim/<ARM>/base_frame``, ``sim/needle/measured_cp``, ``sim/markers/<pair>/entry|exit`` and
``sim/events`` (grasps, score).

It stops commanding and reports when an arm stops answering, when an arm leaves ``ENABLED``
(a fault), on ``~/stop`` (std_msgs/Empty), or after ``timeout`` s. The watchdog tells a dead
arm from a slow machine by the simulator's own clock (``/clock``, read whether or not the node
runs with ``use_sim_time``):

- an arm is silent when ``/clock`` advanced by more than ``stale_timeout`` simulation seconds
  since its last ``measured_cp`` was handled (ten times that once the commands are done and the
  throw settles): the simulation runs but the arm does not answer. A machine too busy to run
  the simulator or this node for a while stops both the clock and the arms, so it never counts;
- the simulator is dead when neither ``/clock`` nor any ``measured_cp`` has arrived for
  ``clock_timeout`` seconds of wall time (not counting ticks this node itself came late to).
  On the same machine the simulator's process tells more (``sim/process``,
  :mod:`sim_bridge.ros.peer`): once it has exited the simulator is dead as soon as the topics
  have been quiet for ``stale_timeout`` s of wall time; while it exists (starved of CPU by a
  busier process, or stopped) the throw waits for it, up to ``starved_timeout`` s of silence.

Without any ``/clock`` message the silence is estimated from the wall time since the last
``measured_cp`` and the rate the simulation clock was advancing over the last second, and a
stall longer than ``stale_timeout`` cannot be told from a dead simulator.

``~/status`` (std_msgs/String JSON, latched) carries the state (``idle``, ``preparing``,
``running``, ``settling``, ``done``, ``stopped``, ``failed``), the pair and the reason;
``~/result`` (latched) the outcome of each throw (pair, score, subtasks, entry and exit errors
from ``sim/events``, duration, ``time_s``: the score's throw time counted from the start of the
throw instead of the pair's selection); every score event of a throw is logged as
``sim/events: {json}``. With the parameter ``result_file`` the node also writes each outcome
there as one JSON object (replaced atomically at the end of every throw): the ``~/result``
record plus ``score_detail`` (the simulator's whole score) and ``executed``: for ``ii`` and
``iv`` the measured needle poses (``world``, ``t`` s from the start of the subtask, ``poses``
rows ``x, y, z, qx, qy, qz, qw``) while the plan was in that subtask; so a process without ROS
(``suture-lfd study --via-ros``) reads the outcome. A throw that cannot be planned (no reachable
grasp carries the needle along the rollouts) fails with ``planning_error`` in its outcome. A
malformed command (unknown pair, a throw already running) is reported on ``~/status`` and in the
log; the node keeps running. With the parameter ``pair`` the node executes that throw at
start-up and exits (code 0 for a throw scored 1.0), as a shell script wants. Parameters:
``config/executor.yaml``.
"""

from collections import deque
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sim_bridge.common.geometry import pose_from_transform
from sim_bridge.kinematics import psm_kinematics
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.client import SimClient
from sim_bridge.ros.params import declare_config
from sim_bridge.ros.peer import ProcessWatch
from sim_bridge.scene.scene_config import load_scene_config
from std_msgs.msg import Empty, String
from suture_lfd.nodes import executables
from suture_lfd.skill import ThrowSkill, learn_skill
from suture_lfd.skill.executor import ExecutorConfig, ThrowExecutor

PSMS = ('PSM1', 'PSM2')


@dataclass(frozen=True)
class ExecutorNodeConfig:
    """Parameters of the executor node (names as in ``config/executor.yaml``)."""

    segments: str = ''
    skill: str = ''
    method: str = 'paper'
    pair: str = ''
    rate: float = 100.0
    stale_timeout: float = 0.1
    clock_timeout: float = 1.0
    starved_timeout: float = 30.0
    settle_time: float = 0.5
    timeout: float = 120.0
    prepare_timeout: float = 60.0
    home: bool = True
    phase_stopping: bool = False
    exit_when_done: bool = False
    result_file: str = ''

    def __post_init__(self):
        if not self.segments and not self.skill:
            raise ValueError('parameter segments is empty: pass the segment file to learn '
                             'from, --ros-args -p segments:=PATH (or a saved skill, skill:=PATH)')
        for name in ('rate', 'stale_timeout', 'clock_timeout', 'starved_timeout', 'timeout',
                     'prepare_timeout'):
            if not getattr(self, name) > 0:
                raise ValueError(f'parameter {name} must be > 0, got {getattr(self, name)}')
        if self.settle_time < 0:
            raise ValueError(f'parameter settle_time must be >= 0, got {self.settle_time}')


class ExecutorNode(Node):
    """Execute learnt throws on the simulator's CRTK topics."""

    def __init__(self):
        super().__init__('executor')
        cfg = self.config = declare_config(self, ExecutorNodeConfig, 'executor.yaml',
                                           'executor')
        if cfg.skill:
            self.skill = ThrowSkill.load(cfg.skill)
        else:
            self.skill = learn_skill(cfg.segments, method=cfg.method)
        self._scene = load_scene_config()
        self._kinematics = psm_kinematics()
        self.finished = False
        self.exit_code = 0
        self._arrival = {}       # arm -> wall time (monotonic) of the last measured_cp
        self._sim_rate = 1.0     # simulation seconds per wall second, from measured_cp stamps
        self._rate_window = deque()
        self._clock_t = None     # newest /clock (s of simulator clock)
        self._clock_wall = None  # wall time (monotonic) /clock last advanced
        self._clock_handled = -math.inf  # wall time (monotonic) a /clock was last handled
        self._heard = {}         # arm -> /clock (s) when its last measured_cp was handled
        self._pair_stamp = None  # simulator clock (s) when the simulator selected the pair
        self._executed = {}      # 'ii' / 'iv' -> [(t, needle pose 7-vector)] measured
        self._score = None
        self._pair = ''
        self._pair_confirmed = False
        self._stage = 'idle'
        self._stage_wall = time.monotonic()
        self._executor = None
        self._t_start = self._t_done = None
        self._last_obs_t = None
        self._last_tick = time.monotonic()
        self._sent = 0
        self.sim = SimClient(self, PSMS, on_event=self._on_event,
                             on_measured_cp=self._on_measured_cp)
        self._status = self.create_publisher(String, '~/status', qos.LATCHED)
        self._result = self.create_publisher(String, '~/result', qos.LATCHED)
        self.create_subscription(ClockMsg, '/clock', self._on_clock, qos.CLOCK_LATEST)
        self.create_subscription(String, '~/execute', self._on_execute, qos.STREAM)
        self.create_subscription(Empty, '~/stop', self._on_stop, qos.STREAM)
        self._simulator = None   # ProcessWatch of the simulator, from sim/process
        self._starved_said = False
        self.create_subscription(String, 'sim/process', self._on_process, qos.LATCHED)
        # A steady (wall) clock: the watchdog must run when the simulation clock has stopped.
        self.create_timer(1.0 / cfg.rate, self._on_timer,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._publish_status('idle', f'skill learnt ({self.skill.method.name}) on '
                                     f'{self.skill.pair.name}; waiting for a pair on '
                                     '~/execute')
        if cfg.pair:
            self._start(cfg.pair)

    # --- inputs -----------------------------------------------------------------------------

    def _on_measured_cp(self, arm, stamp):
        now = time.monotonic()
        if arm == PSMS[0]:
            # Simulation seconds per wall second over the last second of arrivals (bursts of
            # queued messages would make a per-message estimate wild).
            window = self._rate_window
            window.append((now, stamp))
            while now - window[0][0] > 1.0:
                window.popleft()
            wall, advance = now - window[0][0], stamp - window[0][1]
            if wall > 0.2 and advance > 0.0:
                self._sim_rate = min(max(advance / wall, 0.05), 100.0)
        self._arrival[arm] = now
        self._heard[arm] = stamp if self._clock_t is None else max(stamp, self._clock_t)

    def _on_clock(self, msg):
        t = cv.seconds_from_stamp(msg.clock)
        now = time.monotonic()
        if self._clock_t is not None and t > self._clock_t \
                and now - self._clock_handled > 5.0 / self.config.rate:
            # The first /clock after a while without one: this node (or the simulator) was
            # held up, and the measured_cp that came meanwhile are still queued behind it. The
            # jump is no sign of silent arms.
            for a in self._heard:
                self._heard[a] += t - self._clock_t
        self._clock_handled = now
        if self._clock_t is None or t > self._clock_t:
            self._clock_t = t
            self._clock_wall = now

    def _on_process(self, msg):
        try:
            self._simulator = ProcessWatch(msg.data)
        except ValueError as exc:
            self.get_logger().warning(f'sim/process: {exc}')

    def _on_event(self, stamp, data):
        kind, arm = data.get('kind'), data.get('arm')
        if kind in ('grasp', 'release', 'entry', 'exit', 'withdrawn', 'extracted', 'trauma',
                    'drop') and self._stage in ('running', 'settling'):
            at = '' if self._t_start is None else f' at {_throw_time(stamp - self._t_start)}'
            self.get_logger().info(f'scene event {kind}{" " + arm if arm else ""}{at}')
        if kind == 'target_pair' and data.get('pair') == self._pair \
                and self._stage in ('preparing', 'running', 'settling'):
            if data.get('error'):
                if self._stage == 'preparing':
                    self._fail(f'the simulator refused pair {self._pair!r}: {data["error"]}')
            else:
                self._pair_stamp = stamp  # the score's time counts from here
                self._pair_confirmed = True
        elif kind == 'score' and self._stage in ('running', 'settling'):
            self._score = data.get('score')
            self.get_logger().debug(f'sim/events: {json.dumps(data)}')

    def _on_execute(self, msg):
        pair = msg.data.strip()
        if self._stage in ('preparing', 'running', 'settling'):
            self._warn(f'execute {pair!r} ignored: a throw on {self._pair} is in progress '
                       f'({self._stage})')
            return
        if not pair:
            self._warn('execute ignored: empty pair name')
            return
        self._start(pair)

    def _on_stop(self, _msg):
        if self._stage in ('preparing', 'running', 'settling'):
            self._halt('stopped', 'stop requested')

    # --- helpers ----------------------------------------------------------------------------

    def _publish_status(self, state, reason='', **extra):
        status = {'state': state, 'pair': self._pair, 'reason': reason, **extra}
        self._status.publish(String(data=json.dumps(status, sort_keys=True)))

    def _warn(self, text):
        self.get_logger().warning(text)
        self._publish_status(self._stage, text)

    def _enter(self, stage, reason=''):
        self._stage = stage
        self._stage_wall = time.monotonic()
        self._publish_status(stage, reason)

    def _start(self, pair):
        self._pair = pair
        self._pair_confirmed = False
        self._score = None
        self._pair_stamp = None
        self._executor = None
        self._t_start = self._t_done = None
        self.sim.watch_pairs([pair])
        self.sim.select_pair(pair)
        self._last_target = time.monotonic()
        self.get_logger().info(f'executing the {self.skill.method.name} skill learnt on '
                               f'{self.skill.pair.name} on pair {pair}')
        self._enter('preparing', f'throw on {pair} requested')

    def _send(self, command, t):
        self._sent += self.sim.send(command, cv.stamp_from_seconds(t))

    def _silence(self):
        """
        Return the silence of the arms: ``(simulation s, wall s or None)``.

        The first is the simulation time ``/clock`` advanced since the oldest last PSM
        ``measured_cp`` was handled (without ``/clock``: estimated from the wall time and the
        simulation rate); the second the wall time since anything came from the simulator
        (``/clock`` or a ``measured_cp``; None without ``/clock``). Wall time during which this
        node itself was busy (a tick that came late, e.g. while planning) is not held against
        the simulator: messages that arrived meanwhile are still queued, so the wall counts
        restart at the late tick.
        """
        now = time.monotonic()
        late = now - self._last_tick > 5.0 / self.config.rate
        self._last_tick = now
        if late:
            for a in PSMS:
                self._arrival[a] = max(self._arrival.get(a, now), now - 1.0 / self.config.rate)
            if self._clock_wall is not None:
                self._clock_wall = max(self._clock_wall, now - 1.0 / self.config.rate)
        if self._clock_t is None:
            return max((now - self._arrival.get(a, -math.inf)) * self._sim_rate
                       for a in PSMS), None
        silence = max(self._clock_t - self._heard.get(a, -math.inf) for a in PSMS)
        heard = max([self._clock_wall] + [self._arrival.get(a, -math.inf) for a in PSMS])
        return max(silence, 0.0), now - heard

    def _result_record(self, state, reason):
        score = self._score if isinstance(self._score, dict) else None
        duration = (None if self._t_start is None
                    else (self._t_done or self._last_obs_t or self._t_start) - self._t_start)
        time_s = duration
        if score is not None and score.get('score') == 1.0 and score.get('time_s') is not None \
                and self._pair_stamp is not None and self._t_start is not None:
            # the scorer counts from the pair's selection, before the arms were homed
            time_s = score['time_s'] - (self._t_start - self._pair_stamp)
        return {'pair': self._pair, 'state': state, 'outcome': state, 'reason': reason,
                'method': self.skill.method.name, 'learnt_on': self.skill.pair.name,
                'score': None if score is None else score.get('score'),
                'subtasks': None if score is None else score.get('subtasks'),
                'failure': None if score is None else score.get('failure'),
                'entry_error_mm': None if score is None else score.get('entry_error_mm'),
                'exit_error_mm': None if score is None else score.get('exit_error_mm'),
                'duration': duration, 'time_s': time_s, 'servo_cp_sent': self._sent}

    def _write_result(self, record):
        """Write the outcome to ``result_file`` (whole or not at all)."""
        path = Path(self.config.result_file)
        executed = {task: {'t': [t - rows[0][0] for t, _ in rows],
                           'poses': [pose.tolist() for _, pose in rows]}
                    for task, rows in self._executed.items()}
        data = {**record, 'score_detail': self._score if isinstance(self._score, dict) else None,
                'executed': executed}
        tmp = path.with_name(path.name + '.part')
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(data, sort_keys=True))
            os.replace(tmp, path)
        except OSError as exc:
            self.get_logger().error(f'cannot write result_file {path}: {exc}')

    def _halt(self, state, reason, **extra):
        """Stop commanding, say why, publish the result."""
        self._executor = None
        log = self.get_logger().info if state == 'done' else self.get_logger().error
        record = {**self._result_record(state, reason), **extra}
        log(f'throw on {self._pair} {state}: {reason} (score {record["score"]})')
        line = json.dumps(record, sort_keys=True)
        self._result.publish(String(data=line))
        print(line, flush=True)  # the result line on stdout; progress goes to the log (stderr)
        if self.config.result_file:
            self._write_result(record)
        self._stage = state
        self._stage_wall = time.monotonic()
        self._publish_status(state, reason, **extra)
        if self.config.exit_when_done or self.config.pair:
            self.exit_code = 0 if state == 'done' and record['score'] == 1.0 else 1
            self.finished = True

    def on_interrupt(self, signal_name):
        """Stop commanding (the arms hold their setpoints) and report a throw in progress."""
        if self._stage in ('preparing', 'running', 'settling'):
            self._halt('interrupted', f'stopped by {signal_name}')

    def _fail(self, reason):
        self._halt('failed', reason)

    # --- the sequence -----------------------------------------------------------------------

    def _on_timer(self):  # noqa: C901 (one stage per branch)
        cfg = self.config
        stage = self._stage
        if stage not in ('preparing', 'running', 'settling'):
            return
        if stage == 'preparing':
            if not self.sim.ready([self._pair]):
                if self._waited() > cfg.prepare_timeout:
                    missing = 'markers of the pair' if not self.sim.has_pair(self._pair) else \
                        'simulator topics'
                    self._fail(f'unknown marker pair {self._pair!r} or simulator not running '
                               f'({missing} not received in {cfg.prepare_timeout} s)')
                return
            if self.sim.homed():
                if not self._pair_confirmed:
                    if self._waited() > cfg.prepare_timeout:
                        self._fail(f'the simulator did not confirm pair {self._pair!r}')
                    elif time.monotonic() - self._last_target > 1.0:
                        # (again) every second: the first may have gone out before the
                        # simulator's subscription was matched
                        self._last_target = time.monotonic()
                        self.sim.select_pair(self._pair)
                    return
                try:
                    obs = self.sim.observation(self._pair)
                    self._executor = ThrowExecutor(
                        self.skill, obs.pair, self._scene.needle, kinematics=self._kinematics,
                        config=ExecutorConfig(script=self._scene.expert,
                                              phase_stopping=cfg.phase_stopping))
                    self._executor.reset(obs)
                except ValueError as exc:
                    self._halt('failed', f'cannot plan the throw on {self._pair}: {exc}',
                               planning_error=str(exc))
                    return
                self._t_start = self._last_obs_t = obs.t
                self._subtask = None
                self._sent = 0
                self._executed = {}
                self._enter('running', f'throw on {self._pair} started')
                return
            if not cfg.home or self._waited() > cfg.prepare_timeout:
                self._fail('arms not enabled and homed')
                return
            self.sim.enable_and_home()
            return
        silence, quiet = self._silence()
        # While commanding, 100 ms of silence stops the throw; once the commands are done
        # (settling) a silent arm is only reported if it lasts ten times longer.
        if silence > cfg.stale_timeout * (1.0 if stage == 'running' else 10.0):
            last = min(self.sim.tools[a][0] for a in PSMS)
            self._halt('stopped', f'no measured_cp for {silence * 1e3:.0f} ms of simulation '
                                  f'time (last at t = {last:.3f} s): the arms stopped answering',
                       silence_s=silence, last_measured_t=last)
            return
        alive = None
        if quiet is not None and quiet > cfg.stale_timeout and self._simulator is not None:
            alive = self._simulator.alive()
        elif quiet is not None and quiet <= cfg.stale_timeout:
            self._starved_said = False
        if quiet is not None and quiet > cfg.clock_timeout and alive \
                and quiet <= cfg.starved_timeout:
            if not self._starved_said:   # its process runs: starved of CPU, not dead
                self._starved_said = True
                self.get_logger().warning(
                    f'no /clock and no measured_cp for {quiet:.2f} s, but the simulator '
                    f'process {self._simulator.pid} runs: waiting for it (starved_timeout '
                    f'{cfg.starved_timeout:g} s)')
        elif quiet is not None and (quiet > cfg.clock_timeout or alive is False):
            last = min(self.sim.tools[a][0] for a in PSMS)
            if alive is False:
                self._halt('stopped', f'the simulator process {self._simulator.pid} exited: no '
                                      f'/clock and no measured_cp for {quiet:.2f} s of wall '
                                      f'time (last measured_cp at t = {last:.3f} s)',
                           silence_s=silence, wall_silence_s=quiet, last_measured_t=last)
                return
            self._halt('stopped', f'no /clock and no measured_cp for {quiet:.2f} s of wall time '
                                  f'(last measured_cp at t = {last:.3f} s, {silence * 1e3:.0f} '
                                  'ms of simulation time before the clock stopped): the '
                                  'simulator stopped', silence_s=silence, wall_silence_s=quiet,
                       last_measured_t=last)
            return
        fault = self.sim.fault()
        if fault is not None:
            self._halt('stopped', f'arm fault: {fault}')
            return
        obs = self.sim.observation(self._pair)
        if obs.t == self._last_obs_t and stage == 'running':
            return  # nothing new measured since the last command
        self._last_obs_t = obs.t
        if stage == 'running':
            command = self._executor.step(obs)
            self._send(command, obs.t)
            if command.subtask in ('ii', 'iv'):
                self._executed.setdefault(command.subtask, []).append(
                    (obs.t, pose_from_transform(obs.T_world_needle)))
            if command.subtask != self._subtask:
                self._subtask = command.subtask
                self.get_logger().info(f'subtask {command.subtask} at '
                                       f'{_throw_time(obs.t - self._t_start)}')
            if self._executor.done:
                self._t_done = obs.t
                self._enter('settling')
            elif obs.t - self._t_start > cfg.timeout:
                self._t_done = obs.t
                self._halt('failed', f'throw not done after {cfg.timeout} s '
                                     f'(subtask {command.subtask})')
            return
        if obs.t - self._t_done >= cfg.settle_time:
            self._halt('done', 'throw complete')

    def _waited(self):
        return time.monotonic() - self._stage_wall


def _throw_time(seconds):
    """Format simulation seconds since the throw started, labelled, for the log."""
    return f'sim t = {seconds:.3f} s'


def main(args=None):
    return executables.executor(args)


if __name__ == '__main__':
    sys.exit(main())
