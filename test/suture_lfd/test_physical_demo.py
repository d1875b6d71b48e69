"""
Demonstrations in physical mode: recorded on CRTK state and perception outputs, learnt, executed.

A real PyBullet scene: a scripted demonstration on ``synth1`` is recorded as a recorder on the
simulator node in physical mode would keep it (the arms' reports, the ECM's pose, the
registration on ``/tf_static``, the perception's needle and markers from rendered stereo pairs;
no ground truth), read back from the bag file, segmented and learnt from the perceived needle
poses; the skill is executed in physical mode, in-process, on ``synth2`` and scored by the
evaluation.
"""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd import bags
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill
from suture_lfd.skill.executor import execute_throw
from suture_lfd.skill.physical_demo import (
    demonstration_from_physical_bag,
    is_physical_bag,
    record_physical_demonstration,
)

ERROR_LEVEL = 0.0  # mm class of the hidden kinematic errors


@pytest.fixture(scope='module')
def scene():
    config = replace(load_simulation_config(), kinematic_error_level=ERROR_LEVEL,
                     kinematic_error_seed=1)
    sim = Simulation(config)
    yield sim
    sim.close()


@pytest.fixture(scope='module')
def recorded(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp('physical_demo') / 'demo_synth1'
    score, counts = record_physical_demonstration(scene, 'synth1', path, seed=0)
    assert score.score == 1.0, score.failure
    truth = scene.phantom.markers['synth1']
    return path, counts, truth


def test_a_physical_mode_bag_holds_no_ground_truth(recorded):
    path, counts, _ = recorded
    topics = bags.bag_summary(path).topics
    assert is_physical_bag(topics)
    assert not [t for t in topics if t.startswith('/sim/') and t != '/sim/target_pair'], topics
    assert counts['/perception/needle/status'] >= 10
    assert counts['/PSM2/local/measured_cp'] > 20 * counts['/perception/needle/status']


def test_the_demonstration_is_read_from_the_perceived_needle_and_markers(recorded, scene):
    path, _, truth = recorded
    demo = demonstration_from_physical_bag(path)
    assert demo.pair == 'synth1'
    assert np.linalg.norm(demo.entry - truth.entry) < 1e-3
    assert np.linalg.norm(demo.exit - truth.exit) < 1e-3
    # grasps found from the jaws closing on the perceived needle: PSM1 picks it, PSM2 takes it
    assert demo.psm1_holds.any() and demo.psm2_holds.any()
    assert np.isfinite(demo.needle_pose).all()


def test_a_skill_learnt_in_physical_mode_executes_on_another_pair(recorded, scene, tmp_path):
    path, _, _ = recorded
    demo = demonstration_from_physical_bag(path)
    segments = tmp_path / 'synth1_segments.npz'
    make_segment_file(demo, segment_demonstration(demo), source=str(path)).save(segments)
    skill = learn_skill(segments)
    outcome = execute_throw(scene, skill, 'synth2', seed=1, physical=True)
    assert outcome.score >= 0.8, (outcome.score, outcome.failure, outcome.subtasks)
