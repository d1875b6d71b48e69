"""Over ROS with real processes: virtual MTMs (browser back-end) -> teleop -> simulated PSM1."""

import time

from harness import wait_for
import numpy as np
import pytest
from suture_lfd.teleop.mapping import GripperToJaw
from teleop_rig import BrowserOperator, SceneWatch, displacement_in_camera, stream, wait_teleop


@pytest.fixture
def teleop_graph(ros, launch):
    sim = launch('simulator', '--ros-args', '-p', 'footpedals:=false',
                 '-p', 'real_time_factor:=1.0')
    mtms = launch('mtms', '--ros-args', '-p', 'device:=browser')
    teleop = launch('teleop', '--ros-args', '-r', '__node:=MTMR_PSM1')
    node = ros.node('operator')
    watch = SceneWatch(node)
    operator = BrowserOperator(node)
    assert wait_for(lambda: watch.ready() and operator.connected(), timeout=60), \
        sim.log() + mtms.log()
    yield watch, operator, (sim, mtms, teleop)


def test_a_scripted_hand_motion_moves_psm1_a_fifth_of_it_in_the_camera_view(teleop_graph):
    watch, op, procs = teleop_graph
    op.handles['MTMR'] = watch.world('PSM1')          # the handle starts at the tool
    op.handles['MTML'] = watch.world('PSM2') if 'PSM2' in watch.base else np.eye(4)
    logs = lambda: '\n'.join(p.log()[-3000:] for p in procs)  # noqa: E731
    assert wait_teleop(watch, 'MTMR_PSM1', 'ALIGNING', op, timeout=90), logs()
    op.coag = True                                     # the operator sits down ...
    stream(op, 0.3)
    for g in (0.6, 0.8, 0.6):                          # ... and pinches the gripper
        op.grippers['MTMR'] = g
        stream(op, 0.2)
    assert wait_teleop(watch, 'MTMR_PSM1', 'FOLLOWING', op, timeout=30), logs()
    stream(op, 0.5)
    R_cam = watch.camera()[:3, :3]
    right = R_cam[:, 0]                                # camera x (image right), in world

    def move_handle(dx_world, seconds=1.0):
        start = op.handles['MTMR'][:3, 3].copy()

        def during(s):
            op.handles['MTMR'] = op.handles['MTMR'].copy()
            op.handles['MTMR'][:3, 3] = start + min(1.0, s * 1.25) * dx_world
        stream(op, seconds, during=during)

    before = watch.world('PSM1')
    move_handle(0.02 * right)
    stream(op, 0.8)                                     # let the arm settle
    after = watch.world('PSM1')
    moved = displacement_in_camera(watch, before, after)
    np.testing.assert_allclose(moved, [0.004, 0.0, 0.0], atol=0.001)

    # clutch in, recentre the hand 2 cm back, clutch out: the tool does not move
    op.clutch = True
    assert wait_teleop(watch, 'MTMR_PSM1', 'CLUTCHED', op, timeout=10)
    held = watch.world('PSM1')
    move_handle(-0.02 * right)
    op.clutch = False
    t_release = time.monotonic()
    assert wait_teleop(watch, 'MTMR_PSM1', 'FOLLOWING', op, timeout=10), logs()
    stream(op, 0.5)
    with watch.lock:
        after_release = [T for _, T in watch.history['PSM1'][-60:]]
    jumps = [np.linalg.norm(watch.base['PSM1'][:3, :3] @ (T[:3, 3]) + watch.base['PSM1'][:3, 3]
                            - held[:3, 3]) for T in after_release]
    assert max(jumps) < 0.001, (max(jumps), time.monotonic() - t_release)

    # and following again: 2 cm right once more
    before = watch.world('PSM1')
    move_handle(0.02 * right)
    stream(op, 0.8)
    moved = displacement_in_camera(watch, before, watch.world('PSM1'))
    np.testing.assert_allclose(moved, [0.004, 0.0, 0.0], atol=0.001)

    # the jaw follows the gripper
    jaw_map = GripperToJaw()
    for g in (0.2, 0.9):
        op.grippers['MTMR'] = g
        stream(op, 0.8)
        assert wait_for(lambda g=g: abs(watch.jaw['PSM1'] - jaw_map.jaw_from_gripper(g)) < 0.02,
                        timeout=5), (g, watch.jaw['PSM1'])
