"""The needle in tissue: the needle turns in the jaw when pushed off its arc; the pad gives."""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.common.geometry import invert_transform
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.realism.tissue_realism import TissueRealism
from sim_bridge.scene.grasp import GraspManager
from sim_bridge.scene.scene_config import load_scene_config
from sim_bridge.scene.tissue import TissueTracker
from suture_lfd.planning.throw_geometry import ThrowArc

DT = 0.002


class Heard:
    def __init__(self):
        self.slips = []

    def on_slip(self, t, **data):
        self.slips.append(data)


@pytest.fixture(scope='module')
def scene():
    return load_scene_config()


@pytest.fixture(scope='module')
def phantom(scene):
    return scene.build_phantom('synthetic')


def _throw(scene, phantom, config, push, steps=200):
    """Insert along the arc to mid-bite, then move the tool ``push`` m off the arc in-plane."""
    needle = scene.needle
    tracker = TissueTracker(phantom, needle, scene.tissue)
    tracker.set_target_pair('synth1')
    grasp = GraspManager(load_default_grasp(), needle, ('PSM1', 'PSM2'))
    G = needle.T_tool_needle
    grasp.attach('PSM2', G)
    realism = TissueRealism(config, needle, phantom, grasp.jaw_point)
    heard = Heard()
    arc = ThrowArc(phantom.markers['synth1'], needle)
    mid = 0.5 * (arc.alpha_entry + arc.alpha_exit)
    tools = [arc.T_world_needle(a) @ invert_transform(G)
             for a in np.linspace(arc.alpha_entry + 0.2, mid, 300)]
    in_plane = np.cross(arc.plane_normal, [0.0, 0.0, 1.0])
    in_plane /= np.linalg.norm(in_plane)
    last = tools[-1]
    for k in range(1, steps + 1):
        T = last.copy()
        T[:3, 3] += push * min(1.0, k / (0.5 * steps)) * in_plane
        tools.append(T)
    prev = tools[0] @ G
    kinds = []
    T_needle = prev
    for k, T_tool in enumerate(tools):
        if grasp.leader is not None:
            T_needle = grasp.needle_pose(T_tool)
        T_needle = realism.step(k * DT, DT, grasp, tracker, lambda arm, T=T_tool: T,
                                T_needle, prev, True, heard)
        kinds += [e.kind for e in tracker.update(k * DT, T_needle)]
        prev = T_needle
    return realism, heard, kinds, tracker


def load_default_grasp():
    from sim_bridge.simulation_config import load_simulation_config
    return load_simulation_config().grasp


def test_a_throw_pushed_off_its_arc_turns_the_needle_more_with_more_push_and_less_grip(
        scene, phantom):
    tissue = load_tissue_realism('tissue')
    turned = {}
    for push in (0.0, 0.003, 0.006):
        for grip in (1.0, 1.25):
            realism, heard, kinds, _ = _throw(scene, phantom, replace(tissue, grip=grip), push)
            assert kinds[0] == 'entry'
            turned[push, grip] = abs(realism.grip.angle)
    # following its own arc, the grip holds (the puncture's push included); off it, the needle
    # turns in the jaw, more with more push and with a weaker grip (level 1.25: 80 % of the torque)
    assert turned[0.0, 1.0] == 0.0 and turned[0.0, 1.25] == 0.0
    assert turned[0.0, 1.0] < turned[0.003, 1.0] < turned[0.006, 1.0]
    assert turned[0.0, 1.25] < turned[0.003, 1.25] < turned[0.006, 1.25]
    assert turned[0.003, 1.0] < turned[0.003, 1.25]
    assert turned[0.006, 1.0] < turned[0.006, 1.25]
    assert turned[0.006, 1.0] > np.radians(5.0)


def test_a_slip_is_reported_once_per_episode_and_a_weld_never_slips(scene, phantom):
    tissue = load_tissue_realism('tissue')
    realism, heard, _, _ = _throw(scene, phantom, replace(tissue, grip=1.0), 0.006)
    assert heard.slips and all(s['arm'] == 'PSM2' for s in heard.slips)
    assert not any(s['broken'] for s in heard.slips)
    assert sum(s['angle'] for s in heard.slips) == pytest.approx(realism.grip.angle, abs=0.02)
    welded, heard, _, _ = _throw(scene, phantom, replace(tissue, grip=0.0), 0.012)
    assert welded.grip.angle == 0.0 and not heard.slips


def test_a_needle_turned_past_30_degrees_breaks_the_grasp(scene, phantom):
    tissue = load_tissue_realism('tissue')
    realism, heard, _, _ = _throw(scene, phantom, tissue, 0.012)
    assert heard.slips[-1]['broken'] and heard.slips[-1]['arm'] == 'PSM2'
    assert abs(heard.slips[-1]['total_angle']) == pytest.approx(
        tissue.magnitudes.break_angle, abs=tissue.magnitudes.max_slip_step)


def test_a_pad_point_deflects_before_the_puncture_and_relaxes_after(scene, phantom):
    tissue = load_tissue_realism('tissue')
    realism = TissueRealism(tissue, scene.needle, phantom, np.zeros(3))
    pad = realism.pad
    marker = phantom.markers['synth1'].entry
    assert pad.limit == pytest.approx(tissue.magnitudes.puncture_force
                                      / tissue.magnitudes.pad_stiffness)
    # the tip presses in next to the marker: the surface there goes down with it
    tip = marker + np.array([0.001, 0.0, 0.0])
    depths = []
    for indentation in np.linspace(0.0, 0.9 * pad.limit, 10):
        pad.press(tip - indentation * realism.normal, indentation)
        depths.append(-pad.displacement([marker])[0] @ realism.normal)
    assert not pad.punctured
    assert np.all(np.diff(depths) > 0.0) and depths[-1] > 0.5 * pad.limit
    far = marker + np.array([0.03, 0.0, 0.0])
    assert np.linalg.norm(pad.displacement([far])) < 1e-3 * depths[-1]
    pad.press(tip - 1.2 * pad.limit * realism.normal, 1.2 * pad.limit)
    assert pad.punctured
    before = -pad.displacement([marker])[0] @ realism.normal
    for _ in range(int(1.0 / DT)):
        pad.relax(DT)
    assert before > 0.5 * pad.limit and np.linalg.norm(pad.displacement([marker])) < 1e-6


@pytest.fixture(scope='module')
def pressed_sim():
    from sim_bridge.simulation import Simulation, load_simulation_config

    tissue = replace(load_tissue_realism('tissue'), pad=4.0)  # 2 mm of give: well seen
    sim = Simulation(replace(load_simulation_config(), tissue_realism=tissue))
    sim.reset(seed=0)
    yield sim
    sim.close()


def _seen_markers(sim):
    from suture_lfd.perception import detect_markers, stereo_from_camera_info

    frame = sim.render()
    stereo = stereo_from_camera_info(sim.camera.camera_info('left'),
                                     sim.camera.camera_info('right'))
    found = detect_markers(frame.left_rgb, frame.right_rgb, stereo)
    T = frame.T_world_left
    return found.points @ T[:3, :3].T + T[:3, 3]  # world


def test_a_perceived_marker_moves_with_the_deflected_surface(pressed_sim):
    sim = pressed_sim
    realism = sim.physics.realism
    pad = realism.pad
    before = _seen_markers(sim)
    entry = sim.phantom.markers['synth2'].entry
    # the tip touches the pad 1 mm beside the entry marker, then presses it 90 % of the way to a
    # puncture while moving 2 mm along the surface: the surface goes with it
    along = np.array([0.0, 1.0, 0.0])
    along -= (along @ realism.normal) * realism.normal
    along /= np.linalg.norm(along)
    touch = entry + np.array([0.001, 0.0, 0.0])
    pad.press(touch - 1e-5 * realism.normal, 1e-5)
    depth = 0.9 * pad.limit
    pad.press(touch + 0.002 * along - depth * realism.normal, depth)
    assert not pad.punctured
    pressed = _seen_markers(sim)
    assert len(pressed) == len(before) >= 4
    i = int(np.argmin(np.linalg.norm(before - entry, axis=1)))
    j = int(np.argmin(np.linalg.norm(pressed - entry, axis=1)))
    moved = pressed[j] - before[i]
    expected = pad.displacement([entry])[0]
    assert expected @ along > 1e-3
    # seen moved along the surface by about what the surface there did
    assert moved @ along == pytest.approx(expected @ along, abs=0.3e-3)
    far = [k for k in range(len(before)) if np.linalg.norm(before[k] - entry) > 0.02]
    assert far
    for k in far:
        assert np.min(np.linalg.norm(pressed - before[k], axis=1)) < 0.3e-3
    # relaxed after the puncture, the marker is seen back where it was
    pad.press(touch + 0.002 * along - 1.1 * pad.limit * realism.normal, 1.1 * pad.limit)
    assert pad.punctured
    for _ in range(1000):
        pad.relax(0.002)
    back = _seen_markers(sim)
    assert np.min(np.linalg.norm(back - before[i], axis=1)) < 0.2e-3
