"""Expert-derived proficiency bounds decide which demonstrations a skill is learnt from."""

import math

import pytest
from suture_lfd.assessment.acceptance import AcceptanceRule, assess_cohort, proficiency_bounds

RULE = AcceptanceRule(metrics=('entry_error_mm', 'tilt_mean_deg'), k_sd=2.0)


def _row(subject, group, entry, tilt):
    return {'subject': subject, 'group': group, 'entry_error_mm': entry, 'tilt_mean_deg': tilt}


def _cohort():
    rows = []
    for k, subject in enumerate(('E1', 'E2', 'E3')):
        for j in range(4):
            rows.append(_row(subject, 'experienced', 0.4 + 0.1 * j, 1.0 + 0.2 * j + 0.1 * k))
    rows += [_row('N1', 'naive', 0.5, 1.2), _row('N1', 'naive', 0.5, 9.0),
             _row('N1', 'naive', 2.5, 1.0), _row('N1', 'naive', math.nan, 1.0)]
    return rows


def test_the_bounds_are_the_reference_mean_plus_k_standard_deviations():
    rows = _cohort()
    bounds = proficiency_bounds(rows, RULE, without_subject='N1')
    mean, sd, bound = bounds['entry_error_mm']
    assert mean == pytest.approx(0.55)
    assert bound == pytest.approx(mean + 2.0 * sd)


def test_a_demonstration_outside_a_bound_is_rejected_with_the_score_named():
    verdicts = assess_cohort(_cohort(), RULE)
    naive = verdicts[-4:]
    assert [v['accepted'] for v in naive] == [True, False, False, False]
    assert naive[1]['reasons'].startswith('tilt_mean_deg 9.00 >')
    assert naive[2]['reasons'].startswith('entry_error_mm 2.50 >')
    assert naive[3]['reasons'] == 'entry_error_mm not measured'
    assert naive[1]['combined_score'] > RULE.k_sd >= naive[0]['combined_score']


def test_a_subject_is_judged_without_its_own_demonstrations():
    rows = _cohort()
    # E3's demonstrations alone are far worse: with them in the reference they would pass
    for r in rows:
        if r['subject'] == 'E3':
            r['tilt_mean_deg'] += 6.0
    verdicts = assess_cohort(rows, RULE)
    e3 = [v for r, v in zip(rows, verdicts) if r['subject'] == 'E3']
    assert not any(v['accepted'] for v in e3)


def test_too_few_reference_demonstrations_is_a_clear_error():
    with pytest.raises(ValueError, match="two demonstrations of the 'experienced' group"):
        assess_cohort([_row('E1', 'experienced', 0.5, 1.0), _row('N1', 'naive', 0.5, 1.0)],
                      RULE)
    with pytest.raises(ValueError, match='k_sd'):
        AcceptanceRule(k_sd=0.0)
