"""
The executor's sequence as plain logic: prepare, run, settle, report, for a node to drive.

A throw requested on a pair goes through the stages ``preparing`` (the arms enabled and homed,
the pair selected, and in physical mode the markers and the needle seen after homing),
``registering`` (physical mode with ``correction``, once per machine: each PSM registered
against the endoscope, :class:`suture_lfd.skill.registration_run.RegistrationRun`, on the camera's
images; afterwards the machine looks at markers and needle afresh), ``running`` (the
:class:`suture_lfd.skill.executor.ThrowExecutor` stepped on every new measurement, wrapped in a
:class:`suture_lfd.skill.arm_registration.CorrectedController` once registered: it sees the
tools where the correction puts them and its targets are turned into what to command) and
``settling`` (``settle_time`` s of simulation after the plan is done), and ends
``done``, ``stopped``, ``failed`` or ``interrupted``. :class:`ExecutorMachine` holds that
sequence; its caller hands it the arrivals (:meth:`ExecutorMachine.event`,
:meth:`ExecutorMachine.execute`, :meth:`ExecutorMachine.stop`) and ticks it
(:meth:`ExecutorMachine.tick`) with a monotonic wall clock, so it runs the same in a node and in
a test without ROS.

The machine talks to the arms through an :class:`ArmsPort` (the ROS client of the simulator's
topics, :class:`sim_bridge.ros.client.SimClient`, is one; an in-process simulation can be
another) and reports through callables: ``on_status(record)`` at every change of stage,
``on_result(record)`` once a throw ends (the record is the ``~/result`` JSON object), and
``on_feed(feed)`` when a physical-mode throw gets its :class:`PerceptionFeed` (so the caller can
hand it the newest perception outputs); ``images()`` gives the newest stereo pair for the
registration. With ``result_file`` each outcome is also written there
as one JSON object, replaced atomically.

Units: seconds (stamps and ``t``: simulation time; ``now``: monotonic wall time), metres;
frames: ``world`` as the arms report it.

Size: one sequence whose stages share the throw's state (pair, stamps, controller, feed,
correction, outcome); split, each part would reach into the others' state.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import json
import logging
import os
from pathlib import Path
import time
from typing import Any, Protocol

import numpy as np
from sim_bridge.common.geometry import pose_from_transform
from sim_bridge.common.vocabulary import PSMS, TASKS
from sim_bridge.control import Command, Observation
from sim_bridge.scene.world import InstrumentShape
from suture_lfd.skill.arm_registration import CorrectedController, KinematicCorrection
from suture_lfd.skill.executor import ExecutorConfig, ThrowExecutor
from suture_lfd.skill.perceived_feed import PerceptionFeed, pair_index_from_name
from suture_lfd.skill.registration_run import RegistrationRun, StereoLook
from suture_lfd.skill.throw_skill import ThrowSkill
from suture_lfd.skill.watchdog import ArmWatchdog, WatchedProcess

#: the stages in which a throw is in progress
ACTIVE = ('preparing', 'registering', 'running', 'settling')
#: scene events logged while a throw runs
LOGGED_EVENTS = ('grasp', 'release', 'entry', 'exit', 'withdrawn', 'extracted', 'trauma', 'drop')


class ArmsPort(Protocol):
    """The arms (and the simulator's pair selection) as the machine commands them."""

    def ready(self, pairs: Sequence[str] = ()) -> bool:
        """Return whether the arms' state (and the pairs' markers, with truth) has come."""

    def has_pair(self, name: str) -> bool:
        """Return whether the markers of a watched pair have come."""

    def homed(self) -> bool:
        """Return whether every arm is enabled, homed and not busy."""

    def enable_and_home(self) -> bool:
        """Bring the arms towards enabled and homed; return whether they are."""

    def watch_pairs(self, names: Sequence[str]) -> None:
        """Follow the markers of these pairs (ground-truth mode)."""

    def select_pair(self, name: str) -> None:
        """Ask the simulator to make ``name`` the target pair."""

    def target_matched(self) -> bool:
        """Return whether something takes the pair selection."""

    def fault(self) -> str | None:
        """Return ``'<ARM> is <STATE>'`` for an arm not enabled, else None."""

    def observation(self, pair: str | None) -> Observation:
        """Return the arms' reports (with the truth of ``pair`` when given)."""

    def camera_pose(self) -> np.ndarray | None:
        """Return the camera's pose ``T_world_camera`` (4, 4) as the robot reports it."""

    def measured_stamps(self) -> Mapping[str, float]:
        """Return per arm the stamp (s) of its newest ``measured_cp``."""


@dataclass(frozen=True)
class MachineConfig:
    """
    Settings of the sequence (the executor node's parameters of the same names).

    Attributes
    ----------
    settle_time, timeout, prepare_timeout : float
        s of simulation after the plan is done; s of simulation a throw may run; s of wall time
        the preparation may take.
    home : bool
        Enable and home the arms when they are not.
    phase_stopping : bool
        The DMPs' phase stopping (:class:`ExecutorConfig`).
    physical : bool
        Run on the arms' reports and perception (no truth).
    pair_index : int
        1-based position of the pair along the wound (0: from the pair's name).
    result_file : str
        Where each outcome is written ('' for nowhere).
    correction : bool
        Physical mode: register the arms against the endoscope before the first throw and run
        on the corrected kinematics (False: open loop on the arms' own kinematics).
    tissue : bool
        The simulator runs the needle-in-tissue realism (the needle can turn in the jaw): the
        executor watches the grasp during the DMP subtasks as in-process
        (:meth:`ExecutorConfig.on_tissue`; in physical mode it looks at the held needle again
        through the perception's newest look, :meth:`PerceptionFeed.look_at_grasp`). In ground
        truth the grasp is watched every step whatever this says.

    """

    settle_time: float = 0.5
    timeout: float = 120.0
    prepare_timeout: float = 60.0
    home: bool = True
    phase_stopping: bool = False
    physical: bool = False
    pair_index: int = 0
    result_file: str = ''
    correction: bool = True
    tissue: bool = False


def throw_time(seconds: float) -> str:
    """Format simulation seconds since the throw started, labelled, for the log."""
    return f'sim t = {seconds:.3f} s'


class ExecutorMachine:
    """
    One throw at a time on a pair: the executor node's sequence without ROS.

    Parameters
    ----------
    skill : ThrowSkill
        The learnt skill.
    scene : sim_bridge.scene.scene_config.SceneConfig
        The scene's configuration (needle geometry, expert script).
    kinematics : sim_bridge.kinematics.PsmKinematics
        A PSM's kinematics (for the plan's reachability).
    arms : ArmsPort
        The arms.
    send : callable
        ``send(command, t) -> int``: sends a :class:`sim_bridge.control.Command` stamped ``t``
        (s), returns the number of tool poses sent.
    watchdog : ArmWatchdog
        Judges the arms' silence.
    config : MachineConfig
    logger : logging.Logger-like, optional
        Takes ``debug/info/warning/error(text)`` (a node's logger, or this module's).
    on_status, on_result, on_feed : callable, optional
        See the module's docstring.
    clock : callable, optional
        Monotonic wall clock (s) for the stage times (default :func:`time.monotonic`).
    images : callable, optional
        ``images() -> (stamp, stereo, left_rgb, right_rgb) or None``: the newest stereo pair
        and its camera model (physical mode with ``correction``).
    instrument : sim_bridge.scene.world.InstrumentShape, optional
        The instrument's shape, as its maker gives it (its closed jaws are what the
        registration sees).

    Attributes
    ----------
    stage : str
        ``idle``, a stage of :data:`ACTIVE`, or how the last throw ended.
    pair : str
        The pair of the current (or last) throw.
    feed : PerceptionFeed or None
        The physical-mode throw's perception (None in ground-truth mode).
    simulator : WatchedProcess or None
        The simulator's process, when known (set by the caller).
    correction : KinematicCorrection or None
        The arms' correction once registered (kept for every later throw).
    finished, exit_code
        Set when a throw ends with ``exit_when_done``: whether to stop and the exit code
        (0: a throw scored 1.0, or complete in physical mode).

    """

    def __init__(self, skill: ThrowSkill, scene: Any, kinematics: Any, arms: ArmsPort,
                 send: Callable[[Command, float], int], watchdog: ArmWatchdog,
                 config: MachineConfig, *, logger: Any = None,
                 on_status: Callable[[dict], None] | None = None,
                 on_result: Callable[[dict], None] | None = None,
                 on_feed: Callable[[PerceptionFeed], None] | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 exit_when_done: bool = False,
                 images: Callable[[], tuple | None] | None = None,
                 instrument: InstrumentShape | None = None) -> None:
        self.skill, self.scene, self.kinematics = skill, scene, kinematics
        self.arms, self._send_cb, self.watchdog = arms, send, watchdog
        self.config = config
        self.log = logger if logger is not None else logging.getLogger(__name__)
        self._on_status = on_status
        self._on_result = on_result
        self._on_feed = on_feed
        self._clock = clock
        self.exit_when_done = bool(exit_when_done)
        self._images = images
        shape = InstrumentShape() if instrument is None else instrument
        self._jaw = (shape.jaw_length, shape.jaw_width, shape.jaw_thickness)
        self.correction: KinematicCorrection | None = None
        self._registration: RegistrationRun | None = None
        self._registration_t0 = 0.0  # arms' time (s) the registration started
        self._controller: Any = None
        self.finished = False
        self.exit_code = 0
        self.simulator: WatchedProcess | None = None
        self.stage = 'idle'
        self.pair = ''
        self.feed: PerceptionFeed | None = None
        self._stage_wall = clock()
        self._pair_stamp: float | None = None  # simulator clock (s) when the pair was selected
        self._pair_confirmed = False
        self._executed: dict[str, list] = {}  # 'ii' / 'iv' -> [(t, needle pose 7-vector)]
        self._score: Any = None
        self._executor: ThrowExecutor | None = None
        self._t_start: float | None = None
        self._t_done: float | None = None
        self._last_obs_t: float | None = None
        self._last_target = -float('inf')
        self._seen_after: float | None = None
        self._subtask: str | None = None
        self._sent = 0

    # --- arrivals ---------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        """Whether a throw is in progress."""
        return self.stage in ACTIVE

    def event(self, stamp: float, data: Mapping[str, Any]) -> None:
        """
        Take one scene event (``sim/events``, ground-truth mode).

        Parameters
        ----------
        stamp : float
            The event's simulation time (s).
        data : mapping
            The decoded event (``kind``, ``arm``, ``pair``, ``score``, ``error``...).

        """
        kind, arm = data.get('kind'), data.get('arm')
        if kind in LOGGED_EVENTS and self.stage in ('running', 'settling'):
            at = '' if self._t_start is None else f' at {throw_time(stamp - self._t_start)}'
            self.log.info(f'scene event {kind}{" " + arm if arm else ""}{at}')
        if kind == 'target_pair' and data.get('pair') == self.pair and self.active:
            if data.get('error'):
                if self.stage == 'preparing':
                    self._halt('failed', f'the simulator refused pair {self.pair!r}: '
                                         f'{data["error"]}')
            else:
                self._pair_stamp = stamp  # the score's time counts from here
                self._pair_confirmed = True
        elif kind == 'score' and self.stage in ('running', 'settling'):
            self._score = data.get('score')
            self.log.debug(f'sim/events: {json.dumps(dict(data))}')

    def execute(self, pair: str) -> bool:
        """
        Start a throw on ``pair``; return whether it started (else the reason is warned).

        A throw in progress, an empty name or (physical mode) a name without its position along
        the wound is refused with a warning on the status; the machine keeps its state.
        """
        pair = pair.strip()
        if self.active:
            self._warn(f'execute {pair!r} ignored: a throw on {self.pair} is in progress '
                       f'({self.stage})')
            return False
        if not pair:
            self._warn('execute ignored: empty pair name')
            return False
        feed = None
        if self.config.physical:
            try:
                index = self.config.pair_index or pair_index_from_name(pair)
            except ValueError as exc:
                self._warn(f'execute {pair!r} ignored: {exc} (parameter pair_index)')
                return False
            feed = PerceptionFeed(pair, index, self.scene.needle)
        self.pair = pair
        self._pair_confirmed = False
        self._score = None
        self._pair_stamp = None
        self._executor = None
        self._t_start = self._t_done = None
        self._seen_after = None
        self.feed = feed
        if feed is not None:
            if self._on_feed is not None:
                self._on_feed(feed)
        else:
            self.arms.watch_pairs([pair])
        self.arms.select_pair(pair)
        self._last_target = self._clock()
        self.log.info(f'executing the {self.skill.method.name} skill learnt on '
                      f'{self.skill.pair.name} on pair {pair}')
        self._enter('preparing', f'throw on {pair} requested')
        return True

    def stop(self, reason: str = 'stop requested') -> None:
        """Stop a throw in progress (the arms hold their setpoints)."""
        if self.active:
            self._halt('stopped', reason)

    def interrupt(self, signal_name: str) -> None:
        """Stop a throw in progress on a signal and report it."""
        if self.active:
            self._halt('interrupted', f'stopped by {signal_name}')

    def publish_status(self, reason: str = '', **extra: Any) -> None:
        """Report the current stage (``on_status``) with a reason."""
        if self._on_status is not None:
            self._on_status({'state': self.stage, 'pair': self.pair, 'reason': reason, **extra})

    # --- the sequence -----------------------------------------------------------------------

    def tick(self, now: float | None = None) -> None:
        """
        Advance the throw by one period: prepare, or check the arms and step the controller.

        Parameters
        ----------
        now : float, optional
            Monotonic wall time (s); default the machine's clock.

        """
        if not self.active:
            return
        now = self._clock() if now is None else now
        if self.stage == 'preparing':
            self._prepare(now)
            return
        stamps = self.arms.measured_stamps()
        verdict = self.watchdog.check(now, min(stamps[a] for a in PSMS),
                                      settling=self.stage == 'settling',
                                      process=self.simulator)
        if verdict is not None and verdict.halt:
            self._halt('stopped', verdict.reason, **verdict.details)
            return
        if verdict is not None:
            self.log.warning(verdict.reason)
        fault = self.arms.fault()
        if fault is not None:
            self._halt('stopped', f'arm fault: {fault}')
            return
        if max(stamps[a] for a in PSMS) == self._last_obs_t \
                and self.stage in ('running', 'registering'):
            return  # nothing new measured since the last command
        if self.stage == 'registering':
            self._register()
            return
        obs = self.observe()
        self._last_obs_t = obs.t
        if self.stage == 'running':
            self._run(obs)
            return
        if obs.t - (self._t_done or obs.t) >= self.config.settle_time:
            self._halt('done', 'throw complete')

    def _run(self, obs: Observation) -> None:
        """Step the controller on ``obs``, send its command, notice the end."""
        assert self._executor is not None and self._t_start is not None  # running
        command = self._controller.step(obs)
        self._sent += self._send_cb(command, obs.t)
        if command.subtask in TASKS and obs.T_world_needle is not None:
            self._executed.setdefault(command.subtask, []).append(
                (obs.t, pose_from_transform(obs.T_world_needle)))
        if command.subtask != self._subtask:
            self._subtask = command.subtask
            self.log.info(f'subtask {command.subtask} at {throw_time(obs.t - self._t_start)}')
        if self._executor.done:
            self._t_done = obs.t
            self._enter('settling')
        elif obs.t - self._t_start > self.config.timeout:
            self._t_done = obs.t
            self._halt('failed', f'throw not done after {self.config.timeout} s '
                                 f'(subtask {command.subtask})')

    def _prepare(self, now: float) -> None:
        """Home the arms, confirm the pair, then begin (ground truth) or look (physical)."""
        cfg = self.config
        arms = self.arms
        if not arms.ready([self.pair]):
            if self._waited(now) > cfg.prepare_timeout:
                missing = 'markers of the pair' if not arms.has_pair(self.pair) else \
                    'simulator topics'
                self._halt('failed', f'unknown marker pair {self.pair!r} or simulator not '
                                     f'running ({missing} not received in '
                                     f'{cfg.prepare_timeout} s)')
            return
        if arms.homed():
            if cfg.physical:
                self._prepare_physical(now)
                return
            if not self._pair_confirmed:
                if self._waited(now) > cfg.prepare_timeout:
                    self._halt('failed', f'the simulator did not confirm pair {self.pair!r}')
                elif now - self._last_target > 1.0:
                    # (again) every second: the first may have gone out before the
                    # simulator's subscription was matched
                    self._last_target = now
                    arms.select_pair(self.pair)
                return
            self._begin(arms.observation(self.pair))
            return
        if not cfg.home or self._waited(now) > cfg.prepare_timeout:
            self._halt('failed', 'arms not enabled and homed')
            return
        arms.enable_and_home()

    def observe(self) -> Observation:
        """Return the observation: the simulator's truth, or the arms plus perception."""
        if self.feed is None:
            return self.arms.observation(self.pair)
        camera = self.arms.camera_pose()
        if camera is not None:
            self.feed.camera_moved(camera)
        arms = self.arms.observation(None)
        if self.correction is not None:
            arms = self.correction.observe(arms)
        return self.feed.observe(arms)

    def _begin(self, obs: Observation) -> None:
        """Plan the throw on what ``obs`` shows and start commanding."""
        try:
            config = ExecutorConfig(script=self.scene.expert,
                                    phase_stopping=self.config.phase_stopping)
            if self.config.physical:
                config = config.in_physical_mode()
            look = frame_time = None
            if self.config.tissue:
                config = config.on_tissue()
                feed = self.feed
                if feed is not None:
                    def look(arm: str, o: Observation) -> np.ndarray | None:
                        return feed.look_at_grasp(None, arm, o.T_world_tool)
                    # a look at the grasp waits for the perception's look of its instant
                    frame_time = feed.needle_stamp
            self._executor = ThrowExecutor(self.skill, obs.pair, self.scene.needle,
                                           kinematics=self.kinematics, config=config,
                                           look=look, frame_time=frame_time)
            self._controller = self._executor
            if self.correction is not None and self.correction.arms:
                self._controller = CorrectedController(self._executor, self.correction)
            self._controller.reset(obs)
        except ValueError as exc:
            self._halt('failed', f'cannot plan the throw on {self.pair}: {exc}',
                       planning_error=str(exc))
            return
        self._t_start = self._last_obs_t = obs.t
        self._subtask = None
        self._sent = 0
        self._executed = {}
        self._enter('running', f'throw on {self.pair} started')

    def _prepare_physical(self, now: float) -> None:
        """
        Homed, in physical mode: select the pair, wait to see markers and needle, then start.

        The simulator's confirmation of the pair is a truth event (not read here): the pair is
        sent again every second until a subscriber has been matched for a second. The markers
        and the needle must have been seen in an image taken after the arms were homed (an arm
        moving in may have hidden them before).
        """
        assert self.feed is not None  # physical mode
        cfg = self.config
        if not self._pair_confirmed:
            if self.arms.target_matched() and now - self._last_target > 1.0:
                self._pair_confirmed = True
            elif now - self._last_target > 1.0:
                self._last_target = now
                self.arms.select_pair(self.pair)
            if not self._pair_confirmed:
                if self._waited(now) > cfg.prepare_timeout:
                    self._halt('failed', f'no subscriber to sim/target_pair in '
                                         f'{cfg.prepare_timeout} s')
                return
        if self._seen_after is None:
            self._seen_after = self.arms.observation(None).t
            self._last_target = now
            self.arms.select_pair(self.pair)  # once more, now that the arms are in place
        missing = self.feed.seen_since(self._seen_after)
        obs = None if missing else self.observe()
        if obs is not None and obs.pair is None:
            missing = [f'the markers of pair {self.pair} (index {self.feed.pair_index} along '
                       'the wound)']
        elif obs is not None and obs.T_world_needle is None:
            missing = ['the needle']
        if missing:
            if self._waited(now) > cfg.prepare_timeout:
                self._halt('failed', f'not seen: {", ".join(missing)} (within '
                                     f'{cfg.prepare_timeout} s: is the perception node running '
                                     'on the endoscope?)')
            return
        assert obs is not None
        if cfg.correction and self.correction is None:
            self._start_registration(now, obs)
            return
        self._begin(obs)

    def _start_registration(self, now: float, obs: Observation) -> None:
        """Register the arms around the markers seen, once a stereo pair has come."""
        assert self.feed is not None
        look = None if self._images is None else self._images()
        centre = self.feed.markers_centre()
        if look is None or centre is None:
            if self._waited(now) > self.config.prepare_timeout:
                self._halt('failed', 'cannot register the arms: '
                                     + ('no stereo pair on the camera image topics'
                                        if look is None else 'no marker seen')
                                     + f' within {self.config.prepare_timeout} s')
            return
        kinematics = dict.fromkeys(PSMS, self.kinematics)
        self._registration = RegistrationRun(kinematics, look[1], self._jaw, centre)
        self._registration_t0 = obs.t
        self._enter('registering', 'registering the arms against the endoscope')

    def _register(self) -> None:
        """Step the registration; once done, keep the correction and look again."""
        run = self._registration
        assert run is not None
        arms = self.arms.observation(None)
        self._last_obs_t = arms.t
        look = self._stereo_look()
        self._send_cb(run.step(arms, look), arms.t)
        if run.done:
            self.correction = run.correction
            assert self.correction is not None
            fits = ', '.join(f'{a} {1e3 * np.linalg.norm(f.translation):.1f} mm base, '
                             f'{f.residual_px:.2f} px' for a, f in self.correction.arms.items())
            self.log.info(f'registration done in {arms.t - self._registration_t0:.1f} s: '
                          f'{fits or "no arm trusted: open loop"}')
            self._registration = None
            # look at markers and needle afresh, with the arms back in place
            self.feed = PerceptionFeed(self.pair, self.feed.pair_index if self.feed else 1,
                                       self.scene.needle)
            if self._on_feed is not None:
                self._on_feed(self.feed)
            self._seen_after = None
            self._enter('preparing', 'registered; looking at the markers and the needle again')
        elif arms.t - self._registration_t0 > self.config.timeout:
            self._halt('failed', f'registration not done after {self.config.timeout} s '
                                 f'(arm {run.arm}: the instrument not seen?)')

    def _stereo_look(self) -> StereoLook | None:
        """Return the newest stereo pair with the camera's reported pose, or None."""
        pair = None if self._images is None else self._images()
        camera = self.arms.camera_pose()
        if pair is None or camera is None:
            return None
        stamp, _, left, right = pair
        return StereoLook(stamp, left, right, camera)

    # --- reporting --------------------------------------------------------------------------

    def _waited(self, now: float) -> float:
        return now - self._stage_wall

    def _warn(self, text: str) -> None:
        self.log.warning(text)
        self.publish_status(text)

    def _enter(self, stage: str, reason: str = '') -> None:
        self.stage = stage
        self._stage_wall = self._clock()
        self.publish_status(reason)

    def result_record(self, state: str, reason: str) -> dict:
        """
        Return the outcome of the current throw as the ``~/result`` record.

        ``time_s`` is the score's throw time counted from the start of the throw (the scorer
        counts from the pair's selection, before the arms were homed); the score's fields are
        None when no score came (physical mode: the score is the evaluation's).
        """
        score = self._score if isinstance(self._score, dict) else None
        duration = (None if self._t_start is None
                    else (self._t_done or self._last_obs_t or self._t_start) - self._t_start)
        time_s = duration
        if score is not None and score.get('score') == 1.0 and score.get('time_s') is not None \
                and self._pair_stamp is not None and self._t_start is not None:
            time_s = score['time_s'] - (self._t_start - self._pair_stamp)
        return {'pair': self.pair, 'state': state, 'outcome': state, 'reason': reason,
                'method': self.skill.method.name, 'learnt_on': self.skill.pair.name,
                'score': None if score is None else score.get('score'),
                'subtasks': None if score is None else score.get('subtasks'),
                'failure': None if score is None else score.get('failure'),
                'entry_error_mm': None if score is None else score.get('entry_error_mm'),
                'exit_error_mm': None if score is None else score.get('exit_error_mm'),
                'duration': duration, 'time_s': time_s, 'servo_cp_sent': self._sent}

    def _write_result(self, record: dict) -> None:
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
            self.log.error(f'cannot write result_file {path}: {exc}')

    def _halt(self, state: str, reason: str, **extra: Any) -> None:
        """Stop commanding, say why, report the result."""
        self._executor = None
        log = self.log.info if state == 'done' else self.log.error
        record = {**self.result_record(state, reason), **extra}
        log(f'throw on {self.pair} {state}: {reason} (score {record["score"]})')
        if self._on_result is not None:
            self._on_result(record)
        if self.config.result_file:
            self._write_result(record)
        self.stage = state
        self._stage_wall = self._clock()
        self.publish_status(reason, **extra)
        if self.exit_when_done:
            # in physical mode the score is the evaluation's: a complete throw is a success here
            scored = record['score'] == 1.0 or (self.config.physical and record['score'] is None)
            self.exit_code = 0 if state == 'done' and scored else 1
            self.finished = True
