"""
Rebuilding a valid bag from an unfinished one: ``suture-lfd bag recover PATH [--out OUT]``.

The records of the MCAP file are read one after the other; every message of every complete chunk
whose CRC holds is copied, with its topic, type, definition and offered QoS, into a new bag.
"""

import logging
import math
from pathlib import Path
import shutil
from typing import Any

from rosbags.rosbag2.metadata import parse_qos
from suture_lfd.bags.mcap_check import salvage_messages
from suture_lfd.bags.reader import BagSummary, bag_summary
from suture_lfd.bags.writer import MCAP_CHUNK_LIMIT, BagWriter
from suture_lfd.errors import BagError, McapDamageError
import yaml

LOG = logging.getLogger(__name__)


def _storage_files(path: str | Path) -> list[Path]:
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag or MCAP file')
    if path.is_file():
        return [path]
    files = sorted(path.glob('*.mcap'))
    if not files:
        raise BagError(f'{path}: no .mcap file to recover in this folder')
    return files


def _copy_records(file: Path, writer: BagWriter, stats: dict[str, Any]) -> None:
    """Copy the messages of ``file``'s chunks that check out into ``writer``; update ``stats``."""
    try:
        salvage, messages = salvage_messages(file.read_bytes())
    except (OSError, McapDamageError) as exc:
        stats['stops'].append(f'{file}: {exc}')
        return
    stats['dropped'] += [f'{file}: dropped {what}' for what in salvage.dropped]
    if salvage.stop:
        stats['stops'].append(f'{file}: {salvage.stop}')
    channel: Any  # (topic, schema id, metadata); a missing one finds no schema below
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


def recover_bag(path: str | Path, out: str | Path | None = None) -> BagSummary:
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
    writer = BagWriter(out, chunk_bytes=MCAP_CHUNK_LIMIT, chunk_seconds=math.inf)
    stats: dict[str, Any] = {'orphans': 0, 'dropped': [], 'stops': []}
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
