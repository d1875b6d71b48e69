"""
The viewer node: the live scene in a browser page (viser), and the virtual MTMs' browser input.

Run it beside the simulator (``suture-lfd viewer``; ``--host ADDRESS`` and ``--port N`` choose
where it listens, default ``127.0.0.1:8080``: the page accepts control input, so it is not
reachable from the network unless asked) and open the URL it prints. The page draws, in
``world`` (z up, m):

- the PSMs and the ECM as simple shapes (shaft through the RCM, tool-tip axes, the ECM's camera
  frustum), posed from ``/tf`` (``<ARM>_base -> <ARM>``) and ``/tf_static`` (``world ->
  <ARM>_base``);
- the needle (its arc, posed by ``/tf`` ``world -> needle``), the phantom mesh (built from
  ``config/scene.yaml`` for the ``phantom`` parameter, posed by ``world -> phantom``), the
  entry/exit markers (``world -> <pair>_entry|exit``);
- every ``sim/visualization`` marker (LINE_STRIP, SPHERE_LIST; the thread among them; with the
  needle-in-tissue realism the markers moved with the pad and the deflected surface around the
  tip);
- the ECM's left image in its camera frustum when the simulator renders it
  (``ECM/left/image_raw``, ``camera_rate`` > 0), and with the ``Stereo pair`` button the left
  and right images (``ECM/right/image_raw``) side by side in place of the scene, for a 3-D
  display (:mod:`suture_lfd.viewer.stereo`);
- ``sim/events`` as they happen, in the side panel; a ``slip`` (the needle turned in a jaw)
  also as an orange ball and a label at that arm's tool tip;
- what the ``perception`` node sees (parameter ``perception``: its namespace, ``''`` = off):
  the estimated needle (``<perception>/needle/measured_cp``, left optical frame, placed in
  ``world`` through ``/tf``) as an orange arc beside the true one, grey while
  ``<perception>/needle/status`` says not found, its residual in the page's status line; the
  perceived markers (``<perception>/markers/entries|exits``) as yellow spheres beside the red
  ones (:mod:`suture_lfd.viewer.perceived`). A simulator in physical mode has no needle on
  ``/tf``: the true needle is then drawn from ``/evaluation/sim/needle/measured_cp``.

``view: endoscope`` opens the page looking through the ECM's left camera (``/tf``
``ECM -> ECM_left_optical``, the camera model's vertical field of view), following it live;
the ``View`` button switches to a free 3-D view and back.

It sends what changed to the page ``frame_rate`` times a second, and publishes
``viewer/stats`` (std_msgs/String, JSON, every ``stats_period`` s): ``frame_rate`` (frames sent
per second), ``tf_rate`` (``/tf`` messages per second), ``clients`` (browsers connected) and
``cameras`` (each browser's view: ``position``, ``wxyz`` in the OpenCV convention, vertical
``fov`` in rad, ``width`` and ``height`` in px) and ``perception`` (what the page draws of it:
:meth:`suture_lfd.viewer.perceived.PerceivedLayer.summary`).

Contract with the virtual MTMs (browser input back-end)
--------------------------------------------------------
For each MTM named in the parameter ``mtms`` (default ``[MTML, MTMR]``) the page has a handle
at the tool of the PSM it drives (``teleops``: ``<MTM>_<PSM>`` names of the teleop nodes,
default ``MTMR_PSM2``, ``MTML_PSM1``), put there once the arms are homed (the teleop leaves
``SETTING_ARMS``) and again at every clutch (it enters ``CLUTCHED``), a gripper slider, a
``Clutch`` control pressed while held (mouse or key ``C``), ``Coag`` (key ``V``, a toggle) and
``Record`` (key ``R``: one press of the camera pedal) (:mod:`suture_lfd.viewer.controls`). The
node publishes what the person does and nothing else about teleoperation:

- ``viewer/input/<MTM>/pose`` (geometry_msgs/PoseStamped, frame_id ``world``): the handle's
  pose, on every change (at the page's rate, >= 20 Hz, while it is dragged) and when it is put
  at its tool;
- ``viewer/input/<MTM>/gripper`` (std_msgs/Float64): gripper opening angle, rad, 0 ... 1.047
  (60 deg);
- ``viewer/input/pedals`` (sensor_msgs/Joy): ``buttons = [clutch, coag, camera]``, 1 = pressed,
  on every change (the camera pedal pressed and released at once).

All three are RELIABLE, VOLATILE, depth 10, stamped with the node's clock. It reads
``/<teleop>/current_state`` (std_msgs/String) of each teleop node and ``recorder/status`` (the
recorder's JSON) to show on the page each arm's state, what to do next and the bag being
recorded. When a recording starts it selects the simulator's current pair (the last
``target_pair`` event) again on ``sim/target_pair``, as the demonstrator does: the throw is
scored afresh and the bag says which pair it sutures. Parameters: ``config/viewer.yaml``.
"""

from dataclasses import dataclass
import json
import time

from crtk_msgs.msg import StringStamped
from geometry_msgs.msg import PoseArray, PoseStamped
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Image, Joy
from sim_bridge.common.geometry import transform_from_pose
from sim_bridge.ros import conversions as cv
from sim_bridge.ros import qos
from sim_bridge.ros.entry import NodeHooks
from sim_bridge.ros.params import declare_config
from std_msgs.msg import Float64, String
from suture_lfd.viewer.assets import endoscope_fov, load_phantom, needle_arc
from suture_lfd.viewer.controls import MtmControls
from suture_lfd.viewer.page import DEFAULT_HOST, DEFAULT_PORT, VIEWS, FrameClock, ViewerPage
from suture_lfd.viewer.perceived import PerceivedLayer
from suture_lfd.viewer.stereo import StereoPanel
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray


@dataclass(frozen=True)
class ViewerConfig:
    """
    Parameters of the viewer node (names as in ``config/viewer.yaml``).

    Attributes
    ----------
    host : str
        Interface the page listens on (``127.0.0.1``: this machine only; ``--host``).
    port : int
        TCP port of the page (``--port``; the next free one when it is taken).
    phantom : str
        The simulator's ``phantom`` (``synthetic``, ``scanned`` or a mesh file).
    frame_rate : float
        Frames sent to the page per second (Hz of wall time).
    mtms : tuple of str
        MTMs whose browser input the page hosts (``()``: none).
    images : bool
        Subscribe to the ECM's left and right images (the simulator renders only for
        subscribers, and only with ``camera_rate`` > 0); the right one is used only while the
        page shows the stereo pair.
    stats_period : float
        Seconds between ``viewer/stats`` messages.
    view : str
        The page's first view: ``free`` or ``endoscope`` (through the ECM's left camera).
    teleops : tuple of str
        Teleop node names ``<MTM>_<PSM>``: which PSM each MTM drives, whose state is shown.
    recorder : str
        Name of the recorder node whose ``~/status`` is shown (``''``: none).
    perception : str
        Namespace of the perception node's outputs drawn beside the truth (``''``: none).

    """

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    phantom: str = 'synthetic'
    frame_rate: float = 30.0
    mtms: tuple[str, ...] = ('MTML', 'MTMR')
    images: bool = True
    stats_period: float = 1.0
    view: str = 'free'
    teleops: tuple[str, ...] = ('MTMR_PSM2', 'MTML_PSM1')
    recorder: str = 'recorder'
    perception: str = 'perception'

    def __post_init__(self):
        if self.view not in VIEWS:
            raise ValueError(f'parameter view must be one of {", ".join(VIEWS)}, got '
                             f'{self.view!r}')
        for name in self.teleops:
            if name.count('_') != 1 or not all(name.split('_')):
                raise ValueError(f'parameter teleops: {name!r} is not <MTM>_<PSM> (e.g. '
                                 'MTMR_PSM2)')
        if not self.frame_rate > 0:
            raise ValueError(f'parameter frame_rate must be > 0 Hz, got {self.frame_rate}')
        if not 0 <= self.port <= 65535:
            raise ValueError(f'parameter port must be 0 .. 65535 (0: any free port), '
                             f'got {self.port}')
        if not self.stats_period > 0:
            raise ValueError(f'parameter stats_period must be > 0 s, got {self.stats_period}')


def matrix_from_transform(transform):
    """4x4 matrix of a geometry_msgs/Transform."""
    t, q = transform.translation, transform.rotation
    return transform_from_pose((t.x, t.y, t.z, q.x, q.y, q.z, q.w))


def rgb_from_image(msg):
    """``(h, w, 3)`` uint8 of an ``rgb8`` sensor_msgs/Image (None for other encodings)."""
    if msg.encoding != 'rgb8' or msg.height == 0 or msg.width == 0:
        return None
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    return data.reshape(msg.height, msg.step)[:, :3 * msg.width].reshape(msg.height, msg.width, 3)


class Viewer(NodeHooks, Node):
    """The viewer node (see the module docstring)."""

    def __init__(self):
        super().__init__('viewer')
        self.config = declare_config(self, ViewerConfig, 'viewer.yaml', 'viewer')
        phantom = load_phantom(self.config.phantom)
        points, diameter = needle_arc()
        self.page = ViewerPage(points, diameter, host=self.config.host, port=self.config.port,
                               view=self.config.view)
        self.page.show_phantom(phantom)
        self._fov = endoscope_fov()
        self.pairs = dict(name.split('_') for name in self.config.teleops)
        self._to_place = set(self.config.mtms)     # handles to put at their tools
        self._states = {}
        self._input = {}
        for mtm in self.config.mtms:
            self._input[mtm] = (
                self.create_publisher(PoseStamped, f'viewer/input/{mtm}/pose', qos.STREAM),
                self.create_publisher(Float64, f'viewer/input/{mtm}/gripper', qos.STREAM))
        self._pedals = self.create_publisher(Joy, 'viewer/input/pedals', qos.STREAM)
        self._pedal_state = (0, 0)
        self.controls = None
        if self.config.mtms:
            self.controls = self.page.add_panel(MtmControls(
                self.config.mtms, on_pose=self._publish_pose, on_gripper=self._publish_gripper,
                on_pedals=self._publish_pedals, psm_of_mtm=self.pairs))
            for mtm, psm in self.pairs.items():
                self.create_subscription(String, f'/{mtm}_{psm}/current_state',
                                         lambda msg, m=mtm: self._on_teleop_state(m, msg),
                                         qos.LATCHED)
            if self.config.recorder:
                self.create_subscription(String, f'/{self.config.recorder}/status',
                                         self._on_recorder_status, qos.LATCHED)
                self._target_pair = self.create_publisher(String, 'sim/target_pair',
                                                          qos.COMMANDS)
        self._pair = ''
        self._recording = False
        self._tf_count = 0
        self.create_subscription(TFMessage, '/tf', self._on_tf, qos.STREAM)
        self.create_subscription(TFMessage, '/tf_static', self._on_tf_static, qos.STATIC_TF)
        self.create_subscription(MarkerArray, 'sim/visualization', self._on_markers, qos.STREAM)
        self.create_subscription(StringStamped, 'sim/events', self._on_event, qos.SCENE_EVENTS)
        self.stereo = None
        if self.config.images:
            self.stereo = self.page.add_panel(StereoPanel())
            self.create_subscription(Image, 'ECM/left/image_raw', self._on_image, qos.IMAGES)
            self.create_subscription(Image, 'ECM/right/image_raw', self._on_right_image,
                                     qos.IMAGES)
        self.perceived = None
        if self.config.perception:
            self._subscribe_perception(self.config.perception.rstrip('/'), points, diameter)
        self._stats = self.create_publisher(String, 'viewer/stats', qos.LATCHED)
        self.clock = FrameClock()
        self._tf_mark = (time.monotonic(), 0)
        self.create_timer(1.0 / self.config.frame_rate, self._render)
        self.create_timer(self.config.stats_period, self._publish_stats)
        self.get_logger().info(f'viewer page at {self.page.url}')
        print(f'viewer: open {self.page.url}', flush=True)

    # --- scene inputs --------------------------------------------------------------------------

    def _on_tf(self, msg):
        self._tf_count += 1
        self._store(msg)

    def _on_tf_static(self, msg):
        self._store(msg)

    def _store(self, msg):
        scene = self.page.scene
        for tr in msg.transforms:
            scene.set_transform(tr.header.frame_id, tr.child_frame_id,
                                matrix_from_transform(tr.transform))

    def _on_markers(self, msg):
        scene = self.page.scene
        for marker in msg.markers:
            key = f'{marker.ns}/{marker.id}'
            points = [(p.x, p.y, p.z) for p in marker.points]
            c = marker.color
            rgba = (c.r, c.g, c.b, c.a)
            if marker.type == Marker.LINE_STRIP:
                scene.set_line_strip(key, points, rgba, marker.scale.x)
            elif marker.type == Marker.SPHERE_LIST:
                scene.set_spheres(key, points, rgba, marker.scale.x)

    def _on_event(self, msg):
        try:
            _, event = cv.event_from_message(msg)
        except ValueError as exc:
            self.get_logger().warning(f'sim/events: {exc}')
            return
        if event.get('kind') == 'target_pair' and 'error' not in event:
            self._pair = str(event.get('pair', ''))
        self.page.add_event(float(event.get('t', 0.0)), event)

    def _on_image(self, msg):
        rgb = rgb_from_image(msg)
        if rgb is not None:
            self.page.scene.set_image(rgb)
            self.stereo.set_image('left', rgb)

    def _on_right_image(self, msg):
        if not self.stereo.shown:   # no work for a pair nobody looks at
            return
        rgb = rgb_from_image(msg)
        if rgb is not None:
            self.stereo.set_image('right', rgb)

    def _subscribe_perception(self, ns, points, diameter):
        self.perceived = PerceivedLayer(self.page.server.scene, self.page.scene.tf, points,
                                        diameter)
        self._perceived_markers = {}
        self.create_subscription(PoseStamped, f'{ns}/needle/measured_cp', self._on_perceived,
                                 qos.STATE)
        self.create_subscription(String, f'{ns}/needle/status', self._on_perception_status,
                                 qos.STATE)
        # physical mode: the truth to compare with is published for the evaluation only
        self.create_subscription(PoseStamped, '/evaluation/sim/needle/measured_cp',
                                 self._on_true_needle, qos.STATE)
        for side in ('entries', 'exits'):
            self.create_subscription(PoseArray, f'{ns}/markers/{side}',
                                     lambda msg, s=side: self._on_perceived_markers(s, msg),
                                     qos.STATE)

    def _on_perceived(self, msg):
        try:
            T = cv.matrix_from_pose(msg.pose)
        except ValueError as exc:
            self.get_logger().warning(f'{self.config.perception}/needle/measured_cp: {exc}',
                                      throttle_duration_sec=5.0)
            return
        self.perceived.set_needle(msg.header.frame_id, T)

    def _on_true_needle(self, msg):
        if msg.header.frame_id == 'world':
            self.page.scene.set_transform('world', 'needle', cv.matrix_from_pose(msg.pose))

    def _on_perception_status(self, msg):
        try:
            status = json.loads(msg.data)
            self.perceived.set_status(bool(status['found']), status.get('residual_px'))
        except (ValueError, KeyError, TypeError) as exc:
            self.get_logger().warning(f'{self.config.perception}/needle/status: not the '
                                      f"perception node's JSON ({exc})",
                                      throttle_duration_sec=5.0)

    def _on_perceived_markers(self, side, msg):
        self._perceived_markers[side] = [(p.position.x, p.position.y, p.position.z)
                                         for p in msg.poses]
        points = [p for pts in self._perceived_markers.values() for p in pts]
        self.perceived.set_markers(msg.header.frame_id, np.array(points, float).reshape(-1, 3))

    # --- page ----------------------------------------------------------------------------------

    def _render(self):
        rendered = self.page.render()
        if self.stereo is not None:
            rendered = self.stereo.render() or rendered
        if self.perceived is not None:
            rendered = self.perceived.render() or rendered
            text = self.perceived.status_text()
            if self.page.status.content != text:
                self.page.status.content = text
        self.clock.tick(rendered)
        tf = self.page.scene.tf
        T_optical = tf.world('ECM_left_optical')
        if T_optical is not None:
            self.page.set_endoscope(T_optical, self._fov)
        if self.controls is None:
            return
        if T_optical is not None:
            self.controls.set_image_rotation(T_optical[:3, :3])
        self.controls.tick()
        for mtm in list(self._to_place):
            T = tf.world(self.pairs.get(mtm, ''))
            if T is not None:
                self._to_place.discard(mtm)
                self.controls.place(mtm, T)

    # --- the console's state -------------------------------------------------------------------

    def _on_teleop_state(self, mtm, msg):
        before, state = self._states.get(mtm), msg.data
        self._states[mtm] = state
        # put the handle at its tool once the arms are homed, and at every clutch
        if state == 'CLUTCHED' or (state != 'FOLLOWING' and before in (None, 'SETTING_ARMS')):
            self._to_place.add(mtm)
        self.controls.set_teleop_state(mtm, state)

    def _on_recorder_status(self, msg):
        try:
            status = json.loads(msg.data)
        except ValueError:
            return
        bag = status.get('bag')
        recording = bool(status.get('recording'))
        if recording and not self._recording and self._pair:
            self._target_pair.publish(String(data=self._pair))
        self._recording = recording
        if recording:
            text = f'**recording** to `{bag}` — Record (R) stops it'
        elif bag:
            text = f'bag written: `{bag}` — Record (R) starts another'
        else:
            text = 'Record (R): press to start a bag'
        self.controls.set_recording(text)

    def _publish_stats(self):
        now = time.monotonic()
        t0, n0 = self._tf_mark
        tf_rate = (self._tf_count - n0) / max(now - t0, 1e-9)
        self._tf_mark = (now, self._tf_count)
        stats = {'frame_rate': round(self.clock.rate(), 2), 'tf_rate': round(tf_rate, 2),
                 'clients': self.page.connected_clients(), 'frames': self.clock.frames,
                 'cameras': self.page.client_cameras()}
        if self.perceived is not None:
            stats['perception'] = self.perceived.summary()
        self._stats.publish(String(data=json.dumps(stats)))

    # --- browser input -------------------------------------------------------------------------

    def _publish_pose(self, mtm, T):
        msg = cv.pose_stamped(T, 'world', self.get_clock().now().to_msg())
        self._input[mtm][0].publish(msg)

    def _publish_gripper(self, mtm, angle):
        self._input[mtm][1].publish(Float64(data=float(angle)))

    def _publish_pedals(self, clutch, coag, camera=0):
        if clutch and not self._pedal_state[0]:
            # no teleop tells when it clutched: put the handles back at once
            self._to_place.update(m for m in self.config.mtms if m not in self._states)
        self._pedal_state = (int(clutch), int(coag))
        msg = Joy(buttons=[int(clutch), int(coag), int(camera)])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pedals.publish(msg)

    def on_exit(self):
        """Stop the page's server (the shared entry point calls this on the way out)."""
        self.page.close()

