"""
The play a controller follows from the reported joints is the cable transmission's own.

The simulator's :class:`sim_bridge.realism.transmission.JointTransmission` hides a dead band
behind the motors' encoders; :class:`suture_lfd.skill.hysteresis.PlayTracker`, knowing the band,
sees only the reported joints. Once every joint has moved further than its band the two agree
exactly, whatever the play they started with; :func:`plays_at` agrees with both at the poses of a
motion reduced to its monotone runs.
"""

import numpy as np
from sim_bridge.realism.transmission import JointTransmission, TransmissionConfig
from suture_lfd.skill.hysteresis import (
    PSM_STILL,
    PlaysMemo,
    PlayTracker,
    TargetPlay,
    plays_at,
    run_lengths,
)

BAND = (0.0175, 0.0175, 0.0005, 0.052, 0.052, 0.052)


def _motion(rng, n=400):
    """A joint motion with reversals of every size, some shorter than the bands."""
    steps = rng.normal(scale=0.004, size=(n, 6)) * np.array([1, 1, 0.05, 2, 2, 2])
    return np.cumsum(steps, axis=0)


def test_the_tracker_follows_the_hidden_play_once_the_joints_have_moved():
    rng = np.random.default_rng(3)
    for _ in range(5):
        start = rng.uniform(-0.5, 0.5, 6) * np.array(BAND)
        truth = JointTransmission(TransmissionConfig(backlash=BAND), start)
        tracker = PlayTracker(BAND)
        sweep = np.linspace(0.0, 0.2, 30)[:, None] * np.array([1, 1, 0.01, 1, 1, 1])
        Q = np.vstack([sweep, sweep[-1] + _motion(rng)])
        for k, q in enumerate(Q):
            true_q = truth.apply(q)
            play = tracker.update(q)
            if k >= len(sweep):  # past the first long move: the play is known
                assert np.allclose(np.asarray(play), true_q - q, atol=1e-12)


def test_the_play_at_poses_from_run_lengths_equals_the_step_by_step_play():
    rng = np.random.default_rng(4)
    Q = _motion(rng, 600)
    cuts = [50, 120, 121, 300, 420, 599]
    paths, last = [], 0
    for c in cuts:
        paths.append(Q[last:c + 1])
        last = c
    tracker = PlayTracker(BAND)
    expected = []
    for k, q in enumerate(Q[:cuts[-1] + 1]):
        play = tracker.update(q)
        if k in cuts:
            expected.append(play)
    got = plays_at(run_lengths(paths, 6), BAND)
    assert np.allclose(got, np.asarray(expected), atol=1e-12)


def test_the_plays_memo_gives_plays_at_of_every_band_bit_for_bit():
    """A fit's finite differences: one joint's band moved at a time, the memo full and reset."""
    rng = np.random.default_rng(5)
    Q = _motion(rng, 400)
    runs = run_lengths([Q[:100], Q[99:250], Q[249:]], 6)
    memo = PlaysMemo(runs, size=3)
    band = np.asarray(BAND, dtype=float)
    for k in range(20):
        moved = band.copy()
        moved[k % 6] += 1e-8 * (k + 1)
        for b in (band, moved, 0.5 * band, np.zeros(6)):
            assert np.array_equal(memo(b), plays_at(runs, b))


def test_heading_crosses_the_band_of_a_joint_about_to_reverse_and_keeps_a_still_one():
    tracker = PlayTracker(BAND)
    tracker.update(np.zeros(6))
    tracker.update(np.full(6, 0.1))     # every joint moved up: play at -b/2
    q = np.full(6, 0.1)
    q_to = q + np.array([-0.01, 0.01, 0.0, -1e-7, 0.02, -0.02])
    heading = tracker.heading(q, q_to)
    half = 0.5 * np.asarray(BAND)
    assert np.allclose(heading, [half[0], -half[1], -half[2], -half[3], -half[4], half[5]])


def test_a_joint_at_rest_keeps_its_play_through_its_encoders_jitter():
    """A reading that jitters by a count or two is no direction: no dead band flipped at rest."""
    tracker = PlayTracker(BAND)
    tracker.update(np.zeros(6))
    q = np.full(6, 0.1)
    tracker.update(q)                   # every joint moved up: play at -b/2
    rng = np.random.default_rng(0)
    count = np.array([1e-4, 1e-4, 2e-6, 1e-4, 1e-4, 1e-4])  # a dVRK encoder's count
    for _ in range(200):                # at rest: the command is where the arm is
        jitter = q + count * np.round(rng.normal(0.0, 0.7, 6))  # 0.5 rms and a count
        assert tracker.heading(jitter, q, PSM_STILL) == tracker.play
    # a real reversal still crosses the band at once
    half = 0.5 * np.asarray(BAND)
    assert np.allclose(tracker.heading(q, q - 10 * np.asarray(PSM_STILL), PSM_STILL), half)


def test_the_backlash_inverse_follows_the_targets_direction_not_a_reading():
    """The play a command allows for turns with its targets, a few counts' wiggle aside."""
    band = np.array(BAND)
    band[3] = 0.0                        # a joint without backlash keeps its play
    half = 0.5 * band
    inverse = TargetPlay(band, PSM_STILL)
    start = np.full(6, 0.1)
    inverse.start([0.002] * 6, start)
    still = np.asarray(PSM_STILL)
    # the joints where the target is: no direction yet, the play the reports show kept
    assert inverse.update(start + 0.5 * still, start - 0.002, [0.002] * 6) == [0.002] * 6
    rising = [start + k * 2 * still for k in range(1, 6)]
    for target in rising:
        play = inverse.update(target, start, [0.0] * 6)
    assert np.allclose(play, np.where(band > 0, -half, 0.002))
    # back by less than `still` from the furthest target: still rising, wherever the reports
    # say the joint is (a servo's overshoot)
    assert np.allclose(inverse.update(rising[-1] - 0.5 * still, rising[-1] + 3 * still, half),
                       play)
    # back by more: the band is crossed in this very command
    assert np.allclose(inverse.update(rising[-1] - 1.5 * still, rising[-1], [0.0] * 6),
                       np.where(band > 0, half, 0.002))
