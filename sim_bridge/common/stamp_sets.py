"""
Per arm, the newest complete set of state messages that share one stamp.

A robot publishes an arm's state as several messages per state period (``measured_cp``,
``local/measured_cp``, ``measured_js``, ``jaw/measured_js``), all stamped with the period's
time, and they arrive one by one, possibly interleaved with the next period's. A controller that
combines the newest of each combines parts of different periods (a tool pose with the joints of
another instant) whenever the stream lags. :class:`StampSets` pairs them up by stamp: a set
becomes the arm's state only once every part of it has come with the same stamp, and only when
that stamp is newer than the arm's current state.

Units: stamps in seconds (any clock, compared for equality and order only).
"""

from collections.abc import Iterable, Mapping
from typing import Any


class StampSets:
    """
    Pair state messages of one stamp per arm; keep the newest complete set.

    Parameters
    ----------
    arms : iterable of str
        The arms followed.
    parts : iterable of str
        The parts that make a set (``'cp'``, ``'js'``...); every one must come with a stamp for
        the set of that stamp to be complete.
    pending : int
        How many incomplete stamps are kept per arm (the oldest is dropped beyond).

    Examples
    --------
    >>> sets = StampSets(['PSM1'], ['cp', 'js'])
    >>> sets.put('PSM1', 'cp', 1.0, 'pose at 1')
    False
    >>> sets.put('PSM1', 'cp', 2.0, 'pose at 2')
    False
    >>> sets.put('PSM1', 'js', 1.0, 'joints at 1')
    True
    >>> sets.newest('PSM1')
    (1.0, {'cp': 'pose at 1', 'js': 'joints at 1'})

    """

    def __init__(self, arms: Iterable[str], parts: Iterable[str], pending: int = 16) -> None:
        self.parts = tuple(dict.fromkeys(parts))
        if not self.parts:
            raise ValueError('StampSets needs at least one part')
        if pending < 1:
            raise ValueError(f'pending must be >= 1, got {pending}')
        self._pending_max = int(pending)
        self._pending: dict[str, dict[float, dict[str, Any]]] = {a: {} for a in arms}
        self._complete: dict[str, tuple[float, dict[str, Any]]] = {}

    def put(self, arm: str, part: str, stamp: float, value: Any) -> bool:
        """
        Take one message; return whether it completed a newer set for ``arm``.

        Parameters
        ----------
        arm : str
        part : str
            One of :attr:`parts`.
        stamp : float
            The message's stamp (s).
        value : object
            The message (or what the caller keeps of it).

        """
        if part not in self.parts:
            raise ValueError(f'unknown part {part!r}: expected one of {self.parts}')
        pending = self._pending[arm]
        done = self._complete.get(arm)
        if done is not None and stamp <= done[0]:
            return False  # older than (or a repeat of) the arm's state: nothing to complete
        parts = pending.setdefault(stamp, {})
        parts[part] = value
        if len(parts) < len(self.parts):
            if len(pending) > self._pending_max:
                del pending[min(pending)]
            return False
        self._complete[arm] = (stamp, {p: parts[p] for p in self.parts})
        for s in [s for s in pending if s <= stamp]:
            del pending[s]
        return True

    def newest(self, arm: str) -> tuple[float, dict[str, Any]] | None:
        """Return the arm's newest complete set ``(stamp, {part: value})``, or None."""
        return self._complete.get(arm)

    def stamps(self) -> Mapping[str, float]:
        """Return per arm the stamp (s) of its newest complete set (arms without one left out)."""
        return {a: s for a, (s, _) in self._complete.items()}
