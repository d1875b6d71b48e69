"""
The two kinds of study job, run in-process on the package's simulation (no ROS).

``demo`` (one per subject and pair)
    The subject demonstrates the throw (:func:`suture_lfd.demos.demonstrator.run_demonstration`,
    failed throws repeated), the demonstration is written as a rosbag2 bag
    (:func:`suture_lfd.demos.demo_bag.write_demonstration_bag`, what the recorder node writes),
    read back (:func:`suture_lfd.demos.demo_bag.demonstration_from_bag`, what the segmenter node
    reads), segmented by the segmenter's code (:mod:`suture_lfd.segmentation`,
    :mod:`suture_lfd.segmentation.segments`) and its segment file saved for the throws.
``throw`` (one per subject, method, pair learnt on and pair executed on)
    The skill is learnt from the segment file (:func:`suture_lfd.skill.learn_skill`) and
    executed on the test pair (:func:`suture_lfd.skill.executor.execute_throw`); on the pair it was
    learnt on (a regeneration) the regenerated needle trajectories of ii and iv are also
    compared with the demonstrated ones (Table II) and saved for the Fig. 7 plot.

A job is a plain ``dict`` (picklable for worker processes); :func:`run_job` returns the flat
result record stored by :mod:`suture_lfd.study.store`. Paths in jobs and records are relative
to the study's output folder. Each worker process keeps one simulation per phantom and
reuses it (``reset(seed)`` per throw).

With ``--via-ros`` (:func:`init_worker` given :class:`suture_lfd.study.ros.RosSettings`) a
throw's skill is executed by the simulator and executor node processes instead
(:class:`suture_lfd.study.ros.RosThrows`); the record has the same fields, filled from what the
nodes report. Demonstrations always run in-process.

Units of the records: times s (simulated), position errors mm, orientation errors deg.

Size: the two job kinds share the per-process simulations, the code digest and the attachment of
demonstrations; they stay together while the per-job code is being made faster.
"""

from dataclasses import dataclass, field, replace
import logging
import math
import os
from pathlib import Path
import shutil

import numpy as np
from sim_bridge.common.geometry import quaternion_angle
from suture_lfd.archive import save_archive
from suture_lfd.demos.resampling import resample_poses
from suture_lfd.study.metrics import orientation_trajectory_error, trajectory_error

_LOG = logging.getLogger(__name__)
# the demonstrated, rolled-out and executed needle curves of a regeneration throw (Fig. 7)
TRAJECTORIES_FORMAT = 'suture_lfd.trajectories'
TRAJECTORIES_FORMAT_VERSION = 1
TASKS = ('ii', 'iv')
SUBTASKS = ('i', 'ii', 'iii', 'iv', 'v')


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


@dataclass(eq=False)
class WorkerState:
    """
    What one study process keeps between jobs (set up by :func:`init_worker`).

    Attributes
    ----------
    settings : JobSettings
        The study's job settings.
    sims : dict
        ``(phantom, physics step) -> Simulation``, built on first use.
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

    """

    settings: object
    sims: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)
    skills: dict = field(default_factory=dict)
    subjects: dict | None = None
    ros: object = None
    dmp_params: dict | None = None
    base_frames: dict | None = None


_worker = None  # this process's WorkerState (a pool worker is initialised once)


def init_worker(settings, ros=None):
    """
    Set the job settings of this process (worker initializer).

    ``ros`` (:class:`suture_lfd.study.ros.RosSettings`, optional): execute the throws through
    the node processes.
    """
    global _worker
    logging.getLogger('suture_lfd').setLevel(logging.WARNING)
    logging.getLogger('sim_bridge').setLevel(logging.WARNING)
    if _worker is not None and _worker.ros is not None:
        _worker.ros.close()
    _worker = WorkerState(settings)
    if ros is not None:
        import multiprocessing

        from suture_lfd.study.ros import RosThrows

        _worker.ros = RosThrows(ros, settings.out, settings.timeout)
        parent = multiprocessing.parent_process()
        if parent is not None:   # a worker: stop its nodes on SIGTERM and when the study dies
            _worker.ros.install_sigterm(parent.pid)


def close_worker():
    """Release what :func:`init_worker` set up in this process (node processes, ROS domain)."""
    if _worker is not None and _worker.ros is not None:
        _worker.ros.close()
        _worker.ros = None


def _state():
    if _worker is None:
        raise RuntimeError('study jobs need init_worker(settings) first')
    return _worker


def _settings():
    return _state().settings


def _simulation(phantom, step=None, spec=None):
    """
    Return the worker's simulation of a phantom at ``step`` (default: the throws' step).

    ``spec`` (a held-out phantom's configuration, :mod:`suture_lfd.study.held_out`): ``phantom`` is
    then the key of that geometry.
    """
    s = _settings()
    step = s.physics_step if step is None else float(step)
    sims = _state().sims
    if (phantom, step) not in sims:
        from sim_bridge.simulation import Simulation, load_simulation_config

        config = load_simulation_config()
        loop = replace(config.loop, thread_period=s.thread_period,
                       collision_period=max(s.collision_period, step))
        config = replace(config, world=replace(config.world, physics_step=step), loop=loop)
        if spec is not None:
            from suture_lfd.study.held_out import phantom_config

            sims[phantom, step] = Simulation(config, phantom=phantom_config(spec),
                                             rng=np.random.default_rng(0))
        else:
            sims[phantom, step] = Simulation(config, phantom=phantom,
                                             rng=np.random.default_rng(0))
    return sims[phantom, step]


def _subject(name, seed=None):
    """Return a subject of the cohort drawn with ``seed`` (default: the settings' seed)."""
    s = _settings()
    seed = s.cohort_seed if seed is None else int(seed)
    state = _state()
    if state.subjects is None:
        state.subjects = {}
    if seed not in state.subjects:
        from suture_lfd.demos.cohort import load_cohort

        state.subjects[seed] = {x.name: x for x in load_cohort(s.cohort_path, seed=seed)}
    subjects = state.subjects[seed]
    if name not in subjects:
        raise ValueError(f'subject {name!r} is not in the cohort ({sorted(subjects)})')
    return subjects[name]


def run_job(job):
    """
    Run one study job and return its record.

    Parameters
    ----------
    job : dict
        ``kind`` 'demo' or 'throw' and the fields :func:`demo_job` / :func:`throw_job` need.

    Returns
    -------
    dict
        Flat record (JSON-serialisable) with the job's fields and its results.

    """
    if job['kind'] == 'demo':
        return demo_job(job)
    if job['kind'] in ('throw', 'held_out'):
        return throw_job(job)
    raise ValueError(f'unknown study job kind {job["kind"]!r}')


# ---------------------------------------------------------------------- demonstrations
def demo_job(job):
    """
    Record, store, read back and segment one demonstration (a ``demo`` job).

    Parameters
    ----------
    job : dict
        ``key``, ``subject``, ``group``, ``phantom``, ``pair``, ``next_pair`` (or None),
        ``seed`` (scene seed), ``order``, ``bag`` and ``segments`` (paths relative to the
        output folder).

    Returns
    -------
    dict
        The job's fields plus ``attempts``, ``ok``, ``demo_score``, ``failure``, ``time_s``
        (full-throw time of the demonstration) and ``t_i`` .. ``t_v`` (segmented subtask
        durations, s).

    """
    from suture_lfd.demos.demonstrator import run_demonstration
    from suture_lfd.segmentation import segment_demonstration

    s = _settings()
    out = Path(s.out)
    subject = _subject(job['subject'], job.get('cohort_seed'))
    sim = _simulation(job['phantom'], s.demo_physics_step)
    run = run_demonstration(sim, subject, job['pair'], seed=job['seed'],
                            sample_rate=s.sample_rate, command_rate=s.command_rate,
                            timeout=s.timeout,
                            attempts=s.demo_attempts, next_pair=job.get('next_pair'),
                            require_success=False)
    record = {**job, 'attempts': int(run.attempts), 'demo_score': float(run.score.score),
              'failure': run.score.failure, 'time_s': float(run.score.time_s), 'ok': False}
    demo = _through_bag(run.demo, out / job['bag'], job['pair'])
    if run.score.score < 1.0:
        record['failure'] = f'no successful demonstration: {run.score.failure}'
        return record
    segmentation = segment_demonstration(demo)
    for seg in segmentation.subtasks:
        record[f't_{seg.name}'] = float(seg.duration)
    target = out / job['segments']
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(target.stem + '.part' + target.suffix)
    _save_segments(demo, segmentation, tmp, source=job['bag'], subject=job['subject'])
    os.replace(tmp, target)
    record['ok'] = True
    return record


def _through_bag(demo, bag, pair):
    """Write the demonstration as the recorder would and read it back as the segmenter does."""
    from suture_lfd.demos.demo_bag import (
        default_base_frames,
        demonstration_from_bag,
        write_demonstration_bag,
    )

    if bag.exists():
        shutil.rmtree(bag)  # left by a run killed while writing it
    bag.parent.mkdir(parents=True, exist_ok=True)
    state = _state()
    if state.base_frames is None:  # config/world.yaml's arm bases, read once per process
        state.base_frames = default_base_frames()
    write_demonstration_bag(bag, demo, base_frames=state.base_frames)
    return demonstration_from_bag(bag, pair=pair)


def _save_segments(demo, segmentation, path, source='', subject=''):
    """Save what the throws learn from: the demonstration's segment file."""
    from suture_lfd.segmentation.segments import make_segment_file

    make_segment_file(demo, segmentation, source=source, subject=subject).save(path)


# ---------------------------------------------------------------------- throws
def _training(path):
    data = _state().data
    if path not in data:  # the skill's TrainingData of the demonstration's segment file
        from suture_lfd.skill import training_data

        data[path] = training_data(path)
    return data[path]


def _dmp_params():
    """Return ``config/dmp.yaml``'s parameters per task (read once per process)."""
    state = _state()
    if state.dmp_params is None:
        from suture_lfd.dmp import load_dmp_params

        state.dmp_params = {task: load_dmp_params(task=task) for task in TASKS}
    return state.dmp_params


def _skill(path, method, dmp=None):
    """
    Return the skill learnt from a segment file by a method (cached per process).

    ``dmp`` (optional): DMP hyper-parameters that differ from ``config/dmp.yaml``, as
    ``{task: {key: value}}`` (a sweep's cell).
    """
    skills = _state().skills
    overrides = tuple(sorted((task, tuple(sorted(values.items())))
                             for task, values in (dmp or {}).items()))
    key = (path, method, overrides)
    if key not in skills:
        from suture_lfd.skill import learn_skill

        if len(skills) > 64:
            skills.clear()
        params = _dmp_params()
        if overrides:
            from dataclasses import replace as with_values

            params = {task: with_values(params[task], **dmp.get(task, {})) for task in TASKS}
        skills[key] = learn_skill(_training(path), method=method, params=params)
    return skills[key]


def _angle_deg(q1, q2):
    return math.degrees(float(quaternion_angle(np.asarray(q1), np.asarray(q2))))


def regeneration_errors(reference, regenerated):
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


def _nan():
    return float('nan')


def throw_job(job):
    """
    Learn a skill from a demonstration and execute it on a pair (a ``throw`` job).

    Parameters
    ----------
    job : dict
        ``key``, ``subject``, ``group``, ``method``, ``train_phantom``, ``train_pair``,
        ``test_phantom``, ``test_pair``, ``seed`` (scene seed), ``segments`` (the training
        demonstration's segment file, relative, or None when that demonstration failed),
        ``demo_time_s``, ``trajectories`` (where to save the curves of a regeneration, or
        None).

    Returns
    -------
    dict
        The job's fields plus ``score``, ``i`` .. ``v``, ``failure``, ``time_s`` (simulated
        full-throw time), ``entry_error_mm``, ``exit_error_mm``, ``regeneration`` and, for a
        regeneration, the Table II errors ``<task>_<start|goal|traj>_<mm|deg>`` and
        ``<task>_exec_traj_mm``; for a throw executed in-process, ``replay`` (its replay file,
        relative) and ``replay_bytes`` (that file's size).

    """
    if job.get('blocked'):  # stored as an error: done again once the demonstration exists
        return {**job, 'error': job['blocked']}
    s = _settings()
    out = Path(s.out)
    record = {**job, 'regeneration': job['train_pair'] == job['test_pair']}
    spec = record.pop('test_config', None)  # a held-out pair's phantom (kept in the config)
    if not job.get('segments'):
        record.update(score=0.0, failure='no successful demonstration to learn from',
                      time_s=_nan(), entry_error_mm=_nan(), exit_error_mm=_nan(),
                      trajectories=None, **dict.fromkeys(SUBTASKS, False))
        return record
    from suture_lfd.skill.executor import execute_throw
    from suture_lfd.viewer.throw_replay import ThrowSampler, replay_name

    path = str(out / job['segments'])
    skill = _skill(path, job['method'], job.get('dmp'))
    ros = _state().ros
    if ros is None:
        sim = (_simulation(job['test_key'], spec=spec) if spec is not None
               else _simulation(job['test_phantom']))
        sampler = ThrowSampler(sim)
        outcome = execute_throw(sim, skill, job['test_pair'], seed=job['seed'],
                                timeout=s.timeout, control_period=s.control_period,
                                observer=sampler)
        markers = sim.phantom.markers
        # what the viewer needs to replay the throw (suture-lfd view STUDY --throw ROW)
        record['replay'] = replay_name(job)
        record['replay_bytes'] = sampler.save(out / record['replay'], job['test_pair'],
                                              outcome.events, outcome.subtask_times)
    else:
        outcome = ros.execute(job, skill)
        markers = ros.markers(job['test_phantom'])
        # the nodes' throws are not sampled for replay: the record says so in the same fields
        record['replay'], record['replay_bytes'] = None, 0
    record.update(score=float(outcome.score), failure=outcome.failure,
                  time_s=float(outcome.duration), entry_error_mm=float(outcome.entry_error_mm),
                  exit_error_mm=float(outcome.exit_error_mm),
                  **{k: bool(outcome.subtasks.get(k, False)) for k in SUBTASKS})
    if not record['regeneration']:
        record['trajectories'] = None
        return record
    data = _training(path)
    pair = markers[job['test_pair']]
    curves = {}
    for task in TASKS:
        n_pts = skill.dmps[task].params.n_pts
        T, P, Q = data.needle[task]
        _, P0, Q0 = resample_poses(T, P, Q, n_pts=n_pts or len(T))
        _, P1, Q1 = skill.rollout(task, pair)
        for name, value in regeneration_errors((P0, Q0), (P1, Q1)).items():
            record[f'{task}_{name}'] = value
        curves[f'demo_{task}'] = np.hstack((P0, Q0))
        curves[f'rollout_{task}'] = np.hstack((P1, Q1))
        executed = outcome.executed.get(task)
        if executed is not None and len(executed[0]) > 1:
            poses = np.asarray(executed[1], float)
            record[f'{task}_exec_traj_mm'] = trajectory_error(P0, poses[:, :3])['mean_mm']
            curves[f'exec_{task}'] = poses
        else:
            record[f'{task}_exec_traj_mm'] = _nan()
            curves[f'exec_{task}'] = np.zeros((0, 7))
    if job.get('trajectories'):
        target = out / job['trajectories']
        target.parent.mkdir(parents=True, exist_ok=True)
        save_archive(target, curves, TRAJECTORIES_FORMAT, TRAJECTORIES_FORMAT_VERSION,
                     compressed=True)
    return record
