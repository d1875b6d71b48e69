"""The study on a Dask cluster: same results as the local pool, retries, resume, code checks.

Every test runs a real ``distributed`` cluster of process workers on loopback (a
``LocalCluster``, or a scheduler with ``dask worker`` processes started here).
"""

from dataclasses import dataclass
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
import time

import pytest
from suture_lfd.study.engine import (
    CodeMismatchError,
    DaskSession,
    EngineSpec,
    parse_engine,
    run_stages_on,
)
from suture_lfd.study.runner import Progress, run_stages
from suture_lfd.study.store import ResultStore

TIMEOUT = 900
REPO = Path(__file__).resolve().parents[2]


def study(out, *args):
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT)


@dataclass(frozen=True)
class SquareRecord:
    """The record of a :class:`SquareJob`: the fields the job runner and the store need."""

    id: str
    key: str
    value: int | None = None
    error: str = ''
    wall_s: float | None = None
    cpu_s: float | None = None
    code: str | None = None
    worker: str | None = None


@dataclass(frozen=True)
class SquareJob:
    """A job of the machinery's own kind: square ``x``, leaving a file per run in ``runs``."""

    id: str
    key: str
    x: int
    runs: str
    sleep: float = 0.0

    def failed(self, error):
        return SquareRecord(self.id, self.key, error=error)


def parse(data):
    return SquareRecord(**data)


# module-level job functions: Dask workers import them by reference
def square_job(job, state=None):
    """Record ``x * x``; leave a file per run so that tests can count the runs of a job."""
    runs = Path(job.runs)
    runs.mkdir(parents=True, exist_ok=True)
    (runs / f'{job.key}.{os.getpid()}.{time.monotonic_ns()}').touch()
    if job.sleep:
        time.sleep(job.sleep)
    return SquareRecord(job.id, job.key, value=job.x * job.x)


def dying_job(job, state=None):
    """Kill the worker process on the first run of job 'k3' (a crash mid-job); else square."""
    marker = Path(job.runs) / 'killed-once'
    if job.key == 'k3' and not marker.exists():
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()
        os._exit(1)
    return square_job(job)


def jobs(tmp_path, n, **extra):
    return [SquareJob(f'id-k{i}', f'k{i}', i, str(tmp_path / 'runs'), **extra)
            for i in range(n)]


def runs_of(tmp_path, key):
    return len(list((tmp_path / 'runs').glob(f'{key}.*')))


class InterruptAfter(Progress):
    """Progress that raises KeyboardInterrupt (as Ctrl-C would) after ``n`` stored records."""

    def __init__(self, total, n):
        super().__init__(total, every=1e9)
        self.n = n

    def advance(self, label='', n=1):
        super().advance(label, n)
        if self.done - self.resumed >= self.n:
            raise KeyboardInterrupt('test interrupt')


def test_engine_values_are_parsed_and_bad_ones_named():
    assert parse_engine('local') == EngineSpec()
    assert parse_engine('dask') == EngineSpec('dask')
    assert parse_engine('tcp://10.0.0.5:8786').address == 'tcp://10.0.0.5:8786'
    assert parse_engine('scheduler-file:/a/b.json').scheduler_file == '/a/b.json'
    for bad in ('ray', 'tcp://', 'scheduler-file:', 'dask://x'):
        with pytest.raises(ValueError, match='--engine'):
            parse_engine(bad)


def test_quick_study_through_dask_gives_the_local_pool_s_csv_byte_for_byte(tmp_path):
    local = study(tmp_path / 'local', '--quick', '--workers', '2')
    assert local.returncode == 0, local.stderr[-3000:]
    dask = study(tmp_path / 'dask', '--quick', '--workers', '2', '--engine', 'dask')
    assert dask.returncode == 0, dask.stderr[-3000:]
    assert 'local dask cluster (2 workers)' in dask.stderr
    assert 'INFO' not in dask.stderr  # the scheduler's connection log stays off the terminal
    for name in ('throws.csv', 'demos.csv'):
        assert (tmp_path / 'dask' / name).read_bytes() == \
            (tmp_path / 'local' / name).read_bytes(), name
    path = tmp_path / 'dask' / 'results.jsonl'
    records = [json.loads(line) for line in path.read_text().splitlines()]
    assert len({r['code'] for r in records}) == 1  # every record carries the code digest


def test_a_worker_killed_mid_job_is_retried_and_every_job_is_stored(tmp_path):
    todo = jobs(tmp_path, 8)
    with ResultStore(tmp_path, 'killed', parse=parse) as store, \
            DaskSession(EngineSpec('dask'), workers=2) as session:
        ran = session.run_stages([todo], dying_job, store)
        assert ran == 8
        assert {r.key: r.value for r in store.records.values()} == \
            {f'k{i}': i * i for i in range(8)}
        assert all(not r.error for r in store.records.values())
    assert (tmp_path / 'runs' / 'killed-once').exists()  # the worker did die on k3


def test_a_pool_worker_killed_mid_job_stores_an_error_and_the_others_run(tmp_path):
    todo = jobs(tmp_path, 6)
    with ResultStore(tmp_path, 'pool', parse=parse) as store:
        assert run_stages([todo], dying_job, store, workers=2) == 6
        errors = {r.key: r.error for r in store.records.values() if r.error}
        assert list(errors) == ['k3'] and 'died' in errors['k3']
        assert run_stages([todo], dying_job, store, workers=2) == 1  # only k3 again
        assert not any(r.error for r in store.records.values())
    assert runs_of(tmp_path, 'k0') == 1


def test_an_interrupted_dask_run_resumes_without_redoing_jobs(tmp_path):
    todo = jobs(tmp_path, 12, sleep=0.05)
    spec = EngineSpec('dask')
    with ResultStore(tmp_path, 'resume', parse=parse) as store:
        with pytest.raises(KeyboardInterrupt):
            run_stages_on(spec, [todo], square_job, store, workers=2,
                          progress=InterruptAfter(12, 5))
        stored = {r.key for r in store.records.values()}
    assert 5 <= len(stored) < 12
    with ResultStore(tmp_path, 'resume', parse=parse) as store:
        ran = run_stages_on(spec, [todo], square_job, store, workers=2)
        assert ran == 12 - len(stored)
        assert len(store.records) == 12
    lines = (tmp_path / 'resume.jsonl').read_text().splitlines()
    keys = [json.loads(line)['key'] for line in lines]
    assert sorted(keys) == sorted(f'k{i}' for i in range(12))  # each stored once
    for key in stored:  # a stored job never ran again
        assert runs_of(tmp_path, key) == 1


def _other_code(tmp_path):
    """A copy of the package whose simulator sources differ by one comment line."""
    root = tmp_path / 'other'
    for package in ('sim_bridge', 'suture_lfd'):
        shutil.copytree(REPO / package, root / package,
                        ignore=shutil.ignore_patterns('__pycache__'))
    with open(root / 'sim_bridge' / '__init__.py', 'a') as f:
        f.write('# another version of the simulator\n')
    return root


def test_a_worker_with_other_code_is_refused_and_nothing_is_stored(tmp_path):
    from distributed import LocalCluster

    other = _other_code(tmp_path)
    log = open(tmp_path / 'worker.log', 'w')
    with LocalCluster(n_workers=0, host='127.0.0.1', dashboard_address=None,
                      processes=True) as cluster:
        # A worker whose sys.path puts the other copy first (ahead of the environment's
        # install of this one), and this folder, where the job function lives.
        start = ('import sys; sys.path[:0] = sys.argv[1:3]; del sys.argv[1:3]; '
                 'from distributed.cli.dask_worker import main; main()')
        worker = subprocess.Popen(
            [sys.executable, '-c', start, str(other), str(Path(__file__).parent),
             cluster.scheduler_address, '--nthreads', '1', '--nworkers', '1', '--host',
             '127.0.0.1', '--no-dashboard'],
            stdout=log, stderr=subprocess.STDOUT)
        try:
            spec = parse_engine(cluster.scheduler_address)
            with DaskSession(spec) as session:
                session.client.wait_for_workers(1, timeout=120)
                with ResultStore(tmp_path, 'other', parse=parse) as store:
                    with pytest.raises(CodeMismatchError, match='other suture_lfd code'):
                        session.run_stages([jobs(tmp_path, 3)], square_job, store)
                    assert len(store.records) == 0
        finally:
            worker.terminate()
            worker.wait(timeout=60)
            log.close()
    assert not (tmp_path / 'runs').exists()  # the refused worker ran nothing


def test_an_unreachable_scheduler_is_one_clear_error(tmp_path):
    result = study(tmp_path / 'nowhere', '--quick', '--engine', 'tcp://127.0.0.1:9')
    assert result.returncode == 1
    assert 'cannot use the dask cluster at tcp://127.0.0.1:9' in result.stderr
    assert 'Traceback' not in result.stderr
