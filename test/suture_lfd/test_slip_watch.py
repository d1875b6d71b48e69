"""The slip watch takes a turned grasp once it has settled, once per DMP subtask."""

import math

import numpy as np
from suture_lfd.skill.slip_watch import (
    SETTLE,
    SlipWatch,
    grasps_differ,
    observed_grasp,
    slip_checkpoints,
)


def turned_about_z(T, angle):
    c, s = math.cos(angle), math.sin(angle)
    R = np.eye(4)
    R[:2, :2] = [[c, -s], [s, c]]
    return R @ T


def test_the_observed_grasp_is_the_needle_in_the_tool_frame():
    rng = np.random.default_rng(0)
    for _ in range(20):
        tool = turned_about_z(np.eye(4), rng.uniform(-3, 3))
        tool[:3, 3] = rng.normal(size=3)
        grasp = turned_about_z(np.eye(4), rng.uniform(-3, 3))
        grasp[:3, 3] = rng.normal(scale=0.01, size=3)
        assert np.allclose(observed_grasp(tool, tool @ grasp), grasp)


def test_a_turn_past_the_threshold_is_taken_after_it_settled_and_only_once_per_subtask():
    known = np.eye(4)
    known[:3, 3] = [0.01, 0.0, 0.006]
    tool = np.eye(4)
    watch = SlipWatch(turn=0.0035, shift=0.0001, corrections=1)
    small = turned_about_z(known, 0.002)
    assert not grasps_differ(small, known, 0.0035, 0.0001)
    assert all(watch.notice('ii', known, tool, tool @ small) is None for _ in range(10))
    turned = turned_about_z(known, math.radians(3.0))
    taken = [watch.notice('ii', known, tool, tool @ turned) for _ in range(SETTLE)]
    assert all(t is None for t in taken[:-1])
    assert np.allclose(taken[-1], turned) and watch.noticed == 1
    further = turned_about_z(known, math.radians(6.0))
    assert all(watch.notice('ii', known, tool, tool @ further) is None for _ in range(10))
    assert watch.notice('iii', known, tool, tool @ further) is None  # scripted: not watched
    assert [watch.notice('iv', known, tool, tool @ further)
            for _ in range(SETTLE)][-1] is not None
    watch.reset()
    assert watch.noticed == 0


def test_looks_are_spread_evenly_over_each_dmp_subtask_on_its_holding_arm():
    labels = [(0.0, 'i'), (2.0, 'ii'), (5.0, 'iii'), (6.0, 'iv'), (10.0, 'v'), (12.0, 'end')]
    assert slip_checkpoints(labels, 2) == [(3.0, 'PSM2'), (4.0, 'PSM2'),
                                           (6.0 + 4.0 / 3.0, 'PSM1'), (6.0 + 8.0 / 3.0, 'PSM1')]
