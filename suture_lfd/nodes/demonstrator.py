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

Physical mode (``physical: true``): the subject sees what a robot shows. No ``sim/`` truth topic
is read: the arms and the camera's pose come from the CRTK topics and ``/tf_static`` (as the
executor's, :class:`sim_bridge.ros.client.SimClient` with ``physical=True``), the pair (and
``next_pair``) from the ``perception`` node's markers by their position along the wound (the
number the pair's name ends in), the needle from its needle pose, each grasp measured when a
jaw closes (:class:`suture_lfd.skill.perceived_feed.PerceptionFeed`). The score is the
evaluation's: the result's ``score`` is None and a completed throw exits with code 0.
Parameters: ``config/demonstrator.yaml``.
"""

from dataclasses import dataclass
import json
import sys
import time

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Joy
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.ros import qos
from sim_bridge.ros.client import SimClient
from sim_bridge.ros.entry import NodeHooks
from sim_bridge.ros.params import declare_config
from sim_bridge.scene.scene_config import load_scene_config
from std_msgs.msg import String
from suture_lfd.demos.cohort import load_cohort
from suture_lfd.demos.demonstrator import Demonstrator
from suture_lfd.nodes import executables
from suture_lfd.nodes.perception_topics import PerceptionTopics
from suture_lfd.skill.perceived_feed import PerceptionFeed, pair_index_from_name


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
    physical: bool = False

    def __post_init__(self):
        for name in ('rate', 'lag_tolerance', 'lag_tolerance_rad', 'timeout',
                     'startup_timeout'):
            if not getattr(self, name) > 0:
                raise ValueError(f'parameter {name} must be > 0, got {getattr(self, name)}')
        if self.settle_time < 0:
            raise ValueError(f'parameter settle_time must be >= 0, got {self.settle_time}')


class DemonstratorNode(NodeHooks, Node):
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
        self._score = None
        self._pair_confirmed = False
        self._recording = None
        self._bag = ''
        self._stage = 'waiting'
        self._stage_wall = time.monotonic()
        self._t_start = self._t_done = None
        self._dem = None
        self._scene = load_scene_config()
        self.sim = SimClient(self, PSMS, on_event=self._on_event, physical=cfg.physical)
        self._feeds = {}
        if cfg.physical:
            self._feeds = {name: PerceptionFeed(name, pair_index_from_name(name),
                                                self._scene.needle)
                           for name in (cfg.pair, cfg.next_pair) if name}
            PerceptionTopics(self, on_needle=self._on_needle, on_markers=self._on_markers)
        else:
            self.sim.watch_pairs([cfg.pair, cfg.next_pair])
        self._result = self.create_publisher(String, '~/result', qos.LATCHED)
        self._pedals = {}
        self._pressed = 0.0
        for name in (cfg.record_pedal, cfg.operator_pedal):
            if name:
                self._pedals[name] = self.create_publisher(Joy, name, qos.STREAM)
        if cfg.recorder_status:
            self.create_subscription(String, cfg.recorder_status, self._on_recorder, qos.LATCHED)
        self.create_timer(1.0 / cfg.rate, self._on_timer)
        self.get_logger().info(f'subject {self.subject.name} ({self.subject.group}) will suture '
                               f'{cfg.pair}')

    # --- inputs -----------------------------------------------------------------------------

    def _on_event(self, _stamp, data):
        kind = data.get('kind')
        if kind == 'target_pair' and data.get('pair') == self.config.pair \
                and self._stage == 'target':
            if data.get('error'):
                self.get_logger().error(f'the simulator refused pair {self.config.pair}: '
                                        f'{data["error"]}')
                self._finish(False, f'pair refused: {data["error"]}')
            self._pair_confirmed = True
        elif kind == 'score':
            self._score = data.get('score')

    def _on_needle(self, stamp, T_camera_needle, status):
        for feed in self._feeds.values():
            feed.needle_seen(stamp, T_camera_needle, status)

    def _on_markers(self, stamp, entries, exits, normal):
        for feed in self._feeds.values():
            feed.markers_seen(stamp, entries, exits, normal)

    def _observe(self):
        """Return the subject's observation: the simulator's topics, or arms plus perception."""
        if not self.config.physical:
            return self.sim.observation(self.config.pair)
        feed = self._feeds[self.config.pair]
        feed.camera_moved(self.sim.camera_pose())
        return feed.observe(self.sim.observation(None))

    def _next_pair(self):
        name = self.config.next_pair
        if not name:
            return None
        if not self.config.physical:
            return self.sim.marker_pair(name)
        feed = self._feeds[name]
        feed.camera_moved(self.sim.camera_pose())
        return feed.markers()

    def _ready(self):
        cfg = self.config
        if not self.config.physical:
            return self.sim.ready([cfg.pair, cfg.next_pair] if cfg.next_pair else [cfg.pair])
        if not self.sim.ready():
            return False
        obs = self._observe()
        return obs.pair is not None and obs.T_world_needle is not None and (
            not cfg.next_pair or self._next_pair() is not None)

    def _on_recorder(self, msg):
        try:
            status = json.loads(msg.data)
        except json.JSONDecodeError:
            return
        self._recording = bool(status.get('recording'))
        if status.get('bag'):
            self._bag = status['bag']

    # --- helpers ----------------------------------------------------------------------------

    def _press(self, topic, value):
        self._pressed = time.monotonic()
        if topic in self._pedals:
            msg = Joy()
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.buttons = [int(value)]
            self._pedals[topic].publish(msg)

    def _enter(self, stage):
        self._stage = stage
        self._stage_wall = time.monotonic()

    def _waited(self):
        return time.monotonic() - self._stage_wall

    def _finish(self, ok, why='', outcome=None):
        score = self._score
        value = score.get('score') if isinstance(score, dict) else score
        outcome = outcome or ('completed' if ok else 'failed')
        result = {'subject': self.subject.name, 'group': self.subject.group,
                  'pair': self.config.pair, 'completed': bool(ok), 'outcome': outcome,
                  'reason': why,
                  'score': value, 'score_detail': score if isinstance(score, dict) else None,
                  'bag': self._bag, 'published': dict(self.sim.published),
                  'duration': (None if self._t_done is None or self._t_start is None
                               else self._t_done - self._t_start)}
        line = json.dumps(result, sort_keys=True)
        self._result.publish(String(data=line))
        print(line, flush=True)  # the result line on stdout; progress goes to the log (stderr)
        scored = value == 1.0 or (self.config.physical and value is None)
        self.exit_code = 0 if ok and scored else 1
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
                self._finish(False, 'perception outputs or arm topics missing (are the '
                                    'perception node and the simulator running?)'
                             if cfg.physical else
                             'simulator topics missing (is the simulator running?)')
            return
        if stage == 'homing':
            if self.sim.homed():
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
                    self.sim.select_pair(cfg.pair)
                return
            if not cfg.home or self._waited() > cfg.startup_timeout:
                self._finish(False, 'arms not enabled and homed')
                return
            self.sim.enable_and_home()
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
                self.sim.select_pair(cfg.pair)
                self._enter('target')
            return
        if stage == 'target':
            confirmed = self._pair_confirmed or (cfg.physical and self._waited() > 1.0
                                                 and self.sim.target_matched())
            if confirmed or self._waited() > 5.0:
                if cfg.physical:
                    self.sim.select_pair(cfg.pair)  # matched by now: this one arrives
                obs = self._observe()
                self._dem = Demonstrator(
                    self.subject, obs.pair, self._scene.needle,
                    rng=np.random.default_rng([self.subject.trial_seed(cfg.pair), cfg.seed]),
                    next_pair=self._next_pair(),
                    expert_config=self._scene.expert, lag_tolerance=cfg.lag_tolerance,
                    lag_tolerance_rad=cfg.lag_tolerance_rad)
                self._dem.reset(obs)
                self._t_start = obs.t
                self._enter('running')
            return
        obs = self._observe()
        if stage == 'running':
            self.sim.send(self._dem.step(obs), self.get_clock().now().to_msg())
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
