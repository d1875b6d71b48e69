"""
The page shows the endoscope's stereo pair side by side, as the dVRK's stereo viewer does.

Real processes: the simulator rendering the ECM's pair (``camera_rate``) and the viewer; a real
headless Chromium clicks the ``Stereo pair`` button and the screenshot is compared with the
images the simulator published: the left image on the left half, the right one on the right
half, black bars above and below; a second click brings the scene back.
"""

import re
import threading

from browser import Chromium, find_chromium
from harness import FAST_ARMS
import numpy as np
import pytest
from sensor_msgs.msg import Image
from sim_bridge.ros import qos
from suture_lfd.viewer.stereo import side_by_side

CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium executable: tools/setup.sh installs Debian's chromium "
                             'with apt-get when it runs as root or with sudo')
WIDTH, HEIGHT = 1280, 720
PANEL_LEFT = 900  # px, the side panel covers the page right of this
SAME = 12.0  # mean absolute difference (0-255) of a JPEG-sent image and its source


def mad(a, b):
    """Mean absolute difference of two images (0-255)."""
    return float(np.abs(a.astype(float) - b.astype(float)).mean())


def test_the_stereo_pair_is_shown_side_by_side_and_the_scene_comes_back(ros, launch, tmp_path):
    launch('simulator', '--ros-args', *FAST_ARMS, '-p', 'camera_rate:=2.0',
           '-p', 'visualization_rate:=0.0')
    viewer = launch('viewer', '--port', '0')
    node = ros.node('stereo_probe')
    lock = threading.Lock()
    images = {}

    def on_image(side, msg):
        rgb = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.step)
        with lock:
            images[side] = rgb[:, :3 * msg.width].reshape(msg.height, msg.width, 3).copy()
    for side in ('left', 'right'):
        node.create_subscription(Image, f'ECM/{side}/image_raw',
                                 lambda m, s=side: on_image(s, m), qos.IMAGES)
    assert ros.wait_for(lambda: 'viewer: open' in viewer.log(), 90), viewer.log()
    url = re.search(r'viewer: open (\S+)', viewer.log()).group(1)
    assert ros.wait_for(lambda: len(images) == 2, 120), 'the simulator sent no stereo pair'
    browser = Chromium(CHROMIUM, WIDTH, HEIGHT)
    try:
        browser.open(url)
        assert ros.wait_for(lambda: browser.element_center('Stereo pair') is not None, 600), \
            'the page did not connect to the viewer'
        assert ros.wait_for(lambda: browser.close_notification('Software WebGL'), 120, 1.0)
        # the notice closes (it may cover the panel meanwhile)
        assert ros.wait_for(lambda: 'Software WebGL' not in browser.evaluate(
            'document.body.innerText'), 60, 0.5), 'the notice of software GL did not close'
        rect = browser.canvas_rect()
        assert rect == [0, 0, WIDTH, HEIGHT], rect
        browser.click(*browser.element_center('Stereo pair: show'))
        assert ros.wait_for(lambda: browser.element_center('back to the scene') is not None,
                            60, 0.5), 'the Stereo pair button did not turn the pair on'
        seen = {}

        def pair_shown():
            shot = browser.screenshot(tmp_path / 'stereo.png')[:, :PANEL_LEFT]
            with lock:
                left, right = images['left'], images['right']
            expected = side_by_side(left, right, WIDTH / HEIGHT)[:, :PANEL_LEFT]
            swapped = side_by_side(right, left, WIDTH / HEIGHT)[:, :PANEL_LEFT]
            if expected.shape != shot.shape:
                seen['why'] = f'the pair framed is {expected.shape}, the view {shot.shape}'
                return False
            seen.update(own=mad(shot, expected), swapped=mad(shot, swapped),
                        bars=float(shot[:20].mean()))
            return seen['own'] < SAME and seen['own'] < seen['swapped'] and seen['bars'] < 10
        assert ros.wait_for(pair_shown, 120, 1.0), \
            f'the page does not show the pair side by side: {seen} ({tmp_path / "stereo.png"})'
        print(f'\nstereo pair on the page: {seen}')

        browser.click(*browser.element_center('back to the scene'))

        def scene_back():
            shot = browser.screenshot(tmp_path / 'scene.png')
            seen['bars'] = float(shot[:20, :PANEL_LEFT].mean())
            return seen['bars'] > 150      # the scene's light background, not the black bars
        assert ros.wait_for(scene_back, 60, 1.0), \
            f'the scene did not come back: {seen} ({tmp_path / "scene.png"})'
    finally:
        browser.close()


def test_the_pair_is_framed_at_the_views_aspect_and_a_bad_pair_is_refused():
    left = np.full((48, 64, 3), 10, np.uint8)
    right = np.full((48, 64, 3), 200, np.uint8)
    framed = side_by_side(left, right, 16 / 9)
    assert framed.shape == (72, 128, 3)               # bars above and below
    assert (framed[12:60, :64] == 10).all() and (framed[12:60, 64:] == 200).all()
    assert not framed[:12].any() and not framed[60:].any()
    assert side_by_side(left, right, 1.0).shape == (128, 128, 3)
    assert side_by_side(left, right).shape == (48, 128, 3)
    with pytest.raises(ValueError, match='two RGB images'):
        side_by_side(left, right[:, :32])
