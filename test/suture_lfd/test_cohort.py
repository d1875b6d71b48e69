"""The synthetic cohort: the paper's study design, seeded subjects, configuration errors."""

from dataclasses import asdict

import pytest
from sim_bridge.common.configfile import ConfigError
from sim_bridge.common.paths import config_path
from suture_lfd.demos.cohort import SkillProfile, load_cohort, load_study_design
import yaml


def test_the_default_cohort_is_the_papers_ten_subjects():
    subjects = load_cohort()
    assert [s.name for s in subjects] == [f'S{k:02d}' for k in range(1, 11)]
    assert [s.group for s in subjects].count('experienced') == 4
    assert [s.group for s in subjects].count('naive') == 6
    assert len({s.seed for s in subjects}) == 10
    design = load_study_design()
    assert design.trials == [('synthetic', f'synth{k}') for k in range(1, 5)] + [
        ('scanned', f'scan{k}') for k in range(1, 5)]


def test_the_same_seed_gives_the_same_subjects_and_another_seed_others():
    a, b, c = load_cohort(seed=3), load_cohort(seed=3), load_cohort(seed=4)
    assert a == b
    assert [s.seed for s in a] != [s.seed for s in c]
    assert [asdict(s.profile) for s in a] != [asdict(s.profile) for s in c]
    assert [s.group for s in a] == [s.group for s in c]


def test_subjects_vary_around_their_group_mean_and_naive_is_slower_and_less_precise():
    design = load_study_design()
    means = {g.name: g.profile for g in design.groups}
    subjects = load_cohort(seed=0)
    for group in ('experienced', 'naive'):
        speeds = [s.profile.speed_scale for s in subjects if s.group == group]
        assert len(set(speeds)) == len(speeds)   # spread: every subject differs
    assert means['naive'].speed_scale < means['experienced'].speed_scale
    assert means['naive'].aim_std > means['experienced'].aim_std
    assert means['naive'].wrist_rotation <= means['experienced'].wrist_rotation
    for s in subjects:
        assert 0.0 <= s.profile.wrist_rotation <= 1.0


def test_trial_seeds_are_reproducible_and_differ_between_pairs_and_attempts():
    s = load_cohort()[0]
    assert s.trial_seed('synth1') == s.trial_seed('synth1')
    assert len({s.trial_seed('synth1'), s.trial_seed('synth2'),
                s.trial_seed('synth1', attempt=1)}) == 3


def _write(tmp_path, mutate):
    data = yaml.safe_load(config_path('cohort.yaml').read_text())
    mutate(data)
    path = tmp_path / 'cohort.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(('mutate', 'words'), [
    (lambda d: d['cohort']['groups'][0]['profile'].update(speed_scale='fast'),
     ['cohort.groups[0].profile.speed_scale', 'number']),
    (lambda d: d['cohort']['groups'][1]['profile'].update(tremor=1.0),
     ['cohort.groups[1].profile', "'tremor'"]),
    (lambda d: d['cohort']['groups'][0].update(name='expert'), ['cohort.groups[0].name']),
    (lambda d: d['cohort']['groups'][0]['spread'].update(grip=0.1),
     ['cohort.groups[0].spread', "'grip'"]),
    (lambda d: d['cohort'].pop('phantoms'), ['cohort.phantoms']),
    (lambda d: d['cohort']['groups'][0].pop('count'), ['cohort.groups[0].count']),
])
def test_configuration_errors_name_the_file_and_the_key(tmp_path, mutate, words):
    path = _write(tmp_path, mutate)
    with pytest.raises(ConfigError) as err:
        load_cohort(path)
    assert str(path) in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_a_profile_value_out_of_range_is_refused():
    with pytest.raises(ValueError, match='wrist_rotation'):
        SkillProfile(wrist_rotation=1.5)
    with pytest.raises(ValueError, match='speed_scale'):
        SkillProfile(speed_scale=0.0)
    with pytest.raises(ValueError, match='seed'):
        load_cohort(seed=-1)
