"""
The dVRK preset's sensor-side imperfections (sim_bridge.realism): encoders, the ECM, the endoscope.

Real PyBullet scenes at the ``dvrk`` preset: ``measured_js`` is the motor-side joints on the
encoders' counts plus their noise (and ``measured_cp`` follows it); the ECM reports a camera
pose off the true one by the cited ~2 mm; ``camera_info`` reports intrinsics off the render's
by the cited amount; each at level 0 leaves the rest of the model exactly as it was.
"""


import numpy as np
from sim_bridge.control import Command
from sim_bridge.realism.calibration import draw_intrinsics_error, load_arm_realism
from test_realism_arm import dvrk_scene

NEW_OFF = {'encoder_level': 0.0, 'ecm_level': 0.0, 'intrinsics_level': 0.0}


def test_measured_js_is_the_motor_side_joints_on_the_encoder_counts_plus_noise():
    preset = load_arm_realism('dvrk')
    count = np.asarray(preset.encoder.psm)
    sim = dvrk_scene(3)
    try:
        arm = sim.arms['PSM1']
        residuals = []
        for _ in range(200):
            sim.step()
            q, reported = arm.measured_jp, sim.reported_jp('PSM1')
            # read twice within one step: the same sample
            assert np.array_equal(reported, sim.reported_jp('PSM1'))
            residuals.append((reported - q) / count)
        r = np.array(residuals)
        # quantisation (uniform, sd 1/sqrt(12) count) plus 0.5 count of noise: ~0.58 count
        sd = r.std(axis=0)
        assert np.all((sd > 0.4) & (sd < 0.8)), sd
        assert np.all(np.abs(r) < 4.0)
        # the arm at rest: its reading still changes from step to step (the noise)
        assert np.any(r[1:] != r[:-1])
        # measured_cp is the FK of what the encoders read, not of the motor side
        T = sim.reported_tool_pose('PSM1')
        assert 0.0 < np.linalg.norm(T[:3, 3] - (sim.believed_base('PSM1')
                                                 @ arm.local_measured_cp)[:3, 3]) < 1e-4
    finally:
        sim.close()


def test_the_ecm_reports_a_camera_pose_off_the_true_one_by_the_cited_order():
    errors = []
    for seed in range(4):
        sim = dvrk_scene(seed, levels={'encoder_level': 0.0})
        try:
            true, reported = sim.camera_pose(), sim.reported_tool_pose('ECM')
            R = true[:3, :3].T @ reported[:3, :3]
            angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
            errors.append((np.linalg.norm(true[:3, 3] - reported[:3, 3]), angle))
        finally:
            sim.close()
    e = np.array(errors)
    # Shademan et al. 2016: 1.57 +- 0.90 mm hand-eye; dVRK camera registration 5-10 mm cube
    assert 0.5e-3 < e[:, 0].mean() < 5e-3, e
    assert 0.1 < e[:, 1].mean() < 2.0, e


def test_camera_info_reports_intrinsics_off_the_renders_by_the_cited_amount():
    preset = load_arm_realism('dvrk')
    sim = dvrk_scene(5, levels={'encoder_level': 0.0, 'ecm_level': 0.0})
    try:
        camera = sim.camera
        K_true, baseline = camera.K, camera.config.baseline
        left, right = camera.camera_info('left'), camera.camera_info('right')
        fx, fy = left.K[0, 0] / K_true[0, 0] - 1.0, left.K[1, 1] / K_true[1, 1] - 1.0
        focal = preset.intrinsics.focal
        assert 0.0 < abs(fx) <= focal and 0.0 < abs(fy) <= focal
        d = left.K[:2, 2] - K_true[:2, 2]
        assert np.all(np.abs(d) <= preset.intrinsics.principal_point) and np.any(d != 0.0)
        b = -right.P[0, 3] / right.P[0, 0]
        assert 0.0 < abs(b / baseline - 1.0) <= preset.intrinsics.baseline
        # the render keeps the true intrinsics
        assert np.array_equal(camera.lens.K, K_true)
        assert np.array_equal(camera.T_tip_right[:3, 3], [0.5 * baseline, 0.0, 0.0])
        # seeded
        assert draw_intrinsics_error(preset, 5) == draw_intrinsics_error(preset, 5)
        assert draw_intrinsics_error(preset, 5) != draw_intrinsics_error(preset, 6)
    finally:
        sim.close()


def test_with_the_new_levels_zero_the_preset_is_the_model_without_them():
    runs = []
    for levels in (NEW_OFF, {'encoder_level': 0.0}, None):
        sim = dvrk_scene(2, levels=levels)
        try:
            goal = sim.reported_tool_pose('PSM1')
            goal[:3, 3] += [0.01, -0.005, 0.004]
            sim.apply(Command(t=sim.time, T_world_tool={'PSM1': goal}, jaw={}, subtask='i'))
            sim.run(0.7)
            runs.append({'tool': sim.tool_pose('PSM1'), 'q': sim.arms['PSM1'].measured_jp,
                         'reported_q': sim.reported_jp('PSM1'),
                         'camera': sim.camera_pose(), 'ecm': sim.reported_tool_pose('ECM'),
                         'info': sim.camera.camera_info('right').P,
                         'offset': sim.physics.errors['PSM1'].joint_offset.copy()})
        finally:
            sim.close()
    off = runs[0]
    assert np.array_equal(off['q'], off['reported_q'])  # no encoders
    assert np.array_equal(off['camera'], off['ecm'])  # the ECM reports where it is
    assert np.array_equal(off['info'][:, :3], sim.camera.K)  # the true calibration
    # the PSMs' own draws are the same whatever the new levels (their own streams)
    for other in runs[1:]:
        assert np.array_equal(off['offset'], other['offset'])
    # without encoders the PSM's motion is the same with or without the ECM/intrinsics errors
    assert np.array_equal(off['tool'], runs[1]['tool'])


def test_the_simulators_measured_js_and_measured_cp_are_what_the_encoders_read():
    from sim_bridge.nodes.crtk_arm import ArmSnapshot  # the simulator node's state publication
    sim = dvrk_scene(1)
    try:
        sim.run(0.05)
        arm = sim.arms['PSM2']
        state = ArmSnapshot(arm, lambda: sim.reported_jp('PSM2'))
        assert np.array_equal(state.measured_jp, sim.reported_jp('PSM2'))
        assert not np.array_equal(state.measured_jp, arm.measured_jp)
        assert np.allclose(sim.believed_base('PSM2') @ state.local_measured_cp,
                           sim.reported_tool_pose('PSM2'), atol=1e-12)
        # without encoders: the arm's own
        assert np.array_equal(ArmSnapshot(arm).measured_jp, arm.measured_jp)
    finally:
        sim.close()


def test_a_jaw_closed_on_the_needle_reads_where_its_motors_stalled_not_its_command():
    jaw = load_arm_realism('dvrk').jaw
    sim = dvrk_scene(4)
    try:
        sim.attach_needle('PSM2')
        for arm in ('PSM1', 'PSM2'):   # both grip as a client does, PSM1 on nothing
            sim.apply(Command(t=sim.time, T_world_tool={}, jaw={arm: -0.349066}, subtask='i'))
        sim.run(1.0)
        assert sim.grasp.holders == ('PSM2',)
        held = sim.arms['PSM2']
        angle, velocity = sim.reported_jaw('PSM2')
        assert held.jaw_setpoint_jp == held.jaw_measured_jp == -0.349066
        # stalled on the wire short of the -20 deg command, a fifth of the rest beyond it
        assert abs(angle - (jaw.stall + jaw.compliance * (-0.349066 - jaw.stall))) < 1e-12
        assert abs(angle - held.jaw_setpoint_jp) > 0.19 and velocity == 0.0
        # the grasp holds all the same: it reads the jaws themselves
        assert angle <= sim.config.grasp.close_angle
        # a jaw on nothing reads its angle, its command
        assert sim.reported_jaw('PSM1') == (sim.arms['PSM1'].jaw_measured_jp, 0.0) \
            and sim.arms['PSM1'].jaw_measured_jp == -0.349066
    finally:
        sim.close()
    # level 0: every jaw reads its own angle, bit for bit
    sim = dvrk_scene(4, levels={'jaw_level': 0.0})
    try:
        sim.attach_needle('PSM2')
        sim.apply(Command(t=sim.time, T_world_tool={}, jaw={'PSM2': -0.349066}, subtask='i'))
        sim.run(1.0)
        assert sim.grasp.holders == ('PSM2',)
        assert sim.reported_jaw('PSM2') == (sim.arms['PSM2'].jaw_measured_jp,
                                            sim.arms['PSM2'].jaw_measured_jv)
        assert not sim.physics.has_jaw_stall
    finally:
        sim.close()
