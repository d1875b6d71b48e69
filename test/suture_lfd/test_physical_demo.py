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


def test_a_teleoperated_demonstration_at_the_3_mm_class_is_learnt_and_executed(tmp_path):
    """
    The study's path at the 3 mm class: register, then record, segment, learn and execute.

    A subject of the cohort teleoperates ``synth1`` on a robot with hidden 3 mm-class errors;
    the recorder judges the grasps against the registered tool poses, the record goes through a
    bag (the arms as the robot believes them) read back independently, is segmented and
    learnt; the skill is executed in physical mode on ``synth2`` of the same phantom.
    """
    from sim_bridge.common.vocabulary import PSMS
    from suture_lfd.demos.cohort import load_cohort
    from suture_lfd.demos.demo_bag import demonstration_from_bag, write_demonstration_bag
    from suture_lfd.demos.demonstrator import run_demonstration
    from suture_lfd.study.teleoperated import TeleoperatedRobot

    config = replace(load_simulation_config(), kinematic_error_level=3.0, kinematic_error_seed=1)
    sim = Simulation(config)
    try:
        link = TeleoperatedRobot(sim, 'synth1')
        assert set(link.correction.arms) == set(PSMS)
        run = run_demonstration(sim, load_cohort()[0], 'synth1', seed=0, command_rate=50.0,
                                attempts=1, require_success=False, link=link)
        assert run.score.score == 1.0, run.score.failure
        # the grasps the recorder perceived: PSM1 picks the needle, PSM2 takes it over
        assert run.demo.psm1_holds.any() and run.demo.psm2_holds.any()
        assert np.isfinite(run.demo.needle_pose).all()
        # the needle was seen where it lay: a handful of looks, not one per sample
        assert link.images_seen < 20
        bag = tmp_path / 'demo_synth1'
        write_demonstration_bag(bag, run.demo,
                                base_frames={a: sim.believed_base(a) for a in PSMS})
        demo = demonstration_from_bag(bag, pair='synth1')
        segments = tmp_path / 'synth1_segments.npz'
        make_segment_file(demo, segment_demonstration(demo), source=str(bag)).save(segments)
        skill = learn_skill(segments)
        outcome = execute_throw(sim, skill, 'synth2', seed=1, physical=True)
        assert outcome.score >= 0.8, (outcome.score, outcome.failure, outcome.subtasks)
    finally:
        sim.close()


def test_the_recorder_fits_the_grasp_again_once_the_picked_needle_turns():
    """
    On the scanned pad the needle seen lying can be tilted off (the pad slopes where it lies);
    the grasp taken from it carries that into every recorded pose while it is held. Once the
    carried needle turns to face the camera obliquely, the recorder looks once more and fits
    the grasp to both pairs, and the rest is recorded with it.
    """
    from suture_lfd.demos.cohort import load_cohort
    from suture_lfd.demos.demonstrator import run_demonstration
    from suture_lfd.study.teleoperated import TeleoperatedRobot

    config = replace(load_simulation_config(), kinematic_error_level=3.0, kinematic_error_seed=1)
    sim = Simulation(config, phantom='scanned')
    geometry = sim.needle_geometry

    def tip(T):
        return T[:3, :3] @ geometry.point_at(1.0) + T[:3, 3]

    medians, looks = {}, {}
    try:
        for refit in (None, 0.7):
            link = TeleoperatedRobot(sim, 'scan1', refit_facing=refit)
            record = link.record
            errors = []

            def recorded(record=record, errors=errors):
                obs = record()
                if obs.holders and obs.T_world_needle is not None:
                    # checked against the truth here, in the test
                    errors.append(np.linalg.norm(tip(np.asarray(obs.T_world_needle))
                                                 - tip(sim.needle_pose())))
                return obs

            link.record = recorded
            run = run_demonstration(sim, load_cohort()[0], 'scan1', seed=1, command_rate=50.0,
                                    attempts=1, require_success=False, link=link)
            assert run.score.score == 1.0, run.score.failure
            medians[refit], looks[refit] = float(np.median(errors)), link.images_seen
    finally:
        sim.close()
    # measured: the held tip 0.81 mm off (median) with the lying grasp, 0.25 mm refitted
    assert medians[0.7] < 0.0005, medians
    assert medians[None] > 0.0006, medians  # the case: the lying grasp is off
    assert looks[0.7] == looks[None] + 1, looks  # one more pair looked at, not one per sample


def test_a_demonstration_whose_needle_the_recorder_never_sees_fails_with_that_reason():
    from suture_lfd.demos.cohort import load_cohort
    from suture_lfd.demos.demonstrator import run_demonstration
    from suture_lfd.errors import DemonstrationError
    from suture_lfd.study.teleoperated import TeleoperatedRobot

    config = load_simulation_config()
    start = replace(config.loop.needle_start, position=(0.11, 0.0), position_jitter=0.0)
    config = replace(config, kinematic_error_level=3.0, kinematic_error_seed=1,
                     loop=replace(config.loop, needle_start=start))
    sim = Simulation(config)
    try:
        link = TeleoperatedRobot(sim, 'synth1')
        with pytest.raises(DemonstrationError, match='the needle was not seen in'):
            run_demonstration(sim, load_cohort()[0], 'synth1', seed=0, command_rate=50.0,
                              attempts=1, require_success=False, link=link)
    finally:
        sim.close()
