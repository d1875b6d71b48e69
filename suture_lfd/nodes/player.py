"""
Player: replays a rosbag2 bag onto its topics with the recorded timing.

Publishes the stored CDR bytes unchanged (publishers of each topic's type, QoS from the bag's
offered profiles: RELIABLE/BEST_EFFORT and TRANSIENT_LOCAL/VOLATILE as recorded), spaced as
the time stamps were, divided by ``rate``. Optionally starts ``start_offset`` seconds into the
bag, plays only ``topics``, loops, and publishes ``/clock`` from the bag time. When done it
waits until reliable subscribers have acknowledged every message, publishes ``~/done``
(std_msgs/String, JSON counts, latched), logs ``done:`` and exits (or idles with
``exit_when_done: false``).
"""

from dataclasses import dataclass
import json
import sys
import threading
import time

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sim_bridge.ros import qos
from sim_bridge.ros.conversions import message_class
from sim_bridge.ros.entry import NodeHooks
from sim_bridge.ros.params import declare_config
from std_msgs.msg import String
from suture_lfd import bags
from suture_lfd.nodes import executables


@dataclass(frozen=True)
class PlayerConfig:
    """Parameters of the player node (names as in ``config/player.yaml``)."""

    bag: str = ''
    rate: float = 1.0
    loop: bool = False
    start_offset: float = 0.0
    topics: tuple[str, ...] = ()
    publish_clock: bool = False
    clock_rate: float = 100.0
    depth: int = 1000
    wait_for_subscribers: float = 0.0
    exit_when_done: bool = True

    def __post_init__(self):
        if not self.bag:
            raise ValueError('parameter bag is empty: pass the bag directory, '
                             '--ros-args -p bag:=PATH')
        if not self.rate > 0:
            raise ValueError(f'parameter rate must be > 0, got {self.rate}')
        if self.start_offset < 0:
            raise ValueError(f'parameter start_offset must be >= 0 s, got {self.start_offset}')
        if not self.clock_rate > 0:
            raise ValueError(f'parameter clock_rate must be > 0 Hz, got {self.clock_rate}')
        if self.depth < 1:
            raise ValueError(f'parameter depth must be >= 1, got {self.depth}')


def playback_qos(profiles, depth):
    """Return the rclpy QoS of a publisher replaying a topic recorded with ``profiles``."""
    fields = bags.qos_fields(profiles) or (True, False, depth)
    reliable, latched, _ = fields
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class Player(NodeHooks, Node):
    """Replay a bag onto its topics."""

    def __init__(self):
        super().__init__('player')
        self.config = declare_config(self, PlayerConfig, 'player.yaml', 'player')
        self.reader = bags.open_bag(self.config.bag, required=self.config.topics)
        topics = list(self.config.topics) or sorted(self.reader.topics)
        self._topic_pubs = {}
        for topic in topics:
            info = self.reader.topics[topic]
            try:
                cls = message_class(info.msgtype)
            except ValueError as exc:
                self.get_logger().warning(f'{topic}: not played: {exc}')
                continue
            self._topic_pubs[topic] = self.create_publisher(
                cls, topic, playback_qos(info.qos, self.config.depth))
        self._clock_pub = (self.create_publisher(Clock, '/clock', qos.CLOCK)
                           if self.config.publish_clock else None)
        self._done_pub = self.create_publisher(String, '~/done', qos.LATCHED)
        self.published = dict.fromkeys(self._topic_pubs, 0)
        self.exit_code = 0
        self._done = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name='bag-player', daemon=True)
        self._thread.start()

    def _wait_for_subscribers(self):
        deadline = time.monotonic() + self.config.wait_for_subscribers
        while time.monotonic() < deadline and not self._stop.is_set():
            if all(p.get_subscription_count() > 0 for p in self._topic_pubs.values()):
                return
            time.sleep(0.02)
        if self.config.wait_for_subscribers > 0:
            lonely = [t for t, p in self._topic_pubs.items() if p.get_subscription_count() == 0]
            if lonely:
                self.get_logger().warning(f'playing without subscribers on {", ".join(lonely)}')

    def _sleep_until(self, due):
        while not self._stop.is_set():
            left = due - time.monotonic()
            if left <= 0:
                return True
            time.sleep(min(left, 0.05))
        return False

    def _publish_clock(self, t_ns):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 10**9)
        self._clock_pub.publish(msg)

    def _play_once(self):
        summary = self.reader.summary
        start_ns = summary.start_ns + int(round(self.config.start_offset * 1e9))
        clock_step = int(1e9 / self.config.clock_rate)
        next_clock = None
        t0 = time.monotonic()
        for message in self.reader.messages(list(self._topic_pubs), start_ns=start_ns):
            if not self._sleep_until(t0 + (message.t_ns - start_ns) * 1e-9 / self.config.rate):
                return False
            if self._clock_pub is not None and (next_clock is None or message.t_ns >= next_clock):
                self._publish_clock(message.t_ns)
                next_clock = message.t_ns + clock_step
            self._topic_pubs[message.topic].publish(bytes(message.rawdata))
            self.published[message.topic] += 1
        return True

    def _play(self):
        try:
            self._wait_for_subscribers()
            self.get_logger().info(
                f'playing {self.config.bag}: {len(self._topic_pubs)} topics, '
                f'{self.reader.summary.duration_s:.3f} s at rate {self.config.rate}')
            loops = 0
            began = time.monotonic()
            while not self._stop.is_set():
                if not self._play_once():
                    return
                loops += 1
                if not self.config.loop:
                    break
            played = time.monotonic() - began
            for pub in self._topic_pubs.values():
                pub.wait_for_all_acked(Duration(seconds=5.0))
            total = sum(self.published.values())
            done = {'bag': self.config.bag, 'published': total, 'loops': loops,
                    'topics': self.published, 'wall_time': played}
            self._done_pub.publish(String(data=json.dumps(done)))
            self._done_pub.wait_for_all_acked(Duration(seconds=1.0))
            self.get_logger().info(f'done: {total} messages on {len(self.published)} topics '
                                   f'in {played:.3f} s')
        except bags.BagError as exc:
            self.get_logger().error(str(exc))
            self.exit_code = 1
        finally:
            self._done.set()

    @property
    def finished(self):
        """Return True once the bag is played and the node should exit (``exit_when_done``)."""
        return self._done.is_set() and self.config.exit_when_done

    def on_exit(self):
        """Stop playing and close the bag."""
        self._stop.set()
        self._thread.join(2.0)
        self.reader.close()


def main(args=None):
    return executables.player(args)


if __name__ == '__main__':
    sys.exit(main())
