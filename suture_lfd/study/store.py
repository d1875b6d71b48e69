"""
Append-only store of a study's per-job results, so an interrupted study resumes where it stopped.

One study run writes its finished jobs (a demonstration or one executed throw) to
``results-<config hash>.jsonl`` in its output folder, one JSON object per line, each appended and
flushed as soon as the job is done. A later run with the same configuration (same hash) reads
the file back and skips every job already in it; a line cut short by a kill (no trailing
newline, or not valid JSON) is dropped and its job done again. A run with another configuration
uses another file, so results of different configurations never mix.

Every record is a flat ``dict`` with at least ``key`` (the job's unique name) and ``kind``.
"""

import hashlib
import json
import logging
import math
import os
from pathlib import Path

_LOG = logging.getLogger(__name__)


def config_hash(config):
    """
    Return a short, stable hash of a JSON-serialisable configuration.

    Parameters
    ----------
    config : dict
        Everything that changes a study's results (seeds, design, methods, file contents).

    Returns
    -------
    str
        First 12 hex digits of the SHA-256 of the canonical JSON (sorted keys).

    """
    text = json.dumps(config, sort_keys=True, separators=(',', ':'), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _jsonable(value):
    """Replace NaN and infinities (not JSON) by None, recursively; numpy scalars by Python."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, 'item') and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class ResultStore:
    """
    The append-only result file of one study configuration.

    Parameters
    ----------
    folder : str or Path
        Output folder of the study (created if missing).
    digest : str
        Configuration hash (:func:`config_hash`); names the file.

    Attributes
    ----------
    path : Path
        ``<folder>/results-<digest>.jsonl``.
    records : dict of str to dict
        Finished jobs by key, in the order they were stored.
    dropped : int
        Damaged lines ignored when the file was read (a job killed while being written).

    """

    def __init__(self, folder, digest):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.path = self.folder / f'results-{digest}.jsonl'
        self.records = {}
        self.dropped = 0
        self._read()
        self._file = None

    def _read(self):
        if not self.path.exists():
            return
        lines = self.path.read_bytes().split(b'\n')
        tail = lines.pop()  # empty when the file ends with a newline; else cut short by a kill
        if tail.strip():
            self.dropped += 1
        for line in lines:
            try:
                record = json.loads(line)
                if not isinstance(record, dict) or 'key' not in record:
                    raise ValueError('not a study record')
            except ValueError:
                if line.strip():
                    self.dropped += 1
                continue
            self.records[record['key']] = record
        if self.dropped or tail:
            _LOG.warning('%s: ignored %d damaged line(s) (an interrupted write); those jobs '
                         'run again', self.path, self.dropped)
            # Rewrite the file without the damage so appends start on a fresh line.
            tmp = self.path.with_suffix('.jsonl.tmp')
            with open(tmp, 'w') as f:
                for record in self.records.values():
                    f.write(json.dumps(record, sort_keys=True) + '\n')
            os.replace(tmp, self.path)

    def __contains__(self, key):
        return key in self.records

    def __len__(self):
        return len(self.records)

    def add(self, record):
        """
        Append one finished job's record and flush it to disk.

        Parameters
        ----------
        record : dict
            Flat record with ``key`` and ``kind``; NaN becomes ``null``.

        """
        if 'key' not in record or 'kind' not in record:
            raise ValueError(f'a study record needs key and kind, got {sorted(record)}')
        record = _jsonable(record)
        if self._file is None:
            self._file = open(self.path, 'a')
        self._file.write(json.dumps(record, sort_keys=True) + '\n')
        self._file.flush()
        os.fsync(self._file.fileno())
        self.records[record['key']] = record

    def close(self):
        """Close the file (records stay readable in :attr:`records`)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
