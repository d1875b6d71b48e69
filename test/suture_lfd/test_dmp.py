import json
import math

import numpy as np
import pytest
from sim_bridge.common.configfile import ConfigError
from sim_bridge.common.geometry import quaternion_angle, quaternion_from_rotvec, quaternion_product
from suture_lfd.demos.synthetic_throw import minimum_jerk, needle_throw
from suture_lfd.dmp import (
    DmpParams,
    PoseDmp,
    PositionDmp,
    QuaternionDmp,
    load_dmp,
    load_dmp_params,
)
from suture_lfd.study.metrics import (
    endpoint_errors,
    orientation_trajectory_error,
    trajectory_error,
)

HUNDRED = DmpParams(n_bfs=100, n_bfs_o=100, n_pts=500)


def random_throw(rng, rotation_deg=None, wobble_deg=None, n_pts=500):
    """A realistic throw: ~10 mm needle radius, 120-200 degrees, 1-3 s, minimum jerk."""
    return needle_throw(
        n_pts, float(rng.uniform(1.0, 3.0)), radius=float(rng.uniform(0.009, 0.011)),
        rotation_deg=float(rng.uniform(120.0, 200.0)) if rotation_deg is None else rotation_deg,
        wobble_deg=float(rng.uniform(0.0, 5.0)) if wobble_deg is None else wobble_deg,
        start_rotvec=rng.normal(size=3), centre=rng.uniform(-0.05, 0.05, 3))


def test_a_learned_throw_reproduces_its_demonstration():
    rng = np.random.default_rng(1)
    for _ in range(4):
        T, P, Q = random_throw(rng)
        dmp = PoseDmp(HUNDRED).fit(T, P, Q)
        T_out, P_out, Q_out = dmp.rollout()
        assert T_out.shape == (500,) and np.isclose(T_out[-1], T[-1] - T[0])
        position = trajectory_error(P, P_out)
        orientation = orientation_trajectory_error(Q, Q_out)
        ends = endpoint_errors(P_out, P[0], P[-1], Q_out, Q[0], Q[-1])
        assert position['mean_mm'] < 0.2
        assert orientation['mean_deg'] < 1.0
        assert ends['goal_mm'] < 0.1
        assert ends['start_mm'] < 1e-9
        # the same bounds hold without time warping
        assert np.mean(np.linalg.norm(P_out - P, axis=1)) * 1e3 < 0.2
        assert np.degrees(np.mean(quaternion_angle(Q_out, Q))) < 1.0


def test_table_one_defaults_for_task_ii_stay_near_the_paper():
    # Table I: 100 position and 40 orientation basis functions (paper: 0.17 mm, 1.71 deg)
    T, P, Q = random_throw(np.random.default_rng(2))
    dmp = PoseDmp(load_dmp_params(task='ii')).fit(T, P, Q)
    _, P_out, Q_out = dmp.rollout()
    assert P_out.shape == (500, 3)
    assert trajectory_error(P, P_out)['mean_mm'] < 0.2
    assert orientation_trajectory_error(Q, Q_out)['mean_deg'] < 1.71


def half_circle(n_pts=500, radius=0.012):
    """x from r to -r, y out and back (start y = goal y), z constant: two degenerate axes."""
    s = minimum_jerk(np.linspace(0.0, 1.0, n_pts))
    return np.linspace(0.0, 1.0, n_pts), np.column_stack(
        (radius * np.cos(np.pi * s), radius * np.sin(np.pi * s), np.full(n_pts, 0.02)))


def test_an_axis_whose_start_and_goal_coincide_keeps_its_excursion():
    T, Y = half_circle()
    demo_excursion = np.ptp(Y[:, 1])
    dmp = PositionDmp(DmpParams()).fit(T, Y)
    assert dmp.degenerate_.tolist() == [False, True, True]
    _, again = dmp.rollout()
    assert 0.9 * demo_excursion < np.ptp(again[:, 1]) < 1.1 * demo_excursion
    for shift in (0.001, -0.001):
        _, moved = dmp.rollout(goal=Y[-1] + [0.0, shift, 0.0])
        assert 0.5 * demo_excursion < np.ptp(moved[:, 1]) < 2.0 * demo_excursion
        assert moved[:, 1].max() > 0.5 * demo_excursion          # not mirrored
        assert abs(moved[-1, 1] - (Y[-1, 1] + shift)) < 1e-4      # and still heads to the goal
    assert np.allclose(again[:, 2], Y[0, 2], atol=1e-9)


def test_ude_form_reproduces_large_turns_about_a_fixed_axis():
    rng = np.random.default_rng(3)
    for rotation in (170.0, 200.0, 270.0, 340.0):
        T, P, Q = random_throw(rng, rotation_deg=rotation, wobble_deg=0.0)
        signs = np.where(rng.random(T.size) < 0.3, -1.0, 1.0)     # a tracker's sign flips
        dmp = QuaternionDmp(HUNDRED).fit(T, Q * signs[:, None])
        _, Q_out = dmp.rollout()
        assert np.degrees(np.mean(quaternion_angle(Q_out, Q))) < 2.0, rotation


def test_log_form_reproduces_large_turns_about_a_wobbling_axis():
    rng = np.random.default_rng(4)
    params = DmpParams(n_bfs=100, n_bfs_o=100, orientation_form='log')
    for rotation in (170.0, 200.0, 270.0, 340.0):
        T, P, Q = random_throw(rng, rotation_deg=rotation, wobble_deg=5.0)
        _, Q_out = QuaternionDmp(params).fit(T, Q).rollout()
        assert np.degrees(np.mean(quaternion_angle(Q_out, Q))) < 2.0, rotation


def test_ude_form_handles_a_wobbling_axis_up_to_270_degrees_but_not_near_a_full_turn():
    # Documented limitation of the literal-log Ude system (QuaternionDmp docstring).
    rng = np.random.default_rng(5)
    for rotation in (200.0, 270.0):
        T, _, Q = random_throw(rng, rotation_deg=rotation, wobble_deg=5.0)
        _, Q_out = QuaternionDmp(HUNDRED).fit(T, Q).rollout()
        assert np.degrees(np.mean(quaternion_angle(Q_out, Q))) < 2.0
    T, _, Q = random_throw(rng, rotation_deg=340.0, wobble_deg=5.0)
    _, Q_out = QuaternionDmp(HUNDRED).fit(T, Q).rollout()
    assert np.degrees(np.mean(quaternion_angle(Q_out, Q))) > 5.0


def test_goal_sign_does_not_change_the_rollout():
    T, P, Q = random_throw(np.random.default_rng(6), rotation_deg=250.0, wobble_deg=0.0)
    dmp = QuaternionDmp(HUNDRED).fit(T, Q)
    goal = quaternion_product(quaternion_from_rotvec([0.05, -0.02, 0.04]), Q[-1])
    _, plus = dmp.rollout(goal=goal)
    _, minus = dmp.rollout(start=-Q[0], goal=-goal)
    assert np.degrees(quaternion_angle(plus, minus)).max() < 1e-9
    turned = np.degrees(quaternion_angle(plus[0], plus[250])) + np.degrees(
        quaternion_angle(plus[250], plus[-1]))
    assert turned > 200.0                                          # still the long way round


def test_generalised_rollout_starts_at_the_new_start_and_ends_near_the_new_goal():
    rng = np.random.default_rng(7)
    T, P, Q = random_throw(rng)
    dmp = PoseDmp(HUNDRED).fit(T, P, Q)
    for _ in range(5):
        start = np.concatenate((P[0] + rng.uniform(-0.003, 0.003, 3), quaternion_product(
            quaternion_from_rotvec(rng.normal(0.0, 0.1, 3)), Q[0])))
        goal = np.concatenate((P[-1] + rng.uniform(-0.003, 0.003, 3), quaternion_product(
            quaternion_from_rotvec(rng.normal(0.0, 0.1, 3)), Q[-1])))
        _, P_out, Q_out = dmp.rollout(start, goal)
        ends = endpoint_errors(P_out, start[:3], goal[:3], Q_out, start[3:], goal[3:])
        assert ends['start_mm'] < 1e-9 and ends['start_deg'] < 1e-6
        assert ends['goal_mm'] < 0.1 and ends['goal_deg'] < 1.0


def test_stepping_online_gives_the_rollout():
    T, P, Q = random_throw(np.random.default_rng(8))
    dmp = PoseDmp(HUNDRED).fit(T, P, Q)
    _, P_out, Q_out = dmp.rollout()
    dmp.reset()
    dt = T[1] - T[0]
    poses = np.array([np.concatenate((P_out[0], Q_out[0]))]
                     + [dmp.step(dt) for _ in range(T.size - 1)])
    assert np.abs(poses[:, :3] - P_out).max() < 1e-9
    assert np.degrees(quaternion_angle(poses[:, 3:], Q_out)).max() < 1e-6


def test_a_slower_execution_follows_the_same_path():
    T, P, Q = random_throw(np.random.default_rng(9))
    dmp = PositionDmp(HUNDRED).fit(T, P)
    _, fast, v_fast = dmp.rollout(return_velocity=True)
    _, slow, v_slow = dmp.rollout(T=np.linspace(0.0, 2.0 * T[-1], 500), return_velocity=True)
    assert np.abs(fast - slow).max() < 1e-12
    assert np.allclose(v_slow, 0.5 * v_fast)


def run_online(dmp, dt, steps, hold=None, switch=None):
    """Step a PoseDmp; hold = (first, last) steps where the robot is stuck; switch = (k, goal)."""
    poses, phases, vel = [], [], []
    stuck = None
    for k in range(steps):
        if switch is not None and k == switch[0]:
            dmp.set_goal(switch[1], immediate=switch[2] if len(switch) > 2 else False)
        measured = None
        if hold is not None and hold[0] <= k < hold[1]:
            stuck = poses[-1] if stuck is None else stuck
            measured = stuck
        poses.append(dmp.step(dt, measured=measured))
        phases.append(dmp.phase)
        vel.append(dmp.position.velocity.copy())
    return np.array(poses), np.array(phases), np.array(vel)


def test_holding_the_robot_back_pauses_the_phase_and_releasing_it_reaches_the_goal():
    T, P, Q = random_throw(np.random.default_rng(10), wobble_deg=0.0)
    dmp = PoseDmp(HUNDRED).fit(T, P, Q)
    tau, dt = T[-1] - T[0], 0.002
    n_hold = int(0.5 * tau / dt)
    first = int(0.3 * tau / dt)
    dmp.reset()
    poses, phases, _ = run_online(dmp, dt, int(6.0 * tau / dt) + n_hold,
                                  hold=(first, first + n_hold))
    held_phase_time = -np.log(phases[first + n_hold - 1] / phases[first - 1]) * tau
    assert held_phase_time < 0.15 * n_hold * dt                 # the phase nearly stopped
    assert np.linalg.norm(poses[first + n_hold - 1, :3] - poses[first - 1, :3]) < 0.005
    assert phases[-1] < math.exp(-5.0)                           # and then ran on
    assert np.linalg.norm(poses[-1, :3] - P[-1]) < 5e-5
    assert np.degrees(quaternion_angle(poses[-1, 3:], Q[-1])) < 0.1


def test_small_tracking_errors_barely_slow_the_phase():
    T, P, Q = random_throw(np.random.default_rng(11))
    dmp = PoseDmp(HUNDRED).fit(T, P, Q).reset()
    pose = dmp.step(0.002)
    lagging = pose + np.r_[1e-4, 0.0, 0.0, np.zeros(4)]          # 0.1 mm behind
    before = dmp.phase
    dmp.step(0.002, measured=lagging)
    free = math.exp(-0.002 / (T[-1] - T[0]))
    assert dmp.phase / before < free ** 0.98


def test_switching_the_goal_mid_run_reaches_it_without_an_acceleration_jump():
    T, P, Q = random_throw(np.random.default_rng(12))
    tau = T[-1] - T[0]
    new_goal = np.concatenate((P[-1] + [0.003, -0.002, 0.002], quaternion_product(
        quaternion_from_rotvec([0.0, 0.15, 0.1]), Q[-1])))
    dmp = PoseDmp(HUNDRED).fit(T, P, Q).reset()
    poses, _, _ = run_online(dmp, 0.002, int(7.0 * tau / 0.002),
                             switch=(int(0.5 * tau / 0.002), new_goal))
    assert np.linalg.norm(poses[-1, :3] - new_goal[:3]) < 5e-5
    assert np.degrees(quaternion_angle(poses[-1, 3:], new_goal[3:])) < 0.1

    def change_across_switch(dt, immediate):
        """Largest change of the acceleration between neighbouring steps at the switch."""
        k = int(0.5 * tau / dt)
        dmp.reset()
        _, _, vel = run_online(dmp, dt, k + 5, switch=(k, new_goal, immediate))
        acc = np.diff(vel, axis=0) / dt
        return np.linalg.norm(np.diff(acc, axis=0), axis=1)[k - 3:k + 2].max()

    # continuous acceleration: its change across the switch shrinks with the step ...
    assert change_across_switch(0.001, False) < 0.6 * change_across_switch(0.002, False)
    # ... while an unfiltered switch jumps by the same amount at any step
    assert change_across_switch(0.001, True) > 0.9 * change_across_switch(0.002, True)
    assert change_across_switch(0.001, True) > 10.0 * change_across_switch(0.001, False)


def test_a_learnt_dmp_round_trips_through_a_file(tmp_path):
    T, P, Q = random_throw(np.random.default_rng(13))
    params = load_dmp_params(task='iv')
    dmp = PoseDmp(params).fit(T, P, Q)
    path = tmp_path / 'throw.npz'
    dmp.save(path)
    again = load_dmp(path)
    assert isinstance(again, PoseDmp) and again.params == params
    for a, b in zip(dmp.rollout(), again.rollout()):
        assert np.array_equal(a, b)
    part = tmp_path / 'position.npz'
    dmp.position.save(part)
    assert np.array_equal(PositionDmp.load(part).rollout()[1], dmp.position.rollout()[1])


def test_loading_a_wrong_file_says_which_file_and_why(tmp_path):
    T, P, Q = random_throw(np.random.default_rng(14), n_pts=100)
    dmp = PoseDmp(DmpParams(n_bfs=20, n_bfs_o=10)).fit(T, P, Q)
    good = tmp_path / 'good.npz'
    dmp.save(good)
    with np.load(good) as data:
        arrays = dict(data)
    arrays['format_version'] = np.array(99)
    future = tmp_path / 'future.npz'
    with open(future, 'wb') as handle:
        np.savez(handle, **arrays)
    with pytest.raises(ValueError, match=r'future\.npz.*version 99'):
        PoseDmp.load(future)
    text = tmp_path / 'notes.npz'
    text.write_text('not a dmp')
    with pytest.raises(ValueError, match=r'notes\.npz'):
        load_dmp(text)
    with pytest.raises(ValueError, match=r"good\.npz.*'pose'"):
        PositionDmp.load(good)
    arrays['format_version'] = np.array(1)
    arrays['params'] = np.array(json.dumps({'alpha_x': 1.0, 'n_bfs': 'many'}))
    broken = tmp_path / 'broken.npz'
    with open(broken, 'wb') as handle:
        np.savez(handle, **arrays)
    with pytest.raises(ValueError, match=r'broken\.npz.*n_bfs'):
        load_dmp(broken)


def test_dmp_yaml_holds_table_one():
    ii, iv = load_dmp_params(task='ii'), load_dmp_params(task='iv')
    for p in (ii, iv):
        assert (p.alpha_x, p.alpha_y, p.beta_y, p.alpha_z, p.beta_z) == (1, 25, 6.25, 25, 6.25)
    assert (ii.n_pts, ii.n_bfs, ii.n_bfs_o) == (500, 100, 40)
    assert (iv.n_pts, iv.n_bfs, iv.n_bfs_o) == (100, 50, 20)


def test_dmp_yaml_errors_name_the_key(tmp_path):
    path = tmp_path / 'dmp.yaml'
    path.write_text('task_ii:\n  alpha_x: 1.0\n  n_bfs: lots\n')
    with pytest.raises(ConfigError, match=r'dmp\.yaml.*task_ii\.n_bfs'):
        load_dmp_params(path, task='ii')
    with pytest.raises(ValueError, match='task'):
        load_dmp_params(path, task='iii')


def test_parameters_are_checked():
    with pytest.raises(ValueError, match='n_bfs'):
        DmpParams(n_bfs=1)
    with pytest.raises(ValueError, match='alpha_y'):
        DmpParams(alpha_y=-25.0)
    with pytest.raises(ValueError, match='orientation_form'):
        DmpParams(orientation_form='euler')


def test_bad_demonstrations_are_rejected_naming_the_argument():
    T, P, Q = needle_throw(50, 1.0)
    dmp = PoseDmp(DmpParams(n_bfs=10, n_bfs_o=10))
    bad_P = P.copy()
    bad_P[7, 1] = np.nan
    with pytest.raises(ValueError, match=r'^Y must be finite'):
        dmp.position.fit(T, bad_P)
    with pytest.raises(ValueError, match=r'T needs at least 5 points'):
        dmp.fit(T[:3], P[:3], Q[:3])
    backwards = T.copy()
    backwards[10] = backwards[9]
    with pytest.raises(ValueError, match=r'T must be strictly increasing'):
        dmp.fit(backwards, P, Q)
    zero_q = Q.copy()
    zero_q[5] = 0.0
    with pytest.raises(ValueError, match=r'Q is not a unit quaternion \(norm 0'):
        dmp.fit(T, P, zero_q)
    with pytest.raises(ValueError, match=r'Q must have one row per time'):
        dmp.fit(T, P, Q[:-1])
    with pytest.raises(ValueError, match=r'no weights'):
        dmp.rollout()
    dmp.fit(T, P, Q)
    with pytest.raises(ValueError, match=r'goal must have shape \(7\)'):
        dmp.rollout(goal=P[-1])
    with pytest.raises(ValueError, match=r'T must be evenly spaced'):
        dmp.rollout(T=np.r_[0.0, 0.1, 0.3, 0.4])
    with pytest.raises(ValueError, match=r'reset\(\)'):
        PoseDmp(DmpParams(n_bfs=10, n_bfs_o=10)).fit(T, P, Q).step(0.01)
    with pytest.raises(ValueError, match=r'dt must be a finite positive number'):
        dmp.reset().step(0.0)
