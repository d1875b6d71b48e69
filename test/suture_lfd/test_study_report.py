"""The study's tables, report, CSV, result store and progress, on hand-made records."""

from dataclasses import replace
import io
import json
import math

import numpy as np
import pytest
from suture_lfd.study import report
from suture_lfd.study import tables as study_tables
from suture_lfd.study.records import DemoJob, DemoRecord, ThrowRecord, columns
from suture_lfd.study.runner import Progress
from suture_lfd.study.store import ResultStore, config_hash, earlier_format_files

PAIRS = [('synthetic', 'synth1'), ('synthetic', 'synth2'), ('scanned', 'scan1')]
SUBJECTS = [('S01', 'experienced'), ('S02', 'naive'), ('S03', 'naive')]
LEVELS = {1.0: (True,) * 5, 0.8: (True, False, True, True, True),
          0.4: (False, True, True, True, True), 0.0: (True, True, False, False, False)}


def synthetic_records(seed=0, methods=('paper', 'other')):
    rng = np.random.default_rng(seed)
    records = []
    for name, group in SUBJECTS:
        for k, (ph, pair) in enumerate(PAIRS):
            records.append(DemoRecord(key=f'demo/{name}/{pair}', id=f'i-{name}-{pair}',
                                      subject=name, group=group, phantom=ph, pair=pair,
                                      order=k, seed=7, attempts=1, ok=True, demo_score=1.0,
                                      time_s=float(20 + rng.uniform(0, 5)), failure=''))
    for method in methods:
        for name, group in SUBJECTS:
            for a, (tph, train) in enumerate(PAIRS):
                for b, (eph, test) in enumerate(PAIRS):
                    score = float(rng.choice([1.0, 1.0, 0.8, 0.4, 0.0]))
                    key = f'throw/{method}/{name}/{train}/{test}'
                    r = {'key': key, 'id': f'i-{key}',
                         'subject': name, 'group': group, 'method': method,
                         'train_phantom': tph, 'train_pair': train, 'train_order': a,
                         'test_phantom': eph, 'test_pair': test, 'test_order': b,
                         'regeneration': train == test, 'seed': int(rng.integers(1 << 30)),
                         'score': score, 'failure': '' if score == 1.0 else 'x',
                         'time_s': float(15 + rng.uniform(0, 5)), 'demo_time_s': 22.0,
                         'entry_error_mm': float(rng.uniform(0, 3)),
                         'exit_error_mm': float('nan')}
                    r.update(zip(study_tables.SUBTASKS, LEVELS[score]))
                    if train == test:
                        for task in ('ii', 'iv'):
                            for point in ('start', 'goal', 'traj'):
                                r[f'{task}_{point}_mm'] = float(rng.uniform(0, 1))
                                r[f'{task}_{point}_deg'] = float(rng.uniform(0, 5))
                    records.append(ThrowRecord(**r))
    return records


def test_generality_means_are_the_group_means_of_the_scores():
    rows = study_tables.throws(synthetic_records(), 'paper')
    gen = study_tables.generality(rows)
    assert gen['pairs'] == [p for _, p in PAIRS]
    for group in ('experienced', 'naive'):
        scores = [r.score for r in rows if r.group == group]
        assert gen['group_mean'][group] == pytest.approx(np.mean(scores))
        assert gen['n'][group] == len(scores)
    assert gen['group_mean']['overall'] == pytest.approx(np.mean([r.score for r in rows]))
    m = gen['matrix']['S02']
    for r in rows:
        if r.subject == 'S02':
            i, j = gen['pairs'].index(r.train_pair), gen['pairs'].index(r.test_pair)
            assert m[i, j] == r.score
    assert np.allclose(gen['mean_matrix'], np.mean(list(gen['matrix'].values()), axis=0))


def test_subtask_success_counts_individual_and_cumulative():
    rows = study_tables.throws(synthetic_records(), 'paper')
    t4 = study_tables.subtask_success(rows, 'experienced')
    exp = [r for r in rows if r.group == 'experienced']
    assert t4['total'] == len(exp)
    reached = exp
    for task in study_tables.SUBTASKS:
        ok = [r for r in reached if getattr(r, task)]
        assert t4[task] == (len(ok), len(reached), len(ok))
        reached = ok
    # the cumulative count of v is the complete throws: every subtask succeeded
    assert t4['v'][2] == sum(1 for r in exp if all(getattr(r, t) for t in study_tables.SUBTASKS))


def test_regeneration_uses_only_the_diagonal():
    rows = study_tables.throws(synthetic_records(), 'paper')
    reg = study_tables.regeneration(rows)
    diag = [r for r in rows if r.train_pair == r.test_pair]
    assert reg['total'] == len(diag) == len(SUBJECTS) * len(PAIRS)
    assert reg['success'] == sum(r.score == 1.0 for r in diag)
    e = reg['errors'][('iv', 'ori', 'traj')]
    values = [r.iv_traj_deg for r in diag]
    assert e['mean'] == pytest.approx(np.mean(values))
    assert e['median'] == pytest.approx(np.median(values))
    assert e['std'] == pytest.approx(np.std(values, ddof=1))


def test_report_tables_agree_with_its_csv(tmp_path):
    records = synthetic_records()
    config = {'seed': 3, 'methods': ['paper', 'other']}
    path = report.write_report(tmp_path, records, config, {'wall_s': 1.0, 'jobs_run': 3})
    text = path.read_text()
    rows = report.read_csv(tmp_path / 'throws.csv')
    assert len(rows) == sum(isinstance(r, ThrowRecord) for r in records)
    assert tuple(rows[0]) == report.THROW_COLUMNS == columns(ThrowRecord)
    summary = json.loads((tmp_path / 'summary.json').read_text())
    for method in ('paper', 'other'):
        mine = [r for r in rows if r['method'] == method]
        for group in ('experienced', 'naive'):
            mean = np.mean([float(r['score']) for r in mine if r['group'] == group])
            assert summary[method]['generality']['group_mean'][group] == pytest.approx(mean)
            assert f'| {group.capitalize()} | {mean:.3f} |' in text
        exp = [r for r in mine if r['group'] == 'experienced']
        complete = sum(all(r[t] == 'true' for t in study_tables.SUBTASKS) for r in exp)
        assert '| v | ' in text and f'{complete} / {len(exp)}' in text
    for name in ('heatmap_paper.png', 'task_time_paper.png', 'heatmap_other.png'):
        assert (tmp_path / name).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert '0.915' in text and '0.742' in text and 'synthetic' in text
    demos = report.read_csv(tmp_path / 'demos.csv')
    assert len(demos) == len(SUBJECTS) * len(PAIRS)


def test_the_csv_is_the_same_for_the_same_records_in_any_order(tmp_path):
    records = synthetic_records(seed=5)
    shuffled = list(records)
    np.random.default_rng(1).shuffle(shuffled)
    (tmp_path / 'a').mkdir()
    (tmp_path / 'b').mkdir()
    report.write_report(tmp_path / 'a', records, {}, {'wall_s': 1.0})
    report.write_report(tmp_path / 'b', shuffled, {}, {'wall_s': 99.0})
    for name in ('throws.csv', 'demos.csv', 'summary.json'):
        assert (tmp_path / 'a' / name).read_bytes() == (tmp_path / 'b' / name).read_bytes()


def test_task_times_compare_complete_regenerations_with_demonstrations():
    records = synthetic_records()
    rows = study_tables.throws(records, 'paper')
    times = study_tables.task_times(rows, study_tables.demos(records))
    lfd = [r.time_s for r in rows if r.test_phantom == 'scanned'
           and r.train_pair == r.test_pair and r.score == 1.0]
    demo = [d.time_s for d in study_tables.demos(records) if d.phantom == 'scanned']
    assert times['scanned']['demo_mean'] == pytest.approx(np.mean(demo))
    if lfd:
        assert times['scanned']['lfd_mean'] == pytest.approx(np.mean(lfd))
        assert times['scanned']['reduction'] == pytest.approx(1 - np.mean(lfd) / np.mean(demo))
    else:
        assert math.isnan(times['scanned']['lfd_mean'])


def test_calibration_residuals_are_ours_minus_the_paper():
    rows = study_tables.throws(synthetic_records(), 'paper')
    cal = {name: (t, o, r) for name, t, o, r in study_tables.calibration(rows)}
    t, o, r = cal['generality experienced']
    assert t == 0.915 and r == pytest.approx(o - t)
    assert cal['regeneration success'][0] == pytest.approx(0.95)


def record(key, **values):
    return ThrowRecord(id=f'i-{key}', key=key, **values)


def test_store_keeps_finished_records_and_drops_a_line_cut_by_a_kill(tmp_path):
    assert config_hash({'seed': 1}) == config_hash({'seed': 1}) != config_hash({'seed': 2})
    with ResultStore(tmp_path) as store:
        store.add(record('a', score=1.0, entry_error_mm=float('nan')))
        store.add(record('b', score=0.8, replay_bytes=np.int64(3)))
    assert store.path.name == 'results.jsonl'
    with open(store.path, 'a') as f:
        f.write('{"id": "i-c", "key": "c", "kind": "thr')  # killed mid-write
    again = ResultStore(tmp_path)
    assert list(again.records) == ['i-a', 'i-b'] and again.dropped == 1
    assert again.records['i-a'].entry_error_mm is None
    assert again.records['i-b'] == record('b', score=0.8, replay_bytes=3)
    assert type(again.records['i-b'].replay_bytes) is int
    again.add(record('c', score=0.0, error='RuntimeError: x'))
    again.close()
    third = ResultStore(tmp_path)
    assert list(third.records) == ['i-a', 'i-b', 'i-c'] and third.dropped == 0
    demo = DemoJob(key='d', subject='S', group='g', phantom='p', pair='x', seed=0, bag='b',
                   segments='s')
    assert third.done(replace(demo, id='i-b')).score == 0.8
    assert third.done(replace(demo, id='i-c')) is None  # an error: run again
    assert third.done(replace(demo, id='i-d')) is None
    assert ResultStore(tmp_path, 'other').records == {}
    with pytest.raises(ValueError, match='id and key'):
        third.add(ThrowRecord(key='d', score=1.0))


def test_a_line_that_is_not_a_record_of_this_format_is_dropped(tmp_path):
    lines = [{'id': 'i-a', 'key': 'a', 'kind': 'throw', 'score': 1.0, 'x': 2},  # no field x
             {'id': 'i-b', 'key': 'b', 'kind': 'test'},  # no such kind
             {'id': 'i-c', 'key': 'c', 'kind': 'demo', 'ok': True}, [1, 2]]
    (tmp_path / 'results.jsonl').write_text(''.join(json.dumps(x) + '\n' for x in lines))
    store = ResultStore(tmp_path)
    assert list(store.records) == ['i-c'] and store.dropped == 3
    assert store.records['i-c'] == DemoRecord(id='i-c', key='c', ok=True)


def test_a_result_file_of_the_earlier_format_is_named_and_not_read(tmp_path):
    earlier = tmp_path / 'results-0123456789ab.jsonl'
    earlier.write_text(json.dumps({'key': 'a', 'kind': 'throw', 'score': 1.0}) + '\n')
    assert earlier_format_files(tmp_path) == [earlier]
    assert ResultStore(tmp_path).records == {}
    (tmp_path / 'results.jsonl').write_text(
        json.dumps({'key': 'a', 'kind': 'throw', 'score': 1.0}) + '\n')  # no job id
    store = ResultStore(tmp_path)
    assert store.records == {} and store.dropped == 1


def test_progress_reports_rate_and_time_left():
    now = [0.0]
    out = io.StringIO()
    progress = Progress(10, done=2, stream=out, every=0.0, clock=lambda: now[0])
    now[0] = 4.0
    progress.advance('x')
    now[0] = 8.0
    progress.advance('y')
    last = out.getvalue().splitlines()[-1]
    assert last.startswith('study: 4/10 throws done (40.0 %), 0.250 throws/s')
    assert 'left ~0:24' in last and '(2 resumed)' in last and '[y]' in last
