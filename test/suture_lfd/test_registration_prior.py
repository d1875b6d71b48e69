"""
A registration at the ``dvrk`` preset stays within a dVRK's calibration when the camera is off.

Real PyBullet, every effect of the arm realism preset on (the ECM's reported pose off, so the
camera is turned against the arms' bases: a base rotation the registration does not model). The
registration's poses share nearly one shaft direction, along which an insertion offset and a
base translation trade almost freely; without its prior the fit of this robot's PSM1 slid 19 mm
along that valley (insertion -18.7 mm, base 19.7 mm), and the tool was 3-5 mm off where the
shaft pointed elsewhere, at the regrasp (``doc/explanation/realism_arm.md``). The truth is read
here, in the test, only to check.
"""

from dataclasses import replace

import numpy as np
from sim_bridge.realism.calibration import load_arm_realism
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.skill.arm_registration import register_arms
from suture_lfd.study.jobs import JobSettings

ERROR_SEED = 1049926387  # a study's robot (S05, synthetic phantom) the fit slid on


def _robot():
    s = JobSettings(out='')
    config = load_simulation_config()
    config = replace(config, world=replace(config.world, physics_step=s.physics_step),
                     loop=replace(config.loop, thread_period=s.thread_period,
                                  collision_period=max(s.collision_period, s.physics_step)),
                     kinematic_error_seed=ERROR_SEED, arm_realism=load_arm_realism('dvrk'))
    return Simulation(config, phantom='synthetic', rng=np.random.default_rng(0))


def test_the_fit_keeps_to_a_dvrks_calibration_with_the_camera_turned():
    # without the prior this robot's PSM1 fit slid to an insertion offset of -9.8 to -18.7 mm
    # and a base 13-20 mm off (two runs of the study's code); a dVRK's calibration leaves 3 mm
    # on the insertion and the camera's registration a few millimetres on the base
    sim = _robot()
    try:
        correction = register_arms(sim)
        true_insertion = abs(float(sim._errors['PSM1'].joint_offset[2]))  # the truth, to check
    finally:
        sim.close()
    for arm, fit in correction.arms.items():
        insertion = abs(float(fit.joint_offset[2]))
        base = float(np.abs(fit.translation).max())
        assert insertion <= 0.004 and base <= 0.006, (
            f'{arm}: insertion offset {1e3 * insertion:.1f} mm (PSM1 truly '
            f'{1e3 * true_insertion:.1f}), base {1e3 * base:.1f} mm')
