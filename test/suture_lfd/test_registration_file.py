"""A robot's registration saved to its JSON file and loaded: the same correction, not re-run.

Real simulations of a robot with hidden kinematic errors (3 mm class), registered once from the
endoscope's images; a second simulation of the same robot loads the file instead.
"""

import json
import os
import threading
import time

import numpy as np
import pytest
from sim_bridge.control import Command, Observation
from suture_lfd.skill.arm_registration import (
    known_registration,
    load_registration,
    register_arms,
    save_registration,
)
from suture_lfd.study import jobs
from suture_lfd.study.records import RobotErrors

ROBOT = RobotErrors(error_level=3.0, error_seed=11, correction=True)
KEY = ('synthetic', 0.01, 3.0, 11, 'static')


@pytest.fixture(scope='module')
def registered(tmp_path_factory):
    """A study process that registered the robot and saved it; closed afterwards."""
    out = tmp_path_factory.mktemp('study')
    state = jobs.init_worker(jobs.JobSettings(out=str(out)))
    sim = jobs._physical_simulation(state, 'synthetic', 0.01, ROBOT)
    correction = register_arms(sim)
    assert correction.arms, 'the registration should trust at least one arm'
    jobs._save_registrations(state)
    yield out, state, sim, correction
    state.close()


def _joints(sim):
    rng = np.random.default_rng(3)
    return {arm: np.asarray(sim.arms[arm].measured_jp, dtype=float)
            + np.r_[rng.normal(0.0, 0.05, 2), 0.005, rng.normal(0.0, 0.1, 3)]
            for arm in ('PSM1', 'PSM2')}


def test_a_saved_registration_loaded_gives_the_same_corrected_poses(registered, tmp_path):
    _, _, sim, correction = registered
    key = {'robot': 'r', 'code': 'c'}
    path = tmp_path / 'registration.json'
    save_registration(path, correction, key)
    loaded = load_registration(path, sim, key)
    assert loaded is known_registration(sim)
    assert sorted(loaded.arms) == sorted(correction.arms)
    q = _joints(sim)
    for arm, fit in correction.arms.items():
        again = loaded.arms[arm]
        assert np.array_equal(again.joint_offset, fit.joint_offset)
        assert np.array_equal(again.translation, fit.translation)
        assert again.residual_px == fit.residual_px
        assert np.array_equal(again.tool_pose(q[arm]), fit.tool_pose(q[arm]))
    reported = {arm: sim.believed_base(arm) @ sim.kinematics[arm].fk(q[arm]) for arm in q}
    obs = Observation(t=0.0, T_world_tool=reported, jaw={}, T_world_needle=None, holders=(),
                      pair=None, T_world_base={}, q=q)
    seen, seen_again = correction.observe(obs), loaded.observe(obs)
    target = {arm: T.copy() for arm, T in reported.items()}
    cmd = Command(t=0.0, T_world_tool=target, jaw={}, subtask='i')
    sent, sent_again = correction.command(cmd, q), loaded.command(cmd, q)
    for arm in q:
        assert np.array_equal(seen.T_world_tool[arm], seen_again.T_world_tool[arm])
        assert np.array_equal(sent.T_world_tool[arm], sent_again.T_world_tool[arm])
    # saved for another robot or another code: nothing to load (a registration to run)
    assert load_registration(path, sim, {'robot': 'r', 'code': 'other'}) is None
    assert load_registration(tmp_path / 'none.json', sim, key) is None


def test_a_bad_registration_file_is_named_with_what_is_wrong(registered, tmp_path):
    _, _, sim, _ = registered
    path = tmp_path / 'bad.json'
    path.write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match=r"bad\.json: 'format'"):
        load_registration(path, sim, {})
    path.write_text(json.dumps({'format': 'suture_lfd.registration', 'version': 2, 'key': {},
                                'arms': {'PSM1': {'joint_offset': [0.0]}}}))
    with pytest.raises(ValueError, match=r"bad\.json: 'arms'.*T_world_base"):
        load_registration(path, sim, {})
    path.write_text('{not json')
    with pytest.raises(ValueError, match=r'bad\.json: not a readable registration'):
        load_registration(path, sim, {})


def test_a_study_process_with_a_stored_registration_does_not_run_it(registered):
    out, _, _, correction = registered
    assert jobs._registration_path(jobs.init_worker(jobs.JobSettings(out=str(out))),
                                   KEY).is_file()
    other = jobs.init_worker(jobs.JobSettings(out=str(out)))
    try:
        sim = jobs._physical_simulation(other, 'synthetic', 0.01, ROBOT)
        assert KEY in other.registered
        t = sim.time
        kept = known_registration(sim)
        assert kept is not None and register_arms(sim) is kept
        assert sim.time == t  # the arms never moved: no registration was run
        for arm, fit in correction.arms.items():
            assert np.array_equal(kept.arms[arm].joint_offset, fit.joint_offset)
            assert np.array_equal(kept.arms[arm].translation, fit.translation)
        # another robot has no stored registration
        fresh = jobs._physical_simulation(other, 'synthetic', 0.01,
                                          RobotErrors(error_level=3.0, error_seed=12))
        assert known_registration(fresh) is None
    finally:
        other.close()


def test_a_process_waits_for_the_registration_another_has_claimed(registered):
    out, _, _, correction = registered
    other = jobs.init_worker(jobs.JobSettings(out=str(out)))
    key = ('synthetic', 0.01, 3.0, 13, 'static')
    try:
        sim = jobs._physical_simulation(other, 'synthetic', 0.01,
                                        RobotErrors(error_level=3.0, error_seed=13))
        path = jobs._registration_path(other, key)
        claim = path.with_name(path.name + '.claim')
        claim.write_text('')

        def the_other_process():
            time.sleep(1.0)
            save_registration(path, correction, jobs._registration_key(other, key))
            claim.unlink()

        writer = threading.Thread(target=the_other_process)
        writer.start()
        t = sim.time
        jobs._registered(other, key, sim)
        writer.join()
        assert sim.time == t  # waited for the other's file, ran nothing
        kept = known_registration(sim)
        for arm, fit in correction.arms.items():
            assert np.array_equal(kept.arms[arm].joint_offset, fit.joint_offset)
        assert key in other.registered
    finally:
        other.close()


def test_an_abandoned_claim_does_not_stop_the_registration(registered):
    out = registered[0]
    other = jobs.init_worker(jobs.JobSettings(out=str(out)))
    key = ('synthetic', 0.01, 3.0, 14, 'static')
    try:
        sim = jobs._physical_simulation(other, 'synthetic', 0.01,
                                        RobotErrors(error_level=3.0, error_seed=14))
        path = jobs._registration_path(other, key)
        claim = path.with_name(path.name + '.claim')
        claim.write_text('')
        old = time.time() - 2 * jobs.REGISTRATION_WAIT
        os.utime(claim, (old, old))
        t = sim.time
        jobs._registered(other, key, sim)
        assert sim.time > t  # registered here
        assert known_registration(sim) is not None
        assert path.is_file() and key in other.registered
    finally:
        other.close()
