"""
The exceptions of the learning-from-demonstration package, in one place.

Configuration errors are :class:`sim_bridge.common.errors.ConfigError` (shared by both packages).
"""

from collections.abc import Iterable


class BagError(ValueError):
    """A bag is missing, unreadable, truncated, corrupt or lacks what the caller needs."""


class McapDamageError(ValueError):
    """A part of an MCAP file fails its check; ``offset`` (bytes) and ``topics`` say where."""

    def __init__(self, what: str, offset: int, topics: Iterable[str] = ()) -> None:
        self.what, self.offset, self.topics = what, int(offset), tuple(topics)
        where = f' (topic {", ".join(self.topics)})' if self.topics else ''
        super().__init__(f'{what} at byte {self.offset}{where}')


class DemonstrationError(RuntimeError):
    """A demonstration could not be completed (timeout, or every attempt failed)."""


class RosThrowError(RuntimeError):
    """A throw the node processes did not carry out (crash, hang, watchdog); says why."""
