"""
MCAP files whose every byte is accounted for: CRCs written, checked, and damage located.

MCAP (https://mcap.dev/spec) protects a file with three CRC-32 checksums: one per chunk over its
uncompressed records, one over the data section (from the opening magic to the DataEnd record)
and one over the summary section (to the footer's ``summary_offset_start``). A value of 0 means
"not computed". :class:`CrcMcapWriter` fills all three in the MCAP files rosbags writes;
:func:`check_mcap` verifies every non-zero one plus the file's frame (magic, footer, record
lengths) and raises :class:`McapDamageError`, naming the byte offset and the topics concerned,
at the first thing that does not check out; :func:`salvage_messages` walks a damaged or
unfinished file and keeps the messages of every chunk whose CRC holds.

Byte offsets count from the start of the ``.mcap`` file.
"""

from binascii import crc32
from collections.abc import Iterator
from dataclasses import dataclass, field
import mmap
import struct
from typing import Any

from rosbags.rosbag2.storage_mcap import McapWriter
from suture_lfd.errors import McapDamageError

MAGIC = b'\x89MCAP0\r\n'
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE = 0x02, 0x03, 0x04, 0x05
OP_CHUNK, OP_MESSAGE_INDEX, OP_STATISTICS, OP_DATA_END = 0x06, 0x07, 0x0B, 0x0F
_RECORD = struct.Struct('<BQ')                  # opcode, record length
_FOOTER = struct.Struct('<BQQQI')               # opcode, length 20, summary start, offsets, crc
_CHUNK_HEAD = struct.Struct('<QQQI')            # start, end, uncompressed size, uncompressed crc
_U16, _U32, _U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')
_MESSAGE_HEAD = struct.Struct('<HIQQ')          # channel id, sequence, log time, publish time
_STATISTICS_HEAD = struct.Struct('<QHIIIIQQ')   # counts, message start and end time
_CRC_AT = 1 + 8 + 24                            # chunk CRC offset in its record
# The bytes of an MCAP file or chunk, copied, viewed or mapped.
_Buffer = bytes | memoryview | mmap.mmap
# A message of a chunk: (channel id, log time ns, serialised data).
_Message = tuple[int, int, bytes]


@dataclass
class McapFacts:
    """What a checked MCAP file's summary says, and which of its CRCs were present and held."""

    topics: dict = field(default_factory=dict)       # channel id -> topic
    counts: dict = field(default_factory=dict)       # topic -> message count
    message_count: int = 0
    start_ns: int = 0
    end_ns: int = 0
    chunks: int = 0
    chunk_crcs: int = 0
    data_crc: bool = False
    summary_crc: bool = False

    @property
    def intact(self) -> bool:
        """Whether the data and summary CRCs together prove every byte of the file."""
        return self.data_crc and self.summary_crc


class CrcMcapWriter(McapWriter):
    """The rosbags MCAP writer, with chunk, data section and summary CRC-32s filled in."""

    def close_chunk(self) -> None:
        crc = crc32(self.chunk.bio.getbuffer())
        start = self.bio.tell()
        super().close_chunk()
        end = self.bio.tell()
        self.bio.seek(start + _CRC_AT)
        self.bio.write(_U32.pack(crc))
        self.bio.seek(end)

    def close(self, version: int, metadata: Any) -> None:
        super().close(version, metadata)
        with self.path.open('r+b') as file:
            data = file.read()
            footer = len(data) - len(MAGIC) - _FOOTER.size
            _, _, summary_start, _, _ = _FOOTER.unpack_from(data, footer)
            data_end = summary_start - (_RECORD.size + 4)
            if data[data_end] != OP_DATA_END:
                raise RuntimeError(f'{self.path}: no DataEnd record before the summary')
            file.seek(data_end + _RECORD.size)
            file.write(_U32.pack(crc32(data[:data_end])))
            file.seek(footer + _FOOTER.size - 4)
            file.write(_U32.pack(crc32(data[summary_start:footer + _FOOTER.size - 4])))


def _string(buf: _Buffer, at: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, at)
    end = at + 4 + n
    if end > len(buf):
        raise struct.error('string runs past its record')
    return bytes(buf[at + 4:end]).decode(), end


def _chunk_body(data: _Buffer, at: int, end: int) -> tuple[bytes, int]:
    """(uncompressed records, stored CRC) of the chunk record whose body spans [at, end)."""
    _, _, size, crc = _CHUNK_HEAD.unpack_from(data, at)
    compression, at = _string(data, at + _CHUNK_HEAD.size)
    (length,) = _U64.unpack_from(data, at)
    at += 8
    if at + length != end:
        raise struct.error('chunk records do not fill the chunk')
    body = bytes(data[at:end])
    if compression == 'zstd':
        import zstandard
        body = zstandard.ZstdDecompressor().decompress(body, max_output_size=size)
    elif compression:
        raise struct.error(f'unsupported chunk compression {compression!r}')
    if len(body) != size:
        raise struct.error(f'chunk holds {len(body)} bytes, its header says {size}')
    return body, crc


def _records(buf: _Buffer, start: int, stop: int) -> Iterator[tuple[int, int, int, int]]:
    """Yield (offset, opcode, body start, body end) of the records in buf[start:stop]."""
    at = start
    while at < stop:
        if at + _RECORD.size > stop:
            raise McapDamageError('truncated record header', at)
        op, length = _RECORD.unpack_from(buf, at)
        body = at + _RECORD.size
        if length > stop - body:
            raise McapDamageError(
                f'record (opcode 0x{op:02x}) runs past the end of its section', at)
        yield at, op, body, body + length
        at = body + length


def _summary(data: _Buffer, start: int, stop: int, facts: McapFacts) -> None:
    """Read channels and statistics of the summary section into ``facts``."""
    stats = None
    for _, op, at, _ in _records(data, start, stop):
        if op == OP_CHANNEL:
            (cid,) = _U16.unpack_from(data, at)
            facts.topics[cid], _ = _string(data, at + 4)
        elif op == OP_STATISTICS:
            stats = at
    if stats is None:
        return
    (facts.message_count, _, _, _, _, facts.chunks, facts.start_ns,
     facts.end_ns) = _STATISTICS_HEAD.unpack_from(data, stats)
    at = stats + _STATISTICS_HEAD.size
    (size,) = _U32.unpack_from(data, at)
    for k in range(size // 10):
        cid, count = struct.unpack_from('<HQ', data, at + 4 + 10 * k)
        topic = facts.topics.get(cid, f'channel {cid}')
        facts.counts[topic] = facts.counts.get(topic, 0) + count


def _following_topics(data: _Buffer, at: int, stop: int, facts: McapFacts) -> list[str]:
    """Topics of the message index records that follow a chunk ending at ``at``."""
    topics = []
    for _, op, body, _ in _records(data, at, stop):
        if op != OP_MESSAGE_INDEX:
            break
        (cid,) = _U16.unpack_from(data, body)
        topics.append(facts.topics.get(cid, f'channel {cid}'))
    return topics


def check_mcap(data: _Buffer) -> McapFacts:
    """
    Check an MCAP file's frame and every non-zero CRC.

    Parameters
    ----------
    data : bytes
        The whole file.

    Returns
    -------
    McapFacts
        Topics and counts from the summary, and which CRCs were present (all of them held).

    Raises
    ------
    McapDamageError
        At the first magic, footer, record length or CRC that does not check out.

    """
    data = memoryview(data)
    n = len(data)
    if n < 2 * len(MAGIC) or bytes(data[:len(MAGIC)]) != MAGIC:
        raise McapDamageError('not an MCAP file (invalid magic)', 0)
    footer = n - len(MAGIC) - _FOOTER.size
    if footer < len(MAGIC) or bytes(data[-len(MAGIC):]) != MAGIC:
        raise McapDamageError('no closing MCAP magic: the file is truncated or damaged at its end',
                         n)
    op, length, summary_start, summary_offsets, summary_crc = _FOOTER.unpack_from(data, footer)
    if op != OP_FOOTER or length != 20 or not len(MAGIC) <= summary_start <= footer:
        raise McapDamageError('damaged footer record', footer)
    facts = McapFacts()
    if summary_crc:
        if crc32(data[summary_start:footer + _FOOTER.size - 4]) != summary_crc:
            raise McapDamageError('summary section fails its CRC', summary_start)
        facts.summary_crc = True
    try:
        _summary(data, summary_start, footer, facts)
    except (struct.error, UnicodeDecodeError) as exc:
        raise McapDamageError(f'unreadable summary section ({exc})', summary_start) from None
    data_end = None
    records = _records(data, len(MAGIC), summary_start)
    for at, op, body, end in records:
        if op == OP_DATA_END:
            data_end = at
            break
        if op != OP_CHUNK:
            continue
        try:
            records_, crc = _chunk_body(data, body, end)
        except (struct.error, UnicodeDecodeError, ValueError) as exc:
            raise McapDamageError(f'damaged chunk record ({exc})', at,
                             _following_topics(data, end, summary_start, facts)) from None
        if crc:
            if crc32(records_) != crc:
                raise McapDamageError('chunk fails its CRC', at,
                                 _following_topics(data, end, summary_start, facts))
            facts.chunk_crcs += 1
    if data_end is None:
        raise McapDamageError('no DataEnd record before the summary', summary_start)
    (data_crc,) = _U32.unpack_from(data, data_end + _RECORD.size)
    if data_crc:
        if crc32(data[:data_end]) != data_crc:
            raise McapDamageError('data section fails its CRC outside the message chunks '
                             '(header, schema, channel, message index or metadata records)',
                             len(MAGIC))
        facts.data_crc = True
    return facts


@dataclass
class Salvage:
    """What :func:`salvage_messages` kept and dropped."""

    schemas: dict = field(default_factory=dict)      # id -> (name, encoding, data bytes)
    channels: dict = field(default_factory=dict)     # id -> (topic, schema id, metadata dict)
    dropped: list = field(default_factory=list)      # one text per dropped part
    stop: str = ''                                   # why the walk ended early ('' if it did not)


def _map(buf: _Buffer, at: int) -> tuple[dict[str, str], int]:
    (size,) = _U32.unpack_from(buf, at)
    out: dict[str, str]
    end, at, out = at + 4 + size, at + 4, {}
    while at < end:
        key, at = _string(buf, at)
        out[key], at = _string(buf, at)
    return out, end


def _inner(body: _Buffer) -> tuple[dict[int, tuple[str, str, bytes]],
                                    dict[int, tuple[str, int, dict[str, str]]], list[_Message]]:
    """Parse a verified chunk's records: (schemas, channels, [(channel id, log time, data)])."""
    schemas: dict[int, tuple[str, str, bytes]] = {}
    channels: dict[int, tuple[str, int, dict[str, str]]] = {}
    messages: list[_Message] = []
    for _, op, at, end in _records(body, 0, len(body)):
        if op == OP_SCHEMA:
            (sid,) = _U16.unpack_from(body, at)
            name, at = _string(body, at + 2)
            encoding, at = _string(body, at)
            (size,) = _U32.unpack_from(body, at)
            schemas[sid] = (name, encoding, bytes(body[at + 4:at + 4 + size]))
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from('<HH', body, at)
            topic, at = _string(body, at + 4)
            _, at = _string(body, at)
            metadata, _ = _map(body, at)
            channels[cid] = (topic, sid, metadata)
        elif op == OP_MESSAGE:
            cid, _, log_time, _ = _MESSAGE_HEAD.unpack_from(body, at)
            messages.append((cid, log_time, bytes(body[at + _MESSAGE_HEAD.size:end])))
    return schemas, channels, messages


def salvage_messages(data: _Buffer) -> tuple['Salvage', list[_Message]]:
    """
    Yield the messages of every chunk of an MCAP file that checks out, in file order.

    A chunk whose CRC fails or whose records do not parse is dropped and the walk goes on with
    the next record; it ends at the DataEnd record, or where a record header or length is
    truncated or runs past the end of the file (everything from there on is dropped).

    Parameters
    ----------
    data : bytes
        The file's bytes.

    Returns
    -------
    tuple[Salvage, list]
        What was kept and dropped, and the messages as ``(channel id, log time ns, bytes)``.

    Raises
    ------
    McapDamageError
        If the file does not start with the MCAP magic.

    """
    data = memoryview(data)
    if bytes(data[:len(MAGIC)]) != MAGIC:
        raise McapDamageError('not an MCAP file (invalid magic)', 0)
    messages: list[_Message]
    salvage, messages = Salvage(), []
    try:
        for at, op, body, end in _records(data, len(MAGIC), len(data)):
            if op in (OP_DATA_END, OP_FOOTER):
                break
            if op != OP_CHUNK:
                continue
            try:
                records, crc = _chunk_body(data, body, end)
                if crc and crc32(records) != crc:
                    raise ValueError('its CRC fails')
                schemas, channels, inner = _inner(memoryview(records))
            except (struct.error, UnicodeDecodeError, ValueError, McapDamageError) as exc:
                salvage.dropped.append(f'the chunk at byte {at} ({end - at} bytes): {exc}')
                continue
            salvage.schemas.update(schemas)
            salvage.channels.update(channels)
            messages.extend(inner)
    except McapDamageError as exc:
        salvage.stop = (f'truncated or damaged at byte {exc.offset}: {exc.what}; the '
                        f'{len(data) - exc.offset} bytes from there on are dropped')
    _summary_definitions(data, salvage)
    return salvage, messages


def _summary_definitions(data: _Buffer, salvage: 'Salvage') -> None:
    """Add the schemas and channels of an intact summary section that the chunks lacked."""
    footer = len(data) - len(MAGIC) - _FOOTER.size
    if footer < len(MAGIC) or bytes(data[-len(MAGIC):]) != MAGIC:
        return
    op, length, start, _, crc = _FOOTER.unpack_from(data, footer)
    if op != OP_FOOTER or length != 20 or not len(MAGIC) <= start <= footer or not crc \
            or crc32(data[start:footer + _FOOTER.size - 4]) != crc:
        return
    try:
        schemas, channels, _ = _inner(memoryview(bytes(data[start:footer])))
    except (struct.error, UnicodeDecodeError, ValueError, McapDamageError):
        return
    for sid, schema in schemas.items():
        salvage.schemas.setdefault(sid, schema)
    for cid, channel in channels.items():
        salvage.channels.setdefault(cid, channel)
