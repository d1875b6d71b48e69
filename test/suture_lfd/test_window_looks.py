"""A region, not a frame; an image at the camera's rate, never of "now" (real PyBullet).

Perception that tracks something it expects looks at the window around it
(:mod:`suture_lfd.perception.window`): the needle found there must be the needle found in the
whole frame. With an endoscope's frame timing, a look gets the newest frame the endoscope has
delivered (:class:`sim_bridge.realism.frame_timing.Exposures`): the scene as it was exposed,
its latency ago, and rendering it leaves the scene's present untouched.
"""

from dataclasses import replace

import numpy as np
import pytest
from sim_bridge.control import Command
from sim_bridge.realism.endoscope import endoscope_preset
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.perception import NeedleTracker
from suture_lfd.perception.evaluation import SceneMaker
from suture_lfd.perception.window import points_window, window_stereo


@pytest.mark.parametrize('endoscope', ['', 'dvrk'])
def test_a_window_look_finds_the_needle_the_whole_frame_finds(endoscope):
    maker = SceneMaker('synthetic', endoscope=endoscope)
    tracker = NeedleTracker()
    rng = np.random.default_rng(3)
    compared = 0
    try:
        for _ in range(20):
            scene = maker.scene('held', rng)
            if scene is None:
                continue
            stereo = scene.stereo
            # the prior a tracker has: the true pose, 1 mm and a few degrees off
            prior = scene.T_camera_needle.copy()
            prior[:3, 3] += rng.normal(0.0, 0.0006, 3)
            tools = list(scene.tools.values())
            whole = tracker.estimate(scene.left, scene.right, stereo, prior=prior, tools=tools)
            window = points_window(stereo, tracker.geometry.points_world(prior, 24), 0.005)
            assert window is not None
            u0, v0, w, h = window
            assert w * h < 0.6 * stereo.width * stereo.height
            frame = maker.sim.render(window=window)
            assert frame.left_rgb.shape == (h, w, 3)
            seen = tracker.estimate(frame.left_rgb, frame.right_rgb,
                                    window_stereo(stereo, window), prior=prior, tools=tools)
            assert seen.found == whole.found
            if whole.found:
                assert tracker.arc_distance(seen.pose_camera, whole.pose_camera) < 2e-4
                compared += 1
            if compared == 3:
                break
    finally:
        maker.close()
    assert compared == 3


def _sim(endoscope: str) -> Simulation:
    cfg = load_simulation_config()
    cfg = replace(cfg, endoscope=endoscope_preset(endoscope),
                  camera=replace(cfg.camera, noise_std=0.0, light_jitter=0.0))
    sim = Simulation(cfg, phantom='synthetic', rng=np.random.default_rng(0))
    sim.reset(seed=2)
    sim.enable_and_home_all()
    return sim


def _move(sim: Simulation, dz: float, jaw: float | None = None) -> None:
    T = sim.reported_tool_pose('PSM2')
    T[2, 3] += dz
    sim.apply(Command(t=sim.time, T_world_tool={'PSM2': T},
                      jaw={} if jaw is None else {'PSM2': jaw}, subtask='test'))


def test_a_look_gets_the_newest_delivered_frame_as_it_was_exposed():
    sim = _sim('dvrk')
    timing = sim.config.endoscope.timing
    try:
        _move(sim, 0.01)  # PSM2 moves in view: every frame differs
        exposed = {}
        for _ in range(60):
            t0 = sim.time
            sim.step()
            if np.floor(sim.time * timing.rate + 1e-9) > np.floor(t0 * timing.rate + 1e-9):
                exposed[round(sim.time, 9)] = sim.render().left_rgb
        t_scene = sim.delivered_frame()
        # the newest frame whose scene is at or before now minus the latency
        assert t_scene + timing.latency <= sim.time + 1e-9
        assert t_scene + timing.latency + 1.0 / timing.rate + sim.config.world.physics_step \
            > sim.time
        shown, frame = sim.render_delivered()
        assert shown == t_scene
        assert np.array_equal(frame.left_rgb, exposed[round(t_scene, 9)])
        assert not np.array_equal(frame.left_rgb, sim.render().left_rgb)  # not "now"
        # a window of it is the same frame's
        _, part = sim.endoscope_frame(window=(100, 80, 200, 150))
        assert np.array_equal(part.left_rgb, frame.left_rgb[80:230, 100:300])
    finally:
        sim.close()


def test_rendering_a_delivered_frame_leaves_a_falling_needle_alone():
    poses = []
    for look in (False, True):
        sim = _sim('dvrk')
        try:
            sim.attach_needle('PSM2', np.linalg.inv(sim.reported_tool_pose('PSM2'))
                              @ sim.needle_pose())
            _move(sim, 0.02, jaw=0.0)
            sim.run(0.3)
            sim.apply(Command(t=sim.time, T_world_tool={}, jaw={'PSM2': 1.0}, subtask='test'))
            modes = set()
            for _ in range(150):  # let go: the needle falls on the pad
                sim.step()
                modes.add(sim.needle_mode)
                if look:
                    sim.render_delivered()
                else:  # what a render of the scene now leaves in PyBullet: the arms drawn
                    sim.sync_world()
            assert 'free' in modes
            poses.append(sim.needle_pose())
        finally:
            sim.close()
    # put back as PyBullet had it: the fall is the same to the rounding of its floats
    assert np.abs(poses[0] - poses[1]).max() < 1e-12


def test_an_ideal_camera_keeps_no_frames():
    sim = _sim('')
    try:
        sim.run(0.1)
        assert sim.delivered_frame() is None
        assert sim.endoscope_frame()[0] == sim.time
        with pytest.raises(ValueError, match='ideal camera'):
            sim.render_delivered()
    finally:
        sim.close()
