"""
``suture-lfd study --via-ros``: the study's throws executed by the node processes.

Each throw job runs the ``simulator`` node (the job's test phantom, its scene seed, the test pair)
and the ``executor`` node (the skill the study learnt, saved with
:meth:`suture_lfd.skill.ThrowSkill.save` and passed as ``skill``; ``pair``: execute the test
pair at start-up and exit; ``use_sim_time``) as subprocesses, the installed executables next to
``sys.executable``. This module never imports rclpy: the executor writes the throw's outcome to
its ``result_file`` (JSON), which :meth:`RosThrows.execute` reads back as a
:class:`RosOutcome` with the attributes of :class:`suture_lfd.skill.executor.ThrowOutcome` that a
study record is filled from (score, subtasks, failure, duration, entry and exit errors, the
needle poses measured during ii and iv).

Isolation and clean-up: every worker process leases a ROS domain of its own
(:class:`DomainLease`: an exclusive lock file per domain id in the temporary folder, tried from
an offset derived from the study's own ``ROS_DOMAIN_ID``, or its pid, skipping the study's own
domain) and starts its nodes with ``ROS_DOMAIN_ID`` set to it and
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``. Each node runs in a process group of its own and gets
SIGTERM when the worker dies; the nodes of a throw are stopped (SIGINT, SIGTERM, SIGKILL to
the group) when it ends, when it fails, on Ctrl-C, and when a worker is terminated (SIGTERM).

One pair of processes per throw: a fresh simulator takes the job's seed, as the in-process
scene does, and starts from a clean scene; its start-up costs a few seconds of a throw that
takes about 20 s at the simulator's pace (``real_time_factor`` 2 at most, the live simulator's
2 ms physics step). A node that fails, exits without an outcome or overruns ``wall_timeout``
raises :class:`RosThrowError`, which the study stores as the throw's ``error`` (with the reason
and the nodes' log files, kept under ``ros/logs/`` of the output folder; the logs of good throws
are deleted) and runs again on resume. ``ros/results/`` keeps each throw's outcome as the
executor wrote it (without the pose samples).
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import errno
import fcntl
import json
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
from types import FrameType
from typing import TYPE_CHECKING, Any

import numpy as np
from sim_bridge.common.processes import follow_parent, kill_group, popen, stop_group
from sim_bridge.common.vocabulary import SUBTASKS
from suture_lfd.errors import RosThrowError

if TYPE_CHECKING:
    from sim_bridge.scene.phantom import MarkerPair
    from suture_lfd.skill import ThrowSkill
    from suture_lfd.study.records import ThrowJob

MAX_DOMAIN_ID = 101   # highest ROS domain id whose ports stay clear of Linux's ephemeral range


@dataclass(frozen=True)
class RosSettings:
    """
    How ``--via-ros`` runs the nodes of a throw.

    Attributes
    ----------
    domain_base : int
        Where the workers start looking for a free ROS domain id (the study's own domain id, or
        its pid).
    avoid_domain : int or None
        The study's own ``ROS_DOMAIN_ID``: never leased to a worker.
    real_time_factor : float
        The simulator's pace cap (simulated s per wall s). The executor commands at ``rate`` Hz
        of wall time, so at 2 it commands every 20 ms of simulation time, the in-process
        study's control period.
    rate : float
        The executor's command rate (Hz, wall time).
    stale_timeout : float
        The executor's watchdog: simulation seconds an arm may stay silent while ``/clock``
        advances (1 s: generous for a loaded machine, still far below a throw).
    clock_timeout : float
        Wall seconds without ``/clock`` and ``measured_cp`` before the executor takes the
        simulator for dead.
    prepare_timeout : float
        Wall seconds the executor may wait for the simulator's topics and homed arms.
    wall_timeout : float
        Wall seconds a whole throw (start-up included) may take before its nodes are stopped.
    stop_timeout : float
        Wall seconds a node gets to exit after SIGINT before it is terminated.

    """

    domain_base: int = 0
    avoid_domain: int | None = None
    real_time_factor: float = 2.0
    rate: float = 100.0
    stale_timeout: float = 1.0
    clock_timeout: float = 20.0
    prepare_timeout: float = 180.0
    wall_timeout: float = 900.0
    stop_timeout: float = 10.0


def study_settings(environ: Mapping[str, str] | None = None) -> 'RosSettings':
    """Return the :class:`RosSettings` of a study started in this process."""
    environ = os.environ if environ is None else environ
    text = environ.get('ROS_DOMAIN_ID', '').strip()
    own = int(text) if text.isdigit() else None
    return RosSettings(domain_base=own if own is not None else os.getpid(), avoid_domain=own)


def executable(name: str) -> Path:
    """Return the path of a node executable installed next to ``sys.executable``."""
    path = Path(sys.executable).parent / name
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise FileNotFoundError(f'the {name!r} node executable is not installed next to '
                                f'{sys.executable} (./suture-lfd setup installs it)')
    return path


def check_executables() -> None:
    """Raise FileNotFoundError unless both node executables are installed."""
    for name in ('simulator', 'executor'):
        executable(name)


class DomainLease:
    """
    An exclusive ROS domain id for this process, held while the object lives.

    Each id has a lock file in ``<temporary folder>/suture-lfd-ros-domains``; the lock
    (``flock``) is released when this process exits, however it ends.

    Parameters
    ----------
    base : int
        Ids are tried from ``base % MAX_DOMAIN_ID + 1`` on, wrapping around.
    avoid : int or None
        An id never taken (the caller's own domain).

    """

    def __init__(self, base: int, avoid: int | None = None) -> None:
        folder = Path(tempfile.gettempdir()) / 'suture-lfd-ros-domains'
        folder.mkdir(exist_ok=True)
        self.domain_id = 0  # set below to the leased id (or no lease: an error)
        self._fd: int | None = None
        for k in range(MAX_DOMAIN_ID):
            candidate = (int(base) + k) % MAX_DOMAIN_ID + 1
            if candidate == avoid:
                continue
            fd = os.open(folder / f'{candidate}.lock', os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
                    continue
                raise
            self.domain_id, self._fd = candidate, fd
            return
        raise RuntimeError(f'no free ROS domain id in 1..{MAX_DOMAIN_ID} (all leased)')

    def release(self) -> None:
        """Give the id back."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


class NodeProcess:
    """A node executable in a process group of its own, its output in a log file."""

    def __init__(self, argv: Sequence[Any], log_path: str | Path, env: Mapping[str, str]
                 ) -> None:
        self.argv = [str(a) for a in argv]
        self.log_path = Path(log_path)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, 'w') as log:
            self.popen = popen(self.argv, stdout=log, stderr=subprocess.STDOUT,
                               stdin=subprocess.DEVNULL, env=env)

    def poll(self) -> int | None:
        """Return the exit code, or None while it runs."""
        return self.popen.poll()

    def tail(self, lines: int = 6, width: int = 400) -> str:
        """Return the last lines of the node's log (one string)."""
        try:
            text = self.log_path.read_text(errors='replace').strip().splitlines()
        except OSError:
            return ''
        return ' | '.join(line[:width] for line in text[-lines:])

    def stop(self, timeout: float = 10.0) -> int | None:
        """Stop the whole group (SIGINT, then SIGTERM, then SIGKILL); return the exit code."""
        return stop_group(self.popen, timeout)

    def kill_group(self) -> None:
        """SIGKILL whatever is left of the group (nothing may outlive its leader)."""
        kill_group(self.popen)


@dataclass(frozen=True, eq=False)
class RosOutcome:
    """The outcome of a throw the nodes executed (the fields a study record takes)."""

    score: float
    subtasks: dict[str, bool]
    failure: str
    duration: float
    entry_error_mm: float
    exit_error_mm: float
    executed: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    result: dict[str, Any] = field(default_factory=dict)


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


def outcome_from_result(result: dict[str, Any]) -> RosOutcome:
    """
    Return the :class:`RosOutcome` of the executor's ``result_file`` contents.

    Raises
    ------
    RosThrowError
        If the executor stopped the throw (a silent or faulty arm, a dead simulator, a stop
        request) or reported no outcome: the nodes, not the skill, decided it.

    """
    state = result.get('state')
    if result.get('planning_error') is not None:
        # no reachable grasp carries the needle along the rollouts: as in-process, score 0
        return RosOutcome(score=0.0, subtasks=dict.fromkeys(SUBTASKS, False),
                          failure=f'unreachable: {result["planning_error"]}', duration=0.0,
                          entry_error_mm=math.nan, exit_error_mm=math.nan, result=result)
    if state not in ('done', 'failed') or (state == 'failed' and result.get('duration') is None):
        raise RosThrowError(f'executor node: throw {state}: {result.get("reason")}')
    executed = {}
    for task, data in (result.get('executed') or {}).items():
        poses = np.asarray(data.get('poses') or [], float).reshape(-1, 7)
        executed[task] = (np.asarray(data.get('t') or [], float), poses)
    subtasks = result.get('subtasks') or {}
    failure = result.get('failure')
    if result.get('score') is None:
        failure = f'no score from the simulator ({result.get("reason")})'
    elif state == 'failed' and not failure:
        failure = result.get('reason') or 'failed'
    return RosOutcome(score=_number(result.get('score')) if result.get('score') is not None
                      else 0.0,
                      subtasks={k: bool(subtasks.get(k, False)) for k in SUBTASKS},
                      failure=failure or '', duration=_number(result.get('time_s')),
                      entry_error_mm=_number(result.get('entry_error_mm')),
                      exit_error_mm=_number(result.get('exit_error_mm')), executed=executed,
                      result=result)


def _file_name(key: str) -> str:
    return key.split('/', 1)[-1].replace('/', '_')


class RosThrows:
    """
    Executes a worker's throws through node processes (one per worker process).

    Parameters
    ----------
    settings : RosSettings
    out : str or Path
        The study's output folder (skills, logs and outcomes go to its ``ros/`` folder).
    timeout : float
        Longest simulated time (s) of one throw (the executor's ``timeout``).
    tissue : str
        Needle-in-tissue preset (``config/realism_tissue.yaml``) both nodes get as their
        ``tissue`` parameter: the simulator runs it, the executor watches the grasp for it
        (``'none'``: the parameter is not passed, the nodes run as without it).

    """

    def __init__(self, settings: RosSettings, out: str | Path, timeout: float,
                 tissue: str = 'none') -> None:
        self.settings = settings
        self.folder = Path(out) / 'ros'
        self.timeout = float(timeout)
        self.tissue = tissue
        self._lease: DomainLease | None = None
        self._markers: dict[str, dict[str, MarkerPair]] = {}
        self._skills: dict[Path, ThrowSkill] = {}
        self._running: list[NodeProcess] = []
        self._previous_sigterm: Any = None

    @property
    def domain_id(self) -> int:
        """This worker's ROS domain id (leased on first use)."""
        if self._lease is None:
            self._lease = DomainLease(self.settings.domain_base, self.settings.avoid_domain)
        return self._lease.domain_id

    def install_sigterm(self, parent: int | None = None) -> None:
        """
        In a worker process: stop the running nodes, then exit, on SIGTERM.

        With ``parent`` (the pid of the study's process), the SIGTERM also comes when that
        process dies, even by SIGKILL.
        """
        def handler(signum: int, frame: FrameType | None) -> None:
            self.stop_all()
            raise SystemExit(128 + signum)

        self._previous_sigterm = signal.signal(signal.SIGTERM, handler)
        if parent is not None:
            follow_parent(parent)

    def environment(self) -> dict[str, str]:
        """Return the nodes' environment: this worker's domain, DDS on this machine only."""
        env = dict(os.environ)
        env.update(ROS_DOMAIN_ID=str(self.domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   PYTHONUNBUFFERED='1')
        env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
        return env

    def markers(self, phantom: str) -> dict[str, 'MarkerPair']:
        """Return the marker pairs of a phantom (what the simulator node builds)."""
        if phantom not in self._markers:
            from sim_bridge.scene.scene_config import load_scene_config

            self._markers[phantom] = load_scene_config().build_phantom(phantom).markers
        return self._markers[phantom]

    def skill_file(self, skill: 'ThrowSkill', name: str) -> Path:
        """Save a learnt skill once as ``ros/skills/<name>.npz``; return its path."""
        path = self.folder / 'skills' / f'{name}.npz'
        if self._skills.get(path) is not skill or not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f'{path.stem}.{os.getpid()}.part.npz')
            skill.save(tmp)
            os.replace(tmp, path)
            self._skills[path] = skill
        return path

    def execute(self, job: 'ThrowJob', skill: 'ThrowSkill') -> RosOutcome:
        """
        Execute a throw job's skill on its test pair through the node processes.

        Parameters
        ----------
        job : suture_lfd.study.records.ThrowJob
            A study throw job.
        skill : suture_lfd.skill.ThrowSkill
            The skill learnt from the job's training demonstration.

        Returns
        -------
        RosOutcome

        Raises
        ------
        RosThrowError
            If the nodes did not carry the throw out; the message says why and where the logs
            are.

        """
        s = self.settings
        name = _file_name(job.key)
        skill_path = self.skill_file(skill, f'{job.method}_{job.subject}_'
                                            f'{job.train_pair}')
        logs = self.folder / 'logs'
        result_path = self.folder / 'results' / f'{name}.json'
        live = self.folder / 'results' / f'{name}.{os.getpid()}.live.json'
        live.parent.mkdir(parents=True, exist_ok=True)
        live.unlink(missing_ok=True)
        env = self.environment()
        started = time.monotonic()
        tissue = [] if self.tissue == 'none' else ['-p', f'tissue:={self.tissue}']
        sim = executor = None
        try:
            sim = self._start(NodeProcess(
                [executable('simulator'), '--ros-args', '-p', f'phantom:={job.test_phantom}',
                 '-p', f'seed:={int(job.seed)}', '-p', f'target_pair:={job.test_pair}',
                 '-p', f'real_time_factor:={s.real_time_factor:g}', '-p', 'footpedals:=false',
                 # a batch run: arms start at home and power up at once, as in-process
                 '-p', 'power_up_time:=0.0', '-p', 'start_at_home:=true',
                 '-p', 'tf_rate:=0.0', '-p', 'visualization_rate:=0.0', '-p',
                 'camera_rate:=0.0', *tissue], logs / f'{name}.simulator.log', env))
            executor = self._start(NodeProcess(
                [executable('executor'), '--ros-args', '-p', f'skill:={skill_path}', '-p',
                 f'pair:={job.test_pair}', '-p', 'use_sim_time:=true', '-p',
                 f'result_file:={live}', '-p', f'rate:={s.rate:g}', '-p',
                 f'stale_timeout:={s.stale_timeout:g}', '-p',
                 f'clock_timeout:={s.clock_timeout:g}', '-p',
                 f'prepare_timeout:={s.prepare_timeout:g}', '-p',
                 f'timeout:={self.timeout:g}', *tissue], logs / f'{name}.executor.log', env))
            while executor.poll() is None:
                if sim.poll() is not None:
                    raise RosThrowError(f'simulator node exited with code {sim.poll()} during '
                                        f'the throw: {sim.tail()}')
                if time.monotonic() - started > s.wall_timeout:
                    raise RosThrowError(f'no outcome after {s.wall_timeout:g} s of wall time '
                                        f'(executor: {executor.tail(2)})')
                time.sleep(0.1)
            if not live.exists():
                raise RosThrowError(f'executor node exited with code {executor.poll()} without '
                                    f'an outcome: {executor.tail()}')
            result = json.loads(live.read_text())
            outcome = outcome_from_result(result)
        except RosThrowError as exc:
            raise RosThrowError(f'{exc} (logs: {logs / name}.*.log)') from None
        finally:
            for proc in (executor, sim):
                if proc is not None:
                    proc.stop(s.stop_timeout)
                    self._running.remove(proc)
        kept = {k: v for k, v in result.items() if k != 'executed'}
        tmp = result_path.with_name(result_path.stem + '.part.json')
        tmp.write_text(json.dumps({'key': job.key, 'domain_id': self.domain_id,
                                   'wall_s': time.monotonic() - started, **kept},
                                  sort_keys=True) + '\n')
        os.replace(tmp, result_path)
        live.unlink(missing_ok=True)
        for proc in (sim, executor):
            proc.log_path.unlink(missing_ok=True)
        return outcome

    def _start(self, proc: NodeProcess) -> NodeProcess:
        self._running.append(proc)
        return proc

    def stop_all(self) -> None:
        """Stop every node this worker is running (hard: the worker is going away)."""
        for proc in list(self._running):
            try:
                os.killpg(proc.popen.pid, signal.SIGINT)
            except (ProcessLookupError, PermissionError):
                pass
        deadline = time.monotonic() + 3.0
        for proc in list(self._running):
            try:
                proc.popen.wait(max(deadline - time.monotonic(), 0.0))
            except subprocess.TimeoutExpired:
                pass
            proc.kill_group()

    def close(self) -> None:
        """Stop the nodes and give the domain id back."""
        self.stop_all()
        self._running.clear()
        if self._lease is not None:
            self._lease.release()
            self._lease = None
