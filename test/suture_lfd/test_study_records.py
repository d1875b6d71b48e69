"""The study's typed jobs and records: the CSV columns, the store's round trip, refusals."""

from dataclasses import fields
import json
import math
import pickle

import pytest
from suture_lfd.study.records import (
    DemoJob,
    DemoRecord,
    RobotErrors,
    ThrowJob,
    ThrowRecord,
    columns,
    plan_json,
    record_from_json,
    stored,
    to_json,
)
from suture_lfd.study.store import ResultStore

# The published CSV formats (throws.csv, demos.csv): a change here changes every study's files.
THROWS_CSV = (
    'subject', 'group', 'method', 'train_phantom', 'train_pair', 'test_phantom', 'test_pair',
    'regeneration', 'seed', 'score', 'i', 'ii', 'iii', 'iv', 'v', 'failure', 'time_s',
    'demo_time_s', 'entry_error_mm', 'exit_error_mm',
    'ii_start_mm', 'ii_goal_mm', 'ii_traj_mm', 'ii_start_deg', 'ii_goal_deg', 'ii_traj_deg',
    'iv_start_mm', 'iv_goal_mm', 'iv_traj_mm', 'iv_start_deg', 'iv_goal_deg', 'iv_traj_deg',
    'ii_exec_traj_mm', 'iv_exec_traj_mm')
DEMOS_CSV = (
    'subject', 'group', 'phantom', 'pair', 'seed', 'attempts', 'ok', 'demo_score', 'time_s',
    'failure', 't_i', 't_ii', 't_iii', 't_iv', 't_v', 'bag', 'segments')


def throw_job(**values):
    return ThrowJob(**{'key': 'throw/paper/S01/synth1/synth2', 'subject': 'S01',
                       'group': 'experienced', 'method': 'paper', 'train_phantom': 'synthetic',
                       'train_pair': 'synth1', 'test_phantom': 'synthetic',
                       'test_pair': 'synth2', 'seed': 7, 'demo_key': 'demo/S01/synth1',
                       'id': 'i-throw', **values})


def demo_job(**values):
    return DemoJob(**{'key': 'demo/S01/synth1', 'subject': 'S01', 'group': 'experienced',
                      'phantom': 'synthetic', 'pair': 'synth1', 'seed': 3,
                      'bag': 'bags/S01_synth1', 'segments': 'segments/S01_synth1.npz',
                      'id': 'i-demo', **values})


def test_a_record_s_first_fields_are_its_csv_columns_in_order():
    assert columns(ThrowRecord) == THROWS_CSV
    assert columns(DemoRecord) == DEMOS_CSV
    for cls, csv_columns in ((ThrowRecord, THROWS_CSV), (DemoRecord, DEMOS_CSV)):
        names = [f.name for f in fields(cls)]
        assert tuple(names[:len(csv_columns)]) == csv_columns


def test_a_record_carries_its_job_s_fields_and_a_failed_job_is_its_error_record():
    job = throw_job(physical=RobotErrors(3.0, 11, correction=True), cell='c1')
    record = ThrowRecord.of(job, score=0.8, ii=True)
    assert (record.key, record.id, record.test_pair, record.cell) == \
        (job.key, job.id, 'synth2', 'c1')
    assert record.physical == job.physical and record.score == 0.8 and record.ii
    failed = job.failed('RuntimeError: no arm')
    assert isinstance(failed, ThrowRecord) and failed.error == 'RuntimeError: no arm'
    assert failed.key == job.key and failed.score is None
    assert isinstance(demo_job().failed('x'), DemoRecord)
    # a held-out phantom's configuration stays in the job, not in its record
    held = throw_job(kind='held_out', test_key='g1', test_config={'markers': {}})
    assert ThrowRecord.of(held).kind == 'held_out'
    assert 'test_config' not in {f.name for f in fields(ThrowRecord)}


def test_jobs_pickle_for_worker_processes():
    for job in (throw_job(physical=RobotErrors(1.0, 2), dmp={'ii': {'n_bfs': 50}}),
                demo_job(cohort_seed=4)):
        assert pickle.loads(pickle.dumps(job)) == job


def test_a_record_read_back_from_the_store_equals_the_one_it_kept(tmp_path):
    job = throw_job(physical=RobotErrors(3.0, 11, correction=True))
    record = ThrowRecord.of(job, score=1.0, entry_error_mm=float('nan'), replay_bytes=12)
    with ResultStore(tmp_path) as store:
        store.add(record)
        kept = store.records[job.id]
    assert kept == stored(record) and kept.entry_error_mm is None  # JSON has no NaN
    again = ResultStore(tmp_path).records[job.id]
    assert again == kept and isinstance(again.physical, RobotErrors)
    line = json.loads((tmp_path / 'results.jsonl').read_text())
    assert line == to_json(kept)


def test_records_of_unknown_kinds_or_fields_are_refused():
    good = to_json(DemoRecord.of(demo_job(), ok=True))
    assert record_from_json(good) == DemoRecord.of(demo_job(), ok=True)
    with pytest.raises(ValueError, match='kind'):
        record_from_json({**good, 'kind': 'test'})
    with pytest.raises(ValueError, match="no fields \\['x'\\]"):
        record_from_json({**good, 'x': 1})
    with pytest.raises(ValueError, match='id and key'):
        record_from_json({**good, 'id': ''})


def test_the_plan_file_lists_the_fields_a_job_sets():
    plan = plan_json(throw_job())
    assert 'physical' not in plan and 'segments' not in plan and plan['kind'] == 'throw'
    assert plan_json(throw_job(physical=RobotErrors(1.0, 2)))['physical'] == {
        'error_level': 1.0, 'error_seed': 2, 'correction': False, 'arm_realism': 'static',
        'arm_levels': [], 'camera': None}
    assert not any(isinstance(v, float) and math.isnan(v) for v in plan.values())
