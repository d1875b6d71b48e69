"""Joint trajectories stay inside their limits, arrive together; tracking follows setpoints."""

import numpy as np
import pytest
from sim_bridge.trajectory import JointMotion, JointTrajectory, minimum_duration, track_step


def sampled(trajectory, n=1001):
    t = np.linspace(0.0, trajectory.duration, n)
    samples = [trajectory.sample(ti) for ti in t]
    return t, np.array([s[0] for s in samples]), np.array([s[1] for s in samples])


def test_rest_to_rest_durations_are_the_triangle_and_trapezoid_times():
    # v = a = 1: 1 unit is a trapezoid (1 s accelerating, ... total d/v + v/a = 2 s)
    assert JointTrajectory([0.0], [1.0], [1.0], [1.0]).duration == pytest.approx(2.0)
    # 0.25 units never reach v: triangle 2 sqrt(d / a) = 1 s
    assert JointTrajectory([0.0], [0.25], [1.0], [1.0]).duration == pytest.approx(1.0)
    assert JointTrajectory([0.0], [-0.25], [1.0], [1.0]).duration == pytest.approx(1.0)


def test_ratio_scales_velocity_and_acceleration():
    full = JointTrajectory([0.0], [1.0], [1.0], [1.0])
    half = JointTrajectory([0.0], [1.0], [1.0], [1.0], ratio=0.5)
    assert full.duration == pytest.approx(2.0)  # d / v + v / a
    assert half.duration == pytest.approx(3.0)  # d / (v / 2) + (v / 2) / (a / 2)


def test_random_trajectories_respect_limits_and_arrive_together():
    rng = np.random.default_rng(10)
    for case in range(100):
        n = 6
        v_max, a_max = rng.uniform(0.1, 3.0, n), rng.uniform(0.1, 3.0, n)
        start, goal = rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)
        ratio = rng.uniform(0.2, 1.0)
        v0 = rng.uniform(-1.5, 1.5, n) * v_max * ratio if case % 2 else np.zeros(n)
        traj = JointTrajectory(start, goal, v_max, a_max, ratio=ratio, start_velocity=v0)
        t, q, qd = sampled(traj)
        np.testing.assert_allclose(q[0], start, atol=1e-12)
        np.testing.assert_allclose(qd[0], v0, atol=1e-12)
        np.testing.assert_array_equal(q[-1], goal)
        np.testing.assert_array_equal(qd[-1], 0.0)
        v_limit = np.maximum(ratio * v_max, np.abs(v0))  # a faster start only slows down
        assert np.all(np.abs(qd) <= v_limit * (1 + 1e-9))
        accel = np.diff(qd, axis=0) / np.diff(t)[:, None]
        assert np.all(np.abs(accel) <= ratio * a_max * (1 + 1e-6))
        # continuity: positions integrate the velocities
        integral = start + np.concatenate(
            [np.zeros((1, n)), np.cumsum(0.5 * (qd[1:] + qd[:-1]) * np.diff(t)[:, None], 0)])
        assert np.max(np.abs(integral - q)) < 1e-3 * max(1.0, traj.duration)
        # synchronised: every joint that moves is still moving just before the end
        moving = np.abs(goal - start) > 1e-3
        before_end = traj.sample(traj.duration * (1 - 1e-3))[0]
        assert np.all(np.abs(before_end - goal)[moving] > 0.0)
        assert not traj.done(traj.duration * 0.999) and traj.done(traj.duration)


def test_sampling_in_plain_floats_gives_the_array_samples_bit_for_bit():
    rng = np.random.default_rng(3)
    for case in range(50):
        n = 6
        v_max, a_max = rng.uniform(0.1, 3.0, n), rng.uniform(0.1, 3.0, n)
        v0 = rng.uniform(-1.5, 1.5, n) * v_max if case % 2 else np.zeros(n)
        traj = JointTrajectory(rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n), v_max,
                               a_max, ratio=rng.uniform(0.2, 1.0), start_velocity=v0)
        for t in np.append(np.linspace(-0.1, traj.duration + 0.1, 97), traj.duration):
            q, qd = traj.sample(t)
            q_values, qd_values = traj.sample_values(t)
            assert np.array(q_values).tobytes() == q.tobytes(), (case, t)
            assert np.array(qd_values).tobytes() == qd.tobytes(), (case, t)


def test_the_slowest_joint_sets_the_duration():
    v_max, a_max = np.array([1.0, 0.1]), np.array([1.0, 0.1])
    traj = JointTrajectory([0.0, 0.0], [0.1, 0.1], v_max, a_max)
    alone = minimum_duration(np.array([0.1, 0.1]), np.zeros(2), v_max, a_max)
    assert traj.duration == pytest.approx(alone.max())
    assert alone[0] < alone[1]


def test_a_moving_start_that_must_overshoot_comes_back():
    traj = JointTrajectory([0.0], [0.01], [1.0], [1.0], start_velocity=[1.0])
    _, q, _ = sampled(traj)
    assert q.max() == pytest.approx(0.5, abs=1e-3)  # stopping distance v^2 / (2 a)
    assert q[-1, 0] == 0.01


def test_zero_length_trajectory_is_done_immediately():
    traj = JointTrajectory([0.2, 0.3], [0.2, 0.3], [1.0, 1.0], [1.0, 1.0])
    assert traj.duration == 0.0 and traj.done(0.0)
    q, qd = traj.sample(0.01)
    np.testing.assert_array_equal(q, [0.2, 0.3])
    np.testing.assert_array_equal(qd, 0.0)


@pytest.mark.parametrize('kwargs, message', [
    ({'ratio': 0.0}, 'ratio'),
    ({'ratio': 1.5}, 'ratio'),
    ({'start_velocity': [np.nan]}, 'start_velocity'),
])
def test_bad_trajectory_arguments_are_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        JointTrajectory([0.0], [1.0], [1.0], [1.0], **kwargs)


def test_nan_goal_is_rejected():
    with pytest.raises(ValueError, match='finite'):
        JointTrajectory([0.0], [np.nan], [1.0], [1.0])


def test_tracking_a_step_stays_in_limits_and_settles_exactly():
    v_max, a_max, dt = np.array([1.57, 0.2]), np.array([1.57, 0.2]), 0.002
    q, qd = np.zeros(2), np.zeros(2)
    goal = np.array([0.5, 0.05])
    history = []
    for _ in range(1500):
        previous = qd
        q, qd = track_step(q, qd, goal, v_max, a_max, dt)
        history.append(q)
        assert np.all(np.abs(qd) <= v_max + 1e-12)
        assert np.all(np.abs(qd - previous) <= a_max * dt + 1e-12)
    np.testing.assert_array_equal(q, goal)
    overshoot = np.max(np.array(history), axis=0) - goal
    assert np.all(overshoot < 0.01 * goal)


def test_tracking_a_trajectory_with_feed_forward_follows_it():
    v_max, a_max, dt = np.array([1.57, 0.2]), np.array([1.57, 0.2]), 0.002
    traj = JointTrajectory([0.0, 0.0], [0.5, 0.05], v_max, a_max)
    q, qd = np.zeros(2), np.zeros(2)
    t, worst = 0.0, 0.0
    while not traj.done(t - dt):
        t += dt
        setpoint, velocity = traj.sample(t)
        q, qd = track_step(q, qd, setpoint, v_max, a_max, dt, velocity)
        worst = max(worst, np.max(np.abs(q - setpoint)))
    assert worst < 1e-9


def make_motion(q0=(0.0,)):
    n = len(q0)
    return JointMotion(q0, [-3.0] * n, [3.0] * n, [1.5] * n, [1.5] * n)


def test_a_servo_stream_glides_from_setpoint_to_setpoint():
    motion = make_motion()
    t, dt, speed = 0.0, 0.002, 0.2
    worst_lag = 0.0
    for k in range(500):
        if k % 5 == 0:  # 100 Hz commands of a ramp
            motion.servo(np.array([speed * t]), t, stream_gap=0.1)
        t += dt
        assert not motion.advance(t, dt)
        if k > 200:  # after the acceleration-limited start of the stream
            worst_lag = max(worst_lag, abs(speed * t - motion.q[0]))
            assert motion.qd[0] == pytest.approx(speed, rel=1e-6)
    assert worst_lag <= speed * 0.01 + 1e-9  # one command interval behind


def test_a_move_replacing_a_move_starts_from_its_setpoint_and_velocity():
    motion = make_motion()
    dt, t = 0.002, 0.0
    motion.move(np.array([2.0]), t, ratio=1.0)
    for _ in range(300):
        t += dt
        motion.advance(t, dt)
    position, velocity = motion.target(t)
    second = motion.move(np.array([-1.0]), t, ratio=1.0)
    assert second.start[0] == position[0]
    assert second.sample(0.0)[1][0] == pytest.approx(velocity[0])
    arrived = False
    while not arrived:
        t += dt
        arrived = motion.advance(t, dt)
    assert motion.setpoint[0] == -1.0
    assert motion.q[0] == pytest.approx(-1.0, abs=1e-9)


def test_hold_stops_at_the_measured_position():
    motion = make_motion()
    motion.move(np.array([1.0]), 0.0, ratio=1.0)
    motion.advance(0.1, 0.1)
    motion.hold()
    assert motion.trajectory is None and motion.qd[0] == 0.0
    assert motion.setpoint[0] == motion.q[0]


def test_a_motion_tracks_joint_by_joint_exactly_as_track_step_and_the_limits_say():
    # JointMotion tracks in plain floats; the array functions are the definition
    rng = np.random.default_rng(7)
    lower, upper = np.array([-1.0, -0.5, 0.0, -2.0]), np.array([1.0, 0.5, 0.24, 2.0])
    v_max, a_max = np.array([1.0, 0.7, 0.2, 3.0]), np.array([2.0, 1.5, 0.5, 6.0])
    motion = JointMotion(np.zeros(4), lower, upper, v_max, a_max)
    hits = 0
    for k in range(3000):
        dt = (0.002, 0.01, 0.02)[k % 3]
        motion.q = rng.uniform(lower - 0.01, upper + 0.01)
        motion.qd = rng.normal(scale=0.5, size=4) * (k % 5 != 0)
        target = np.where(rng.random(4) < 0.2, motion.q + rng.normal(scale=1e-13, size=4),
                          rng.uniform(lower - 0.2, upper + 0.2))
        velocity = None if k % 2 else rng.normal(scale=0.3, size=4)
        q, qd = track_step(motion.q, motion.qd, target, v_max, a_max, dt, velocity)
        q_ref = np.clip(q, lower, upper)
        qd_ref = np.where(q_ref == q, qd, 0.0)
        got_q, got_qd = motion._track(target.tolist(),
                                      None if velocity is None else velocity.tolist(), dt)
        assert np.array(got_q).tobytes() == q_ref.tobytes(), k
        assert np.array(got_qd).tobytes() == qd_ref.tobytes(), k
        hits += int(np.any(q_ref != q)) + int(np.any(q == target))
    assert hits > 100   # the limits and the exact arrival were exercised


def test_exact_tracking_clips_as_numpy_does_down_to_the_sign_of_zero():
    lower, upper = np.array([0.0, -1.0, -0.5]), np.array([1.0, -0.0, 0.5])
    motion = JointMotion([0.5, -0.5, 0.0], lower, upper, [1.0] * 3, [1.0] * 3)
    for goal in ([-0.0, 0.0, 0.2], [-0.3, 2.0, -0.7], [0.0, -0.0, 0.5], [1.5, -1.5, 0.1]):
        motion.servo(np.array(goal), 0.0, stream_gap=0.1)
        motion.advance(0.002, 0.002, exact=True)
        expected = np.clip(np.array(goal), lower, upper)
        assert motion.q.tobytes() == expected.tobytes(), goal
