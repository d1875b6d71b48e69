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

Physical mode (``physical: true``, for a physical dVRK or the simulator's ``physical:=true``):
the node reads only what a dVRK provides and never a ``sim/`` truth topic. The arms come from
their CRTK topics (``measured_cp`` in the camera frame, ``local/measured_cp`` in
``<ARM>_base``), the bases and the camera's optical frame from ``/tf_static``, the camera's pose
from ``ECM/local/measured_cp``; the markers and the needle from the ``perception`` node
(``perception/markers/entries|exits``, ``perception/needle/measured_cp`` and ``status``), through
:class:`suture_lfd.skill.perceived_feed.PerceptionFeed`, which measures each grasp when a jaw
closes. The pair is found in the markers by its position along the wound (``pair_index``, or
the number the pair's name ends in). Before the throw starts the node waits for the markers and
the needle seen after the arms were homed; a throw whose markers or needle are not seen within
``prepare_timeout`` is not pushed: it fails with ``not seen: ...``. With ``correction`` (the
default) the node first registers each PSM against the endoscope, once (state ``registering``):
it commands the PSM to six poses in view, finds the instrument in ``<camera>/left|right/
image_raw`` (with their ``camera_info``), fits each arm's joint offsets and base translation
(:mod:`suture_lfd.skill.arm_registration`, the core the in-process physical mode runs), then
runs every throw on the corrected kinematics. The score is the
evaluation's (not read here): the outcome's ``score`` is None.

The controller steps on consistent data only: once per new stamp of the arms' state, where an
arm's state is its ``measured_cp``, ``local/measured_cp``, ``measured_js`` and
``jaw/measured_js`` of one stamp (paired by :class:`sim_bridge.ros.client.SimClient`, never the
newest of each), and in physical mode with the perception's looks stamped at or before that
state (:class:`suture_lfd.skill.perceived_feed.PerceptionFeed`); each command is stamped with
the state's stamp.

It stops commanding and reports when an arm stops answering, when an arm leaves ``ENABLED``
(a fault), on ``~/stop`` (std_msgs/Empty), or after ``timeout`` s. The watchdog
(:class:`suture_lfd.skill.watchdog.ArmWatchdog`) tells a dead arm from a slow machine by the
simulator's own clock (``/clock``, read whether or not the node runs with ``use_sim_time``):
an arm is silent when ``/clock`` advanced by more than ``stale_timeout`` simulation seconds since
its last ``measured_cp``; the simulator is dead when neither ``/clock`` nor any ``measured_cp``
came for ``clock_timeout`` s of wall time; on the same machine the simulator's process
(``sim/process``, :mod:`sim_bridge.ros.peer`) tells a starved simulator (waited for up to
``starved_timeout`` s) from an exited one.

``~/status`` (std_msgs/String JSON, latched) carries the state (``idle``, ``preparing``,
``registering``, ``running``, ``settling``, ``done``, ``stopped``, ``failed``), the pair and
the reason;
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
start-up and exits (code 0 for a throw scored 1.0), as a shell script wants. With ``tissue``
(the simulator's needle-in-tissue preset, ``config/realism_tissue.yaml``) the node watches the
grasp during the DMP subtasks as the in-process executor does: in ground truth the needle turned
in the jaw is seen every step (as always), in physical mode the held needle is looked at again
through the perception's newest look. Parameters: ``config/executor.yaml``.
"""

from dataclasses import dataclass
import json
import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.kinematics import psm_kinematics
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.client import SimClient
from sim_bridge.ros.entry import NodeHooks
from sim_bridge.ros.params import declare_config
from sim_bridge.ros.peer import ProcessWatch
from sim_bridge.scene.scene_config import load_scene_config
from std_msgs.msg import Empty, String
from suture_lfd.nodes import executables
from suture_lfd.nodes.perception_topics import PerceptionTopics, StereoImages
from suture_lfd.skill import ThrowSkill, learn_skill
from suture_lfd.skill.executor_machine import ExecutorMachine, MachineConfig
from suture_lfd.skill.watchdog import ArmWatchdog


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
    physical: bool = False
    pair_index: int = 0
    correction: bool = True
    camera: str = 'ECM'
    tissue: str = 'none'

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
        load_tissue_realism(self.tissue)  # a preset the file has (the error names them)
        if self.pair_index < 0:
            raise ValueError(f'parameter pair_index must be >= 0 (0: from the pair name), got '
                             f'{self.pair_index}')


class ExecutorNode(NodeHooks, Node):
    """Execute learnt throws on the simulator's CRTK topics."""

    def __init__(self):
        super().__init__('executor')
        cfg = self.config = declare_config(self, ExecutorNodeConfig, 'executor.yaml',
                                           'executor')
        if cfg.skill:
            self.skill = ThrowSkill.load(cfg.skill)
        else:
            self.skill = learn_skill(cfg.segments, method=cfg.method)
        self.watchdog = ArmWatchdog(PSMS, cfg.rate, cfg.stale_timeout, cfg.clock_timeout,
                                    cfg.starved_timeout)
        self.sim = SimClient(self, PSMS, on_event=self._on_event,
                             on_measured_cp=self._on_measured_cp, physical=cfg.physical)
        self._perceived = (PerceptionTopics(self, on_needle=self._feed_needle,
                                            on_markers=self._feed_markers)
                           if cfg.physical else None)
        self._images = (StereoImages(self, cfg.camera) if cfg.physical and cfg.correction
                        else None)
        self._status = self.create_publisher(String, '~/status', qos.LATCHED)
        self._result = self.create_publisher(String, '~/result', qos.LATCHED)
        self.machine = ExecutorMachine(
            self.skill, load_scene_config(), psm_kinematics(), self.sim, self._send,
            self.watchdog,
            MachineConfig(settle_time=cfg.settle_time, timeout=cfg.timeout,
                          prepare_timeout=cfg.prepare_timeout, home=cfg.home,
                          phase_stopping=cfg.phase_stopping, physical=cfg.physical,
                          pair_index=cfg.pair_index, result_file=cfg.result_file,
                          correction=cfg.correction,
                          tissue=load_tissue_realism(cfg.tissue).active),
            logger=self.get_logger(), on_status=self._publish_status,
            on_result=self._publish_result,
            on_feed=None if self._perceived is None else self._perceived.replay,
            exit_when_done=cfg.exit_when_done or bool(cfg.pair),
            images=None if self._images is None else self._images.newest)
        self.create_subscription(ClockMsg, '/clock', self._on_clock, qos.CLOCK_LATEST)
        self.create_subscription(String, '~/execute', self._on_execute, qos.STREAM)
        self.create_subscription(Empty, '~/stop', self._on_stop, qos.STREAM)
        self.create_subscription(String, 'sim/process', self._on_process, qos.LATCHED)
        # A steady (wall) clock: the watchdog must run when the simulation clock has stopped.
        self.create_timer(1.0 / cfg.rate, self._on_timer,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.machine.publish_status(f'skill learnt ({self.skill.method.name}) on '
                                    f'{self.skill.pair.name}; waiting for a pair on '
                                    '~/execute')
        if cfg.pair:
            self.machine.execute(cfg.pair)

    @property
    def finished(self):
        """Whether the node's throw ended and it should exit (``pair`` or ``exit_when_done``)."""
        return self.machine.finished

    @property
    def exit_code(self):
        """Exit code once :attr:`finished` (0: a throw scored 1.0)."""
        return self.machine.exit_code

    # --- inputs -----------------------------------------------------------------------------

    def _on_measured_cp(self, arm, stamp):
        self.watchdog.measured(arm, stamp, time.monotonic())

    def _on_clock(self, msg):
        self.watchdog.clock(cv.seconds_from_stamp(msg.clock), time.monotonic())

    def _feed_needle(self, stamp, T_camera_needle, status):
        if self.machine.feed is not None:
            self.machine.feed.needle_seen(stamp, T_camera_needle, status)

    def _feed_markers(self, stamp, entries, exits, normal):
        if self.machine.feed is not None:
            self.machine.feed.markers_seen(stamp, entries, exits, normal)

    def _on_process(self, msg):
        try:
            self.machine.simulator = ProcessWatch(msg.data)
        except ValueError as exc:
            self.get_logger().warning(f'sim/process: {exc}')

    def _on_event(self, stamp, data):
        self.machine.event(stamp, data)

    def _on_execute(self, msg):
        self.machine.execute(msg.data)

    def _on_stop(self, _msg):
        self.machine.stop()

    def _on_timer(self):
        self.machine.tick()

    def on_interrupt(self, signal_name):
        """Stop commanding (the arms hold their setpoints) and report a throw in progress."""
        self.machine.interrupt(signal_name)

    # --- outputs ----------------------------------------------------------------------------

    def _send(self, command, t):
        return self.sim.send(command, cv.stamp_from_seconds(t))

    def _publish_status(self, record):
        self._status.publish(String(data=json.dumps(record, sort_keys=True)))

    def _publish_result(self, record):
        line = json.dumps(record, sort_keys=True)
        self._result.publish(String(data=line))
        print(line, flush=True)  # the result line on stdout; progress goes to the log (stderr)


def main(args=None):
    return executables.executor(args)


if __name__ == '__main__':
    sys.exit(main())
