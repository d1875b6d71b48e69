"""
rosbag2 bags of demonstrations: typestore, writing, reading, inspection and recovery.

A bag is a rosbag2 directory, as ``ros2 bag`` writes it: ``metadata.yaml`` (format version 9) and
one MCAP file with profile ``ros2`` and ``ros2msg`` schemas, so that ``ros2 bag play``, Foxglove
and the ``mcap`` tools read it. Messages are stored as CDR bytes with their time stamps in
nanoseconds (receive time of the recorder's clock: wall time, or sim time with
``use_sim_time``). Message types are ROS 2 Jazzy's plus ``crtk_msgs`` and ``tf2_msgs``, read
from the ``.msg`` files the package installs (``share/suture_lfd/interfaces/<pkg>/msg``), so this
module works without ROS.

Crash safety: :class:`BagWriter` closes an MCAP chunk every ``chunk_seconds`` or ``chunk_bytes``
and pushes it to the operating system, so a writer killed mid-recording (``SIGKILL``, power is
another story) leaves an MCAP file whose complete chunks hold every message written up to the
last flush, but no ``metadata.yaml`` and no MCAP summary. Recover it with::

    suture-lfd bag recover PATH [--out OUT]

which reads the records of ``PATH`` (the bag directory or its ``.mcap`` file) one after the other,
stops cleanly at the first truncated or corrupt record, and writes a new, valid bag to ``OUT``
(default: ``PATH-recovered`` next to it) holding every message of the complete chunks.
``suture-lfd bag info PATH`` prints the topics, types, counts and duration of a bag.

Integrity: the MCAP files carry CRC-32s of every chunk, of the data section and of the summary
(:mod:`suture_lfd.bags.mcap_check`). Opening a bag checks them all, and that ``metadata.yaml``
agrees with the MCAP summary, so a flipped byte is refused before any message is read;
``bag recover`` keeps the chunks whose CRC holds and says which it dropped.

Errors about a bag (missing ``metadata.yaml``, truncated or corrupt file, a message that does not
decode, missing topics) raise :class:`BagError`, a ``ValueError`` whose one-line message names the
file, the topic and the byte offset or time stamp where known, and says what to do.
"""

from dataclasses import dataclass
import functools
import logging
import math
import mmap
import os
from pathlib import Path
import re
import shutil
import struct
import sys
import time
from typing import NamedTuple

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from sim_bridge import cdr
from sim_bridge.paths import share_dir
from suture_lfd.bags.mcap_check import CrcMcapWriter, check_mcap, salvage_messages
from suture_lfd.errors import BagError, McapDamageError
import yaml

LOG = logging.getLogger(__name__)

INTERFACE_PACKAGES = ('crtk_msgs', 'tf2_msgs')
METADATA = 'metadata.yaml'
ROS_DISTRO = 'jazzy'  # metadata.yaml's ros_distro: the distribution of the message types
CHUNK_BYTES = 256 * 1024
CHUNK_SECONDS = 0.5
_MCAP_CHUNK_LIMIT = 2**20  # rosbags closes a chunk itself past 1 MiB
_NO_DURATION = QosTime(0, 0)


# --- message types -------------------------------------------------------------------------------

def interface_definitions(root=None):
    """
    Return the ``.msg`` text of the package's own interfaces (crtk_msgs, tf2_msgs).

    Parameters
    ----------
    root : str or Path, optional
        Folder holding ``<pkg>/msg/*.msg``; default ``<share>/interfaces`` of the installed
        package (or ``interfaces/`` of a source checkout).

    Returns
    -------
    dict[str, str]
        ``{'crtk_msgs/msg/OperatingState': text, ...}``.

    """
    root = Path(root) if root is not None else share_dir() / 'interfaces'
    found = {}
    for pkg in INTERFACE_PACKAGES:
        for path in sorted((root / pkg / 'msg').glob('*.msg')):
            found[f'{pkg}/msg/{path.stem}'] = path.read_text()
    if not found:
        raise FileNotFoundError(
            f'no interface definitions under {root}: expected <pkg>/msg/*.msg for '
            f'{", ".join(INTERFACE_PACKAGES)}; reinstall the package')
    return found


@functools.lru_cache(maxsize=1)
def _interface_types():
    types = {}
    for name, text in interface_definitions().items():
        types.update(get_types_from_msg(text, name))
    return types


def make_typestore():
    """
    Return a new rosbags typestore: ROS 2 Jazzy plus crtk_msgs and tf2_msgs.

    Returns
    -------
    rosbags.typesys.store.Typestore
        Serialises, deserialises, and gives definitions and RIHS01 hashes. Each call returns
        a new store, so callers may register more types without affecting others.

    """
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(_interface_types())
    return store


def _share_prefixes():
    prefixes = [Path(sys.prefix)]
    prefixes += [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    return prefixes


def ensure_type(store, msgtype, msgdef=None):
    """
    Make ``msgtype`` known to ``store``, from ``msgdef`` or from an installed ``.msg`` file.

    Parameters
    ----------
    store : rosbags.typesys.store.Typestore
        Store to extend.
    msgtype : str
        ``'pkg/msg/Name'``.
    msgdef : str, optional
        Definition in the ``ros2msg`` format of rosbag2 (the type's text followed by its
        dependencies, each after a line of 80 ``=`` and ``MSG: pkg/Name``).

    Raises
    ------
    BagError
        If the type is unknown and no definition is given or installed.

    """
    if msgtype in store.fielddefs:
        return
    if not msgdef:
        pkg, _, name = msgtype.partition('/msg/')
        for prefix in _share_prefixes():
            path = prefix / 'share' / pkg / 'msg' / f'{name}.msg'
            if path.is_file():
                msgdef = path.read_text()
                break
    if not msgdef:
        raise BagError(
            f'message type {msgtype!r} is unknown: it is not a ROS 2 Jazzy, crtk_msgs or '
            f'tf2_msgs type and no share/{msgtype.split("/")[0]}/msg file is installed')
    types = get_types_from_msg(msgdef, msgtype)
    try:
        store.register(types)
    except TypesysError as exc:
        raise BagError(f'message type {msgtype!r}: {exc}') from exc
    for _, desc in types[msgtype][1]:
        for nested in _nested_types(desc):
            ensure_type(store, nested)


def _nested_types(desc):
    """Yield the message type names a rosbags field description refers to."""
    kind, detail = desc
    if kind == Nodetype.NAME:
        yield detail
    elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        yield from _nested_types(detail[0])


# --- QoS -----------------------------------------------------------------------------------------

def make_qos(*, reliable=True, transient_local=False, depth=100):
    """
    Return the rosbags description of a QoS profile, for a bag's ``offered_qos_profiles``.

    Parameters
    ----------
    reliable : bool
        RELIABLE (True) or BEST_EFFORT (False).
    transient_local : bool
        TRANSIENT_LOCAL (latched, True) or VOLATILE (False).
    depth : int
        KEEP_LAST history depth (messages).

    Returns
    -------
    rosbags.interfaces.Qos
        The profile.

    """
    return Qos(
        history=QosHistory.KEEP_LAST, depth=int(depth),
        reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=_NO_DURATION, lifespan=_NO_DURATION, liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_NO_DURATION, avoid_ros_namespace_conventions=False)


def qos_fields(profiles):
    """
    Summarise a topic's offered QoS profiles as (reliable, transient_local, depth).

    Parameters
    ----------
    profiles : sequence of rosbags.interfaces.Qos
        Profiles offered by the topic's publishers (empty: unknown).

    Returns
    -------
    tuple[bool, bool, int] or None
        RELIABLE if every publisher was reliable, TRANSIENT_LOCAL if every publisher was,
        the largest depth; None for no profiles.

    """
    if not profiles:
        return None
    reliable = all(p.reliability != QosReliability.BEST_EFFORT for p in profiles)
    latched = all(p.durability == QosDurability.TRANSIENT_LOCAL for p in profiles)
    depth = max((p.depth for p in profiles), default=0)
    return reliable, latched, depth


# --- writing -------------------------------------------------------------------------------------

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

    def __init__(self, path, *, typestore=None, chunk_bytes=CHUNK_BYTES,
                 chunk_seconds=CHUNK_SECONDS):
        self.path = Path(path)
        if not 0 < chunk_bytes <= _MCAP_CHUNK_LIMIT:
            raise ValueError(f'chunk_bytes must be in (0, {_MCAP_CHUNK_LIMIT}], got {chunk_bytes}')
        if not chunk_seconds > 0:
            raise ValueError(f'chunk_seconds must be > 0, got {chunk_seconds}')
        if self.path.exists():
            raise BagError(f'{self.path}: exists already; a bag is never overwritten, '
                           'choose another name')
        self.typestore = typestore if typestore is not None else make_typestore()
        self.chunk_bytes = int(chunk_bytes)
        self.chunk_seconds = float(chunk_seconds)
        self.counts = {}
        self._connections = {}
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
    def mcap_path(self):
        """Path of the bag's MCAP file."""
        return self.path / f'{self.path.name}.mcap'

    def add_topic(self, topic, msgtype, *, qos=(), msgdef=None):
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

    def has_topic(self, topic):
        """Whether ``topic`` was declared with :meth:`add_topic`."""
        return topic in self._connections

    def write(self, topic, t_ns, rawdata):
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
        if self._writer.storage.chunk.bio.tell() >= self.chunk_bytes:
            self.flush()

    def flush(self):
        """Close the open chunk (if it holds messages) and hand the file data to the OS."""
        storage = self._writer.storage
        if storage is None:
            return
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()
        self._last_flush = time.monotonic()

    def flush_if_due(self):
        """Flush when ``chunk_seconds`` passed since the last flush; return whether it did."""
        if time.monotonic() - self._last_flush >= self.chunk_seconds:
            self.flush()
            return True
        return False

    def set_custom_data(self, key, value):
        """Store a string in the ``custom_data`` of ``metadata.yaml`` (written at close)."""
        self._writer.set_custom_data(str(key), str(value))

    def close(self):
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

    def abort(self):
        """Close the file without summary or ``metadata.yaml`` (a recoverable bag remains)."""
        if self._writer.storage is not None:
            self.flush()
            self._writer.abort()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# --- reading -------------------------------------------------------------------------------------

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
    def duration_s(self):
        """Time between the first and last message, seconds."""
        return max(0, self.end_ns - self.start_ns) * 1e-9


def _checked_storage(path, file):
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


def _name_ros_distro(meta):
    """Write the ROS distribution the bag's types are from (rosbags' writer names itself)."""
    text = meta.read_text()
    meta.write_text(re.sub(r'^(\s*ros_distro:)\s*rosbags\s*$', rf'\1 {ROS_DISTRO}', text,
                           flags=re.M))


def _agree_with_metadata(path, summary, facts):
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


def _check_bag_dir(path):
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

    def __init__(self, path, *, typestore=None):
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
        topics = {}
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

    def _files_text(self):
        return ', '.join(str(f) for f in self.files) or str(self.path)

    @property
    def topics(self):
        """Topics by name (:class:`TopicSummary`)."""
        return self.summary.topics

    def messages(self, topics=None, *, start_ns=None, stop_ns=None):
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

    def deserialize(self, message):
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

    def close(self):
        """Close the bag's files."""
        self._reader.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _nanoseconds(t):
    return int(round(float(t) * 1e9))


def pose_stamped_cdr(t, frame_id, pose):
    """
    Return the CDR bytes of a geometry_msgs/PoseStamped (:func:`sim_bridge.cdr.pose_stamped`).

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


def joint_state_cdr(t, names, position):
    """Return the CDR bytes of a sensor_msgs/JointState of ``name`` and ``position`` only."""
    return cdr.joint_state(_nanoseconds(t), tuple(names), position)


def open_bag(path, *, required=(), typestore=None):
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


def bag_summary(path):
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


def bag_custom_data(path):
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


def _seconds_text(t_ns):
    return f'{t_ns // 10**9}.{t_ns % 10**9:09d}'


def format_summary(summary):
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


# --- recovery ------------------------------------------------------------------------------------

def _storage_files(path):
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag or MCAP file')
    if path.is_file():
        return [path]
    files = sorted(path.glob('*.mcap'))
    if not files:
        raise BagError(f'{path}: no .mcap file to recover in this folder')
    return files


def _copy_records(file, writer, stats):
    """Copy the messages of ``file``'s chunks that check out into ``writer``; update ``stats``."""
    try:
        salvage, messages = salvage_messages(file.read_bytes())
    except (OSError, McapDamageError) as exc:
        stats['stops'].append(f'{file}: {exc}')
        return
    stats['dropped'] += [f'{file}: dropped {what}' for what in salvage.dropped]
    if salvage.stop:
        stats['stops'].append(f'{file}: {salvage.stop}')
    for cid, t_ns, rawdata in messages:
        channel = salvage.channels.get(cid)
        schema = salvage.schemas.get(channel[1]) if channel else None
        if schema is None:
            stats['orphans'] += 1
            continue
        topic = channel[0]
        try:
            if not writer.has_topic(topic):
                qos = parse_qos(channel[2].get('offered_qos_profiles', ''))
                writer.add_topic(topic, schema[0], qos=qos, msgdef=schema[2].decode())
        except (BagError, ValueError, TypeError, UnicodeDecodeError, yaml.YAMLError) as exc:
            stats['dropped'].append(f'{file}: dropped the messages on {topic} ({exc})')
            continue
        writer.write(topic, t_ns, rawdata)


def recover_bag(path, out=None):
    """
    Rebuild a valid bag from an unfinished one (writer killed, file truncated).

    Reads the MCAP records of ``path`` in order with the ``mcap`` stream reader and copies
    every message of every complete chunk whose CRC holds, with its topic, type, definition and
    offered QoS, into a new bag; drops (and logs) a chunk that fails its CRC and goes on, and
    stops where a record is truncated or its length is damaged. The source is left as it
    is. Command line: ``suture-lfd bag recover PATH [--out OUT]``.

    Parameters
    ----------
    path : str or Path
        Bag directory (``metadata.yaml`` may be missing) or one ``.mcap`` file.
    out : str or Path, optional
        New bag directory; default ``<path>-recovered`` beside ``path``. Must not exist.

    Returns
    -------
    BagSummary
        Summary of the recovered bag.

    Raises
    ------
    BagError
        If nothing can be recovered (not MCAP, or no complete chunk).

    """
    path = Path(path)
    files = _storage_files(path)
    if out is None:
        base = path if path.is_dir() else path.with_suffix('')
        out = base.with_name(base.name + '-recovered')
    out = Path(out)
    writer = BagWriter(out, chunk_bytes=_MCAP_CHUNK_LIMIT, chunk_seconds=math.inf)
    stats = {'orphans': 0, 'dropped': [], 'stops': []}
    try:
        for file in files:
            _copy_records(file, writer, stats)
        total = sum(writer.counts.values())
        if total == 0:
            why = '; '.join(stats['stops']) or 'no messages'
            raise BagError(f'{path}: nothing to recover, no complete chunk holds a message '
                           f'({why})')
        writer.set_custom_data('suture_lfd.recovered_from', str(path))
        writer.close()
    except BaseException:
        writer.abort()
        shutil.rmtree(out, ignore_errors=True)
        raise
    for stop in stats['stops']:
        LOG.info('recover: %s; kept the records before it', stop)
    for dropped in stats['dropped']:
        LOG.warning('recover: %s', dropped)
    if stats['orphans']:
        LOG.warning('recover: %d messages without a channel record were skipped',
                    stats['orphans'])
    LOG.info('recover: %d messages on %d topics written to %s', total, len(writer.counts), out)
    return bag_summary(out)
