"""
Learning with skill assessment: the study's demonstrations scored and screened.

The generality of the skills learnt only from the accepted demonstrations, beside it.

:func:`score_demonstrations` scores every usable demonstration of a study from its bag and
segment file (:mod:`suture_lfd.assessment`), writes one table per demonstration
(``assessment/<subject>_<pair>.csv``, reused when present) and ``assessment.csv`` with all of
them and the verdict of the acceptance rule (:mod:`suture_lfd.assessment.acceptance`), which
sees demonstrations only, never a throw.

:func:`assessed_generality` then gives each subject a skill library learnt only from accepted
demonstrations: a rejected demonstration's pair is learnt instead from

- ``'subject'``: the subject's own accepted demonstration with the best combined score (or, for
  a subject with none accepted, as ``'cohort'``);
- ``'cohort'``: the accepted demonstration of the same pair with the best combined score in
  the cohort.

The replacement skill's throws on every test pair are the study's throws of that skill (the
same skill on the same pairs; the scene seed is the replacement demonstration's own), so the
generality with assessment costs no further throw.
"""

from collections.abc import Iterable, Mapping, Sequence
import csv
from dataclasses import replace
import logging
import math
from pathlib import Path
from typing import Any

from suture_lfd.assessment.acceptance import AcceptanceRule, assess_cohort
from suture_lfd.study import tables
from suture_lfd.study.records import DemoRecord, Record, ThrowRecord

_LOG = logging.getLogger(__name__)
MODES = ('subject', 'cohort', 'off')
VERDICT_COLUMNS = ('subject', 'group', 'pair', 'combined_score', 'accepted', 'reasons')


def _cell(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return '' if math.isnan(value) else repr(round(value, 6))
    return '' if value is None else str(value)


def score_demonstrations(folder: str | Path, demo_records: Iterable[DemoRecord],
                         rule: AcceptanceRule | None = None) -> list[dict[str, Any]]:
    """
    Score and screen the study's usable demonstrations.

    Parameters
    ----------
    folder : str or Path
        Report folder (holds ``bags/`` and ``segments/``).
    demo_records : list of dict
        Demonstration records (``ok`` ones are scored).
    rule : AcceptanceRule, optional

    Returns
    -------
    list of dict
        One row per scored demonstration: ``subject``, ``group``, ``pair``, the scores,
        ``combined_score``, ``accepted``, ``reasons``; empty when fewer than two reference
        demonstrations exist.

    """
    from suture_lfd.assessment.demo_scores import (
        assess_bag,
        read_score_table,
        write_score_table,
    )

    folder = Path(folder)
    rule = AcceptanceRule() if rule is None else rule
    tables_dir = folder / 'assessment'
    tables_dir.mkdir(exist_ok=True)
    rows = []
    for d in demo_records:
        if not d.ok or not d.bag or not d.segments:
            continue
        table = tables_dir / f'{d.subject}_{d.pair}.csv'
        scores = None
        if table.exists():
            scores = read_score_table(table)
        if scores is None or 'task_time_s' not in scores:
            try:
                scores = assess_bag(folder / d.bag, folder / d.segments, pair=d.pair)
            except (ValueError, OSError) as exc:
                _LOG.warning('demonstration %s/%s not scored: %s', d.subject, d.pair, exc)
                continue
        scores = {k: v for k, v in scores.items() if k not in VERDICT_COLUMNS}
        rows.append({'subject': d.subject, 'group': d.group, 'pair': d.pair,
                     **scores})
    try:
        verdicts = assess_cohort(rows, rule)
    except ValueError as exc:
        _LOG.warning('no skill assessment: %s', exc)
        return []
    for row, verdict in zip(rows, verdicts):
        row.update(verdict)
        write_score_table(tables_dir / f'{row["subject"]}_{row["pair"]}.csv', row)
    if rows:
        columns = list(VERDICT_COLUMNS) + [k for k in rows[0] if k not in VERDICT_COLUMNS]
        with open(folder / 'assessment.csv', 'w', newline='') as f:
            writer = csv.writer(f, lineterminator='\n')
            writer.writerow(columns)
            for row in rows:
                writer.writerow([_cell(row.get(c)) for c in columns])
    return rows


def learnt_from(verdicts: Sequence[Mapping[str, Any]], mode: str
                ) -> dict[tuple[str, str], tuple[str, str]]:
    """
    Return which demonstration each subject's pair is learnt from under assessment.

    Parameters
    ----------
    verdicts : list of dict
        Rows of :func:`score_demonstrations`.
    mode : {'subject', 'cohort'}

    Returns
    -------
    dict
        ``(subject, pair) -> (subject', pair')`` for every rejected demonstration that has a
        replacement (accepted ones learn from themselves and are not listed).

    """
    if mode not in ('subject', 'cohort'):
        raise ValueError(f"assessment mode must be 'subject' or 'cohort', got {mode!r}")
    accepted = [v for v in verdicts if v['accepted']]

    def best(candidates: Sequence[Mapping[str, Any]]) -> Mapping[str, Any]:
        return min(candidates, key=lambda v: (v['combined_score'], v['subject'], v['pair']))

    out: dict[tuple[str, str], tuple[str, str]] = {}
    for v in verdicts:
        if v['accepted']:
            continue
        own = [a for a in accepted if a['subject'] == v['subject']]
        same_pair = [a for a in accepted if a['pair'] == v['pair']]
        pick = best(own) if mode == 'subject' and own else (best(same_pair) if same_pair
                                                            else None)
        if pick is not None:
            out[(v['subject'], v['pair'])] = (pick['subject'], pick['pair'])
    return out


def assessed_generality(throw_rows: Iterable[ThrowRecord], verdicts: Sequence[Mapping[str, Any]],
                        mode: str) -> dict[str, Any]:
    """
    Return the generality of one method's skills learnt only from accepted demonstrations.

    Parameters
    ----------
    throw_rows : list of ThrowRecord
        Throw records of one method.
    verdicts : list of dict
        Rows of :func:`score_demonstrations`.
    mode : {'subject', 'cohort'}

    Returns
    -------
    dict
        :func:`suture_lfd.study.tables.generality` of the throws with every rejected row
        replaced, plus ``replaced`` (the :func:`learnt_from` map).

    """
    replaced = learnt_from(verdicts, mode)
    by_row: dict[tuple[str, str], list[ThrowRecord]] = {}
    for r in throw_rows:
        by_row.setdefault((r.subject, r.train_pair), []).append(r)
    rows = []
    for (subject, pair), own in by_row.items():
        source = replaced.get((subject, pair))
        if source is None:
            rows.extend(own)
            continue
        for r in by_row.get(source, []):
            rows.append(replace(r, subject=subject, group=own[0].group, train_pair=pair,
                                train_order=own[0].train_order))
    out = tables.generality(rows)
    out['replaced'] = replaced
    return out


def _f(value: float | None, digits: int = 3) -> str:
    return '–' if value is None or (isinstance(value, float) and math.isnan(value)) \
        else f'{value:.{digits}f}'


def report_section(folder: str | Path, records: Sequence[Record], mode: str = 'subject',
                   rule: AcceptanceRule | None = None) -> tuple[list[str], dict[str, Any]]:
    """
    Return the report's "Skill assessment" section (markdown lines) and its numbers.

    Parameters
    ----------
    folder : str or Path
        Report folder.
    records : list of DemoRecord or ThrowRecord
        Study records.
    mode : {'subject', 'cohort', 'off'}
        How rejected demonstrations are replaced; ``'off'`` gives no section.
    rule : AcceptanceRule, optional

    Returns
    -------
    lines : list of str
    summary : dict
        ``mode``, ``accepted`` (group -> [accepted, scored]) and, per method, the group means
        without and with assessment.

    """
    if mode == 'off':
        return [], {}
    if mode not in MODES:
        raise ValueError(f'assessment mode must be one of {MODES}, got {mode!r}')
    rule = AcceptanceRule() if rule is None else rule
    verdicts = score_demonstrations(folder, tables.demos(records), rule)
    if not verdicts:
        return [], {}
    accepted = {g: [sum(1 for v in verdicts if v['group'] == g and v['accepted']),
                    sum(1 for v in verdicts if v['group'] == g)] for g in tables.GROUPS}
    summary: dict[str, Any] = {'mode': mode, 'accepted': accepted, 'methods': {}}
    other = 'cohort' if mode == 'subject' else 'subject'
    rows_md = []
    for method in tables.methods(records):
        rows = tables.throws(records, method)
        before = tables.generality(rows)['group_mean']
        with_mode = assessed_generality(rows, verdicts, mode)['group_mean']
        with_other = assessed_generality(rows, verdicts, other)['group_mean']
        summary['methods'][method] = {'without': before, mode: with_mode, other: with_other}
        for group in tables.GROUPS + ('overall',):
            rows_md.append(f'| {method} | {group} | {_f(before[group])} | '
                           f'{_f(with_mode[group])} | {_f(with_other[group])} |')
    scored = ', '.join(f'{g}: {a} of {n} accepted' for g, (a, n) in accepted.items())
    bounds_text = ', '.join(rule.metrics)
    lines = [
        '## Skill assessment', '',
        'Every usable demonstration is scored from its bag and segment file '
        '(`assessment/<subject>_<pair>.csv`, all in `assessment.csv`; `suture-lfd assess BAG` '
        'scores one): task and subtask times; per instrument path length, economy of motion, '
        'RMS and log dimensionless jerk, velocity peaks, spectral arc length, idle time and '
        'movements (Moorthy 2004, Vedula 2016, Balasubramanian 2015); idle time of both '
        'instruments; entry and exit accuracy where the needle tip crossed the surface, tilt '
        'of the needle plane during the insertion and the needle-to-arc deviation of its '
        'punctures inside the tissue (Frischknecht 2013); grasps and regrasps.', '',
        f'Acceptance (expert-derived proficiency bounds, no throw outcome seen): a '
        f'demonstration is accepted when each of {bounds_text} is at most the mean + '
        f"{rule.k_sd:g} SD of the {rule.reference_group} subjects' demonstrations, the "
        f"assessed subject's own left out; combined score = the largest of its z-scores. "
        f'{scored}.', '',
        f"With assessment (`--assessment {mode}`, the study's setting; the other mode beside "
        "it): a rejected demonstration's pair is learnt from "
        + ("the subject's own accepted demonstration with the best combined score (a subject "
           'with none accepted: the best accepted demonstration of that pair in the cohort)'
           if mode == 'subject' else
           'the best accepted demonstration of that pair in the cohort')
        + "; that skill's throws on every test pair are the study's throws of it. "
        'Generality = mean throw score.', '',
        '| method | user | without assessment | with assessment '
        f'({mode}) | with assessment ({other}) |',
        '|---|---|---|---|---|', *rows_md, '',
        '### Demonstrations excluded', '']
    replaced = learnt_from(verdicts, mode)
    excluded = [v for v in verdicts if not v['accepted']]
    if excluded:
        lines += ['| subject | group | pair | combined score | why | learnt instead from |',
                  '|---|---|---|---|---|---|']
        for v in excluded:
            source = replaced.get((v['subject'], v['pair']))
            lines.append(f'| {v["subject"]} | {v["group"]} | {v["pair"]} | '
                         f'{_f(v["combined_score"], 2)} | {v["reasons"]} | '
                         + (f'{source[0]} {source[1]}' if source else '–') + ' |')
    else:
        lines.append('None.')
    lines.append('')
    return lines, summary
