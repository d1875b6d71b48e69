"""The executor on tissue: the needle turns in the jaw while inserting, the throw goes on."""

from dataclasses import replace

import pytest
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill
from suture_lfd.skill.executor import ThrowExecutor, execute_throw


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
