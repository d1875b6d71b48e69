"""
The executor's sequence without ROS: the core machine driven on a real in-process simulation.

The arms the machine commands are the real PyBullet scene (:class:`SceneArms` answers the
machine's questions from it and applies its commands); the machine's wall clock is the
simulation's own clock, so every timeout is counted deterministically.
"""

from dataclasses import replace
import json

import numpy as np
import pytest
from sim_bridge.common.vocabulary import PSMS
from sim_bridge.observers import PhysicalObserver
from sim_bridge.scene.scene_config import load_scene_config
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.perception import StereoPerception, stereo_from_camera_info
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill, training_data
from suture_lfd.skill.executor import ExecutorConfig, _event_dict
from suture_lfd.skill.executor_machine import ExecutorMachine, MachineConfig
from suture_lfd.skill.perceived_feed import NeedleStatus
from suture_lfd.skill.watchdog import ArmWatchdog

CONTROL_PERIOD = 0.01  # s of simulation between ticks


class SceneArms:
    """The in-process scene as the machine's arms: what it reports, what it applies."""

    def __init__(self, sim):
        self.sim = sim
        self.events = []  # (t, data) for the machine, as a simulator node publishes them
        self.sent = 0

    def ready(self, pairs=()):
        return all(p in self.sim.phantom.markers for p in pairs)

    def has_pair(self, name):
        return name in self.sim.phantom.markers

    def _states(self):
        return [self.sim.arms[a].operating_state for a in PSMS]

    def homed(self):
        return all(s.state == 'ENABLED' and s.is_homed and not s.is_busy for s in self._states())

    def enable_and_home(self):
        for a in PSMS:
            s = self.sim.arms[a].operating_state
            if s.state != 'ENABLED':
                self.sim.arms[a].state_command('enable')
            elif not s.is_homed and not s.is_busy:
                self.sim.arms[a].state_command('home')
        return self.homed()

    def watch_pairs(self, names):
        pass  # the scene's markers are all known in-process

    def select_pair(self, name):
        if name in self.sim.phantom.markers:
            self.sim.set_target_pair(name)
            self.events.append((self.sim.time, {'kind': 'target_pair', 'pair': name}))
        else:
            self.events.append((self.sim.time, {'kind': 'target_pair', 'pair': name,
                                                'error': 'unknown pair'}))

    def target_matched(self):
        return True

    def fault(self):
        for a, s in zip(PSMS, self._states()):
            if s.state != 'ENABLED':
                return f'{a} is {s.state}'
        return None

    def observation(self, pair):
        return self.sim.observation()

    def camera_pose(self):
        return self.sim.camera_pose()

    def measured_stamps(self):
        return dict.fromkeys(PSMS, self.sim.time)

    def send(self, command, t):
        self.sim.apply(command)
        self.sent += 1
        return sum(command.T_world_tool.get(a) is not None for a in PSMS)


def make_machine(sim, skill, arms, on_feed=None, **config):
    statuses, results = [], []
    watchdog = ArmWatchdog(PSMS, 1.0 / CONTROL_PERIOD, 0.1, 1.0, 30.0)
    machine = ExecutorMachine(
        skill, load_scene_config(), sim.kinematics['PSM1'], arms, arms.send, watchdog,
        MachineConfig(**config), on_status=statuses.append, on_result=results.append,
        on_feed=on_feed, clock=lambda: sim.time)
    return machine, watchdog, statuses, results


def run(sim, arms, machine, watchdog, seconds):
    """Tick the machine every control period for up to ``seconds`` of simulation."""
    steps = round(CONTROL_PERIOD / sim.dt)
    end = sim.time + seconds
    while machine.active and sim.time < end:
        for a in PSMS:
            watchdog.measured(a, sim.time, sim.time)
        watchdog.clock(sim.time, sim.time)
        machine.tick()
        for _ in range(steps):
            sim.step()
        arms.events.extend((ev.t, _event_dict(ev)) for ev in sim.pop_events())
        for t, data in arms.events:
            machine.event(t, data)
        arms.events.clear()


@pytest.fixture(scope='module')
def segments(simulation, tmp_path_factory):
    demo, _, score = record_scripted_demonstration(simulation, 'synth1', seed=0)
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('executor_machine') / 'synth1_segments.npz'
    make_segment_file(demo, segment_demonstration(demo), source='scripted expert').save(path)
    return path


@pytest.fixture(scope='module')
def skill(segments):
    return learn_skill(segments)


@pytest.fixture(scope='module')
def pair_frame_skill(segments):
    return learn_skill(training_data(segments), 'pair_frame')


def test_a_throw_goes_through_its_stages_and_its_outcome_is_written(simulation, skill,
                                                                     tmp_path):
    simulation.reset(seed=0)
    arms = SceneArms(simulation)
    outcome = tmp_path / 'out' / 'outcome.json'
    machine, watchdog, statuses, results = make_machine(simulation, skill, arms,
                                                        result_file=str(outcome))
    assert machine.execute('synth2')
    run(simulation, arms, machine, watchdog, 90.0)
    stages = [s['state'] for s in statuses]
    assert stages == ['preparing', 'running', 'settling', 'done'], statuses
    [result] = results
    assert result['state'] == 'done' and result['pair'] == 'synth2'
    assert result['score'] == 1.0, result
    assert result['servo_cp_sent'] > 0 and arms.sent > 0
    assert 0 < result['time_s'] <= result['duration'] + 1e-9
    written = json.loads(outcome.read_text())
    assert written['score'] == 1.0 and written['score_detail']['score'] == 1.0
    assert set(written['executed']) == {'ii', 'iv'}
    assert written['executed']['ii']['t'][0] == 0.0
    assert not machine.finished  # not asked to exit


def test_a_request_during_a_throw_an_empty_name_and_a_stop_are_reported(simulation, skill):
    simulation.reset(seed=0)
    arms = SceneArms(simulation)
    machine, watchdog, statuses, results = make_machine(simulation, skill, arms)
    assert not machine.execute('  ')
    assert statuses[-1]['reason'] == 'execute ignored: empty pair name'
    assert machine.stage == 'idle'
    assert machine.execute('synth1')
    assert not machine.execute('synth2')
    assert 'in progress' in statuses[-1]['reason'] and machine.pair == 'synth1'
    machine.stop()
    assert machine.stage == 'stopped' and results[-1]['reason'] == 'stop requested'
    machine.stop()  # nothing in progress: nothing happens
    assert len(results) == 1


def test_arms_that_are_not_homed_fail_the_throw_when_homing_is_off(simulation, skill):
    simulation.reset(seed=0)
    arms = SceneArms(simulation)
    machine, watchdog, statuses, results = make_machine(simulation, skill, arms, home=False)
    machine.exit_when_done = True
    assert machine.execute('synth1')
    run(simulation, arms, machine, watchdog, 1.0)
    assert results[-1]['state'] == 'failed'
    assert results[-1]['reason'] == 'arms not enabled and homed'
    assert machine.finished and machine.exit_code == 1


def test_a_pair_the_simulator_refuses_fails_the_preparation(simulation, skill):
    simulation.reset(seed=0)
    arms = SceneArms(simulation)
    arms.ready = lambda pairs=(): True  # the node's client has its markers; the scene has not
    machine, watchdog, statuses, results = make_machine(simulation, skill, arms)
    assert machine.execute('synth9')
    run(simulation, arms, machine, watchdog, 5.0)
    assert results[-1]['state'] == 'failed', statuses
    assert "refused pair 'synth9'" in results[-1]['reason']


def test_in_physical_mode_a_pair_name_without_its_position_is_refused(simulation, skill):
    arms = SceneArms(simulation)
    machine, _, statuses, _ = make_machine(simulation, skill, arms, physical=True)
    assert not machine.execute('left')
    assert 'does not end in its position along the wound' in statuses[-1]['reason']
    assert machine.stage == 'idle' and machine.feed is None


def test_in_physical_mode_nothing_seen_fails_with_what_was_not_seen(simulation, skill):
    simulation.reset(seed=0)
    arms = SceneArms(simulation)
    fed = []
    machine, watchdog, statuses, results = make_machine(simulation, skill, arms, fed.append,
                                                        physical=True, prepare_timeout=3.0)
    assert machine.execute('synth1')
    assert fed == [machine.feed] and machine.feed.pair_index == 1
    run(simulation, arms, machine, watchdog, 10.0)
    assert results[-1]['state'] == 'failed'
    assert results[-1]['reason'].startswith('not seen: markers, needle'), results[-1]


class PerceivedSceneArms(SceneArms):
    """
    The in-process scene as a physical dVRK shows it: the arms' reports, a stereo pair once
    every ``image_period`` simulated seconds, and a perception process on those images.
    """

    def __init__(self, sim, image_period=0.5):
        super().__init__(sim)
        self.observer = PhysicalObserver(sim, estimator=None)
        self.perception = StereoPerception()
        camera = sim.camera
        self.stereo = stereo_from_camera_info(camera.camera_info('left'),
                                              camera.camera_info('right'))
        self.image_period = image_period
        self.feed = None
        self.pair = None   # the newest stereo pair: (stamp, stereo, left, right)
        self._last = -np.inf

    def select_pair(self, name):
        self.sim.set_target_pair(name)  # the evaluation's, not read by the machine

    def observation(self, pair):
        return self.observer.arm_state()

    def camera_pose(self):
        return self.sim.reported_tool_pose('ECM') @ self.sim.camera.T_tip_left

    def images(self):
        return self.pair

    def look(self):
        """Take a stereo pair when one is due and hand the perception's outputs to the feed."""
        if self.sim.time - self._last < self.image_period - 1e-9:
            return
        self._last = t = self.sim.time
        frame = self.sim.render()
        self.pair = (t, self.stereo, frame.left_rgb, frame.right_rgb)
        result = self.perception.process(frame.left_rgb, frame.right_rgb, self.stereo, t)
        if self.feed is None:
            return
        est = result.needle
        self.feed.needle_seen(t, est.pose_camera if est.found else None,
                              NeedleStatus(est.found, est.reason))
        if result.markers is not None:
            self.feed.markers_seen(t, result.markers.entries, result.markers.exits,
                                   result.markers.normal)


def run_physical(sim, arms, machine, watchdog, seconds):
    """Tick the machine on the perceived scene for up to ``seconds`` of simulation."""
    steps = round(CONTROL_PERIOD / sim.dt)
    end = sim.time + seconds
    while machine.active and sim.time < end:
        arms.feed = machine.feed
        arms.look()
        for a in PSMS:
            watchdog.measured(a, sim.time, sim.time)
        watchdog.clock(sim.time, sim.time)
        machine.tick()
        for _ in range(steps):
            sim.step()
    score = sim.score()
    return score


@pytest.mark.parametrize('level', [0.0, 3.0])
def test_in_physical_mode_the_machine_registers_the_arms_and_scores_on_what_it_sees(
        pair_frame_skill, level):
    config = replace(load_simulation_config(), kinematic_error_level=level,
                     kinematic_error_seed=1)
    sim = Simulation(config)
    try:
        sim.reset(seed=0)
        arms = PerceivedSceneArms(sim)
        statuses, results, presses = [], [], []

        def on_status(record):
            statuses.append(record)
            if record['state'] == 'running':  # the settings the throw runs with
                presses.append(machine._executor.executor_config.start_press)

        watchdog = ArmWatchdog(PSMS, 1.0 / CONTROL_PERIOD, 0.1, 1.0, 30.0)
        machine = ExecutorMachine(
            pair_frame_skill, load_scene_config(), sim.kinematics['PSM1'], arms, arms.send,
            watchdog, MachineConfig(physical=True, prepare_timeout=30.0),
            on_status=on_status, on_result=results.append, clock=lambda: sim.time,
            images=arms.images, instrument=sim.config.world.instrument)
        assert machine.execute('synth1')
        score = run_physical(sim, arms, machine, watchdog, 150.0)
    finally:
        sim.close()
    stages = [s['state'] for s in statuses]
    assert stages[:3] == ['preparing', 'registering', 'preparing'], statuses
    assert set(machine.correction.arms) == {'PSM1', 'PSM2'}
    # physical mode's settings, as in-process: the start of the insertion pressed deeper
    assert presses == [ExecutorConfig().physical_start_press], presses
    assert results and results[-1]['state'] == 'done', (results, statuses[-3:])
    assert score.score >= 0.8, (score.score, score.failure, score.entry_error_mm,
                                score.exit_error_mm)
