"""The executor on tissue: the needle turns in the jaw while inserting, the throw goes on; aimed
along its arc, the needle pushes the tissue less."""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill
from suture_lfd.skill.arc_aim import circle_offsets
from suture_lfd.skill.executor import ExecutorConfig, ThrowExecutor, execute_throw


@pytest.fixture(scope='module')
def skill(tmp_path_factory):
    sim = Simulation()
    demo, _, score = record_scripted_demonstration(sim, 'synth1', seed=0)
    sim.close()
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('segments') / 'synth1.npz'
    make_segment_file(demo, segment_demonstration(demo), source='synth1 expert').save(path)
    return learn_skill(path, 'paper')


@pytest.fixture(scope='module')
def weak_grip():
    # 70 % of the preset's grip torque: less than the puncture's push about the grasp
    tissue = replace(load_tissue_realism('tissue'), grip=1.4)
    sim = Simulation(replace(load_simulation_config(), tissue_realism=tissue))
    yield sim
    sim.close()


def test_a_needle_that_turns_in_the_jaw_is_noticed_and_the_throw_completes(
        weak_grip, skill, monkeypatch):
    noticed = []
    notice = ThrowExecutor._notice_slip

    def counting(self, obs, tau):
        before = self.slips_noticed
        notice(self, obs, tau)
        if self.slips_noticed > before:
            noticed.append(tau)

    monkeypatch.setattr(ThrowExecutor, '_notice_slip', counting)
    outcome = execute_throw(weak_grip, skill, 'synth1', seed=1)
    slips = [e for e in outcome.events if e['kind'] == 'slip']
    assert slips and slips[0]['arm'] == 'PSM2'
    assert not any(e['broken'] for e in slips)
    assert noticed
    assert outcome.score == 1.0, outcome.failure


@pytest.fixture(scope='module')
def preset():
    sim = Simulation(replace(load_simulation_config(),
                             tissue_realism=load_tissue_realism('tissue')))
    yield sim
    sim.close()


def test_aiming_along_the_arc_pushes_the_tissue_less(preset, skill):
    # the tissue's lateral push is its stiffness times the puncture-to-arc distance the tracker
    # averages over the throw
    pushes = {}
    for aim in (False, True):
        config = ExecutorConfig(script=preset.config.scene.expert, aim_on_tissue=aim)
        outcome = execute_throw(preset, skill, 'synth1', seed=1, config=config)
        assert outcome.score == 1.0, outcome.failure
        pushes[aim] = preset.physics.tissue.trauma_mean
    assert pushes[True] < 0.5 * pushes[False]


def test_aimed_insertion_takes_its_circle_through_the_entry_smoothly(skill):
    sim = Simulation()
    try:
        pair = sim.phantom.markers['synth1']
        g = sim.needle_geometry
        aimed = ThrowExecutor(skill, pair, g, config=ExecutorConfig(arc_aim=True))
        plain = ThrowExecutor(skill, pair, g)
        aimed.rollout_paths()
        plain.rollout_paths()
    finally:
        sim.close()

    def poses(rollout):
        _, P, Q = rollout
        T = np.zeros((len(P), 4, 4))
        T[:, :3, :3] = matrix_from_quaternion(Q)
        T[:, :3, 3] = P
        T[:, 3, 3] = 1.0
        return T

    T_aim, T_plain = poses(aimed.rollouts['ii']), poses(plain.rollouts['ii'])
    # the puncture: the tip lowered along the normal onto the insertion's start
    entry = T_aim[0, :3, :3] @ g.point_at(1.0) + T_aim[0, :3, 3]
    entry -= ((entry - pair.entry) @ pair.normal) * pair.normal

    def off(T):
        return np.array([np.linalg.norm(circle_offsets(Tk, g.radius, entry[None])[0])
                         for Tk in T])

    half = len(T_aim) // 2
    assert off(T_plain)[0] > 1e-4  # lowered straight, the circle misses the puncture
    assert off(T_aim)[half // 2:half].max() < 0.1 * off(T_plain)[half // 2:half].min()
    # no jump: the needle centre moves at most the aim's speed faster than the rollout's
    dt = float(np.diff(aimed.rollouts['ii'][0]).max())
    steps = np.linalg.norm(np.diff(T_aim[:, :3, 3], axis=0), axis=1)
    assert steps.max() < np.linalg.norm(np.diff(T_plain[:, :3, 3], axis=0), axis=1).max() \
        + 0.0005 * dt + 1e-9
    # the rotation is the rollout's, the start too
    np.testing.assert_allclose(aimed.rollouts['ii'][2], plain.rollouts['ii'][2])
    np.testing.assert_allclose(T_aim[0], T_plain[0])
