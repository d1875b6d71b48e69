"""``suture-lfd study --physical`` end to end: the study on what a physical dVRK provides.

One subject, one synthetic pair, the ``pair_frame`` method: the ground-truth demonstration and
throw, and the same in physical mode at error levels 0 and 3 (demonstrations teleoperated
through the robot and recorded from its reports and the endoscope; throws with and without the
correction), in 2 worker processes; beside it the same design without ``--physical``, whose
``throws.csv`` and ``demos.csv`` the physical study must leave byte for byte unchanged.
"""

import json
from pathlib import Path
import subprocess
import sys

import pytest
from suture_lfd.study import report

SMALL = ['--quick', '--subjects', '1', '--phantoms', 'synthetic', '--pairs', '1',
         '--methods', 'pair_frame', '--workers', '2']
PHYSICAL = ['--physical', '--arm-realism', 'static', '--error-level', '0,3', '--correction',
            'both']
TIMEOUT = 1500


def study(out, *args):
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT)


def records(out):
    return [json.loads(line) for line in (Path(out) / 'results.jsonl').read_text().splitlines()]


@pytest.fixture(scope='module')
def studies(tmp_path_factory):
    ground = tmp_path_factory.mktemp('ground_truth')
    result = study(ground, *SMALL)
    assert result.returncode == 0, result.stderr[-3000:]
    both = tmp_path_factory.mktemp('physical')
    result = study(both, *SMALL, *PHYSICAL)
    assert result.returncode == 0, result.stderr[-3000:]
    return ground, both, result


def test_the_physical_study_leaves_the_ground_truth_results_unchanged(studies):
    ground, both, _ = studies
    for name in ('throws.csv', 'demos.csv'):
        assert (both / name).read_bytes() == (ground / name).read_bytes(), name
    ground_ids = {r['key']: r['id'] for r in records(ground)}
    mine = records(both)
    assert {r['key']: r['id'] for r in mine if r['key'] in ground_ids} == ground_ids
    physical = [r for r in mine if r['key'] not in ground_ids]
    # per level one demonstration; per level and correction one throw
    assert len(physical) == 2 + 4
    assert not {r['id'] for r in physical} & set(ground_ids.values())
    for r in physical:
        assert r['physical']['error_level'] in (0.0, 3.0)
        assert r['error'] == '', r['error']


def test_the_physical_study_keeps_one_registration_per_robot(studies):
    _, both, _ = studies
    # one robot at level 3 (one subject, one phantom), registered once if anything on it used
    # its registration (a corrected throw that ran: it had a demonstration to learn from);
    # level 0 is perfect kinematics (nothing to register); no claim left behind
    corrected = [r for r in records(both) if r['kind'] == 'throw' and r['physical']
                 and r['physical']['error_level'] == 3.0 and r['physical']['correction']
                 and r['segments']]
    folder = both / 'physical' / 'registrations'
    files = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    assert len(corrected) <= len(files) <= 1, files
    for name in files:
        assert name.startswith('synthetic_0.01s_3mm_') and name.endswith('.json'), files
        saved = json.loads((folder / name).read_text())
        assert saved['key']['error_level'] == 3.0, saved


def test_the_physical_study_reports_its_tables_beside_ground_truth_and_the_curve(studies):
    _, both, result = studies
    assert 'physical mode (4 variants): 2 demonstrations + 4 throws' in result.stderr
    text = (both / 'report.md').read_text()
    section = text[text.index('## Physical mode'):]
    for title in ('#### Table II', '#### Table III', '#### Table IV',
                  '### Generality against the error level'):
        assert title in section, title
    header = ('|  | ground truth | L0 corrected | L0 open loop | L3 corrected | L3 open loop '
              '| paper |')
    assert header in section
    curve = report.read_csv(both / 'physical_curve.csv')
    assert {(r['error_level'], r['correction']) for r in curve} == {
        ('0.0', 'true'), ('0.0', 'false'), ('3.0', 'true'), ('3.0', 'false')}
    assert (both / 'physical_curve.png').read_bytes()[:4] == b'\x89PNG'
    # each variant's full report, its throws read back against the curve's figures
    for r in curve:
        name = f'level-{float(r["error_level"]):g}' + ('' if r['correction'] == 'true'
                                                        else '-open')
        throws = report.read_csv(both / 'physical' / name / 'throws.csv')
        assert len(throws) == 1 == int(r['throws'])
        assert float(r['generality_overall']) == pytest.approx(float(throws[0]['score']))
    # the level's demonstration was recorded as a bag in its own folder
    demos = report.read_csv(both / 'physical' / 'level-3' / 'demos.csv')
    assert demos[0]['bag'].startswith('physical/level-3/bags/')
    assert (both / demos[0]['bag'] / 'metadata.yaml').exists()


def test_physical_options_are_checked_and_planned_apart(tmp_path):
    result = study(tmp_path / 'bad', '--physical', '--error-level', '3,x', '--plan')
    assert result.returncode == 2
    assert "--error-level takes mm classes >= 0 separated by commas, got 'x'" in result.stderr
    result = study(tmp_path / 'plain', '--plan')
    assert result.returncode == 0, result.stderr
    plain = json.loads((tmp_path / 'plain' / 'jobs.json').read_text())
    result = study(tmp_path / 'physical', '--plan', '--physical', '--arm-realism', 'static',
                   '--no-correction')
    assert result.returncode == 0, result.stderr
    jobs = json.loads((tmp_path / 'physical' / 'jobs.json').read_text())
    assert jobs[:len(plain)] == plain  # the ground-truth jobs, ids and all, as without it
    extra = jobs[len(plain):]
    assert len(extra) == len(plain)  # one level: the design once more
    assert {j['physical']['error_level'] for j in extra} == {3.0}
    assert {j['physical'].get('correction') for j in extra if j['kind'] == 'throw'} == {False}
    # one robot per subject and phantom: its demonstrations and the throws on that phantom
    # share its errors, another subject's robot has its own
    robots = {}
    for j in extra:
        phantom = j['phantom'] if j['kind'] == 'demo' else j['test_phantom']
        robots.setdefault((j['subject'], phantom), set()).add(j['physical']['error_seed'])
    assert all(len(seeds) == 1 for seeds in robots.values()), robots
    assert len({next(iter(seeds)) for seeds in robots.values()}) == len(robots) > 1, robots


def test_physical_mode_runs_the_dvrk_preset_by_name_and_names_a_bad_preset(tmp_path):
    result = study(tmp_path / 'dvrk', '--plan', '--physical', '--arm-realism', 'dvrk')
    assert result.returncode == 0, result.stderr
    jobs = json.loads((tmp_path / 'dvrk' / 'jobs.json').read_text())
    extra = [j for j in jobs if j.get('physical') is not None]
    assert extra and {j['physical']['arm_realism'] for j in extra} == {'dvrk'}
    assert all(j['key'].startswith('physical/dvrk/') for j in extra)
    result = study(tmp_path / 'bad', '--plan', '--physical', '--arm-realism', 'nope')
    assert result.returncode != 0
    assert "no preset 'nope'" in result.stderr


def test_physical_mode_runs_the_dvrk_preset_by_default_and_static_by_name(tmp_path):
    result = study(tmp_path / 'default', '--plan', '--physical')
    assert result.returncode == 0, result.stderr
    jobs = json.loads((tmp_path / 'default' / 'jobs.json').read_text())
    extra = [j for j in jobs if j.get('physical') is not None]
    assert extra and {j['physical']['arm_realism'] for j in extra} == {'dvrk'}
    # an error class belongs to the static offsets: asked without them, the study says so
    result = study(tmp_path / 'class', '--plan', '--physical', '--error-level', '1')
    assert result.returncode == 2
    assert '--error-level is the class of the static offsets' in result.stderr
    assert '--arm-realism static' in result.stderr
    result = study(tmp_path / 'static', '--plan', '--physical', '--arm-realism', 'static')
    assert result.returncode == 0, result.stderr
    jobs = json.loads((tmp_path / 'static' / 'jobs.json').read_text())
    extra = [j for j in jobs if j.get('physical') is not None]
    assert extra and {j['physical'].get('arm_realism', 'static') for j in extra} == {'static'}
    assert {j['physical']['error_level'] for j in extra} == {3.0}


def test_physical_throws_may_learn_from_the_ground_truth_demonstrations(tmp_path):
    result = study(tmp_path, '--plan', '--physical', '--arm-realism', 'static',
                   '--error-level', '1,5', '--physical-demos', 'ground-truth')
    assert result.returncode == 0, result.stderr
    jobs = json.loads((tmp_path / 'jobs.json').read_text())
    ground = [j for j in jobs if j.get('physical') is None]
    extra = [j for j in jobs if j.get('physical') is not None]
    assert all(j['kind'] == 'throw' for j in extra)  # no demonstration of its own
    ground_demos = {j['key'] for j in ground if j['kind'] == 'demo'}
    assert {j['demo_key'] for j in extra} == ground_demos
    assert len(extra) == 2 * sum(j['kind'] == 'throw' for j in ground)


def test_a_study_process_builds_and_registers_each_robot_once(tmp_path):
    from suture_lfd.skill.arm_registration import register_arms
    from suture_lfd.study import jobs
    from suture_lfd.study.records import RobotErrors

    state = jobs.init_worker(jobs.JobSettings(out=str(tmp_path)))
    try:
        robot = RobotErrors(error_level=3.0, error_seed=7, correction=True)
        sim = jobs._physical_simulation(state, 'synthetic', 0.01, robot)
        correction = register_arms(sim)
        # the open-loop variant and the next job of the same subject and phantom: the same
        # robot, its registration kept
        again = jobs._physical_simulation(state, 'synthetic', 0.01,
                                          RobotErrors(error_level=3.0, error_seed=7))
        assert again is sim
        assert register_arms(again) is correction
        # other robots: a process keeps a few, the least recently used closed first
        others = [jobs._physical_simulation(state, 'synthetic', 0.01,
                                            RobotErrors(error_level=3.0, error_seed=s))
                  for s in range(100, 100 + jobs.ROBOTS_KEPT)]
        assert len(state.robots) == jobs.ROBOTS_KEPT
        assert sim not in state.robots.values()
        assert all(o in state.robots.values() for o in others)
        # level 0 is the process's shared ground-truth simulation (nothing to draw)
        plain = jobs._physical_simulation(state, 'synthetic', 0.01,
                                          RobotErrors(error_level=0.0, error_seed=7))
        assert plain is jobs._simulation(state, 'synthetic', 0.01)
    finally:
        state.close()
    assert not state.robots


def test_the_camera_option_names_its_preset_and_reaches_the_simulations(tmp_path):
    from sim_bridge.realism.endoscope import EndoscopeRealism, endoscope_preset
    from suture_lfd.study import jobs
    from suture_lfd.study.records import RobotErrors

    result = study(tmp_path / 'bad', '--plan', '--camera', 'nope')
    assert result.returncode == 2
    assert 'realism_camera.yaml' in result.stderr and "'nope'" in result.stderr
    result = study(tmp_path / 'dvrk', '--plan', '--physical', '--camera', 'dvrk')
    assert result.returncode == 0, result.stderr
    config = json.loads((tmp_path / 'dvrk' / 'config.json').read_text())
    assert config['settings']['camera'] == 'dvrk'
    state = jobs.init_worker(jobs.JobSettings(out=str(tmp_path), camera='dvrk'))
    try:
        dvrk = endoscope_preset('dvrk')
        assert jobs._simulation(state, 'synthetic', 0.01).config.endoscope == dvrk
        # a job's own camera (a sweep's cell) overrides the study's
        own = jobs._physical_simulation(state, 'synthetic', 0.01,
                                        RobotErrors(error_level=0.0, error_seed=1,
                                                    camera='none'))
        assert own.config.endoscope == EndoscopeRealism()
        assert own is not jobs._simulation(state, 'synthetic', 0.01)
    finally:
        state.close()


def test_the_arm_ablation_plans_each_effect_alone_beside_the_preset(tmp_path):
    result = study(tmp_path / 'ablation', '--plan', *SMALL, '--physical', '--arm-realism',
                   'dvrk', '--arm-ablation', '--correction', 'both', '--arm-levels',
                   'jaw_level=0')
    assert result.returncode == 0, result.stderr
    jobs = json.loads((tmp_path / 'ablation' / 'jobs.json').read_text())
    extra = [j for j in jobs if j.get('physical') is not None]
    folders = {j['key'].split('/')[1] for j in extra}
    # the preset with every effect (jaw off, as asked) and each remaining effect alone, each
    # corrected and open loop; the jaw, at 0, has no variant of its own
    alone = {'calibration', 'transmission', 'servo', 'encoder', 'ecm', 'intrinsics'}
    assert folders == ({'dvrk', 'dvrk-open'} | {f'dvrk-only-{e}' for e in alone}
                       | {f'dvrk-only-{e}-open' for e in alone})
    for j in extra:
        levels = dict(j['physical']['arm_levels'])
        name = j['key'].split('/')[1].removesuffix('-open')
        if name == 'dvrk':
            assert levels == {'jaw_level': 0.0}, j['key']
        else:
            effect = name.removeprefix('dvrk-only-')
            assert levels.pop(f'{effect}_level') == 1.0 and set(levels.values()) == {0.0}
        if j['kind'] == 'throw':  # learns from the demonstration of its own robot model
            assert j['demo_key'].startswith(f'physical/{name}/demo/'), j
    # one demonstration per model (7), one throw per variant (14)
    assert sorted(j['kind'] for j in extra).count('demo') == 7
    assert sorted(j['kind'] for j in extra).count('throw') == 14
    for bad, message in ((['--arm-realism', 'static', '--arm-ablation'],
                          'need --arm-realism PRESET'),
                         (['--arm-realism', 'dvrk', '--arm-levels', 'servo=1'],
                          '--arm-levels takes KEY=LEVEL'),
                         (['--arm-realism', 'dvrk', '--arm-levels', 'servo_level=-1'],
                          "got 'servo_level=-1'")):
        result = study(tmp_path / 'bad', '--plan', '--physical', *bad)
        assert result.returncode == 2 and message in result.stderr, result.stderr
