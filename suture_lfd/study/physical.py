"""
The study in physical mode: the same design on what a physical dVRK provides.

``--physical`` runs, beside the study's ground-truth jobs (reused when stored), the same
demonstrations and throws in physical mode, in-process, once per *variant*: the arm model
(``--arm-realism``: by default the ``dvrk`` preset of ``config/realism_arm.yaml``, a physical
dVRK's imperfection; ``static`` the constant offsets of earlier releases, at an error level
``--error-level``, a mm class of :mod:`sim_bridge.kinematic_errors`, several as a
comma-separated list) and whether the executor corrects on what it sees (``--correction
on|off|both``, ``--no-correction`` for ``off``):

- the PSMs' hidden kinematic errors are drawn per subject and phantom (:func:`robot_key`: one
  robot per setup, as a lab registers a dVRK once per setup, not per throw) at the level; the
  jobs of that subject on that phantom share the robot (``error_seed``), so a study worker
  builds and registers it once (:mod:`suture_lfd.study.jobs`); the scene seed is the
  ground-truth job's, so the two modes differ only by the robot;
- a demonstration is teleoperated through the robot and recorded as the robot sees it
  (:mod:`suture_lfd.study.teleoperated`: the arms' reports, the needle and markers from the
  endoscope); it depends on the level, not on the correction, so the variants of a level share
  their demonstrations;
- a throw is executed on the arms' reports and perception
  (:func:`suture_lfd.skill.executor.execute_throw` with ``physical=True``).

Physical jobs carry ``physical`` (level, error seed and, for a throw, the correction) and
``folder`` in their fields, so their ``id`` s (:mod:`suture_lfd.study.keys`) never meet a
ground-truth job's, and the ground-truth jobs are planned exactly as without ``--physical``
(same ``id`` s, the same ``throws.csv``). Each variant gets a full study report in
``physical/<variant>/``; the main report gets a "Physical mode" section: Tables II-IV of each
variant beside ground-truth mode and the paper, and, with more than one level or correction, the
curve of generality against the error level (``physical_curve.png``, ``physical_curve.csv``).

With an arm realism preset (``--arm-realism dvrk``), ``--arm-levels`` sets its effects' levels
(``servo_level=0,jaw_level=0.5``) and ``--arm-ablation`` adds, beside the preset with every
effect, one variant per effect alone (the others at level 0: ``dvrk-only-servo``, each with its
own robots' demonstrations unless ``--physical-demos ground-truth``); the report then shows the
ablation table (``physical_ablation.csv``): generality with each effect alone and all together,
with and without the executor's correction (``--correction both``), so a reader sees which
imperfection costs the skill most.

Size: the options, the plan and the report of physical mode read one configuration (its
variants, their curve and their ablation); the report's part is the one to split off next.
"""

import argparse
from collections.abc import Callable, Sequence
from dataclasses import replace
import math
from typing import Any, NamedTuple

from sim_bridge.realism.calibration import ARM_LEVELS, load_arm_realism
from suture_lfd.study import tables
from suture_lfd.study.records import DemoJob, DemoRecord, RobotErrors, ThrowJob, ThrowRecord

# the paper's figures (tables.PAPER), read as nested mappings
_PAPER: dict[str, Any] = tables.PAPER

#: The levels of the issue's curve (mm class).
CURVE_LEVELS = (0.0, 1.0, 3.0, 5.0)
CURVE_COLUMNS = ('method', 'correction', 'error_level', 'generality_experienced',
                 'generality_naive', 'generality_overall', 'ground_truth_overall', 'ratio',
                 'regeneration_success', 'throws')
ABLATION_COLUMNS = ('method', 'effects', 'correction', 'generality_experienced',
                    'generality_naive', 'generality_overall', 'ground_truth_overall', 'ratio',
                    'regeneration_success', 'throws')
#: The ablation's row of every effect together.
ALL_EFFECTS = 'all'


class Variant(NamedTuple):
    """
    One physical-mode variant: a robot model and whether the throws correct.

    Attributes
    ----------
    name : str
        Its folder under ``physical/`` (:func:`variant_name`).
    level : float
        Static error class (mm; 0 with a preset).
    correction : bool
        Whether the throws correct from what they see.
    arm_levels : tuple of (str, float)
        The preset's effect levels it overrides (empty: the preset's own, or static).
    effects : str
        With ``--arm-ablation``: the effect it keeps (``'servo'``) or :data:`ALL_EFFECTS`;
        otherwise ``''``.

    """

    name: str
    level: float
    correction: bool
    arm_levels: tuple[tuple[str, float], ...] = ()
    effects: str = ''


#: The arm model of ``--physical`` when none is named: a physical dVRK's imperfection
#: (``config/realism_arm.yaml``); ``static`` names the constant offsets of earlier releases.
DEFAULT_ARM_REALISM = 'dvrk'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the physical-mode options to the study's argparse parser."""
    parser.add_argument('--physical', action='store_true',
                        help='also run the study in physical mode: hidden kinematic errors, '
                             'demonstrations recorded and throws executed on what the robot '
                             'reports and the endoscope shows; reported beside ground truth')
    parser.add_argument('--error-level', default=None, metavar='L[,L...]',
                        help="with --arm-realism static: the constant offsets' class(es), mm "
                             f'(default 3; {",".join(_text(v) for v in CURVE_LEVELS)} draws the '
                             'curve)')
    parser.add_argument('--arm-realism', default=DEFAULT_ARM_REALISM, metavar='NAME|static',
                        help="with --physical: the arms' imperfection, a preset of "
                             'config/realism_arm.yaml (default dvrk: calibration errors with '
                             'base rotation and wrist offsets, cable hysteresis and stretch, '
                             "servo lag, encoders, the ECM's hand-eye error, intrinsics a "
                             'calibration leaves off, a jaw that stalls; the executor does not '
                             'master it yet) or static (constant offsets of class --error-level, '
                             'the model of earlier releases)')
    parser.add_argument('--arm-levels', default='', metavar='KEY=V[,KEY=V...]',
                        help='with --arm-realism PRESET: levels of its effects (0: off, 1: the '
                             f'preset), keys {", ".join(ARM_LEVELS)} (e.g. servo_level=0)')
    parser.add_argument('--arm-ablation', action='store_true',
                        help='with --arm-realism PRESET: also run one variant per effect alone '
                             '(the others at 0) and report the ablation table; with '
                             '--correction both, with and without the correction')
    parser.add_argument('--correction', choices=('on', 'off', 'both'), default='on',
                        help='with --physical: the executor closes its loop on what it sees '
                             "(on, default), runs open loop on the arms' kinematics (off), or "
                             'both side by side')
    parser.add_argument('--no-correction', dest='correction', action='store_const',
                        const='off', help='the same as --correction off')
    parser.add_argument('--physical-demos', choices=('recorded', 'ground-truth'),
                        default='recorded',
                        help='with --physical: learn from demonstrations recorded in physical '
                             'mode (default) or from the ground-truth ones, to measure the '
                             'execution alone')


def _text(value: float) -> str:
    return f'{value:g}'


def physical_config(args: argparse.Namespace) -> dict[str, Any] | None:
    """
    Return the physical-mode part of a study configuration, or None without ``--physical``.

    Parameters
    ----------
    args : argparse.Namespace
        Options of :func:`add_arguments`.

    Returns
    -------
    dict or None
        ``levels`` (mm class, in the given order), ``corrections`` (bool) and ``demos``
        (``'recorded'``, or ``'ground-truth'``: the throws learn from the ground-truth
        demonstrations).

    Raises
    ------
    ValueError
        A level that is not a finite number >= 0.

    """
    if not getattr(args, 'physical', False):
        return None
    levels = []
    given = getattr(args, 'error_level', None)
    for part in str('3' if given is None else given).split(','):
        try:
            level = float(part)
        except ValueError:
            level = math.nan
        if not (math.isfinite(level) and level >= 0.0):
            raise ValueError(f'--error-level takes mm classes >= 0 separated by commas, got '
                             f'{part.strip()!r}')
        if level not in levels:
            levels.append(level)
    correction = getattr(args, 'correction', 'on')
    corrections = {'on': [True], 'off': [False], 'both': [True, False]}[correction]
    demos = getattr(args, 'physical_demos', 'recorded')
    realism = str(getattr(args, 'arm_realism', DEFAULT_ARM_REALISM))
    arm_levels = parse_arm_levels(str(getattr(args, 'arm_levels', '') or ''))
    ablation = bool(getattr(args, 'arm_ablation', False))
    if realism != 'static':
        load_arm_realism(realism, levels=arm_levels)  # a bad name fails here, naming the presets
        if given is not None:
            raise ValueError(f'--error-level is the class of the static offsets, and the arms are '
                             f"the {realism!r} preset (physical mode's default unless named): "
                             'add --arm-realism static to run the static offsets, or drop '
                             '--error-level')
        levels = [0.0]  # the static class is unused with a preset
    elif arm_levels or ablation:
        raise ValueError('--arm-levels and --arm-ablation need --arm-realism PRESET (a preset '
                         'of config/realism_arm.yaml, e.g. dvrk)')
    return {'levels': levels, 'corrections': corrections,
            **({'demos': demos} if demos != 'recorded' else {}),
            **({'arm_realism': realism} if realism != 'static' else {}),
            **({'arm_levels': arm_levels} if arm_levels else {}),
            **({'ablation': True} if ablation else {})}


def parse_arm_levels(text: str) -> dict[str, float]:
    """
    Return the effect levels of ``--arm-levels`` (``'servo_level=0,jaw_level=0.5'``).

    Raises
    ------
    ValueError
        A key not in :data:`ARM_LEVELS` or a level that is not a finite number >= 0.

    """
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(','))):
        key, sep, value = part.partition('=')
        key = key.strip()
        try:
            level = float(value) if sep else math.nan
        except ValueError:
            level = math.nan
        if key not in ARM_LEVELS or not (math.isfinite(level) and level >= 0.0):
            raise ValueError(f'--arm-levels takes KEY=LEVEL separated by commas, KEY one of '
                             f'{", ".join(ARM_LEVELS)} and LEVEL a number >= 0, got {part!r}')
        out[key] = level
    return out


def effect_name(key: str) -> str:
    """Return an effect's short name: ``'servo'`` for ``'servo_level'``."""
    return key.removesuffix('_level')


def variant_name(level: float, correction: bool, realism: str = 'static',
                 effects: str = '') -> str:
    """
    Return the folder name of a variant: ``level-3`` / ``dvrk`` (corrected) or ``...-open``.

    Parameters
    ----------
    level : float
        Static error class (mm), used with ``realism`` ``'static'``.
    correction : bool
        Whether the throws correct from what they see.
    realism : str
        The arm model (``'static'`` or a preset name).
    effects : str
        An ablation's effect alone (``'servo'``: ``dvrk-only-servo``); ``''`` or
        :data:`ALL_EFFECTS`: the preset as configured.

    Returns
    -------
    str

    """
    name = f'level-{_text(level)}' if realism == 'static' else realism
    if effects and effects != ALL_EFFECTS:
        name += f'-only-{effects}'
    return name + ('' if correction else '-open')


def variants(physical: dict[str, Any]) -> list[Variant]:
    """Return the variants of a physical configuration, in order."""
    realism = physical.get('arm_realism', 'static')
    base = dict(physical.get('arm_levels', {}))
    models: list[tuple[str, tuple[tuple[str, float], ...]]] = [
        (ALL_EFFECTS if physical.get('ablation') else '', tuple(sorted(base.items())))]
    if physical.get('ablation'):
        preset = load_arm_realism(realism, levels=base)
        for key in ARM_LEVELS:
            if getattr(preset, key) > 0.0:  # an effect the preset has
                models.append((effect_name(key), tuple(
                    (k, getattr(preset, key) if k == key else 0.0) for k in ARM_LEVELS)))
    return [Variant(variant_name(level, c, realism, effects), level, c, arm_levels, effects)
            for effects, arm_levels in models
            for level in physical['levels'] for c in physical['corrections']]


def robot_key(subject: str, phantom: str) -> str:
    """
    Return the name the errors' seed of a subject's robot on a phantom is drawn from.

    Parameters
    ----------
    subject : str
        The subject (its demonstrations and the throws learnt from them).
    phantom : str
        The phantom the robot works on (a throw's test phantom).

    Returns
    -------
    str
        ``robot/<subject>/<phantom>``: the same at every level (the level scales the errors),
        so the curve compares the same robots.

    """
    return f'robot/{subject}/{phantom}'


def plan_physical(physical: dict[str, Any], demos: Sequence[DemoJob],
                  throws: Sequence[ThrowJob], job_seed: Callable[[int, str], int],
                  seed: int) -> tuple[list[DemoJob], list[ThrowJob]]:
    """
    Return the physical-mode jobs made from the ground-truth ones (without ``id``).

    Parameters
    ----------
    physical : dict
        Output of :func:`physical_config`.
    demos : list of DemoJob
    throws : list of ThrowJob
        The study's ground-truth jobs (:func:`suture_lfd.study.run.plan_jobs`).
    job_seed : callable
        ``(study seed, key) -> seed``: the errors' seed of a robot (:func:`robot_key`).
    seed : int
        The study seed.

    Returns
    -------
    demos : list of DemoJob
    throws : list of ThrowJob
        Per level its demonstrations (``physical/level-L/...``), per variant its throws,
        learning from the demonstrations of their level; with ``demos`` ``'ground-truth'``
        no demonstrations, the throws learning from the ground-truth ones.

    """
    out_demos, out_throws = [], []
    recorded = physical.get('demos', 'recorded') == 'recorded'
    realism = physical.get('arm_realism', 'static')
    every = variants(physical)
    # one set of demonstrations per robot model, in its corrected variant's folder
    models = {(v.level, v.arm_levels, v.effects): None for v in every}
    for level, arm_levels, effects in models if recorded else ():
        where = f'physical/{variant_name(level, True, realism, effects)}'
        for job in demos:
            key = f'{where}/{job.key}'
            out_demos.append(replace(
                job, id='', key=key, folder=where, bag=f'{where}/{job.bag}',
                segments=f'{where}/{job.segments}',
                physical=RobotErrors(error_level=level, error_seed=job_seed(
                    seed, robot_key(job.subject, job.phantom)), arm_realism=realism,
                    arm_levels=arm_levels)))
    for v in every:
        where = f'physical/{v.name}'
        demo_where = f'physical/{variant_name(v.level, True, realism, v.effects)}'
        for throw in throws:
            key = f'{where}/{throw.key}'
            trajectories = throw.trajectories
            out_throws.append(replace(
                throw, id='', key=key, folder=where,
                demo_key=f'{demo_where}/{throw.demo_key}' if recorded else throw.demo_key,
                trajectories=f'{where}/{trajectories}' if trajectories else None,
                physical=RobotErrors(error_level=v.level, error_seed=job_seed(
                    seed, robot_key(throw.subject, throw.test_phantom)),
                    correction=v.correction, arm_realism=realism, arm_levels=v.arm_levels)))
    return out_demos, out_throws


def variant_records(records: Sequence[DemoRecord | ThrowRecord], name: str, level: float,
                    ground_demos: Sequence[DemoRecord] | None = None
                    ) -> list[DemoRecord | ThrowRecord]:
    """
    Return the records of one variant, keyed and pathed as a ground-truth study's own.

    Parameters
    ----------
    records : list of DemoRecord or ThrowRecord
        Physical-mode records (demonstrations and throws of every variant).
    name : str
        The variant (:func:`variant_name`).
    level : float
        Its level (its demonstrations are the level's).
    ground_demos : list of DemoRecord, optional
        The ground-truth demonstrations, when the throws learnt from them.

    Returns
    -------
    list of DemoRecord or ThrowRecord

    """
    demo_prefix = f'physical/{name.removesuffix("-open")}/'  # its corrected variant's demos
    throw_prefix = f'physical/{name}/'
    out: list[DemoRecord | ThrowRecord] = list(ground_demos or [])
    for r in records:
        if isinstance(r, DemoRecord) and r.key.startswith(demo_prefix):
            out.append(replace(r, key=r.key[len(demo_prefix):]))
        elif isinstance(r, ThrowRecord) and r.kind == 'throw' and r.key.startswith(throw_prefix):
            t = r.trajectories
            out.append(replace(r, key=r.key[len(throw_prefix):],
                               trajectories=t[len(throw_prefix):]
                               if t and t.startswith(throw_prefix) else t))
    return out


def _f(value: float | None, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return '–'
    return f'{value:.{digits}f}'


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    return tables.markdown(header, rows).split('\n')


def _cumulative(t4: dict[str, Any], task: str) -> str:
    """Table IV's overall success of a subtask, in %."""
    return (_f(100.0 * t4[task][2] / t4['total'], 1) + ' %') if t4['total'] else '–'


def _variant_label(v: Variant, realism: str = 'static') -> str:
    if realism == 'static':
        name = f'L{_text(v.level)}'
    elif v.effects and v.effects != ALL_EFFECTS:
        name = f'{realism} {v.effects} alone'
    else:
        name = realism
    return f'{name} ' + ('corrected' if v.correction else 'open loop')


def _generality_row(method: str, s: dict[str, Any], ground_truth: dict[str, Any]
                    ) -> dict[str, Any]:
    gen = s['generality']['group_mean']
    gt = ground_truth.get(method, {}).get('generality', {}).get('group_mean', {})
    gt_overall = gt.get('overall', math.nan)
    overall = gen['overall']
    return {'method': method, 'generality_experienced': gen['experienced'],
            'generality_naive': gen['naive'], 'generality_overall': overall,
            'ground_truth_overall': gt_overall,
            'ratio': overall / gt_overall if gt_overall else math.nan,
            'regeneration_success': s['regeneration']['rate'],
            'throws': s['generality']['n']['overall']}


def curve_rows(summaries: dict[Variant, dict[str, Any]],
               ground_truth: dict[str, Any]) -> list[dict[str, Any]]:
    """
    Return one row per method, correction and level: generality in physical mode.

    Parameters
    ----------
    summaries : dict
        :class:`Variant` -> summary (:func:`suture_lfd.study.report.summarise`); an
        ablation's variants of one effect alone are left out.
    ground_truth : dict
        The ground-truth summary.

    Returns
    -------
    list of dict
        Columns :data:`CURVE_COLUMNS`; ``ratio`` is overall generality over ground truth's.

    """
    rows = []
    for v, summary in summaries.items():
        if v.effects not in ('', ALL_EFFECTS):
            continue
        for method, s in summary.items():
            rows.append({**_generality_row(method, s, ground_truth),
                         'correction': v.correction, 'error_level': v.level})
    return sorted(rows, key=lambda r: (r['method'], not r['correction'], r['error_level']))


def ablation_rows(summaries: dict[Variant, dict[str, Any]],
                  ground_truth: dict[str, Any]) -> list[dict[str, Any]]:
    """
    Return one row per method, effect (alone, then :data:`ALL_EFFECTS`) and correction.

    Parameters
    ----------
    summaries : dict
        :class:`Variant` -> summary of an ``--arm-ablation`` study.
    ground_truth : dict
        The ground-truth summary.

    Returns
    -------
    list of dict
        Columns :data:`ABLATION_COLUMNS`.

    """
    order = [effect_name(k) for k in ARM_LEVELS] + [ALL_EFFECTS]
    rows = []
    for v, summary in summaries.items():
        if v.effects:
            for method, s in summary.items():
                rows.append({**_generality_row(method, s, ground_truth),
                             'effects': v.effects, 'correction': v.correction})
    return sorted(rows, key=lambda r: (r['method'], order.index(r['effects']),
                                       not r['correction']))


def report_section(summaries: dict[Variant, dict[str, Any]],
                   ground_truth: dict[str, Any], physical: dict[str, Any],
                   curve_png: str | None = None) -> list[str]:
    """
    Return the lines of the report's "Physical mode" section.

    Parameters
    ----------
    summaries : dict
        :class:`Variant` -> summary of each variant.
    ground_truth : dict
        The ground-truth summary (same design, same scene seeds).
    physical : dict
        The physical configuration (:func:`physical_config`).
    curve_png : str, optional
        File name of the curve's figure (drawn when there is more than one variant).

    Returns
    -------
    list of str

    """
    realism = physical.get('arm_realism', 'static')
    if realism == 'static':
        errors = ("the PSMs' kinematic errors hidden in the simulation (joints 1-2 up to ±L deg, "
                  'insertion ±L mm, base registration ±L mm per axis')
    else:
        levels = ', '.join(f'{k}={_text(v)}'
                           for k, v in sorted(physical.get('arm_levels', {}).items()))
        errors = (f'arms of the `{realism}` preset of `config/realism_arm.yaml` hidden in the '
                  'simulation (calibration errors with base rotation and wrist offsets, cable '
                  'backlash and stretch, servo lag, encoders, a hand-eye error of the ECM, '
                  'endoscope intrinsics a calibration leaves off, a jaw that stalls on the '
                  'needle' + (f'; levels {levels}' if levels else ''))
    md = ['## Physical mode', '',
          f'The same design run on what a physical dVRK provides: {errors}; drawn per subject '
          'and phantom: one robot per setup, registered once), demonstrations teleoperated '
          'through the robot and recorded as it reports them, with the needle and the markers '
          "from the endoscope's images; throws executed on the arms' reports and perception. "
          "The scoring reads the simulation's truth, as an observer of the real robot would. "
          'Each variant has its full report in `physical/<variant>/`.', '']
    if physical.get('demos') == 'ground-truth':
        md += ['**The throws here learn from the ground-truth demonstrations** '
               '(`--physical-demos ground-truth`): only their execution is in physical '
               'mode.', '']
    keys = [v for v in variants(physical) if v.effects in ('', ALL_EFFECTS)]
    methods = list(ground_truth)
    for method in methods:
        gt = ground_truth[method]
        shown = [(k, summaries[k][method]) for k in keys
                 if k in summaries and method in summaries[k]]
        header = (['', 'ground truth'] + [_variant_label(k, realism) for k, _ in shown]
                  + ['paper'])
        md += [f'### Method `{method}`', '', '#### Table II: regeneration errors (mean)', '']
        rows = []
        for task in tables.TASKS:
            for kind, unit in tables.ERROR_KINDS:
                for point in tables.ERROR_POINTS:
                    name = f'{task}/{kind}/{point}'
                    paper = _PAPER['table2'][(task, kind, point)][0]
                    rows.append([f'task {task} {point} ({unit})',
                                 _f(gt['regeneration']['errors'][name]['mean'], 2)]
                                + [_f(s['regeneration']['errors'][name]['mean'], 2)
                                   for _, s in shown] + [f'{paper:.2f}'])
        rows.append(['regeneration success', _f(100.0 * gt['regeneration']['rate'], 1) + ' %']
                    + [_f(100.0 * s['regeneration']['rate'], 1) + ' %' for _, s in shown]
                    + ['95.0 %'])
        md += _table(header, rows) + ['', '#### Table III: generality', '']
        rows = []
        for group in ('experienced', 'naive', 'overall'):
            rows.append([group, _f(gt['generality']['group_mean'][group])]
                        + [_f(s['generality']['group_mean'][group]) for _, s in shown]
                        + [f'{_PAPER["generality"][group]:.3f}'])
        gt_overall = gt['generality']['group_mean']['overall']
        rows.append(['overall / ground truth', '1.000']
                    + [_f(s['generality']['group_mean']['overall'] / gt_overall
                          if gt_overall else math.nan) for _, s in shown] + ['–'])
        md += _table(header, rows)
        md += ['', "#### Table IV: experienced users' success, overall (cumulative) %", '']
        rows = []
        for task in tables.SUBTASKS:
            paper = _PAPER['table4'][task][2] / _PAPER['table4_total']
            rows.append([task, _cumulative(gt['table4'], task)]
                        + [_cumulative(s['table4'], task) for _, s in shown]
                        + [f'{100.0 * paper:.1f} %'])
        md += _table(header, rows) + ['']
    if physical.get('ablation'):
        md += ablation_section(ablation_rows(summaries, ground_truth), realism)
    if has_curve(physical):
        curve = curve_rows(summaries, ground_truth)
        md += ['### Generality against the error level', '',
               'Overall generality in physical mode per error level (mm class), with the '
               "executor's correction and open loop on the arms' own kinematics, beside "
               'ground-truth mode (`physical_curve.csv`).', '']
        md += _table(['method', 'correction', 'level (mm)', 'experienced', 'naive', 'overall',
                      'ground truth', 'overall / ground truth', 'regeneration', 'throws'],
                     [[r['method'], 'on' if r['correction'] else 'off', _text(r['error_level']),
                       _f(r['generality_experienced']), _f(r['generality_naive']),
                       _f(r['generality_overall']), _f(r['ground_truth_overall']),
                       _f(r['ratio']), _f(100.0 * r['regeneration_success'], 1) + ' %',
                       r['throws']] for r in curve])
        md += ['']
        if curve_png:
            md += [f'![generality against the error level]({curve_png})', '']
    return md


def has_curve(physical: dict[str, Any]) -> bool:
    """Return whether a configuration draws the curve: static errors, several variants."""
    return (physical.get('arm_realism', 'static') == 'static'
            and len(physical['levels']) * len(physical['corrections']) > 1)


def ablation_section(rows: Sequence[dict[str, Any]], realism: str) -> list[str]:
    """Return the report's ablation table: generality per effect alone and all together."""
    md = ["### Ablation: each of the arm's imperfections alone", '',
          f'Overall generality in physical mode with one effect of the `{realism}` preset at '
          'its level and the others off, then with every effect, beside ground-truth mode '
          "(`physical_ablation.csv`); \"corrected\": the executor closes its loop on what it "
          "sees, \"open loop\": it runs on the arms' own kinematics.", '']
    md += _table(['method', 'effects', 'correction', 'experienced', 'naive', 'overall',
                  'ground truth', 'overall / ground truth', 'regeneration', 'throws'],
                 [[r['method'], r['effects'] if r['effects'] != ALL_EFFECTS else 'all together',
                   'on' if r['correction'] else 'off', _f(r['generality_experienced']),
                   _f(r['generality_naive']), _f(r['generality_overall']),
                   _f(r['ground_truth_overall']), _f(r['ratio']),
                   _f(100.0 * r['regeneration_success'], 1) + ' %', r['throws']]
                  for r in rows])
    return md + ['']


def curve_figure(rows: Sequence[dict[str, Any]], path: Any) -> Any:
    """Plot overall generality against the error level, one line per method and correction."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.0, 3.4))
    lines: dict[tuple[str, bool], list[dict[str, Any]]] = {}
    for r in rows:
        lines.setdefault((r['method'], r['correction']), []).append(r)
    for (method, correction), series in sorted(lines.items()):
        x = [r['error_level'] for r in series]
        ax.plot(x, [r['generality_overall'] for r in series], marker='o',
                linestyle='-' if correction else '--',
                label=f'{method}, ' + ('corrected' if correction else 'open loop'))
    for method in sorted({r['method'] for r in rows}):
        gt = next(r['ground_truth_overall'] for r in rows if r['method'] == method)
        ax.axhline(gt, color='grey', linewidth=0.8, linestyle=':')
    ax.set_xlabel('kinematic error level (mm class)')
    ax.set_ylabel('overall generality')
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title('physical mode (dotted: ground truth)', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
