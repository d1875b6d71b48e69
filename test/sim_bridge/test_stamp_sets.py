"""
Pairing an arm's state messages by stamp: a controller steps only on parts of one instant.

Plain Python, no ROS: the messages arrive in the orders a lagging or bursting stream delivers.
"""

import pytest
from sim_bridge.common.stamp_sets import StampSets

PARTS = ('cp', 'local', 'js', 'jaw')


def deliver(sets, arrivals):
    """Put ``(arm, part, stamp)`` arrivals; return the arm's state after each one."""
    states = []
    for arm, part, stamp in arrivals:
        sets.put(arm, part, stamp, f'{part}@{stamp}')
        states.append(sets.newest(arm))
    return states


def test_interleaved_periods_give_a_state_made_of_one_stamp_only():
    sets = StampSets(['PSM1'], PARTS)
    # the next period's pose overtakes this period's joints (a burst after a stalled loop)
    arrivals = [('PSM1', 'cp', 1.0), ('PSM1', 'local', 1.0), ('PSM1', 'cp', 2.0),
                ('PSM1', 'local', 2.0), ('PSM1', 'js', 1.0), ('PSM1', 'jaw', 1.0),
                ('PSM1', 'js', 2.0)]
    states = deliver(sets, arrivals)
    assert states[:5] == [None] * 5  # nothing whole yet: no state at all
    stamp, parts = states[5]
    assert stamp == 1.0
    # the newest of each part would join the pose of 2.0 to the joints of 1.0
    assert parts == {p: f'{p}@1.0' for p in PARTS}
    assert states[6] == states[5]  # 2.0 still lacks its jaw
    sets.put('PSM1', 'jaw', 2.0, 'jaw@2.0')
    assert sets.newest('PSM1') == (2.0, {p: f'{p}@2.0' for p in PARTS})
    assert sets.stamps() == {'PSM1': 2.0}


def test_a_late_part_of_an_older_stamp_never_takes_the_state_back():
    sets = StampSets(['PSM1', 'PSM2'], ('cp', 'js'))
    deliver(sets, [('PSM1', 'cp', 2.0), ('PSM1', 'js', 2.0), ('PSM1', 'cp', 1.0),
                   ('PSM1', 'js', 1.0), ('PSM2', 'js', 1.0)])
    assert sets.newest('PSM1') == (2.0, {'cp': 'cp@2.0', 'js': 'js@2.0'})
    assert sets.newest('PSM2') is None
    assert sets.stamps() == {'PSM1': 2.0}


def test_incomplete_stamps_are_forgotten_beyond_the_pending_limit():
    sets = StampSets(['PSM1'], ('cp', 'js'), pending=2)
    deliver(sets, [('PSM1', 'cp', 1.0), ('PSM1', 'cp', 2.0), ('PSM1', 'cp', 3.0)])
    assert not sets.put('PSM1', 'js', 1.0, 'js@1.0')  # 1.0 was dropped: its pose is gone
    assert sets.newest('PSM1') is None
    assert sets.put('PSM1', 'js', 3.0, 'js@3.0')
    assert sets.newest('PSM1') == (3.0, {'cp': 'cp@3.0', 'js': 'js@3.0'})


def test_an_unknown_part_is_refused_with_the_parts_expected():
    sets = StampSets(['PSM1'], PARTS)
    with pytest.raises(ValueError, match="unknown part 'pose'.*'cp', 'local', 'js', 'jaw'"):
        sets.put('PSM1', 'pose', 1.0, None)
