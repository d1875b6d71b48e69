"""
Messages lost between a publisher and a subscriber, counted from publication sequence numbers.

Every DDS writer numbers its samples 1, 2, 3, ... and rmw hands the number to the subscriber
with each message (``publication_sequence_number`` of rclpy's message info). A gap in one
writer's numbers is a message that writer published and this subscriber never received
(overwritten in a history, dropped by a best-effort link). rclpy's message info does not say
which writer sent a message, so :class:`PublicationGaps` follows one stream per writer by
matching each number to the stream it continues: the stream whose last number is the highest
below it; a number no stream is below is a new writer (one that started, or restarted, later).
With one publisher per topic the count is exact; with several it stays exact as long as no
stream jumps past another's numbers by a loss.
"""


class PublicationGaps:
    """Count the publication sequence numbers a subscriber never saw, per topic."""

    def __init__(self) -> None:
        # topic -> list of the last number of each writer
        self._streams: dict[str, list[int]] = {}
        # topic -> messages missed since the topic's first message
        self.missed: dict[str, int] = {}

    def observe(self, topic: str, sequence: int | None) -> int:
        """
        Note a received message's publication sequence number.

        Parameters
        ----------
        topic : str
            Topic it came on.
        sequence : int or None
            Its ``publication_sequence_number`` (None or 0 when rmw does not provide one).

        Returns
        -------
        int
            Messages of its writer missed just before it (0 for the first of a writer).

        """
        if not sequence:
            return 0
        streams = self._streams.setdefault(topic, [])
        below = [k for k, last in enumerate(streams) if last < sequence]
        if not below:
            streams.append(sequence)
            return 0
        k = max(below, key=streams.__getitem__)
        gap = sequence - streams[k] - 1
        streams[k] = sequence
        if gap:
            self.missed[topic] = self.missed.get(topic, 0) + gap
        return gap
