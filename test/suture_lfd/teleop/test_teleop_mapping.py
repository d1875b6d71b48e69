"""The dVRK teleoperation's map and state machine on synthetic input (no ROS)."""

import math

import numpy as np
import pytest
from suture_lfd.teleop.mapping import DEG, CartesianMap, GripperToJaw, JawRamp, rotation_angle
from suture_lfd.teleop.teleoperation import (
    ALIGNING,
    CLUTCHED,
    FOLLOWING,
    SETTING_ARMS,
    ArmState,
    TeleopConfig,
    Teleoperation,
    TeleopInputs,
)
from suture_lfd.teleop.virtual_mtm import rotation_from_rotvec

READY = ArmState('ENABLED', True, False)


def random_rotation(rng):
    return rotation_from_rotvec(rng.normal(size=3))


def pose(R=None, p=(0, 0, 0)):
    T = np.eye(4)
    T[:3, :3] = np.eye(3) if R is None else R
    T[:3, 3] = p
    return T


def test_translation_is_scaled_and_expressed_in_the_camera_frame():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R_C_M, R_C_P = random_rotation(rng), random_rotation(rng)
        cmap = CartesianMap(scale=0.2)
        T_mtm0 = pose(random_rotation(rng), rng.normal(size=3))
        T_psm0 = pose(random_rotation(rng), rng.normal(size=3) * 0.1)
        cmap.anchor(T_mtm0, T_psm0, R_C_M, R_C_P)
        step_camera = rng.normal(size=3) * 0.05       # the hand's motion seen by the camera
        T_mtm = T_mtm0.copy()
        T_mtm[:3, 3] += R_C_M.T @ step_camera
        goal = cmap.goal(T_mtm)
        moved_camera = R_C_P @ (goal[:3, 3] - T_psm0[:3, 3])
        np.testing.assert_allclose(moved_camera, 0.2 * step_camera, atol=1e-12)
        np.testing.assert_allclose(goal[:3, :3], T_psm0[:3, :3], atol=1e-12)


def test_right_in_the_camera_is_right_in_the_camera():
    # camera looking down (world z down), x right = world -y; PSM frame = world rotated about z
    R_world_camera = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    R_world_psm = rotation_from_rotvec([0, 0, 0.7])
    R_C_P = R_world_camera.T @ R_world_psm
    R_C_M = R_world_camera.T          # a virtual MTM in world
    cmap = CartesianMap(scale=0.2)
    cmap.anchor(pose(), pose(), R_C_M, R_C_P)
    hand = pose(p=R_world_camera @ [0.02, 0, 0])      # 2 cm right in the camera view
    tool_world = R_world_psm @ cmap.goal(hand)[:3, 3]
    np.testing.assert_allclose(R_world_camera.T @ tool_world, [0.004, 0, 0], atol=1e-12)


def test_rotation_follows_the_hand_seen_through_the_camera():
    rng = np.random.default_rng(1)
    R_C_M, R_C_P = random_rotation(rng), random_rotation(rng)
    cmap = CartesianMap()
    T_mtm0, T_psm0 = pose(random_rotation(rng)), pose(random_rotation(rng))
    cmap.anchor(T_mtm0, T_psm0, R_C_M, R_C_P)
    turn_camera = rotation_from_rotvec([0.0, 0.0, 0.3])  # about the view axis
    T_mtm = pose(R_C_M.T @ turn_camera @ R_C_M @ T_mtm0[:3, :3])
    R_goal = cmap.goal(T_mtm)[:3, :3]
    # the tool turned by the same rotation, about the same camera axis
    turn_tool_camera = (R_C_P @ R_goal) @ (R_C_P @ T_psm0[:3, :3]).T
    np.testing.assert_allclose(turn_tool_camera, turn_camera, atol=1e-12)


def test_locks_keep_the_anchor():
    cmap = CartesianMap(scale=0.2, rotation_locked=True, translation_locked=True)
    T_psm0 = pose(rotation_from_rotvec([0.1, 0.2, 0.3]), (0.01, 0.02, 0.03))
    cmap.anchor(pose(), T_psm0, np.eye(3), np.eye(3))
    np.testing.assert_allclose(cmap.goal(pose(rotation_from_rotvec([1, 0, 0]), (1, 1, 1))),
                               T_psm0)


def test_map_refuses_a_goal_before_its_anchor_and_a_bad_scale():
    with pytest.raises(RuntimeError):
        CartesianMap().goal(np.eye(4))
    with pytest.raises(ValueError, match='scale'):
        CartesianMap(scale=0.0)


def test_gripper_to_jaw_maps_the_range_and_limits():
    m = GripperToJaw()
    assert m.jaw_from_gripper(0.0) == pytest.approx(-20 * DEG)
    assert m.jaw_from_gripper(60 * DEG) == pytest.approx(80 * DEG)
    assert m.jaw_from_gripper(30 * DEG) == pytest.approx(30 * DEG)
    assert m.jaw_from_gripper(90 * DEG) == pytest.approx(80 * DEG)
    assert m.jaw_from_gripper(-1.0) == pytest.approx(-20 * DEG)
    dvrk = GripperToJaw(jaw_at_gripper_zero=0.0)      # the dVRK's own: gripper 0 -> jaw 0
    assert dvrk.jaw_from_gripper(0.0) == 0.0
    assert dvrk.jaw_from_gripper(60 * DEG) == pytest.approx(80 * DEG)
    assert dvrk.gripper_from_jaw(dvrk.jaw_from_gripper(0.3)) == pytest.approx(0.3)
    with pytest.raises(ValueError, match='gripper_max'):
        GripperToJaw(gripper_max=0.0)


def test_jaw_ramps_at_its_rate_and_slowly_back_from_a_clutch():
    m = GripperToJaw()
    ramp = JawRamp(m)
    ramp.start(m.jaw_from_gripper(0.0))
    dt = 0.005
    jaws = [ramp.step(60 * DEG, dt) for _ in range(40)]
    steps = np.diff([m.jaw_from_gripper(0.0)] + jaws)
    assert np.all(steps <= 2 * math.pi * dt * m.scale + 1e-12)   # 2 pi rad/s of gripper
    assert steps[0] == pytest.approx(2 * math.pi * dt * m.scale)
    assert jaws[-1] == pytest.approx(80 * DEG)                    # 60 deg in 0.17 s: reached
    # back from a clutch the ghost moves at 0.05 pi rad/s until it has caught up
    ramp.start(m.jaw_from_gripper(0.0), back_from_clutch=True)
    first = ramp.step(60 * DEG, dt)
    assert first - m.jaw_from_gripper(0.0) == pytest.approx(0.05 * math.pi * dt * m.scale)
    ramp.start(m.jaw_from_gripper(0.5), back_from_clutch=True)
    ramp.step(0.5 + 0.01, dt)                 # within 2 deg: caught up, full rate again
    assert ramp.caught_up


# --- the state machine ----------------------------------------------------------------------

class Rig:
    """A PSM that goes where it is told, an MTM moved by the test, pedals."""

    def __init__(self, **overrides):
        cfg = TeleopConfig(**{'start_gripper_threshold': 5 * DEG, **overrides})
        self.teleop = Teleoperation(cfg)
        self.t = 0.0
        self.mtm = pose(p=(0.1, 0.0, 0.0))
        self.psm = pose(rotation_from_rotvec([math.pi, 0, 0]), (0.0, 0.0, -0.1))
        self.jaw = 0.0
        self.gripper = 0.5
        self.clutch = False
        self.present = True
        self.R_C_M = np.eye(3)
        self.R_C_P = rotation_from_rotvec([0.0, 0.0, 0.4])
        self.sent = []

    def step(self, n=1):
        for _ in range(n):
            self.t += 0.005
            out = self.teleop.step(TeleopInputs(
                t=self.t, mtm_cp=self.mtm.copy(), gripper=self.gripper, psm_cp=self.psm.copy(),
                psm_jaw=self.jaw, mtm_state=READY, psm_state=READY, R_C_M=self.R_C_M,
                R_C_P=self.R_C_P, clutch=self.clutch, operator_present=self.present))
            for c in out:
                self.sent.append(c)
                if c.kind == 'servo_cp':
                    self.psm = c.value
                elif c.kind == 'jaw_servo_jp':
                    self.jaw = c.value
                elif c.kind == 'move_cp':
                    self.mtm = c.value          # an MTM that moves at once
        return self

    def kinds(self):
        return [c.kind for c in self.sent]


def test_following_needs_the_operators_gripper_gesture_and_an_aligned_mtm():
    rig = Rig().step(3)
    assert rig.teleop.state == ALIGNING
    assert 'move_cp' in rig.kinds()             # the MTM was aligned to the PSM
    err = CartesianMap.alignment_error(rig.mtm[:3, :3], rig.psm[:3, :3], rig.R_C_M, rig.R_C_P)
    assert err < 1e-9
    rig.step(10)
    assert rig.teleop.state == ALIGNING         # no gesture yet
    rig.gripper += 6 * DEG
    rig.step(2)
    assert rig.teleop.state == FOLLOWING


@pytest.mark.parametrize('pinch_first', [True, False])
def test_coag_and_the_pinch_start_following_in_either_order(pinch_first):
    rig = Rig()
    rig.present = False
    rig.step(3)                                 # aligned, nobody at the console
    assert rig.teleop.state == ALIGNING
    first, second = ('gripper', 'present') if pinch_first else ('present', 'gripper')
    for what in (first, second):
        assert rig.teleop.state == ALIGNING
        if what == 'gripper':
            rig.gripper += 6 * DEG
        else:
            rig.present = True
        rig.step(2)
    assert rig.teleop.state == FOLLOWING
    rig.present = False                         # the operator leaves: the gesture is forgotten
    rig.step(2)
    rig.present = True
    rig.step(5)
    assert rig.teleop.state == ALIGNING
    rig.gripper -= 6 * DEG
    rig.step(2)
    assert rig.teleop.state == FOLLOWING


def test_clutch_reanchors_without_a_jump():
    rig = Rig().step(2)
    rig.gripper += 6 * DEG
    rig.step(2)
    assert rig.teleop.state == FOLLOWING
    start = rig.psm[:3, 3].copy()
    rig.mtm[:3, 3] += [0.02, 0.0, 0.0]
    rig.step(2)
    np.testing.assert_allclose(rig.R_C_P @ (rig.psm[:3, 3] - start), [0.004, 0, 0], atol=1e-12)
    rig.clutch = True
    rig.step(2)
    assert rig.teleop.state == CLUTCHED
    assert 'hold' in rig.kinds() and 'lock_orientation' in rig.kinds()
    held = rig.psm.copy()
    rig.mtm[:3, 3] -= [0.05, 0.01, 0.0]         # recentre the hand: the PSM does not move
    rig.step(5)
    np.testing.assert_array_equal(rig.psm, held)
    rig.clutch = False
    n = len(rig.sent)
    rig.step(3)
    assert rig.teleop.state == FOLLOWING
    first = next(c.value for c in rig.sent[n:] if c.kind == 'servo_cp')
    np.testing.assert_allclose(first, held, atol=1e-12)   # no jump at release
    rig.mtm[:3, 3] += [0.0, 0.01, 0.0]
    rig.step(1)
    np.testing.assert_allclose(rig.R_C_P @ (rig.psm[:3, 3] - held[:3, 3]), [0, 0.002, 0],
                               atol=1e-12)


def test_the_psm_holds_when_the_operator_leaves_and_waits_for_the_arms():
    rig = Rig().step(2)
    rig.gripper += 6 * DEG
    rig.step(2)
    rig.present = False
    rig.step(1)
    assert rig.teleop.state == ALIGNING and rig.sent[-1].kind == 'hold'
    teleop = Teleoperation(TeleopConfig())
    out = teleop.step(TeleopInputs(t=0.0, mtm_state=ArmState('DISABLED', False, False),
                                   psm_state=ArmState('ENABLED', False, True)))
    assert teleop.state == SETTING_ARMS
    assert [(c.arm, c.value) for c in out] == [('mtm', 'enable')]   # the busy PSM is waited on
    out = teleop.step(TeleopInputs(t=0.1, mtm_state=ArmState('DISABLED', False, True),
                                   psm_state=ArmState('ENABLED', False, False)))
    assert [(c.arm, c.value) for c in out] == [('psm', 'home')]


def test_config_names_a_bad_parameter():
    with pytest.raises(ValueError, match='mtm_rotation'):
        TeleopConfig(mtm_rotation=(0.0, 0.0, 0.0, 2.0))
    with pytest.raises(ValueError, match='scale'):
        TeleopConfig(scale=-1.0)
    assert rotation_angle(rotation_from_rotvec([0, 0.5, 0])) == pytest.approx(0.5)


def test_the_frame_tree_gives_the_psm_frame_in_the_camera_frame():
    from suture_lfd.teleop.frames import FrameTree
    rng = np.random.default_rng(3)
    T_world_psm_base = pose(random_rotation(rng), rng.normal(size=3))
    T_world_ecm_base = pose(random_rotation(rng), rng.normal(size=3))
    T_ecm_base_tip = pose(random_rotation(rng), rng.normal(size=3))
    tree = FrameTree()
    tree.set('world', 'PSM1_base', T_world_psm_base)
    tree.set('world', 'ECM_base', T_world_ecm_base)
    tree.set('ECM_base', 'ECM', T_ecm_base_tip)
    expected = np.linalg.inv(T_world_ecm_base @ T_ecm_base_tip) @ T_world_psm_base
    np.testing.assert_allclose(tree.transform('ECM', 'PSM1_base'), expected, atol=1e-12)
    np.testing.assert_allclose(tree.rotation('ECM', 'world'),
                               (T_world_ecm_base @ T_ecm_base_tip)[:3, :3].T, atol=1e-12)
    assert tree.transform('ECM', 'HRSV') is None and not tree.knows('HRSV')
    assert tree.knows('world') and tree.knows('ECM')
