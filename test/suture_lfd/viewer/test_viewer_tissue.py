"""
The viewer shows the needle in tissue, in a real headless Chromium: a slip marked at the jaw,
and the pad's deflected surface where the simulation pressed it.

Real parts: a simulation with the ``tissue`` preset whose pad is pressed by the needle's tip, the
simulator node's visualization (the moved markers and the deflected patch, read off the same
publisher code path), a real viser server and Chromium with software GL.
"""

from copy import deepcopy
from dataclasses import replace
import time

from browser import Chromium, find_chromium, project
from harness import wait_for
import numpy as np
import pytest
from sim_bridge.realism.tissue_config import load_tissue_realism
from sim_bridge.simulation import Simulation, load_simulation_config
from suture_lfd.viewer.assets import needle_arc
from suture_lfd.viewer.page import CAMERA_FOV, CAMERA_LOOK_AT, CAMERA_POSITION, ViewerPage

CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason='no chromium executable')


def is_orange(rgb):
    r, g, b = np.moveaxis(np.asarray(rgb, float), -1, 0)
    return (r > 150) & (g > 0.3 * r) & (g < 0.8 * r) & (b < 0.35 * r)


def near(mask, uv, radius):
    u, v = int(round(uv[0])), int(round(uv[1]))
    return bool(mask[max(v - radius, 0):v + radius + 1, max(u - radius, 0):u + radius + 1].any())


@pytest.fixture(scope='module')
def pressed():
    """A simulation whose pad the tip has pressed in beside the entry of synth2."""
    tissue = replace(load_tissue_realism('tissue'), pad=4.0)  # 2 mm of give: well seen
    sim = Simulation(replace(load_simulation_config(), tissue_realism=tissue))
    sim.reset(seed=0)
    realism = sim.physics.realism
    entry = sim.phantom.markers['synth2'].entry
    touch = entry + np.array([0.001, 0.0, 0.0])
    realism.pad.press(touch - 1e-5 * realism.normal, 1e-5)
    depth = 0.9 * realism.pad.limit
    realism.pad.press(touch - depth * realism.normal, depth)
    yield sim, entry
    sim.close()


def test_the_pressed_pad_moves_its_patch_and_markers_in_and_relaxes(pressed):
    sim, entry = pressed
    realism = sim.physics.realism
    patch = realism.surface_patch()
    assert len(patch) == 1 + 4 * 12
    centre_in = (realism.pad.centre - patch[0]) @ realism.normal
    assert centre_in == pytest.approx(realism.pad.depth, rel=1e-6)   # pressed in at the tip
    outer = (realism.pad.centre - patch[-12:]) @ realism.normal
    assert (outer < 0.2 * centre_in).all()                          # two spreads out: hardly
    moved = realism.moved(np.array([entry]))[0]
    assert (entry - moved) @ realism.normal > 0.5 * realism.pad.depth
    relaxed = deepcopy(realism)  # punctured, a second later the pad is back at rest
    relaxed.pad.punctured = True
    for _ in range(1000):
        relaxed.pad.relax(0.002)
    assert len(relaxed.surface_patch()) == 0
    assert np.allclose(relaxed.moved(np.array([entry]))[0], entry)


def test_the_page_marks_a_slip_at_the_jaw_and_draws_the_deflected_pad(pressed, tmp_path):
    sim, entry = pressed
    realism = sim.physics.realism
    points, diameter = needle_arc()
    page = ViewerPage(points, diameter, port=0)
    browser = Chromium(CHROMIUM)
    try:
        # PSM2's tool 3 cm above the pad's far side; the patch around the pressed entry
        T_tool = np.eye(4)
        T_tool[:3, 3] = entry + np.array([-0.02, 0.0, 0.03])
        page.scene.set_transform('world', 'PSM2', T_tool)
        page.scene.set_spheres('pad/0', realism.surface_patch(), (1.0, 0.55, 0.1, 1.0), 0.0015)
        page.add_event(1.25, {'kind': 'slip', 'arm': 'PSM2', 'angle': -0.0733, 'slide': 0.0,
                              'total_angle': -0.0733, 'in_tissue': True, 'broken': False})
        page.scene.mark_slip('PSM2', 'slip 4.2 deg', shown=600.0)  # stays while Chromium loads
        page.render()
        browser.open(page.url)
        assert wait_for(lambda: browser.canvas_rect() is not None, 600), 'no 3-D view'
        wait_for(lambda: browser.close_notification('Software WebGL'), 60, 1.0)
        rect = browser.canvas_rect()
        uv_tool, uv_pad = project(np.array([T_tool[:3, 3], realism.pad.centre]),
                                  CAMERA_POSITION, CAMERA_LOOK_AT, CAMERA_FOV, rect)

        def drawn():
            page.render()
            orange = is_orange(browser.screenshot(tmp_path / 'tissue.png'))
            return near(orange, uv_tool, 6) and near(orange, uv_pad, 6)
        assert wait_for(drawn, 600, 1.0), \
            f'no orange at the jaw {uv_tool.round()} and the dimple {uv_pad.round()} ' \
            f'({tmp_path / "tissue.png"})'
        # the mark goes when its time is up; the pad's patch stays
        page.scene.mark_slip('PSM2', 'slip 4.2 deg', shown=0.0)
        time.sleep(0.1)

        def gone():
            page.render()
            orange = is_orange(browser.screenshot(tmp_path / 'gone.png'))
            return not near(orange, uv_tool, 4) and near(orange, uv_pad, 6)
        assert wait_for(gone, 300, 1.0), f'the slip mark stayed ({tmp_path / "gone.png"})'
    finally:
        browser.close()
        page.close()
