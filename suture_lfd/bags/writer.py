"""
Writing a bag that a crash leaves recoverable; the CDR bytes of a demonstration's messages.

:class:`BagWriter` closes an MCAP chunk every ``chunk_seconds`` or ``chunk_bytes`` and pushes it
to the operating system, so a writer killed mid-recording leaves every message written up to the
last flush in complete chunks (:func:`suture_lfd.bags.recovery.recover_bag` rebuilds the bag).
"""

from collections.abc import Iterable, Sequence
from pathlib import Path
import re
import time
from typing import Any, cast

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.errors import WriterError
from rosbags.rosbag2.storage_mcap import McapWriter
from sim_bridge.common import cdr
from suture_lfd.bags.format import METADATA, ROS_DISTRO, ensure_type, make_typestore
from suture_lfd.bags.mcap_check import CrcMcapWriter
from suture_lfd.errors import BagError

CHUNK_BYTES = 256 * 1024
CHUNK_SECONDS = 0.5
MCAP_CHUNK_LIMIT = 2**20  # rosbags closes a chunk itself past 1 MiB


class BagWriter:
    """
    Write a rosbag2 bag (metadata v9 + MCAP) that a crash leaves recoverable.

    Messages go into an MCAP chunk that is closed and handed to the operating system when it
    holds ``chunk_bytes`` or after ``chunk_seconds`` (see :meth:`flush_if_due`), so a process
    killed mid-recording loses at most the open chunk. ``close()`` writes the MCAP summary and
    ``metadata.yaml``. Use it as a context manager; leaving the block on an exception closes
    the bag too (what was written stays valid). Relies on rosbags 0.11's MCAP writer internals
    (pending chunk, file object) for the flushes.

    Parameters
    ----------
    path : str or Path
        Bag directory to create; must not exist.
    typestore : rosbags.typesys.store.Typestore, optional
        Types for definitions and hashes; default :func:`make_typestore`.
    chunk_bytes : int
        Close a chunk when it holds this many bytes (at most 1 MiB).
    chunk_seconds : float
        :meth:`flush_if_due` closes a non-empty chunk this many seconds after the last flush.

    """

    def __init__(self, path: str | Path, *, typestore: Any = None, chunk_bytes: int = CHUNK_BYTES,
                 chunk_seconds: float = CHUNK_SECONDS) -> None:
        self.path = Path(path)
        if not 0 < chunk_bytes <= MCAP_CHUNK_LIMIT:
            raise ValueError(f'chunk_bytes must be in (0, {MCAP_CHUNK_LIMIT}], got {chunk_bytes}')
        if not chunk_seconds > 0:
            raise ValueError(f'chunk_seconds must be > 0, got {chunk_seconds}')
        if self.path.exists():
            raise BagError(f'{self.path}: exists already; a bag is never overwritten, '
                           'choose another name')
        self.typestore = typestore if typestore is not None else make_typestore()
        self.chunk_bytes = int(chunk_bytes)
        self.chunk_seconds = float(chunk_seconds)
        self.counts: dict[str, int] = {}
        self._connections: dict[str, Any] = {}
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS,
                                        StoragePlugin.MCAP: CrcMcapWriter}
        try:
            self._writer.open()
        except (OSError, WriterError) as exc:
            raise BagError(f'{self.path}: cannot create the bag ({exc})') from exc
        if not isinstance(self._writer.storage, McapWriter):
            raise TypeError('BagWriter needs the rosbags MCAP storage writer')
        self._last_flush = time.monotonic()

    @property
    def mcap_path(self) -> Path:
        """Path of the bag's MCAP file."""
        return self.path / f'{self.path.name}.mcap'

    def add_topic(self, topic: str, msgtype: str, *, qos: Sequence[Any] = (),
                  msgdef: str | None = None) -> None:
        """
        Declare a topic before its first message (again for the same type: no-op).

        Parameters
        ----------
        topic : str
            Absolute topic name.
        msgtype : str
            ``'pkg/msg/Name'``.
        qos : sequence of rosbags.interfaces.Qos
            Offered QoS profiles, stored for playback.
        msgdef : str, optional
            Definition of a type the typestore does not know (``ros2msg`` format).

        """
        if topic in self._connections:
            have = self._connections[topic].msgtype
            if have != msgtype:
                raise BagError(f'{self.path}: topic {topic} is recorded as {have}, '
                               f'cannot add it again as {msgtype}')
            return
        ensure_type(self.typestore, msgtype, msgdef)
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self.typestore, offered_qos_profiles=list(qos))
        self.counts[topic] = 0

    def has_topic(self, topic: str) -> bool:
        """Whether ``topic`` was declared with :meth:`add_topic`."""
        return topic in self._connections

    def write(self, topic: str, t_ns: int, rawdata: bytes) -> None:
        """
        Append one serialised message.

        Parameters
        ----------
        topic : str
            A topic declared with :meth:`add_topic`.
        t_ns : int
            Time stamp, nanoseconds.
        rawdata : bytes
            CDR-serialised message.

        """
        try:
            connection = self._connections[topic]
        except KeyError:
            raise BagError(f'{self.path}: topic {topic} was not added; call add_topic first') \
                from None
        self._writer.write(connection, int(t_ns), rawdata)
        self.counts[topic] += 1
        # the MCAP storage writer (checked at open; cast: typing only)
        if cast(McapWriter, self._writer.storage).chunk.bio.tell() >= self.chunk_bytes:
            self.flush()

    def flush(self) -> None:
        """Close the open chunk (if it holds messages) and hand the file data to the OS."""
        storage = cast('McapWriter | None', self._writer.storage)  # MCAP (checked at open)
        if storage is None:
            return
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()
        self._last_flush = time.monotonic()

    def flush_if_due(self) -> bool:
        """Flush when ``chunk_seconds`` passed since the last flush; return whether it did."""
        if time.monotonic() - self._last_flush >= self.chunk_seconds:
            self.flush()
            return True
        return False

    def set_custom_data(self, key: object, value: object) -> None:
        """Store a string in the ``custom_data`` of ``metadata.yaml`` (written at close)."""
        self._writer.set_custom_data(str(key), str(value))

    def close(self) -> Path:
        """
        Finish the bag: MCAP summary and ``metadata.yaml``.

        Returns
        -------
        Path
            The bag directory.

        """
        if self._writer.storage is not None:
            self._writer.close()
            _name_ros_distro(self.path / METADATA)
        return self.path

    def abort(self) -> None:
        """Close the file without summary or ``metadata.yaml`` (a recoverable bag remains)."""
        if self._writer.storage is not None:
            self.flush()
            self._writer.abort()

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()



def _name_ros_distro(meta: Path) -> None:
    """Write the ROS distribution the bag's types are from (rosbags' writer names itself)."""
    text = meta.read_text()
    meta.write_text(re.sub(r'^(\s*ros_distro:)\s*rosbags\s*$', rf'\1 {ROS_DISTRO}', text,
                           flags=re.M))



def _nanoseconds(t: float) -> int:
    return int(round(float(t) * 1e9))


def pose_stamped_cdr(t: float, frame_id: str, pose: Sequence[float]) -> bytes:
    """
    Return the CDR bytes of a geometry_msgs/PoseStamped.

    See :func:`sim_bridge.common.cdr.pose_stamped`.

    Little endian, padding zeroed as rosbags writes it.

    Parameters
    ----------
    t : float
        Header stamp (s), rounded to the nanosecond.
    frame_id : str
        Header frame.
    pose : sequence of 7 float
        ``(x, y, z, qx, qy, qz, qw)``.

    """
    return cdr.pose_stamped(_nanoseconds(t), frame_id, pose)


def joint_state_cdr(t: float, names: Iterable[str], position: Sequence[float]) -> bytes:
    """Return the CDR bytes of a sensor_msgs/JointState of ``name`` and ``position`` only."""
    return cdr.joint_state(_nanoseconds(t), tuple(names), position)

