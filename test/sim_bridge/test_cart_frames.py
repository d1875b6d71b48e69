"""The patient cart's frames in the simulation core: PSM poses in the live camera frame."""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.arm import ArmConfig
from sim_bridge.common.geometry import invert_transform
from sim_bridge.control import Command
from sim_bridge.simulation import PSMS, Simulation, load_simulation_config


@pytest.fixture(scope='module')
def config():
    return replace(load_simulation_config(), arm=ArmConfig(tracking='exact'))


def _homed(config, frames):
    sim = Simulation(replace(config, world=replace(config.world, frames=frames)))
    sim.enable_and_home_all()
    return sim


def test_psm_poses_are_in_the_camera_frame_and_follow_the_ecm(config):
    sim = _homed(config, 'cart')
    try:
        ecm = sim.arms['ECM']
        assert ecm.reference_frame == 'world'
        np.testing.assert_allclose(ecm.measured_cp, sim.camera_pose(), atol=1e-12)
        for move in ((0.0, 0.0), (0.10, 0.05)):
            q = ecm.setpoint_jp
            q[:2] += move
            ecm.servo_jp(q)
            sim.step()
            T_camera_world = invert_transform(sim.camera_pose())
            for name in PSMS:
                arm = sim.arms[name]
                assert arm.reference_frame == 'ECM'
                np.testing.assert_allclose(arm.measured_cp, T_camera_world @ sim.tool_pose(name),
                                           atol=1e-12)
                np.testing.assert_allclose(
                    arm.local_measured_cp, invert_transform(sim.T_world_base(name))
                    @ sim.tool_pose(name), atol=1e-12)
    finally:
        sim.close()


def test_a_world_command_reaches_the_same_pose_in_both_frame_options(config):
    poses = {}
    for frames in ('cart', 'base'):
        sim = _homed(config, frames)
        try:
            T = sim.tool_pose('PSM1')
            T[:3, 3] += (0.004, -0.003, 0.002)
            sim.apply(Command(t=0.0, T_world_tool={'PSM1': T}, jaw={}, subtask=''))
            sim.step()
            poses[frames] = sim.tool_pose('PSM1')
            np.testing.assert_allclose(poses[frames], T, atol=1e-9)
            expected = 'ECM' if frames == 'cart' else 'PSM1_base'
            assert sim.arms['PSM1'].reference_frame == expected
        finally:
            sim.close()
    np.testing.assert_array_equal(poses['cart'], poses['base'])


def test_the_frames_option_is_checked(config):
    with pytest.raises(ValueError, match="world frames must be 'cart'"):
        replace(config.world, frames='camera')
