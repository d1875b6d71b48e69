"""
The two kinds of study job, run in-process on the package's simulation (no ROS).

``demo`` (one per subject and pair)
    The subject demonstrates the throw (:func:`suture_lfd.demos.demonstrator.run_demonstration`,
    failed throws repeated), the demonstration is written as a rosbag2 bag
    (:func:`suture_lfd.demos.demo_bag.write_demonstration_bag`, what the recorder node writes),
    read back (:func:`suture_lfd.demos.demo_bag.demonstration_from_bag`, what the segmenter node
    reads), segmented by the segmenter's code (:mod:`suture_lfd.segmentation`,
    :mod:`suture_lfd.demos.segment_file`) and its segment file saved for the throws.
``throw`` (one per subject, method, pair learnt on and pair executed on)
    The skill is learnt from the segment file (:func:`suture_lfd.skill.learn_skill`) and
    executed on the test pair (:func:`suture_lfd.skill.executor.execute_throw`); on the pair it was
    learnt on (a regeneration) the regenerated needle trajectories of ii and iv are also
    compared with the demonstrated ones (Table II) and saved for the Fig. 7 plot.

A job is a frozen dataclass (:class:`~suture_lfd.study.records.DemoJob`,
:class:`~suture_lfd.study.records.ThrowJob`, picklable for worker processes); :func:`run_job`
returns its record (:class:`~suture_lfd.study.records.DemoRecord`,
:class:`~suture_lfd.study.records.ThrowRecord`), stored by :mod:`suture_lfd.study.store`. Paths
in jobs and records are relative to the study's output folder. What a process keeps between jobs
is a :class:`WorkerState`, made once per process by :func:`init_worker` and given to every job
(one simulation per phantom, reused with ``reset(seed)`` per throw; learnt skills; the cohort).

With ``--via-ros`` (:func:`init_worker` given :class:`suture_lfd.study.ros.RosSettings`) a
throw's skill is executed by the simulator and executor node processes instead
(:class:`suture_lfd.study.ros.RosThrows`); the record has the same fields, filled from what the
nodes report. Demonstrations always run in-process.

Units of the records: times s (simulated), position errors mm, orientation errors deg.

Size: the two job kinds share the per-process simulations, the code digest and the attachment of
demonstrations; they stay together while the per-job code is being made faster.
"""

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
import logging
import math
import multiprocessing
import os
from pathlib import Path
import shutil
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.archive import save_archive
from sim_bridge.common.geometry import quaternion_angle
from sim_bridge.common.vocabulary import PSMS, SUBTASKS, TASKS
from sim_bridge.realism.calibration import load_arm_realism
from sim_bridge.realism.endoscope import endoscope_preset
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.simulation import Simulation, load_simulation_config
from sim_bridge.simulation_config import SimulationConfig
from suture_lfd.demos.cohort import Subject, load_cohort
from suture_lfd.demos.demo_bag import (
    default_base_frames,
    demonstration_from_bag,
    write_demonstration_bag,
)
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.demos.demonstrator import run_demonstration
from suture_lfd.demos.resampling import resample_poses
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.dmp import DmpParams, load_dmp_params
from suture_lfd.errors import DemonstrationError
from suture_lfd.segmentation import Segmentation, segment_demonstration
from suture_lfd.skill import ThrowSkill, learn_skill, training_data
from suture_lfd.skill.arm_registration import (
    known_registration,
    load_registration,
    register_arms,
    save_registration,
)
from suture_lfd.skill.executor import ThrowOutcome, execute_throw
from suture_lfd.study.digest import code_digest
from suture_lfd.study.held_out import phantom_config
from suture_lfd.study.metrics import orientation_trajectory_error, trajectory_error
from suture_lfd.study.records import (
    DemoJob,
    DemoRecord,
    RobotErrors,
    ThrowJob,
    ThrowRecord,
    to_json,
)
from suture_lfd.study.ros import RosOutcome, RosSettings, RosThrows
from suture_lfd.study.teleoperated import TeleoperatedRobot
from suture_lfd.viewer.throw_replay import ThrowSampler, replay_name

_LOG = logging.getLogger(__name__)
# the demonstrated, rolled-out and executed needle curves of a regeneration throw (Fig. 7)
TRAJECTORIES_FORMAT = 'suture_lfd.trajectories'
TRAJECTORIES_FORMAT_VERSION = 1


@dataclass(frozen=True)
class JobSettings:
    """
    Settings shared by every job of a study (set once per worker process).

    Attributes
    ----------
    out : str
        Output folder (absolute).
    cohort_path : str or None
        ``cohort.yaml`` (None: the installed one).
    cohort_seed : int
        Cohort seed.
    demo_attempts : int
        Throws a subject gets to produce a successful demonstration.
    timeout : float
        Longest simulated time (s) of one throw.
    sample_rate : float
        Demonstration sampling rate (Hz).
    command_rate : float
        Rate (Hz) of a demonstrating subject's commands: 50 Hz like the executor's control
        period; the arms glide between streamed commands, and the demonstration is still
        sampled at ``sample_rate``.
    control_period : float
        Executor control period (s).
    physics_step : float
        Simulation step (s) of the executed throws: coarser than the live simulator's 2 ms to
        make hundreds of throws affordable. The arms track kinematically and the tissue finds
        crossings between steps, so throws score alike: 15 executions of three skills on five
        pairs gave the same scores, entry and exit errors within 0.01 mm and throw times
        within 0.04 s at 5 ms and at 10 ms. Not 20 ms: there one seed in six of a throw that
        scores 1.0 at 10 ms put the needle tip into the pad 33 mm from the entry marker while
        carrying it there.
    demo_physics_step : float
        Simulation step (s) of the demonstrations: their samples at ``sample_rate`` need a step
        that divides the sample period.
    thread_period : float
        Time (s) between thread updates in the batch runs (a multiple of both steps): the thread
        is drawn, never scored, and nothing in a batch run reads it, so it follows the needle
        at 2 Hz instead of 100 Hz (a tenth of a throw's time at 20 Hz).
    collision_period : float
        Time (s) between instrument-phantom contact checks in the batch runs (a multiple of
        both steps): contacts are counted, never scored (``max_collisions`` -1) and the study
        reports no count, so they are checked every 50 ms instead of every step (at every
        10 ms step they cost about a sixth of a throw).
    tissue : str
        Preset of ``config/realism_tissue.yaml`` for every simulation of the study (the
        needle in tissue); ``'none'``: without those effects. A job's own ``tissue`` (a
        sweep's cell) overrides it.
    camera : str
        Preset of ``config/realism_camera.yaml`` of the endoscope every simulation of the study
        renders through (physical mode looks at its images; ground truth renders none);
        ``'none'``: an ideal camera. A physical-mode job's ``camera`` (a sweep's cell)
        overrides it.

    """

    out: str
    cohort_path: str | None = None
    cohort_seed: int = 0
    demo_attempts: int = 3
    timeout: float = 60.0
    sample_rate: float = 100.0
    command_rate: float = 50.0
    control_period: float = 0.02
    physics_step: float = 0.01
    demo_physics_step: float = 0.01
    thread_period: float = 0.5
    collision_period: float = 0.05
    tissue: str = 'none'
    camera: str = 'none'


@dataclass(eq=False)
class WorkerState:
    """
    What one study process keeps between jobs (made by :func:`init_worker`, given to each job).

    Attributes
    ----------
    settings : JobSettings
        The study's job settings.
    sims : dict
        ``(phantom, physics step) -> Simulation`` (the study's tissue and camera), or
        ``(phantom, physics step, tissue, camera) -> Simulation`` for a job's own, built on
        first use.
    data : dict
        Training data of demonstrations, by key.
    skills : dict
        Learnt skills, by key.
    subjects : dict or None
        The cohort's subjects by name, read on first use.
    ros : suture_lfd.study.ros.RosThrows or None
        Node processes executing the throws (None: in-process).
    dmp_params : dict or None
        ``config/dmp.yaml``'s DMP parameters per task, read on first use.
    base_frames : dict or None
        ``config/world.yaml``'s ``T_world_base`` of the PSMs (the demonstration bags' arm
        bases), read on first use.
    robots : dict
        ``(phantom, physics step, error level, error seed) -> Simulation``: the physical-mode
        robots (hidden kinematic errors) of the latest jobs, at most :data:`ROBOTS_KEPT`,
        the least recently used closed first; each keeps its registration
        (:func:`suture_lfd.skill.arm_registration.register_arms`), so a robot is registered
        once, not per job.
    registered : set
        Keys of ``robots`` whose registration is in the study folder (loaded from it or saved
        to it: :data:`REGISTRATIONS`), so that every process uses the first one made.
    code : str or None
        The code digest (:func:`suture_lfd.study.digest.code_digest`) a saved registration is
        valid for, computed on first use.

    """

    settings: JobSettings
    sims: dict[tuple[Any, ...], Simulation] = field(default_factory=dict)
    data: dict[str, Any] = field(default_factory=dict)
    skills: dict[tuple[str, str, tuple[Any, ...]], ThrowSkill] = field(default_factory=dict)
    subjects: dict[int, dict[str, Subject]] | None = None
    ros: RosThrows | None = None
    dmp_params: dict[str, DmpParams] | None = None
    base_frames: dict[str, np.ndarray] | None = None
    robots: dict[tuple[str, float, float, int, str], Simulation] = field(default_factory=dict)
    registered: set[tuple[str, float, float, int, str]] = field(default_factory=set)
    code: str | None = None

    def close(self) -> None:
        """Release what the state holds beyond this process's memory (node processes)."""
        while self.robots:
            self.robots.pop(next(iter(self.robots))).close()
        if self.ros is not None:
            self.ros.close()
            self.ros = None


def init_worker(settings: JobSettings, ros: RosSettings | None = None) -> WorkerState:
    """
    Return the state of a study process (the job runner's initializer, once per process).

    Parameters
    ----------
    settings : JobSettings
        The study's job settings.
    ros : suture_lfd.study.ros.RosSettings, optional
        Execute the throws through the node processes.

    Returns
    -------
    WorkerState
        Given to every job of the process (:func:`run_job`).

    """
    logging.getLogger('suture_lfd').setLevel(logging.WARNING)
    logging.getLogger('sim_bridge').setLevel(logging.WARNING)
    state = WorkerState(settings)
    if ros is not None:
        state.ros = RosThrows(ros, settings.out, settings.timeout, settings.tissue)
        parent = multiprocessing.parent_process()
        if parent is not None:   # a worker: stop its nodes on SIGTERM and when the study dies
            state.ros.install_sigterm(parent.pid)
    return state


def _simulation(state: WorkerState, phantom: str, step: float | None = None,
                spec: Mapping[str, Any] | None = None, tissue: str | None = None,
                camera: str | None = None) -> Simulation:
    """
    Return the worker's simulation of a phantom at ``step`` (default: the throws' step).

    ``spec`` (a held-out phantom's configuration, :mod:`suture_lfd.study.held_out`): ``phantom`` is
    then the key of that geometry. ``tissue``, ``camera``: a job's presets (default: the
    study's).
    """
    s = state.settings
    dt = s.physics_step if step is None else float(step)
    tissue = s.tissue if tissue is None else tissue
    camera = s.camera if camera is None else camera
    sims = state.sims
    key: tuple[Any, ...] = (phantom, dt) if (tissue, camera) == (s.tissue, s.camera) \
        else (phantom, dt, tissue, camera)
    if key not in sims:
        config = load_simulation_config()
        loop = replace(config.loop, thread_period=s.thread_period,
                       collision_period=max(s.collision_period, dt))
        config = replace(config, world=replace(config.world, physics_step=dt), loop=loop)
        config = _with_camera(_with_tissue(config, tissue), camera)
        if spec is not None:
            sims[key] = Simulation(config, phantom=phantom_config(spec),
                                   rng=np.random.default_rng(0))
        else:
            sims[key] = Simulation(config, phantom=phantom, rng=np.random.default_rng(0))
    return sims[key]


#: Physical-mode robots a study process keeps between jobs (the jobs of one subject on one
#: phantom come in a row, so a few cover a process's share of them).
ROBOTS_KEPT = 4


def _physical_simulation(state: WorkerState, phantom: str, step: float,
                         physical: RobotErrors, tissue: str | None = None) -> Simulation:
    """
    Return the simulation of a phantom for a physical-mode job (the worker's: kept).

    ``physical``: the job's robot errors (and its camera). Level 0 is the worker's shared
    simulation (perfect kinematics: nothing to draw); any other level the robot of those errors
    (drawn per subject and phantom, :func:`suture_lfd.study.physical.robot_key`), kept in
    ``state.robots`` for the next jobs on it. ``tissue``: the job's preset (default: the
    study's).
    """
    if not _has_errors(physical):
        return _simulation(state, phantom, step, tissue=tissue,
                           camera=_camera(state, physical))
    key = _robot_key(phantom, step, physical, *_presets(state, physical, tissue))
    robots = state.robots
    sim = robots.pop(key, None)
    if sim is None:
        sim = _robot(state, phantom, step, physical, tissue)
        state.registered.discard(key)
        if load_registration(_registration_path(state, key), sim,
                             _registration_key(state, key)) is not None:
            state.registered.add(key)
        while len(robots) >= ROBOTS_KEPT:
            robots.pop(next(iter(robots))).close()
    robots[key] = sim  # the most recently used last
    return sim


#: The study folder's registrations of the physical-mode robots (one JSON file per robot:
#: :func:`suture_lfd.skill.arm_registration.save_registration`).
REGISTRATIONS = 'physical/registrations'


def _registration_path(state: WorkerState, key: tuple[str, float, float, int, str]) -> Path:
    """Return the file of a robot's registration (``key`` as in ``state.robots``)."""
    phantom, step, level, seed, realism = key
    model = f'{level:g}mm' if realism == 'static' else realism
    name = f'{phantom}_{step:g}s_{model}_{seed}.json'
    return Path(state.settings.out) / REGISTRATIONS / name


def _registration_key(state: WorkerState, key: tuple[str, float, float, int, str]
                      ) -> dict[str, Any]:
    """Return what a robot's saved registration is valid for: the robot and the code."""
    if state.code is None:
        state.code = code_digest()
    phantom, step, level, seed, realism = key
    return {'phantom': phantom, 'physics_step': step, 'error_level': level,
            'error_seed': seed, **({} if realism == 'static' else {'arm_realism': realism}),
            'code': state.code}


def _save_registrations(state: WorkerState) -> None:
    """Save the registrations of the process's robots that are not in the study folder yet."""
    for key, sim in state.robots.items():
        if key in state.registered:
            continue
        correction = known_registration(sim)
        if correction is not None:
            save_registration(_registration_path(state, key), correction,
                              _registration_key(state, key))
            state.registered.add(key)


#: Age (s) after which another process's claim to register a robot is taken as abandoned.
REGISTRATION_WAIT = 120.0


def _registered(state: WorkerState, key: tuple[str, float, float, int, str], sim: Simulation
                ) -> None:
    """
    Make sure the robot ``key`` (``sim``) has its registration, run once per study.

    The study folder's file is loaded when there is one; otherwise the first process to claim
    the robot (a ``.claim`` file beside the registration's) registers it and saves it, and the
    others wait for its file instead of registering the robot again.
    """
    if known_registration(sim) is not None:
        return
    path = _registration_path(state, key)
    expected = _registration_key(state, key)
    claim = path.with_name(path.name + '.claim')
    claim.parent.mkdir(parents=True, exist_ok=True)
    while load_registration(path, sim, expected) is None:
        try:
            os.close(os.open(claim, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            try:
                abandoned = time.time() - claim.stat().st_mtime > REGISTRATION_WAIT
            except FileNotFoundError:
                continue  # just released: its file is there, or the claim is free
            if not abandoned:
                time.sleep(0.1)
                continue
            _LOG.warning('%s: claimed for over %.0f s and not written; registering here',
                         path, REGISTRATION_WAIT)
        else:
            try:
                if load_registration(path, sim, expected) is None:
                    register_arms(sim)
                    _save_registrations(state)
            finally:
                claim.unlink(missing_ok=True)
            return
        register_arms(sim)
        _save_registrations(state)
        return
    state.registered.add(key)


def _has_errors(physical: RobotErrors) -> bool:
    """Whether a job's robot differs from the perfect one (a realism preset or a level > 0)."""
    return physical.arm_realism != 'static' or float(physical.error_level) != 0.0


def _camera(state: WorkerState, physical: RobotErrors | None) -> str:
    """Return a job's camera preset: its own (a sweep's cell) or the study's."""
    own = None if physical is None else physical.camera
    return state.settings.camera if own is None else own


def _presets(state: WorkerState, physical: RobotErrors, tissue: str | None) -> tuple[str, str]:
    """Return a physical-mode job's (tissue, camera) presets, its own or the study's."""
    return (state.settings.tissue if tissue is None else tissue), _camera(state, physical)


def _robot_key(phantom: str, step: float, physical: RobotErrors, tissue: str = 'none',
               camera: str = 'none') -> tuple[str, float, float, int, str]:
    """
    Return a robot's key: (phantom, physics step, error level, error seed, model).

    The model is the arm realism with its levels, then the tissue and camera presets other than
    ``none`` (``dvrk-servo_level0.5-camera-dvrk``).
    """
    model = physical.arm_realism + ''.join(f'-{k}{v:g}' for k, v in physical.arm_levels)
    model += ''.join(f'-{what}-{name}' for what, name in (('tissue', tissue), ('camera', camera))
                     if name != 'none')
    return (phantom, float(step), float(physical.error_level), int(physical.error_seed), model)


def _robot(state: WorkerState, phantom: str, step: float, physical: RobotErrors,
           tissue: str | None = None) -> Simulation:
    """Build the simulation of a robot with the hidden kinematic errors ``physical``."""
    level = float(physical.error_level)
    s = state.settings
    config = load_simulation_config()
    loop = replace(config.loop, thread_period=s.thread_period,
                   collision_period=max(s.collision_period, step))
    realism = None if physical.arm_realism == 'static' else load_arm_realism(
        physical.arm_realism, levels=dict(physical.arm_levels))
    config = replace(config, world=replace(config.world, physics_step=float(step)), loop=loop,
                     kinematic_error_level=level,
                     kinematic_error_seed=int(physical.error_seed), arm_realism=realism)
    tissue, camera = _presets(state, physical, tissue)
    config = _with_camera(_with_tissue(config, tissue), camera)
    return Simulation(config, phantom=phantom, rng=np.random.default_rng(0))


def _slips(events: list[dict[str, Any]]) -> dict[str, Any]:
    """Return the record's ``slips`` (the needle turning in the jaw), if the throw had any."""
    slips = [{'t': float(ev['t']), 'arm': ev.get('arm'), 'angle': float(ev.get('angle', 0.0)),
              'slide': float(ev.get('slide', 0.0)), 'in_tissue': bool(ev.get('in_tissue')),
              'broken': bool(ev.get('broken'))}
             for ev in events if ev.get('kind') == 'slip']
    return {'slips': slips} if slips else {}


def _with_tissue(config: SimulationConfig, preset: str) -> SimulationConfig:
    """Return ``config`` with the needle-in-tissue preset ``preset`` (unchanged for none)."""
    if preset == 'none':
        return config
    return replace(config, tissue_realism=load_tissue_realism(preset))


def _with_camera(config: SimulationConfig, preset: str) -> SimulationConfig:
    """Return ``config`` with the endoscope preset ``preset`` (unchanged for none)."""
    if preset == 'none':
        return config
    return replace(config, endoscope=endoscope_preset(preset))


def _subject(state: WorkerState, name: str, seed: int | None = None) -> Subject:
    """Return a subject of the cohort drawn with ``seed`` (default: the settings' seed)."""
    s = state.settings
    drawn = s.cohort_seed if seed is None else int(seed)
    if state.subjects is None:
        state.subjects = {}
    if drawn not in state.subjects:
        state.subjects[drawn] = {x.name: x for x in load_cohort(s.cohort_path, seed=drawn)}
    subjects = state.subjects[drawn]
    if name not in subjects:
        raise ValueError(f'subject {name!r} is not in the cohort ({sorted(subjects)})')
    return subjects[name]


def run_job(job: DemoJob | ThrowJob, state: WorkerState) -> DemoRecord | ThrowRecord:
    """
    Run one study job and return its record.

    Parameters
    ----------
    job : DemoJob or ThrowJob
        The job.
    state : WorkerState
        This process's state (:func:`init_worker`).

    Returns
    -------
    DemoRecord or ThrowRecord
        The job's record: its fields and its results.

    """
    record: DemoRecord | ThrowRecord
    if isinstance(job, DemoJob):
        record = demo_job(job, state)
    elif isinstance(job, ThrowJob):
        record = throw_job(job, state)
    else:
        raise TypeError(f'a study job is a DemoJob or a ThrowJob, got {type(job).__name__}')
    if state.robots:
        _save_registrations(state)
    return record


# ---------------------------------------------------------------------- demonstrations
def demo_job(job: DemoJob, state: WorkerState) -> DemoRecord:
    """
    Record, store, read back and segment one demonstration (a ``demo`` job).

    Parameters
    ----------
    job : DemoJob
        The demonstration to record (paths relative to the output folder).
    state : WorkerState
        This process's state (:func:`init_worker`).

    Returns
    -------
    DemoRecord
        The job's fields plus ``attempts``, ``ok``, ``demo_score``, ``failure``, ``time_s``
        (full-throw time of the demonstration) and ``t_i`` .. ``t_v`` (segmented subtask
        durations, s).

    """
    s = state.settings
    out = Path(s.out)
    subject = _subject(state, job.subject, job.cohort_seed)
    physical = job.physical
    if physical is None:
        sim = _simulation(state, job.phantom, s.demo_physics_step, tissue=job.tissue)
        link = None
    else:
        sim = _physical_simulation(state, job.phantom, s.demo_physics_step, physical,
                                   job.tissue)
        if _has_errors(physical):
            # registered before anything is recorded, as in a lab (once per study)
            _registered(state, _robot_key(job.phantom, s.demo_physics_step, physical,
                                          *_presets(state, physical, job.tissue)), sim)
        link = TeleoperatedRobot(sim, job.pair)
    try:
        run = run_demonstration(sim, subject, job.pair, seed=job.seed,
                                sample_rate=s.sample_rate, command_rate=s.command_rate,
                                timeout=s.timeout,
                                attempts=s.demo_attempts, next_pair=job.next_pair,
                                require_success=False, link=link)
    except DemonstrationError as exc:
        if link is None:
            raise
        # on a robot, a demonstration whose needle the recorder never saw is a result, not a
        # fault to run again
        return DemoRecord.of(job, attempts=1, demo_score=0.0, failure=str(exc),
                             time_s=None, ok=False)
    # a robot's recorder writes its arms as it believes them: measured_cp through the believed
    # bases
    bases = None if link is None else {arm: sim.believed_base(arm) for arm in PSMS}
    record = DemoRecord.of(job, attempts=int(run.attempts), demo_score=float(run.score.score),
                           failure=run.score.failure, time_s=float(run.score.time_s), ok=False)
    demo = _through_bag(state, run.demo, out / job.bag, job.pair, bases)
    if run.score.score < 1.0:
        return replace(record, failure=f'no successful demonstration: {run.score.failure}')
    target = out / job.segments
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(target.stem + '.part' + target.suffix)
    try:
        segmentation = segment_demonstration(demo)
        _save_segments(demo, segmentation, tmp, source=job.bag, subject=job.subject)
    except ValueError as exc:
        if physical is None:
            raise
        # on what the robot saw, a demonstration the segmenter cannot read is a result (the
        # perceived grasps miss one), not a fault to run again
        return replace(record, failure=f'not segmentable from what the robot recorded: {exc}')
    durations: dict[str, Any] = {f't_{seg.name}': float(seg.duration)
                                 for seg in segmentation.subtasks}
    os.replace(tmp, target)
    return replace(record, ok=True, **durations)


def _through_bag(state: WorkerState, demo: Demonstration, bag: Path, pair: str,
                 base_frames: Mapping[str, ArrayLike] | None = None) -> Demonstration:
    """
    Write the demonstration as the recorder would and read it back as the segmenter does.

    ``base_frames``: the arms' ``T_world_base`` the recorder writes (default
    ``config/world.yaml``'s).
    """
    if bag.exists():
        shutil.rmtree(bag)  # left by a run killed while writing it
    bag.parent.mkdir(parents=True, exist_ok=True)
    if state.base_frames is None:  # config/world.yaml's arm bases, read once per process
        state.base_frames = default_base_frames()
    write_demonstration_bag(bag, demo, base_frames=base_frames or state.base_frames)
    return demonstration_from_bag(bag, pair=pair)


def _save_segments(demo: Demonstration, segmentation: Segmentation, path: Path,
                   source: str = '', subject: str = '') -> None:
    """Save what the throws learn from: the demonstration's segment file."""
    make_segment_file(demo, segmentation, source=source, subject=subject).save(path)


# ---------------------------------------------------------------------- throws
def _training(state: WorkerState, path: str) -> Any:
    data = state.data
    if path not in data:  # the skill's TrainingData of the demonstration's segment file
        data[path] = training_data(path)
    return data[path]


def _dmp_params(state: WorkerState) -> dict[str, DmpParams]:
    """Return ``config/dmp.yaml``'s parameters per task (read once per process)."""
    if state.dmp_params is None:
        state.dmp_params = {task: load_dmp_params(task=task) for task in TASKS}
    return state.dmp_params


def _skill(state: WorkerState, path: str, method: str,
           dmp: Mapping[str, Mapping[str, Any]] | None = None) -> ThrowSkill:
    """
    Return the skill learnt from a segment file by a method (cached per process).

    ``dmp`` (optional): DMP hyper-parameters that differ from ``config/dmp.yaml``, as
    ``{task: {key: value}}`` (a sweep's cell).
    """
    skills = state.skills
    overrides = tuple(sorted((task, tuple(sorted(values.items())))
                             for task, values in (dmp or {}).items()))
    key = (path, method, overrides)
    if key not in skills:
        if len(skills) > 64:
            skills.clear()
        params = _dmp_params(state)
        if overrides:
            params = {task: replace(params[task], **(dmp or {}).get(task, {})) for task in TASKS}
        skills[key] = learn_skill(_training(state, path), method=method, params=params)
    return skills[key]


def _angle_deg(q1: ArrayLike, q2: ArrayLike) -> float:
    return math.degrees(float(quaternion_angle(np.asarray(q1), np.asarray(q2))))


def regeneration_errors(reference: tuple[ArrayLike, ArrayLike],
                        regenerated: tuple[ArrayLike, ArrayLike]) -> dict[str, float]:
    """
    Return the Table II errors of a regenerated needle trajectory against the demonstrated one.

    Parameters
    ----------
    reference : tuple of ndarray
        ``(P (n, 3), Q (n, 4))`` demonstrated needle positions (m) and quaternions.
    regenerated : tuple of ndarray
        ``(P (m, 3), Q (m, 4))`` regenerated trajectory, same frame.

    Returns
    -------
    dict
        ``start_mm``, ``goal_mm``, ``traj_mm`` (mean distance along the DTW path),
        ``start_deg``, ``goal_deg``, ``traj_deg`` (mean angle along the orientation DTW path).

    """
    P0, Q0 = (np.asarray(a, float) for a in reference)
    P1, Q1 = (np.asarray(a, float) for a in regenerated)
    return {'start_mm': float(np.linalg.norm(P1[0] - P0[0]) * 1e3),
            'goal_mm': float(np.linalg.norm(P1[-1] - P0[-1]) * 1e3),
            'traj_mm': trajectory_error(P0, P1)['mean_mm'],
            'start_deg': _angle_deg(Q1[0], Q0[0]), 'goal_deg': _angle_deg(Q1[-1], Q0[-1]),
            'traj_deg': orientation_trajectory_error(Q0, Q1)['mean_deg']}


def _nan() -> float:
    return float('nan')


def throw_job(job: ThrowJob, state: WorkerState) -> ThrowRecord:
    """
    Learn a skill from a demonstration and execute it on a pair (a ``throw`` job).

    Parameters
    ----------
    job : ThrowJob
        The throw, with its training demonstration's segment file (``segments``, relative, or
        None when that demonstration failed) and ``demo_time_s`` attached.
    state : WorkerState
        This process's state (:func:`init_worker`).

    Returns
    -------
    ThrowRecord
        The job's fields plus ``score``, ``i`` .. ``v``, ``failure``, ``time_s`` (simulated
        full-throw time), ``entry_error_mm``, ``exit_error_mm``, ``regeneration`` and, for a
        regeneration, the Table II errors ``<task>_<start|goal|traj>_<mm|deg>`` and
        ``<task>_exec_traj_mm``; for a throw executed in-process, ``replay`` (its replay file,
        relative) and ``replay_bytes`` (that file's size).

    """
    if job.blocked:  # stored as an error: done again once the demonstration exists
        return job.failed(job.blocked)
    s = state.settings
    out = Path(s.out)
    regeneration = job.train_pair == job.test_pair
    if not job.segments:
        return ThrowRecord.of(job, regeneration=regeneration, score=0.0,
                              failure='no successful demonstration to learn from',
                              time_s=_nan(), entry_error_mm=_nan(), exit_error_mm=_nan(),
                              trajectories=None, **dict.fromkeys(SUBTASKS, False))
    path = str(out / job.segments)
    skill = _skill(state, path, job.method, job.dmp)
    ros = state.ros
    physical = job.physical
    # what the viewer needs to replay the throw (suture-lfd view STUDY --throw ROW)
    name = replay_name(to_json(job))
    replay: str | None = name
    outcome: ThrowOutcome | RosOutcome
    if physical is not None:
        sim = _physical_simulation(state, job.test_phantom, s.physics_step, physical,
                                   job.tissue)
        if physical.correction and _has_errors(physical):
            _registered(state, _robot_key(job.test_phantom, s.physics_step, physical,
                                          *_presets(state, physical, job.tissue)), sim)
        sampler = ThrowSampler(sim)
        outcome = execute_throw(sim, skill, job.test_pair, seed=job.seed,
                                timeout=s.timeout, control_period=s.control_period,
                                observer=sampler, physical=True,
                                correction=bool(physical.correction))
        markers = sim.phantom.markers
        replay = f'{job.folder}/{name}'
        replay_bytes = sampler.save(out / replay, job.test_pair, outcome.events,
                                    outcome.subtask_times)
    elif ros is None:
        sim = (_simulation(state, job.test_key or job.test_phantom, spec=job.test_config,
                           tissue=job.tissue)
               if job.test_config is not None
               else _simulation(state, job.test_phantom, tissue=job.tissue))
        sampler = ThrowSampler(sim)
        outcome = execute_throw(sim, skill, job.test_pair, seed=job.seed,
                                timeout=s.timeout, control_period=s.control_period,
                                observer=sampler)
        markers = sim.phantom.markers
        replay_bytes = sampler.save(out / name, job.test_pair, outcome.events,
                                    outcome.subtask_times)
    else:
        outcome = ros.execute(job, skill)
        markers = ros.markers(job.test_phantom)
        # the nodes' throws are not sampled for replay: the record says so in the same fields
        replay, replay_bytes = None, 0
    record = ThrowRecord.of(
        job, regeneration=regeneration, replay=replay, replay_bytes=replay_bytes,
        score=float(outcome.score), failure=outcome.failure,
        time_s=float(outcome.duration), entry_error_mm=float(outcome.entry_error_mm),
        exit_error_mm=float(outcome.exit_error_mm),
        **{k: bool(outcome.subtasks.get(k, False)) for k in SUBTASKS},
        **_slips(getattr(outcome, 'events', None) or []))
    if not regeneration:
        return replace(record, trajectories=None)
    data = _training(state, path)
    pair = markers[job.test_pair]
    errors: dict[str, Any] = {}
    curves: dict[str, np.ndarray] = {}
    for task in TASKS:
        n_pts = skill.dmps[task].params.n_pts
        T, P, Q = data.needle[task]
        _, P0, Q0 = resample_poses(T, P, Q, n_pts=n_pts or len(T))
        _, P1, Q1 = skill.rollout(task, pair)
        for name, value in regeneration_errors((P0, Q0), (P1, Q1)).items():
            errors[f'{task}_{name}'] = value
        curves[f'demo_{task}'] = np.hstack((P0, Q0))
        curves[f'rollout_{task}'] = np.hstack((P1, Q1))
        executed = outcome.executed.get(task)
        if executed is not None and len(executed[0]) > 1:
            poses = np.asarray(executed[1], float)
            errors[f'{task}_exec_traj_mm'] = trajectory_error(P0, poses[:, :3])['mean_mm']
            curves[f'exec_{task}'] = poses
        else:
            errors[f'{task}_exec_traj_mm'] = _nan()
            curves[f'exec_{task}'] = np.zeros((0, 7))
    if job.trajectories:
        target = out / job.trajectories
        target.parent.mkdir(parents=True, exist_ok=True)
        save_archive(target, curves, TRAJECTORIES_FORMAT, TRAJECTORIES_FORMAT_VERSION,
                     compressed=True)
    return replace(record, **errors)
