"""
Reading a bag without ROS: integrity checks, topics, counts, messages as CDR bytes, a summary.

Opening a bag checks the CRC-32s of its MCAP chunks, data section and summary
(:mod:`suture_lfd.bags.mcap_check`) and that ``metadata.yaml`` agrees with the MCAP summary, so a
flipped byte is refused before any message is read.
"""

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
import logging
import mmap
import os
from pathlib import Path
import struct
from typing import Any, NamedTuple

from rosbags.rosbag2 import Reader
from rosbags.rosbag2.errors import ReaderError
from suture_lfd.bags.format import METADATA, ensure_type, make_typestore, qos_fields
from suture_lfd.bags.mcap_check import McapFacts, check_mcap
from suture_lfd.errors import BagError, McapDamageError
import yaml

LOG = logging.getLogger(__name__)


class BagMessage(NamedTuple):
    """One stored message: topic, type (``'pkg/msg/Name'``), time stamp (ns), CDR bytes."""

    topic: str
    msgtype: str
    t_ns: int
    rawdata: bytes


@dataclass(frozen=True)
class TopicSummary:
    """A topic of a bag: message type, message count, offered QoS profiles (rosbags Qos)."""

    msgtype: str
    count: int
    qos: tuple = ()


@dataclass(frozen=True)
class BagSummary:
    """
    What a bag holds.

    Attributes
    ----------
    path : Path
        Bag directory.
    storage : str
        Storage identifier (``'mcap'``).
    message_count : int
        Messages in the bag.
    start_ns, end_ns : int
        Time stamps of the first and last message, nanoseconds (0 for an empty bag).
    topics : dict[str, TopicSummary]
        Topics by name.

    """

    path: Path
    storage: str
    message_count: int
    start_ns: int
    end_ns: int
    topics: dict

    @property
    def duration_s(self) -> float:
        """Time between the first and last message, seconds."""
        return max(0, self.end_ns - self.start_ns) * 1e-9




def _checked_storage(path: Path, file: Path) -> McapFacts | None:
    """Check an MCAP storage file's frame and CRCs; return its :class:`McapFacts`."""
    if file.suffix != '.mcap':
        return None
    try:
        with open(file, 'rb') as handle:
            # mapped, not read: a bag with camera images may be larger than the memory at hand
            data = (mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
                    if os.fstat(handle.fileno()).st_size else b'')
        return check_mcap(data)
    except OSError as exc:
        raise BagError(f'{file}: cannot read the bag ({exc})') from None
    except McapDamageError as exc:
        raise BagError(f'{file}: damaged bag: {exc}; run `suture-lfd bag recover {path}` to keep '
                       'what checks out') from None



def _agree_with_metadata(path: Path, summary: BagSummary,
                         facts: list[McapFacts | None]) -> None:
    """Refuse a ``metadata.yaml`` whose topics, counts or times differ from the MCAP summary."""
    if len(facts) != 1 or facts[0] is None or not facts[0].counts:
        return
    mcap = facts[0]
    said = {t: s.count for t, s in summary.topics.items() if s.count}
    if said != mcap.counts or summary.message_count != mcap.message_count or (
            mcap.message_count and (summary.start_ns, summary.end_ns)
            != (mcap.start_ns, mcap.end_ns)):
        raise BagError(f'{path / METADATA}: disagrees with the MCAP summary of the bag (topics, '
                       'counts or times); the metadata file is damaged, run `suture-lfd bag '
                       f'recover {path}` to rebuild it')


def _check_bag_dir(path: str | Path) -> tuple[Path, list[Path]]:
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag (expected a rosbag2 directory)')
    if not path.is_dir():
        raise BagError(f'{path}: not a rosbag2 directory; pass the folder that holds '
                       f'{METADATA} and the .mcap file')
    meta = path / METADATA
    if not meta.is_file():
        raise BagError(f'{meta} is missing: the recording was not closed; run '
                       f'`suture-lfd bag recover {path}` to rebuild the bag')
    try:
        data = yaml.safe_load(meta.read_text())
        info = data['rosbag2_bagfile_information']
        files = [path / f for f in info['relative_file_paths']]
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise BagError(f'{meta}: not a rosbag2 metadata file ({exc!r})') from exc
    for file in files:
        if not file.is_file():
            raise BagError(f'{file}: missing storage file named in {meta}')
    return path, files


class BagReader:
    """
    Read a rosbag2 bag without ROS: topics, counts, and messages as CDR bytes.

    Iterating yields :class:`BagMessage` tuples in time-stamp order. Use :func:`open_bag`;
    close it (or use it as a context manager) when done.

    """

    def __init__(self, path: str | Path, *, typestore: Any = None) -> None:
        self.path, self.files = _check_bag_dir(path)
        self.typestore = typestore if typestore is not None else make_typestore()
        facts = [_checked_storage(self.path, file) for file in self.files]
        self._reader = Reader(self.path)
        try:
            self._reader.open()
        except (ReaderError, OSError, struct.error, ValueError, KeyError) as exc:
            raise BagError(f'{self._files_text()}: unreadable or truncated bag ({exc}); if the '
                           f'recording was interrupted, run `suture-lfd bag recover '
                           f'{self.path}`') from exc
        for connection in self._reader.connections:
            if connection.msgtype not in self.typestore.fielddefs:
                try:
                    ensure_type(self.typestore, connection.msgtype, connection.msgdef.data)
                except BagError as exc:
                    LOG.warning('%s: cannot decode %s: %s', self.path, connection.topic, exc)
        topics: dict[str, TopicSummary] = {}
        info: Any  # rosbags types a connection's ext as rosbag1's or rosbag2's; here rosbag2's
        for name, info in self._reader.topics.items():
            qos = tuple(q for c in info.connections for q in c.ext.offered_qos_profiles)
            topics[name] = TopicSummary(info.msgtype or '', int(info.msgcount), qos)
        count = int(self._reader.message_count)
        self.summary = BagSummary(
            path=self.path, storage=self.files[0].suffix.lstrip('.') if self.files else '',
            message_count=count,
            start_ns=int(self._reader.start_time) if count else 0,
            end_ns=int(self._reader.end_time) - 1 if count else 0, topics=topics)
        _agree_with_metadata(self.path, self.summary, facts)

    def _files_text(self) -> str:
        return ', '.join(str(f) for f in self.files) or str(self.path)

    @property
    def topics(self) -> dict[str, TopicSummary]:
        """Topics by name (:class:`TopicSummary`)."""
        return self.summary.topics

    def messages(self, topics: Iterable[str] | None = None, *, start_ns: int | None = None,
                 stop_ns: int | None = None) -> Iterator[BagMessage]:
        """
        Yield the stored messages in time-stamp order.

        Parameters
        ----------
        topics : iterable of str, optional
            Only these topics (default all).
        start_ns, stop_ns : int, optional
            Only messages with ``start_ns <= t_ns < stop_ns``.

        Yields
        ------
        BagMessage
            Topic, type, time stamp (ns), CDR bytes.

        """
        wanted = None if topics is None else set(topics)
        connections = [c for c in self._reader.connections
                       if wanted is None or c.topic in wanted]
        if not connections:
            return
        try:
            for connection, t_ns, rawdata in self._reader.messages(
                    connections=connections, start=start_ns, stop=stop_ns):
                yield BagMessage(connection.topic, connection.msgtype, t_ns, rawdata)
        except Exception as exc:  # noqa: BLE001 -- whatever the damage, one line names the bag
            raise BagError(f'{self._files_text()}: corrupt bag data ({exc!r})') from None

    __iter__ = messages

    def deserialize(self, message: BagMessage) -> Any:
        """
        Decode a :class:`BagMessage` into a rosbags message object (fields as in ROS).

        Raises
        ------
        BagError
            If the bytes do not decode as the message's type.

        """
        try:
            return self.typestore.deserialize_cdr(message.rawdata, message.msgtype)
        except Exception as exc:  # noqa: BLE001 -- whatever the damage, one line names the bag
            raise BagError(f'{self._files_text()}: the {message.msgtype} message on '
                           f'{message.topic} stamped {message.t_ns} ns does not decode '
                           f'({exc!r})') from None

    def close(self) -> None:
        """Close the bag's files."""
        self._reader.close()

    def __enter__(self) -> 'BagReader':
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()



def open_bag(path: str | Path, *, required: Iterable[str] = (), typestore: Any = None
             ) -> BagReader:
    """
    Open a rosbag2 bag for reading.

    Parameters
    ----------
    path : str or Path
        Bag directory (holding ``metadata.yaml`` and the storage file).
    required : iterable of str
        Topics that must be in the bag with at least one message.
    typestore : rosbags.typesys.store.Typestore, optional
        Store for deserialising; default :func:`make_typestore`. Types the bag defines and the
        store lacks are registered from the bag.

    Returns
    -------
    BagReader
        Iterate it for :class:`BagMessage` tuples ``(topic, msgtype, t_ns, rawdata)``.

    Raises
    ------
    BagError
        If ``metadata.yaml`` is missing or invalid, the storage file is truncated or corrupt,
        or a required topic is absent.

    """
    reader = BagReader(path, typestore=typestore)
    missing = [t for t in required
               if t not in reader.topics or reader.topics[t].count == 0]
    if missing:
        have = ', '.join(sorted(reader.topics)) or 'none'
        reader.close()
        raise BagError(f'{reader.path}: bag has no messages on {", ".join(missing)} '
                       f'(topics present: {have})')
    return reader


def bag_summary(path: str | Path) -> BagSummary:
    """
    Summarise a bag: topics, types, counts, time span.

    Parameters
    ----------
    path : str or Path
        Bag directory.

    Returns
    -------
    BagSummary
        The summary (times in ns, ``duration_s`` in s).

    """
    with BagReader(path) as reader:
        return reader.summary


def bag_custom_data(path: str | Path) -> dict[str, str]:
    """
    Return the ``custom_data`` strings of a bag's ``metadata.yaml`` (recorder counts, ...).

    Parameters
    ----------
    path : str or Path
        Bag directory.

    Returns
    -------
    dict[str, str]
        Key to value; empty when the bag has none.

    """
    path, _ = _check_bag_dir(path)
    info = yaml.safe_load((path / METADATA).read_text())['rosbag2_bagfile_information']
    custom = info.get('custom_data') or {}
    if not isinstance(custom, dict):
        raise BagError(f'{path / METADATA}: custom_data is not a mapping')
    return {str(k): str(v) for k, v in custom.items()}


def _seconds_text(t_ns: int) -> str:
    return f'{t_ns // 10**9}.{t_ns % 10**9:09d}'


def format_summary(summary: BagSummary) -> str:
    """Return a bag summary as the text ``suture-lfd bag info`` prints."""
    lines = [f'bag       {summary.path}',
             f'storage   {summary.storage}',
             f'messages  {summary.message_count}',
             f'duration  {summary.duration_s:.3f} s',
             f'start     {_seconds_text(summary.start_ns)} s',
             f'end       {_seconds_text(summary.end_ns)} s',
             f'topics    {len(summary.topics)}']
    width = max((len(t) for t in summary.topics), default=0)
    for topic, info in sorted(summary.topics.items()):
        fields = qos_fields(info.qos)
        qos = '' if fields is None else (
            f"  {'reliable' if fields[0] else 'best_effort'}"
            f"{' transient_local' if fields[1] else ''}")
        lines.append(f'  {topic:{width}s}  {info.count:8d}  {info.msgtype}{qos}')
    return '\n'.join(lines)

