"""Input devices of the virtual MTMs: velocity integration, the gamepad through SDL, SpaceMouse
reports, and the virtual MTM's own commands."""

import math

import numpy as np
import pytest
from suture_lfd.teleop.devices import open_device
from suture_lfd.teleop.devices.browser import BrowserDevice
from suture_lfd.teleop.devices.spacemouse import FULL_SCALE, SpaceMouseState
from suture_lfd.teleop.virtual_mtm import (
    VirtualMtm,
    deadband,
    integrate_twist,
    rotation_from_rotvec,
)


def test_deadband_zeroes_small_deflections_without_a_step_at_its_edge():
    out = deadband([0.02, -0.03, 0.0300001, 0.5, -1.0, 1.0], 0.03)
    np.testing.assert_allclose(out[:3], [0.0, 0.0, 0.0], atol=1e-6)
    assert out[3] == pytest.approx((0.5 - 0.03) / 0.97)
    assert out[4] == -1.0 and out[5] == 1.0
    with pytest.raises(ValueError, match='deadband'):
        deadband([0.1], 1.0)


def test_integrating_a_constant_velocity_moves_and_turns_by_velocity_times_time():
    T = np.eye(4)
    v, w = np.array([0.05, -0.01, 0.02]), np.array([0.0, 0.0, 0.5])
    for _ in range(200):
        T = integrate_twist(T, v, w, 0.005)
    np.testing.assert_allclose(T[:3, 3], v * 1.0, atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], rotation_from_rotvec([0, 0, 0.5]), atol=1e-12)


def test_a_virtual_mtm_moves_when_told_then_follows_the_hand_without_a_jump():
    mtm = VirtualMtm('MTMR', move_duration=0.5)
    assert mtm.state_command('home') is not None          # DISABLED: home refused
    assert mtm.state_command('enable') is None and mtm.state_command('home') is None
    goal = np.eye(4)
    goal[:3, :3] = rotation_from_rotvec([0.0, 0.0, 1.0])
    goal[:3, 3] = [0.1, 0.0, 0.0]
    mtm.move_cp(goal, t=0.0)
    assert mtm.is_busy(0.25) and not mtm.is_busy(0.5)
    halfway = mtm.measured_cp(0.25)
    assert 0.0 < halfway[0, 3] < 0.1
    np.testing.assert_allclose(mtm.measured_cp(0.6), goal, atol=1e-12)
    mtm.lock_orientation(goal[:3, :3], t=0.6)
    mtm.set_device_pose(integrate_twist(mtm.device, [0.01, 0, 0], [0.3, 0, 0], 1.0))
    T = mtm.measured_cp(1.0)
    np.testing.assert_allclose(T[:3, :3], goal[:3, :3], atol=1e-12)   # orientation locked
    np.testing.assert_allclose(T[:3, 3], [0.11, 0, 0], atol=1e-12)    # position follows
    mtm.unlock_orientation(1.0)
    np.testing.assert_allclose(mtm.measured_cp(1.0), T, atol=1e-12)   # no jump at unlock


def test_a_clutch_release_frees_the_wrist_without_unlock_orientation_and_without_a_jump():
    mtm = VirtualMtm('MTMR', move_duration=0.0)
    mtm.state_command('enable')
    locked = rotation_from_rotvec([0.0, 0.4, 0.0])
    mtm.lock_orientation(locked, t=0.0)                  # the clutch goes down
    mtm.set_device_pose(integrate_twist(mtm.device, [0.02, 0, 0], [0, 0, 0.5], 1.0))
    T = mtm.measured_cp(1.0)
    np.testing.assert_allclose(T[:3, :3], locked, atol=1e-12)
    mtm.release_clutch(1.0)                              # the pedal comes up
    np.testing.assert_allclose(mtm.measured_cp(1.0), T, atol=1e-12)   # no jump
    turn = rotation_from_rotvec([0.2, 0.0, 0.0])
    device = mtm.device.copy()
    device[:3, :3] = turn @ device[:3, :3]
    mtm.set_device_pose(device)
    np.testing.assert_allclose(mtm.measured_cp(1.1)[:3, :3], turn @ locked, atol=1e-12)


def test_the_browser_device_holds_the_latest_handle_and_names_bad_pedals():
    dev = open_device('browser', ('MTMR', 'MTML'))
    assert isinstance(dev, BrowserDevice) and dev.frame_id == 'world'
    T = np.eye(4)
    T[:3, 3] = [0.01, 0.02, 0.03]
    dev.set_pose('MTMR', T)
    dev.set_gripper('MTMR', 0.4)
    dev.set_pedals([1, 0])
    reading = dev.poll(0.0)
    np.testing.assert_array_equal(reading.arms['MTMR'].pose, T)
    assert reading.arms['MTMR'].gripper == 0.4 and reading.arms['MTML'].pose is None
    assert reading.pedals == {'clutch': True, 'coag': False}
    with pytest.raises(ValueError, match='clutch, coag'):
        dev.set_pedals([1])
    with pytest.raises(ValueError, match='unknown device'):
        open_device('keyboard', ('MTMR',))


@pytest.fixture
def pad():
    from suture_lfd.teleop.devices.gamepad import VirtualController
    controller = VirtualController()
    yield controller
    controller.close()


def test_the_gamepad_drives_virtual_mtms_through_sdls_game_controller_mapping(pad):
    import pygame
    dev = open_device('gamepad', ('MTMR', 'MTML'), index=pad.index, linear_speed=0.05,
                      angular_speed=1.0, deadband=0.03, gripper_speed=1.0, gripper_start=0.5)
    mtms = {m: VirtualMtm(m) for m in ('MTMR', 'MTML')}
    t = 0.0

    def run(seconds, rate=100):
        nonlocal t
        reading = None
        for _ in range(int(seconds * rate)):
            t += 1.0 / rate
            reading = dev.poll(t)
            for m, arm in reading.arms.items():
                mtms[m].apply_twist(arm.twist[0], arm.twist[1], 1.0 / rate)
                mtms[m].set_gripper(arm.gripper)
        return reading

    run(0.05)
    pad.set_axis(pygame.CONTROLLER_AXIS_LEFTX, 1.0)       # full right
    pad.set_axis(pygame.CONTROLLER_AXIS_LEFTY, 0.02)      # inside the dead zone
    run(1.0)
    pad.set_axis(pygame.CONTROLLER_AXIS_LEFTX, 0.0)
    pad.set_axis(pygame.CONTROLLER_AXIS_LEFTY, 0.0)
    run(0.05)
    p = mtms['MTMR'].measured_cp(t)[:3, 3]
    assert p[0] == pytest.approx(0.05, abs=0.002)         # 0.05 m/s for 1 s, to the right
    assert abs(p[1]) < 1e-9 and abs(p[2]) < 1e-9
    assert np.linalg.norm(mtms['MTML'].measured_cp(t)[:3, 3]) < 1e-12
    # the right trigger closes the active MTM's gripper, the shoulder switches MTM
    pad.set_trigger(pygame.CONTROLLER_AXIS_TRIGGERRIGHT, 1.0)
    run(0.3)
    pad.set_trigger(pygame.CONTROLLER_AXIS_TRIGGERRIGHT, 0.0)
    assert mtms['MTMR'].gripper == pytest.approx(0.2, abs=0.03)
    pad.set_button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER, True)
    run(0.05)
    pad.set_button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER, False)
    pad.set_axis(pygame.CONTROLLER_AXIS_RIGHTY, -1.0)     # push up: away from the camera
    run(0.5)
    pad.set_axis(pygame.CONTROLLER_AXIS_RIGHTY, 0.0)
    assert mtms['MTML'].measured_cp(t)[2, 3] == pytest.approx(0.025, abs=0.002)
    # pedals: A held is the clutch, B toggles the operator's presence, Y is the camera pedal
    pad.set_button(pygame.CONTROLLER_BUTTON_A, True)
    pad.set_button(pygame.CONTROLLER_BUTTON_B, True)
    reading = run(0.05)
    assert reading.pedals == {'clutch': True, 'coag': True, 'camera': False}
    pad.set_button(pygame.CONTROLLER_BUTTON_A, False)
    pad.set_button(pygame.CONTROLLER_BUTTON_B, False)
    reading = run(0.05)
    assert reading.pedals == {'clutch': False, 'coag': True, 'camera': False}
    dev.close()


# Reports in the 3Dconnexion HID layout: id, then little-endian int16 values
PUSH_RIGHT = bytes.fromhex('01 5e01 0000 0000')           # x +350
PRESS_DOWN_SMALL = bytes.fromhex('01 0000 0000 0800')     # z +8: inside a 0.03 deadband
TWIST_CCW = bytes.fromhex('02 0000 0000 a2fe')            # rz -350
BOTH_BUTTONS = bytes.fromhex('03 0300')
COMBINED = bytes.fromhex('01 af00 51ff 0000 0000 0000 5e01')  # newer devices: 12 bytes


def test_spacemouse_reports_parse_into_camera_frame_velocities():
    state = SpaceMouseState()
    state.update(PUSH_RIGHT)
    v, w = state.twist(0.05, 1.0, 0.03)
    np.testing.assert_allclose(v, [0.05, 0.0, 0.0])
    state.update(PRESS_DOWN_SMALL)
    v, _ = state.twist(0.05, 1.0, 0.03)
    np.testing.assert_allclose(v, 0.0)                    # 8/350 < 0.03: the deadband
    state.update(TWIST_CCW)
    _, w = state.twist(0.05, 1.0, 0.03)
    np.testing.assert_allclose(w, [0.0, -1.0, 0.0])       # device z is camera y
    state.update(BOTH_BUTTONS)
    assert state.button(0) and state.button(1) and not state.button(2)
    state.update(COMBINED)
    np.testing.assert_allclose(state.translation, [175, -175, 0])
    np.testing.assert_allclose(state.rotation, [0, 0, FULL_SCALE])
    v, _ = state.twist(0.05, 1.0, 0.0)
    np.testing.assert_allclose(v, [0.025, 0.0, 0.025])    # pushed away from the user: deeper
    with pytest.raises(ValueError, match='expected 6'):
        state.update(bytes.fromhex('02 0000'))
    with pytest.raises(ValueError, match='report id 9'):
        state.update(bytes.fromhex('09 00'))
    assert math.isfinite(float(np.sum(state.translation)))
