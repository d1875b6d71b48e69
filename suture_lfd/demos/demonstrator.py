"""
A synthetic study subject performing one suturing throw, and in-process demonstrations.

:class:`Demonstrator` is a controller (``reset(obs)``, ``step(obs) -> Command``, ``done``) like
:class:`suture_lfd.planning.expert.ScriptedExpert`, on which it is built: the expert plans the
throw (minimum-jerk motions through the five subtasks, reachable grasps, grasp and release gates)
with the subject's speed, entry precision and needle-plane alignment
(:class:`suture_lfd.demos.cohort.SkillProfile`), and the demonstrator runs the plan on the
subject's own clock and adds the subject's imperfections to the commanded tool poses:

- **tremor**: a sinusoid at ``tremor_frequency`` in position and orientation with random
  phases, in free motions (attenuated to nothing while the needle touches the tissue, where the
  tissue steadies it);
- **path smoothness**: a slow, smooth deviation (a few random sines up to ``wander_frequency``)
  that vanishes at the start and end of every free motion;
- **corrections**: an approach motion overshoots its goal by ``correction_distance`` and is
  corrected back in ``correction_time``;
- **hesitations**: pauses where both arms rest between motions, plus ``entry_pause`` with the
  needle tip on the entry marker before the insertion and ``release_pause`` after a jaw lets
  the needle go;
- **wrist rotation vs translation**: during the insertion part of the needle's turn about its
  arc centre is replaced by a push along the wound (``1 - wrist_rotation``), which strains the
  tissue (the simulator reports it as trauma).

Like a teleoperating person, the subject watches the arms: its clock waits while a grasp or
release is not yet confirmed (up to the expert's ``gate_timeout``) and while an arm lags behind
its command by more than ``lag_tolerance`` (the dVRK joints have velocity limits).

:func:`demonstrate` runs one demonstration in-process on a :class:`sim_bridge.simulation.
Simulation` and samples it at ``sample_rate`` into a :class:`suture_lfd.demos.demonstration.
Demonstration`; a throw that does not score 1.0 is done again with the next attempt seed (the
paper's subjects produced usable demonstrations).

Frames: ``world``; poses 4x4 ``T_world_*``; m, rad, s.

Size: the subject's controller and the in-process demonstration it drives share the subject's clock
and imperfections; it is on the per-step path being made faster, so it stays one file.
"""

from dataclasses import dataclass, replace
import logging
import math
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np
from sim_bridge.common.geometry import pose_from_transform
from sim_bridge.common.validation import check_positive
from sim_bridge.control import Command, ExpertConfig, Observation
from suture_lfd.demos.cohort import SkillProfile, Subject
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.errors import DemonstrationError
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ARMS, ScriptedExpert
from suture_lfd.planning.plan import Plan, track_grasps
from suture_lfd.planning.waypoints import ArcPath, minimum_jerk, rotation_exp

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.control import CommandSource
    from sim_bridge.kinematics import PsmKinematics
    from sim_bridge.scene.phantom import MarkerPair
    from sim_bridge.scene.scoring import ThrowScore
    from sim_bridge.simulation import SimEvent, Simulation

_LOG = logging.getLogger(__name__)

DEFAULT_LAG_TOLERANCE = 0.0005
DEFAULT_LAG_TOLERANCE_RAD = 0.05
_WANDER_SINES = 3
# A needle pose the recorder did not see (position and quaternion NaN).
_NOT_SEEN = np.full(7, np.nan)
_HOVER_TIME = 0.15   # s the tip hovers above the entry before it is pressed in
_LOWER_TIME = 0.55   # s to press it in (slow: peak speed ~2 mm/s, below a motion's threshold)


@dataclass(frozen=True)
class Pause:
    """
    A stop of the subject's clock at a plan time.

    Attributes
    ----------
    t : float
        Plan time (s) where the clock stops.
    duration : float
        Length (s).
    kind : str
        ``'hesitation'``, ``'entry'`` or ``'correction'``.
    arm : str
        Arm being corrected (``'correction'`` only).
    offset : ndarray, shape (3,) or None
        Overshoot (m, world) at the start of a correction, brought back to zero.

    """

    t: float
    duration: float
    kind: str
    arm: str = ''
    offset: np.ndarray | None = None


def _moving(seg: Any) -> bool:
    path = seg.path
    return bool(path.distance > 1e-9 or path.angle > 1e-9)


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0.0 else v


class Demonstrator:
    """
    A synthetic subject performing one throw on a marker pair (controller).

    Parameters
    ----------
    subject : suture_lfd.demos.cohort.Subject or suture_lfd.demos.cohort.SkillProfile
        Who demonstrates (its profile is used).
    pair : sim_bridge.scene.phantom.MarkerPair
        Target pair (world frame).
    needle_geometry : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    kinematics : sim_bridge.kinematics.PsmKinematics or dict, optional
        PSM kinematics for the planner (default: the expert's).
    rng : numpy.random.Generator, optional
        The subject's randomness in this demonstration; default ``default_rng(subject.seed)``.
    next_pair : sim_bridge.scene.phantom.MarkerPair, optional
        Pair of the next throw (PSM2 ends above its entry).
    expert_config : sim_bridge.control.ExpertConfig, optional
        Base motion parameters (default ``ExpertConfig()``); the profile's speed, aim and tilt
        replace its ``speed_scale``, ``aim_std`` and ``tilt_std_deg``.
    lag_tolerance : float
        Tool lag (m) behind the last command above which the subject waits.
    lag_tolerance_rad : float
        Same for the tool orientation (rad).
    max_step : float
        Longest advance (s) of the subject's clock between two observations: when the
        observed time jumps (a simulator that skips ahead), the subject does not.
    entry_clearance : float
        Height (m, along the pair normal) above the entry marker at which the needle tip
        arrives at the end of subtask i; in the entry pause the subject lets the arm settle,
        then slowly presses the tip into the tissue.
    entry_press : float
        Depth (m) of that press, taken back along the insertion (a tip arriving exactly on the
        surface, or an arm that overshoots it, would prick the tissue and pull out again).

    """

    def __init__(self, subject: Subject | SkillProfile, pair: 'MarkerPair',
                 needle_geometry: 'NeedleGeometry',
                 kinematics: 'PsmKinematics | dict[str, PsmKinematics] | None' = None,
                 rng: np.random.Generator | None = None, next_pair: 'MarkerPair | None' = None,
                 expert_config: ExpertConfig | None = None,
                 lag_tolerance: float = DEFAULT_LAG_TOLERANCE,
                 lag_tolerance_rad: float = DEFAULT_LAG_TOLERANCE_RAD, max_step: float = 0.05,
                 entry_clearance: float = 0.0005, entry_press: float = 0.0001) -> None:
        if isinstance(subject, Subject):
            profile, seed = subject.profile, subject.seed
        elif isinstance(subject, SkillProfile):
            profile, seed = subject, 0
        else:
            raise ValueError(f'subject must be a Subject or a SkillProfile, got '
                             f'{type(subject).__name__}')
        for value, name in ((lag_tolerance, 'lag_tolerance (m)'),
                            (lag_tolerance_rad, 'lag_tolerance_rad'), (max_step, 'max_step (s)')):
            check_positive(value, name)
        self.max_step = float(max_step)
        if entry_clearance < 0.0:
            raise ValueError(f'entry_clearance must be >= 0 m, got {entry_clearance}')
        self.entry_clearance = float(entry_clearance)
        if entry_press < 0.0:
            raise ValueError(f'entry_press must be >= 0 m, got {entry_press}')
        self.entry_press = float(entry_press)
        self.profile = profile
        self.pair = pair
        self.rng = rng if rng is not None else np.random.default_rng(seed)
        base = ExpertConfig() if expert_config is None else expert_config
        self.expert_config = replace(base, speed_scale=base.speed_scale * profile.speed_scale,
                                     aim_std=profile.aim_std, tilt_std_deg=profile.tilt_std_deg)
        self.expert = ScriptedExpert(pair, needle_geometry, self.expert_config, rng=self.rng,
                                     kinematics=kinematics, next_pair=next_pair)
        self.lag_tolerance = float(lag_tolerance)
        self.lag_tolerance_rad = float(lag_tolerance_rad)
        self.plan_: Plan | None = None
        self.pauses: tuple[Pause, ...] = ()
        self._overshoot: dict[tuple[str, int], np.ndarray] = {}
        self._active: Pause | None = None
        self._insertion: Any = None
        self._approach: Any = None

    # ------------------------------------------------------------------ planning
    def _rest_times(self, plan: Plan) -> list[float]:
        """Plan times where every arm is at a segment boundary or standing still."""
        times = sorted({round(seg.t1, 9) for segs in plan.segments.values() for seg in segs})
        gates = [g.t for g in plan.gates]
        out: list[float] = []
        for t in times:
            if t <= 0.0 or t >= plan.duration - 1e-9:
                continue
            if any(abs(t - g) < 1e-6 for g in gates):
                continue
            ok = True
            for segs in plan.segments.values():
                for seg in segs:
                    if seg.t0 + 1e-9 < t < seg.t1 - 1e-9 and _moving(seg):
                        ok = False
            if ok:
                out.append(t)
        return out

    def _schedule(self, plan: Plan) -> tuple[Pause, ...]:
        p, rng = self.profile, self.rng
        labels = {name: t for t, name in plan.labels}
        t_entry = labels['ii']
        entry = p.entry_pause * (0.75 + 0.5 * rng.random())
        if self.entry_clearance + self.entry_press > 0.0:
            entry += _HOVER_TIME + _LOWER_TIME
        pauses = [Pause(t_entry, entry, 'entry')]
        for gate in plan.gates:   # the subject sees the jaw let go before moving on
            if gate.kind == 'release' and p.release_pause > 0.0:
                pauses.append(Pause(gate.t, p.release_pause * (0.75 + 0.5 * rng.random()),
                                    'release'))
        for t in self._rest_times(plan):
            if abs(t - t_entry) > 1e-6 and p.hesitation_time > 0.0 \
                    and rng.random() < p.hesitation_probability:
                pauses.append(Pause(t, float(rng.exponential(p.hesitation_time)), 'hesitation'))
        # Corrections: free approach motions followed by a further motion of the same arm.
        self._overshoot = {}
        for arm, segs in plan.segments.items():
            for k, seg in enumerate(segs[:-1]):
                nxt = segs[k + 1]
                if seg.carries_needle or nxt.carries_needle or not _moving(seg) \
                        or not _moving(nxt) or abs(seg.jaw1 - nxt.jaw1) > 1e-9:
                    continue
                if p.correction_distance <= 0.0 or rng.random() >= p.correction_probability:
                    continue
                direction = _unit(rng.standard_normal(3))
                offset = p.correction_distance * direction
                self._overshoot[(arm, k)] = offset
                pauses.append(Pause(seg.t1, p.correction_time, 'correction', arm, offset))
        pauses.sort(key=lambda x: (x.t, x.kind != 'entry'))
        merged: list[Pause] = []
        for pause in pauses:   # one stop per plan time; corrections keep their offset
            if merged and abs(merged[-1].t - pause.t) < 1e-9:
                keep = merged[-1] if merged[-1].kind == 'correction' else pause
                merged[-1] = replace(keep, duration=max(merged[-1].duration, pause.duration))
            else:
                merged.append(pause)
        return tuple(merged)

    def _draw_noise(self) -> None:
        p, rng = self.profile, self.rng
        self._tremor_phase = {arm: rng.uniform(0.0, 2.0 * math.pi, 6) for arm in ARMS}
        self._tremor_dir = {arm: np.array([_unit(rng.standard_normal(3)) for _ in range(2)])
                            for arm in ARMS}
        freqs = p.wander_frequency * rng.uniform(0.3, 1.0, (len(ARMS), _WANDER_SINES))
        self._wander = {arm: (freqs[k], rng.uniform(0.0, 2.0 * math.pi, (_WANDER_SINES, 3)),
                              rng.standard_normal((_WANDER_SINES, 3)) / math.sqrt(_WANDER_SINES))
                        for k, arm in enumerate(ARMS)}
        push = rng.uniform(0.7, 1.0)
        self._push_gain = push

    def reset(self, obs: Observation) -> None:
        """
        Plan the throw from an observation and start the subject's clock at ``obs.t``.

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Start state (world frame).

        """
        plan = self.expert.plan(obs)
        self.plan_ = plan
        self._draw_noise()
        self.pauses = self._schedule(plan)
        self._insertion = self._approach = None
        t_ii = {name: t for t, name in plan.labels}['ii']
        for seg in plan.segments['PSM2']:
            if isinstance(seg.path, ArcPath) and abs(seg.t0 - t_ii) < 1e-9:
                self._insertion = seg
            if isinstance(seg.path, ArcPath) and abs(seg.t1 - t_ii) < 1e-9:
                self._approach = seg
        self._t_last = float(obs.t)
        self._tau = 0.0
        self._gate = 0
        self._waited = 0.0
        self._pause = 0
        self._pause_left = 0.0
        self._active = None
        self._pressed = False
        self._grasps: dict[str, np.ndarray] = {}
        self._last_cmd: dict[str, np.ndarray] = {}
        self.waits = {'gate': 0.0, 'lag': 0.0, 'pause': 0.0}

    @property
    def done(self) -> bool:
        """Whether the plan has run to its end."""
        return self.plan_ is not None and self._tau >= self.plan_.duration

    @property
    def plan_time(self) -> float:
        """Current plan time (s)."""
        return self._tau

    @property
    def subtask(self) -> str:
        """Subtask label (``'i'`` .. ``'v'``, ``'done'``) at the current plan time."""
        return 'i' if self.plan_ is None else self.plan_.label(self._tau)

    # ------------------------------------------------------------------ control
    def _plan(self) -> Plan:
        if self.plan_ is None:
            raise RuntimeError('the demonstrator has no plan yet: call reset(obs) first')
        return self.plan_

    def _lagging(self, obs: Observation) -> bool:
        for arm, T_cmd in self._last_cmd.items():
            T = np.asarray(obs.T_world_tool[arm])
            if np.linalg.norm(T[:3, 3] - T_cmd[:3, 3]) > self.lag_tolerance:
                return True
            c = (np.trace(T[:3, :3].T @ T_cmd[:3, :3]) - 1.0) / 2.0
            if math.acos(min(1.0, max(-1.0, c))) > self.lag_tolerance_rad:
                return True
        return False

    def _advance(self, obs: Observation, dt: float) -> None:
        plan = self._plan()
        if self._pause_left > 0.0:
            self._pause_left -= dt
            self.waits['pause'] += dt
            if self._pause_left <= 0.0:
                self._pressed = self._pressed or (self._active is not None
                                                  and self._active.kind == 'entry')
                self._active = None
            return
        if self._lagging(obs):
            self.waits['lag'] += dt
            return
        new = self._tau + dt
        holders = set(obs.holders)
        blocked = False
        while self._gate < len(plan.gates) and plan.gates[self._gate].t <= new:
            gate = plan.gates[self._gate]
            if (gate.arm in holders) == (gate.kind == 'grasp'):
                self._gate += 1
                self._waited = 0.0
                continue
            if self._waited <= self.expert_config.gate_timeout:
                self._waited += dt
                self.waits['gate'] += dt
                new = max(self._tau, gate.t)
                blocked = True
                break
            _LOG.warning('%s %s not confirmed after %.2f s; going on', gate.arm, gate.kind,
                         self._waited)
            self._gate += 1
            self._waited = 0.0
        if not blocked and self._pause < len(self.pauses) \
                and self.pauses[self._pause].t <= new:
            pause = self.pauses[self._pause]
            new = max(self._tau, pause.t)
            self._pause += 1
            self._pause_left = pause.duration
            self._active = pause
        self._tau = min(new, plan.duration)

    def _offset(self, arm: str, seg: Any, t_obs: float) -> tuple[np.ndarray, np.ndarray]:
        """Position offset (m) and rotation vector (rad) the subject adds to an arm's pose."""
        p = self.profile
        tau = self._tau
        u = 0.0 if seg.t1 <= seg.t0 else min(1.0, max(0.0, (tau - seg.t0) / (seg.t1 - seg.t0)))
        offset = np.zeros(3)
        rot = np.zeros(3)
        in_tissue = isinstance(seg.path, ArcPath) or (
            self._active is not None and self._active.kind == 'entry')
        free = not seg.carries_needle or not in_tissue
        if free and not in_tissue:
            w = 2.0 * math.pi * p.tremor_frequency * t_obs
            ph = self._tremor_phase[arm]
            d = self._tremor_dir[arm]
            offset += p.tremor_amplitude * (math.sin(w + ph[0]) * d[0]
                                            + 0.5 * math.sin(1.3 * w + ph[1]) * d[1])
            rot += math.radians(p.tremor_rotation_deg) * np.sin(w + ph[3:6])
        if _moving(seg) and not in_tissue and p.wander > 0.0:
            freqs, phases, amps = self._wander[arm]
            waves = np.sin(2.0 * math.pi * freqs[:, None] * tau + phases) * amps
            offset += p.wander * math.sin(math.pi * u) ** 2 * waves.sum(axis=0)
        if seg is self._approach:   # arrive above the entry, settle, press the tip in slowly
            active = self._active
            if self._pressed:
                height = -self.entry_press
            elif active is not None and active.kind == 'entry':
                elapsed = active.duration - max(0.0, self._pause_left)
                height = self.entry_clearance - (self.entry_clearance + self.entry_press) \
                    * minimum_jerk((elapsed - _HOVER_TIME) / _LOWER_TIME)
            else:
                height = self.entry_clearance * minimum_jerk(u / 0.5)
            offset += height * self.pair.normal
        elif seg is self._insertion:
            offset -= self.entry_press * (1.0 - minimum_jerk(u)) * self.pair.normal
        if seg is self._insertion and p.wrist_rotation < 1.0:
            path = seg.path
            reach = self.expert.needle.radius * path.angle
            chord = _unit(self.pair.exit - self.pair.entry)
            push = (1.0 - p.wrist_rotation) * reach * self._push_gain
            offset += push * math.sin(math.pi * seg.sigma(tau)) * chord
        return offset, rot

    def _correction(self, arm: str, seg_index: int, seg: Any) -> np.ndarray:
        """Overshoot offset (m) of a corrected approach motion of ``arm``, or zero."""
        active = self._active
        if active is not None and active.kind == 'correction' and active.arm == arm \
                and active.offset is not None:
            left = max(0.0, self._pause_left) / max(active.duration, 1e-9)
            return active.offset * minimum_jerk(left)
        offset = self._overshoot.get((arm, seg_index))
        if offset is None or seg.t1 <= seg.t0:
            return np.zeros(3)
        u = (self._tau - seg.t0) / (seg.t1 - seg.t0)
        return offset * minimum_jerk((u - 0.5) / 0.5)

    def step(self, obs: Observation) -> Command:
        """
        Command for the observation.

        Parameters
        ----------
        obs : sim_bridge.control.Observation
            Current state (world frame).

        Returns
        -------
        sim_bridge.control.Command
            Tool-tip pose and jaw targets of both PSMs at ``obs.t``.

        """
        if self.plan_ is None:
            self.reset(obs)
        plan = self._plan()
        dt = min(max(0.0, float(obs.t) - self._t_last), self.max_step)
        self._t_last = float(obs.t)
        self._advance(obs, dt)
        track_grasps(self._grasps, obs)
        cmd = plan.sample(self._tau, self._grasps)
        tools = {}
        for arm in ARMS:
            segs = plan.segments[arm]
            k = next((i for i, s in enumerate(segs) if self._tau <= s.t1), len(segs) - 1)
            seg = segs[k]
            offset, rot = self._offset(arm, seg, float(obs.t))
            if not seg.carries_needle:
                offset = offset + self._correction(arm, k, seg)
            T = np.array(cmd.T_world_tool[arm], dtype=float)
            T[:3, 3] += offset
            if np.any(rot):
                T[:3, :3] = T[:3, :3] @ rotation_exp(rot)
            tools[arm] = T
        self._last_cmd = dict(tools.items())
        return Command(t=float(obs.t), T_world_tool=tools, jaw=cmd.jaw, subtask=cmd.subtask)


@dataclass(frozen=True, eq=False)
class DemonstrationRun:
    """
    One in-process demonstration with what the simulator reported.

    Attributes
    ----------
    demo : suture_lfd.demos.demonstration.Demonstration
        The sampled record.
    labels : ndarray of str, shape (n,)
        The subject's subtask label at each sample (ground truth for the segmentation).
    score : sim_bridge.scene.scoring.ThrowScore
        The simulator's score of the throw.
    events : list of sim_bridge.simulation.SimEvent
        Scene events of the throw.
    attempts : int
        Attempts it took (1: the first throw succeeded).
    seed : int
        Seed of the successful attempt.

    """

    demo: Demonstration
    labels: np.ndarray
    score: 'ThrowScore'
    events: list['SimEvent']
    attempts: int
    seed: int


def _pair_rng(subject: Subject | SkillProfile, pair_name: str, seed: int, attempt: int
              ) -> np.random.Generator:
    base = subject.trial_seed(pair_name, attempt) if isinstance(subject, Subject) else 0
    return np.random.default_rng([base, int(seed), int(attempt)])


def run_demonstration(sim: 'Simulation', subject: Subject | SkillProfile, pair_name: str,
                      seed: int = 0, sample_rate: float = 100.0, timeout: float = 60.0,
                      attempts: int = 3, next_pair: str | None = None,
                      expert_config: ExpertConfig | None = None, require_success: bool = True,
                      command_rate: float | None = None,
                      link: 'RobotLink | None' = None) -> DemonstrationRun:
    """
    Run a subject's throw on a pair in-process and sample it (with score and labels).

    The scene is reset with ``seed`` (+ the attempt number), the arms enabled and homed, the
    pair made the target, and the demonstrator run with one command per sample (or per
    ``command_rate`` period: the arms glide between streamed commands as a dVRK does).

    Parameters
    ----------
    sim : sim_bridge.simulation.Simulation
        The simulation (its phantom must hold ``pair_name``).
    subject : suture_lfd.demos.cohort.Subject or suture_lfd.demos.cohort.SkillProfile
        Who demonstrates.
    pair_name : str
        Target pair (``'synth1'``).
    seed : int
        Scene and subject randomness of the first attempt.
    sample_rate : float
        Samples per second; the physics step must divide its period.
    timeout : float
        Longest simulated time (s) of a throw.
    attempts : int
        Throws tried until one scores 1.0.
    next_pair : str, optional
        Pair of the next throw (PSM2 ends above its entry).
    expert_config : sim_bridge.control.ExpertConfig, optional
        Base motion parameters; default the scene's ``expert`` section.
    require_success : bool
        Raise :class:`DemonstrationError` when no attempt scores 1.0 (otherwise return the
        last attempt).
    command_rate : float, optional
        Commands per second (default ``sample_rate``); the sample period must divide the
        command period.
    link : RobotLink, optional
        Physical mode: the subject still watches the scene, but its commands reach the arms
        through ``link.command`` and the record is what ``link.record()`` observes (what a
        recorder gets from the robot); ``link.start()`` at every attempt's start. Default: the
        subject's commands go to the arms as they are and the record is the subject's own
        observation (ground truth).

    Returns
    -------
    DemonstrationRun

    """
    if pair_name not in sim.phantom.markers:
        raise ValueError(f'unknown marker pair {pair_name!r}; the phantom has '
                         f'{sorted(sim.phantom.markers)}')
    if not sample_rate > 0.0:
        raise ValueError(f'sample_rate must be > 0 Hz, got {sample_rate}')
    period = 1.0 / float(sample_rate)
    every = int(round(period / sim.dt))
    if every < 1 or abs(every * sim.dt - period) > 1e-9:
        raise ValueError(f'sample period {period} s must be a multiple of the physics step '
                         f'{sim.dt} s')
    command_rate = float(sample_rate if command_rate is None else command_rate)
    if not command_rate > 0.0:
        raise ValueError(f'command_rate must be > 0 Hz, got {command_rate}')
    per_command = int(round(float(sample_rate) / command_rate))
    if per_command < 1 or abs(per_command / float(sample_rate) - 1.0 / command_rate) > 1e-9:
        raise ValueError(f'command period {1.0 / command_rate} s must be a multiple of the '
                         f'sample period {period} s')
    config = sim.config.scene.expert if expert_config is None else expert_config
    nxt = sim.phantom.markers[next_pair] if next_pair is not None else None
    failures: list[str] = []
    run: DemonstrationRun | None = None
    for attempt in range(max(1, int(attempts))):
        run = _one_throw(sim, subject, pair_name, seed, attempt, every, per_command, timeout,
                         nxt, config, link)
        if run.score.score >= 1.0:
            return run
        failures.append(f'attempt {attempt + 1}: score {run.score.score} '
                        f'({run.score.failure or "incomplete"})')
        _LOG.info('demonstration on %s failed (%s); trying again', pair_name, failures[-1])
    if require_success:
        raise DemonstrationError(f'no successful demonstration on {pair_name} in {attempts} '
                                 f'attempts: {"; ".join(failures)}')
    assert run is not None  # at least one attempt ran
    return run


class RobotLink(Protocol):
    """
    How a subject's commands reach a robot, and what a recorder on that robot observes.

    Methods
    -------
    start()
        A new attempt begins (the scene was just reset).
    command(cmd)
        Return the :class:`~sim_bridge.control.Command` the arms get for the subject's.
    record()
        Return the :class:`~sim_bridge.control.Observation` the recorder writes now (its
        ``T_world_needle`` None when the needle is not seen).

    A link may also have ``lag_tolerance``: ``(m, rad)``, how far a tool may be from the
    subject's command for the subject to take it as arrived (default: the Demonstrator's).

    """

    def start(self) -> None:
        """Begin an attempt."""

    def command(self, cmd: Command) -> Command:
        """Return the command the arms get."""

    def record(self) -> Observation:
        """Return the observation recorded now."""


class _Recorder:
    """Record every sample of a demonstration; ask the subject for a command every few."""

    def __init__(self, demonstrator: Demonstrator, per_command: int,
                 link: RobotLink | None = None) -> None:
        self.demonstrator, self.per_command, self.sample = demonstrator, per_command, 0
        self.link = link
        self.rows: dict[str, list[Any]] = {
            't': [], 'psm1': [], 'psm2': [], 'j1': [], 'j2': [], 'needle': [], 'h1': [], 'h2': [],
            'label': []}

    def step(self, obs: Observation) -> Command | None:
        dem, rows = self.demonstrator, self.rows
        cmd = dem.step(obs) if self.sample % self.per_command == 0 else None
        self.sample += 1
        if self.link is not None:
            if cmd is not None:
                cmd = self.link.command(cmd)
            obs = self.link.record()
        rows['t'].append(obs.t)
        rows['psm1'].append(pose_from_transform(obs.T_world_tool['PSM1']))
        rows['psm2'].append(pose_from_transform(obs.T_world_tool['PSM2']))
        rows['j1'].append(obs.jaw['PSM1'])
        rows['j2'].append(obs.jaw['PSM2'])
        rows['needle'].append(_NOT_SEEN if obs.T_world_needle is None
                              else pose_from_transform(obs.T_world_needle))
        rows['h1'].append('PSM1' in obs.holders)
        rows['h2'].append('PSM2' in obs.holders)
        rows['label'].append(dem.subtask)
        return cmd


def _one_throw(sim: 'Simulation', subject: Subject | SkillProfile, pair_name: str, seed: int,
               attempt: int, every: int, per_command: int, timeout: float,
               next_pair: 'MarkerPair | None', config: ExpertConfig,
               link: RobotLink | None = None) -> DemonstrationRun:
    scene_seed = int(seed) + 1000 * attempt
    pair = start_episode(sim, pair_name, scene_seed)
    sim.pop_events()
    if link is not None:
        link.start()
    # a person at a robot's console judges a tool arrived within what the link says it can
    # see (a robot's own error never settles to a simulation's half millimetre)
    lag = getattr(link, 'lag_tolerance', (DEFAULT_LAG_TOLERANCE, DEFAULT_LAG_TOLERANCE_RAD))
    dem = Demonstrator(subject, pair, sim.needle_geometry,
                       kinematics=cast('PsmKinematics', sim.kinematics['PSM2']),
                       rng=_pair_rng(subject, pair_name, seed, attempt), next_pair=next_pair,
                       expert_config=config, lag_tolerance=lag[0], lag_tolerance_rad=lag[1])
    recorder = _Recorder(dem, per_command, link)
    # between the subject's commands the recorder returns None, which run_episode's
    # stop_at_done loop skips (the arms keep gliding to the last command)
    run_episode(sim, dem, every * sim.dt, stepper=cast('CommandSource', recorder),
                timeout=timeout, settle=0.0, reset=False, stop_at_done=True)
    if not dem.done:
        raise DemonstrationError(f'demonstration on {pair_name} did not finish within '
                                 f'{timeout} s of simulated time (stuck in subtask '
                                 f'{dem.subtask})')
    events = sim.pop_events()
    rows = recorder.rows
    seen = None if link is None else link.record().pair
    if seen is not None:  # the recorder's markers: as the robot perceives them
        pair = cast('MarkerPair', seen)
    elif link is not None:  # physical mode: the truth is not there to fall back on
        raise DemonstrationError(f'demonstration on {pair_name}: the recorder never saw the '
                                 f'entry/exit markers (physical mode has no true pair to use)')
    needle = np.array(rows['needle'])
    unseen = int(np.isnan(needle).any(axis=1).sum()) if len(needle) else 0
    if unseen:
        raise DemonstrationError(f'demonstration on {pair_name}: the needle was not seen in '
                                 f'{unseen} of {len(needle)} samples (the recorder needs its '
                                 f'pose throughout)')
    demo = Demonstration(
        t=np.array(rows['t']), psm1_pose=np.array(rows['psm1']),
        psm2_pose=np.array(rows['psm2']), psm1_jaw=np.array(rows['j1']),
        psm2_jaw=np.array(rows['j2']), needle_pose=needle,
        psm1_holds=np.array(rows['h1']), psm2_holds=np.array(rows['h2']),
        entry=pair.entry, exit=pair.exit, normal=pair.normal, pair=pair_name)
    return DemonstrationRun(demo=demo, labels=np.array(rows['label']), score=sim.score(),
                            events=events, attempts=attempt + 1,
                            seed=int(seed) + 1000 * attempt)


def demonstrate(sim: 'Simulation', subject: Subject | SkillProfile, pair_name: str,
                seed: int = 0, sample_rate: float = 100.0, timeout: float = 60.0,
                **kwargs: Any) -> Demonstration:
    """
    Run a subject's demonstration on a pair in-process and return the sampled record.

    See :func:`run_demonstration` for the parameters (and for the score, labels and events).

    Returns
    -------
    suture_lfd.demos.demonstration.Demonstration
        Tool poses, jaws, needle pose and holders at ``sample_rate`` (world frame), and the
        pair's entry, exit and normal.

    """
    return run_demonstration(sim, subject, pair_name, seed=seed, sample_rate=sample_rate,
                             timeout=timeout, **kwargs).demo
