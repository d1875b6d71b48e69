import math

import numpy as np
import pytest
from sim_bridge.scene.scoring import ScoringConfig, ThrowScorer
from sim_bridge.scene.tissue import TissueEvent


def event(t, kind, error_mm=0.0, deviation=0.0):
    return TissueEvent(t, kind, np.zeros(3), error_mm * 1e-3, 'synth1.' + (
        'entry' if kind == 'entry' else 'exit'), deviation)


def complete_throw(scorer, entry_mm=0.5, exit_mm=0.5, skip=()):
    steps = [
        ('grasp', 1.0, 'PSM2'),
        ('tissue', 2.0, event(2.0, 'entry', entry_mm)),
        ('tissue', 3.0, event(3.0, 'exit', exit_mm)),
        ('grasp', 4.0, 'PSM1'),
        ('release', 4.5, 'PSM2'),
        ('tissue', 5.0, event(5.0, 'extracted', exit_mm, 0.0002)),
        ('grasp', 6.0, 'PSM2'),
        ('release', 6.5, 'PSM1'),
    ]
    for k, (what, t, arg) in enumerate(steps):
        if k in skip:
            continue
        if what == 'grasp':
            scorer.on_grasp(t, arg)
        elif what == 'release':
            scorer.on_release(t, arg)
        else:
            scorer.on_tissue_event(arg)
    return scorer


def test_a_complete_throw_scores_one_with_every_subtask():
    r = complete_throw(ThrowScorer(t_start=0.5)).result(10.0)
    assert r.score == 1.0 and r.complete and r.failure == ''
    assert r.subtasks == {'i': True, 'ii': True, 'iii': True, 'iv': True, 'v': True}
    assert r.entry_error_mm == pytest.approx(0.5) and r.exit_error_mm == pytest.approx(0.5)
    assert r.trauma_mm == pytest.approx(0.2)
    assert r.time_s == pytest.approx(6.0)
    assert not r.dropped and r.collisions == 0


def test_missing_only_the_exit_marker_scores_0_8():
    r = complete_throw(ThrowScorer(), exit_mm=4.0).result(10.0)
    assert r.score == 0.8
    assert r.failures == ('exit missed',)
    assert r.subtasks['i'] and not r.subtasks['ii'] and r.subtasks['iv']


def test_missing_the_entry_marker_on_a_reasonable_trajectory_scores_0_4():
    r = complete_throw(ThrowScorer(), entry_mm=4.0, exit_mm=4.0).result(10.0)
    assert r.score == 0.4
    assert not r.subtasks['i'] and not r.subtasks['ii']
    assert 'entry missed' in r.failure


def test_missing_the_entry_marker_by_far_scores_zero():
    r = complete_throw(ThrowScorer(), entry_mm=12.0, exit_mm=12.0).result(10.0)
    assert r.score == 0.0


@pytest.mark.parametrize('skip, reason', [
    ((3, 4), 'not regrasped'),
    ((5,), 'not extracted'),
    ((6, 7), 'no handover'),
    ((2,), 'no exit'),
    ((0,), 'not held by PSM2 at entry'),
])
def test_a_missing_step_scores_zero(skip, reason):
    r = complete_throw(ThrowScorer(), skip=skip).result(10.0)
    assert r.score == 0.0
    assert reason in r.failures
    assert r.time_s == pytest.approx(10.0)


def test_no_entry_at_all_scores_zero_with_nan_errors():
    s = ThrowScorer()
    s.on_grasp(0.0, 'PSM2')
    r = s.result(3.0)
    assert r.score == 0.0 and r.failures[0] == 'no entry'
    assert math.isnan(r.entry_error_mm) and math.isnan(r.exit_error_mm)
    assert not any(r.subtasks.values())


def test_a_drop_before_the_handover_scores_zero():
    s = ThrowScorer()
    s.on_grasp(1.0, 'PSM2')
    s.on_tissue_event(event(2.0, 'entry'))
    s.on_drop(2.5)
    r = s.result(3.0)
    assert r.dropped and r.score == 0.0 and 'dropped' in r.failures


def test_trauma_above_tolerance_scores_zero():
    s = complete_throw(ThrowScorer())
    s.on_tissue_event(event(5.5, 'trauma', deviation=0.003))
    r = s.result(10.0)
    assert r.score == 0.0 and r.failures == ('trauma',)
    assert r.trauma_mm == pytest.approx(3.0)


def test_withdrawing_and_reinserting_is_a_failure():
    s = ThrowScorer()
    s.on_grasp(1.0, 'PSM2')
    s.on_tissue_event(event(2.0, 'entry'))
    s.on_tissue_event(event(2.5, 'withdrawn', 0.0))
    s.on_tissue_event(event(3.0, 'entry'))
    s.on_tissue_event(event(4.0, 'exit'))
    r = s.result(5.0)
    assert 'withdrawn' in r.failures and r.score == 0.0


def test_collisions_are_counted_and_fail_only_past_the_configured_limit():
    s = complete_throw(ThrowScorer())
    for k in range(3):
        s.on_collision(1.0 + k, 'PSM1')
    assert s.result(10.0).collisions == 3 and s.result(10.0).score == 1.0
    strict = complete_throw(ThrowScorer(ScoringConfig(max_collisions=2)))
    for k in range(3):
        strict.on_collision(1.0 + k, 'PSM1')
    assert strict.result(10.0).failures == ('collisions',)


def test_handover_is_optional_when_configured():
    r = complete_throw(ThrowScorer(ScoringConfig(require_handover=False)),
                       skip=(6, 7)).result(10.0)
    assert r.score == 1.0 and not r.subtasks['v']


def test_unknown_event_kinds_are_rejected():
    with pytest.raises(ValueError, match='unknown tissue event kind'):
        ThrowScorer().on_tissue_event(event(0.0, 'bleed'))
