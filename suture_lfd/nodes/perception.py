"""
Perception node: the needle's pose and the markers from the ECM's stereo pair, nothing else.

Subscribes ``<camera>/left|right/image_raw`` (sensor_msgs/Image, rgb8 or bgr8) and
``<camera>/left|right/camera_info``; at most ``rate`` times a second it takes the newest pair
whose two images have the same stamp (raw images whose ``camera_info`` has a non-zero ``D`` are
rectified first, with OpenCV maps built once per calibration) and runs
:class:`suture_lfd.perception.StereoPerception` on it (markers, then the needle, tracked from
pair to pair). Publishes, stamped with the pair and in its frame (the left optical frame,
``<camera>_left_optical``):

- ``perception/needle/measured_cp`` (geometry_msgs/PoseStamped): the needle's pose, when found;
- ``perception/needle/status`` (std_msgs/String, JSON): ``found``, ``residual_px``,
  ``visible_share``, ``visible_left``, ``visible_right``, ``partial``, ``tracked``, ``reason``,
  ``stamp`` (s, the pair's stamp: a client matches it with the pose);
- ``perception/markers/entries``, ``perception/markers/exits`` (geometry_msgs/PoseArray):
  pair ``i`` along the wound at index ``i`` (NaN where not seen); each pose's ``z`` axis is the
  normal of the plane through the dots (towards the camera).

An image with another encoding, or a size that does not match its ``camera_info``, is refused
with an error in the log and on ``perception/needle/status`` (``error``); the node goes on with
the next pair. Parameters: ``config/perception.yaml``.
"""

from dataclasses import dataclass
import json
import math
import sys

from geometry_msgs.msg import Point, Pose, PoseArray, PoseStamped, Quaternion
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from sim_bridge.realism.lens import Lens
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.params import declare_config
from std_msgs.msg import String
from suture_lfd.nodes import executables
from suture_lfd.perception import StereoPerception, stereo_from_camera_info
from suture_lfd.skill.perceived_feed import normal_quaternion

SIDES = ('left', 'right')


@dataclass(frozen=True)
class PerceptionConfig:
    """Parameters of the perception node (names as in ``config/perception.yaml``)."""

    rate: float = 10.0
    camera: str = 'ECM'
    markers: bool = True
    track_timeout: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f'parameter rate must be > 0 Hz, got {self.rate}')
        if not self.camera:
            raise ValueError('parameter camera is empty: name the camera namespace (ECM)')
        if not self.track_timeout >= 0:
            raise ValueError(f'parameter track_timeout must be >= 0 s, got {self.track_timeout}')


class PerceptionNode(Node):
    """Images and camera_info in; needle pose, its status and the markers out."""

    def __init__(self):
        super().__init__('perception')
        self.config = cfg = declare_config(self, PerceptionConfig, 'perception.yaml',
                                           'perception')
        self.perception = StereoPerception(track_timeout=cfg.track_timeout, markers=cfg.markers)
        self._images = dict.fromkeys(SIDES)
        self._infos = dict.fromkeys(SIDES)
        self._lenses = {}       # rectification maps per calibration
        self._done_stamp = None
        for side in SIDES:
            self.create_subscription(Image, f'{cfg.camera}/{side}/image_raw',
                                     lambda m, s=side: self._images.__setitem__(s, m),
                                     qos.IMAGES)
            self.create_subscription(CameraInfo, f'{cfg.camera}/{side}/camera_info',
                                     lambda m, s=side: self._infos.__setitem__(s, m), qos.IMAGES)
        self._pose = self.create_publisher(PoseStamped, 'perception/needle/measured_cp',
                                           qos.STATE)
        self._status = self.create_publisher(String, 'perception/needle/status', qos.STATE)
        self._entries = self.create_publisher(PoseArray, 'perception/markers/entries', qos.STATE)
        self._exits = self.create_publisher(PoseArray, 'perception/markers/exits', qos.STATE)
        self.create_timer(1.0 / cfg.rate, self._on_timer)

    def _pair(self):
        """Return the newest unprocessed pair with stamps and calibration, or None."""
        left, right = self._images['left'], self._images['right']
        if left is None or right is None or None in self._infos.values():
            return None
        stamp = cv.nanoseconds_from_stamp(left.header.stamp)
        if stamp != cv.nanoseconds_from_stamp(right.header.stamp) or stamp == self._done_stamp:
            return None
        self._done_stamp = stamp
        return left, right

    def _on_timer(self):
        pair = self._pair()
        if pair is None:
            return
        left_msg, right_msg = pair
        try:
            infos = [cv.camera_info_arrays(self._infos[s]) for s in SIDES]
            stereo = stereo_from_camera_info(*infos)
            images = [self._rectified(cv.rgb_from_image(m, i['width'], i['height']), i)
                      for m, i in zip(pair, infos)]
            result = self.perception.process(images[0], images[1], stereo,
                                             cv.nanoseconds_from_stamp(left_msg.header.stamp)
                                             * 1e-9)
        except ValueError as exc:
            self.get_logger().error(f'stereo pair refused: {exc}', throttle_duration_sec=1.0)
            self._status.publish(String(data=json.dumps({'found': False, 'error': str(exc)})))
            return
        stamp, frame = left_msg.header.stamp, left_msg.header.frame_id
        est = result.needle
        if est.found:
            self._pose.publish(cv.pose_stamped(est.pose_camera, frame, stamp))
        self._status.publish(String(data=json.dumps({
            'found': est.found, 'residual_px': _finite(est.residual_px),
            'visible_share': est.visible_share, 'visible_left': est.visible_left,
            'visible_right': est.visible_right, 'partial': est.partial,
            'tracked': result.tracked, 'reason': est.reason,
            'stamp': cv.seconds_from_stamp(stamp)})))
        if result.markers is not None:
            x, y, z, w = normal_quaternion(result.markers.normal)
            for pub, points in ((self._entries, result.markers.entries),
                                (self._exits, result.markers.exits)):
                msg = PoseArray()
                msg.header.stamp, msg.header.frame_id = stamp, frame
                msg.poses = [Pose(position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                                  orientation=Quaternion(x=x, y=y, z=z, w=w)) for p in points]
                pub.publish(msg)


    def _rectified(self, image, info):
        """Return the image rectified with its camera_info's ``D`` (raw images of a lens)."""
        if not info['D'].any():
            return image
        key = (info['width'], info['height'], info['K'].tobytes(), info['D'].tobytes())
        lens = self._lenses.get(key)
        if lens is None:        # OpenCV's maps, built once per calibration
            lens = self._lenses[key] = Lens(info['K'], info['D'], (info['width'],
                                                                  info['height']))
        return lens.rectify(image)


def _finite(value):
    return float(value) if math.isfinite(value) else None


def main(args=None):
    return executables.perception(args)


if __name__ == '__main__':
    sys.exit(main())
