"""The study report's section on the needle turning in the jaw."""

from suture_lfd.study.records import ThrowRecord
from suture_lfd.study.slips import report_section, slip_counts


def _slip(arm, broken=False):
    return {'t': 1.0, 'arm': arm, 'angle': 0.02, 'slide': 0.0, 'in_tissue': True,
            'broken': broken}


def _rows():
    return [ThrowRecord(key='a', method='paper', score=1.0, failure='',
                        slips=[_slip('PSM2'), _slip('PSM1')]),
            ThrowRecord(key='b', method='paper', score=0.0, failure='trauma',
                        slips=[_slip('PSM1'), _slip('PSM1', broken=True)]),
            ThrowRecord(key='c', method='paper', score=1.0, failure=''),
            ThrowRecord(key='d', method='pair_frame', score=1.0, failure='')]


def test_slips_are_counted_by_the_arm_that_held_the_needle():
    c = slip_counts([r for r in _rows() if r.method == 'paper'])
    assert c == {'throws': 3, 'slipped': 2, 'by_phase': {'i-ii': 1, 'iii-iv': 2},
                 'episodes': 4, 'complete': 1, 'failures': {'trauma': 1}, 'broken': 1}


def test_the_section_shows_with_the_tissue_preset_only():
    assert report_section([ThrowRecord(key='d', method='pair_frame', score=1.0)],
                          {'settings': {'tissue': 'none'}}) == []
    lines = report_section(_rows(), {'settings': {'tissue': 'tissue'}})
    table = '\n'.join(lines)
    assert '| `paper` | 3 | 2 | 1 | 2 | 4 | 1 | trauma 1 | 1 |' in table
    assert '| `pair_frame` | 1 | 0 | 0 | 0 | 0 | 0 | - | 0 |' in table
