"""
The dVRK's kinematic errors, hidden: the arms report what they were told, the tools are elsewhere.

Real PyBullet scenes: with errors the reported pose follows the command while the true tool pose
(where the needle it holds goes, where PyBullet draws the instrument) is off by the configured
amount; at level 0 nothing changes.
"""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.control import Command
from sim_bridge.kinematic_errors import draw_arm_errors
from sim_bridge.observers import GroundTruthObserver, PhysicalObserver
from sim_bridge.simulation import PSMS, Simulation, load_simulation_config


def _scene(level, seed=3):
    config = load_simulation_config()
    config = replace(config, kinematic_error_level=level, kinematic_error_seed=seed)
    sim = Simulation(config)
    sim.enable_and_home_all()
    return sim


def _move_psm1(sim, offset):
    """Command PSM1 a few mm away from where it reports itself, and let it get there."""
    goal = sim.reported_tool_pose('PSM1')
    goal[:3, 3] += offset
    sim.apply(Command(t=sim.time, T_world_tool={'PSM1': goal}, jaw={}, subtask='i'))
    sim.run(1.5)
    return goal


def test_with_errors_the_reported_pose_follows_the_command_and_the_tool_is_elsewhere():
    level = 3.0
    sim = _scene(level)
    try:
        goal = _move_psm1(sim, np.array([0.004, -0.003, 0.002]))
        reported = sim.reported_tool_pose('PSM1')
        assert np.linalg.norm(reported[:3, 3] - goal[:3, 3]) < 1e-4
        assert np.allclose(reported[:3, :3], goal[:3, :3], atol=1e-4)
        # the arm's own report: its believed base and its local measured_cp
        arm = sim.arms['PSM1']
        assert np.allclose(sim.believed_base('PSM1') @ arm.local_measured_cp, reported)
        true = sim.tool_pose('PSM1')
        off = np.linalg.norm(true[:3, 3] - reported[:3, 3])
        # level 3: joints 1-2 within 3 deg at ~0.12 m, insertion 3 mm, registration 3 mm a side
        assert 0.5e-3 < off < 20e-3, off
        # the needle put in the jaw goes with the true tool, not the reported one
        sim.attach_needle('PSM1')
        G = sim.needle_geometry.T_tool_needle
        assert np.allclose(sim.needle_pose(), true @ G, atol=1e-9)
        assert not np.allclose(sim.needle_pose(), reported @ G, atol=1e-4)
        # PyBullet draws the instrument where it truly is
        sim.sync_world()
        drawn = sim.world.instrument_points('PSM1', sim.arms['PSM1'].measured_jp
                                            + sim._errors['PSM1'].joint_offset, 0.0)
        points = sim.world.instrument_points('PSM1', sim.arms['PSM1'].measured_jp, 0.0)
        assert not np.allclose(drawn, points, atol=1e-4)
    finally:
        sim.close()


def test_the_error_grows_with_the_level_and_is_seeded():
    offs = []
    for level in (1.0, 5.0):
        errors = draw_arm_errors(level, np.random.default_rng(7), PSMS)
        again = draw_arm_errors(level, np.random.default_rng(7), PSMS)
        for arm in PSMS:
            e = errors[arm]
            assert np.array_equal(e.joint_offset, again[arm].joint_offset)
            assert np.all(np.abs(np.degrees(e.joint_offset[:2])) <= level)
            assert abs(e.joint_offset[2]) <= level * 1e-3
            assert np.all(np.abs(e.T_believed_true[:3, 3]) <= level * 1e-3)
            assert not e.joint_offset[3:].any()
        offs.append(np.abs(errors['PSM1'].joint_offset[:3]).sum())
    assert offs[1] > offs[0]


def test_a_bad_level_is_refused_with_its_name():
    with pytest.raises(ValueError, match='kinematic error level'):
        draw_arm_errors(-1.0, np.random.default_rng(0), PSMS)
    with pytest.raises(ValueError, match='kinematic error level'):
        draw_arm_errors(float('nan'), np.random.default_rng(0), PSMS)


def test_level_zero_is_the_scene_without_errors():
    plain = Simulation()
    zero = _scene(0.0)
    try:
        plain.enable_and_home_all()
        for sim in (plain, zero):
            _move_psm1(sim, np.array([0.003, 0.002, -0.001]))
        for arm in PSMS:
            assert np.array_equal(plain.tool_pose(arm), zero.tool_pose(arm))
            assert np.array_equal(zero.tool_pose(arm), zero.reported_tool_pose(arm))
            assert np.array_equal(zero.T_world_base(arm), zero.believed_base(arm))
        assert np.array_equal(plain.needle_pose(), zero.needle_pose())
    finally:
        plain.close()
        zero.close()


class _TruthEstimator:
    """Needle, holders and pair from the task's truth: checks the observer's plumbing only."""

    def __init__(self):
        self.calls = 0

    def estimate(self, sim, arm_state):
        self.calls += 1
        return sim.needle_pose(), sim.grasp.holders, sim.target_pair


def test_the_physical_observer_shows_the_reports_and_the_ground_truth_observer_the_truth():
    sim = _scene(3.0)
    try:
        truth = GroundTruthObserver(sim).observe()
        estimator = _TruthEstimator()
        physical = PhysicalObserver(sim, estimator).observe()
        assert estimator.calls == 1
        for arm in PSMS:
            assert np.array_equal(truth.T_world_tool[arm], sim.tool_pose(arm))
            assert np.allclose(physical.T_world_tool[arm], sim.reported_tool_pose(arm))
            assert not np.allclose(physical.T_world_tool[arm], truth.T_world_tool[arm],
                                   atol=1e-4)
            assert np.array_equal(physical.T_world_base[arm], sim.believed_base(arm))
            assert np.array_equal(truth.T_world_base[arm], sim.T_world_base(arm))
        # the simulation's own observation is the ground truth by default
        assert np.array_equal(sim.observation().T_world_tool['PSM1'], truth.T_world_tool['PSM1'])
        sim.observer = PhysicalObserver(sim, estimator)
        assert np.allclose(sim.observation().T_world_tool['PSM1'],
                           sim.reported_tool_pose('PSM1'))
    finally:
        sim.close()
