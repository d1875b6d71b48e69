import numpy as np
import pytest
from sim_bridge.common.geometry import (
    compose_poses,
    invert_pose,
    quaternion_from_rotvec,
    quaternion_product,
    quaternion_rotate,
)
from sim_bridge.common.needle import NeedleGeometry
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.demos.synthetic_throw import minimum_jerk
from suture_lfd.segmentation import (
    SegmentationConfig,
    activity,
    segment_demonstration,
    velocity_keypoints,
)

RATE_HZ = 200.0
TOLERANCE_S = 0.050


def arm_track(T, start_pose, motions):
    """Poses (n, 7) of an arm doing minimum-jerk motions (start, duration, dp, rotvec)."""
    P = np.tile(start_pose[:3], (T.size, 1))
    Q = np.tile(start_pose[3:], (T.size, 1))
    for start, duration, dp, rotvec in motions:
        m = minimum_jerk(np.clip((T - start) / duration, 0.0, 1.0))
        P = P + m[:, None] * np.asarray(dp)
        Q = quaternion_product(quaternion_from_rotvec(m[:, None] * np.asarray(rotvec)), Q)
    return np.hstack((P, Q))


def synthetic_demonstration(rng, noise_m=10e-6, noise_rad=1e-4, split_insertion=False):
    """
    A five-subtask demonstration with known boundaries (s), jittered by rng.

    ``split_insertion``: the insertion is two motions with a rest between them, the first
    pushing the tip 4 mm into the tissue (as a person who pauses while inserting); the pair's
    surface is then put 0.1 mm above the tip at the start of the insertion. ``'out'``: a third
    motion follows, which starts with the tip already out of the exit (a person who pulls the
    needle on a little after it came out). ``'shallow'``: the first motion stops with the tip
    0.45 mm deep, just short of ``entered_depth``, and the second one goes on down.
    """
    def jitter(value, spread=0.1):
        return value + rng.uniform(-spread, spread)

    t = 0.5
    schedule = {}
    psm1, psm2 = [], []

    def move(arm, duration, dp, rotvec=(0.0, 0.0, 0.0), rest=0.4):
        nonlocal t
        start = t
        arm.append((start, duration, dp, rotvec))
        t = start + duration + jitter(rest, 0.1)
        return start, start + duration

    a0, a1 = move(psm2, jitter(1.2), (0.02, 0.01, -0.015), (0.0, 0.3, 0.1), rest=0.5)
    grasp2 = a1 + 0.2
    b0, b1 = move(psm2, jitter(1.5), (-0.01, 0.02, -0.01), (0.2, 0.0, -0.2), rest=0.5)
    schedule['i'] = (a0, b1)
    if split_insertion:
        dive = -0.00035 if split_insertion == 'shallow' else -0.004
        push, _ = move(psm2, 0.8, (0.0, -0.004, dive), (0.0, 0.0, 0.5), rest=0.5)
        rise = {'out': 0.0045, 'shallow': -0.002}.get(split_insertion, 0.002)  # 'out': 0.4 mm up
        schedule['ii'] = (push, move(psm2, jitter(2.0), (0.003, -0.012, rise),
                                     (0.0, 0.0, 2.6))[1])
        if split_insertion == 'out':
            schedule['ii'] = (push, move(psm2, 0.6, (0.002, -0.003, 0.002))[1])
    else:
        schedule['ii'] = move(psm2, jitter(2.0), (0.003, -0.012, 0.002), (0.0, 0.0, 2.6))
    c0, c1 = move(psm1, jitter(1.2), (-0.015, -0.02, -0.01), (0.1, 0.2, 0.0), rest=0.5)
    regrasp, release = c1 + 0.15, c1 + 0.3
    schedule['iii'] = (c0, release)
    t = release + jitter(0.3, 0.05)
    psm2.append((release + 0.05, 0.5, (0.0, 0.0, 0.008), (0.0, 0.0, 0.0)))  # PSM2 backs off
    schedule['iv'] = move(psm1, jitter(1.6), (0.004, -0.01, 0.015), (0.0, 0.0, 1.8), rest=0.5)
    d0, d1 = move(psm2, jitter(1.0), (0.01, 0.0, 0.01), (0.0, 0.1, 0.0), rest=0.5)
    handover, letgo = d1 + 0.15, d1 + 0.3
    e0, e1 = move(psm2, jitter(1.5), (0.02, 0.02, 0.01), (0.3, 0.0, 0.0), rest=0.6)
    psm1.append((e0 + 0.1, 0.8, (-0.02, 0.0, 0.01), (0.0, 0.0, 0.0)))          # PSM1 backs off
    schedule['v'] = (d0, e1)

    T = np.arange(0.0, t, 1.0 / RATE_HZ)
    pose1 = arm_track(T, np.array([-0.03, 0.0, 0.05, 0.0, 0.0, 0.0, 1.0]), psm1)
    pose2 = arm_track(T, np.array([0.03, 0.0, 0.05, 0.0, 0.0, 0.0, 1.0]), psm2)
    for pose in (pose1, pose2):
        pose[:, :3] += rng.normal(0.0, noise_m, (T.size, 3))
        pose[:, 3:] = quaternion_product(
            quaternion_from_rotvec(rng.normal(0.0, noise_rad, (T.size, 3))), pose[:, 3:])
    holds2 = (T >= grasp2) & ((T < release) | (T >= handover))
    holds1 = (T >= regrasp) & (T < letgo)
    # the needle rides on PSM2, then on PSM1 from the release, then on PSM2 again
    k_release, k_handover = np.searchsorted(T, release), np.searchsorted(T, handover)
    needle = compose_poses(pose2, [0.0, 0.005, 0.0, 0.0, 0.0, 0.0, 1.0])
    grip1 = compose_poses(invert_pose(pose1[k_release]), needle[k_release])
    needle[k_release:] = compose_poses(pose1[k_release:], grip1)
    grip2 = compose_poses(invert_pose(pose2[k_handover]), needle[k_handover])
    needle[k_handover:] = compose_poses(pose2[k_handover:], grip2)
    entry = np.zeros(3)
    if split_insertion:
        k = np.searchsorted(T, schedule['ii'][0])
        entry = needle[k, :3] + quaternion_rotate(needle[k, 3:], NeedleGeometry().tip)
        entry[2] += 0.0001
    demo = Demonstration(
        t=T, psm1_pose=pose1, psm2_pose=pose2,
        psm1_jaw=np.where(holds1, 0.0, 0.6), psm2_jaw=np.where(holds2, 0.0, 0.6),
        needle_pose=needle, psm1_holds=holds1, psm2_holds=holds2,
        entry=entry, exit=entry + [0.01, 0.0, 0.0], normal=[0.0, 0.0, 1.0], pair='synth1')
    return demo, schedule


def test_segmentation_recovers_the_five_subtask_boundaries_within_50_ms():
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(6):
        demo, truth = synthetic_demonstration(rng)
        found = segment_demonstration(demo)
        for name, (start, end) in truth.items():
            subtask = found[name]
            worst = max(worst, abs(subtask.start_time - start), abs(subtask.end_time - end))
            assert abs(subtask.start_time - start) < TOLERANCE_S, (name, subtask, start)
            assert abs(subtask.end_time - end) < TOLERANCE_S, (name, subtask, end)
            assert abs(demo.t[subtask.start_index] - subtask.start_time) <= 0.5 / RATE_HZ + 1e-9
    assert worst < TOLERANCE_S


def test_an_insertion_paused_with_the_tip_in_the_tissue_starts_where_the_tip_entered():
    rng = np.random.default_rng(11)
    for _ in range(3):
        demo, truth = synthetic_demonstration(rng, split_insertion=True)
        found = segment_demonstration(demo)
        for name in ('i', 'ii'):
            start, end = truth[name]
            assert abs(found[name].start_time - start) < TOLERANCE_S, (name, found[name], start)
            assert abs(found[name].end_time - end) < TOLERANCE_S, (name, found[name], end)
        # without the depth rule, the insertion would be its last motion only
        blind = segment_demonstration(demo, SegmentationConfig(entered_depth=1.0))
        assert blind['ii'].start_time > truth['ii'][0] + 1.0


def test_subtasks_come_in_order_and_do_not_overlap():
    demo, _ = synthetic_demonstration(np.random.default_rng(3))
    bounds = segment_demonstration(demo).boundaries()
    assert bounds.shape == (5, 2)
    assert np.all(bounds[:, 1] > bounds[:, 0])
    assert np.all(bounds[1:, 0] >= bounds[:-1, 1])


def test_jaw_angles_stand_in_for_missing_grasp_flags():
    demo, truth = synthetic_demonstration(np.random.default_rng(4))
    blind = Demonstration(**{**demo.__dict__, 'psm1_holds': np.zeros(demo.n, bool),
                             'psm2_holds': np.zeros(demo.n, bool)})
    found = segment_demonstration(blind)
    assert abs(found['iii'].end_time - truth['iii'][1]) < TOLERANCE_S


def test_a_demonstration_without_regrasp_is_rejected_naming_the_signal():
    demo, _ = synthetic_demonstration(np.random.default_rng(5))
    no_regrasp = Demonstration(**{**demo.__dict__, 'psm1_holds': np.zeros(demo.n, bool),
                                  'psm1_jaw': np.full(demo.n, 0.6)})
    with pytest.raises(ValueError, match='psm1_holds'):
        segment_demonstration(no_regrasp)


def test_a_single_minimum_jerk_motion_gives_one_keypoint_pair_at_its_ends():
    T = np.arange(0.0, 4.0, 1.0 / RATE_HZ)
    m = minimum_jerk(np.clip((T - 1.0) / 2.0, 0.0, 1.0))
    P = m[:, None] * np.array([0.03, -0.01, 0.02])
    motions = velocity_keypoints(T, P)
    assert len(motions) == 1
    assert abs(motions[0].start_time - 1.0) < 0.02
    assert abs(motions[0].end_time - 3.0) < 0.02


def test_short_rests_are_bridged_and_short_twitches_dropped():
    T = np.arange(0.0, 6.0, 1.0 / RATE_HZ)
    P = np.zeros((T.size, 3))
    for start, duration, dx in ((0.5, 1.5, 0.02), (2.05, 1.5, 0.02), (4.5, 0.08, 0.0005)):
        P[:, 0] += dx * minimum_jerk(np.clip((T - start) / duration, 0.0, 1.0))
    config = SegmentationConfig(min_rest_s=0.2, min_motion_s=0.35)
    motions = velocity_keypoints(T, P, config=config)
    assert len(motions) == 1
    assert motions[0].start_time < 0.6 and motions[0].end_time > 3.4


def test_activity_is_zero_phase_filtered():
    T = np.arange(0.0, 4.0, 1.0 / RATE_HZ)
    m = minimum_jerk(np.clip((T - 1.0) / 2.0, 0.0, 1.0))
    a = activity(T, m[:, None] * np.array([0.02, 0.0, 0.0]))
    assert abs(T[np.argmax(a)] - 2.0) < 0.01   # the speed peak stays in the middle


def test_segmentation_config_rejects_nonsense():
    with pytest.raises(ValueError, match='threshold'):
        SegmentationConfig(threshold=1.5)
    with pytest.raises(ValueError, match='cutoff_hz'):
        SegmentationConfig(cutoff_hz=0.0)


@pytest.mark.parametrize('split', ['out', 'shallow'])
def test_an_insertion_whose_last_motion_starts_out_of_the_exit_starts_where_the_tip_entered(
        split):
    # a person under a lagging teleoperation pulls the needle on after its tip came out, or
    # pauses with the tip just short of entered_depth: the insertion starts where it went in
    rng = np.random.default_rng(12)
    for _ in range(3):
        demo, truth = synthetic_demonstration(rng, split_insertion=split)
        found = segment_demonstration(demo)
        for name in ('i', 'ii'):
            start, end = truth[name]
            assert abs(found[name].start_time - start) < TOLERANCE_S, (name, found[name], start)
            assert abs(found[name].end_time - end) < TOLERANCE_S, (name, found[name], end)
