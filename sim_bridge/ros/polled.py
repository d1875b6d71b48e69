"""
Streams a node reads once per cycle: the newest sample of each, and no callback per sample.

A node short of CPU then skips to the newest sample instead of working through a queue of stale
ones, and a stream that brings nothing new costs nothing between the node's cycles. The
subscriptions belong to a node that is never spun (its callbacks never run); :meth:`read` takes
their samples at the cycle.
"""


class PolledInputs:
    """The streams of one node, each read by a handler at the node's cycle."""

    def __init__(self, node, resolve):
        """
        Keep the streams of ``node``.

        ``node`` is the unspun node that owns the subscriptions; ``resolve`` gives a topic's full
        name (the spinning node's ``resolve_topic_name``, so that names resolve in its namespace).
        """
        self._node = node
        self._resolve = resolve
        self._streams = []

    def add(self, msg_type, name, handler, qos_profile):
        """Subscribe to topic ``name``; :meth:`read` hands its newest sample to ``handler``."""
        sub = self._node.create_subscription(msg_type, self._resolve(name), lambda msg: None,
                                             qos_profile)
        self._streams.append((sub, handler))

    def read(self):
        """Hand the newest sample of every stream, if a new one came, to its handler."""
        for sub, handler in self._streams:
            msg = None
            with sub.handle:
                while True:
                    taken = sub.handle.take_message(sub.msg_type, False)
                    if taken is None:
                        break
                    msg = taken[0]
            if msg is not None:
                handler(msg)
