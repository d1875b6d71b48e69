"""
The arm realism model (sim_bridge.realism): a dVRK whose tool is not where its encoders say.

Real PyBullet scenes at the ``dvrk`` preset: the tool tip's distance from what the arm reports
(the FK of measured_js in its believed base) lies within the cited range over a sweep of poses
and depends on the direction the arm came from (hysteresis); measured_js lags setpoint_js during
a move_jp and settles on it; with every level at 0 the scene is bit-identical to one without the
model.
"""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.common.errors import ConfigError
from sim_bridge.control import Command
from sim_bridge.realism.calibration import draw_arm_realism, load_arm_realism
from sim_bridge.realism.transmission import JointTransmission, TransmissionConfig
from sim_bridge.simulation import PSMS, Simulation, load_simulation_config

ZERO = {'calibration_level': 0.0, 'transmission_level': 0.0, 'servo_level': 0.0,
        'encoder_level': 0.0, 'ecm_level': 0.0, 'intrinsics_level': 0.0}


def dvrk_scene(seed=0, levels=None):
    realism = load_arm_realism('dvrk', levels=levels)
    config = replace(load_simulation_config(), arm_realism=realism, kinematic_error_seed=seed)
    sim = Simulation(config)
    sim.enable_and_home_all()
    return sim


def _go(sim, goal, time=1.0):
    sim.apply(Command(t=sim.time, T_world_tool={'PSM1': goal}, jaw={}, subtask='i'))
    sim.run(time)


def _error(sim):
    true, reported = sim.tool_pose('PSM1'), sim.reported_tool_pose('PSM1')
    R = true[:3, :3].T @ reported[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return np.linalg.norm(true[:3, 3] - reported[:3, 3]), angle


def test_the_tool_tip_error_at_the_preset_is_of_barragans_order_over_a_sweep_of_poses():
    positions, angles = [], []
    for seed in (0, 1):
        sim = dvrk_scene(seed)
        try:
            home = sim.reported_tool_pose('PSM1')
            rng = np.random.default_rng(seed)
            for _ in range(5):
                goal = home.copy()
                goal[:3, 3] += rng.uniform(-0.02, 0.02, 3)
                _go(sim, goal)
                # the arm reports where it was told (its servo settled) ...
                assert np.linalg.norm(sim.reported_tool_pose('PSM1')[:3, 3] - goal[:3, 3]) < 1e-4
                # ... and the tool is elsewhere
                p, a = _error(sim)
                positions.append(p)
                angles.append(a)
        finally:
            sim.close()
    # Barragan et al. 2024: 5.0 +- 2.0 mm, 3.6 +- 1.4 deg (the mean within one sd of theirs)
    assert 3.0e-3 < np.mean(positions) < 7.0e-3, positions
    assert 2.2 < np.mean(angles) < 5.0, angles
    assert np.std(positions) > 0.2e-3  # it changes across the workspace


def test_the_same_reported_pose_reached_from_two_sides_leaves_the_tool_in_two_places():
    sim = dvrk_scene(2)
    try:
        target = sim.reported_tool_pose('PSM1')
        reached = []
        for side in (1.0, -1.0):
            before = target.copy()
            before[:3, 3] += side * np.array([0.015, 0.015, 0.0])
            _go(sim, before)
            _go(sim, target)
            assert np.linalg.norm(sim.reported_tool_pose('PSM1')[:3, 3] - target[:3, 3]) < 1e-4
            reached.append(sim.tool_pose('PSM1')[:3, 3].copy())
        # the backlash of the outer joints (1 deg dead band at ~0.12 m) shows as mm
        assert np.linalg.norm(reached[0] - reached[1]) > 0.5e-3
    finally:
        sim.close()


def test_measured_js_lags_setpoint_js_during_a_move_jp_and_settles_on_it():
    sim = dvrk_scene(0, levels={'calibration_level': 0.0, 'transmission_level': 0.0})
    try:
        arm = sim.arms['PSM1']
        goal = arm.measured_jp.copy()
        goal[0] += 0.3
        arm.move_jp(goal)
        lags = []
        for _ in range(40):
            sim.run(0.02)
            lags.append(arm.setpoint_jp[0] - arm.measured_jp[0])
        assert max(lags[:10]) > 2e-4  # behind a setpoint moving forward
        assert min(lags) < 0.0  # and a small overshoot at the end
        assert -0.05 * 0.3 < min(lags)
        sim.run(2.0)
        assert np.array_equal(arm.measured_jp, arm.setpoint_jp)
        assert np.array_equal(arm.measured_jp, goal)
    finally:
        sim.close()


def test_with_every_level_zero_the_scene_is_the_one_without_the_model():
    poses = []
    for realism in (None, load_arm_realism('dvrk', levels=ZERO)):
        config = replace(load_simulation_config(), arm_realism=realism)
        sim = Simulation(config)
        try:
            sim.enable_and_home_all()
            goal = sim.reported_tool_pose('PSM1')
            goal[:3, 3] += [0.01, -0.005, 0.004]
            _go(sim, goal, 0.7)
            poses.append((sim.tool_pose('PSM1').copy(), sim.arms['PSM1'].measured_jp.copy()))
        finally:
            sim.close()
    assert np.array_equal(poses[0][0], poses[1][0])
    assert np.array_equal(poses[0][1], poses[1][1])


def test_the_play_operator_depends_on_the_direction_and_not_on_repeats():
    t = JointTransmission(TransmissionConfig(backlash=(0.02,), stretch=(0.0,), neutral=(0.0,)))
    t.apply(np.array([0.0]))
    up = t.apply(np.array([0.1]))[0]
    assert up == pytest.approx(0.09)  # lagging by half the dead band
    assert t.apply(np.array([0.1]))[0] == up
    t.apply(np.array([0.2]))
    down = t.apply(np.array([0.1]))[0]
    assert down == pytest.approx(0.11)


def test_the_draw_is_seeded_and_a_bad_preset_or_value_is_named():
    a = draw_arm_realism(load_arm_realism('dvrk'), np.random.default_rng(4), PSMS)
    b = draw_arm_realism(load_arm_realism('dvrk'), np.random.default_rng(4), PSMS)
    assert np.array_equal(a['PSM1'].joint_offset, b['PSM1'].joint_offset)
    assert np.array_equal(a['PSM2'].T_believed_true, b['PSM2'].T_believed_true)
    assert not np.allclose(a['PSM1'].T_believed_true[:3, :3], np.eye(3))  # a base rotation
    assert np.all(a['PSM1'].joint_offset[3:] != 0.0)  # wrist offsets
    with pytest.raises(ConfigError, match='no preset .nope.'):
        load_arm_realism('nope')
    with pytest.raises(ConfigError, match='servo_level'):
        load_arm_realism('dvrk', levels={'servo_level': -1.0})
