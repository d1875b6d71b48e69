"""
Append-only store of a folder's per-job results, so a study never redoes a job it has.

Every run in a folder (a study, its held-out throws, a rerun with the methods reordered or one
added, a sweep) writes its finished jobs (a demonstration or one executed throw) to
``results.jsonl`` in the folder, one JSON object per line, each appended and flushed as soon as
the job is done. A record is found again by its job's ``id``: the digest of everything that
decides the job's result (:mod:`suture_lfd.study.keys`: method and parameters, subject, pairs,
seeds, the content of the configuration files, the code), so a later run skips every job whose
``id`` is stored, whatever other jobs it runs beside it, and a record of other code, files or
parameters is never taken for one of this run's. A line cut short by a kill (no trailing
newline, or not valid JSON) is dropped and its job done again.

Files of the earlier format (``results-<configuration hash>.jsonl``, one per configuration, whose
records have no ``id``) are not read (:func:`earlier_format_files` names them for the run's
message): their jobs run again.

Records are typed (:mod:`suture_lfd.study.records`): each line is a record's fields
(:func:`~suture_lfd.study.records.to_json`), read back by the store's ``parse`` function
(:func:`~suture_lfd.study.records.record_from_json` by default); a line it refuses counts as
damaged. A record has at least ``id``, ``key`` (the job's name in its run) and ``error``.
"""

from collections.abc import Callable, Mapping
import hashlib
import json
import logging
import os
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from suture_lfd.study.records import RunJob, RunRecord, record_from_json, to_json

_LOG = logging.getLogger(__name__)


def config_hash(config: Any, length: int = 12) -> str:
    """
    Return a short, stable hash of a JSON-serialisable configuration.

    Parameters
    ----------
    config : dict
        Everything that changes a study's results (seeds, design, methods, file contents).
    length : int
        Hex digits kept (12 by default).

    Returns
    -------
    str
        First ``length`` hex digits of the SHA-256 of the canonical JSON (sorted keys).

    """
    text = json.dumps(config, sort_keys=True, separators=(',', ':'), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


RESULTS_NAME = 'results'


def earlier_format_files(folder: str | Path) -> list[Path]:
    """
    Return the result files of the earlier format in ``folder`` (not read by this version).

    They are ``results-<configuration hash>.jsonl``: one file per whole study configuration,
    records without a job ``id``; their jobs run again under this version's keys.
    """
    return sorted(p for p in Path(folder).glob('results-*.jsonl') if p.is_file())


class ResultStore:
    """
    The append-only result file of a folder, records found by their job's ``id``.

    Parameters
    ----------
    folder : str or Path
        Output folder of the study or sweep (created if missing).
    name : str
        File name without ``.jsonl`` (default ``results``).
    parse : callable
        ``dict -> record`` of a stored line, raising ValueError or TypeError on anything else
        (default :func:`~suture_lfd.study.records.record_from_json`).

    Attributes
    ----------
    path : Path
        ``<folder>/<name>.jsonl``.
    records : dict of str to record
        Finished jobs by ``id``, in the order they were stored (the last record of an ``id``
        wins: a job stored with an error and run again).
    dropped : int
        Damaged lines ignored when the file was read (a job killed while being written), and
        lines that are not records of this format.

    """

    def __init__(self, folder: str | Path, name: str = RESULTS_NAME,
                 parse: Callable[[Mapping[str, Any]], Any] = record_from_json) -> None:
        self.parse = parse
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.path = self.folder / f'{name}.jsonl'
        self.records: dict[str, Any] = {}
        self.dropped = 0
        self._read()
        self._file: IO[str] | None = None

    def _read(self) -> None:
        if not self.path.exists():
            return
        lines = self.path.read_bytes().split(b'\n')
        tail = lines.pop()  # empty when the file ends with a newline; else cut short by a kill
        if tail.strip():
            self.dropped += 1
        kept = []
        for line in lines:
            try:
                data = json.loads(line)
                if not isinstance(data, dict):
                    raise ValueError('not a study record')
                record = self.parse(data)
            except (ValueError, TypeError):
                if line.strip():
                    self.dropped += 1
                continue
            self.records[record.id] = record
            kept.append(line)
        if self.dropped or tail:
            _LOG.warning('%s: ignored %d damaged line(s) (an interrupted write, or not a record '
                         'with a job id); those jobs run again', self.path, self.dropped)
            # Rewrite the file without the damage so appends start on a fresh line.
            tmp = self.path.with_suffix('.jsonl.tmp')
            with open(tmp, 'wb') as f:
                f.writelines(line + b'\n' for line in kept)
            os.replace(tmp, self.path)

    def __contains__(self, job_id: object) -> bool:
        return job_id in self.records

    def done(self, job: RunJob) -> Any:
        """Return the record of ``job`` (by its ``id``) if stored without an error, else None."""
        record = self.records.get(job.id)
        return None if record is None or record.error else record

    def __len__(self) -> int:
        return len(self.records)

    def add(self, record: RunRecord) -> None:
        """
        Append one finished job's record and flush it to disk.

        Parameters
        ----------
        record : dataclass
            A record with ``id`` and ``key``; NaN becomes ``null``, and the record kept is the
            one read back (:attr:`parse`), as a later run finds it.

        Raises
        ------
        ValueError
            A record without ``id`` or ``key``, or one :attr:`parse` refuses.

        """
        data = to_json(record)
        if not data.get('id') or not data.get('key'):
            raise ValueError(f'a study record needs its id and key, got {data!r}')
        kept = self.parse(data)
        if self._file is None:
            self._file = open(self.path, 'a')
        self._file.write(json.dumps(data, sort_keys=True) + '\n')
        self._file.flush()
        os.fsync(self._file.fileno())
        self.records[kept.id] = kept

    def close(self) -> None:
        """Close the file (records stay readable in :attr:`records`)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> 'ResultStore':
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
