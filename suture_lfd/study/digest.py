"""
Digests of what a study's results depend on: the code and the configuration files.

:func:`code_digest` covers the simulator's and the pipeline's sources a job's result depends on
(not the study's driver, store, report, engine plumbing or skill assessment); it goes into
every job's ``id`` (:mod:`suture_lfd.study.keys`) and every Dask worker's record, where a
mismatch is refused (:class:`suture_lfd.study.engine.CodeMismatchError`).
"""

import hashlib
from pathlib import Path

#: Study modules that run, store or report jobs without deciding their results.
_NOT_RESULTS = frozenset({
    'study/__init__.py', 'study/run.py', 'study/report.py', 'study/figures.py',
    'study/tables.py', 'study/runner.py', 'study/store.py', 'study/keys.py', 'study/pool.py',
    'study/signals.py', 'study/digest.py', 'study/assessed.py', 'cli.py'})


def file_digest(path: str | Path) -> str:
    """Return the first 16 hex digits of the SHA-256 of a file's content."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def code_digest() -> str:
    """Return the digest of the simulator and LfD sources a job's result depends on."""
    h = hashlib.sha256()
    package = Path(__file__).resolve().parent.parent
    for root in (package, package.parent / 'sim_bridge'):
        for path in sorted(root.rglob('*.py')):
            name = path.relative_to(root).as_posix()
            if name not in _NOT_RESULTS and not name.startswith('assessment/'):
                h.update(name.encode())
                h.update(path.read_bytes())
    return h.hexdigest()[:16]
