"""The simulation loop: grasping, dropping, handover, tissue, events, determinism, rendering."""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.arm import ArmConfig
from sim_bridge.common.geometry import invert_transform
from sim_bridge.control import Command
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.planning.expert import ScriptedExpert
from suture_lfd.planning.throw_geometry import ThrowArc


@pytest.fixture(scope='module')
def config():
    return load_simulation_config()


@pytest.fixture(scope='module')
def exact_config(config):
    """Arms that reach every servo goal at once, to test the world's rules on their own."""
    return replace(config, arm=ArmConfig(tracking='exact'))


@pytest.fixture()
def sim(exact_config):
    s = Simulation(exact_config)
    s.enable_and_home_all()
    s.pop_events()
    yield s
    s.close()


def _kinds(events):
    return [e.kind for e in events if e.kind != 'score']


def _reachable_grasp(sim, arm, T_needle, s):
    """World tool pose grasping the needle at arc parameter s, reachable with a small wrist."""
    chain = sim.kinematics[arm]
    T_base_world = invert_transform(sim.T_world_base(arm))
    best, best_cost = None, np.inf
    for flip in (False, True):
        for roll in np.radians(np.arange(-180.0, 180.0, 15.0)):
            T_tool = T_needle @ invert_transform(
                sim.needle_geometry.grasp_transform(s, roll=roll, flip=flip))
            Q, ok = chain.ik_batch((T_base_world @ T_tool)[None])
            if ok[0] and np.abs(Q[0, 4:]).max() < best_cost:
                best, best_cost = T_tool, np.abs(Q[0, 4:]).max()
    assert best is not None
    return best


def _command(arm, T=None, jaw=None):
    return Command(t=0.0, T_world_tool={arm: T}, jaw={arm: jaw}, subtask='')


def _hold_needle_in_the_air(sim, arm='PSM2', height=0.02):
    """PSM2 picks the needle lying on the pad and lifts it by ``height``."""
    T_grasp = _reachable_grasp(sim, arm, sim.needle_pose(), 1.0 / 3.0)
    above = T_grasp.copy()
    above[2, 3] += 0.01
    sim.apply(_command(arm, above, 0.8))
    sim.run(0.3)
    sim.apply(_command(arm, T_grasp))
    sim.run(0.1)
    sim.apply(_command(arm, jaw=-0.35))
    sim.run(0.3)
    assert sim.grasp.holders == (arm,)
    lifted = T_grasp.copy()
    lifted[2, 3] += height
    sim.apply(_command(arm, lifted))
    sim.run(0.2)
    return lifted


def test_closing_on_the_needle_grasps_it_and_it_follows_the_tool(sim):
    start = sim.needle_pose()
    assert sim.needle_mode == 'resting'
    lifted = _hold_needle_in_the_air(sim)
    events = sim.pop_events()
    grasps = [e for e in events if e.kind == 'grasp']
    assert len(grasps) == 1 and grasps[0].data['arm'] == 'PSM2'
    relative = sim.grasp.relative_pose('PSM2')
    assert np.allclose(sim.tool_pose('PSM2'), lifted, atol=1e-9)
    assert np.allclose(sim.needle_pose(), lifted @ relative, atol=1e-12)
    assert sim.needle_pose()[2, 3] == pytest.approx(start[2, 3] + 0.02, abs=1e-6)
    assert sim.needle_mode == 'held'


def test_closing_five_millimetres_beside_the_needle_grasps_nothing(sim):
    T_grasp = _reachable_grasp(sim, 'PSM2', sim.needle_pose(), 1.0 / 3.0)
    beside = T_grasp.copy()
    beside[:3, 3] += 0.005 * T_grasp[:3, 1]  # along the jaws' closing direction
    sim.apply(_command('PSM2', beside, 0.8))
    sim.run(0.3)
    sim.apply(_command('PSM2', jaw=-0.35))
    sim.run(0.3)
    assert sim.grasp.holders == ()
    assert 'grasp' not in _kinds(sim.pop_events())


def test_opening_drops_the_needle_which_falls_and_rests_on_the_pad(sim):
    _hold_needle_in_the_air(sim, height=0.03)
    sim.pop_events()
    sim.apply(_command('PSM2', jaw=0.1))  # inside the hysteresis band: still held
    sim.run(0.2)
    assert sim.grasp.holders == ('PSM2',)
    sim.apply(_command('PSM2', jaw=0.8))
    sim.run(1.5)
    events = sim.pop_events()
    kinds = _kinds(events)
    assert kinds[:2] == ['release', 'drop']
    drop = next(e for e in events if e.kind == 'drop')
    assert drop.data['fall'] > sim.config.loop.drop_distance
    assert sim.needle_mode == 'resting'
    wire = sim.needle_geometry.points_world(sim.needle_pose(), 48)
    top = sim.world.support_height(wire[:, :2])
    gap = wire[:, 2] - top - 0.5 * sim.needle_geometry.wire_diameter
    assert gap.min() == pytest.approx(0.0, abs=3e-4)
    assert sim.score().dropped


def test_handover_between_arms_keeps_the_needle_pose_continuous(sim):
    _hold_needle_in_the_air(sim, height=0.025)
    N = sim.needle_pose()
    T1 = _reachable_grasp(sim, 'PSM1', N, 0.85)
    approach = T1.copy()
    approach[:3, 3] -= 0.01 * T1[:3, 2]
    sim.apply(_command('PSM1', approach, 0.8))
    sim.run(0.3)
    sim.apply(_command('PSM1', T1))
    sim.run(0.1)
    sim.pop_events()
    poses = []
    for command in (_command('PSM1', jaw=-0.35), _command('PSM2', jaw=0.8)):
        sim.apply(command)
        for _ in range(150):
            sim.step()
            poses.append(sim.needle_pose())
    events = sim.pop_events()
    assert [(e.kind, e.data['arm'], e.data['leader']) for e in events if e.kind != 'score'] == [
        ('grasp', 'PSM1', 'PSM2'), ('release', 'PSM2', 'PSM1')]
    steps = [np.abs(b - a).max() for a, b in zip(poses[:-1], poses[1:])]
    assert max(steps) < 1e-12
    # PSM1 now carries it
    moved = T1.copy()
    moved[2, 3] += 0.01
    sim.apply(_command('PSM1', moved))
    sim.run(0.05)
    assert sim.needle_pose()[2, 3] == pytest.approx(N[2, 3] + 0.01, abs=1e-9)


def test_a_needle_released_inside_the_tissue_stays_where_it_is(sim):
    # PSM2 holds the needle a third of the way from the entry to the exit of pair synth3
    arc = ThrowArc(sim.phantom.markers['synth3'], sim.needle_geometry)
    T_needle = arc.T_world_needle(arc.alpha_entry + 0.3 * (arc.alpha_exit - arc.alpha_entry))
    T_tool = _reachable_grasp(sim, 'PSM2', T_needle, 1.0 / 3.0)
    sim.apply(_command('PSM2', T_tool, -0.35))
    sim.run(0.05)
    sim.attach_needle('PSM2', invert_transform(sim.tool_pose('PSM2')) @ T_needle)
    sim.run(0.05)
    assert sim.tissue.in_tissue
    sim.apply(_command('PSM2', jaw=0.8))
    sim.run(0.5)
    assert sim.needle_mode == 'tissue'
    assert np.allclose(sim.needle_pose(), T_needle, atol=1e-12)
    # no arm holds it any more: reported as a drop, though it does not fall
    drops = [e for e in sim.pop_events() if e.kind == 'drop']
    assert len(drops) == 1 and drops[0].data['in_tissue'] and drops[0].data['fall'] == 0.0


def test_driving_the_jaws_into_the_pad_reports_one_collision(sim):
    T = sim.tool_pose('PSM2').copy()
    T[:3, 3] = [0.02, 0.0, 0.004]  # jaw tips (9 mm along tool z, pointing down) in the pad
    sim.apply(_command('PSM2', T, 0.3))
    sim.run(0.3)
    events = [e for e in sim.pop_events() if e.kind == 'collision']
    assert len(events) == 1 and events[0].data['arm'] == 'PSM2'
    assert events[0].data['depth'] > 0.002
    assert sim.score().collisions == 1


def test_jaws_held_in_the_pad_touch_once_and_again_after_leaving_it(sim):
    T = sim.tool_pose('PSM2').copy()
    for z, seconds in ((0.004, 0.3), (0.004, 0.3), (0.03, 0.5), (0.004, 0.5)):
        T[:3, 3] = [0.02, 0.0, z]
        sim.apply(_command('PSM2', T, 0.3))
        sim.run(seconds)
    events = [e for e in sim.pop_events() if e.kind == 'collision']
    assert [e.data['arm'] for e in events] == ['PSM2', 'PSM2']
    assert events[1].t > events[0].t + 0.5
    assert sim.score().collisions == 2


def test_nan_and_inf_targets_are_rejected_by_the_arm(sim):
    before = sim.arms['PSM2'].setpoint_jp
    bad = sim.tool_pose('PSM2').copy()
    bad[0, 3] = np.nan
    sim.apply(_command('PSM2', bad))
    bad[0, 3] = np.inf
    sim.apply(_command('PSM2', bad, np.inf))
    sim.run(0.05)
    errors = [e for e in sim.arms['PSM2'].pop_events() if e.kind == 'error']
    assert len(errors) >= 2
    assert np.array_equal(sim.arms['PSM2'].setpoint_jp, before)


def _trajectory(config, seed):
    sim = Simulation(config, rng=np.random.default_rng(seed))
    sim.enable_and_home_all()
    expert = ScriptedExpert(sim.target_pair, sim.needle_geometry, config.scene.expert,
                            kinematics=sim.kinematics['PSM2'])
    poses = []
    for _ in range(360):  # pick and carry with the real arm tracking, then drop it
        sim.apply(expert.step(sim.observation()))
        for _ in range(5):
            sim.step()
            poses.append(sim.needle_pose())
    sim.apply(_command('PSM2', jaw=0.8))
    for _ in range(300):
        sim.step()
        poses.append(sim.needle_pose())
    kinds = _kinds(sim.pop_events())
    sim.close()
    return np.array(poses), kinds


def test_the_same_seed_gives_bit_identical_needle_trajectories(config):
    a, kinds_a = _trajectory(config, 5)
    b, kinds_b = _trajectory(config, 5)
    assert 'grasp' in kinds_a and 'drop' in kinds_a
    assert np.array_equal(a, b) and kinds_a == kinds_b
    c, _ = _trajectory(config, 6)
    assert not np.allclose(a[0], c[0])


def test_reset_with_a_seed_starts_the_same_scene_again(exact_config):
    sim = Simulation(exact_config)
    sim.reset(seed=3)
    first = sim.needle_pose()
    sim.enable_and_home_all()
    _hold_needle_in_the_air(sim)
    sim.reset(seed=3)
    assert np.array_equal(sim.needle_pose(), first)
    assert sim.time == 0.0 and sim.grasp.holders == () and sim.pop_events() == []
    assert sim.arms['PSM1'].operating_state.state == 'DISABLED'
    sim.close()


def test_the_endoscope_sees_the_markers_where_the_intrinsics_put_them(sim):
    frame = sim.render()
    h, w = sim.camera.config.height, sim.camera.config.width
    assert frame.left_rgb.shape == (h, w, 3) and frame.right_depth.shape == (h, w)
    for name, T in sim.marker_poses().items():
        for rgb, T_cam in ((frame.left_rgb, frame.T_world_left),
                           (frame.right_rgb, frame.T_world_right)):
            u, v = sim.camera.project(T[:3, 3], T_cam)[0]
            patch = rgb[int(round(v)) - 1:int(round(v)) + 2, int(round(u)) - 1:int(round(u)) + 2]
            red = patch[..., 0].astype(int) - patch[..., 1].astype(int)
            assert red.min() > 80, name
    # depth at the pad centre is the distance along the optical axis to the pad
    centre = sim.camera.project(np.zeros(3), frame.T_world_left)[0]
    z = (np.linalg.inv(frame.T_world_left) @ np.array([0.0, 0.0, 0.0, 1.0]))[2]
    d = frame.left_depth[int(round(centre[1])), int(round(centre[0]))]
    assert d == pytest.approx(z, abs=1e-3)


def test_ground_truth_getters_agree_with_the_scene(sim):
    markers = sim.marker_poses()
    assert sorted(markers) == sorted(f'synth{i}.{k}' for i in range(1, 5)
                                     for k in ('entry', 'exit'))
    pair = sim.phantom.markers['synth2']
    T = markers['synth2.entry']
    assert np.allclose(T[:3, 3], pair.entry)
    assert np.dot(T[:3, 0], pair.exit - pair.entry) > 0.0
    assert np.allclose(sim.phantom_pose(), np.eye(4))
    base = sim.T_world_base('PSM2')
    assert np.allclose(sim.tool_pose('PSM2'), base @ sim.arms['PSM2'].local_measured_cp)
    thread = sim.thread_points()
    tail = sim.needle_pose() @ np.append(sim.needle_geometry.tail, 1.0)
    assert np.allclose(thread[0], tail[:3], atol=1e-9)
    lengths = np.linalg.norm(np.diff(thread, axis=0), axis=1)
    assert np.allclose(lengths, sim.thread_geometry.length / sim.thread_geometry.n_segments)


def test_the_scanned_phantom_and_a_user_mesh_can_be_chosen(config, tmp_path):
    scanned = Simulation(config, phantom='scanned')
    assert sorted(scanned.phantom.markers) == ['scan1', 'scan2', 'scan3', 'scan4']
    # the needle starts on the curved pad where it was dropped, not slid off onto the table
    start = config.loop.needle_start
    for seed in range(4):
        scanned.reset(seed=seed)
        T = scanned.needle_pose()
        assert np.linalg.norm(T[:2, 3] - start.position) < 2 * start.position_jitter + 0.003
        wire = scanned.needle_geometry.points_world(T, 24)
        gap = wire[:, 2] - scanned.world.support_height(wire[:, :2])
        assert gap.min() == pytest.approx(0.5 * scanned.needle_geometry.wire_diameter,
                                          abs=3e-4)
        assert T[2, 2] > 0.8  # lying on its side, not upside down
    path = tmp_path / 'pad.stl'
    scanned.phantom.mesh.export(str(path))
    scanned.close()
    user = Simulation(config, phantom=path)
    assert len(user.phantom.markers) == 4
    assert user.needle_mode == 'resting'
    user.close()
    with pytest.raises(ValueError, match='STL, OBJ or PLY'):
        Simulation(config, phantom='no-such-phantom')


@pytest.mark.parametrize('seed', [1011, 1031])
def test_a_needle_at_rest_on_the_scanned_pad_lies_on_the_tissue_not_in_it(exact_config, seed):
    # with the batch runs' 10 ms step these seeds used to settle the needle with its tip 0.15 mm
    # inside the tissue model: picking it up then counted an exit puncture and trauma
    config = replace(exact_config, world=replace(exact_config.world, physics_step=0.01))
    sim = Simulation(config, phantom='scanned')
    try:
        sim.reset(seed)
        sim.enable_and_home_all()
        gap = 0.5 * sim.needle_geometry.wire_diameter
        assert sim.tissue.wire_depth(sim.needle_pose()) <= -gap + 1e-4
        sim.step()
        assert not sim.tissue.tip_inside and not sim.tissue.in_tissue
        sim.pop_events()
        _hold_needle_in_the_air(sim)
        kinds = _kinds(sim.pop_events())
        assert 'grasp' in kinds
        assert not {'entry', 'exit', 'trauma', 'withdrawn'} & set(kinds), kinds
        assert sim.tissue.punctures == []
    finally:
        sim.close()


def test_arms_at_rest_power_up_then_home_with_the_dvrk_timings(config):
    rest = {'psm_rest_jp': (0.0,) * 6, 'ecm_rest_jp': (0.0,) * 4}
    sim = Simulation(replace(config, arm=ArmConfig(power_up_time=0.5), **rest))
    try:
        for name, arm in sim.arms.items():
            assert arm.operating_state.state == 'DISABLED'
            assert arm.measured_jp[2] == 0.0, name  # instrument and endoscope retracted
        sim.enable_and_home_all()
        # the power-up, then the slowest homing: the ECM's 12 cm at 60 mm/s and 60 mm/s^2
        assert sim.time == pytest.approx(0.5 + 3.0, abs=0.05)
        for arm in sim.arms.values():
            assert arm.operating_state.is_homed and arm.measured_jp[2] == pytest.approx(0.12)
        sim.reset()
        assert all(arm.measured_jp[2] == 0.0 for arm in sim.arms.values())
    finally:
        sim.close()
