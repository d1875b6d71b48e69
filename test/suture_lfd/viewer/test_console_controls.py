"""The console's controls on a real viser page, without a browser: the held clutch, the handles."""

import math

import numpy as np
import pytest
from sim_bridge.common.geometry import matrix_from_quaternion
from suture_lfd.viewer.assets import needle_arc
from suture_lfd.viewer.controls import HOLD_TIMEOUT, MODES, MtmControls, next_action
from suture_lfd.viewer.page import ViewerPage
from suture_lfd.viewer.scene import wxyz_from_matrix


class Clock:
    """Time the test sets (s)."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


@pytest.fixture
def console():
    points, diameter = needle_arc()
    page = ViewerPage(points, diameter, port=0)
    sent = {'poses': [], 'pedals': []}
    clock = Clock()
    controls = page.add_panel(MtmControls(
        ('MTML', 'MTMR'), clock=clock,
        on_pose=lambda mtm, T: sent['poses'].append((mtm, T)),
        on_pedals=lambda *buttons: sent['pedals'].append(list(buttons))))
    try:
        yield controls, sent, clock
    finally:
        page.close()


def test_the_clutch_is_pressed_while_held_and_released_once(console):
    controls, sent, clock = console
    for _ in range(40):                         # held 2 s: the page reports it at 20 Hz
        controls.clutch_held()
        clock.t += 0.05
        controls.tick()
    assert sent['pedals'] == [[1, 0, 0]]
    controls.clutch_released()
    assert sent['pedals'] == [[1, 0, 0], [0, 0, 0]]
    controls.clutch_held()                      # held, then the page goes quiet (lost pointer)
    clock.t += HOLD_TIMEOUT + 0.01
    controls.tick()
    assert sent['pedals'][-2:] == [[1, 0, 0], [0, 0, 0]]
    count = len(sent['pedals'])
    controls.clutch_released()                  # that hold's late release changes nothing
    assert len(sent['pedals']) == count


def test_a_tap_whose_press_the_page_coalesced_away_is_a_press_and_a_release(console):
    # the page keeps only the latest of its messages within 50 ms: a quick key C tap (key down,
    # key up) can arrive as the release alone
    controls, sent, clock = console
    controls.clutch_released()
    assert sent['pedals'] == [[1, 0, 0], [0, 0, 0]]
    controls.clutch_held()                      # a tap whose press did arrive: one of each
    clock.t += 0.02
    controls.clutch_released()
    assert sent['pedals'][2:] == [[1, 0, 0], [0, 0, 0]]
    assert controls.pedals['clutch'] == 0


def test_a_handle_sits_at_its_tool_in_the_image_plane_and_keeps_the_hands_orientation(console):
    controls, sent, _ = console
    assert controls.psm_of_mtm == {'MTMR': 'PSM2', 'MTML': 'PSM1'}
    R_image = matrix_from_quaternion((math.sin(0.3), 0.0, 0.0, math.cos(0.3)))
    controls.set_image_rotation(R_image)
    T_tool = np.eye(4)
    T_tool[:3, :3] = matrix_from_quaternion((0.0, math.sin(0.5), 0.0, math.cos(0.5)))
    T_tool[:3, 3] = (0.04, 0.0, 0.04)
    controls.place('MTMR', T_tool)
    mtm, T = sent['poses'][-1]
    assert mtm == 'MTMR' and controls.placed('MTMR') and not controls.placed('MTML')
    np.testing.assert_allclose(T, T_tool, atol=1e-12)           # the pose sent: the tool's
    handle = controls.handles['MTMR']
    np.testing.assert_allclose(np.abs(handle.wxyz), np.abs(wxyz_from_matrix(R_image)),
                               atol=1e-9)                        # the arrows: the image's
    # the default mode: the ball alone, no gizmo part to catch
    ball = controls.balls['MTMR']
    assert ball.visible and not handle.visible
    assert handle.disable_rotations and handle.disable_axes and handle.disable_sliders
    np.testing.assert_allclose(ball.position, T_tool[:3, 3], atol=1e-12)
    controls.set_mode('rotate')
    assert not handle.disable_rotations and handle.disable_axes and handle.disable_sliders
    assert handle.visible and not ball.visible
    controls.set_mode(MODES[0])
    assert ball.visible and not handle.visible
    T_tool[:3, 3] += 0.01                       # at the next clutch: back to the moved tool
    controls.place('MTMR', T_tool)
    np.testing.assert_allclose(sent['poses'][-1][1][:3, 3], T_tool[:3, 3], atol=1e-12)
    with pytest.raises(ValueError, match='handle mode'):
        controls.set_mode('scale')


def test_a_drag_moves_the_handle_in_the_image_plane_wherever_its_ball_is_grabbed(console):
    controls, sent, _ = console
    T_tool = np.eye(4)
    T_tool[:3, :3] = matrix_from_quaternion((0.0, math.sin(0.5), 0.0, math.cos(0.5)))
    T_tool[:3, 3] = (0.04, 0.0, 0.04)
    controls.place('MTMR', T_tool)
    grabbed = T_tool[:3, 3] + (0.001, -0.002, 0.0015)   # off the ball's centre
    right = np.array([0.004, 0.001, 0.0])                # the pointer's motion on the plane
    controls.drag('MTMR', 'start', grabbed, grabbed)
    controls.drag('MTMR', 'update', grabbed + 0.5 * right, grabbed + 0.5 * right)
    controls.drag('MTMR', 'end', grabbed + right, grabbed + right)
    mtm, T = sent['poses'][-1]
    assert mtm == 'MTMR'
    np.testing.assert_allclose(T[:3, 3], T_tool[:3, 3] + right, atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], T_tool[:3, :3], atol=1e-12)   # never turned
    np.testing.assert_allclose(controls.balls['MTMR'].position, T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(controls.handles['MTMR'].position, T[:3, 3], atol=1e-12)
    n = len(sent['poses'])
    controls.drag('MTMR', 'update', grabbed, grabbed)     # no drag under way: nothing
    controls.set_mode('rotate')                          # and none of the ball in rotate mode
    controls.drag('MTMR', 'start', grabbed, grabbed + right)
    assert len(sent['poses']) == n
    controls.set_mode(MODES[0])
    controls.drag('MTML', 'start', grabbed, grabbed + right)   # not placed yet: nothing
    assert len(sent['poses']) == n


def test_the_page_says_what_to_do_next():
    assert 'Coag' in next_action('ALIGNING', coag=False)
    assert 'pinch' in next_action('ALIGNING', coag=True)
    assert 'release C' in next_action('CLUTCHED', coag=True)
    assert 'teleop' in next_action(None, coag=False)
