"""
The registration stepped like a controller finds each tool's error from images as they come.

A real PyBullet scene with hidden 3 mm-class kinematic errors: :class:`RegistrationRun` is given
only the arms' reports (through :class:`sim_bridge.observers.PhysicalObserver`, uncorrected) and
a stereo pair rendered once a simulated second, as a camera topic brings them; its commands are
applied as a node would send them. The fit is checked against the truth here, in the test.
"""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.control import Command
from sim_bridge.observers import PhysicalObserver
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.perception import stereo_from_camera_info
from suture_lfd.skill.arm_registration import BENDS, SPOTS, _markers_centre
from suture_lfd.skill.registration_run import RegistrationRun, StereoLook

LEVEL = 3.0
ERROR_SEED = 1
CONTROL_PERIOD = 0.01  # s
IMAGE_PERIOD = 1.0     # s of simulation between stereo pairs


@pytest.fixture(scope='module')
def scene():
    config = replace(load_simulation_config(), kinematic_error_level=LEVEL,
                     kinematic_error_seed=ERROR_SEED)
    sim = Simulation(config)
    yield sim
    sim.close()


def test_the_stepped_registration_brings_each_tool_within_a_millimetre(scene):
    scene.reset(seed=0)
    scene.enable_and_home_all()
    camera = scene.camera
    stereo = stereo_from_camera_info(camera.camera_info('left'), camera.camera_info('right'))
    shape = scene.config.world.instrument
    centre = _markers_centre(scene, stereo)
    assert centre is not None
    run = RegistrationRun(scene.kinematics, stereo,
                          (shape.jaw_length, shape.jaw_width, shape.jaw_thickness), centre)
    arms = PhysicalObserver(scene, estimator=None)
    steps = round(CONTROL_PERIOD / scene.dt)
    look, last_image = None, -np.inf
    start = {a: scene.reported_tool_pose(a) for a in run.arms}
    while not run.done and scene.time < 60.0:
        if scene.time - last_image >= IMAGE_PERIOD - 1e-9:
            frame = scene.render()
            T = scene.reported_tool_pose('ECM') @ camera.T_tip_left
            look = StereoLook(scene.time, frame.left_rgb, frame.right_rgb, T)
            last_image = scene.time
        command = run.step(arms.arm_state(), look)
        scene.apply(command)
        for _ in range(steps):
            scene.step()
    assert run.done, f'registration not done after {scene.time:.1f} s (arm {run.arm})'
    assert set(run.correction.arms) == {'PSM1', 'PSM2'}
    for arm in run.arms:
        assert len(run.samples[arm]) == len(run.paths[arm]) == len(SPOTS) + len(BENDS)
        # back where it started
        assert np.linalg.norm(scene.reported_tool_pose(arm)[:3, 3] - start[arm][:3, 3]) < 1e-3
    # each tool a centimetre above the pair, where the throw works
    mid = scene.target_pair.midpoint if scene.target_pair is not None else centre
    for arm, side in (('PSM1', -1.0), ('PSM2', 1.0)):
        T = scene.reported_tool_pose(arm)
        T[:3, 3] = mid + np.array([0.004 * side, 0.0, 0.008])
        scene.apply(Command(t=scene.time, T_world_tool={arm: T}, jaw={}, subtask='i'))
    scene.run(1.5)
    for arm, fit in run.correction.arms.items():
        assert fit.residual_px < 1.0
        q = np.array(scene.arms[arm].measured_jp)
        off = fit.tool_pose(q)[:3, 3] - scene.tool_pose(arm)[:3, 3]
        before = scene.reported_tool_pose(arm)[:3, 3] - scene.tool_pose(arm)[:3, 3]
        assert np.linalg.norm(before) > 2e-3
        assert np.linalg.norm(off) < 1e-3, (arm, off)
