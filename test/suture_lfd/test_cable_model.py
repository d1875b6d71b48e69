"""
The instrument's cable model in the arm correction is the transmission's own.

:meth:`suture_lfd.skill.arm_registration.KinematicCorrection.with_cable_model` adds the wrist's
stretch and the roll's dead band to a registered correction. Against the simulator's
:class:`sim_bridge.realism.transmission.JointTransmission` with the same stretch and bands, the
corrected tool pose is the true one exactly once every joint has moved further than its band;
without the model it is a degree or more off when the wrist turns.
"""

import numpy as np
from sim_bridge.control import Observation
from sim_bridge.kinematics import psm_kinematics
from sim_bridge.realism.transmission import JointTransmission, TransmissionConfig
from suture_lfd.skill.arm_registration import (
    ROLL_BAND,
    WRIST_STRETCH,
    ArmCorrection,
    KinematicCorrection,
)

BAND = (0.0175, 0.0175, 0.0005, ROLL_BAND, 0.052, 0.052)


def _correction(kinematics, cable_model):
    fitted = np.array(BAND)
    fitted[3] = 0.0  # the registration does not see the roll's band
    fit = ArmCorrection(arm='PSM2', kinematics=kinematics, T_world_base=np.eye(4),
                        joint_offset=np.zeros(6), translation=np.zeros(3), backlash=fitted)
    correction = KinematicCorrection({'PSM2': fit})
    if cable_model:
        correction.with_cable_model()
    return correction


def _angle(R):
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def test_the_corrected_tool_follows_the_wrists_stretch_and_the_rolls_play():
    kinematics = psm_kinematics()
    rng = np.random.default_rng(5)
    home = np.array(kinematics.home, dtype=float)
    truth = JointTransmission(TransmissionConfig(backlash=BAND, stretch=WRIST_STRETCH),
                              rng.uniform(-0.5, 0.5, 6) * np.array(BAND))
    modelled, unmodelled = _correction(kinematics, True), _correction(kinematics, False)
    sweep = np.linspace(0.0, 0.3, 40)[:, None] * np.array([0.3, 0.3, 0.01, 1.0, 1.0, 1.0])
    wander = np.cumsum(rng.normal(scale=0.01, size=(200, 6)) * [0.3, 0.3, 0.01, 1, 1, 1],
                       axis=0)
    Q = home + np.vstack([sweep, sweep[-1] + wander])
    worst_without = 0.0
    for k, q in enumerate(Q):
        T_true = kinematics.fk(truth.apply(q))
        obs = Observation(t=0.01 * k, T_world_tool={'PSM2': kinematics.fk(q)}, jaw={},
                          T_world_needle=None, holders=(), pair=None,
                          T_world_base={'PSM2': np.eye(4)}, q={'PSM2': q})
        got = modelled.observe(obs).T_world_tool['PSM2']
        without = unmodelled.observe(obs).T_world_tool['PSM2']
        if k >= len(sweep):  # past the first long move: the play is known
            assert np.allclose(got, T_true, atol=1e-9)
            worst_without = max(worst_without, _angle(without[:3, :3].T @ T_true[:3, :3]))
    assert worst_without > 1.0
