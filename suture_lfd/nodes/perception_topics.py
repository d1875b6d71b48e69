"""
The perception node's outputs as a client node reads them: needle looks and marker rows.

:class:`PerceptionTopics` subscribes, on a node the caller made, to ``perception/needle/
measured_cp`` and ``perception/needle/status`` (one look is complete when both of one stamp
have come, or the status says not found) and to ``perception/markers/entries|exits`` (a look at
the markers is complete when both rows of one stamp have come), and hands each complete look
over in the form :class:`suture_lfd.skill.perceived_feed.PerceptionFeed` takes.

Frames: the camera's left optical frame (the messages' ``frame_id``); metres; stamps in s.
"""

import json

from geometry_msgs.msg import PoseArray, PoseStamped
import numpy as np
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from std_msgs.msg import String
from suture_lfd.skill.perceived_feed import NeedleStatus


class PerceptionTopics:
    """
    The perception node's outputs on a client node, converted and paired.

    Parameters
    ----------
    node : rclpy.node.Node
        The node the subscriptions are made on.
    on_needle : callable
        Called as ``on_needle(stamp, T_camera_needle or None, NeedleStatus)`` with every
        complete look at the needle.
    on_markers : callable
        Called as ``on_markers(stamp, entries, exits, normal)`` with every complete look at
        the markers.

    """

    def __init__(self, node, on_needle, on_markers):
        self.node = node
        self._on_needle, self._on_markers = on_needle, on_markers
        sub = node.create_subscription
        sub(PoseStamped, 'perception/needle/measured_cp', lambda m: self._got(self.pose(m)),
            qos.STATE)
        sub(String, 'perception/needle/status', lambda m: self._got(self.status(m)), qos.STATE)
        for which in ('entries', 'exits'):
            sub(PoseArray, f'perception/markers/{which}',
                lambda m, w=which: self._got_markers(self.markers(w, m)), qos.STATE)
        self._pose = None      # (stamp, T_camera_needle)
        self._status = None    # (stamp, NeedleStatus)
        self._rows = {}        # 'entries' / 'exits' -> (stamp, points (n, 3), normal (3,))
        self.needle = None     # newest complete look: (stamp, T or None, NeedleStatus)
        self.marker_rows = None

    def pose(self, msg):
        """Take ``perception/needle/measured_cp``; return a complete look or None."""
        self._pose = (cv.seconds_from_stamp(msg.header.stamp), cv.matrix_from_pose(msg.pose))
        return self._match()

    def _got(self, seen):
        if seen is not None:
            self._on_needle(*seen)

    def _got_markers(self, seen):
        if seen is not None:
            self._on_markers(*seen)

    def status(self, msg):
        """Take ``perception/needle/status``; return a complete look or None."""
        try:
            data = json.loads(msg.data)
            stamp = float(data['stamp'])
            status = NeedleStatus(bool(data['found']), str(data.get('reason') or ''),
                                  data.get('residual_px'))
        except (ValueError, TypeError, KeyError) as exc:
            self.node.get_logger().warning(
                f'perception/needle/status: not a status with found and stamp ({exc})',
                throttle_duration_sec=5.0)
            return None
        self._status = (stamp, status)
        return self._match()

    def _match(self):
        if self._status is None:
            return None
        stamp, status = self._status
        if not status.found:
            self.needle = (stamp, None, status)
        elif self._pose is not None and self._pose[0] == stamp:
            self.needle = (stamp, self._pose[1], status)
        else:
            return None
        self._status = None
        return self.needle

    def markers(self, which, msg):
        """Take one marker row; return ``(stamp, entries, exits, normal)`` when both match."""
        stamp = cv.seconds_from_stamp(msg.header.stamp)
        points = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses],
                          dtype=float).reshape(-1, 3)
        normal = np.array([0.0, 0.0, -1.0])  # facing the camera, when no pair is seen
        if msg.poses:
            o = msg.poses[0].orientation
            q = np.array([o.x, o.y, o.z, o.w], dtype=float)
            if np.isfinite(q).all() and abs(np.linalg.norm(q) - 1.0) < 1e-3:
                normal = matrix_from_quaternion(q)[:3, 2]
        self._rows[which] = (stamp, points, normal)
        entries, exits = self._rows.get('entries'), self._rows.get('exits')
        if entries is None or exits is None or entries[0] != exits[0] \
                or len(entries[1]) != len(exits[1]):
            return None
        self.marker_rows = (stamp, entries[1], exits[1], entries[2])
        return self.marker_rows

    def replay(self, feed):
        """Give a new feed the newest looks."""
        if self.marker_rows is not None:
            feed.markers_seen(*self.marker_rows)
        if self.needle is not None:
            feed.needle_seen(*self.needle)
