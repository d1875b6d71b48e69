"""
Ground truth of the simulated scene on ROS topics, with TF, markers and the stereo camera.

All poses are in ``world`` (z up, phantom at the origin; SI units):

- ``sim/needle/measured_cp`` (geometry_msgs/PoseStamped, at the state rate, RELIABLE);
- ``sim/phantom/measured_cp``, ``sim/markers/<pair>/entry``, ``sim/markers/<pair>/exit``
  (z axis = outward surface normal) and ``sim/<ARM>/base_frame`` (``T_world_<ARM>_base``):
  PoseStamped, latched (RELIABLE, TRANSIENT_LOCAL, depth 1);
- ``/tf``: ``<reference frame> -> <ARM>`` (``measured_cp``) per arm and ``world -> needle``;
  ``/tf_static``: ``world -> <ARM>_base``, ``world -> phantom``, ``world -> <pair>_entry|exit``
  and ``ECM -> ECM_left|right_optical``;
- ``sim/visualization`` (visualization_msgs/MarkerArray): needle arc, thread, red markers, tool
  tips; with the needle-in-tissue realism the markers moved with the pad's dimple and ``pad``:
  points of the deflected surface around the needle's tip (none while the pad is at rest);
- ``ECM/left|right/image_raw`` (sensor_msgs/Image, rgb8), ``ECM/left|right/camera_info`` (the
  right ``P`` has ``-fx * baseline``; ``D`` the lens's coefficients) and
  ``ECM/left|right/image_rect`` (the rectified images, as the ROS image pipeline publishes them,
  with ``ECM/left|right/image_rect/camera_info``, zero ``D``) and, when asked for,
  ``ECM/left|right/depth`` (32FC1, m); rendered only while someone subscribes. With an ideal
  lens (the default) the raw images are the rectified ones. An endoscope with a frame timing
  (:mod:`sim_bridge.realism.frame_timing`) exposes a frame at its rate and publishes it, stamped,
  its latency later.

In physical mode the ground truth is for the evaluation only: the needle, phantom, marker and
base topics and ``sim/visualization`` move under ``/evaluation/`` (:func:`truth_topic`), ``/tf``
carries the arms only and ``/tf_static`` the arms' bases as the robot believes them (its
registration) and the camera's optical frames.

The node calls these publishers from its one executor thread; they skip topics nobody reads.
"""

from geometry_msgs.msg import PoseStamped
import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from sim_bridge.common import cdr
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.simulation import ARMS, PSMS
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

WORLD = 'world'
EVALUATION = '/evaluation/'
_RED = (0.85, 0.05, 0.05, 1.0)
_SILVER = (0.75, 0.75, 0.8, 1.0)
_THREAD = (0.2, 0.3, 0.9, 1.0)
_TOOL = (0.1, 0.8, 0.2, 1.0)
_PAD = (1.0, 0.55, 0.1, 1.0)


def truth_topic(name, physical):
    """
    Return the name a ground-truth topic has: ``/evaluation/<name>`` in physical mode.

    Parameters
    ----------
    name : str
        Relative topic name (``'sim/needle/measured_cp'``).
    physical : bool
        Physical mode: the truth is published for the evaluation only.

    Returns
    -------
    str

    """
    return EVALUATION + name if physical else name


class SceneTopics:
    """
    Publishers of the scene's ground truth, TF, visualization and camera.

    Parameters
    ----------
    node : rclpy.node.Node
    sim : sim_bridge.simulation.Simulation
    depth : bool
        Publish the metric depth images too.
    physical : bool
        Physical mode: ground truth under ``/evaluation/`` only, none on ``/tf``.

    """

    def __init__(self, node, sim, depth=False, physical=False):
        self._node = node
        self._sim = sim
        self._physical = physical
        pub = node.create_publisher

        def truth(name):
            return truth_topic(name, physical)

        self._needle = pub(PoseStamped, truth('sim/needle/measured_cp'), qos.STATE)
        self._phantom = pub(PoseStamped, truth('sim/phantom/measured_cp'), qos.LATCHED)
        self._bases = {a: pub(PoseStamped, truth(f'sim/{a}/base_frame'), qos.LATCHED)
                       for a in ARMS}
        self._markers = {}
        for key in sim.marker_poses():
            pair, which = key.split('.')
            self._markers[key] = pub(PoseStamped, truth(f'sim/markers/{pair}/{which}'),
                                     qos.LATCHED)
        self._tf = pub(TFMessage, '/tf', qos.STATE)
        self._tf_static = pub(TFMessage, '/tf_static', qos.LATCHED)
        self._viz = pub(MarkerArray, truth('sim/visualization'), qos.STATE)
        self._images = {s: pub(Image, f'ECM/{s}/image_raw', qos.IMAGES) for s in ('left', 'right')}
        self._infos = {s: pub(CameraInfo, f'ECM/{s}/camera_info', qos.IMAGES)
                       for s in ('left', 'right')}
        self._depths = ({s: pub(Image, f'ECM/{s}/depth', qos.IMAGES) for s in ('left', 'right')}
                        if depth else {})
        self._rect = {s: pub(Image, f'ECM/{s}/image_rect', qos.IMAGES) for s in ('left', 'right')}
        self._rect_infos = {s: pub(CameraInfo, f'ECM/{s}/image_rect/camera_info', qos.IMAGES)
                            for s in ('left', 'right')}
        self._exposed = []   # (t_publish, frame) rendered, waiting for the camera's latency

    def publish_latched(self, stamp):
        """Publish the scene's fixed frames (after start-up and after a reset)."""
        sim = self._sim
        self._phantom.publish(cv.pose_stamped(sim.phantom_pose(), WORLD, stamp))
        for arm, pub in self._bases.items():
            pub.publish(cv.pose_stamped(sim.T_world_base(arm), WORLD, stamp))
        markers = sim.marker_poses()
        for key, pub in self._markers.items():
            pub.publish(cv.pose_stamped(markers[key], WORLD, stamp))
        if self._physical:  # what the robot believes; no phantom or markers
            transforms = [cv.transform_stamped(sim.believed_base(a), WORLD, f'{a}_base', stamp)
                          for a in ARMS]
        else:
            transforms = [cv.transform_stamped(sim.T_world_base(a), WORLD, f'{a}_base', stamp)
                          for a in ARMS]
            transforms.append(cv.transform_stamped(sim.phantom_pose(), WORLD, 'phantom', stamp))
            transforms += [cv.transform_stamped(T, WORLD, key.replace('.', '_'), stamp)
                           for key, T in markers.items()]
        camera = sim.camera
        transforms += [cv.transform_stamped(camera.T_tip_left, 'ECM', 'ECM_left_optical', stamp),
                       cv.transform_stamped(camera.T_tip_right, 'ECM', 'ECM_right_optical',
                                            stamp)]
        self._tf_static.publish(cv.tf_message(transforms))

    def publish_state(self, ns):
        """Publish the needle pose (state rate), stamped ``ns`` (int nanoseconds)."""
        if self._needle.get_subscription_count():
            pose = cv.pose_vector(self._sim.needle_pose())
            self._needle.publish(cdr.pose_stamped(ns, WORLD, pose))

    def publish_tf(self, stamp):
        """Publish the moving frames: each arm's ``measured_cp`` and the needle."""
        if not self._tf.get_subscription_count():
            return
        sim = self._sim
        transforms = [cv.transform_stamped(arm.measured_cp, arm.reference_frame, name, stamp)
                      for name, arm in sim.arms.items()]
        if not self._physical:
            transforms.append(cv.transform_stamped(sim.needle_pose(), WORLD, 'needle', stamp))
        self._tf.publish(cv.tf_message(transforms))

    def publish_visualization(self, stamp):
        """Publish the needle arc, thread, markers and tool tips as a MarkerArray."""
        if not self._viz.get_subscription_count():
            return
        sim = self._sim
        needle = sim.needle_geometry.points_world(sim.needle_pose(), 24)
        markers = [p[:3, 3] for p in sim.marker_poses().values()]
        tips = [sim.tool_pose(a)[:3, 3] for a in PSMS]
        diameter = sim.needle_geometry.wire_diameter
        realism = sim.physics.realism
        if realism is not None:  # the markers go with the pad's dimple
            markers = list(realism.moved(np.asarray(markers)))
        msg = MarkerArray(markers=[
            cv.line_strip_marker(needle, 'needle', 0, WORLD, stamp, _SILVER, diameter),
            cv.line_strip_marker(sim.thread_points(), 'thread', 0, WORLD, stamp, _THREAD,
                                 2 * sim.thread_geometry.radius),
            cv.sphere_list_marker(markers, 'markers', 0, WORLD, stamp, _RED, 0.002),
            cv.sphere_list_marker(tips, 'tool_tips', 0, WORLD, stamp, _TOOL, 0.003),
        ])
        if realism is not None:  # the deflected surface around the tip (empty at rest)
            msg.markers.append(cv.sphere_list_marker(list(realism.surface_patch()), 'pad', 0,
                                                     WORLD, stamp, _PAD, 0.001))
        self._viz.publish(msg)

    def expose_camera(self, t, t_publish):
        """
        Render the stereo pair of the scene at ``t`` if someone listens.

        It is published at ``t_publish`` (simulation s), stamped then (:meth:`publish_camera`).
        """
        publishers = (*self._images.values(), *self._infos.values(), *self._depths.values(),
                      *self._rect.values(), *self._rect_infos.values())
        if not any(p.get_subscription_count() for p in publishers):
            return
        self._exposed.append((t_publish, self._sim.render()))

    def publish_camera(self, t, stamp):
        """Publish the exposed frames whose time has come (``stamp(t)``: the clock's stamp)."""
        while self._exposed and self._exposed[0][0] <= t + 1e-9:
            t_publish, frame = self._exposed.pop(0)
            self._publish_frame(frame, stamp(t_publish))

    def _publish_frame(self, frame, stamp):
        camera = self._sim.camera
        for side, rgb, raw, depth in (('left', frame.left_rgb, frame.left_raw, frame.left_depth),
                                      ('right', frame.right_rgb, frame.right_raw,
                                       frame.right_depth)):
            frame_id = f'ECM_{side}_optical'
            rect_msg = cv.image_message(rgb, frame_id, stamp)
            self._images[side].publish(rect_msg if raw is None
                                       else cv.image_message(raw, frame_id, stamp))
            self._infos[side].publish(cv.camera_info_message(camera.camera_info(side, raw=True),
                                                             frame_id, stamp))
            self._rect[side].publish(rect_msg)
            self._rect_infos[side].publish(cv.camera_info_message(camera.camera_info(side),
                                                                  frame_id, stamp))
            if side in self._depths and depth is not None:
                self._depths[side].publish(cv.depth_message(depth, frame_id, stamp))
