"""``suture-lfd sweep``: a grid of studies as one job set, with shared demonstrations.

The sweep here is the issue's small one cut to stay affordable on two cores: two values of the
insertion's N_bfs x two seeds, the ``--quick`` design with one subject and the paper's method
(2 x 4 demonstrations, 2 x 2 x 16 throws).
"""

import json
from pathlib import Path
import subprocess
import sys

import pytest
from suture_lfd.study.report import read_csv
from suture_lfd.study.sweep import dmp_overrides, load_sweep

TIMEOUT = 1200
SWEEP = """\
sweep:
  design: {quick: true, subjects: 1}
  seeds: [0, 1]
  methods: [paper]
  dmp:
    task_ii.n_bfs: [50, 100]
"""


def cli(*args):
    cmd = [sys.executable, '-m', 'suture_lfd.cli', *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT)


@pytest.fixture(scope='module')
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp('sweep')
    (root / 'sweep.yaml').write_text(SWEEP)
    result = cli('sweep', str(root / 'sweep.yaml'), '--out', str(root / 'out'),
                 '--workers', '2')
    assert result.returncode == 0, result.stderr[-3000:]
    return root / 'out', result


def test_a_small_sweep_writes_its_report_with_plots_and_a_study_per_cell(sweep):
    out, result = sweep
    assert 'sweep report:' in result.stderr
    rows = read_csv(out / 'sweep.csv')
    assert {(r['task_ii.n_bfs'], r['seed'], r['method']) for r in rows} == {
        (n, s, 'paper') for n in ('50', '100') for s in ('0', '1')}
    for r in rows:
        assert 0.0 <= float(r['generality_overall']) <= 1.0
    text = (out / 'sweep.md').read_text()
    assert '## task_ii.n_bfs' in text and '![task_ii.n_bfs](sweep_task_ii_n_bfs.png)' in text
    assert (out / 'sweep_task_ii_n_bfs.png').read_bytes()[:4] == b'\x89PNG'
    for cell in ('task_ii.n_bfs=50', 'task_ii.n_bfs=100'):
        for seed in (0, 1):
            folder = out / 'cells' / cell / f'seed-{seed}'
            assert (folder / 'report.md').exists() and (folder / 'throws.csv').exists()
            assert len(read_csv(folder / 'throws.csv')) == 16


def test_cells_of_a_seed_share_its_demonstrations(sweep):
    out, _ = sweep
    (path,) = Path(out).glob('results.jsonl')
    records = [json.loads(line) for line in path.read_text().splitlines()]
    demos = [r['key'] for r in records if r['kind'] == 'demo']
    assert len(demos) == len(set(demos)) == 2 * 4  # per seed, not per cell
    throws = [r for r in records if r['kind'] == 'throw']
    assert len(throws) == 2 * 2 * 16
    assert {json.dumps(r['dmp'], sort_keys=True) for r in throws} == {
        '{"ii": {"n_bfs": 50}}', '{"ii": {"n_bfs": 100}}'}


def test_the_cell_at_table_i_s_value_is_the_plain_study_of_its_seed(sweep, tmp_path):
    out, _ = sweep
    plain = cli('study', '--quick', '--subjects', '1', '--methods', 'paper', '--seed', '1',
                '--workers', '2', '--out', str(tmp_path / 'plain'))
    assert plain.returncode == 0, plain.stderr[-3000:]
    cell = out / 'cells' / 'task_ii.n_bfs=100' / 'seed-1'
    assert (cell / 'throws.csv').read_bytes() == (tmp_path / 'plain' / 'throws.csv').read_bytes()


def test_sweep_values_for_both_tasks_or_one():
    assert dmp_overrides({'n_bfs': 20}) == {'ii': {'n_bfs': 20}, 'iv': {'n_bfs': 20}}
    assert dmp_overrides({'task_iv.alpha_y': 20.0}) == {'iv': {'alpha_y': 20.0}}


@pytest.mark.parametrize('body, named', [
    ('sweep:\n  dmp:\n    n_bases: [1, 2]\n', 'sweep.dmp.n_bases'),
    ('sweep:\n  seeds: [-1]\n', 'sweep.seeds'),
    ('sweep:\n  methods: [best]\n', 'sweep.methods'),
    ('sweep:\n  dmp:\n    n_bfs: 5\n', 'sweep.dmp.n_bfs'),
    ('sweep:\n  dmp:\n    n_bfs: [0]\n', 'sweep.dmp'),
    ('study: {}\n', '"sweep"'),
    ('sweep:\n  physical:\n    error_level: [-1]\n', 'sweep.physical.error_level'),
    ('sweep:\n  physical:\n    correction: [maybe]\n', 'sweep.physical.correction'),
    ('sweep:\n  physical:\n    noise: [1]\n', 'sweep.physical.noise'),
    ('sweep:\n  tissue: [soft]\n', 'sweep.tissue'),
    ('sweep:\n  tissue: none\n', 'sweep.tissue'),
    ('sweep:\n  physical:\n    camera: [hd]\n', 'sweep.physical.camera'),
    ('sweep:\n  physical:\n    arm_realism: [wobbly]\n', 'sweep.physical.arm_realism'),
    ('sweep:\n  physical:\n    arm_realism: [dvrk]\n    servo_level: [-1]\n',
     'sweep.physical.servo_level'),
    ('sweep:\n  physical:\n    calibration_level: [0]\n', 'sweep.physical.calibration_level'),
])
def test_a_bad_sweep_file_names_the_file_and_key(tmp_path, body, named):
    path = tmp_path / 'bad.yaml'
    path.write_text(body)
    with pytest.raises(ValueError, match=named) as info:
        load_sweep(path)
    assert str(path) in str(info.value)
    result = cli('sweep', str(path), '--out', str(tmp_path / 'out'))
    assert result.returncode == 2 and named in result.stderr
    assert 'Traceback' not in result.stderr


PHYSICAL_SWEEP = """\
sweep:
  design: {subjects: 1, pairs: 1, phantoms: [synthetic]}
  methods: [pair_frame]
  physical:
    error_level: [0, 3]
    correction: [true, false]
"""


def test_error_level_and_correction_are_sweep_keys_with_demonstrations_per_level(tmp_path):
    (tmp_path / 'sweep.yaml').write_text(PHYSICAL_SWEEP)
    result = cli('sweep', str(tmp_path / 'sweep.yaml'), '--plan', '--out', str(tmp_path / 'o'))
    assert result.returncode == 0, result.stderr[-3000:]
    jobs = json.loads((tmp_path / 'o' / 'jobs.json').read_text())
    demos = [j for j in jobs if j['kind'] == 'demo']
    throws = [j for j in jobs if j['kind'] == 'throw']
    # one demonstration per level (no ground-truth cell: none in ground-truth mode)
    assert sorted(j['physical']['error_level'] for j in demos) == [0.0, 3.0]
    assert {(j['physical']['error_level'], j['physical']['correction']) for j in throws} == {
        (0.0, True), (0.0, False), (3.0, True), (3.0, False)}
    by_key = {j['key']: j for j in demos}
    for j in throws:  # each learns from its level's demonstration
        assert by_key[j['demo_key']]['physical']['error_level'] == j['physical']['error_level']
    assert len({j['id'] for j in jobs}) == len(jobs)


REALISM_SWEEP = """\
sweep:
  design: {subjects: 1, pairs: 1, phantoms: [synthetic]}
  methods: [pair_frame]
  tissue: [none, tissue]
  physical:
    arm_realism: [dvrk]
    transmission_level: [0, 1]
    camera: [none, dvrk]
"""


def test_tissue_camera_and_arm_realism_are_sweep_keys_with_their_own_robots(tmp_path):
    (tmp_path / 'sweep.yaml').write_text(REALISM_SWEEP)
    sweep = load_sweep(tmp_path / 'sweep.yaml')
    assert [a for a, _ in sweep.axes] == ['tissue', 'arm_realism', 'transmission_level',
                                          'camera']
    result = cli('sweep', str(tmp_path / 'sweep.yaml'), '--plan', '--out', str(tmp_path / 'o'))
    assert result.returncode == 0, result.stderr[-3000:]
    jobs = json.loads((tmp_path / 'o' / 'jobs.json').read_text())
    demos = [j for j in jobs if j['kind'] == 'demo']
    throws = [j for j in jobs if j['kind'] == 'throw']
    robot = ('arm_realism', 'arm_levels', 'camera')

    def made(j):
        return (j.get('tissue'), *(json.dumps(j['physical'][k]) for k in robot))

    # one demonstration per robot and tissue (8 cells, 8 robots), each throw learns from its own
    assert len(demos) == len({made(j) for j in demos}) == 8
    assert len(throws) == 8
    by_key = {j['key']: j for j in demos}
    for j in throws:
        assert made(by_key[j['demo_key']]) == made(j)
    assert {j['physical']['camera'] for j in throws} == {None, 'dvrk'}
    assert {j.get('tissue') for j in throws} == {None, 'tissue'}
    assert {json.dumps(j['physical']['arm_levels']) for j in throws} == {
        '[["transmission_level", 0.0]]', '[["transmission_level", 1.0]]'}
    assert {j['physical']['error_level'] for j in jobs} == {0.0}  # a preset: no static class
    assert len({j['id'] for j in jobs}) == len(jobs)


def test_a_ground_truth_cell_in_tissue_records_its_own_demonstrations(tmp_path):
    from suture_lfd.study.sweep import cell_mode, plan_sweep

    (tmp_path / 'sweep.yaml').write_text(
        'sweep:\n  design: {subjects: 1, pairs: 1, phantoms: [synthetic]}\n'
        '  methods: [pair_frame]\n  tissue: [none, tissue]\n')
    config, demos, throws = plan_sweep(load_sweep(tmp_path / 'sweep.yaml'))
    assert cell_mode({}).demo_folder() == cell_mode({'tissue': 'none'}).demo_folder() == ''
    assert sorted((j.key, j.tissue) for j in demos) == [
        ('seed-0/demo/S01/synth1', None), ('seed-0/tissue-tissue/demo/S01/synth1', 'tissue')]
    assert sorted((j.cell, j.demo_key, j.tissue) for j in throws) == [
        ('tissue=none', 'seed-0/demo/S01/synth1', None),
        ('tissue=tissue', 'seed-0/tissue-tissue/demo/S01/synth1', 'tissue')]
