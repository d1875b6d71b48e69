"""
One episode in the real simulation: start (reset, home, pair), the control loop, the settling.

A small controller opens PSM2's jaw a little more at every call and says it is done after a
given number of calls; the episode's clock and the arm's jaw show which commands were applied.
"""

import pytest
from sim_bridge.control import Command, Controller
from sim_bridge.simulation import Simulation
from suture_lfd.planning.episode import run_episode, start_episode
from suture_lfd.planning.expert import ScriptedExpert

PERIOD = 0.02


class Opener:
    """Commands PSM2's jaw to ``0.1 * calls`` rad; done after ``calls`` calls."""

    def __init__(self, calls):
        self.calls, self.made, self.resets = calls, 0, 0

    def reset(self, obs):
        self.resets += 1

    @property
    def done(self):
        return self.made >= self.calls

    def step(self, obs):
        self.made += 1
        return Command(t=obs.t, T_world_tool={}, jaw={'PSM2': 0.1 * self.made}, subtask='i')


@pytest.fixture(scope='module')
def sim():
    sim = Simulation(phantom='synthetic')
    yield sim
    sim.close()


def test_the_start_homes_the_arms_and_aims_at_the_pair(sim):
    pair = start_episode(sim, 'synth2', seed=4)
    assert pair.name == 'synth2' and sim.target_pair is pair
    assert all(arm.operating_state.is_homed for arm in sim.arms.values())


def test_stopping_at_done_leaves_the_last_command_unapplied(sim):
    start_episode(sim, 'synth1')
    t0 = sim.time
    opener = Opener(3)
    elapsed = run_episode(sim, opener, PERIOD, settle=0.0, reset=False, stop_at_done=True)
    assert opener.made == 3 and opener.resets == 0
    # the first two commands ran a period each; the third, made when done, was not applied
    assert elapsed == pytest.approx(2 * PERIOD) and sim.time - t0 == pytest.approx(2 * PERIOD)
    assert sim.arms['PSM2'].jaw_setpoint_jp == pytest.approx(0.2)


def test_the_chunked_loop_runs_to_the_end_of_its_chunk_then_settles(sim):
    start_episode(sim, 'synth1')
    t0 = sim.time
    opener = Opener(3)
    elapsed = run_episode(sim, opener, PERIOD, chunk=5 * PERIOD, settle=2 * PERIOD)
    assert opener.resets == 1
    assert elapsed == pytest.approx(5 * PERIOD)
    assert sim.time - t0 == pytest.approx(7 * PERIOD)
    assert opener.made == 7  # the controller keeps commanding while the scene settles


def test_a_stop_condition_and_a_timeout_end_the_loop_before_done(sim):
    start_episode(sim, 'synth1')
    opener = Opener(100)
    run_episode(sim, opener, PERIOD, until=lambda: opener.made >= 4, chunk=PERIOD, settle=0.0)
    assert opener.made == 4 and not opener.done
    opener = Opener(100)
    elapsed = run_episode(sim, opener, PERIOD, timeout=3 * PERIOD, chunk=PERIOD, settle=1.0)
    assert elapsed == pytest.approx(3 * PERIOD) and not opener.done
    assert opener.made == 3  # no settling after a timeout unless asked


def test_the_scripted_expert_is_a_controller_and_a_stepper_alone_is_not(sim):
    class StepsOnly:
        def step(self, obs):
            return None

    pair = next(iter(sim.phantom.markers.values()))
    assert isinstance(ScriptedExpert(pair, sim.needle_geometry), Controller)
    assert isinstance(Opener(1), Controller)
    assert not isinstance(StepsOnly(), Controller)
