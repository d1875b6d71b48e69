"""
Perception sees the needle and the markers from the stereo pair alone.

Every scene is rendered by the simulator, its two images written to PNG files and read back, and
the calibration passed as the plain numbers of ``camera_info``: the code under test gets nothing
else of the simulation. Bounds are set from ``bench/bench_perception.py``'s measurements with a
margin (its median summed error of a found needle is about 1 mm; the largest point error of a
found estimate stays under 3 mm).
"""

from dataclasses import replace
import math

import cv2
import numpy as np
import pytest
from suture_lfd.perception import (
    HeldView,
    NeedleTracker,
    StereoPerception,
    detect_markers,
    estimate_grasp,
    needle_prior,
    stereo_from_camera_info,
)
from suture_lfd.perception.arc_stereo import arc_distances, centre_line_points, fit_arc_to_points
from suture_lfd.perception.evaluation import SceneMaker, needle_errors, perturbed
from suture_lfd.perception.markers import pair_normal
from suture_lfd.perception.wire_images import WireImage


def on_disk(scene, tmp_path):
    """The scene's images as PNG files read back, and camera_info as plain numbers."""
    images = []
    for side, rgb in (('left', scene.left), ('right', scene.right)):
        path = tmp_path / f'{side}.png'
        assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        images.append(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB))
    infos = [{'width': i.width, 'height': i.height, 'K': i.K.ravel().tolist(),
              'P': i.P.ravel().tolist()} for i in scene.camera_info]
    return images[0], images[1], stereo_from_camera_info(*infos)


@pytest.fixture(scope='module')
def synthetic():
    maker = SceneMaker('synthetic')
    yield maker
    maker.close()


@pytest.fixture(scope='module')
def scanned():
    maker = SceneMaker('scanned')
    yield maker
    maker.close()


def scenes(maker, kind, n, seed, **kwargs):
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        scene = maker.scene(kind, rng, **kwargs)
        if scene is not None:
            out.append((scene, rng))
    return out


def estimate_resting(scene, tmp_path):
    """The default tracker's estimate of a resting needle, and its errors (total, max, angle)."""
    left, right, stereo = on_disk(scene, tmp_path)
    markers = detect_markers(left, right, stereo)
    tracker = NeedleTracker()
    est = tracker.estimate(left, right, stereo, support_normal=markers.normal)
    assert est.found, est.reason
    return est, needle_errors(est.pose_camera, scene.T_camera_needle, tracker.geometry)


@pytest.mark.parametrize('phantom', ['synthetic', 'scanned'])
def test_markers_are_found_triangulated_and_paired_along_the_wound(phantom, request, tmp_path):
    maker = request.getfixturevalue(phantom)
    (scene, _), = scenes(maker, 'free', 1, seed=3)
    left, right, stereo = on_disk(scene, tmp_path)
    markers = detect_markers(left, right, stereo)
    assert markers.n_pairs == 4
    for found, true in ((markers.entries, scene.entries), (markers.exits, scene.exits)):
        errors = np.linalg.norm(found - true, axis=1)  # NaN (not seen) fails too
        assert errors.max() < 0.0008, errors  # measured: at most 0.45 mm in view of the thread
        assert np.median(errors) < 0.0004
    assert markers.normal[2] < -0.5  # the tissue faces the camera


def test_a_pairs_normal_from_its_and_its_neighbours_dots_follows_the_curved_pad(scanned,
                                                                               tmp_path):
    # the plane of all the dots is 3-5 degrees off the outer pairs' surface on the scanned pad
    scene = scanned.resting(0)
    left, right, stereo = on_disk(scene, tmp_path)
    found = detect_markers(left, right, stereo)
    sim = scanned.sim
    T_camera_world = scene.T_camera_needle @ np.linalg.inv(sim.needle_pose())
    pairs = sorted(sim.phantom.markers.values(), key=lambda p: p.index)
    assert found.n_pairs == len(pairs)
    off_all, off_local = [], []
    for i, pair in enumerate(pairs):
        true = T_camera_world[:3, :3] @ pair.normal
        local = pair_normal(found.entries, found.exits, i, found.normal)
        assert abs(np.linalg.norm(local) - 1.0) < 1e-9 and local @ found.normal > 0.0
        off_all.append(math.degrees(math.acos(min(1.0, abs(true @ found.normal)))))
        off_local.append(math.degrees(math.acos(min(1.0, abs(true @ local)))))
    # measured: 4.0, 1.3, 3.2, 5.5 degrees -> 1.3, 0.9, 2.0, 1.6
    assert max(off_local) < 2.5 and max(off_all) > 4.0, (off_all, off_local)


def test_markers_of_a_users_mesh_are_found(tmp_path):
    from test_user_mesh import scanned_pad  # the user mesh of the phantom tests
    pad = scanned_pad(tmp_path / 'pad.obj')
    maker = SceneMaker(pad)
    try:
        (scene, _), = scenes(maker, 'free', 1, seed=0)
    finally:
        maker.close()
    left, right, stereo = on_disk(scene, tmp_path)
    markers = detect_markers(left, right, stereo)
    assert markers.n_pairs == len(scene.entries) == 4
    errors = np.linalg.norm(np.vstack([markers.entries - scene.entries,
                                       markers.exits - scene.exits]), axis=1)
    assert errors.max() < 0.0008, errors


@pytest.mark.parametrize('phantom', ['synthetic', 'scanned'])
def test_a_needle_lying_free_is_detected_without_a_prior_or_said_ambiguous(phantom, request,
                                                                           tmp_path):
    maker = request.getfixturevalue(phantom)
    tracker = NeedleTracker()
    found = 0
    for scene, _ in scenes(maker, 'free', 3, seed=11):
        left, right, stereo = on_disk(scene, tmp_path)
        markers = detect_markers(left, right, stereo)
        est = tracker.estimate(left, right, stereo, support_normal=markers.normal)
        if not est.found:
            assert est.reason  # says why: ambiguous, too little seen, a poor fit
            continue
        found += 1
        total, largest, angle = needle_errors(est.pose_camera, scene.T_camera_needle,
                                              tracker.geometry)
        assert largest < 0.003 and total < 0.005, (total, largest)  # never confident and wrong
        assert est.residual_px < 1.0 and est.visible_share > 0.8
    assert found >= 1


def test_a_needle_resting_into_the_pad_at_the_studys_physics_step_is_seen_as_one_wire(tmp_path):
    # At the study's 10 ms step the needle of this scene seed settles a few hundredths of a
    # millimetre into the pad, and the render shows the pad along the middle of part of the
    # wire: two thin lines 2-3 px apart. Read as two lines, half the arc had no edges and the
    # fit tilted 11.5 degrees and 2.6 mm off (a study's robot then scored 0).
    maker = SceneMaker('synthetic', physics_step=0.01)
    try:
        scene = maker.resting(1277661016)
        wire_radius = 0.5 * maker.geometry.wire_diameter
        resting_z = float(maker.sim.needle_pose()[2, 3])
    finally:
        maker.close()
    assert resting_z < wire_radius  # the case: the wire's centre lower than its radius
    est, (total, largest, angle) = estimate_resting(scene, tmp_path)
    # measured: 0.62 mm, 0.7 degrees, 90 % of the arc seen (before: 2.62 mm, 11.5, 40 %)
    assert largest < 0.0012 and math.degrees(angle) < 3.0, (largest, math.degrees(angle))
    assert est.visible_share > 0.8


def test_a_needle_lying_on_the_curved_pad_is_told_from_its_mirror_by_its_triangulated_ends(
        tmp_path):
    # On the scanned pad a lying needle and its tilt the other way across the line of sight
    # fit the images within 0.03-0.04 px: that was "ambiguous", so every physical throw there
    # stopped with "not seen: the needle". Their arc ends lie 1-1.5 mm apart in depth, and the
    # ends of the wire's pixels, triangulated, tell them apart.
    maker = SceneMaker('scanned', physics_step=0.01)
    tracker = NeedleTracker()
    try:
        for seed in (0, 1):  # the physical bench's scene seed, and another
            scene = maker.resting(seed)
            left, right, stereo = on_disk(scene, tmp_path)
            markers = detect_markers(left, right, stereo)
            est = tracker.estimate(left, right, stereo, support_normal=markers.normal)
            assert est.found, (seed, est.reason)
            total, largest, angle = needle_errors(est.pose_camera, scene.T_camera_needle,
                                                  tracker.geometry)
            # measured: 0.64 and 0.56 mm (the mirror 2.55 and 2.56 mm)
            assert largest < 0.0012, (seed, largest, math.degrees(angle))
            # without the ends the same images stay a tie
            off = NeedleTracker(config=replace(tracker.config, ends_margin=0.0))
            tie = off.estimate(left, right, stereo, support_normal=markers.normal)
            assert not tie.found and tie.reason.startswith('ambiguous'), (seed, tie.reason)
    finally:
        maker.close()


def test_a_lying_needle_smaller_in_view_than_two_instruments_is_still_detected(tmp_path):
    # A study's robot at the 3 mm class (error seed 1166009287): at home its instruments show
    # two metal blobs larger than the needle in the right image. Only the two largest blobs
    # were looked at, so its demonstrations failed with the needle never seen.
    maker = SceneMaker('synthetic', physics_step=0.01, kinematic_errors=(3.0, 1166009287))
    try:
        scene = maker.resting(1271076244)
    finally:
        maker.close()
    est, (total, largest, angle) = estimate_resting(scene, tmp_path)
    assert largest < 0.0012, (largest, math.degrees(angle))  # measured: 0.35 mm, 1.7 degrees


def test_a_lying_needle_whose_triangulated_start_is_far_off_is_found_from_its_blobs_laid_flat(
        tmp_path):
    # A study's robot and scene (error seed 400735080, scene seed 1110648719): the only start
    # triangulated from the blob's ends was tilted 53 degrees, every fit from it stayed over
    # the surface's 35 degrees, and the best of them was 8.5 mm off at the tip (the throw
    # grasped the needle where it was not and scored 0). Laid on the markers' plane, the
    # blob gives a start the edges refine onto the needle.
    maker = SceneMaker('synthetic', physics_step=0.01, kinematic_errors=(3.0, 400735080))
    try:
        scene = maker.resting(1110648719)
    finally:
        maker.close()
    left, right, stereo = on_disk(scene, tmp_path)
    markers = detect_markers(left, right, stereo)
    tracker = NeedleTracker()
    laid = tracker.estimate(left, right, stereo, support_normal=markers.normal,
                            support_point=markers.points.mean(axis=0))
    assert laid.found, laid.reason
    _, largest, angle = needle_errors(laid.pose_camera, scene.T_camera_needle, tracker.geometry)
    assert largest < 0.0008, (largest, math.degrees(angle))  # measured: 0.06 mm, 0.1 degrees
    # without the surface's point the same images give the far-off fit (the claim can fail)
    alone = tracker.estimate(left, right, stereo, support_normal=markers.normal)
    _, largest, _ = needle_errors(alone.pose_camera, scene.T_camera_needle, tracker.geometry)
    assert largest > 0.003, largest


def test_a_lying_needle_tied_with_a_pose_a_millimetre_away_is_taken_by_the_robot(tmp_path):
    # A study's robot on the scanned pad (error seed 692295364, scene seed 2081992995): the
    # needle and a pose 1.2 mm away fit the images alike and their ends do not tell them
    # apart. The tracker says so; the robot's perception takes the better fit (either lies
    # within a jaw's reach, and the grasp is fitted again once held), where before its
    # demonstrations recorded no needle at all.
    from suture_lfd.skill.perceived import PerceivedScene

    maker = SceneMaker('scanned', physics_step=0.01, kinematic_errors=(3.0, 692295364))
    try:
        scene = maker.resting(2081992995)
        left, right, stereo = on_disk(scene, tmp_path)
        markers = detect_markers(left, right, stereo)
        tracker = NeedleTracker()
        est = tracker.estimate(left, right, stereo, support_normal=markers.normal,
                               support_point=markers.points.mean(axis=0))
        assert not est.found and est.reason.startswith('ambiguous'), est.reason
        assert est.rival_distance < 0.0015, est.rival_distance
        _, largest, _ = needle_errors(est.pose_camera, scene.T_camera_needle, tracker.geometry)
        assert largest < 0.001, largest  # measured: 0.54 mm
        pair = maker.sim.phantom.markers['scan2']
        perceived = PerceivedScene('scan2', pair.index, maker.geometry)
        assert perceived.markers(maker.sim) is not None
        view = perceived.needle(maker.sim)
        assert view.T_world_needle is not None
        # checked against the truth here, in the test
        _, largest, _ = needle_errors(view.T_world_needle, maker.sim.needle_pose(),
                                      tracker.geometry)
        assert largest < 0.001, largest
    finally:
        maker.close()


def test_a_grasp_fitted_to_the_lying_and_the_turned_needle_together_sees_the_tilt(tmp_path):
    # On the scanned pad a lying needle seen nearly face on can be 10-15 degrees off in tilt
    # and fit its pair as well as the truth; the grasp taken from it then puts the tip 1-3 mm
    # off. PSM2 picks the needle up and turns it: one grasp, two pairs, fitted together.
    maker = SceneMaker('scanned', physics_step=0.01)
    tracker = NeedleTracker()
    before, after = [], []
    try:
        for seed in (0, 3, 6):
            lying = maker.resting(seed)
            left, right, stereo = on_disk(lying, tmp_path)
            markers = detect_markers(left, right, stereo)
            seen = tracker.estimate(left, right, stereo, support_normal=markers.normal,
                                    support_point=markers.points.mean(axis=0))
            assert seen.found, (seed, seen.reason)
            rng = np.random.default_rng(seed)
            G = maker.pick(rng)
            assert G is not None
            T_grasp = lying.T_camera_needle @ np.linalg.inv(G)  # the tool where it closes
            G0 = np.linalg.inv(T_grasp) @ seen.pose_camera  # the grasp from the lying needle
            frames = maker.held_frames(G, 1, rng)
            assert frames is not None
            turned = frames[0]
            T_tool = turned.tools['PSM2']
            views = [HeldView(left, right, T_grasp),
                     HeldView(*on_disk(turned, tmp_path)[:2], T_tool, (T_tool,))]
            fit = tracker.fit_grasp(views, stereo, G0)
            assert min(fit.visible_share) > 0.5 and max(fit.residual_px) < 0.5, fit
            before.append(needle_errors(T_tool @ G0, turned.T_camera_needle, tracker.geometry))
            after.append(needle_errors(T_tool @ fit.T_tool_needle, turned.T_camera_needle,
                                       tracker.geometry))
    finally:
        maker.close()
    largest_before = np.array([e[1] for e in before])
    largest_after = np.array([e[1] for e in after])
    # measured: 0.64, 1.16, 2.69 mm -> 0.12, 0.17, 0.51 mm (5.6, 6.5, 14.3 -> 0.7, 1.5, 6.1 deg)
    assert (largest_after < 0.0008).all(), largest_after
    assert (largest_after < largest_before).all(), (largest_before, largest_after)
    assert largest_before.max() > 0.002, largest_before  # the case: a tip 2 mm off


@pytest.mark.parametrize('phantom', ['synthetic', 'scanned'])
def test_a_held_needle_is_tracked_from_the_tool_pose_and_an_estimated_grasp(phantom, request,
                                                                            tmp_path):
    maker = request.getfixturevalue(phantom)
    tracker = NeedleTracker()
    results = []
    for scene, rng in scenes(maker, 'held', 3, seed=5, grasp_frames=3):
        # the grasp as known at the pick (1 mm, 5 deg off), refined from three frames
        G0 = perturbed(scene.grasps['PSM2'], rng, 0.001, math.radians(5.0))
        tools = [f.tools['PSM2'] for f in scene.history]
        ests = [tracker.estimate(*on_disk(f, tmp_path), prior=T @ G0, tools=[T])
                for f, T in zip(scene.history, tools)]
        grasp = estimate_grasp(tools, ests)
        assert grasp.n_frames >= 1
        assert np.linalg.norm(grasp.T_tool_needle[:3, 3] - scene.grasps['PSM2'][:3, 3]) < 0.001
        left, right, stereo = on_disk(scene, tmp_path)
        T_tool = scene.tools['PSM2']
        est = tracker.estimate(left, right, stereo, prior=needle_prior(T_tool, grasp),
                               tools=[T_tool])
        assert est.found, est.reason
        results.append(needle_errors(est.pose_camera, scene.T_camera_needle, tracker.geometry))
    total = np.array([r[0] for r in results])
    largest = np.array([r[1] for r in results])
    angle = np.degrees([r[2] for r in results])
    assert largest.max() < 0.003, largest
    assert np.median(total) < 0.0025 and np.median(angle) < 6.0, (total, angle)


def test_a_held_needle_carried_out_of_the_trackers_reach_is_found_again(synthetic, tmp_path):
    # an arm lifts the needle 5 mm between two processed pairs, more than a second apart (a
    # busy loop): the tracker's refinement does not reach that far, the last estimate is too
    # old to track from, and a needle in a jaw cannot be detected afresh
    rng = np.random.default_rng(11)
    found = 0
    for _ in range(3):
        scene = None
        while scene is None:
            scene = synthetic.scene('held', rng)
        grip = perturbed(scene.grasps['PSM2'], rng, 0.001, math.radians(5.0))
        looks = {reach: StereoPerception(markers=False, search_reach=reach) for reach in (0, 80)}
        for perception in looks.values():
            first = perception.process(*on_disk(scene, tmp_path), 0.0,
                                       prior=scene.tools['PSM2'] @ grip,
                                       tools=[scene.tools['PSM2']])
            assert first.needle.found, first.needle.reason
        lifted = synthetic.carry([0.0, 0.0, 0.005])
        left, right, stereo = on_disk(lifted, tmp_path)
        without = looks[0].process(left, right, stereo, 2.0)
        est = looks[80].process(left, right, stereo, 2.0)
        assert est.needle.found and est.tracked, est.needle.reason
        total, largest, angle = needle_errors(est.needle.pose_camera, lifted.T_camera_needle,
                                              synthetic.geometry)
        assert largest < 0.002 and angle < math.radians(8.0), (total, largest, angle)
        found += without.needle.found
    assert found < 3  # without the search, it is lost (the claim above can fail)


def test_the_wire_triangulated_row_by_row_lies_on_the_true_arc_and_fixes_its_plane(scanned,
                                                                                  tmp_path):
    geometry = NeedleTracker().geometry
    for scene, rng in scenes(scanned, 'free', 2, seed=3):
        left, right, stereo = on_disk(scene, tmp_path)
        masks = [WireImage(image, 1.0).mask for image in (left, right)]
        wire_px = geometry.wire_diameter * stereo.fx / scene.T_camera_needle[2, 3]
        points = centre_line_points(*masks, stereo, int(2.0 * wire_px) + 1)
        assert len(points) >= 20
        d = arc_distances(scene.T_camera_needle, points, geometry)
        assert np.median(d) < 0.0006, np.median(d)  # about half a pixel of disparity
        T0 = perturbed(scene.T_camera_needle, rng, 0.002, math.radians(10.0))
        fitted = fit_arc_to_points(T0, points, geometry)
        before = needle_errors(T0, scene.T_camera_needle, geometry)
        after = needle_errors(fitted, scene.T_camera_needle, geometry)
        assert after[1] < min(before[1], 0.0015) and after[2] < before[2], (before, after)


def test_a_partly_inserted_needle_uses_what_it_sees_and_says_so(synthetic, tmp_path):
    tracker = NeedleTracker()
    for scene, rng in scenes(synthetic, 'inserted', 2, seed=2, grasp_frames=3):
        G0 = perturbed(scene.grasps['PSM2'], rng, 0.001, math.radians(5.0))
        ests = [tracker.estimate(f.left, f.right, f.stereo, prior=f.tools['PSM2'] @ G0,
                                 tools=[f.tools['PSM2']]) for f in scene.history]
        grasp = estimate_grasp([f.tools['PSM2'] for f in scene.history], ests)
        left, right, stereo = on_disk(scene, tmp_path)
        T_tool = scene.tools['PSM2']
        est = tracker.estimate(left, right, stereo, prior=needle_prior(T_tool, grasp),
                               tools=[T_tool])
        if est.found:
            assert est.partial  # part of it is in the tissue or the jaw
            _, largest, _ = needle_errors(est.pose_camera, scene.T_camera_needle,
                                          tracker.geometry)
            assert largest < 0.003
        else:
            assert 'too little' in est.reason


def test_a_needle_hidden_from_one_eye_is_not_found(synthetic, tmp_path):
    tracker = NeedleTracker()
    (scene, _), = scenes(synthetic, 'free', 1, seed=3)
    left, right, stereo = on_disk(scene, tmp_path)
    assert tracker.estimate(left, right, stereo).found
    # cover the needle in the right image with the tissue around it
    from suture_lfd.perception.images import metal_mask
    hidden = right.copy()
    mask = cv2.dilate(metal_mask(right), np.ones((7, 7), np.uint8)) > 0
    mask[:, :200] = False  # (leave the instrument in the corner alone)
    hidden[mask] = np.median(right[(~mask) & (np.arange(right.shape[1]) > 300)[None, :]],
                             axis=0).astype(np.uint8)
    est = tracker.estimate(left, hidden, stereo)
    assert not est.found and est.reason
    # and with a prior (a held needle's) it says it sees too little of it
    est = tracker.estimate(left, hidden, stereo, prior=scene.T_camera_needle)
    assert not est.found and 'too little' in est.reason
    assert est.visible_right < 0.1 < est.visible_left


def test_bad_images_and_calibrations_get_a_clear_error(synthetic):
    (scene, _), = scenes(synthetic, 'free', 1, seed=3)
    stereo = scene.stereo
    tracker = NeedleTracker()
    with pytest.raises(ValueError, match='uint8'):
        tracker.estimate(scene.left.astype(np.float32), scene.right, stereo)
    with pytest.raises(ValueError, match=r'right image is 320x240 but camera_info says 640x480'):
        detect_markers(scene.left, scene.right[::2, ::2], stereo)
    with pytest.raises(ValueError, match=r'shape \(height, width, 3\)'):
        tracker.estimate(scene.left[:, :, 0], scene.right, stereo)
    with pytest.raises(ValueError, match='prior must be a finite 4x4'):
        tracker.estimate(scene.left, scene.right, stereo, prior=np.eye(3))
    left, right = scene.camera_info
    unrectified = {'width': 640, 'height': 480, 'K': right.K, 'P': right.P + 1.0}
    with pytest.raises(ValueError, match='not rectified'):
        stereo_from_camera_info(left, unrectified)
    with pytest.raises(ValueError, match='right camera_info P must carry -fx'):
        stereo_from_camera_info(left, left)
    with pytest.raises(ValueError, match='none of the 1 frames'):
        estimate_grasp([np.eye(4)], [tracker.estimate(scene.left, scene.left, stereo)])
