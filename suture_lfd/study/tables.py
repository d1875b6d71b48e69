"""
The seed paper's evaluation tables, computed from a study's per-job records.

Records are typed (:mod:`suture_lfd.study.records`): a :class:`DemoRecord` for a demonstration,
a :class:`ThrowRecord` of ``kind == 'throw'`` for one executed throw (a skill learnt on
``train_pair`` executed on ``test_pair`` by ``method``). A throw with ``train_pair ==
test_pair`` is a regeneration (Table II); all throws of a subject form its generality matrix
(heat map, Table III); the throws of the experienced subjects give the subtask success rates
(Table IV); complete throws and demonstrations give the task times (the paper's task-time
figure).

Every function here is a pure function of the records, so the report's tables can be checked
against its CSV.
"""

from collections.abc import Iterable, Sequence
import math
from typing import Any
import warnings

import numpy as np
from sim_bridge.common.vocabulary import SUBTASKS, TASKS
from suture_lfd.study.records import DemoRecord, Record, ThrowRecord

GROUPS = ('experienced', 'naive')
ERROR_KINDS = (('pos', 'mm'), ('ori', 'deg'))
ERROR_POINTS = ('start', 'goal', 'traj')

# The seed paper's figures (Zhou et al., ISMR 2024): Table II (mean, std, median or None),
# Table III, Table IV, regeneration success and task time.
PAPER: dict[str, Any] = {
    'table2': {
        ('ii', 'pos', 'start'): (0.0, 0.0, None), ('ii', 'pos', 'goal'): (0.05, 0.06, None),
        ('ii', 'pos', 'traj'): (0.17, 0.07, None),
        ('ii', 'ori', 'start'): (0.0, 0.0, None), ('ii', 'ori', 'goal'): (0.74, 1.24, None),
        ('ii', 'ori', 'traj'): (1.71, 8.44, None),
        ('iv', 'pos', 'start'): (0.02, 0.02, None), ('iv', 'pos', 'goal'): (0.43, 0.31, None),
        ('iv', 'pos', 'traj'): (0.38, 0.16, None),
        ('iv', 'ori', 'start'): (0.0, 0.0, None), ('iv', 'ori', 'goal'): (11.32, 22.03, 2.71),
        ('iv', 'ori', 'traj'): (17.54, 27.09, 1.42),
    },
    'regeneration_success': (76, 80),
    'generality': {'experienced': 0.915, 'naive': 0.742, 'overall': 0.811},
    # subtask -> (individual successes, individual trials, cumulative successes); of 256
    'table4': {'i': (256, 256, 256), 'ii': (202, 256, 202), 'iii': (197, 202, 197),
               'iv': (181, 197, 181), 'v': (181, 181, 181)},
    'table4_total': 256,
    'time_reduction': {'synthetic': 'slight', 'scanned': 0.20},
}


def demos(records: Iterable[Record]) -> list[DemoRecord]:
    """Return the demonstration records, sorted by subject and pair order of appearance."""
    rows = [r for r in records if isinstance(r, DemoRecord) and not r.error]
    return sorted(rows, key=lambda r: (r.subject, r.order, r.pair))


def throws(records: Iterable[Record], method: str | None = None) -> list[ThrowRecord]:
    """Return the throw records (of one method), sorted by method, subject, train, test."""
    rows = [r for r in records if isinstance(r, ThrowRecord) and r.kind == 'throw'
            and not r.error and (method is None or r.method == method)]
    return sorted(rows, key=lambda r: (r.method, r.subject, r.train_order,
                                       r.train_pair, r.test_order, r.test_pair))


def methods(records: Iterable[Record]) -> list[str]:
    """Return the methods present, in first-seen order."""
    seen: list[str] = []
    for r in records:
        if isinstance(r, ThrowRecord) and r.kind == 'throw' and r.method not in seen:
            seen.append(r.method)
    return seen


def _mean(values: Iterable[float | None]) -> float:
    kept = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    return float(np.mean(kept)) if kept else float('nan')


def pair_order(rows: Iterable[ThrowRecord]) -> list[str]:
    """Return the marker pairs in the order of the study (train then test appearance)."""
    keyed: dict[str, int] = {}
    for r in rows:
        keyed.setdefault(r.train_pair, r.train_order)
        keyed.setdefault(r.test_pair, r.test_order)
    return sorted(keyed, key=lambda p: (keyed[p], p))


def generality(rows: Sequence[ThrowRecord]) -> dict[str, Any]:
    """
    Return the generality of one method's throws: heat maps and mean scores.

    Parameters
    ----------
    rows : list of dict
        Throw records of one method.

    Returns
    -------
    dict
        ``pairs`` (list, matrix order), ``subjects`` (name -> group), ``matrix`` (subject ->
        ndarray (n_pairs, n_pairs) of scores, rows = train pair, columns = test pair, NaN where
        not run), ``mean_matrix`` (average over subjects), ``subject_mean`` (subject -> mean
        score), ``group_mean`` ('experienced', 'naive', 'overall' -> mean over the group's
        throws, NaN without throws), ``n`` (group -> throw count).

    """
    pairs = pair_order(rows)
    index = {p: k for k, p in enumerate(pairs)}
    subjects: dict[str, str] = {}
    matrix: dict[str, np.ndarray] = {}
    for r in rows:
        subjects.setdefault(r.subject, r.group)
        m = matrix.setdefault(r.subject, np.full((len(pairs), len(pairs)), np.nan))
        m[index[r.train_pair], index[r.test_pair]] = r.score
    subject_mean = {s: _mean([r.score for r in rows if r.subject == s]) for s in subjects}
    group_mean: dict[str, float] = {}
    n: dict[str, int] = {}
    for group in GROUPS:
        scores = [r.score for r in rows if r.group == group]
        group_mean[group], n[group] = _mean(scores), len(scores)
    group_mean['overall'] = _mean([r.score for r in rows])
    n['overall'] = len(rows)
    stack = np.array(list(matrix.values())) if matrix else np.zeros((0, len(pairs), len(pairs)))
    with np.errstate(invalid='ignore'), warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)  # all-NaN cells: pairs not run
        mean_matrix = (np.nanmean(stack, axis=0) if len(stack)
                       else np.full((len(pairs), len(pairs)), np.nan))
    return {'pairs': pairs, 'subjects': subjects, 'matrix': matrix, 'mean_matrix': mean_matrix,
            'subject_mean': subject_mean, 'group_mean': group_mean, 'n': n}


def score_counts(rows: Iterable[ThrowRecord]) -> dict[float, int]:
    """Return ``{score level: count}`` for the levels 1.0, 0.8, 0.4, 0.0."""
    rows = list(rows)
    return {level: sum(1 for r in rows if r.score is not None and abs(r.score - level) < 1e-9)
            for level in (1.0, 0.8, 0.4, 0.0)}


def regeneration_rows(rows: Iterable[ThrowRecord]) -> list[ThrowRecord]:
    """Return the regeneration throws (learnt and executed on the same pair)."""
    return [r for r in rows if r.train_pair == r.test_pair]


def regeneration(rows: Iterable[ThrowRecord]) -> dict[str, Any]:
    """
    Return Table II and the regeneration success of one method's throws.

    Parameters
    ----------
    rows : list of dict
        Throw records of one method (the regeneration throws are picked out).

    Returns
    -------
    dict
        ``errors``: (task, 'pos'|'ori', 'start'|'goal'|'traj') -> dict ``mean``, ``std``,
        ``median``, ``n`` (mm or deg; column ``<task>_<point>_<mm|deg>`` of the records);
        ``success`` (complete throws), ``total``, ``rate``.

    """
    regen = regeneration_rows(rows)
    errors: dict[tuple[str, str, str], dict[str, Any]] = {}
    for task in TASKS:
        for kind, unit in ERROR_KINDS:
            for point in ERROR_POINTS:
                column = f'{task}_{point}_{unit}'
                cells = [getattr(r, column) for r in regen]
                values = np.array([v for v in cells if v is not None and not math.isnan(v)],
                                  float)
                errors[(task, kind, point)] = {
                    'mean': float(values.mean()) if values.size else float('nan'),
                    'std': float(values.std(ddof=1)) if values.size > 1 else float('nan'),
                    'median': float(np.median(values)) if values.size else float('nan'),
                    'n': int(values.size), 'column': column}
    success = sum(1 for r in regen if r.score == 1.0)
    total = len(regen)
    return {'errors': errors, 'success': success, 'total': total,
            'rate': success / total if total else float('nan')}


def subtask_success(rows: Iterable[ThrowRecord], group: str | None = 'experienced'
                    ) -> dict[str, Any]:
    """
    Return Table IV: per-subtask success, individual and cumulative, of one group's throws.

    Individual: throws where subtask k succeeded among those where every earlier subtask
    succeeded; cumulative ("overall" in the paper): throws where subtasks 1..k all succeeded,
    over all the group's throws.

    Returns
    -------
    dict
        ``total`` (throws) and, per subtask, ``(individual successes, individual trials,
        cumulative successes)``.

    """
    rows = [r for r in rows if group is None or r.group == group]
    out: dict[str, Any] = {'total': len(rows)}
    alive = rows
    for task in SUBTASKS:
        ok = [r for r in alive if getattr(r, task)]
        out[task] = (len(ok), len(alive), len(ok))
        alive = ok
    return out


def task_times(rows: Iterable[ThrowRecord], demo_rows: Iterable[DemoRecord]
               ) -> dict[str, dict[str, Any]]:
    """
    Return the full-throw times of demonstrations and LfD executions per phantom and pair.

    LfD times are those of complete regeneration throws (learnt and executed on the pair);
    demonstration times those of the demonstrations used for learning. Times are simulated
    seconds.

    Returns
    -------
    dict
        phantom -> {``pairs``: list, ``demo``: pair -> list of s, ``lfd``: pair -> list of s,
        ``demo_mean``, ``lfd_mean``, ``reduction`` (1 - lfd_mean / demo_mean)}.

    """
    out: dict[str, dict[str, Any]] = {}
    for d in demo_rows:
        if not d.ok:
            continue
        ph = out.setdefault(d.phantom, {'pairs': [], 'demo': {}, 'lfd': {}})
        if d.pair not in ph['pairs']:
            ph['pairs'].append(d.pair)
        ph['demo'].setdefault(d.pair, []).append(d.time_s)
    for r in regeneration_rows(rows):
        if r.score != 1.0:
            continue
        ph = out.setdefault(r.test_phantom, {'pairs': [], 'demo': {}, 'lfd': {}})
        if r.test_pair not in ph['pairs']:
            ph['pairs'].append(r.test_pair)
        ph['lfd'].setdefault(r.test_pair, []).append(r.time_s)
    for ph in out.values():
        ph['demo_mean'] = _mean([t for ts in ph['demo'].values() for t in ts])
        ph['lfd_mean'] = _mean([t for ts in ph['lfd'].values() for t in ts])
        ph['reduction'] = (1.0 - ph['lfd_mean'] / ph['demo_mean']
                           if ph['demo_mean'] > 0 else float('nan'))
    return out


def calibration(rows: Sequence[ThrowRecord]) -> list[tuple[str, float, float, float]]:
    """
    Return the calibration targets of the paper method, ours and the residuals.

    Returns
    -------
    list of tuple
        ``(name, target, ours, residual = ours - target)``.

    """
    gen = generality(rows)['group_mean']
    reg = regeneration(rows)
    target_reg = PAPER['regeneration_success'][0] / PAPER['regeneration_success'][1]
    out = []
    for name in ('experienced', 'naive', 'overall'):
        target = PAPER['generality'][name]
        out.append((f'generality {name}', target, gen[name], gen[name] - target))
    out.append(('regeneration success', target_reg, reg['rate'], reg['rate'] - target_reg))
    t4 = subtask_success(rows)
    if t4['total']:
        target = PAPER['table4']['v'][2] / PAPER['table4_total']
        ours = t4['v'][2] / t4['total']
        out.append(('suturing success (experienced)', target, ours, ours - target))
    return out


def markdown(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """Return a Markdown table of ``header`` and ``rows`` (each cell written with ``str``)."""
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join('---' for _ in header) + '|']
    lines += ['| ' + ' | '.join(str(c) for c in row) + ' |' for row in rows]
    return '\n'.join(lines)
