"""
``suture-lfd sweep SWEEP.yaml``: a grid of studies run as one job set, with a sweep report.

A sweep file names the study design, the seeds, the methods and the DMP hyper-parameters to
vary (keys of ``config/dmp.yaml``, for both learnt subtasks or one)::

    sweep:
      design: {quick: true}          # or subjects: 4, pairs: 2, phantoms: [synthetic]
      seeds: [0, 1]
      methods: [paper, pair_frame]
      dmp:
        n_bfs: [50, 100]             # both tasks (ii and iv)
        task_iv.alpha_y: [20.0, 25.0]  # one task
      tissue: [none, tissue]         # optional: needle-in-tissue presets
      physical:                      # optional: cells in physical mode
        error_level: [0, 1, 3, 5]    # mm class of the hidden kinematic errors
        correction: [true, false]    # the executor's correction on what it sees
        arm_realism: [static, dvrk]  # the arm model: static offsets or a realism preset
        servo_level: [0, 1]          # a level of the preset's effects (also calibration_level,
                                     # transmission_level, encoder_level, ecm_level,
                                     # intrinsics_level, jaw_level)
        camera: [none, dvrk]         # the endoscope's preset

The grid is every combination of the ``dmp``, ``tissue`` and ``physical`` values (a *cell*),
each studied with every seed and method. A cell with a ``physical`` value runs in physical mode
(:mod:`suture_lfd.study.physical`; ``error_level`` 3, ``correction`` true, ``arm_realism``
static and ``camera`` none unless swept; with an arm realism preset the static ``error_level``
is unused, and a static cell ignores the preset's levels): its demonstrations are its seed's
and robot's (level, arm model, camera, tissue) physical-mode ones, shared by every cell of that
seed and robot. A ``tissue`` preset other than ``none`` gives its cells their own
demonstrations too (the needle in tissue changes them). Demonstrations depend on nothing else
(the DMP hyper-parameters act when a skill
is learnt from a segment file: the segment file keeps the installed ``n_pts`` and a cell
resamples it to its own), so every cell of a seed shares that seed's demonstrations: a
2 x 2 sweep over two seeds records two sets of demonstrations, not eight.

All jobs (every seed's demonstrations, then every cell's throws) run as one job set on the
chosen ``--engine`` (:mod:`suture_lfd.study.engine`), stored in ``results.jsonl`` in the sweep
folder by job ``id`` (:mod:`suture_lfd.study.keys`): a sweep resumes, and reuses every stored
job it shares, as a study does; SIGINT and SIGTERM stop it as they stop a study. The
folder gets ``seed-<s>/`` (bags, segment files), ``cells/<cell>/seed-<s>/`` (a full study
report per cell and seed) and ``sweep.md`` / ``sweep.csv`` / ``sweep_<parameter>.png``:
generality, regeneration success and Table II errors against each swept parameter, mean and
seed-to-seed spread (standard deviation of the per-seed values).

Size: the sweep file's checks, the grid's plan (ground truth and physical mode), the cells'
records and the sweep report are one reading of the same grid; split them when a third mode of
cell comes.
"""

import argparse
from collections.abc import Mapping, Sequence
import copy
import csv
import dataclasses
import itertools
import json
import math
import os
from pathlib import Path
import sys
import time
from typing import IO, Any

import numpy as np
from sim_bridge.common.configfile import ConfigError, load_yaml
from sim_bridge.common.vocabulary import TASKS
from sim_bridge.realism.calibration import ARM_LEVELS, load_arm_realism
from sim_bridge.realism.endoscope import endoscope_preset
from suture_lfd.study import physical
from suture_lfd.study.engine import parse_engine
from suture_lfd.study.jobs import JobSettings
from suture_lfd.study.keys import demo_ids, with_ids
from suture_lfd.study.records import (
    DemoJob,
    DemoRecord,
    Record,
    RobotErrors,
    ThrowJob,
    ThrowRecord,
    plan_json,
)
from suture_lfd.study.run import (
    attach_demos,
    build_config,
    hashed_config,
    job_seed,
    ordered_records,
    plan_jobs,
    stored_note,
)
from suture_lfd.study.runner import Progress
from suture_lfd.study.signals import stop_on_signals
from suture_lfd.study.stages import Stage, run_job_stages
from suture_lfd.study.store import ResultStore, config_hash

SWEEP_FORMAT = 1
DESIGN_KEYS = ('quick', 'subjects', 'pairs', 'phantoms', 'cohort')
#: Columns of ``sweep.csv`` after the cell's parameters: (column, summary path, scale).
METRICS = (
    ('generality_experienced', ('generality', 'group_mean', 'experienced')),
    ('generality_naive', ('generality', 'group_mean', 'naive')),
    ('generality_overall', ('generality', 'group_mean', 'overall')),
    ('regeneration_success', ('regeneration', 'success')),
    ('ii_goal_mm', ('regeneration', 'errors', 'ii/pos/goal', 'mean')),
    ('ii_traj_mm', ('regeneration', 'errors', 'ii/pos/traj', 'mean')),
    ('iv_goal_mm', ('regeneration', 'errors', 'iv/pos/goal', 'mean')),
    ('iv_traj_mm', ('regeneration', 'errors', 'iv/pos/traj', 'mean')),
    ('ii_goal_deg', ('regeneration', 'errors', 'ii/ori/goal', 'mean')),
    ('iv_goal_deg', ('regeneration', 'errors', 'iv/ori/goal', 'mean')),
)
PLOTTED = ('generality_overall', 'regeneration_success', 'ii_goal_mm', 'iv_goal_mm')
#: Physical-mode keys of a sweep file (``sweep.physical``) and their value when not swept
#: (None: the arm realism preset's own level).
PHYSICAL_AXES: dict[str, Any] = {
    'error_level': 3.0, 'correction': True, 'arm_realism': 'static',
    **dict.fromkeys(ARM_LEVELS), 'camera': 'none'}
#: Top-level keys of a sweep file's ``sweep`` mapping.
SWEEP_KEYS = ('design', 'seeds', 'methods', 'dmp', 'tissue', 'physical')


@dataclasses.dataclass(frozen=True)
class Sweep:
    """
    A parsed sweep file.

    Attributes
    ----------
    design : dict
        Study options of the design (``quick``, ``subjects``, ``pairs``, ``phantoms``,
        ``cohort``).
    seeds : tuple of int
        Study seeds.
    methods : tuple of str
        Methods (empty: every registered one).
    axes : tuple of (str, tuple)
        Swept DMP parameters: ``('n_bfs', (50, 100))`` (both tasks) or
        ``('task_iv.alpha_y', (20.0, 25.0))``, in file order.

    """

    design: dict[str, Any]
    seeds: tuple[int, ...]
    methods: tuple[str, ...]
    axes: tuple[tuple[str, tuple[Any, ...]], ...]

    def cells(self) -> list[tuple[str, dict[str, Any]]]:
        """Return every cell as ``(name, {parameter: value})``, in grid order."""
        names = [a for a, _ in self.axes]
        out = []
        for values in itertools.product(*(v for _, v in self.axes)):
            point = dict(zip(names, values))
            name = ','.join(f'{k}={_text(v)}' for k, v in point.items()) or 'default'
            out.append((name.replace('/', '_'), point))
        return out


def _text(value: Any) -> str:
    return repr(value) if isinstance(value, float) else str(value)


def dmp_overrides(point: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Return a cell's DMP values as ``{task: {key: value}}`` (what a throw job carries)."""
    out: dict[str, dict[str, Any]] = {task: {} for task in TASKS}
    for name, value in point.items():
        if name in PHYSICAL_AXES or name == 'tissue':
            continue
        task, _, key = name.rpartition('.')
        for t in ([task[len('task_'):]] if task else TASKS):
            out[t][key] = value
    return {t: v for t, v in out.items() if v}


def load_sweep(path: str | Path) -> Sweep:
    """
    Read and check a sweep file.

    Raises
    ------
    ConfigError
        Naming the file, the key and what was expected.

    """
    from suture_lfd.dmp import DmpParams
    from suture_lfd.skill import METHODS

    path = str(path)
    data = load_yaml(path)
    if not isinstance(data, dict) or not isinstance(data.get('sweep'), dict):
        raise ConfigError(f'{path}: expected a mapping with the key "sweep"')
    body = data['sweep']
    unknown = sorted(set(body) - set(SWEEP_KEYS))
    if unknown:
        raise ConfigError(f'{path}: sweep.{unknown[0]}: unknown key (expected '
                          f'{", ".join(SWEEP_KEYS)})')
    design = body.get('design') or {}
    if not isinstance(design, dict) or set(design) - set(DESIGN_KEYS):
        bad = sorted(set(design) - set(DESIGN_KEYS)) if isinstance(design, dict) else ['']
        raise ConfigError(f'{path}: sweep.design{"." + bad[0] if bad[0] else ""}: expected a '
                          f'mapping with keys from {", ".join(DESIGN_KEYS)}')
    seeds = body.get('seeds', [0])
    if (not isinstance(seeds, list) or not seeds
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0
                       for s in seeds)):
        raise ConfigError(f'{path}: sweep.seeds: expected a non-empty list of integers >= 0, '
                          f'got {seeds!r}')
    methods = body.get('methods') or []
    if not isinstance(methods, list) or any(m not in METHODS for m in methods):
        raise ConfigError(f'{path}: sweep.methods: expected a list of methods from '
                          f'{sorted(METHODS)}, got {methods!r}')
    fields = {f.name: f.type for f in dataclasses.fields(DmpParams)}
    axes = []
    for name, values in (body.get('dmp') or {}).items():
        task, _, key = str(name).rpartition('.')
        if task not in ('', 'task_ii', 'task_iv') or key not in fields:
            raise ConfigError(f'{path}: sweep.dmp.{name}: not a DMP hyper-parameter (expected '
                              f'a key of config/dmp.yaml, {", ".join(fields)}, alone for both '
                              'tasks or as task_ii.<key> / task_iv.<key>)')
        if not isinstance(values, list) or not values:
            raise ConfigError(f'{path}: sweep.dmp.{name}: expected a non-empty list of values, '
                              f'got {values!r}')
        axes.append((str(name), tuple(values)))
    axes += _tissue_axis(path, body.get('tissue'))
    axes += _physical_axes(path, body.get('physical'))
    sweep = Sweep(dict(design), tuple(seeds), tuple(methods), tuple(axes))
    for _, point in sweep.cells():  # every value must make valid parameters
        try:
            _check_point(point)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f'{path}: sweep.dmp: {exc}') from exc
    return sweep


def _presets(path: str | Path, key: str, values: Any, off: str, kind: str,
             load: Any) -> tuple[str, ...]:
    """Return a swept list of preset names, each checked with ``load`` (``off``: none)."""
    if (not isinstance(values, list) or not values
            or not all(isinstance(v, str) for v in values)):
        raise ConfigError(f'{path}: sweep.{key}: expected a non-empty list of {off} or presets '
                          f'of {kind}, got {values!r}')
    for name in values:
        if name != off:
            try:
                load(name)
            except (ConfigError, ValueError) as exc:
                raise ConfigError(f'{path}: sweep.{key}: expected {off} or presets of {kind}, '
                                  f'got {name!r} ({exc})') from None
    return tuple(values)


def _tissue_axis(path: str | Path, values: Any) -> list[tuple[str, tuple[Any, ...]]]:
    """Return the swept needle-in-tissue presets of a sweep file (``sweep.tissue``)."""
    if values is None:
        return []
    from sim_bridge.realism.tissue_config import load_tissue_realism

    return [('tissue', _presets(path, 'tissue', values, 'none', 'config/realism_tissue.yaml',
                                load_tissue_realism))]


def _physical_axes(path: str | Path, section: Any) -> list[tuple[str, tuple[Any, ...]]]:
    """Return the swept physical-mode axes of a sweep file's ``physical`` section."""
    if section is None:
        return []
    if not isinstance(section, dict) or set(section) - set(PHYSICAL_AXES):
        bad = sorted(set(section) - set(PHYSICAL_AXES)) if isinstance(section, dict) else ['']
        raise ConfigError(f'{path}: sweep.physical{"." + bad[0] if bad[0] else ""}: expected a '
                          f'mapping with keys from {", ".join(PHYSICAL_AXES)}')
    axes: list[tuple[str, tuple[Any, ...]]] = []
    levels = section.get('error_level')
    if levels is not None:
        if (not isinstance(levels, list) or not levels
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           and math.isfinite(v) and v >= 0 for v in levels)):
            raise ConfigError(f'{path}: sweep.physical.error_level: expected a non-empty list '
                              f'of numbers >= 0 (mm class), got {levels!r}')
        axes.append(('error_level', tuple(float(v) for v in levels)))
    corrections = section.get('correction')
    if corrections is not None:
        if (not isinstance(corrections, list) or not corrections
                or not all(isinstance(v, bool) for v in corrections)):
            raise ConfigError(f'{path}: sweep.physical.correction: expected a non-empty list '
                              f'of true / false, got {corrections!r}')
        axes.append(('correction', tuple(corrections)))
    if 'arm_realism' in section:
        axes.append(('arm_realism', _presets(
            path, 'physical.arm_realism', section['arm_realism'], 'static',
            'config/realism_arm.yaml', load_arm_realism)))
    for key in ARM_LEVELS:
        values = section.get(key)
        if values is None:
            continue
        if 'arm_realism' not in section:
            raise ConfigError(f'{path}: sweep.physical.{key}: a level of the arm realism needs '
                              'sweep.physical.arm_realism (presets of config/realism_arm.yaml)')
        if (not isinstance(values, list) or not values
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           and math.isfinite(v) and v >= 0 for v in values)):
            raise ConfigError(f'{path}: sweep.physical.{key}: expected a non-empty list of '
                              f'numbers >= 0 (0: the effect off, 1: the preset), got {values!r}')
        axes.append((key, tuple(float(v) for v in values)))
    if 'camera' in section:
        axes.append(('camera', _presets(path, 'physical.camera', section['camera'], 'none',
                                        'config/realism_camera.yaml', endoscope_preset)))
    return axes


@dataclasses.dataclass(frozen=True)
class CellMode:
    """
    How a cell's jobs run, beside its DMP values.

    Attributes
    ----------
    tissue : str
        Needle-in-tissue preset (``'none'``: without).
    physical : RobotErrors or None
        The robot of a physical-mode cell (its error seed left 0: drawn per subject and
        phantom when planned); None: ground truth.

    """

    tissue: str = 'none'
    physical: RobotErrors | None = None

    def demo_folder(self) -> str:
        """Return the folder (``''`` or ending in ``/``) of the cell's demonstrations."""
        extra = f'tissue-{self.tissue}' if self.tissue != 'none' else ''
        if self.physical is None:
            return f'{extra}/' if extra else ''
        return f'physical/{self._robot(True)}/'

    def throw_folder(self) -> str:
        """Return the folder (``''`` or ending in ``/``) of the cell's throws in its own."""
        if self.physical is None:
            return ''
        return f'physical/{self._robot(self.physical.correction)}/'

    def _robot(self, correction: bool) -> str:
        p = self.physical
        assert p is not None
        name = physical.variant_name(p.error_level, True, p.arm_realism)
        name += ''.join(f'-{k}{v:g}' for k, v in p.arm_levels)
        name += f'-camera-{p.camera}' if p.camera is not None else ''
        name += f'-tissue-{self.tissue}' if self.tissue != 'none' else ''
        return name + ('' if correction else '-open')

    def _mark(self, job: Any, where: str, old: str) -> Any:
        """Return a planned physical-mode job moved from ``old`` to this cell's folders."""
        p = self.physical
        assert p is not None

        def moved(value: str | None, to: str = where) -> str | None:
            return value.replace(old, to, 1) if value and value.startswith(old) else value

        fields = {'key': moved(job.key), 'folder': moved(job.folder),
                  'physical': dataclasses.replace(job.physical, arm_levels=p.arm_levels,
                                                  camera=p.camera),
                  'tissue': self.tissue if self.tissue != 'none' else None}
        if isinstance(job, DemoJob):
            fields.update(bag=moved(job.bag), segments=moved(job.segments))
        else:
            fields.update(trajectories=moved(job.trajectories))
        return dataclasses.replace(job, **fields)

    def demos(self, demos: Sequence[DemoJob], seed: int) -> list[DemoJob]:
        """Return the cell's demonstrations made from a seed's ground-truth ones."""
        if self.physical is None:
            folder = self.demo_folder()
            return [dataclasses.replace(job, key=folder + job.key, bag=folder + job.bag,
                                        segments=folder + job.segments, tissue=self.tissue)
                    for job in demos] if folder else list(demos)
        p = self.physical
        planned, _ = physical.plan_physical(
            {'levels': [p.error_level], 'corrections': [True], 'arm_realism': p.arm_realism},
            demos, [], job_seed, seed)
        old = f'physical/{physical.variant_name(p.error_level, True, p.arm_realism)}/'
        return [self._mark(job, self.demo_folder(), old) for job in planned]

    def throws(self, throws: Sequence[ThrowJob], seed: int) -> list[ThrowJob]:
        """Return the cell's throws made from a seed's ground-truth ones."""
        if self.physical is None:
            folder = self.demo_folder()
            return [dataclasses.replace(job, demo_key=folder + job.demo_key,
                                        tissue=self.tissue) for job in throws] \
                if folder else list(throws)
        p = self.physical
        _, planned = physical.plan_physical(
            {'levels': [p.error_level], 'corrections': [p.correction],
             'arm_realism': p.arm_realism}, [], throws, job_seed, seed)
        old = f'physical/{physical.variant_name(p.error_level, p.correction, p.arm_realism)}/'
        old_demos = f'physical/{physical.variant_name(p.error_level, True, p.arm_realism)}/'
        out = []
        for job in planned:
            job = dataclasses.replace(job, demo_key=job.demo_key.replace(
                old_demos, self.demo_folder(), 1))
            out.append(self._mark(job, self.throw_folder(), old))
        return out


def cell_mode(point: Mapping[str, Any]) -> CellMode:
    """Return how a cell (``{parameter: value}``) runs: its tissue and, in physical mode, robot."""
    tissue = str(point.get('tissue', 'none'))
    if not any(k in point for k in PHYSICAL_AXES):
        return CellMode(tissue)
    realism = str(point.get('arm_realism', PHYSICAL_AXES['arm_realism']))
    # a preset's robot has no static class; a static robot no preset levels
    level = float(point.get('error_level', PHYSICAL_AXES['error_level'])) \
        if realism == 'static' else 0.0
    levels = () if realism == 'static' else tuple(
        (k, float(point[k])) for k in ARM_LEVELS if point.get(k) is not None)
    camera = str(point.get('camera', PHYSICAL_AXES['camera']))
    return CellMode(tissue, RobotErrors(
        error_level=level, error_seed=0,
        correction=bool(point.get('correction', PHYSICAL_AXES['correction'])),
        arm_realism=realism, arm_levels=levels, camera=None if camera == 'none' else camera))


def _check_point(point: Mapping[str, Any]) -> None:
    from suture_lfd.dmp import load_dmp_params

    for task, values in dmp_overrides(point).items():
        dataclasses.replace(load_dmp_params(task=task), **values)


def _study_args(sweep: Sweep, seed: int) -> argparse.Namespace:
    d = sweep.design
    phantoms = d.get('phantoms')
    return argparse.Namespace(
        seed=int(seed), quick=bool(d.get('quick', False)), subjects=d.get('subjects'),
        pairs=d.get('pairs'), cohort=d.get('cohort'), via_ros=False,
        phantoms=','.join(phantoms) if isinstance(phantoms, list) else phantoms,
        methods=','.join(sweep.methods) if sweep.methods else None)


def plan_sweep(sweep: Sweep) -> tuple[dict[str, Any], list[DemoJob], list[ThrowJob]]:
    """
    Return the sweep's configuration and jobs.

    Returns
    -------
    config : dict
        ``studies`` (seed -> study configuration), ``cells`` (name -> parameters), ``axes``.
    demos : list of DemoJob
    throws : list of ThrowJob
        Study jobs with keys, paths and seeds of the sweep: ``seed-<s>/demo/...`` (in physical
        mode ``seed-<s>/physical/level-<L>/demo/...``) and ``<cell>/seed-<s>/throw/...``;
        throws carry their cell's ``dmp`` values; every job its ``id``
        (:func:`suture_lfd.study.keys.with_ids`, with its seed's study context).

    """
    studies, demos, throws = {}, [], []
    cells = sweep.cells()
    modes = {name: cell_mode(point) for name, point in cells}
    # one set of demonstrations per demonstration folder: ground truth (per tissue) first,
    # then the physical robots by error level
    kept: dict[str, CellMode] = {}
    for mode in sorted(modes.values(), key=lambda m: (
            m.physical is not None, m.physical.error_level if m.physical else 0.0)):
        kept.setdefault(mode.demo_folder(), mode)
    for seed in sweep.seeds:
        config = build_config(_study_args(sweep, seed))
        studies[str(seed)] = config
        seed_demos, seed_throws = plan_jobs(config)
        prefix = f'seed-{seed}'
        placed = [dataclasses.replace(job, id='', key=f'{prefix}/{job.key}',
                                      cohort_seed=int(seed), bag=f'{prefix}/{job.bag}',
                                      segments=f'{prefix}/{job.segments}')
                  for mode in kept.values() for job in mode.demos(seed_demos, seed)]
        placed_demos = with_ids(placed, config)
        demos += placed_demos
        for name, point in cells:
            where = f'cells/{name}/{prefix}'
            throws += with_ids([dataclasses.replace(
                job, id='', key=f'{name}/{prefix}/{job.key}', cell=name,
                dmp=dmp_overrides(point), demo_key=f'{prefix}/{job.demo_key}',
                trajectories=f'{where}/{job.trajectories}' if job.trajectories else None)
                for job in modes[name].throws(seed_throws, seed)], config,
                demo_ids(placed_demos))
    config = {'format': SWEEP_FORMAT, 'studies': studies, 'cells': dict(cells),
              'axes': [[a, list(v)] for a, v in sweep.axes], 'seeds': list(sweep.seeds)}
    return config, demos, throws


def _hashed_sweep(config: dict[str, Any]) -> dict[str, Any]:
    return {**config, 'studies': {s: hashed_config(c) for s, c in config['studies'].items()}}


def _cell_records(records: Sequence[Record], name: str, seed: int,
                  mode: CellMode | None = None) -> list[Record]:
    """
    Return the records of one cell and seed, keyed and pathed as a study's own.

    ``mode``: how the cell runs (:func:`cell_mode`; its demonstrations are its folder's);
    None: ground truth without tissue.
    """
    mode = mode or CellMode()
    prefix, where = f'seed-{seed}/' + mode.demo_folder(), f'cells/{name}/seed-{seed}/'
    variant = mode.throw_folder()
    out: list[Record] = []
    for r in records:
        if isinstance(r, DemoRecord) and r.key.startswith(prefix + 'demo/'):
            out.append(dataclasses.replace(r, key=r.key[len(prefix):]))
        elif isinstance(r, ThrowRecord) and r.kind == 'throw' and r.cell == name and \
                r.key.startswith(f'{name}/seed-{seed}/{variant}'):
            t = r.trajectories
            where_t = where + variant
            key = r.key[len(name) + 1 + len(f'seed-{seed}/{variant}'):]
            out.append(dataclasses.replace(
                r, key=key, trajectories=t[len(where_t):] if t and t.startswith(where_t) else t))
    return out


def _lookup(summary: Mapping[str, Any], path: Sequence[str]) -> float:
    value: Any = summary
    for part in path:
        if not isinstance(value, dict) or part not in value:
            return float('nan')
        value = value[part]
    return float(value) if isinstance(value, (int, float)) else float('nan')


def sweep_rows(config: dict[str, Any], summaries: Mapping[tuple[str, int], Any]
               ) -> list[dict[str, Any]]:
    """
    Return one row per cell, seed and method: the cell's parameters and its metrics.

    ``summaries``: ``(cell, seed) -> summary.json`` of that study.
    """
    rows = []
    for (name, seed), summary in summaries.items():
        for method in summary:
            if not isinstance(summary[method], dict):
                continue
            row = {'cell': name, 'seed': int(seed), 'method': method,
                   **config['cells'][name]}
            for column, path in METRICS:
                row[column] = _lookup(summary[method], path)
            rows.append(row)
    return rows


def spread_table(rows: Sequence[Mapping[str, Any]], axis: str, metric: str
                 ) -> dict[str, list[tuple[Any, float, float, int]]]:
    """
    Return ``{method: [(value, mean, std, n)]}``: a metric against one swept parameter.

    The per-seed value of a parameter value is the mean over the cells having it (the other
    parameters marginalised); ``mean`` and ``std`` are over seeds.
    """
    out = {}
    for method in sorted({r['method'] for r in rows}):
        series = []
        values = sorted({r[axis] for r in rows if r['method'] == method})
        for v in values:
            per_seed: dict[int, list[float]] = {}
            for r in rows:
                if r['method'] == method and r[axis] == v and not math.isnan(r[metric]):
                    per_seed.setdefault(r['seed'], []).append(r[metric])
            seeds = [float(np.mean(x)) for x in per_seed.values()]
            series.append((v, float(np.mean(seeds)) if seeds else float('nan'),
                           float(np.std(seeds)) if len(seeds) > 1 else 0.0, len(seeds)))
        out[method] = series
    return out


def write_sweep_report(folder: str | Path, config: dict[str, Any],
                       rows: Sequence[dict[str, Any]], run_info: Mapping[str, Any]) -> Path:
    """Write ``sweep.csv``, ``sweep.md`` and one plot per swept parameter; return sweep.md."""
    folder = Path(folder)
    axes = [a for a, _ in config['axes']]
    columns = ['cell', 'seed', 'method', *axes, *(c for c, _ in METRICS)]
    with open(folder / 'sweep.csv', 'w', newline='') as f:
        writer = csv.writer(f, lineterminator='\n')
        writer.writerow(columns)
        for r in sorted(rows, key=lambda r: (r['cell'], r['seed'], r['method'])):
            writer.writerow(['' if isinstance(r[c], float) and math.isnan(r[c])
                             else (repr(round(r[c], 6)) if isinstance(r[c], float) else r[c])
                             for c in columns])
    md = ['# Sweep report', '',
          f'{len(config["cells"])} cells x {len(config["seeds"])} seeds '
          f'({", ".join(str(s) for s in config["seeds"])}); '
          f'engine: {run_info.get("engine", "?")}, {run_info.get("jobs_run", 0)} jobs run in '
          f'{run_info.get("wall_s", 0.0):.1f} s, {run_info.get("resumed", 0)} reused from '
          'the stored results.', '',
          'Each value is the mean over seeds (± the standard deviation of the per-seed values) '
          'of the cells having that parameter value; every cell has a full study report in '
          '`cells/<cell>/seed-<s>/report.md`.', '']
    if not axes:
        axes_shown = ['cell']
        for r in rows:
            r.setdefault('cell', 'default')
    else:
        axes_shown = axes
    for axis in axes_shown:
        md += [f'## {axis}', '']
        header = f'| {axis} | method | ' + ' | '.join(c for c, _ in METRICS) + ' |'
        md += [header, '|' + '---|' * (2 + len(METRICS))]
        tables = {c: spread_table(rows, axis, c) for c, _ in METRICS}
        for method in sorted({r['method'] for r in rows}):
            for k, (v, *_rest) in enumerate(tables[METRICS[0][0]][method]):
                cells = []
                for c, _ in METRICS:
                    _, mean, std, n = tables[c][method][k]
                    cells.append('–' if math.isnan(mean) else
                                 (f'{mean:.3f} ± {std:.3f}' if n > 1 else f'{mean:.3f}'))
                md.append(f'| {_text(v)} | {method} | ' + ' | '.join(cells) + ' |')
        md.append('')
        if axis != 'cell':
            png = _plot_axis(folder, axis, {c: tables[c] for c in PLOTTED})
            md += [f'![{axis}]({png.name})', '']
    path = folder / 'sweep.md'
    path.write_text('\n'.join(md) + '\n')
    return path


def _plot_axis(folder: str | Path, axis: str, tables: Mapping[str, Any]) -> Path:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, panels = plt.subplots(1, len(tables), figsize=(3.6 * len(tables), 3.2),
                               squeeze=False)
    values = {v for table in tables.values() for series in table.values() for v, *_ in series}
    # a parameter that is not a number (a preset's name): its values side by side
    names = sorted(str(v) for v in values) if any(isinstance(v, str) for v in values) else []
    for ax, (metric, table) in zip(panels[0], tables.items()):
        for method, series in table.items():
            x = [names.index(str(v)) if names else float(v) for v, *_ in series]
            y = [m for _, m, _, _ in series]
            e = [s for _, _, s, _ in series]
            ax.errorbar(x, y, yerr=e, marker='o', capsize=3, label=method)
        ax.set_xlabel(axis)
        if names:
            ax.set_xticks(range(len(names)), names)
        ax.set_title(metric, fontsize=9)
        ax.grid(alpha=0.3)
    panels[0][0].legend(fontsize=8)
    fig.tight_layout()
    path = Path(folder) / f'sweep_{axis.replace(".", "_")}.png'
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run_sweep(args: argparse.Namespace, stream: IO[str] | None = None) -> int:
    """
    Run (or resume) a sweep and write its reports; return the exit status.

    0 done, 1 the engine failed, 2 bad sweep file or options, 130/143 interrupted (SIGINT,
    SIGTERM; the stored results kept, no report).
    """
    stream = stream if stream is not None else sys.stderr
    t0 = time.monotonic()
    try:
        sweep = load_sweep(args.sweep_file)
        engine = parse_engine(args.engine)
        config, demos, throws = plan_sweep(sweep)
    except (ValueError, OSError) as exc:
        print(f'suture-lfd sweep: error: {exc}', file=sys.stderr)
        return 2
    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    if workers < 1:
        print(f'suture-lfd sweep: error: --workers must be >= 1, got {workers}', file=sys.stderr)
        return 2
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    digest = config_hash(_hashed_sweep(config))
    config['hash'] = digest
    (out / 'sweep.json').write_text(json.dumps(config, indent=1, sort_keys=True) + '\n')
    jobs: list[DemoJob | ThrowJob] = [*demos, *throws]
    total = len(jobs)
    print(f'sweep {digest}: {len(config["cells"])} cells x {len(sweep.seeds)} seeds: '
          f'{len(demos)} demonstrations + {len(throws)} throws; results in {out}',
          file=stream, flush=True)
    if args.plan:
        (out / 'jobs.json').write_text(json.dumps([plan_json(job) for job in jobs],
                                                  indent=1) + '\n')
        return 0
    cohort = next(iter(config['studies'].values()))['cohort_file']
    settings = JobSettings(out=str(out), cohort_path=cohort, cohort_seed=sweep.seeds[0])
    with stop_on_signals('sweep') as stop, ResultStore(out) as store:
        reused = stored_note('sweep', store, jobs, stream)
        progress = Progress(total, done=reused, stream=stream)
        stages = [Stage(lambda: demos, (settings,)),
                  Stage(lambda: attach_demos(throws, store, demos), (settings,))]
        status = run_job_stages('sweep', engine, stages, jobs, store, stop, progress,
                                workers, stream)
        if status > 128:
            return status
        ran = progress.done - progress.resumed
        records = ordered_records(store, jobs)
    wall = time.monotonic() - t0
    run_info = {'engine': engine.describe(), 'jobs_run': ran, 'resumed': reused, 'wall_s': wall,
                'workers': workers}
    from suture_lfd.study import report as report_writer

    summaries = {}
    for name in config['cells']:
        for seed in sweep.seeds:
            folder = out / 'cells' / name / f'seed-{seed}'
            folder.mkdir(parents=True, exist_ok=True)
            study = copy.deepcopy(config['studies'][str(seed)])
            study['dmp'] = dmp_overrides(config['cells'][name])
            cell = _cell_records(records, name, seed, cell_mode(config['cells'][name]))
            report_writer.write_report(folder, cell, study, run_info)
            summaries[name, seed] = json.loads((folder / 'summary.json').read_text())
    path = write_sweep_report(out, config, sweep_rows(config, summaries), run_info)
    print(f'sweep report: {path} ({len(records)}/{total} jobs; {wall:.1f} s)', file=stream,
          flush=True)
    return status


def main(args: argparse.Namespace) -> int:
    """Entry point of ``suture-lfd sweep`` (called by :mod:`suture_lfd.cli`)."""
    return run_sweep(args)
