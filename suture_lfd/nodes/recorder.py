"""
Recorder of demonstrations: selected topics into one rosbag2 bag per demonstration.

Subscribes to the CRTK state and commands of the arms, the foot pedals, the simulator's ground
truth and events (``config/recorder.yaml``; optional camera images and ``/clock``) and to the
topics that match its patterns as they appear in the graph, receiving CDR bytes (raw
subscriptions, RELIABLE, deep history, TRANSIENT_LOCAL where the publisher latches). Recording
starts and stops on the ``~/start`` and ``~/stop`` services (std_srvs/Trigger; the start response
holds the bag path, the stop response a JSON object of counts) and on a press of the toggle pedal
(``/footpedals/camera`` by default). A writer thread empties a queue into the bag and closes an
MCAP chunk every ``chunk_seconds``, so a recorder killed mid-recording leaves a bag that
``suture-lfd bag recover`` restores. ``~/status`` (std_msgs/String, JSON, latched) reports
per topic the messages received while recording, carried over into the bag, written, and
``missed``: published but never received, counted from the gaps in the publishers' sequence
numbers (:class:`suture_lfd.bags.losses.PublicationGaps`). ``lost`` is what was missed plus
what was received but not written, so ``lost: 0`` means the bag holds every message published
while it was recorded; the bag's ``metadata.yaml`` keeps the per-topic counts (custom data
``suture_lfd.counts``) and the total (``suture_lfd.lost``). Stopped by SIGINT or SIGTERM while
recording, the node closes the bag with what it holds and marks it ``suture_lfd.outcome:
interrupted``.

At rest the recorder costs next to nothing: the streamed topics (neither latched nor carried
over: the arms' 100 Hz state and commands) are subscribed by a companion node that is spun only
while recording. Their subscriptions stay matched in between, so DDS keeps their latest
messages; a recording takes them in one pass at its start (after saying it records) and drops
those received before it started (``received_timestamp``), reading their sequence numbers
only to count gaps from there on.

The bags are stamped by the streams' node's clock: with ``use_sim_time`` the simulator's
``/clock`` is subscribed by that node alone, so a recorder at rest does not take the 200 Hz
clock either. Its latest message, held by DDS, sets the clock at the start of a recording; the
recorder's own node (timers, status) runs on the wall clock, and says so in its
``use_sim_time`` parameter (``recorder_streams``'s holds the value given).
"""

from dataclasses import dataclass
import datetime
import fnmatch
import functools
import json
from pathlib import Path
import queue
import sys
import threading
import time

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Joy
from sim_bridge.common.vocabulary import ARMS
from sim_bridge.ros import qos
from sim_bridge.ros.conversions import message_class
from sim_bridge.ros.entry import NodeHooks
from sim_bridge.ros.params import declare_config
from std_msgs.msg import String
from std_srvs.srv import Trigger
from suture_lfd import bags
from suture_lfd.bags.losses import PublicationGaps
from suture_lfd.nodes import executables

_STOP = object()
DRAIN = 200   # messages a callback takes from its subscription's queue after its own


@dataclass(frozen=True)
class RecorderConfig:
    """Parameters of the recorder node (names as in ``config/recorder.yaml``)."""

    output_dir: str = 'demonstrations'
    prefix: str = 'demo'
    arms: tuple[str, ...] = ARMS
    arm_topics: tuple[str, ...] = ()
    topics: tuple[str, ...] = ()
    patterns: tuple[str, ...] = ()
    discovery_period: float = 1.0
    types: tuple[str, ...] = ()
    latched: tuple[str, ...] = ()
    best_effort: tuple[str, ...] = ()
    carry_over: tuple[str, ...] = ()
    record_images: bool = False
    image_topics: tuple[str, ...] = ()
    record_clock: bool = False
    toggle_pedal: str = '/footpedals/camera'
    depth: int = 1000
    chunk_bytes: int = bags.CHUNK_BYTES
    chunk_seconds: float = bags.CHUNK_SECONDS
    status_period: float = 1.0

    def __post_init__(self):
        for name in ('discovery_period', 'chunk_seconds', 'status_period'):
            if not getattr(self, name) > 0:
                raise ValueError(f'parameter {name} must be > 0 s, got {getattr(self, name)}')
        if self.depth < 1:
            raise ValueError(f'parameter depth must be >= 1, got {self.depth}')
        for rule in self.types:
            if '=' not in rule:
                raise ValueError(f'parameter types: rule {rule!r} must read <glob>=<pkg/msg/Type>')

    def type_for(self, topic):
        """Return the message type the rules give the absolute ``topic``, or None."""
        for rule in self.types:
            glob, _, msgtype = rule.partition('=')
            if fnmatch.fnmatchcase(topic, glob.strip()):
                return msgtype.strip()
        return None

    def matches(self, name, topic):
        """Whether the absolute ``topic`` matches a glob of the list parameter ``name``."""
        return any(fnmatch.fnmatchcase(topic, glob) for glob in getattr(self, name))


def offered_qos(endpoints, fallback):
    """Return the rosbags QoS profiles of a topic's publishers (``fallback`` if none)."""
    profiles = [bags.make_qos(
        reliable=e.qos_profile.reliability != ReliabilityPolicy.BEST_EFFORT,
        transient_local=e.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL,
        depth=e.qos_profile.depth) for e in endpoints]
    return profiles or [fallback]


class BagSession:
    """One bag being written: the queue, the writer thread and the counts."""

    def __init__(self, path, config, logger):
        self.path = path
        self.received = {}
        self.carried = {}
        self.missed = {}
        self.types = {}
        self.qos = {}
        self.error = None
        self.started_ns = 0       # wall clock (ns) of the start: DDS's received_timestamp
        self._logger = logger
        self._queue = queue.SimpleQueue()
        self._writer = bags.BagWriter(path, chunk_bytes=config.chunk_bytes,
                                      chunk_seconds=config.chunk_seconds)
        self._writer.set_custom_data('suture_lfd.recorder', 'demonstration')
        self._poll = min(0.1, config.chunk_seconds / 2)
        self._thread = threading.Thread(target=self._run, name='bag-writer', daemon=True)
        self._thread.start()

    def put(self, topic, t_ns, rawdata):
        self._queue.put((topic, t_ns, rawdata))

    def _run(self):
        writer = self._writer
        while True:
            try:
                item = self._queue.get(timeout=self._poll)
            except queue.Empty:
                writer.flush_if_due()
                continue
            if item is _STOP:
                break
            if self.error is not None:
                continue
            topic, t_ns, rawdata = item
            try:
                if not writer.has_topic(topic):
                    writer.add_topic(topic, self.types[topic], qos=self.qos[topic])
                writer.write(topic, t_ns, rawdata)
                writer.flush_if_due()
            except (OSError, ValueError) as exc:
                self.error = f'writing {topic} to {self.path} failed: {exc}'
                self._logger.error(self.error)

    def counts(self, closed=False):
        """
        Return per-topic counts and totals as a JSON-ready mapping.

        ``missed``: published, never received; ``queued``: received, not yet written; ``lost``:
        missed, plus (once ``closed``) received but never written.
        """
        written = dict(self._writer.counts)
        topics = sorted(set(self.received) | set(self.carried) | set(written) | set(self.missed))
        per_topic = {t: {'received': self.received.get(t, 0), 'carried': self.carried.get(t, 0),
                         'written': written.get(t, 0), 'missed': self.missed.get(t, 0)}
                     for t in topics}
        total = {k: sum(v[k] for v in per_topic.values())
                 for k in ('received', 'carried', 'written', 'missed')}
        queued = total['received'] + total['carried'] - total['written']
        lost = total['missed'] + (queued if closed else 0)
        return {'bag': str(self.path), **total, 'queued': 0 if closed else queued, 'lost': lost,
                'topics': per_topic}

    def set_custom_data(self, key, value):
        """Store a string in the bag's ``metadata.yaml`` ``custom_data`` (written at close)."""
        self._writer.set_custom_data(key, value)

    def close(self):
        """Write what is queued, close the bag; return the counts."""
        self._queue.put(_STOP)
        self._thread.join()
        summary = self.counts(closed=True)
        self._writer.set_custom_data('suture_lfd.counts', json.dumps(summary['topics']))
        self._writer.set_custom_data('suture_lfd.lost', str(summary['lost']))
        try:
            self._writer.close()
        except (OSError, ValueError) as exc:
            self.error = self.error or f'closing {self.path} failed: {exc}'
        return summary


class Recorder(NodeHooks, Node):
    """Record demonstrations into rosbag2 bags, started and stopped on command."""

    def __init__(self):
        super().__init__('recorder')
        self.config = declare_config(self, RecorderConfig, 'recorder.yaml', 'recorder')
        self._session = None
        self._counter = 0
        self._topic_subs = {}   # absolute topic -> subscription
        self._types = {}           # absolute topic -> msgtype
        self._latched = {}         # absolute topic -> subscribed TRANSIENT_LOCAL
        self._last = {}            # carry-over topic -> last CDR bytes
        self._gaps = PublicationGaps()
        # the streamed topics' subscriptions, and /clock on sim time: spun only while
        # recording (see the module's doc)
        sim_time = bool(self.get_parameter('use_sim_time').value)
        self._streams = rclpy.create_node(
            f'{self.get_name()}_streams', namespace=self.get_namespace(), context=self.context,
            use_global_arguments=False,   # topics are absolute
            start_parameter_services=False,
            parameter_overrides=[Parameter('use_sim_time', value=sim_time)])
        self._ros_clock = self._streams.get_clock()     # the bags' stamps
        if sim_time:   # this node's timers need no /clock: only the streams' node takes it
            self.set_parameters([Parameter('use_sim_time', value=False)])
        self._spinning_streams = False
        self._status_pub = self.create_publisher(String, '~/status', qos.LATCHED)
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        if self.config.toggle_pedal:
            # VOLATILE: a press latched before this node started must not toggle it.
            self.create_subscription(Joy, self.config.toggle_pedal, self._on_pedal,
                                     qos.STREAM)
        self._wanted = []
        for name in self._listed_topics():
            topic = self.resolve_topic_name(name)
            if topic in self._wanted:
                continue
            self._wanted.append(topic)
            msgtype = self.config.type_for(topic)
            if msgtype is not None:
                self._subscribe(topic, msgtype)
        self.create_timer(self.config.discovery_period, self._discover)
        self.create_timer(self.config.status_period, self._publish_status)
        self._publish_status()
        self.get_logger().info(
            f'recording {len(self._topic_subs)} topics (+ discovered ones) into '
            f'{Path(self.config.output_dir).resolve()} on ~/start, ~/stop'
            + (f' or {self.config.toggle_pedal}' if self.config.toggle_pedal else ''))

    # --- topics ----------------------------------------------------------------------------

    def _listed_topics(self):
        cfg = self.config
        names = [f'{arm}/{t}' for arm in cfg.arms for t in cfg.arm_topics]
        names += list(cfg.topics)
        if cfg.record_images:
            names += list(cfg.image_topics)
        if cfg.record_clock:
            names.append('/clock')
        return names

    def _subscribe(self, topic, msgtype, endpoints=()):
        try:
            cls = message_class(msgtype)
        except ValueError as exc:
            self.get_logger().warning(f'{topic}: not recorded: {exc}')
            self._topic_subs[topic] = None
            return
        latched = self.config.matches('latched', topic) or (
            bool(endpoints) and all(e.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                                    for e in endpoints))
        best_effort = self.config.matches('best_effort', topic) or any(
            e.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for e in endpoints)
        profile = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=self.config.depth,
            reliability=(ReliabilityPolicy.BEST_EFFORT if best_effort
                         else ReliabilityPolicy.RELIABLE),
            durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                        else DurabilityPolicy.VOLATILE))
        carry = self.config.matches('carry_over', topic)
        self._types[topic] = msgtype
        self._latched[topic] = latched
        node = self if latched or carry else self._streams
        self._topic_subs[topic] = node.create_subscription(
            cls, topic, functools.partial(self._on_messages, topic, carry), profile, raw=True)

    def _discover(self):
        for topic, types in self.get_topic_names_and_types():
            if topic in self._topic_subs or not types:
                continue
            if topic not in self._wanted and not self.config.matches('patterns', topic):
                continue
            msgtype = self.config.type_for(topic) or types[0]
            endpoints = self.get_publishers_info_by_topic(topic)
            self.get_logger().info(f'discovered {topic} ({msgtype})')
            self._subscribe(topic, msgtype, endpoints)

    def _on_messages(self, topic, carry, rawdata, info):
        """Handle a message, then take the ones queued behind it (at most ``DRAIN``)."""
        self._on_message(topic, carry, rawdata, info)
        sub = self._topic_subs.get(topic)
        if sub is None:
            return
        # The executor hands over one message per wait; at 1 kHz its overhead per wait is what
        # falls behind, so the messages already queued are taken here, in one go.
        with sub.handle:
            for _ in range(DRAIN):
                taken = sub.handle.take_message(sub.msg_type, True)
                if taken is None:
                    return
                self._on_message(topic, carry, taken[0], taken[1])

    def _on_message(self, topic, carry, rawdata, info):
        if carry:
            self._last[topic] = rawdata
        missed = self._gaps.observe(topic, info.get('publication_sequence_number'))
        session = self._session
        if session is None or (info.get('received_timestamp') or session.started_ns) \
                < session.started_ns:      # held by DDS from before the recording
            return
        if missed:
            session.missed[topic] = session.missed.get(topic, 0) + missed
        if topic not in session.types:
            session.types[topic] = self._types[topic]
            fallback = bags.make_qos(transient_local=self._latched[topic],
                                     depth=self.config.depth)
            session.qos[topic] = offered_qos(self.get_publishers_info_by_topic(topic), fallback)
        session.received[topic] = session.received.get(topic, 0) + 1
        session.put(topic, self._ros_clock.now().nanoseconds, rawdata)

    # --- start / stop ----------------------------------------------------------------------

    def _next_path(self):
        out = Path(self.config.output_dir)
        stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S')
        while True:
            self._counter += 1
            path = (out / f'{self.config.prefix}_{stamp}_{self._counter:03d}').resolve()
            if not path.exists():
                return path

    def start(self):
        """Open a new bag; return its path."""
        if self._session is not None:
            raise ValueError(f'already recording to {self._session.path}; call ~/stop first')
        path = self._next_path()
        path.parent.mkdir(parents=True, exist_ok=True)
        session = BagSession(path, self.config, self.get_logger())
        session.started_ns = time.time_ns()
        self._take_clock()
        now = self._ros_clock.now().nanoseconds
        for topic, rawdata in self._last.items():
            session.types[topic] = self._types[topic]
            fallback = bags.make_qos(transient_local=self._latched[topic],
                                     depth=self.config.depth)
            session.qos[topic] = offered_qos(self.get_publishers_info_by_topic(topic), fallback)
            session.carried[topic] = 1
            session.put(topic, now, rawdata)
        self._session = session
        self.get_logger().info(f'recording to {path}')
        self._publish_status()        # at once: what DDS holds may take a while to go through
        self._spin_streams(True)
        return path

    def stop(self, publish=True):
        """Close the bag being written; return its counts."""
        session, self._session = self._session, None
        if session is None:
            raise ValueError('not recording; call ~/start first')
        self._spin_streams(False)
        counts = session.close()
        log = self.get_logger().warning if counts['lost'] else self.get_logger().info
        log(f'closed {session.path}: {counts["written"]} messages written, '
            f'{counts["received"]} received, {counts["carried"]} carried over, '
            f'{counts["missed"]} published but never received, {counts["lost"]} lost')
        if publish:
            self._publish_status(counts)
        if session.error:
            raise ValueError(session.error)
        return counts

    def _spin_streams(self, on):
        """Add the streamed topics' node to this node's executor (``on``) or take it off."""
        executor = self.executor
        if executor is None or on == self._spinning_streams:
            return
        if on:
            self._take_held()
            executor.add_node(self._streams)
        else:
            executor.remove_node(self._streams)
        self._spinning_streams = on

    def _is_clock(self, sub):
        """Whether ``sub`` is the streams' node's own ``/clock`` (its time source's)."""
        return sub.topic_name == '/clock' and sub is not self._topic_subs.get('/clock')

    def _take_clock(self):
        """Set the stamps' clock from the newest ``/clock`` DDS holds (on sim time)."""
        for sub in self._streams.subscriptions:
            if not self._is_clock(sub):
                continue
            newest = None
            with sub.handle:
                while (taken := sub.handle.take_message(sub.msg_type, False)) is not None:
                    newest = taken[0]
            if newest is not None:
                sub.callback(newest)

    def _take_held(self):
        """Take what DDS holds of the streams in one pass (recording what came after start)."""
        for sub in self._streams.subscriptions:
            topic = sub.topic_name
            if self._is_clock(sub):
                continue
            carry = self.config.matches('carry_over', topic)
            with sub.handle:
                while True:
                    taken = sub.handle.take_message(sub.msg_type, True)
                    if taken is None:
                        break
                    self._on_message(topic, carry, taken[0], taken[1])

    def destroy_node(self):
        self._spin_streams(False)
        self._streams.destroy_node()
        return super().destroy_node()

    def _on_start(self, request, response):
        try:
            response.message = str(self.start())
            response.success = True
        except (ValueError, OSError) as exc:
            response.success, response.message = False, str(exc)
            self.get_logger().warning(f'~/start refused: {exc}')
        return response

    def _on_stop(self, request, response):
        try:
            response.message = json.dumps(self.stop())
            response.success = True
        except (ValueError, OSError) as exc:
            response.success, response.message = False, str(exc)
            self.get_logger().warning(f'~/stop refused: {exc}')
        return response

    def _on_pedal(self, msg):
        if list(msg.buttons[:1]) != [1]:
            return
        try:
            if self._session is None:
                self.start()
            else:
                self.stop()
        except (ValueError, OSError) as exc:
            self.get_logger().error(f'{self.config.toggle_pedal}: {exc}')

    def _publish_status(self, counts=None):
        session = self._session
        if counts is None and session is not None:
            counts = session.counts()
        status = {'recording': session is not None, **(counts or {})}
        self._status_pub.publish(String(data=json.dumps(status)))

    def on_interrupt(self, signal_name):
        """Mark the bag being written as ended by a signal (``on_exit`` then closes it)."""
        if self._session is not None:
            self._session.set_custom_data('suture_lfd.outcome', 'interrupted')
            self.get_logger().warning(f'{signal_name} while recording {self._session.path}: '
                                      'the bag is closed with what it holds, outcome interrupted')

    def on_exit(self):
        """Close the bag if one is open (on exit)."""
        if self._session is not None:
            try:
                self.stop(publish=False)
            except ValueError as exc:
                self.get_logger().error(str(exc))


def main(args=None):
    return executables.recorder(args)


if __name__ == '__main__':
    sys.exit(main())
