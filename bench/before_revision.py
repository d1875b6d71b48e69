"""
The ``--before REV`` of the benchmarks: the same measurement with the code of an older revision.

:func:`measure_before` checks git revision ``REV`` out in a temporary worktree (detached, removed
afterwards, even on an error) and runs a measurement with it; :func:`code_env` gives the
environment of a process that imports that worktree's code before this checkout's
(``PYTHONPATH``), so that both are measured side by side in one run on the same machine.
"""

import os
from pathlib import Path
import subprocess
import tempfile

REPO = Path(__file__).resolve().parents[1]


def measure_before(rev, measure):
    """Return ``measure(tree)``, ``tree`` a temporary worktree of git revision ``rev``."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / 'before'
        subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', str(tree), rev],
                       check=True, capture_output=True)
        try:
            return measure(tree)
        finally:
            subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force', str(tree)],
                           capture_output=True)


def code_env(code, env=None):
    """Return ``env`` (default: this process's) importing ``code`` first (None: unchanged)."""
    env = dict(os.environ if env is None else env)
    if code is not None:
        env['PYTHONPATH'] = str(code) + os.pathsep + env.get('PYTHONPATH', '')
    return env
