"""
The perception feed: perception outputs (camera frame) in, the scene in the robot's ``world`` out.

Plain numbers through the feed the executor and demonstrator nodes and the physical-mode bag
reader share: the markers and the needle placed by the camera's reported pose, the pair found by
its position along the wound, a grasp measured when a jaw closes on the perceived needle.
"""

import numpy as np
import pytest
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.control import Observation
from suture_lfd.skill.perceived_feed import (
    NeedleStatus,
    PerceptionFeed,
    normal_quaternion,
    pair_index_from_name,
)

NAN3 = [np.nan] * 3


def camera_pose():
    """The camera 0.1 m above the pad, looking down (optical z along world -z)."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [0.0, 0.0, 0.1]
    return T


def arms(t, jaw1, jaw2, tool1=None, tool2=None):
    tools = {'PSM1': np.eye(4) if tool1 is None else tool1,
             'PSM2': np.eye(4) if tool2 is None else tool2}
    return Observation(t=t, T_world_tool=tools, jaw={'PSM1': jaw1, 'PSM2': jaw2},
                       T_world_needle=None, holders=(), pair=None, T_world_base={})


def test_the_pair_is_placed_in_world_by_the_camera_pose_and_found_by_its_position():
    feed = PerceptionFeed('synth2', 2)
    feed.camera_moved(camera_pose())
    entries = [[-0.01, 0.004, 0.1], [0.0, 0.004, 0.1], NAN3]
    exits = [[-0.01, -0.004, 0.1], [0.0, -0.004, 0.1], NAN3]
    feed.markers_seen(1.0, entries, exits, [0.0, 0.0, -1.0])
    pair = feed.markers()
    np.testing.assert_allclose(pair.entry, [0.0, -0.004, 0.0], atol=1e-12)
    np.testing.assert_allclose(pair.exit, [0.0, 0.004, 0.0], atol=1e-12)
    np.testing.assert_allclose(pair.normal, [0.0, 0.0, 1.0], atol=1e-12)
    assert PerceptionFeed('synth3', 3).markers() is None  # nothing seen yet
    unseen = PerceptionFeed('synth3', 3)
    unseen.camera_moved(camera_pose())
    unseen.markers_seen(1.0, entries, exits, [0.0, 0.0, -1.0])
    assert unseen.markers() is None                       # pair 3 is NaN


def test_what_was_not_seen_since_a_time_is_named():
    feed = PerceptionFeed('synth1', 1)
    assert feed.seen_since(0.0) == ['markers', 'needle']
    feed.needle_seen(2.0, None, NeedleStatus(False, 'too few wire pixels'))
    feed.markers_seen(0.5, [[0, 0, 0.1]], [[0, 0.01, 0.1]], [0, 0, -1])
    assert feed.seen_since(1.0) == ['markers']
    with pytest.raises(ValueError, match='must pair up'):
        feed.markers_seen(3.0, [[0, 0, 0.1]], np.zeros((2, 3)), [0, 0, -1])


def test_a_jaw_closing_on_the_perceived_needle_holds_it_and_carries_it():
    feed = PerceptionFeed('synth1', 1)
    feed.camera_moved(camera_pose())
    feed.markers_seen(0.0, [[0, 0.004, 0.1]], [[0, -0.004, 0.1]], [0, 0, -1])
    T_cam_needle = np.eye(4)
    T_cam_needle[:3, 3] = [0.02, 0.0, 0.1]     # needle centre at (0.02, 0, 0) in world
    feed.needle_seen(0.0, T_cam_needle, NeedleStatus(True))
    first = feed.observe(arms(0.0, 0.8, 0.8))
    assert first.holders == () and first.pair is not None
    lying = first.T_world_needle
    np.testing.assert_allclose(lying[:3, 3], [0.02, 0.0, 0.0], atol=1e-12)
    # PSM2's jaw closes on the wire: a point of the arc, 1 mm off
    wire = feed._tracker.geometry.points_world(lying, 48)
    tool = np.eye(4)
    tool[:3, 3] = wire[10] + [0.0, 0.0, 0.001]
    held = feed.observe(arms(0.1, 0.8, -0.2, tool2=tool))
    assert held.holders == ('PSM2',)
    np.testing.assert_allclose(held.T_world_needle, lying, atol=1e-12)
    moved = tool.copy()
    moved[:3, 3] += [0.0, 0.0, 0.01]           # lifted 10 mm: the needle goes with it
    carried = feed.observe(arms(0.2, 0.8, -0.2, tool2=moved))
    np.testing.assert_allclose(carried.T_world_needle[:3, 3], [0.02, 0.0, 0.01], atol=1e-12)
    # PSM1 closes far away: no grasp
    far = np.eye(4)
    far[:3, 3] = [-0.05, 0.0, 0.02]
    assert feed.observe(arms(0.3, -0.2, -0.2, tool1=far, tool2=moved)).holders == ('PSM2',)


def test_pair_names_give_their_index_or_an_error_saying_what_to_pass():
    assert pair_index_from_name('synth3') == 3
    assert pair_index_from_name('scan12') == 12
    with pytest.raises(ValueError, match='give the pair index'):
        pair_index_from_name('left_pair')


@pytest.mark.parametrize('normal', [[0, 0, 1], [0, 0, -1], [0.3, -0.2, -0.93], [1, 0, 0]])
def test_the_marker_orientation_carries_the_plane_normal_as_its_z_axis(normal):
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    q = normal_quaternion(n)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    np.testing.assert_allclose(matrix_from_quaternion(q)[:3, 2], n, atol=1e-12)


def test_a_needle_let_go_is_where_it_was_left_until_a_look_taken_after_the_release():
    feed = PerceptionFeed('synth1', 1)
    feed.camera_moved(camera_pose())
    feed.markers_seen(0.0, [[0, 0.004, 0.1]], [[0, -0.004, 0.1]], [0, 0, -1])
    T_cam_needle = np.eye(4)
    T_cam_needle[:3, 3] = [0.02, 0.0, 0.1]     # needle centre at (0.02, 0, 0) in world
    feed.needle_seen(0.0, T_cam_needle, NeedleStatus(True))
    lying = feed.observe(arms(0.0, 0.8, 0.8)).T_world_needle
    wire = feed._tracker.geometry.points_world(lying, 48)
    tool = np.eye(4)
    tool[:3, 3] = wire[10]
    assert feed.observe(arms(0.1, 0.8, -0.2, tool2=tool)).holders == ('PSM2',)
    moved = tool.copy()
    moved[:3, 3] += [0.0, 0.005, 0.0]          # carried 5 mm along y
    # a look while it is carried (the jaws hide it: a stale pose, 2 mm short)
    stale = T_cam_needle.copy()
    stale[:3, 3] += [0.0, -0.003, 0.0]         # camera y is world -y
    feed.needle_seen(0.3, stale, NeedleStatus(True))
    left = feed.observe(arms(0.4, 0.8, 0.8, tool2=moved))   # PSM2 lets go
    assert left.holders == ()
    np.testing.assert_allclose(left.T_world_needle[:3, 3], [0.02, 0.005, 0.0], atol=1e-12)
    # the look taken before the release is not taken for where it lies now
    assert np.allclose(feed.observe(arms(0.5, 0.8, 0.8, tool2=moved)).T_world_needle,
                       left.T_world_needle)
    # a look after the release is
    seen = T_cam_needle.copy()
    seen[:3, 3] += [0.0, -0.0055, 0.0]
    feed.needle_seen(0.6, seen, NeedleStatus(True))
    after = feed.observe(arms(0.7, 0.8, 0.8, tool2=moved)).T_world_needle
    np.testing.assert_allclose(after[:3, 3], [0.02, 0.0055, 0.0], atol=1e-12)


def test_an_observation_takes_only_looks_stamped_at_or_before_the_arms_state():
    feed = PerceptionFeed('synth1', 1)
    feed.camera_moved(camera_pose())
    feed.markers_seen(0.0, [[0, 0.004, 0.1]], [[0, -0.004, 0.1]], [0, 0, -1])
    before, later = np.eye(4), np.eye(4)
    before[:3, 3] = [0.02, 0.0, 0.1]            # world (0.02, 0, 0)
    later[:3, 3] = [0.03, 0.0, 0.1]             # world (0.03, 0, 0): seen after the arms' state
    feed.needle_seen(0.9, before, NeedleStatus(True))
    feed.needle_seen(1.1, later, NeedleStatus(True))
    # the arms' state of 1.0 arrives after the look of 1.1 (queued behind the images)
    first = feed.observe(arms(1.0, 0.8, 0.8))
    np.testing.assert_allclose(first.T_world_needle[:3, 3], [0.02, 0.0, 0.0], atol=1e-12)
    assert feed.needle_stamp() == 0.9           # the executor's frame_time: the look it uses
    # nothing of a known stamp yet: no needle rather than one seen later
    empty = PerceptionFeed('synth1', 1)
    empty.camera_moved(camera_pose())
    empty.markers_seen(0.0, [[0, 0.004, 0.1]], [[0, -0.004, 0.1]], [0, 0, -1])
    empty.needle_seen(1.1, later, NeedleStatus(True))
    assert empty.observe(arms(1.0, 0.8, 0.8)).T_world_needle is None
    assert empty.needle_stamp() is None        # no look of the arms' instant yet: a look waits
    seen = empty.observe(arms(1.1, 0.8, 0.8)).T_world_needle
    np.testing.assert_allclose(seen[:3, 3], [0.03, 0.0, 0.0], atol=1e-12)
