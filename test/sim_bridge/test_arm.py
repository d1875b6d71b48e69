"""The simulated arm follows the dVRK CRTK operating-state rules and motion semantics."""

import re

import numpy as np
import pytest
from sim_bridge.arm import Arm, ArmConfig, ArmEvent, OperatingState
from sim_bridge.kinematics import ecm_kinematics, psm_kinematics

DT = 0.005
HOME = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
DISABLED = OperatingState('DISABLED', False, False)


@pytest.fixture(scope='module')
def psm_chain():
    return psm_kinematics()


def make_psm(chain, **config):
    return Arm('PSM1', chain, ArmConfig(**config))


def run(arm, seconds, dt=DT):
    events = []
    for _ in range(int(round(seconds / dt))):
        arm.step(dt)
        events += arm.pop_events()
    return events


def run_until_idle(arm, timeout=20.0, dt=DT):
    events = []
    t = 0.0
    while arm.operating_state.is_busy:
        assert t < timeout, 'arm still busy'
        arm.step(dt)
        t += dt
        events += arm.pop_events()
    return events


def ready_psm(chain, **config):
    arm = make_psm(chain, **config)
    arm.state_command('enable')
    arm.state_command('home')
    run_until_idle(arm)
    arm.pop_events()
    return arm


def states(events):
    return [e.value for e in events if e.kind == 'operating_state']


def kinds(events):
    return [e.kind for e in events]


def messages(events, kind):
    return [e.value for e in events if e.kind == kind]


# --- operating state ------------------------------------------------------------------------


def test_a_new_arm_is_disabled_not_homed_and_at_its_configured_position(psm_chain):
    arm = make_psm(psm_chain)
    assert arm.operating_state == DISABLED
    np.testing.assert_array_equal(arm.measured_jp, HOME)
    q0 = (0.1, 0.0, 0.05, 0.0, 0.0, 0.0)
    np.testing.assert_array_equal(make_psm(psm_chain, initial_jp=q0).measured_jp, q0)
    with pytest.raises(ValueError, match='initial_jp'):
        make_psm(psm_chain, initial_jp=(0.0, 0.0, 0.5, 0.0, 0.0, 0.0))


def test_enable_goes_through_busy_disabled_to_enabled(psm_chain):
    arm = make_psm(psm_chain)
    arm.state_command('enable')
    assert states(arm.pop_events()) == [
        DISABLED, OperatingState('DISABLED', False, True), OperatingState('ENABLED', False, False)]


def test_every_state_command_emits_the_state_even_without_change(psm_chain):
    arm = make_psm(psm_chain)
    arm.state_command('disable')
    assert arm.pop_events() == [ArmEvent('operating_state', DISABLED)]
    arm.state_command('enable')
    arm.pop_events()
    arm.state_command('enable')
    assert arm.pop_events() == [
        ArmEvent('operating_state', OperatingState('ENABLED', False, False))]


def test_home_is_rejected_while_disabled(psm_chain):
    arm = make_psm(psm_chain)
    arm.state_command('home')
    assert arm.pop_events() == [
        ArmEvent('operating_state', DISABLED),
        ArmEvent('warning', 'PSM1: command home is not supported in state DISABLED')]
    run(arm, 1.0)
    assert arm.operating_state == DISABLED


def test_unknown_state_command_is_an_error(psm_chain):
    arm = make_psm(psm_chain)
    arm.state_command('power_on')
    events = arm.pop_events()
    assert kinds(events) == ['operating_state', 'error']
    assert 'unknown state command' in events[1].value and 'enable' in events[1].value


def test_home_pulses_busy_moves_to_the_homing_goal_and_sets_homed(psm_chain):
    arm = make_psm(psm_chain, initial_jp=(0.3, -0.2, 0.05, 1.0, 0.3, -0.3))
    arm.state_command('enable')
    arm.pop_events()
    arm.state_command('home')
    assert states(arm.pop_events()) == [
        OperatingState('ENABLED', False, False), OperatingState('ENABLED', False, True)]
    events = run_until_idle(arm)
    assert states(events) == [OperatingState('ENABLED', True, False)]
    assert 'goal_reached' not in kinds(events)
    np.testing.assert_allclose(arm.setpoint_jp, HOME)
    np.testing.assert_allclose(arm.measured_jp, HOME, atol=1e-6)


def test_home_while_homed_or_homing_only_reemits_the_state(psm_chain):
    # the dVRK takes home as a desired state: HOMED (or HOMING) already changes nothing
    arm = ready_psm(psm_chain)
    goal = HOME + np.array([0.1, -0.05, 0.0, 0.2, 0.0, 0.0])
    arm.move_jp(goal)
    run_until_idle(arm)
    arm.state_command('home')
    assert states(arm.pop_events()) == [OperatingState('ENABLED', True, False)]
    assert states(run(arm, 1.0)) == []
    np.testing.assert_allclose(arm.setpoint_jp, goal)
    # while homing: the homing motion goes on, not restarted
    arm = make_psm(psm_chain, initial_jp=(0.0,) * 6)
    arm.state_command('enable')
    arm.state_command('home')
    run(arm, 0.5)
    arm.pop_events()
    arm.state_command('home')
    assert states(arm.pop_events()) == [OperatingState('ENABLED', False, True)]
    events = run_until_idle(arm)
    assert states(events) == [OperatingState('ENABLED', True, False)]
    np.testing.assert_allclose(arm.measured_jp, HOME, atol=1e-6)


def test_pause_resume_unhome_and_disable(psm_chain):
    arm = ready_psm(psm_chain)
    arm.state_command('pause')
    assert states(arm.pop_events())[-1] == OperatingState('PAUSED', True, False)
    arm.servo_jp(HOME)
    assert messages(arm.pop_events(), 'warning') == ['PSM1: servo_jp, arm not ready']
    arm.state_command('enable')
    assert 'not supported in state PAUSED' in messages(arm.pop_events(), 'warning')[0]
    arm.state_command('resume')
    assert states(arm.pop_events())[-1] == OperatingState('ENABLED', True, False)
    arm.state_command('unhome')
    assert states(arm.pop_events())[-1] == OperatingState('ENABLED', False, False)
    arm.state_command('disable')
    assert states(arm.pop_events())[-1] == DISABLED


def test_disable_during_a_move_stops_it_with_goal_not_reached(psm_chain):
    arm = ready_psm(psm_chain)
    arm.move_jp([0.5, 0.0, 0.12, 0.0, 0.0, 0.0])
    run(arm, 0.1)
    arm.state_command('disable')
    events = arm.pop_events()
    assert kinds(events) == ['operating_state', 'goal_reached', 'operating_state']
    assert events[1].value is False
    assert events[2].value == OperatingState('DISABLED', True, False)
    frozen = arm.measured_jp
    run(arm, 0.5)
    np.testing.assert_array_equal(arm.measured_jp, frozen)


# --- readiness ------------------------------------------------------------------------------


def test_commands_while_disabled_are_ignored_with_a_throttled_warning(psm_chain):
    arm = make_psm(psm_chain)
    for _ in range(5):
        arm.servo_cp(arm.measured_cp)
        arm.step(0.1)
    arm.move_jp(HOME)
    warnings = messages(arm.pop_events(), 'warning')
    assert warnings == ['PSM1: servo_cp, arm not ready', 'PSM1: move_jp, arm not ready']
    run(arm, 0.6)
    arm.servo_cp(arm.measured_cp)
    assert messages(arm.pop_events(), 'warning') == ['PSM1: servo_cp, arm not ready']
    np.testing.assert_array_equal(arm.measured_jp, HOME)


def test_enabled_but_not_homed_is_not_ready(psm_chain):
    arm = make_psm(psm_chain)
    arm.state_command('enable')
    arm.pop_events()
    arm.move_jp(HOME)
    assert messages(arm.pop_events(), 'warning') == ['PSM1: move_jp, arm not ready']


def test_cartesian_and_jaw_commands_need_the_tool(psm_chain):
    arm = ready_psm(psm_chain)
    arm.emulate_tool_present(False)
    arm.servo_cp(arm.measured_cp)
    arm.jaw_move_jp(0.5)
    arm.servo_jp(HOME)
    warnings = messages(arm.pop_events(), 'warning')
    assert warnings == ['PSM1: servo_cp, arm not ready', 'PSM1: jaw_move_jp, arm not ready']


# --- moves ----------------------------------------------------------------------------------


def test_move_jp_pulses_busy_and_reports_the_goal_reached(psm_chain):
    arm = ready_psm(psm_chain)
    goal = np.array([0.2, -0.1, 0.1, 0.5, 0.2, -0.1])
    arm.move_jp(goal)
    assert arm.pop_events() == [
        ArmEvent('operating_state', OperatingState('ENABLED', True, True))]
    events = run_until_idle(arm)
    assert events == [ArmEvent('goal_reached', True),
                      ArmEvent('operating_state', OperatingState('ENABLED', True, False))]
    np.testing.assert_array_equal(arm.setpoint_jp, goal)
    np.testing.assert_allclose(arm.measured_jp, goal, atol=1e-6)


def test_a_zero_length_move_pulses_busy_at_the_next_step(psm_chain):
    arm = ready_psm(psm_chain)
    arm.move_jp(arm.setpoint_jp)
    assert states(arm.pop_events()) == [OperatingState('ENABLED', True, True)]
    arm.step(DT)
    assert arm.pop_events() == [
        ArmEvent('goal_reached', True),
        ArmEvent('operating_state', OperatingState('ENABLED', True, False))]


def test_a_new_move_replaces_the_running_one_without_a_jump(psm_chain):
    arm = ready_psm(psm_chain)
    arm.move_jp([0.6, 0.0, 0.12, 0.0, 0.0, 0.0])
    run(arm, 0.3)
    arm.pop_events()
    moving = arm.measured_jv[0]
    assert moving > 0.1
    second = np.array([-0.3, 0.1, 0.15, 0.0, 0.0, 0.0])
    arm.move_jp(second)
    assert states(arm.pop_events()) == [OperatingState('ENABLED', True, True)]
    velocities = []
    events = []
    while arm.operating_state.is_busy:
        arm.step(DT)
        velocities.append(arm.measured_jv)
        events += arm.pop_events()
    assert velocities[0][0] == pytest.approx(moving, abs=psm_chain.a_max[0] * DT * 2)
    assert messages(events, 'goal_reached') == [True]
    np.testing.assert_array_equal(arm.setpoint_jp, second)


def test_move_jr_and_move_cp_reach_their_goals(psm_chain):
    arm = ready_psm(psm_chain)
    arm.move_jr([0.1, 0.0, 0.02, 0.0, 0.0, 0.0])
    run_until_idle(arm)
    np.testing.assert_allclose(arm.setpoint_jp, HOME + [0.1, 0, 0.02, 0, 0, 0], atol=1e-12)
    goal = arm.measured_cp
    goal[:3, 3] += [0.02, -0.01, 0.0]
    arm.pop_events()
    arm.move_cp(goal)
    events = run_until_idle(arm)
    assert messages(events, 'goal_reached') == [True]
    np.testing.assert_allclose(arm.setpoint_cp, goal, atol=1e-9)
    np.testing.assert_allclose(arm.measured_cp, goal, atol=1e-6)


def test_an_unreachable_move_cp_ends_with_goal_not_reached(psm_chain):
    arm = ready_psm(psm_chain)
    goal = arm.measured_cp
    goal[2, 3] = -0.6
    arm.move_cp(goal)
    events = arm.pop_events()
    assert kinds(events) == ['error', 'operating_state', 'goal_reached', 'operating_state']
    assert 'outside the joint limits' in events[0].value and 'insertion' in events[0].value
    assert events[2].value is False
    assert not arm.operating_state.is_busy
    run(arm, 0.2)
    np.testing.assert_array_equal(arm.setpoint_jp, HOME)


def test_move_targets_outside_the_limits_are_clipped_with_a_warning(psm_chain):
    arm = ready_psm(psm_chain)
    arm.move_jp([0.0, 0.0, 0.5, 0.0, 0.0, 2.0])
    warnings = messages(arm.pop_events(), 'warning')
    assert len(warnings) == 1 and 'clipped' in warnings[0] and 'insertion' in warnings[0]
    run_until_idle(arm)
    np.testing.assert_allclose(arm.setpoint_jp, [0.0, 0.0, 0.29, 0.0, 0.0, 1.39626])


def test_moves_respect_the_velocity_and_acceleration_limits_scaled_by_the_ratio(psm_chain):
    arm = ready_psm(psm_chain)
    for ratio in (1.0, 0.5):
        arm.set_ratio(ratio)
        assert arm.pop_events() == [ArmEvent('ratio', ratio)]
        arm.move_jp([2.5, -0.8, 0.25, 3.0, 1.2, -1.2])  # yaw long enough to cruise
        qd = []
        while arm.operating_state.is_busy:
            arm.step(0.002)
            qd.append(arm.measured_jv)
        qd = np.array(qd)
        assert np.all(np.abs(qd) <= ratio * psm_chain.v_max * (1 + 1e-9))
        accel = np.diff(qd, axis=0) / 0.002
        assert np.all(np.abs(accel) <= ratio * psm_chain.a_max * (1 + 1e-6))
        assert np.max(np.abs(qd[:, 0])) > 0.99 * ratio * psm_chain.v_max[0]
        arm.move_jp(HOME)
        run_until_idle(arm)


def test_bad_ratio_is_an_error(psm_chain):
    arm = make_psm(psm_chain)
    for bad in (0.0, 1.5, float('nan'), 'fast'):
        arm.set_ratio(bad)
    assert kinds(arm.pop_events()) == ['error'] * 4
    assert arm.ratio == 1.0


# --- servo ----------------------------------------------------------------------------------


def test_servo_commands_leave_busy_false(psm_chain):
    arm = ready_psm(psm_chain)
    arm.servo_jp(HOME + [0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    arm.servo_jr([0.0, 0.05, 0.0, 0.0, 0.0, 0.0])
    goal = arm.measured_cp
    goal[0, 3] += 0.005
    arm.servo_cp(goal)
    events = run(arm, 0.5)
    assert arm.pop_events() == [] and events == []
    assert not arm.operating_state.is_busy
    np.testing.assert_allclose(arm.measured_cp, goal, atol=1e-6)


def test_servo_supersedes_a_running_move(psm_chain):
    arm = ready_psm(psm_chain)
    arm.move_jp([0.5, 0.0, 0.12, 0.0, 0.0, 0.0])
    run(arm, 0.1)
    arm.pop_events()
    arm.servo_jp(arm.setpoint_jp)
    assert arm.pop_events() == [
        ArmEvent('goal_reached', False),
        ArmEvent('operating_state', OperatingState('ENABLED', True, False))]


def test_servo_jp_beyond_the_limits_is_clipped(psm_chain):
    arm = ready_psm(psm_chain)
    arm.servo_jp([0.0, 0.0, 0.12, 0.0, 0.0, 3.0])
    assert 'clipped' in messages(arm.pop_events(), 'warning')[0]
    assert arm.setpoint_jp[5] == psm_chain.upper[5]


@pytest.mark.parametrize('command, bad, message', [
    ('servo_jp', [0.0, 0.0, np.nan, 0.0, 0.0, 0.0], 'NaN'),
    ('servo_jp', [0.0, 0.0, 0.1], 'must have 6 joint values'),
    ('servo_jr', [np.inf] * 6, 'NaN or infinite'),
    ('servo_cp', np.diag([0.0, 0.0, 0.0, 1.0]), 'not a proper rotation'),
    ('servo_cp', [0.0, 0.0, -0.1, 0.0, 0.0, 0.0, 0.0], r'not a unit quaternion \(norm 0\)'),
    ('servo_cp', [0.0, 0.0, -0.1, 0.0, 0.0, 0.0, 2.0], 'not a unit quaternion'),
    ('servo_cp', np.eye(3), r'shape \(4, 4\)'),
    ('move_jp', [np.nan] * 6, 'NaN'),
    ('move_cp', [0.0, 0.0, np.nan, 0.0, 0.0, 0.0, 1.0], 'NaN'),
    ('jaw_servo_jp', float('nan'), 'finite angle'),
    ('jaw_move_jp', [0.1, 0.2], 'one finite angle'),
])
def test_bad_input_is_an_error_and_the_arm_keeps_holding(psm_chain, command, bad, message):
    arm = ready_psm(psm_chain)
    arm.servo_jp(HOME + [0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    run(arm, 0.5)
    before = arm.setpoint_jp
    getattr(arm, command)(bad)
    errors = messages(arm.pop_events(), 'error')
    assert len(errors) == 1
    assert errors[0].startswith('PSM1: ')
    assert re.search(message, errors[0]), errors[0]
    run(arm, 0.2)
    np.testing.assert_array_equal(arm.setpoint_jp, before)
    np.testing.assert_allclose(arm.measured_jp, before, atol=1e-9)
    assert not arm.operating_state.is_busy


def test_servo_cp_tracks_a_2_cm_circle(psm_chain):
    """The dvrk_arm_test circle: 2 cm amplitude, 5 s at 100 Hz."""
    arm = ready_psm(psm_chain)
    arm.move_jp([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
    run_until_idle(arm)
    start = arm.setpoint_cp
    setpoint_error, measured_error = [], []
    dt = 0.002
    for k in range(500):
        angle = 2 * np.pi * k / 500
        goal = start.copy()
        goal[:3, 3] += 0.02 * np.array([np.sin(angle), 1 - np.cos(angle), 0.0]) / 2
        arm.servo_cp(goal)
        setpoint_error.append(np.linalg.norm(arm.setpoint_cp[:3, 3] - goal[:3, 3]))
        for _ in range(5):
            arm.step(dt)
        measured_error.append(np.linalg.norm(arm.measured_cp[:3, 3] - goal[:3, 3]))
    assert max(setpoint_error) < 1e-4
    assert max(measured_error) < 5e-4
    assert messages(arm.pop_events(), 'error') == []


# --- jaw ------------------------------------------------------------------------------------


def test_jaw_and_arm_moves_run_concurrently_under_one_busy_flag(psm_chain):
    arm = ready_psm(psm_chain)
    arm.jaw_move_jp(1.0)
    arm.move_jr([0.0, 0.0, 0.05, 0.0, 0.0, 0.0])
    assert states(arm.pop_events()) == [OperatingState('ENABLED', True, True)] * 2
    run(arm, 0.1)
    assert arm.jaw_measured_jp > 0.0 and arm.measured_jp[2] > 0.12
    events = run_until_idle(arm)
    assert messages(events, 'goal_reached') == [True, True]
    assert states(events) == [OperatingState('ENABLED', True, False)]
    assert arm.jaw_setpoint_jp == 1.0
    assert arm.jaw_measured_jp == pytest.approx(1.0, abs=1e-9)
    assert arm.setpoint_jp[2] == pytest.approx(0.17)


def test_a_still_arm_keeps_its_tool_pose_and_a_moving_one_gets_a_new_one(psm_chain):
    """The shared pose is what the simulation keys its world pose on: same object, same joints."""
    arm = ready_psm(psm_chain)
    still = arm.local_measured_cp_view
    run(arm, 0.1)
    assert arm.local_measured_cp_view is still and not still.flags.writeable
    np.testing.assert_array_equal(still, psm_chain.fk(arm.measured_jp))
    goal = arm.measured_jp + np.array([0.01, -0.01, 0.002, 0.02, 0.0, 0.0])
    arm.servo_jp(goal)
    arm.step(DT)
    moved = arm.local_measured_cp_view
    assert moved is not still
    assert moved.tobytes() == psm_chain.fk(arm.measured_jp).tobytes()


def test_jaw_servo_and_clipping(psm_chain):
    arm = ready_psm(psm_chain)
    arm.jaw_servo_jp(-1.0)
    assert 'clipped' in messages(arm.pop_events(), 'warning')[0]
    run(arm, 0.5)
    assert arm.jaw_setpoint_jp == psm_chain.jaw_lower
    assert arm.jaw_measured_jp == pytest.approx(psm_chain.jaw_lower)
    assert not arm.operating_state.is_busy


# --- frames and velocities ------------------------------------------------------------------


def test_base_frame_is_prepended_to_measured_cp_and_applies_to_servo_cp(psm_chain):
    arm = ready_psm(psm_chain)
    base = np.eye(4)
    base[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    base[:3, 3] = [0.1, 0.2, 0.3]
    arm.set_base_frame(base, frame_id='world')
    assert arm.reference_frame == 'world'
    np.testing.assert_allclose(arm.measured_cp, base @ arm.local_measured_cp)
    goal = arm.measured_cp
    goal[:3, 3] += [0.01, 0.0, 0.0]  # +x of world = -y of the RCM frame
    arm.servo_cp(goal)
    run(arm, 0.3)
    np.testing.assert_allclose(arm.local_setpoint_cp[:3, 3], [0.0, -0.01, -0.1135], atol=1e-9)
    arm.set_base_frame(np.diag([0.0, 0.0, 0.0, 1.0]))
    assert 'not a proper rotation' in messages(arm.pop_events(), 'error')[0]
    assert make_psm(psm_chain).reference_frame == 'PSM1_base'


def test_measured_cv_is_the_tip_velocity(psm_chain):
    arm = ready_psm(psm_chain)
    arm.set_base_frame(np.diag([-1.0, -1.0, 1.0, 1.0]))
    arm.move_jp([0.5, 0.3, 0.2, 1.0, 0.5, 0.5])
    run(arm, 0.4, dt=0.001)
    before = arm.measured_cp
    twist, body = arm.measured_cv, arm.local_measured_cv
    R = arm.local_measured_cp[:3, :3]
    np.testing.assert_allclose(body[:3], R.T @ (arm.jacobian_spatial @ arm.measured_jv)[:3],
                               atol=1e-12)
    np.testing.assert_allclose(arm.jacobian_body[3:], R.T @ arm.jacobian_spatial[3:], atol=1e-12)
    arm.step(1e-6)
    after = arm.measured_cp
    np.testing.assert_allclose(twist[:3], (after[:3, 3] - before[:3, 3]) / 1e-6, atol=1e-5)


def test_hold_stops_a_move_and_free_lets_go(psm_chain):
    arm = ready_psm(psm_chain)
    arm.move_jp([0.5, 0.0, 0.12, 0.0, 0.0, 0.0])
    run(arm, 0.2)
    arm.pop_events()
    arm.hold()
    assert arm.pop_events() == [
        ArmEvent('goal_reached', False),
        ArmEvent('operating_state', OperatingState('ENABLED', True, False))]
    held = arm.measured_jp
    np.testing.assert_array_equal(arm.setpoint_jp, held)
    arm.free()
    run(arm, 0.2)
    np.testing.assert_array_equal(arm.setpoint_jp, held)


# --- ECM ------------------------------------------------------------------------------------


def test_ecm_homes_to_insertion_12_cm_and_has_no_jaw():
    arm = Arm('ECM', ecm_kinematics(), ArmConfig(initial_jp=(0.2, 0.1, 0.05, 0.0)))
    arm.state_command('enable')
    arm.state_command('home')
    run_until_idle(arm)
    np.testing.assert_allclose(arm.measured_jp, [0.0, 0.0, 0.12, 0.0], atol=1e-6)
    np.testing.assert_allclose(arm.measured_cp[:3, 3], [0.0, 0.0, -0.1207], atol=1e-6)
    arm.pop_events()
    arm.jaw_move_jp(0.3)
    assert messages(arm.pop_events(), 'error') == ['ECM: jaw_move_jp: this arm has no jaw']
    with pytest.raises(AttributeError):
        _ = arm.jaw_measured_jp
    goal = arm.measured_cp
    arm.move_cp(goal)
    assert messages(run_until_idle(arm), 'goal_reached') == [True]


# --- dVRK operating-state timings -----------------------------------------------------------


def test_enable_powers_up_for_the_power_up_time_then_is_enabled(psm_chain):
    arm = make_psm(psm_chain, power_up_time=1.0, initial_jp=(0.0,) * 6)
    arm.state_command('enable')
    powering = OperatingState('DISABLED', False, True)
    assert states(arm.pop_events()) == [DISABLED, powering]
    # meanwhile: another enable changes nothing, home is refused, motions are not ready
    events = run(arm, 0.5)
    arm.state_command('enable')
    arm.state_command('home')
    arm.move_jp(HOME)
    events += arm.pop_events()
    assert states(events) == [powering, powering]
    assert 'PSM1: command home is not supported in state DISABLED' in messages(events, 'warning')
    assert 'PSM1: move_jp, arm not ready' in messages(events, 'warning')
    events = run(arm, 0.5 + DT)
    assert states(events) == [OperatingState('ENABLED', False, False)]
    # the arm holds its rest pose (tool retracted) until homed
    np.testing.assert_array_equal(arm.measured_jp, np.zeros(6))


def test_disable_while_powering_stops_the_power_up(psm_chain):
    arm = make_psm(psm_chain, power_up_time=1.0)
    arm.state_command('enable')
    run(arm, 0.2)
    arm.state_command('disable')
    assert states(arm.pop_events())[-1] == DISABLED
    assert states(run(arm, 2.0)) == []
    assert arm.operating_state == DISABLED


def test_home_from_the_rest_pose_is_a_busy_motion_at_the_trajectory_limits(psm_chain):
    arm = make_psm(psm_chain, initial_jp=(0.0,) * 6)
    arm.state_command('enable')
    arm.state_command('home')
    arm.pop_events()
    t, insertion = 0.0, []
    while arm.operating_state.is_busy:
        arm.step(DT)
        t += DT
        insertion.append(arm.setpoint_jp[2])
    # 0.12 m of insertion at 0.2 m/s and 0.2 m/s^2: a triangle profile of 2 sqrt(0.12 / 0.2) s
    assert t == pytest.approx(2.0 * np.sqrt(0.12 / 0.2), abs=0.02)
    assert np.max(np.abs(np.diff(insertion))) / DT <= 0.2 + 1e-9
    assert arm.operating_state == OperatingState('ENABLED', True, False)
    np.testing.assert_allclose(arm.measured_jp, HOME, atol=1e-6)


def test_a_negative_power_up_time_is_refused():
    with pytest.raises(ValueError, match='power_up_time'):
        ArmConfig(power_up_time=-1.0)


# --- ECM Cartesian goals --------------------------------------------------------------------


def ready_ecm():
    arm = Arm('ECM', ecm_kinematics(), ArmConfig())
    arm.state_command('enable')
    arm.state_command('home')
    run_until_idle(arm)
    arm.pop_events()
    return arm


def test_ecm_servo_cp_reaches_the_position_of_a_goal_it_cannot_orient():
    arm = ready_ecm()
    T0 = arm.setpoint_cp
    for k in range(100):
        a = 2 * np.pi * k / 100
        goal = T0.copy()
        goal[:2, 3] += 0.02 * np.array([np.cos(a) - 1.0, np.sin(a)])  # start orientation kept
        arm.servo_cp(goal)
        arm.step(0.01)
        T = arm.setpoint_cp
        np.testing.assert_allclose(T[:3, 3], goal[:3, 3], atol=1e-9)
        # the camera looks along the line from the RCM to the tip, as yaw, pitch and insertion
        # make it
        np.testing.assert_allclose(T[:3, 2], T[:3, 3] / np.linalg.norm(T[:3, 3]), atol=1e-9)
    assert messages(arm.pop_events(), 'warning') == []
    assert messages(arm.pop_events(), 'error') == []


def test_ecm_cartesian_goals_roll_about_the_shaft_as_commanded():
    arm = ready_ecm()
    q = np.array([0.2, -0.1, 0.1, 0.4])
    goal = arm.kinematics.fk(q)
    tilted = goal.copy()
    c, s = np.cos(0.05), np.sin(0.05)  # plus a small tilt the ECM cannot make
    tilted[:3, :3] = goal[:3, :3] @ np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    arm.move_cp(tilted)
    events = run_until_idle(arm)
    assert messages(events, 'goal_reached') == [True]
    np.testing.assert_allclose(arm.setpoint_jp, q, atol=2e-3)
    np.testing.assert_allclose(arm.setpoint_cp[:3, 3], goal[:3, 3], atol=1e-9)


def test_ecm_move_cp_5_cm_either_side_reaches_the_goal():
    arm = ready_ecm()
    T0 = arm.setpoint_cp
    for dx in (-0.05, 0.05, 0.0):
        goal = T0.copy()
        goal[0, 3] += dx
        arm.move_cp(goal)
        events = run_until_idle(arm)
        assert messages(events, 'goal_reached') == [True]
        assert messages(events, 'warning') == [] and messages(events, 'error') == []
        np.testing.assert_allclose(arm.measured_cp[:3, 3], goal[:3, 3], atol=1e-6)


def test_ecm_goal_outside_the_workspace_is_a_warning_and_goes_to_the_closest_limit():
    arm = ready_ecm()
    goal = arm.setpoint_cp
    goal[2, 3] = -0.5  # 0.5 m deep: insertion stops at its limit
    arm.servo_cp(goal)
    events = arm.pop_events()
    assert messages(events, 'error') == []
    [warning] = messages(events, 'warning')
    assert 'outside the workspace' in warning and 'insertion' in warning
    assert arm.setpoint_jp[2] == pytest.approx(arm.kinematics.upper[2])
    arm.move_cp(np.eye(4))  # the RCM itself: nothing to move to
    events = arm.pop_events()
    assert 'outside the workspace' in messages(events, 'warning')[0]
    assert messages(events, 'goal_reached') == [False]
