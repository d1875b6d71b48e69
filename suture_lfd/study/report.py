"""
The study's report folder: ``report.md``, CSV files, PNG figures and ``summary.json``.

:func:`write_report` turns the per-job records of a study (:mod:`suture_lfd.study`) into

- ``throws.csv``: one row per executed throw (columns :data:`THROW_COLUMNS`),
- ``demos.csv``: one row per demonstration (columns :data:`DEMO_COLUMNS`),
- ``report.md``: every table of the seed paper's evaluation with the paper's value beside ours,
  the calibration targets and residuals, the figures, the configuration and seeds,
- ``heatmap_<method>.png``, ``task_time_<method>.png``, ``trajectories_<method>.png``,
  ``filmstrip_demo_<method>.png`` and ``filmstrip_throw_<method>.png`` (ECM frames of the
  Fig. 7 subject's demonstration and of its skill executed on another pair),
- ``summary.json``: the numbers of the tables, machine-readable,
- with the needle-in-tissue realism, a section on the needle turning in the jaw
  (:mod:`suture_lfd.study.slips`),
- ``assessment.csv`` and ``assessment/``: the skill assessment of every demonstration and the
  section on learning only from the accepted ones (:mod:`suture_lfd.study.assessed`).

The CSV files and every table depend only on the records (not on wall time), so the same
configuration gives byte-identical CSV files; wall times appear only in the report's run section.
"""

from collections.abc import Iterable, Mapping, Sequence
import csv
from dataclasses import asdict
import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
from sim_bridge.common.archive import load_archive
from suture_lfd.study import figures, slips, tables
from suture_lfd.study.records import DemoRecord, Record, ThrowRecord, columns

#: ``throws.csv``'s columns: the first fields of a throw's record.
THROW_COLUMNS = columns(ThrowRecord)
#: ``demos.csv``'s columns: the first fields of a demonstration's record.
DEMO_COLUMNS = columns(DemoRecord)


def _cell(value: Any) -> str:
    if value is None:
        return ''
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return '' if math.isnan(value) else repr(round(value, 6))
    return str(value)


def write_csv(path: str | Path, rows: Iterable[Mapping[str, Any]], columns: Sequence[str]
              ) -> None:
    """Write ``rows`` (dicts) as CSV with ``columns`` (missing values empty)."""
    with open(path, 'w', newline='') as f:
        writer = csv.writer(f, lineterminator='\n')
        writer.writerow(columns)
        for r in rows:
            writer.writerow([_cell(r.get(c)) for c in columns])


def read_csv(path: str | Path) -> list[dict[str, str]]:
    """Read a CSV written by :func:`write_csv` back into a list of dicts of strings."""
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def _f(value: float | np.floating[Any] | None, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return '–'
    return f'{value:.{digits}f}'


_table = tables.markdown


def _table2(reg: Mapping[str, Any]) -> str:
    rows = []
    for task in tables.TASKS:
        for kind, unit in tables.ERROR_KINDS:
            for point in tables.ERROR_POINTS:
                e = reg['errors'][(task, kind, point)]
                pm, ps, pmed = tables.PAPER['table2'][(task, kind, point)]
                paper = f'{pm:.2f} ± {ps:.2f}' + (f' (median {pmed:.2f})' if pmed else '')
                rows.append([f'task {task} {"position" if kind == "pos" else "orientation"} '
                             f'({unit})', point if point != 'traj' else 'trajectory',
                             _f(e['mean']), _f(e['std']), _f(e['median']), e['n'], paper])
    return _table(['item', 'point', 'mean', 'std', 'median', 'n', 'paper mean ± std'], rows)


def _table3(gen: Mapping[str, Any]) -> str:
    rows = []
    for name in ('experienced', 'naive', 'overall'):
        ours = gen['group_mean'][name]
        paper = tables.PAPER['generality'][name]
        rows.append([name.capitalize(), _f(ours, 3), gen['n'][name], f'{paper:.3f}',
                     _f(ours - paper, 3)])
    return _table(['user', 'generality', 'throws', 'paper', 'ours − paper'], rows)


def _table4(t4: Mapping[str, Any]) -> str:
    rows = []
    total = t4['total']
    for task in tables.SUBTASKS:
        ok, trials, cum = t4[task]
        pok, ptrials, pcum = tables.PAPER['table4'][task]
        ptotal = tables.PAPER['table4_total']
        rows.append([task, f'{ok} / {trials}', f'{cum} / {total}',
                     _f(100.0 * cum / total if total else float('nan'), 1) + ' %',
                     f'{pok} / {ptrials}', f'{pcum} / {ptotal}',
                     f'{100.0 * pcum / ptotal:.1f} %'])
    return _table(['task', 'individual', 'overall', 'overall %', 'paper individual',
                   'paper overall', 'paper %'], rows)


def _time_table(times: Mapping[str, Mapping[str, Any]]) -> str:
    rows = []
    for phantom, ph in times.items():
        paper = tables.PAPER['time_reduction'].get(phantom)
        paper = f'{paper * 100:.0f} %' if isinstance(paper, float) else (paper or '–')
        n_demo = sum(len(v) for v in ph['demo'].values())
        n_lfd = sum(len(v) for v in ph['lfd'].values())
        rows.append([phantom, f'{_f(ph["demo_mean"])} (n={n_demo})',
                     f'{_f(ph["lfd_mean"])} (n={n_lfd})', _f(100.0 * ph['reduction'], 1) + ' %',
                     paper])
    return _table(['phantom', 'demonstration (s)', 'LfD (s)', 'time reduction',
                   'paper reduction'], rows)


def _subject_table(gen: Mapping[str, Any], demo_rows: Sequence[DemoRecord]) -> str:
    rows = []
    for s, group in gen['subjects'].items():
        own = [d for d in demo_rows if d.subject == s]
        ok = sum(1 for d in own if d.ok)
        m = gen['matrix'][s]
        n = len(gen['pairs'])
        diag = np.nanmean(np.diag(m)) if n else float('nan')
        phantoms = {p: p.rstrip('0123456789') for p in gen['pairs']}
        same = [m[i, j] for i in range(n) for j in range(n)
                if phantoms[gen['pairs'][i]] == phantoms[gen['pairs'][j]]]
        cross = [m[i, j] for i in range(n) for j in range(n)
                 if phantoms[gen['pairs'][i]] != phantoms[gen['pairs'][j]]]
        rows.append([s, group, f'{ok} / {len(own)}', _f(gen['subject_mean'][s], 3),
                     _f(diag, 3), _f(np.nanmean(same) if same else float('nan'), 3),
                     _f(np.nanmean(cross) if cross else float('nan'), 3)])
    return _table(['subject', 'group', 'demos ok', 'generality', 'same pair',
                   'same phantom', 'other phantom'], rows)


def _fig7_curves(folder: str | Path, rows: Sequence[ThrowRecord]
                 ) -> tuple[ThrowRecord | None, dict[str, dict[str, np.ndarray]] | None]:
    """Pick the paper's Fig. 7 case (first subject at scan2, else the first regeneration)."""
    regen = [r for r in tables.regeneration_rows(rows) if r.trajectories]
    if not regen:
        return None, None
    pick = next((r for r in regen if r.test_pair == 'scan2'), regen[0])
    if pick.trajectories is None:
        return None, None
    path = Path(folder) / pick.trajectories
    if not path.exists():
        return None, None
    from suture_lfd.study.jobs import TRAJECTORIES_FORMAT, TRAJECTORIES_FORMAT_VERSION

    data = load_archive(path, TRAJECTORIES_FORMAT, TRAJECTORIES_FORMAT_VERSION, 'trajectory file')
    curves: dict[str, dict[str, np.ndarray]] = {}
    for task in tables.TASKS:
        entry: dict[str, np.ndarray] = {}
        for label, name in (('demonstration', f'demo_{task}'), ('DMP', f'rollout_{task}'),
                            ('executed', f'exec_{task}')):
            if name in data and data[name].shape[0] > 1:
                entry[label] = data[name]
        if len(entry) > 1:
            curves[task] = entry
    return pick, curves


def _goal_note(method: str, config: Mapping[str, Any]) -> str:
    """Say how the method fits its weights, and what that does to task iv's goal error."""
    from suture_lfd.skill import METHODS

    known = METHODS.get(method)
    regression = known.regression if known is not None else 'lwr'
    why = ("Task iv's needle centre rests while the needle turns about it and moves only in "
           'the pull at the end of the subtask; the rollout runs over the demonstrated '
           'duration, so at t = T the phase is still exp(-alpha_x) = 0.37 (alpha_x = 1) and '
           'the forcing term still acts.')
    if regression == 'lwr':
        return (f'Weights fitted by LWR as in the paper (Table I bases). {why} LWR fits each '
                'basis function alone, a weighted average of the target under it, and the '
                'bases of width N^1.5 / (alpha_x c_i) span two to three centre spacings: the '
                'short pull is smoothed away and the rollout ends short of the goal.')
    return (f'Weights fitted by least squares over all basis functions (the paper: LWR; same '
            f'Table I bases, alpha_x, gains and points). {why} The joint fit keeps the short '
            'pull that LWR smooths away, so the rollout reaches the goal.')


def _filmstrips(folder: Path, rows: Sequence[ThrowRecord], demo_rows: Sequence[DemoRecord],
                pick: ThrowRecord, method: str) -> list[str]:
    """
    Draw the filmstrips of the Fig. 7 subject: its demonstration and a throw on another pair.

    Returns the report lines (none when a file is missing or cannot be drawn).
    """
    from suture_lfd.viewer.filmstrip import write_filmstrip
    from suture_lfd.viewer.replay import recording_from_bag
    from suture_lfd.viewer.throw_replay import recording_from_file

    folder = Path(folder)
    demo = next((d for d in demo_rows if d.subject == pick.subject
                 and d.pair == pick.train_pair and d.bag), None)
    other = [r for r in rows if r.subject == pick.subject
             and r.train_pair == pick.train_pair and r.test_pair != pick.train_pair
             and r.replay and (folder / r.replay).is_file()]
    if demo is None or not (folder / demo.bag).is_dir() or not other:
        return []
    throw = max(other, key=lambda r: (r.score or 0.0,
                                      r.test_phantom == pick.train_phantom))
    demo_png = f'filmstrip_demo_{method}.png'
    throw_png = f'filmstrip_throw_{method}.png'
    try:
        write_filmstrip(recording_from_bag(folder / demo.bag), folder / demo_png,
                        title=f'demonstration: {demo.subject} at {demo.pair}')
        write_filmstrip(recording_from_file(folder / (throw.replay or '')), folder / throw_png,
                        title=f'learnt at {throw.train_pair}, executed at '
                              f'{throw.test_pair} (score {_f(throw.score, 1)})')
    except (ValueError, OSError) as exc:
        logging.getLogger(__name__).warning('filmstrips not drawn: %s', exc)
        return []
    return ['#### Seen from the ECM', '',
            f'The demonstration of {demo.subject} at {demo.pair}, and the skill learnt '
            f'from it executed at {throw.test_pair} (frames at the subtask starts and the '
            f'end, rendered offline from the recorded poses; replay it with `suture-lfd view '
            f'<study folder> --throw throw/{method}/{throw.subject}/{throw.train_pair}/'
            f'{throw.test_pair}`).', '', f'![demonstration]({demo_png})', '',
            f'![regeneration on another pair]({throw_png})', '']


def summarise(records: Sequence[Record]) -> dict[str, Any]:
    """
    Return the numbers of every table for every method (JSON-serialisable).

    Parameters
    ----------
    records : list of DemoRecord or ThrowRecord
        Study records.

    Returns
    -------
    dict
        method -> {'generality', 'regeneration', 'table4', 'task_time', 'score_counts',
        'calibration'}.

    """
    demo_rows = tables.demos(records)
    out = {}
    for method in tables.methods(records):
        rows = tables.throws(records, method)
        gen = tables.generality(rows)
        reg = tables.regeneration(rows)
        t4 = tables.subtask_success(rows)
        times = tables.task_times(rows, demo_rows)
        out[method] = {
            'generality': {'group_mean': gen['group_mean'], 'n': gen['n'],
                           'subject_mean': gen['subject_mean'], 'pairs': gen['pairs'],
                           'mean_matrix': gen['mean_matrix'].tolist()},
            'regeneration': {'success': reg['success'], 'total': reg['total'],
                             'rate': reg['rate'],
                             'errors': {'/'.join(k): v for k, v in reg['errors'].items()}},
            'table4': t4,
            'task_time': {p: {k: v for k, v in ph.items() if k in ('demo_mean', 'lfd_mean',
                                                                     'reduction')}
                          for p, ph in times.items()},
            'score_counts': {str(k): v for k, v in tables.score_counts(rows).items()},
            'calibration': [list(c) for c in tables.calibration(rows)],
        }
    return out


def _nan_to_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _nan_to_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_nan_to_none(v) for v in value]
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def write_report(folder: str | Path, records: Sequence[Record], config: Mapping[str, Any],
                 run_info: Mapping[str, Any] | None = None) -> Path:
    """
    Write the report folder of a study from its records.

    Parameters
    ----------
    folder : str or Path
        Report folder (exists).
    records : list of DemoRecord or ThrowRecord
        Study records (:mod:`suture_lfd.study.records`).
    config : dict
        The exact configuration (seeds, design, methods, cohort, files) to print.
    run_info : dict, optional
        Wall time and throughput of the run (``wall_s``, ``jobs_run``, ``workers``,
        ``command``, ``resumed``); printed in the run section only.

    Returns
    -------
    Path
        The ``report.md`` written.

    """
    folder = Path(folder)
    run_info = run_info or {}
    demo_rows = tables.demos(records)
    throw_rows = tables.throws(records)
    write_csv(folder / 'throws.csv', [asdict(r) for r in throw_rows], THROW_COLUMNS)
    write_csv(folder / 'demos.csv', [asdict(r) for r in demo_rows], DEMO_COLUMNS)
    summary = summarise(records)
    (folder / 'summary.json').write_text(
        json.dumps(_nan_to_none(summary), indent=1, sort_keys=True) + '\n')
    errors = [r for r in records if r.error]

    md = ['# Study report: suturing skills learnt from demonstrations (simulation)', '']
    md += [
        'This folder reproduces the evaluation of the seed paper (Zhou et al., "Suturing Tasks '
        'Automation Based on Skills Learned From Demonstrations: A Simulation Study", ISMR 2024) '
        "in the package's simulated dVRK. **The subjects are synthetic**: a cohort model "
        "(`config/cohort.yaml`) of the paper's 10 users (4 experienced, 6 naive), calibrated "
        "so that the `paper` method on it lands near the paper's figures. Agreement with the "
        'paper on the calibrated numbers is therefore by construction; the other numbers '
        '(errors, success rates per subtask, times, other methods) are what the model '
        'predicts.', '',
        f'Subjects: {len({d.subject for d in demo_rows})}; demonstrations: {len(demo_rows)} '
        f'({sum(1 for d in demo_rows if d.ok)} usable); executed throws: '
        f'{len(throw_rows)}; methods: {", ".join(summary) or "none"}; jobs that raised an '
        f'error: {len(errors)}.', '',
        'Files: `throws.csv` (one row per executed throw), `demos.csv` (one row per '
        'demonstration), `summary.json` (every number below), PNG figures, `bags/` (the '
        'demonstrations as rosbag2 bags), `segments/` (their segment files), `replays/` (what '
        'the viewer needs to replay each throw: `suture-lfd view <this folder> --throw ROW`, '
        'ROW a row of `throws.csv`), `results.jsonl` (the per-job results, found by the '
        "digest of each job's inputs: resume and reuse).", '']
    for method, s in summary.items():
        rows = tables.throws(records, method)
        gen = tables.generality(rows)
        reg = tables.regeneration(rows)
        times = tables.task_times(rows, demo_rows)
        md += [f'## Method `{method}`', '']
        description = config.get('method_descriptions', {}).get(method)
        if description:
            md += [description, '']
        md += ['### Calibration (targets of the cohort model)', '',
               _table(['quantity', 'paper (target)', 'ours', 'residual (ours − paper)'],
                      [[name, _f(t, 3), _f(o, 3), _f(o - t, 3)]
                       for name, t, o, _ in tables.calibration(rows)]), '']
        md += ['### Table II: errors of the regenerated trajectories', '',
               "Regeneration: each subject's skill learnt on a pair and executed on the same "
               'pair (the diagonal of the generality matrix). Errors of the DMP-regenerated '
               'needle trajectory of tasks ii and iv against the demonstrated one (both '
               'resampled as in the paper): start and goal (t = T) errors, and the trajectory '
               'error = mean distance along the DTW warping path (position: Euclidean, mm; '
               'orientation: rotation angle, deg). The `*_exec_traj_mm` CSV columns give the '
               'same trajectory error for the needle trajectory the simulator actually '
               'executed.', '', _table2(reg), '', _goal_note(method, config), '',
               f'Regeneration success (complete throws): **{reg["success"]} / {reg["total"]} '
               f'= {_f(100.0 * reg["rate"], 1)} %** (paper: 76 / 80 = 95 %).', '']
        md += ['### Table III: generality', '',
               "Each subject's skill learnt on each pair and executed on every pair; score of "
               'a throw: 1.0 complete, 0.8 only the exit marker missed, 0.4 entry marker '
               "missed on a reasonable trajectory, 0 otherwise. Mean over the group's "
               'throws.', '', _table3(gen), '',
               'Score levels: ' + ', '.join(f'{k}: {v}' for k, v in s['score_counts'].items()),
               '', '#### Per subject', '', _subject_table(gen, demo_rows), '',
               f'![generality heat maps](heatmap_{method}.png)', '']
        t4 = tables.subtask_success(rows)
        md += ["### Table IV: success rate of the experienced users' skills", '',
               'Individual: successes of a subtask among the throws that reached it; overall: '
               'throws with every subtask up to it successful, over all throws.', '',
               _table4(t4), '']
        md += ['### Task time', '',
               'Full-throw time (simulated seconds) of the demonstrations and of the complete '
               'regeneration throws, per phantom.', '', _time_table(times), '',
               f'![task time](task_time_{method}.png)', '']
        figures.heat_maps(gen, folder / f'heatmap_{method}.png',
                          title=f'generality, method {method}')
        figures.task_time_bars(times, folder / f'task_time_{method}.png',
                               title=f'task time, method {method}')
        pick, curves = _fig7_curves(folder, rows)
        if pick is not None and curves:
            figures.trajectory_figure(
                curves, folder / f'trajectories_{method}.png',
                title=f'{pick.subject} at {pick.test_pair}, method {method}')
            md += ['### Demonstrated and regenerated needle trajectories (Fig. 7)', '',
                   f'Subject {pick.subject} ({pick.group}), pair {pick.test_pair}.',
                   '', f'![trajectories](trajectories_{method}.png)', '']
            md += _filmstrips(folder, rows, demo_rows, pick, method)
    if len(summary) > 1:
        md += ['## Methods side by side', '',
               _table(['method', 'generality exp.', 'naive', 'overall', 'regeneration success',
                       'suturing success (exp.)'],
                      [[m, _f(s['generality']['group_mean']['experienced'], 3),
                        _f(s['generality']['group_mean']['naive'], 3),
                        _f(s['generality']['group_mean']['overall'], 3),
                        _f(100.0 * s['regeneration']['rate'], 1) + ' %',
                        (_f(100.0 * s['table4']['v'][2] / s['table4']['total'], 1) + ' %')
                        if s['table4']['total'] else '–']
                       for m, s in summary.items()]), '']
    md += slips.report_section(records, config)
    mode = config.get('assessment', 'subject')
    if mode != 'off':
        from suture_lfd.study.assessed import report_section

        lines, assessed = report_section(folder, records, mode)
        md += lines
        if assessed:
            summary_all = json.loads((folder / 'summary.json').read_text())
            summary_all['skill_assessment'] = _nan_to_none(assessed)
            (folder / 'summary.json').write_text(
                json.dumps(summary_all, indent=1, sort_keys=True) + '\n')
    if errors:
        md += ['## Jobs that raised an error', '',
               _table(['job', 'error'], [[r.key, r.error] for r in errors[:50]]), '']
    md += ['## Run', '']
    if run_info:
        md += [f'- command: `{run_info.get("command", "")}`',
               f'- workers: {run_info.get("workers", "")}',
               f'- jobs run by this invocation: {run_info.get("jobs_run", 0)} '
               f'(reused from the results stored in the folder: {run_info.get("resumed", 0)}, '
               'jobs found by the digest of their inputs and code)',
               f'- wall time of this invocation: {_f(run_info.get("wall_s", float("nan")), 1)} s',
               f'- throughput: {_f(run_info.get("rate", float("nan")), 3)} jobs/s', '']
    wall = [r.wall_s for r in records if r.wall_s is not None]
    if wall:
        md += [f'- CPU-side time per job (sum over jobs, any invocation): '
               f'{_f(sum(wall), 1)} s over {len(wall)} jobs', '']
    md += ['## Configuration and seeds', '',
           'Rerun with the same command (same seed, same configuration files) to get the same '
           'CSV files; the configuration hash names the results file.', '',
           '```json', json.dumps(config, indent=1, sort_keys=True, default=str), '```', '']
    path = folder / 'report.md'
    path.write_text('\n'.join(md))
    return path
