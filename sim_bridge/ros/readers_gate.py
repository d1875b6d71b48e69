"""
An arm's state changes announced only once its new readers can get its state.

A physical dVRK takes seconds to power up and home, so a client that sends ``enable`` and
``home`` as soon as its node exists (crtk's latched ``state_command``) has its state streams
(``measured_cp``, ``setpoint_cp``, ...) matched long before it sees the arm ready. An arm that
powers and homes at once (the simulator's fast start, the virtual MTMs) would announce
``ENABLED`` and ``is_homed`` while discovery has matched the client's ``operating_state`` reader
but not yet its stream readers, and the client's first getter would find no data. The
:class:`ReadersGate` holds the arm's events (in order) until each of its stream publishers has
matched at least as many readers as its ``operating_state`` publisher, or for ``max_wait``
seconds at most (a reader of the events alone, such as ``ros2 topic echo``, delays them no
longer than that).
"""

from collections.abc import Callable, Sequence
import time


class ReadersGate:
    """
    Hold an arm's events until its state streams reach every reader of its events.

    Parameters
    ----------
    events : rclpy.publisher.Publisher
        The arm's ``operating_state`` publisher.
    streams : sequence of rclpy.publisher.Publisher
        The state streams a client reads once the arm is ready.
    max_wait : float
        s at most that events are held.
    clock : callable, optional
        Monotonic time in s (default :func:`time.monotonic`).

    """

    def __init__(self, events, streams: Sequence, max_wait: float = 0.5,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._events = events
        self._streams = tuple(streams)
        self.max_wait = float(max_wait)
        self._clock = clock
        self._since: float | None = None

    def matched(self) -> bool:
        """Whether every stream has matched as many readers as the events have."""
        n = self._events.get_subscription_count()
        return all(p.get_subscription_count() >= n for p in self._streams)

    def holds(self) -> bool:
        """
        Whether events must wait now.

        The first call that finds the streams behind starts the wait; it ends when they catch
        up or ``max_wait`` s later.
        """
        if self.matched():
            self._since = None
            return False
        now = self._clock()
        if self._since is None:
            self._since = now
        return now - self._since < self.max_wait
