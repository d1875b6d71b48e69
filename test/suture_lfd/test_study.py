"""``suture-lfd study`` end to end: real demonstrations, bags, segment files and throws.

A small design keeps the file to a few minutes on two cores: ``--quick`` cut to one subject,
one pair of the synthetic phantom and the paper's method -- one demonstration (simulated,
written as a bag, read back, segmented) and its regeneration throw, in 2 worker processes.
Jobs that raise (a broken upstream piece) are stored with their error and listed in the report;
the checks below hold for whatever the jobs returned.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from suture_lfd.study import report
from suture_lfd.study import tables as study_tables

SMALL = ['--quick', '--subjects', '1', '--phantoms', 'synthetic', '--pairs', '1',
         '--methods', 'paper', '--workers', '2']
N_JOBS = 2
TIMEOUT = 900


def study(out, *args, **kwargs):
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT, **kwargs)


def records(out):
    (path,) = Path(out).glob('results.jsonl')
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope='module')
def small_study(tmp_path_factory):
    out = tmp_path_factory.mktemp('study_a')
    result = study(out, *SMALL)
    assert result.returncode == 0, result.stderr[-3000:]
    return out, result


def table_row(text, first_cell):
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if cells and cells[0] == first_cell:
            return cells
    raise AssertionError(f'no table row starting with {first_cell!r}')


def test_quick_study_writes_a_report_consistent_with_its_csv(small_study):
    out, result = small_study
    assert 'throws done' in result.stderr and 'report:' in result.stderr
    jobs = records(out)
    assert {r['key'] for r in jobs} == {'demo/S01/synth1', 'throw/paper/S01/synth1/synth1'}
    text = (out / 'report.md').read_text()
    for r in jobs:
        if r['error']:
            assert f'| {r["key"]} | {r["error"]}'[:60] in text  # listed, not hidden
    rows = report.read_csv(out / 'throws.csv')
    assert len(rows) == sum(1 for r in jobs if r['kind'] == 'throw' and not r['error'])
    demos = report.read_csv(out / 'demos.csv')
    assert len(demos) == sum(1 for r in jobs if r['kind'] == 'demo' and not r['error'])
    for d in demos:
        assert (out / d['bag'] / 'metadata.yaml').exists()  # the demonstration as a bag
        assert d['ok'] == 'false' or (out / d['segments']).exists()
    scores = [float(r['score']) for r in rows]
    assert set(scores) <= {0.0, 0.4, 0.8, 1.0}
    for r in rows:  # the subtask flags and the score agree
        every = all(r[t] == 'true' for t in study_tables.SUBTASKS)
        # a complete throw has every subtask; one with every subtask can still fail on the
        # way (tissue trauma), and then says why
        assert every or float(r['score']) < 1.0
        assert float(r['score']) == 1.0 or r['failure'], r
    if rows:
        # Table III from the CSV
        group = rows[0]['group']
        row = table_row(text, group.capitalize())
        assert float(row[1]) == pytest.approx(np.mean(scores), abs=5e-4)
        assert int(row[2]) == len(rows)
        assert float(table_row(text, 'Overall')[1]) == pytest.approx(np.mean(scores), abs=5e-4)
        # regeneration success from the CSV's diagonal
        diag = [r for r in rows if r['train_pair'] == r['test_pair']]
        complete = sum(float(r['score']) == 1.0 for r in diag)
        assert f'**{complete} / {len(diag)} = ' in text
        # Table II from the CSV
        values = [float(r['ii_traj_mm']) for r in diag if r['ii_traj_mm']]
        prefix = '| task ii position (mm) | trajectory |'
        (line,) = [ln for ln in text.splitlines() if ln.startswith(prefix)]
        if values:
            assert float(line.split('|')[3]) == pytest.approx(np.mean(values), abs=5e-3)
        # Table IV from the CSV
        if group == 'experienced':
            ok = sum(all(r[t] == 'true' for t in study_tables.SUBTASKS) for r in rows)
            assert table_row(text, 'v')[2] == f'{ok} / {len(rows)}'
        for name in ('heatmap_paper.png', 'task_time_paper.png'):
            assert (out / name).read_bytes()[:4] == b'\x89PNG'
    config = json.loads((out / 'config.json').read_text())
    assert config['seed'] == 0 and config['methods'] == ['paper']
    assert config['subjects'][0]['seed'] and config['subjects'][0]['profile']
    assert '"seed": 0' in text and 'synthetic' in text


def test_an_interrupted_study_resumes_without_redoing_finished_throws(small_study, tmp_path):
    reference, _ = small_study
    out = tmp_path / 'study_b'
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *SMALL]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + TIMEOUT
    try:
        while time.monotonic() < deadline:  # interrupt once the demonstration is stored
            files = list(out.glob('results.jsonl'))
            if files and files[0].read_text().count('\n') >= 1:
                break
            assert proc.poll() is None, proc.communicate()[1][-3000:]
            time.sleep(0.2)
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the whole process group
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    first = records(out)
    if proc.returncode == 0:
        pytest.skip('the study finished before it could be interrupted')
    assert proc.returncode == 130, err[-3000:]
    assert 'run the same command again to resume' in err
    assert 1 <= len(first) < N_JOBS
    result = study(out, *SMALL)
    assert result.returncode == 0, result.stderr[-3000:]
    done = [r['key'] for r in first if not r['error']]
    if done:
        assert f'({len(done)} resumed)' in result.stderr
    final = records(out)
    assert final[:len(first)] == first  # append-only: nothing stored before was rewritten
    keys = [r['key'] for r in final]
    assert all(keys.count(k) == 1 for k in done)  # finished jobs were not run again
    assert len(set(keys)) == N_JOBS
    # same seed, same report: the interrupted and resumed run gives the uninterrupted one's CSV
    assert (out / 'throws.csv').read_bytes() == (reference / 'throws.csv').read_bytes()
    assert (out / 'demos.csv').read_bytes() == (reference / 'demos.csv').read_bytes()


def test_the_seed_decides_the_subjects(tmp_path):
    def plan(seed, name):
        result = study(tmp_path / name, '--plan', '--seed', str(seed))
        assert result.returncode == 0, result.stderr
        config = json.loads((tmp_path / name / 'config.json').read_text())
        jobs = json.loads((tmp_path / name / 'jobs.json').read_text())
        return config, jobs

    a, jobs_a = plan(0, 'a')
    b, jobs_b = plan(0, 'b')
    c, jobs_c = plan(1, 'c')
    assert a['subjects'] == b['subjects'] and jobs_a == jobs_b and a['hash'] == b['hash']
    assert [s['group'] for s in a['subjects']] == ['experienced'] * 4 + ['naive'] * 6
    assert [s['seed'] for s in a['subjects']] != [s['seed'] for s in c['subjects']]
    assert a['subjects'][0]['profile'] != c['subjects'][0]['profile']
    assert [j['seed'] for j in jobs_a] != [j['seed'] for j in jobs_c]
    assert a['hash'] != c['hash']
    # the paper's design: 10 subjects x 8 demonstrations, 64 throws per subject and method
    demos = [j for j in jobs_a if j['kind'] == 'demo']
    throws = [j for j in jobs_a if j['kind'] == 'throw']
    assert len(demos) == 80 and len(throws) == 640 * len(a['methods'])


def test_bad_options_are_named(tmp_path):
    result = study(tmp_path, '--methods', 'paper,nonsense', '--plan')
    assert result.returncode == 2 and "unknown method 'nonsense'" in result.stderr
    result = study(tmp_path, '--phantoms', 'jelly', '--plan')
    assert result.returncode == 2 and "unknown phantom 'jelly'" in result.stderr
