"""The DMP executor on the real simulation: a skill learnt from a demonstration, executed back."""

import numpy as np
import pytest
from sim_bridge.common.geometry import compose_poses, pose_from_transform, quaternion_angle
from sim_bridge.simulation import Simulation
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.segmentation.segments import make_segment_file
from suture_lfd.skill import PairGeometry, get_method, training_data
from suture_lfd.skill.executor import (
    METHODS,
    ThrowSkill,
    execute_throw,
    learn_skill,
    training_data_from_demonstration,
)
from suture_lfd.study.metrics import (
    endpoint_errors,
    orientation_trajectory_error,
    trajectory_error,
)


@pytest.fixture(scope='module')
def synthetic():
    sim = Simulation()
    yield sim
    sim.close()


@pytest.fixture(scope='module')
def demonstration(synthetic, tmp_path_factory):
    demo, _, score = record_scripted_demonstration(synthetic, 'synth1', seed=0)
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('segments') / 'synth1.npz'
    make_segment_file(demo, segment_demonstration(demo), source='synth1 expert').save(path)
    return demo, training_data(path), path


@pytest.fixture(scope='module')
def skill(demonstration):
    return learn_skill(demonstration[2], 'paper')


def test_a_segment_file_and_its_demonstration_teach_the_same_skill(demonstration):
    demo, data, path = demonstration
    direct = training_data_from_demonstration(demo, segment_demonstration(demo))
    pair = data.pair
    for method in METHODS:
        a, b = learn_skill(path, method), learn_skill(direct, method)
        for task in ('ii', 'iv'):
            _, Pa, Qa = a.rollout(task, pair)
            _, Pb, Qb = b.rollout(task, pair)
            assert np.abs(Pa - Pb).max() < 1e-9 and np.abs(Qa - Qb).max() < 1e-9


@pytest.fixture(scope='module')
def regeneration(synthetic, skill):
    return execute_throw(synthetic, skill, 'synth1', seed=1)


def test_the_skill_regenerates_its_demonstration_on_the_same_pair(regeneration, demonstration):
    data = demonstration[1]
    assert regeneration.score == 1.0, regeneration.failure
    assert all(regeneration.subtasks[k] for k in ('i', 'ii', 'iii', 'iv', 'v'))
    for task, bound_mm, bound_deg in (('ii', 0.5, 2.0), ('iv', 2.0, 5.0)):
        t, poses = regeneration.executed[task]
        T, P, Q = data.needle[task]
        assert np.all(np.diff(t) > 0.0) and t[-1] > 0.5 * (T[-1] - T[0])
        position = trajectory_error(P, poses[:, :3])
        orientation = orientation_trajectory_error(Q, poses[:, 3:])
        ends = endpoint_errors(poses[:, :3], P[0], P[-1], poses[:, 3:], Q[0], Q[-1])
        assert position['mean_mm'] < bound_mm, (task, position['mean_mm'])
        assert orientation['mean_deg'] < bound_deg, (task, orientation['mean_deg'])
        assert ends['start_mm'] < bound_mm and ends['goal_mm'] < 2.0 * bound_mm, (task, ends)


def test_the_executed_insertion_follows_the_dmp_rollout(regeneration):
    T, P, Q = regeneration.rollouts['ii']
    t, poses = regeneration.executed['ii']
    inside = t <= T[-1]
    planned = np.column_stack([np.interp(t[inside], T, P[:, k]) for k in range(3)])
    assert np.linalg.norm(poses[inside, :3] - planned, axis=1).mean() < 1e-3


@pytest.mark.parametrize('pair', ['synth3', 'synth4'])
def test_a_skill_learnt_on_synth1_completes_other_synthetic_pairs(synthetic, skill, pair):
    outcome = execute_throw(synthetic, skill, pair)
    assert outcome.score == 1.0, outcome.failure
    start, _ = skill.start_goal('ii', synthetic.phantom.markers[pair])
    executed_start = outcome.executed['ii'][1][0]
    assert np.linalg.norm(executed_start[:3] - start[:3]) < 1e-3
    assert outcome.duration > 0.0 and outcome.events[-1]['t'] <= outcome.duration + 1.0


@pytest.fixture(scope='module')
def scanned():
    sim = Simulation(phantom='scanned')
    yield sim
    sim.close()


@pytest.mark.parametrize('pair', ['scan2', 'scan3'])
def test_a_skill_learnt_on_synth1_completes_throws_on_the_scanned_phantom(scanned, skill, pair):
    outcome = execute_throw(scanned, skill, pair)
    assert outcome.score == 1.0, outcome.failure
    assert set(outcome.executed) == {'ii', 'iv'} and outcome.duration > 0.0


def test_a_saved_skill_loads_with_its_hyper_parameters_and_rollouts(skill, synthetic, tmp_path):
    path = tmp_path / 'skill.npz'
    skill.save(path)
    loaded = ThrowSkill.load(path)
    assert loaded.method == skill.method and loaded.params == skill.params
    assert loaded.params['ii'].n_bfs == 100 and loaded.params['iv'].n_bfs == 50
    pair = synthetic.phantom.markers['synth2']
    for task in ('ii', 'iv'):
        for a, b in zip(skill.rollout(task, pair), loaded.rollout(task, pair)):
            np.testing.assert_array_equal(a, b)


def test_a_damaged_skill_file_names_the_file_and_the_key(skill, tmp_path):
    path = tmp_path / 'skill.npz'
    skill.save(path)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    broken = tmp_path / 'broken.npz'
    np.savez(broken, **{k: v for k, v in arrays.items() if k != 'iv.orientation.weights'})
    with pytest.raises(ValueError, match=r'broken\.npz.*iv\.orientation\.weights|'
                                         r'iv\.orientation\.weights.*broken\.npz'):
        ThrowSkill.load(broken)
    old = tmp_path / 'old.npz'
    np.savez(old, **{**arrays, 'format_version': np.array(99)})
    with pytest.raises(ValueError, match=r"old\.npz: key 'format_version' is 99"):
        ThrowSkill.load(old)
    garbage = tmp_path / 'garbage.npz'
    garbage.write_bytes(b'not a zip file')
    with pytest.raises(ValueError, match=r'garbage\.npz: not a readable skill file'):
        ThrowSkill.load(garbage)


def test_methods_are_chosen_by_name(demonstration):
    assert {'paper', 'pair_frame'} <= set(METHODS)
    with pytest.raises(ValueError, match="unknown skill method 'magic'.*'paper'"):
        learn_skill(demonstration[1], 'magic')
    assert get_method('paper').frame == 'world'


def _moved(pair, T):
    R, p = T[:3, :3], T[:3, 3]
    return PairGeometry(pair.name, R @ pair.entry + p, R @ pair.exit + p, R @ pair.normal)


def test_the_pair_frame_method_moves_rigidly_with_the_pair(demonstration):
    skill = learn_skill(demonstration[1], 'pair_frame')
    rng = np.random.default_rng(3)
    for _ in range(3):
        axis = rng.normal(size=3)
        angle = rng.uniform(0.2, 1.0)
        T = np.eye(4)
        k = axis / np.linalg.norm(axis)
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        T[:3, :3] = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
        T[:3, 3] = rng.uniform(-0.02, 0.02, 3)
        _, P, Q = skill.rollout('ii', skill.pair)
        _, P2, Q2 = skill.rollout('ii', _moved(skill.pair, T))
        expected = compose_poses(pose_from_transform(T), np.hstack((P, Q)))
        assert np.abs(P2 - expected[:, :3]).max() < 1e-9
        assert np.degrees(quaternion_angle(Q2, expected[:, 3:])).max() < 1e-6


def test_every_method_reproduces_the_demonstration_on_its_own_pair(demonstration):
    data = demonstration[1]
    for name in METHODS:
        skill = learn_skill(data, name)
        _, P, _ = skill.rollout('ii', skill.pair)
        assert trajectory_error(data.needle['ii'][1], P)['mean_mm'] < 0.05, name


def test_an_unknown_pair_is_named(synthetic, skill):
    with pytest.raises(ValueError, match="unknown marker pair 'scan9'"):
        execute_throw(synthetic, skill, 'scan9')
