"""
Replay in the viewer's page: a real demonstration bag (written, read back by the bag reader),
served by a real viser server; the scene graph the page receives shows the needle where the bag
recorded it, the slider carries the segment file's subtasks, and playing reaches the end in the
recording's duration divided by the speed.
"""

import time

from harness import wait_for
import numpy as np
import pytest
from sim_bridge.common.geometry import quaternion_angle
from suture_lfd import bags
from suture_lfd.demos.demo_bag import write_demonstration_bag
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.segmentation.segments import make_segment_file
from suture_lfd.viewer.show import open_replay


@pytest.fixture(scope='module')
def demo_bag(experienced_run, tmp_path_factory):
    folder = tmp_path_factory.mktemp('replay')
    path = folder / 'demo_synth1'
    write_demonstration_bag(path, experienced_run.demo)
    demo = experienced_run.demo
    make_segment_file(demo, segment_demonstration(demo), source=str(path)).save(
        folder / 'demo_synth1.segments.npz')
    return path


def recorded_needle(path):
    """The bag's needle poses ``(t s of their stamps, (n, 7))``, decoded by rosbags."""
    t, poses = [], []
    with bags.open_bag(path) as reader:
        for message in reader.messages(['/sim/needle/measured_cp']):
            msg = reader.deserialize(message)
            p, q = msg.pose.position, msg.pose.orientation
            t.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
            poses.append((p.x, p.y, p.z, q.x, q.y, q.z, q.w))
    return np.array(t), np.array(poses)


def test_the_slider_shows_the_needle_where_the_bag_recorded_it(demo_bag):
    page, panel = open_replay(demo_bag, port=0)
    try:
        rec = panel.recording
        t_bag, poses = recorded_needle(demo_bag)
        # the recording's axis starts at the bag's first pose sample (the needle's, here)
        assert rec.duration == pytest.approx(t_bag[-1] - t_bag[0], abs=0.02)
        labels = [label for _, label in rec.marks]
        assert labels == ['i', 'ii', 'iii', 'iv', 'v', 'end']
        assert [label for _, label in panel.marks] == labels
        needle = page.scene.needle
        for fraction in (0.2, 0.55, 0.9):
            t = round(fraction * rec.duration, 2)
            panel.slider.value = t  # as a user drags it: the page's callback seeks
            k = np.searchsorted(t_bag - t_bag[0], t + 1e-9, side='right') - 1
            expected = poses[k]
            assert wait_for(lambda e=expected: np.linalg.norm(np.asarray(needle.position) - e[:3])
                            < 1e-6, 10), (t, needle.position, expected[:3])
            w, x, y, z = needle.wxyz
            assert quaternion_angle((x, y, z, w), expected[3:]) < 1e-6
        # and the needle moved between those times: the check above can fail
        assert np.ptp(poses[:, :3], axis=0).max() > 0.01
    finally:
        panel.close()
        page.close()


@pytest.mark.parametrize('speed', [4.0])
def test_playing_reaches_the_end_in_duration_over_speed(demo_bag, speed):
    page, panel = open_replay(demo_bag, port=0)
    try:
        expected = panel.recording.duration / speed
        start = time.monotonic()
        panel.play(speed=speed)
        assert panel.finished.wait(expected * 3 + 30), 'playing did not reach the end'
        elapsed = time.monotonic() - start
        assert panel.time == pytest.approx(panel.recording.duration)
        # wall time: never shorter than duration / speed; longer only by a loaded machine's lag
        assert elapsed >= expected - 0.05
        assert elapsed < expected * 2.0 + 5.0, (elapsed, expected)
        assert not panel.playing and panel.play_button.label == 'Play'
    finally:
        panel.close()
        page.close()
