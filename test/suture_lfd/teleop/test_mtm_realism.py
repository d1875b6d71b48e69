"""A physical MTM's imperfection: level 0 exact, the preset off by its cited magnitudes, seeded."""

import math

import numpy as np
import pytest
from suture_lfd.teleop.mtm_realism import MtmImperfection, MtmRealism
from suture_lfd.teleop.virtual_mtm import VirtualMtm


def angle(T_a, T_b):
    cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return math.acos(max(-1.0, min(1.0, cos)))


def goal_pose(rng):
    T = np.eye(4)
    q = rng.normal(size=4)
    x, y, z, w = q / np.linalg.norm(q)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = rng.uniform(-0.1, 0.1, 3)
    return T


def test_level_zero_is_an_exact_mtm():
    perfect = MtmImperfection(MtmRealism(level=0.0))
    T = goal_pose(np.random.default_rng(0))
    assert np.array_equal(perfect.reached(T), T)
    assert np.array_equal(perfect.measured(T), T)
    assert perfect.gripper(0.3) == 0.3


def test_the_preset_lands_a_move_near_its_goal_never_on_it_and_reads_with_noise():
    rng = np.random.default_rng(1)
    mtm = MtmImperfection(MtmRealism(), stream=0)
    errors, noise, dots = [], [], []
    for _ in range(400):
        T = goal_pose(rng)
        reached = mtm.reached(T)
        errors.append(angle(reached, T))
        noise.append(angle(mtm.measured(reached), reached))
        # the dVRK teleoperation script's roll: acos of the dot of the two y axes, unclamped
        dots.append(float(np.dot(T[:3, 1], mtm.measured(reached)[:3, 1])))
    errors = np.degrees(errors)
    assert 0.2 < np.sqrt(np.mean(errors ** 2)) < 1.0      # 0.5 deg RMS about a random axis
    assert errors.max() < 5.0                              # inside the teleop's tolerance
    assert 0.0 < np.degrees(np.median(noise)) < 0.05       # encoder-class noise
    assert max(dots) < 1.0                                 # acos never leaves its domain
    # seeded: the same draws again, another stream other draws
    again = MtmImperfection(MtmRealism(), stream=0)
    other = MtmImperfection(MtmRealism(), stream=1)
    T = goal_pose(np.random.default_rng(2))
    assert np.array_equal(again.reached(T), MtmImperfection(MtmRealism(), stream=0).reached(T))
    assert not np.array_equal(again.reached(T), other.reached(T))


def test_a_virtual_mtm_move_ends_off_its_goal_and_stays_there():
    mtm = VirtualMtm('MTMR', np.eye(4), move_duration=0.5,
                     imperfection=MtmImperfection(MtmRealism(seed=3)))
    goal = goal_pose(np.random.default_rng(4))
    mtm.move_cp(goal, 0.0)
    assert mtm.is_busy(0.1)
    end = mtm.measured_cp(0.6)
    assert not mtm.is_busy(0.6)
    assert 0.0 < angle(end, goal) < math.radians(5.0)
    assert np.array_equal(mtm.measured_cp(1.0), end)       # it holds where it landed


def test_a_bad_magnitude_is_refused_with_its_name():
    with pytest.raises(ValueError, match='align_error'):
        MtmRealism(align_error=-1.0)
    with pytest.raises(ValueError, match='level'):
        MtmRealism(level=float('nan'))
