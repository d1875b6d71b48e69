"""
A throw replay file: sampled from a real simulated throw, written as a versioned archive and
read back into the viewer's recording; another file is refused with its name and key.
"""

import numpy as np
import pytest
from sim_bridge.common.geometry import transform_from_pose
from sim_bridge.simulation import Simulation
from suture_lfd.archive import save_archive
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ScriptedExpert
from suture_lfd.viewer.throw_replay import ThrowSampler, recording_from_file

CONTROL = 0.02


class Sampled:
    """The expert's commands, with the replay sampler called at every control step."""

    def __init__(self, expert, sampler):
        self.expert, self.sampler = expert, sampler

    def step(self, obs):
        self.sampler()
        return self.expert.step(obs)


@pytest.fixture(scope='module')
def replay(tmp_path_factory):
    sim = Simulation(phantom='synthetic')
    try:
        pair = start_episode(sim, 'synth1')
        expert = ScriptedExpert(pair, sim.needle_geometry, sim.config.scene.expert,
                                kinematics=sim.kinematics['PSM2'])
        sampler = ThrowSampler(sim)
        run_episode(sim, expert, CONTROL, stepper=Sampled(expert, sampler), timeout=40.0,
                    settle=0.0)
        assert expert.done
        path = tmp_path_factory.mktemp('replays') / 'throw.npz'
        sampler.save(path, 'synth1', events=[{'t': sampler.rows[-1][0], 'kind': 'done'}])
        return path, np.array(sampler.rows), sim.needle_pose()
    finally:
        sim.close()


def test_the_replay_shows_the_needle_where_the_simulation_had_it(replay):
    path, rows, last_needle = replay
    recording = recording_from_file(path)
    needle = next(track for track in recording.tracks if track.child == 'needle')
    assert len(needle.t) == len(rows) > 100
    assert needle.t[0] == 0.0
    assert recording.duration == pytest.approx(rows[-1, 0] - rows[0, 0])
    # samples are stored as float32: the last one is within a micrometre of the scene's pose
    T = transform_from_pose(needle.poses[-1])
    assert np.allclose(T[:3, 3], rows[-1, 1:4], atol=1e-6)
    assert recording.phantom == 'synthetic'
    assert [event['kind'] for _, event in recording.events] == ['done']


def test_a_file_of_another_format_is_refused_with_its_name(tmp_path):
    other = tmp_path / 'segments.npz'
    save_archive(other, {'x': np.zeros(3)}, 'suture_lfd.segments', 1)
    with pytest.raises(ValueError, match=r"segments\.npz: key 'format' is 'suture_lfd\.segments'"):
        recording_from_file(other)
