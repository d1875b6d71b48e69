"""
The study's jobs and records as types: what a job may touch and what its record holds.

A job says what to compute (:class:`DemoJob`, :class:`ThrowJob`, with the robot's hidden
errors of a physical-mode job in :class:`RobotErrors`); its record (:class:`DemoRecord`,
:class:`ThrowRecord`) is what :mod:`suture_lfd.study.jobs` returns and
:mod:`suture_lfd.study.store` keeps. A record's first fields are its CSV file's columns, in
order (:func:`columns`: ``demos.csv``, ``throws.csv``); the fields after them are the job's
bookkeeping (``id``, ``key``, paths, order) and the run's (``error``, ``wall_s``, ``cpu_s``, the
worker's ``code`` digest).

Paths in jobs and records are relative to the study's output folder. Units: times s
(simulated, except ``wall_s`` and ``cpu_s``), position errors mm, orientation errors deg. A
value that is not a finite number is stored as None (JSON has no NaN), so a record read back
from the store equals the one stored.

Size: the two jobs and their two records are one schema (a record's fields are its job's plus
its results, read and written in one place); split it when a third kind of job comes.
"""

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
import math
from typing import Any, ClassVar, Protocol, TypeVar


class RunRecord(Protocol):
    """
    What the job runner and the store need of a record (a frozen dataclass).

    :class:`DemoRecord` and :class:`ThrowRecord` are the study's; the runner's own tests use
    records of their own kind.
    """

    __dataclass_fields__: ClassVar[dict[str, Any]]

    @property
    def id(self) -> str:
        """The job's ``id``."""

    @property
    def key(self) -> str:
        """The job's name in its run."""

    @property
    def error(self) -> str:
        """Why the job raised ('' when it did not)."""

    @property
    def code(self) -> str | None:
        """The code digest of the Dask worker that computed it."""

    @property
    def worker(self) -> str | None:
        """The address of that worker."""


class RunJob(Protocol):
    """What the job runner needs of a job (a frozen, picklable dataclass)."""

    __dataclass_fields__: ClassVar[dict[str, Any]]

    @property
    def id(self) -> str:
        """What decides its result (:mod:`suture_lfd.study.keys`)."""

    @property
    def key(self) -> str:
        """Its name in its run."""

    def failed(self, error: str) -> Any:
        """Return its record stored as an error."""


#: Metadata of a record field that is a column of the record's CSV file.
_COLUMN = {'column': True}


def _column(default: Any = None) -> Any:
    return field(default=default, metadata=_COLUMN)


@dataclass(frozen=True)
class RobotErrors:
    """
    The hidden kinematic errors of a physical-mode job's robot.

    Attributes
    ----------
    error_level : float
        Error class (mm) of the arms' kinematics; 0 is perfect kinematics.
    error_seed : int
        Seed of the drawn errors (a robot's errors last its life: one robot per subject
        and phantom).
    correction : bool
        A throw corrects its plan from what the robot perceives (demonstrations: unused).
    arm_realism : str
        The arm model: ``'static'`` (offsets of class ``error_level``) or a preset of
        ``config/realism_arm.yaml`` (``'dvrk'``; ``error_level`` then unused).
    arm_levels : tuple of (str, float)
        Per-effect levels overriding the preset's (``(('servo_level', 0.0),)``).
    camera : str or None
        The endoscope's preset of ``config/realism_camera.yaml`` (``'none'``: an ideal
        camera); None: the study's (``--camera``).

    """

    error_level: float
    error_seed: int
    correction: bool = False
    arm_realism: str = 'static'
    arm_levels: tuple[tuple[str, float], ...] = ()
    camera: str | None = None


@dataclass(frozen=True)
class DemoJob:
    """
    One subject demonstrating the throw on one pair (a ``demo`` job).

    Attributes
    ----------
    key : str
        The job's name in its run (``demo/<subject>/<pair>``, prefixed in sweeps and
        physical mode).
    subject, group : str
        The demonstrating subject and its group (``experienced``, ``naive``).
    phantom, pair : str
        Where the throw is demonstrated.
    seed : int
        Scene seed.
    bag, segments : str
        Where the demonstration's bag and segment file go (relative to the output folder).
    order : int
        The pair's place in the study (report order).
    next_pair : str or None
        The pair demonstrated after this one (the subject's hand-over), None for the last.
    id : str
        Digest of everything that decides the result (:mod:`suture_lfd.study.keys`).
    cohort_seed : int or None
        The cohort's seed (None: the study's).
    physical : RobotErrors or None
        Demonstrated on a robot with these hidden errors (None: ground truth).
    folder : str or None
        The physical-mode variant's folder.
    tissue : str or None
        The needle-in-tissue preset of its simulation (a sweep's cell); None: the study's
        (``--tissue``).

    """

    key: str
    subject: str
    group: str
    phantom: str
    pair: str
    seed: int
    bag: str
    segments: str
    order: int = 0
    next_pair: str | None = None
    id: str = ''
    cohort_seed: int | None = None
    physical: RobotErrors | None = None
    folder: str | None = None
    tissue: str | None = None
    kind: str = 'demo'

    def failed(self, error: str) -> 'DemoRecord':
        """Return this job's record stored as an error (it runs again in a later run)."""
        return DemoRecord.of(self, error=error)


@dataclass(frozen=True)
class ThrowJob:
    """
    A skill learnt on one pair executed on another (``throw``, or ``held_out`` geometry).

    Attributes
    ----------
    key : str
        The job's name in its run (``throw/<method>/<subject>/<train>/<test>``).
    subject, group, method : str
        Whose demonstration, and the learning method.
    train_phantom, train_pair, test_phantom, test_pair : str
        Where the skill was demonstrated and where it is executed.
    seed : int
        Scene seed.
    demo_key : str
        The key of the demonstration it learns from.
    kind : str
        ``'throw'`` or ``'held_out'`` (a held-out geometry, records kept apart).
    train_order, test_order : int
        The pairs' places in the study (report order).
    trajectories : str or None
        Where a regeneration saves its needle curves (None: not saved).
    test_key : str or None
        A held-out phantom's geometry key (its simulations are cached under it).
    test_config : dict or None
        A held-out phantom's configuration (JSON form of ``PhantomConfig``).
    id : str
        Digest of everything that decides the result (:mod:`suture_lfd.study.keys`).
    segments : str or None
        The demonstration's segment file (set by ``attach_demos``; None: it failed).
    demo_time_s : float or None
        The demonstration's full-throw time.
    blocked : str or None
        Why the demonstration is missing (stored as an error, run again later).
    cell : str or None
        A sweep's cell.
    dmp : dict or None
        DMP parameters that differ from ``config/dmp.yaml``, ``{task: {key: value}}``.
    cohort_seed : int or None
        The cohort's seed (None: the study's).
    physical : RobotErrors or None
        Executed on a robot with these hidden errors (None: ground truth).
    folder : str or None
        The physical-mode variant's folder.
    tissue : str or None
        The needle-in-tissue preset of its simulation (a sweep's cell); None: the study's
        (``--tissue``).

    """

    key: str
    subject: str
    group: str
    method: str
    train_phantom: str
    train_pair: str
    test_phantom: str
    test_pair: str
    seed: int
    demo_key: str
    kind: str = 'throw'
    train_order: int = 0
    test_order: int = 0
    trajectories: str | None = None
    test_key: str | None = None
    test_config: dict[str, Any] | None = None
    id: str = ''
    segments: str | None = None
    demo_time_s: float | None = None
    blocked: str | None = None
    cell: str | None = None
    dmp: dict[str, dict[str, Any]] | None = None
    cohort_seed: int | None = None
    physical: RobotErrors | None = None
    folder: str | None = None
    tissue: str | None = None

    def failed(self, error: str) -> 'ThrowRecord':
        """Return this job's record stored as an error (it runs again in a later run)."""
        return ThrowRecord.of(self, error=error)


R = TypeVar('R', 'DemoRecord', 'ThrowRecord')


@dataclass(frozen=True)
class DemoRecord:
    """
    A demonstration's record: the columns of ``demos.csv`` in order, then its job's and run's.

    Attributes
    ----------
    attempts : int
        Throws the subject needed (failed ones repeated).
    ok : bool
        The demonstration succeeded and was segmented.
    demo_score : float
        Its score (1 a complete throw).
    time_s : float or None
        Its full-throw time.
    failure : str
        Why it failed ('' when it did not).
    t_i, t_ii, t_iii, t_iv, t_v : float or None
        Segmented subtask durations.
    error : str
        The job raised (the message; '' when it did not); such a record runs again.
    wall_s, cpu_s : float or None
        The job's wall time and its process's CPU time.
    code, worker : str or None
        The code digest and address of the Dask worker that computed it.

    The other fields are the job's (:class:`DemoJob`).

    """

    subject: str = _column('')
    group: str = _column('')
    phantom: str = _column('')
    pair: str = _column('')
    seed: int = _column(0)
    attempts: int = _column(0)
    ok: bool = _column(False)
    demo_score: float | None = _column(0.0)
    time_s: float | None = _column()
    failure: str | None = _column('')
    t_i: float | None = _column()
    t_ii: float | None = _column()
    t_iii: float | None = _column()
    t_iv: float | None = _column()
    t_v: float | None = _column()
    bag: str = _column('')
    segments: str | None = _column()
    id: str = ''
    key: str = ''
    kind: str = 'demo'
    order: int = 0
    next_pair: str | None = None
    cohort_seed: int | None = None
    physical: RobotErrors | None = None
    folder: str | None = None
    tissue: str | None = None
    error: str = ''
    wall_s: float | None = None
    cpu_s: float | None = None
    code: str | None = None
    worker: str | None = None

    @classmethod
    def of(cls, job: DemoJob, **values: Any) -> 'DemoRecord':
        """Return the record of ``job`` with ``values`` (result fields) set."""
        return _of(cls, job, values)


@dataclass(frozen=True)
class ThrowRecord:
    """
    An executed throw's record: the columns of ``throws.csv`` in order, then its job's and run's.

    Attributes
    ----------
    regeneration : bool
        Executed on the pair it was learnt on (Table II).
    score : float or None
        The throw's score (1 complete).
    i, ii, iii, iv, v : bool
        The subtasks that succeeded.
    failure : str or None
        Why it failed ('' when it did not).
    time_s : float or None
        Simulated full-throw time.
    entry_error_mm, exit_error_mm : float or None
        Distances of the needle's entry and exit from their markers.
    ii_start_mm .. iv_traj_deg : float or None
        A regeneration's Table II errors of the rolled-out needle trajectory against the
        demonstrated one (start, goal, mean along the DTW path; position mm, orientation deg).
    ii_exec_traj_mm, iv_exec_traj_mm : float or None
        The same for the executed needle trajectory (position, mm).
    replay : str or None
        The throw's replay file (None: executed by the nodes, not sampled).
    replay_bytes : int or None
        That file's size.
    error : str
        The job raised (the message; '' when it did not); such a record runs again.
    wall_s, cpu_s : float or None
        The job's wall time and its process's CPU time.
    code, worker : str or None
        The code digest and address of the Dask worker that computed it.
    slips : list of dict or None
        The needle's slips in the jaw (``t``, ``arm``, ``angle`` rad, ``slide`` m,
        ``in_tissue``), with the needle-in-tissue realism on; None without any.

    The other fields are the job's (:class:`ThrowJob`).

    """

    subject: str = _column('')
    group: str = _column('')
    method: str = _column('')
    train_phantom: str = _column('')
    train_pair: str = _column('')
    test_phantom: str = _column('')
    test_pair: str = _column('')
    regeneration: bool = _column(False)
    seed: int = _column(0)
    score: float | None = _column()
    i: bool = _column(False)
    ii: bool = _column(False)
    iii: bool = _column(False)
    iv: bool = _column(False)
    v: bool = _column(False)
    failure: str | None = _column()
    time_s: float | None = _column()
    demo_time_s: float | None = _column()
    entry_error_mm: float | None = _column()
    exit_error_mm: float | None = _column()
    ii_start_mm: float | None = _column()
    ii_goal_mm: float | None = _column()
    ii_traj_mm: float | None = _column()
    ii_start_deg: float | None = _column()
    ii_goal_deg: float | None = _column()
    ii_traj_deg: float | None = _column()
    iv_start_mm: float | None = _column()
    iv_goal_mm: float | None = _column()
    iv_traj_mm: float | None = _column()
    iv_start_deg: float | None = _column()
    iv_goal_deg: float | None = _column()
    iv_traj_deg: float | None = _column()
    ii_exec_traj_mm: float | None = _column()
    iv_exec_traj_mm: float | None = _column()
    id: str = ''
    key: str = ''
    kind: str = 'throw'
    train_order: int = 0
    test_order: int = 0
    demo_key: str = ''
    trajectories: str | None = None
    segments: str | None = None
    test_key: str | None = None
    blocked: str | None = None
    cell: str | None = None
    dmp: dict[str, dict[str, Any]] | None = None
    cohort_seed: int | None = None
    physical: RobotErrors | None = None
    folder: str | None = None
    tissue: str | None = None
    replay: str | None = None
    replay_bytes: int | None = None
    error: str = ''
    wall_s: float | None = None
    cpu_s: float | None = None
    code: str | None = None
    worker: str | None = None
    slips: list[dict[str, Any]] | None = None

    @classmethod
    def of(cls, job: ThrowJob, **values: Any) -> 'ThrowRecord':
        """Return the record of ``job`` with ``values`` (result fields) set."""
        return _of(cls, job, values)


Job = DemoJob | ThrowJob
Record = DemoRecord | ThrowRecord


def _of(cls: type[R], job: Job, values: Mapping[str, Any]) -> R:
    names = {f.name for f in fields(cls)}
    # what a record has no field for (a held-out phantom's configuration) stays in the job
    shared = {f.name: getattr(job, f.name) for f in fields(job) if f.name in names}
    return cls(**{**shared, **values})


def columns(cls: type[DemoRecord] | type[ThrowRecord]) -> tuple[str, ...]:
    """Return the CSV columns of a record type: its first fields, in order."""
    return tuple(f.name for f in fields(cls) if f.metadata.get('column'))


def _finite(value: Any) -> Any:
    """Replace NaN and infinities (not JSON) by None, recursively; numpy scalars by Python."""
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    item = getattr(type(value), 'item', None)  # a numpy scalar
    if item is not None and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def to_json(item: RunJob | RunRecord) -> dict[str, Any]:
    """Return a job or record as a JSON-serialisable dict (non-finite numbers as None)."""
    return dict(_finite(asdict(item)))


def plan_json(job: Job) -> dict[str, Any]:
    """Return a job as a plan file lists it: the fields it sets (those that are not None)."""
    return {k: v for k, v in to_json(job).items() if v is not None}


def stored(record: R) -> R:
    """Return ``record`` as the store keeps it: non-finite numbers None, numpy scalars Python."""
    return record_from_json(to_json(record))  # type: ignore[return-value]


def record_from_json(data: Mapping[str, Any]) -> Record:
    """
    Return the record of a stored JSON object.

    Raises
    ------
    ValueError
        Not a study record of this format (no ``id``/``key``, an unknown ``kind`` or fields).

    """
    kind = data.get('kind')
    cls: type[DemoRecord] | type[ThrowRecord]
    if kind == 'demo':
        cls = DemoRecord
    elif kind in ('throw', 'held_out'):
        cls = ThrowRecord
    else:
        raise ValueError(f'a study record has kind demo, throw or held_out, got {kind!r}')
    if not data.get('id') or not data.get('key'):
        raise ValueError('a study record needs its id and key')
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f'a {kind} record has no fields {unknown}')
    values = dict(data)
    if values.get('physical') is not None:
        values['physical'] = RobotErrors(**values['physical'])
    return cls(**values)
