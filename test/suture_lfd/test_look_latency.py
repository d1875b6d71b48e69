"""A look at the held needle waits for the frame of its instant (real PyBullet, a dVRK endoscope).

The executor looks at the needle PSM2 carries at a planned instant, chosen for how the needle
then faces the camera. An endoscope's frames arrive their latency after the scene they show: a
look taken when it falls due would see the needle as it was a few frames before, turned
differently. With ``frame_time`` the look is taken once a frame of its instant has arrived.
"""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.realism.endoscope import endoscope_preset
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill
from suture_lfd.skill.executor import ThrowExecutor
from suture_lfd.skill.perceived import PerceivedScene

CONTROL_PERIOD = 0.02


@pytest.fixture(scope='module')
def sim():
    cfg = load_simulation_config()
    cfg = replace(cfg, endoscope=endoscope_preset('dvrk'),
                  camera=replace(cfg.camera, noise_std=0.0, light_jitter=0.0))
    scene = Simulation(cfg, phantom='synthetic', rng=np.random.default_rng(0))
    yield scene
    scene.close()


@pytest.fixture(scope='module')
def skill(sim, tmp_path_factory):
    demo, _, score = record_scripted_demonstration(sim, 'synth1', seed=0)
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('segments') / 'synth1.npz'
    make_segment_file(demo, segment_demonstration(demo), source='synth1 expert').save(path)
    return learn_skill(path, 'pair_frame')


def _first_look(sim, skill, wait_for_frame: bool) -> tuple[float, float]:
    """Run a throw until its first look; return (time of the look, scene time of its frame)."""
    pair = start_episode(sim, 'synth2', seed=1)
    looks: list[tuple[float, float]] = []

    def look(arm, obs):
        looks.append((float(obs.t), float(sim.delivered_frame())))
        return None  # the grasp is kept: both runs go on alike

    scene = PerceivedScene('synth2', pair.index, sim.needle_geometry)
    executor = ThrowExecutor(skill, pair, sim.needle_geometry, kinematics=sim.kinematics['PSM1'],
                             look=look, facing=lambda T: scene.facing(sim, T),
                             frame_time=sim.delivered_frame if wait_for_frame else None)
    run_episode(sim, executor, CONTROL_PERIOD, until=lambda: bool(looks), timeout=30.0,
                reset=False, chunk=CONTROL_PERIOD, settle=0.0)
    assert looks, 'the executor never looked at the held needle'
    return looks[0]


def test_a_look_waits_for_the_frame_of_its_instant(sim, skill):
    timing = sim.config.endoscope.timing
    due, stale = _first_look(sim, skill, wait_for_frame=False)
    # taken when it falls due, the look gets a frame of the scene its latency before
    assert stale <= due - timing.latency + 1e-9
    taken, shown = _first_look(sim, skill, wait_for_frame=True)
    # waiting, it gets a frame of the instant it fell due or later, within a frame and a
    # control period of the latency
    assert shown >= due - 1e-9
    assert taken - due <= timing.latency + 1.0 / timing.rate + 2 * CONTROL_PERIOD
