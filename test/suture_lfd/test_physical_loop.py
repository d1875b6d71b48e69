"""
The executor in physical mode closes its loop on what the endoscope sees.

Real PyBullet scenes with hidden 3 mm-class kinematic errors, a ``pair_frame`` skill learnt from
a scripted demonstration on ``synth1``: with the correction (each PSM registered against the
endoscope, the throw run on the corrected kinematics) a throw completes; a needle the camera
cannot see stops the throw with a reason before anything moves; and nothing in a physical
throw reads the simulation's truth (its truth accessors raise during the throw).
"""

from dataclasses import replace
import inspect
import sys

import numpy as np
import pytest
from sim_bridge.control import Command
from sim_bridge.observers import GroundTruthObserver
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.demos.scripted_demo import record_scripted_demonstration
from suture_lfd.demos.segment_file import make_segment_file
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.skill import learn_skill, training_data
from suture_lfd.skill.arm_registration import known_registration, register_arms
from suture_lfd.skill.executor import ExecutorConfig, execute_throw

LEVEL = 3.0
ERROR_SEED = 1


@pytest.fixture(scope='module')
def skill(tmp_path_factory):
    sim = Simulation()
    try:
        demo, _, score = record_scripted_demonstration(sim, 'synth1', seed=0)
    finally:
        sim.close()
    assert score.score == 1.0, score.failure
    path = tmp_path_factory.mktemp('segments') / 'synth1.npz'
    make_segment_file(demo, segment_demonstration(demo), source='synth1 expert').save(path)
    return learn_skill(training_data(path), 'pair_frame')


def _scene(**loop_changes):
    config = load_simulation_config()
    config = replace(config, kinematic_error_level=LEVEL, kinematic_error_seed=ERROR_SEED)
    if loop_changes:
        config = replace(config, loop=replace(config.loop, **loop_changes))
    return Simulation(config)


@pytest.fixture(scope='module')
def scene():
    sim = _scene()
    yield sim
    sim.close()


_TRUTH = ('tool_pose', 'needle_pose', 'needle_tip', 'T_world_base', 'marker_poses',
          'phantom_pose')
# the facade's private accessors of the truth (what the ground-truth observer reads): blocked
# for callers in suture_lfd only, as sim_bridge's own observers may use them
_PRIVATE_TRUTH = ('_tool_pose', '_T_needle', '_T_world_base_true', '_errors')


def _guarded(name):
    original = inspect.getattr_static(Simulation, name)

    def caller_is_the_skill():
        return sys._getframe(2).f_globals.get('__name__', '').startswith('suture_lfd')

    if isinstance(original, property):
        def read(self):
            if caller_is_the_skill():
                raise AssertionError(f'a physical throw read the simulation truth: '
                                     f'Simulation.{name}')
            return original.fget(self)
        return property(read)

    def call(self, *args, **kwargs):
        if caller_is_the_skill():
            raise AssertionError(f'a physical throw read the simulation truth: Simulation.{name}')
        return original(self, *args, **kwargs)
    return call


def _poisoned(name):
    def read_truth(*args, **kwargs):
        raise AssertionError(f'a physical throw read the simulation truth: Simulation.{name}')
    return read_truth


def test_the_registration_finds_each_tools_error_within_a_millimetre(scene):
    correction = register_arms(scene)
    assert set(correction.arms) == {'PSM1', 'PSM2'}
    # each tool a centimetre above the pair, where the throw works
    centre = scene.target_pair.midpoint
    for arm, side in (('PSM1', -1.0), ('PSM2', 1.0)):
        T = scene.reported_tool_pose(arm)
        T[:3, 3] = centre + np.array([0.004 * side, 0.0, 0.008])
        scene.apply(Command(t=scene.time, T_world_tool={arm: T}, jaw={}, subtask='i'))
    scene.run(1.5)
    for arm, fit in correction.arms.items():
        assert fit.residual_px < 1.0
        q = np.array(scene.arms[arm].measured_jp)
        # checked against the truth here, in the test: the tool where the correction says
        off = fit.tool_pose(q)[:3, 3] - scene.tool_pose(arm)[:3, 3]
        before = scene.reported_tool_pose(arm)[:3, 3] - scene.tool_pose(arm)[:3, 3]
        assert np.linalg.norm(before) > 2e-3
        assert np.linalg.norm(off) < 1e-3, (arm, off)


def test_a_registration_whose_poses_half_disagree_is_fitted_to_those_that_agree():
    # A study's robot (error seed 1060198364, the study's 10 ms step): three of PSM1's six
    # registration poses were seen off (10 px), the fit of all six settled on offsets of
    # 12 degrees and 2 cm and was refused, and the robot's demonstrations on that phantom
    # could not hand the needle over. Fitted to three poses at a time, the poses that agree
    # give the arm's errors.
    config = load_simulation_config()
    config = replace(config, kinematic_error_level=LEVEL, kinematic_error_seed=1060198364,
                     world=replace(config.world, physics_step=0.01),
                     loop=replace(config.loop, collision_period=max(
                         config.loop.collision_period, 0.01)))
    sim = Simulation(config)
    try:
        correction = register_arms(sim)
        assert set(correction.arms) == {'PSM1', 'PSM2'}
        for arm, fit in correction.arms.items():
            assert fit.residual_px < 1.0, (arm, fit.residual_px)
            q = np.array(sim.arms[arm].measured_jp)
            # checked against the truth here, in the test
            off = fit.tool_pose(q)[:3, 3] - sim.tool_pose(arm)[:3, 3]
            assert np.linalg.norm(off) < 1e-3, (arm, off)
    finally:
        sim.close()


@pytest.mark.parametrize('fit_wrist', [False, True])
def test_a_level_3_throw_completes_on_what_the_camera_sees_and_reads_no_truth(
        scene, skill, monkeypatch, fit_wrist):
    # fit_wrist: the wrist's offsets fitted with the grasp during the carry, from the images
    config = ExecutorConfig(script=scene.config.scene.expert, fit_wrist=fit_wrist)
    for name in _TRUTH:
        monkeypatch.setattr(Simulation, name, _poisoned(name))
    for name in _PRIVATE_TRUTH:
        monkeypatch.setattr(Simulation, name, _guarded(name))
    monkeypatch.setattr(GroundTruthObserver, 'observe', _poisoned('observer (ground truth)'))
    outcome = execute_throw(scene, skill, 'synth1', seed=0, physical=True, correction=True,
                            config=config)
    monkeypatch.undo()
    assert outcome.score >= 0.8, outcome.failure
    assert outcome.subtasks['i'] and outcome.subtasks['ii']
    assert outcome.entry_error_mm < 1.5
    wrist = known_registration(scene).arms['PSM2'].joint_offset[3:5]
    assert np.any(wrist != 0.0) == fit_wrist, wrist  # fitted from the images, plausible
    assert np.all(np.abs(wrist) < 0.12), wrist


def test_a_needle_out_of_view_stops_the_throw_with_a_reason(skill):
    start = load_simulation_config().loop.needle_start
    sim = _scene(needle_start=replace(start, position=(0.11, 0.0), position_jitter=0.0))
    try:
        outcome = execute_throw(sim, skill, 'synth1', seed=0, physical=True)
        assert outcome.score == 0.0
        assert outcome.failure == 'not seen: the needle'
        assert outcome.executed == {} and outcome.duration == 0.0
    finally:
        sim.close()


def test_physical_mode_holds_the_start_press_until_the_rollout_is_as_deep(skill):
    # A skill learnt on what a robot saw can start the tip a little high and go down slowly;
    # faded by time, the press left the tip in the puncture's mouth and the first turn of the
    # insertion pulled it out ("withdrawn" on every synthetic pair for three of a study's
    # skills). Held, the planned tip stays the press below the rollout's own (less what the
    # rollout has already gone down) until the rollout is that deep, then follows it.
    from sim_bridge.common.geometry import matrix_from_quaternion
    from suture_lfd.skill.executor import ThrowExecutor

    sim = Simulation()
    try:
        pair, geometry = sim.phantom.markers['synth2'], sim.needle_geometry
        physical = ExecutorConfig(script=sim.config.scene.expert).in_physical_mode()
        assert physical.hold_press and physical.start_press == physical.physical_start_press
        executor = ThrowExecutor(skill, pair, geometry, config=physical)
        executor.rollout_paths()
    finally:
        sim.close()
    start, goal = skill.start_goal('ii', pair, needle=geometry)
    _, P, Q = skill.rollout('ii', pair, start=start, goal=goal, needle=geometry,
                            targets=(start, goal))
    _, Pp, Qp = executor.rollouts['ii']

    def heights(P, Q):
        tips = np.einsum('kij,j->ki', matrix_from_quaternion(Q), geometry.point_at(1.0)) + P
        return (tips - pair.entry) @ pair.normal

    raw, pressed = heights(P, Q), heights(Pp, Qp)
    press = physical.start_press
    descent = np.maximum.accumulate(np.maximum(0.0, raw[0] - raw))
    holding = descent < press
    assert holding[0] and not holding[-1]
    np.testing.assert_allclose(pressed[holding], raw[holding] - press + descent[holding],
                               atol=1e-12)
    # faded by time instead, the press is gone at a quarter of the insertion
    assert holding[len(raw) // 4]
    np.testing.assert_allclose(pressed[~holding], raw[~holding], atol=1e-12)


def test_physical_mode_ends_the_carry_higher_and_lowers_the_needle_in_two_legs(skill):
    # A tool off by millimetres away from where it was registered let the carried needle's
    # turning tip graze a curved pad mid-carry: an entry far from the marker. In physical mode
    # the carry ends physical_carry_lift higher along the pair's normal; the needle is lowered
    # to the start lift first, then as slowly as before onto the insertion's start. Ground truth
    # plans as before.
    from suture_lfd.planning.throw import Carry, Hold
    from suture_lfd.skill.executor import ThrowExecutor

    sim = Simulation()
    try:
        pair, geometry = sim.phantom.markers['synth2'], sim.needle_geometry
        plain = ExecutorConfig(script=sim.config.scene.expert)
        physical = plain.in_physical_mode()
        assert plain.carry_lift == 0.0 and physical.carry_lift == physical.physical_carry_lift > 0
        truth = ThrowExecutor(skill, pair, geometry, config=plain).rollout_paths()
        robot = ThrowExecutor(skill, pair, geometry, config=physical).rollout_paths()
    finally:
        sim.close()
    lowered, settle = truth.approach
    assert isinstance(lowered, Carry) and isinstance(settle, Hold)
    assert lowered.min_duration == plain.final_approach_time
    np.testing.assert_array_equal(lowered.path.A, truth.above)
    start = lowered.path.B  # the insertion's start (ground truth's press)
    assert len(robot.approach) == 3
    down, last, _ = robot.approach
    assert down.min_duration is None and last.min_duration == physical.final_approach_time
    np.testing.assert_array_equal(down.path.A, robot.above)
    np.testing.assert_array_equal(down.path.B, last.path.A)
    normal = np.asarray(pair.normal)
    # the carry ends carry_lift above where the final approach starts, start_lift above the
    # insertion's start (the physical press moves that start into the tissue)
    np.testing.assert_allclose(robot.above[:3, :3], last.path.A[:3, :3], atol=1e-12)
    np.testing.assert_allclose((robot.above[:3, 3] - last.path.A[:3, 3]) @ normal,
                               physical.physical_carry_lift, atol=1e-12)
    np.testing.assert_allclose((last.path.A[:3, 3] - last.path.B[:3, 3]) @ normal,
                               physical.start_lift, atol=1e-12)
    np.testing.assert_allclose((truth.above[:3, 3] - start[:3, 3]) @ normal, plain.start_lift,
                               atol=1e-12)
