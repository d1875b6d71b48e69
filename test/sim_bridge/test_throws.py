"""Whole suture throws in the stepped simulation, driven by the scripted expert.

The arms track their servo goals within the dVRK's velocity and acceleration limits, grasps
follow the jaw hysteresis rule, the needle falls under PyBullet when nothing holds it, and the
tissue tracker and scorer see the needle the simulation moves. Every score below is produced by
what happens in the scene, not by feeding events to the scorer.
"""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.control import Command
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ScriptedExpert

CONTROL = 0.01  # s between expert commands (100 Hz servo_cp stream)
PAIRS = [('synthetic', f'synth{i}') for i in range(1, 5)] + \
    [('scanned', f'scan{i}') for i in range(1, 5)]


@pytest.fixture(scope='module')
def config():
    return load_simulation_config()


@pytest.fixture(scope='module')
def sims(config):
    sims = {name: Simulation(config, phantom=name) for name in ('synthetic', 'scanned')}
    yield sims
    for sim in sims.values():
        sim.close()


def start_throw(sim, pair_name, seed=0):
    """Reset the scene, home the arms and aim the scorer at ``pair_name``."""
    start_episode(sim, pair_name, seed)
    sim.pop_events()


def expert_for(sim, pair=None):
    return ScriptedExpert(sim.target_pair if pair is None else pair, sim.needle_geometry,
                          sim.config.scene.expert, kinematics=sim.kinematics['PSM2'])


class JawOverride:
    """The expert's commands, with one PSM's jaw forced to ``jaw`` once ``when(plan_time)``."""

    def __init__(self, expert, arm, jaw, when):
        self.expert, self.arm, self.jaw, self.when = expert, arm, jaw, when
        self.t_fired = None

    def step(self, obs):
        cmd = self.expert.step(obs)
        if self.t_fired is None and self.when(self.expert.plan_time):
            self.t_fired = obs.t
        if self.t_fired is None:
            return cmd
        return Command(t=cmd.t, T_world_tool=cmd.T_world_tool,
                       jaw={**cmd.jaw, self.arm: self.jaw}, subtask=cmd.subtask)


def drive(sim, controller, stop, limit=40.0):
    """Run the controller at ``CONTROL`` until ``stop()`` or ``limit`` s; return the events."""
    run_episode(sim, controller, CONTROL, until=stop, timeout=limit, chunk=CONTROL, settle=0.0,
                reset=False)
    assert stop(), 'the throw never finished'
    return sim.pop_events()


def kinds(events):
    return [e.kind for e in events if e.kind not in ('score', 'collision')]


def label_times(expert):
    return {label: t for t, label in expert.plan_.labels}


@pytest.mark.parametrize(('phantom', 'pair'), PAIRS)
def test_the_expert_completes_every_pair_with_all_five_subtasks(sims, phantom, pair):
    sim = sims[phantom]
    start_throw(sim, pair)
    expert = expert_for(sim)
    events = drive(sim, expert, lambda: expert.done)
    result = sim.score()
    assert result.score == 1.0, result.failure
    assert all(result.subtasks.values()), result.subtasks
    assert result.entry_error_mm < 0.5 and result.exit_error_mm < 0.5
    assert result.trauma_mm < 0.5 and not result.dropped
    assert kinds(events) == ['grasp', 'entry', 'exit', 'grasp', 'release', 'extracted',
                                      'grasp', 'release']
    grasps = [e.data['arm'] for e in events if e.kind in ('grasp', 'release')]
    assert grasps[-4:] == ['PSM1', 'PSM2', 'PSM2', 'PSM1']
    # the last score event the scene reported is the complete throw
    scores = [e.data['score'] for e in events if e.kind == 'score']
    assert scores[-1].score == 1.0 and scores[-1].time_s == pytest.approx(result.time_s)
    assert sim.grasp.holders == ('PSM2',) and sim.needle_mode == 'held'


def test_a_throw_aimed_5_mm_along_the_wound_misses_the_entry_and_scores_0_4(sims):
    sim = sims['synthetic']
    start_throw(sim, 'synth2')
    true = sim.target_pair
    along = true.frame[:3, 1]
    aimed = replace(true, entry=true.entry + 0.005 * along, exit=true.exit + 0.005 * along)
    expert = expert_for(sim, aimed)
    drive(sim, expert, lambda: expert.done)
    result = sim.score()
    assert result.entry_error_mm == pytest.approx(5.0, abs=0.3)
    assert result.exit_error_mm == pytest.approx(5.0, abs=0.3)
    assert set(result.failures) == {'entry missed', 'exit missed'}, result.failure
    assert result.score == 0.4
    assert not result.subtasks['i'] and not result.subtasks['ii']
    assert result.subtasks['iii'] and result.subtasks['iv'] and result.subtasks['v']


def test_a_throw_that_comes_out_beside_the_exit_scores_0_8(sims):
    sim = sims['synthetic']
    start_throw(sim, 'synth3')
    true = sim.target_pair
    aimed = replace(true, exit=true.exit + 0.004 * true.frame[:3, 1])
    expert = expert_for(sim, aimed)
    drive(sim, expert, lambda: expert.done)
    result = sim.score()
    assert result.entry_error_mm < 0.5
    assert result.exit_error_mm == pytest.approx(4.0, abs=0.3)
    assert result.failures == ('exit missed',)
    assert result.score == 0.8


def test_opening_the_jaw_while_carrying_to_the_entry_drops_the_needle_and_scores_0(sims):
    sim = sims['synthetic']
    start_throw(sim, 'synth1')
    expert = expert_for(sim)
    expert.step(sim.observation())  # plans the throw
    t_ii = label_times(expert)['ii']
    pick = expert.plan_.gates[0].t
    # half-way between the pick and the entry the needle is in the air, held by PSM2 alone
    override = JawOverride(expert, 'PSM2', 0.8, lambda tau: tau >= 0.5 * (pick + t_ii))
    events = drive(sim, override, lambda: override.t_fired is not None
                   and sim.needle_mode == 'resting', limit=20.0)
    assert kinds(events)[:3] == ['grasp', 'release', 'drop']
    drop = next(e for e in events if e.kind == 'drop')
    assert drop.data['fall'] > sim.config.loop.drop_distance
    result = sim.score()
    assert result.score == 0.0 and result.dropped
    assert 'dropped' in result.failures and 'no entry' in result.failures
    assert not any(result.subtasks.values())
    assert sim.grasp.holders == ()


def test_opening_the_jaw_mid_insertion_reports_a_drop_and_scores_0(sims):
    sim = sims['synthetic']
    start_throw(sim, 'synth4')
    expert = expert_for(sim)
    expert.step(sim.observation())
    times = label_times(expert)
    t_open = times['ii'] + 0.3 * (times['iii'] - times['ii'])
    override = JawOverride(expert, 'PSM2', 0.8, lambda tau: tau >= t_open)
    events = drive(sim, override, lambda: override.t_fired is not None
                   and sim.time > override.t_fired + 1.0, limit=20.0)
    assert kinds(events)[:4] == ['grasp', 'entry', 'release', 'drop']
    release = next(e for e in events if e.kind == 'release')
    assert release.data['arm'] == 'PSM2' and release.data['leader'] is None
    # released in the tissue: reported as a drop, but the tissue holds the needle, it does not
    # fall
    drop = next(e for e in events if e.kind == 'drop')
    assert drop.data['in_tissue'] and drop.t == release.t
    assert sim.needle_mode == 'tissue'
    before = sim.needle_pose()
    sim.run(0.5)
    assert np.array_equal(sim.needle_pose(), before)
    result = sim.score()
    assert result.score == 0.0
    assert 'dropped' in result.failures and not result.subtasks['ii']
    assert result.entry_error_mm < 0.5


def test_closing_the_jaw_5_mm_beside_the_needle_grasps_nothing(sims):
    sim = sims['synthetic']
    start_throw(sim, 'synth2')
    N = sim.needle_pose()
    geometry = sim.needle_geometry
    expert = expert_for(sim)
    s_grasp = expert.plan(sim.observation())
    # aim the pick 5 mm radially outside the wire at the planned grasp point
    G = s_grasp.grasps['PSM2_drive']  # T_tool_needle
    jaw_point = np.linalg.inv(G) @ np.array([0.0, 0.0, geometry.grasp_depth, 1.0])
    radial = jaw_point[:3] / np.linalg.norm(jaw_point[:3])
    shifted = N.copy()
    shifted[:3, 3] += N[:3, :3] @ (0.005 * radial)
    obs = sim.observation()
    expert.reset(replace(obs, T_world_needle=shifted))
    gate = expert.plan_.gates[0]
    assert (gate.arm, gate.kind) == ('PSM2', 'grasp')
    closed = {}

    def stop():
        jaw = sim.arms['PSM2'].jaw_measured_jp
        if jaw > sim.config.grasp.release_angle:
            closed['opened'] = True
        if 'd' not in closed and closed.get('opened') and jaw < sim.config.grasp.close_angle:
            T_needle_tool = np.linalg.inv(sim.needle_pose()) @ sim.tool_pose('PSM2')
            p = (T_needle_tool @ np.array([0.0, 0.0, geometry.grasp_depth, 1.0]))[:3]
            closed['d'] = geometry.distance_to_arc(p[None])[0]
        return expert.plan_time > gate.t + 0.5

    events = drive(sim, expert, stop, limit=20.0)
    assert closed['d'] == pytest.approx(0.005, abs=5e-4)
    assert 'grasp' not in kinds(events)
    assert sim.grasp.holders == () and sim.needle_mode == 'resting'
    assert np.allclose(sim.needle_pose(), N, atol=1e-9)
