"""
A command topic taken from latched and volatile publishers alike: once, in order, never stale.

Why two subscriptions. A dVRK client (crtk) publishes ``state_command`` latched (RELIABLE,
TRANSIENT_LOCAL) and sends ``enable`` milliseconds after creating its node, without waiting for
DDS discovery to match it with the receiver. A volatile subscription never receives a sample
written before the match, so that command was lost. A transient-local subscription receives it
(the publisher keeps its last samples and hands them to a reader that matches later), but it does
not match a volatile publisher (``ros2 topic pub``, a client that does not latch). So each topic
has both, 100 deep (the dVRK simulators' contract queues up to 32 commands; a latched command
fills both readers, hence the margin), and a burst is queued, never dropped.

Once. A latched publisher's sample reaches both subscriptions; it is applied the first time, and
the second copy is recognised by its sender's source timestamp, publication sequence number and
fields. Not by its serialized bytes: CDR's alignment padding is not initialised, so two
serializations of one message can differ (a copy applied twice, once in a few runs).

Order. One reader delivers one publisher's samples in order, and the transient-local reader also
delivers a latched publisher's history before its live samples. But the volatile reader may get a
live sample of a latched publisher before the transient-local reader has received that
publisher's older history (on matching, the history follows the live sample). So while a
latched publisher exists on the topic, a sample seen first by the volatile reader waits up to
:data:`HOLD` seconds for its latched copy, which is applied in its place, in the latched order; a
volatile publisher's samples have no latched copy and are applied when their wait ends, in
their order. With no latched publisher on the topic, the volatile reader's samples are applied
at once.

Stale. A transient-local reader also receives history written before its process existed: the
commands of a client still alive that drove an earlier run of this node (a restarted simulator
would enable and home an arm nobody asked it to). A latched sample written (source timestamp, on
the sender's system clock) before this process started is stale: it is dropped and reported
through ``on_stale``. A client that exited takes its history with it; a subscription created
late in its node's start-up still takes what was written after the process started. A client
that sends before the receiver's process is started must send again, as it would with a volatile
subscription. The rule compares two system clocks: on one machine they are the same; across
machines their offset shifts the line.

Threads: every callback runs on the owning node's executor (single-threaded in this project).
"""

from collections import deque
import time

from rclpy.qos import DurabilityPolicy
from sim_bridge.ros import qos
from sim_bridge.ros.peer import process_start_ns

# s a sample first seen by the volatile reader waits for its latched copy while a latched
# publisher exists on the topic: a transient-local reader gets a new publisher's history within
# a few ms of the match on loopback, and hundreds of ms on a loaded machine
HOLD = 0.25
# commands remembered to recognise the second copy of a latched one; a copy arrives within
# HOLD of the first, when at most a few hundred commands can have arrived in between
_REMEMBERED = 4096
_TICK = 0.01  # s between checks of the commands waiting for their latched copy


class CommandIntake:
    """
    The two subscriptions of one command topic and the rules that merge them.

    Parameters
    ----------
    node : rclpy.node.Node
        Owner of the subscriptions and of the timer that ends waits.
    msg_type : type
        Message type of the topic.
    topic : str
        Topic name (relative names resolve in the node's namespace).
    handler : callable
        ``handler(msg, sent_ns)``: called once per command, in order; ``sent_ns`` is the
        sender's source timestamp (int ns, system clock) or None when the middleware gives none.
    on_stale : callable, optional
        ``on_stale(msg, age_s)``: called for a dropped stale command, ``age_s`` being how long
        before this process started it was written (s).
    started_ns : int, optional
        Commands written before this time (ns, system clock) are stale (default: the start of
        this process).
    hold : float, optional
        s a volatile reader's sample waits for its latched copy (default :data:`HOLD`).
    **kwargs
        Passed to ``create_subscription`` (``callback_group``, ``event_callbacks``).

    Attributes
    ----------
    stale, duplicates : int
        Commands dropped as stale, copies dropped as already applied.

    """

    def __init__(self, node, msg_type, topic, handler, on_stale=None, started_ns=None,
                 hold=HOLD, **kwargs):
        self._node = node
        self._handler = handler
        self._on_stale = on_stale or (lambda msg, age: None)
        self.started_ns = process_start_ns() if started_ns is None else int(started_ns)
        self._hold = float(hold)
        self._seen = set()
        self._remembered = deque()
        self._waiting = deque()  # [deadline (monotonic s), key, msg, sent ns], oldest first
        self._timer = None
        self.stale = 0
        self.duplicates = 0
        self.latched = node.create_subscription(msg_type, topic, self._on_latched,
                                                qos.LATCHED_COMMANDS, **kwargs)
        self.volatile = node.create_subscription(msg_type, topic, self._on_volatile,
                                                 qos.QUEUED_COMMANDS, **kwargs)

    # -- the two readers -----------------------------------------------------------------------

    def _on_latched(self, msg, info):
        sent = info.get('source_timestamp')
        key = self._key(msg, info)
        if key in self._seen:
            self.duplicates += 1
            return
        if sent is not None and sent < self.started_ns:
            self.stale += 1
            self._remember(key)
            self._on_stale(msg, (self.started_ns - sent) * 1e-9)
            return
        for item in self._waiting:
            if item[1] == key:  # its volatile copy is waiting: apply it now, in latched order
                self._waiting.remove(item)
                break
        self._apply(key, msg, sent)

    def _on_volatile(self, msg, info):
        key = self._key(msg, info)
        if key in self._seen or any(item[1] == key for item in self._waiting):
            self.duplicates += 1
            return
        sent = info.get('source_timestamp')
        if not self._waiting and not self._latched_publishers():
            self._apply(key, msg, sent)
            return
        self._waiting.append([time.monotonic() + self._hold, key, msg, sent])
        if self._timer is None:
            self._timer = self._node.create_timer(_TICK, self._release)
        elif self._timer.is_canceled():
            self._timer.reset()

    def _release(self):
        """Apply, in order, the volatile samples whose wait for a latched copy has ended."""
        now = time.monotonic()
        while self._waiting and self._waiting[0][0] <= now:
            _, key, msg, sent = self._waiting.popleft()
            self._apply(key, msg, sent)
        if not self._waiting:
            self._timer.cancel()

    # -- helpers -------------------------------------------------------------------------------

    @staticmethod
    def _key(msg, info):
        return (info.get('source_timestamp'), info.get('publication_sequence_number'), repr(msg))

    def _latched_publishers(self):
        """Return whether a transient-local publisher is on the topic (graph, no I/O)."""
        infos = self._node.get_publishers_info_by_topic(self.volatile.topic_name)
        return any(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)

    def _remember(self, key):
        self._seen.add(key)
        self._remembered.append(key)
        if len(self._remembered) > _REMEMBERED:
            self._seen.discard(self._remembered.popleft())

    def _apply(self, key, msg, sent):
        self._remember(key)
        self._handler(msg, sent)
