"""
The perception node's outputs as a client node reads them: needle looks and marker rows.

:class:`PerceptionTopics` subscribes, on a node the caller made, to ``perception/needle/
measured_cp`` and ``perception/needle/status`` (one look is complete when both of one stamp
have come, or the status says not found) and to ``perception/markers/entries|exits`` (a look at
the markers is complete when both rows of one stamp have come), and hands each complete look
over in the form :class:`suture_lfd.skill.perceived_feed.PerceptionFeed` takes.

:class:`StereoImages` keeps the newest stereo pair of ``<camera>/left|right/image_raw`` and
their ``camera_info`` (for a registration of the arms against the endoscope) and converts a pair
only when asked.

Frames: the camera's left optical frame (the messages' ``frame_id``); metres; stamps in s.
"""

import json

from geometry_msgs.msg import PoseArray, PoseStamped
import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from std_msgs.msg import String
from suture_lfd.perception import stereo_from_camera_info
from suture_lfd.skill.perceived_feed import NeedleStatus

SIDES = ('left', 'right')


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


class StereoImages:
    """
    The newest stereo pair of the endoscope on a client node, converted on request.

    Parameters
    ----------
    node : rclpy.node.Node
        The node the subscriptions are made on.
    camera : str
        Namespace of ``<camera>/left|right/image_raw`` and ``camera_info``.

    """

    def __init__(self, node, camera='ECM'):
        self.node = node
        self._images = dict.fromkeys(SIDES)
        self._infos = dict.fromkeys(SIDES)
        self._converted = None  # (stamp, stereo, left, right) of the last pair asked for
        for side in SIDES:
            node.create_subscription(Image, f'{camera}/{side}/image_raw',
                                     lambda m, s=side: self._images.__setitem__(s, m),
                                     qos.IMAGES)
            node.create_subscription(CameraInfo, f'{camera}/{side}/camera_info',
                                     lambda m, s=side: self._infos.__setitem__(s, m), qos.IMAGES)

    def newest(self):
        """
        Return the newest pair of one stamp, or None.

        Returns
        -------
        tuple or None
            ``(stamp_s, stereo, left_rgb, right_rgb)``: the stereo model from the pair's
            ``camera_info``, the images ``(h, w, 3)`` uint8; None until a matching pair and both
            ``camera_info`` came, or when the pair does not fit its ``camera_info`` (logged).

        """
        left, right = self._images['left'], self._images['right']
        if left is None or right is None or None in self._infos.values():
            return None
        stamp = cv.seconds_from_stamp(left.header.stamp)
        if stamp != cv.seconds_from_stamp(right.header.stamp):
            return None
        if self._converted is not None and self._converted[0] == stamp:
            return self._converted
        try:
            infos = [cv.camera_info_arrays(self._infos[s]) for s in SIDES]
            stereo = stereo_from_camera_info(*infos)
            rgb = [cv.rgb_from_image(m, i['width'], i['height'])
                   for m, i in zip((left, right), infos)]
        except ValueError as exc:
            self.node.get_logger().error(f'stereo pair refused: {exc}',
                                         throttle_duration_sec=1.0)
            return None
        self._converted = (stamp, stereo, rgb[0], rgb[1])
        return self._converted
