"""``suture-lfd study --held-out``: skills executed on random pairs beside the fixed ones."""

import csv
import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

TIMEOUT = 900
SMALL = ['--quick', '--subjects', '1', '--phantoms', 'synthetic', '--pairs', '1',
         '--methods', 'pair_frame', '--workers', '2']


def study(out, *args):
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT)


def planned(out, *args):
    result = study(out, '--plan', *args)
    assert result.returncode == 0, result.stderr[-3000:]
    config = json.loads((out / 'config.json').read_text())
    jobs = json.loads((out / 'jobs.json').read_text())
    return config, jobs


def test_held_out_pairs_are_seeded_on_the_wound_line_and_leave_the_fixed_design_alone(
        tmp_path):
    base, _ = planned(tmp_path / 'a')
    config, jobs = planned(tmp_path / 'b', '--held-out', '16')
    assert 'held_out' not in base
    assert config['hash'] == base['hash']  # the fixed pairs' results are shared
    fixed = [j for j in jobs if j['kind'] != 'held_out']
    assert [j['key'] for j in fixed] == [j['key'] for j in json.loads(
        (tmp_path / 'a' / 'jobs.json').read_text())]
    held = config['held_out']
    assert held['count'] == 16 and held['seed'] == 0
    for phantom, half_width in (('synthetic', 0.004), ('scanned', 0.006)):
        spec = held['phantoms'][phantom]
        markers = spec['config']['markers']
        assert len(markers) == 16 and set(markers) == set(spec['pairs'])
        for m in markers.values():
            entry, exit_ = np.array(m['entry']), np.array(m['exit'])
            mid = 0.5 * (entry + exit_)
            # within the markers' spacing range: between the first and last fixed pair
            assert -0.0185 <= mid[0] <= 0.0185
            assert np.linalg.norm(entry - exit_) == pytest.approx(2 * half_width, rel=0.02)
    synth = held['phantoms']['synthetic']['config']['markers']
    assert all(m['entry'][1] == pytest.approx(0.004) for m in synth.values())
    # every subject (2 in --quick) executes every held-out pair once per method
    n_subjects, n_methods = len(config['subjects']), len(config['methods'])
    assert len(jobs) - len(fixed) == n_subjects * n_methods * 32
    # seeded: the same seed gives the same pairs, the first of more pairs are the same
    again, _ = planned(tmp_path / 'c', '--held-out', '4', '--phantoms', 'synthetic')
    first = again['held_out']['phantoms']['synthetic']['config']['markers']
    assert first == {f'synthr{k}': synth[f'synthr{k}'] for k in range(1, 5)}
    other, _ = planned(tmp_path / 'd', '--held-out', '4', '--held-out-seed', '5',
                       '--phantoms', 'synthetic')
    assert other['held_out']['phantoms']['synthetic']['config']['markers'] != first


def test_a_small_study_reports_held_out_generality_beside_the_fixed_pairs(tmp_path):
    out = tmp_path / 'study'
    result = study(out, *SMALL, '--held-out', '2')
    assert result.returncode == 0, result.stderr[-3000:]
    assert '2 held-out throws' in result.stderr
    with open(out / 'held_out.csv', newline='') as f:
        rows = list(csv.DictReader(f))
    assert [r['test_pair'] for r in rows] == ['synthr1', 'synthr2']
    assert {r['train_pair'] for r in rows} == {'synth1'}
    for r in rows:
        assert float(r['entry_y_mm']) == pytest.approx(4.0)
        assert float(r['exit_y_mm']) == pytest.approx(-4.0)
        assert r['score'] in ('0.0', '0.4', '0.8', '1.0')
    text = (out / 'report.md').read_text()
    section = text[text.index('## Held-out geometry'):]
    summary = json.loads((out / 'held_out.json').read_text())['pair_frame']
    mean = np.mean([float(r['score']) for r in rows])
    assert summary['held_out']['overall'] == pytest.approx(mean)
    assert '| `pair_frame` | held-out, all | ' in section
    assert f'**{mean:.3f}**' in section
    fixed = [json.loads(line) for p in Path(out).glob('results.jsonl')
             for line in p.read_text().splitlines()]
    throws = [r for r in fixed if r['kind'] == 'throw']
    assert len(throws) == 1
    assert summary['fixed']['overall'] == pytest.approx(throws[0]['score'])
    # held-out throws never enter the fixed-pair tables
    with open(out / 'throws.csv', newline='') as f:
        assert [r['test_pair'] for r in csv.DictReader(f)] == ['synth1']


def test_bad_held_out_options_are_named(tmp_path):
    result = study(tmp_path, '--plan', '--held-out-mesh', 'pad.obj')
    assert result.returncode == 2 and '--held-out-mesh needs --held-out' in result.stderr
    result = study(tmp_path, '--plan', '--held-out', '-1')
    assert result.returncode == 2 and '--held-out must be >= 0' in result.stderr
    result = study(tmp_path, '--plan', '--held-out', '2', '--held-out-mesh',
                   str(tmp_path / 'nowhere.obj'))
    assert result.returncode == 2 and 'nowhere.obj does not exist' in result.stderr
