"""The study stops when told and never redoes a job it has.

Real ``suture-lfd study`` processes, real signals, real worker processes (the local pool and a
local Dask cluster), real results files read back. The ``--quick`` design with the paper's
method only is interrupted by SIGTERM and resumed; the same folder then gets both methods
(only the added method's throws run) and both methods reversed (nothing runs), so one study's
jobs serve every claim of the file.
"""

import csv
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

import psutil
import pytest

TIMEOUT = 900
#: The issue's bound: a study told to stop exits within this many seconds.
STOP_S = 5.0
QUICK_PAPER = ['--quick', '--methods', 'paper', '--workers', '2']
QUICK_PAPER_JOBS = 8 + 32  # 2 subjects x 4 pairs demonstrations, 2 x 4 x 4 throws


def study(out, *args):
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT)


def lines(out):
    path = Path(out) / 'results.jsonl'
    return path.read_text().splitlines() if path.exists() else []


def alive(process):
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def session_members(sid):
    """Processes of a session still running (the study is started as a session's leader)."""
    found = []
    for process in psutil.process_iter():
        try:
            if os.getsid(process.pid) == sid and alive(process):
                found.append(process)
        except (ProcessLookupError, PermissionError, psutil.Error):
            continue
    return found


def interrupt(out, args, after, log):
    """
    Start a study, send it SIGTERM once ``after`` results are stored; return what happened.

    Returns ``(exit status, seconds from the signal to the exit, stderr, processes seen,
    processes left)``: seen, every descendant of the study while it ran; left, those and any
    other process of the study's session still running after it exited (killed here).
    """
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *args]
    with open(log, 'w') as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err,
                                start_new_session=True)
    seen = {}
    try:
        deadline = time.monotonic() + TIMEOUT
        while len(lines(out)) < after:
            assert time.monotonic() < deadline, 'the study stored too little in time'
            assert proc.poll() is None, Path(log).read_text()[-3000:]
            try:
                for child in psutil.Process(proc.pid).children(recursive=True):
                    seen[child.pid] = child
            except psutil.NoSuchProcess:
                pass
            time.sleep(0.1)
        assert proc.poll() is None, 'the study finished before it could be interrupted'
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        status = proc.wait(timeout=120)
        elapsed = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    left = [p for p in seen.values() if alive(p)] + session_members(proc.pid)
    for p in left:  # no leak into the other tests, whatever the assertions below say
        p.kill()
    return status, elapsed, Path(log).read_text(), seen, left


def check_stopped_and_resumed(out, args, after, log, total):
    """SIGTERM mid-run, then the same command: the claims of a stop and a resume."""
    status, elapsed, err, seen, left = interrupt(out, args, after, log)
    assert status == 143, err[-3000:]
    assert elapsed < STOP_S, f'the study took {elapsed:.1f} s to stop'
    assert seen, 'the study ran no worker process'
    assert not left, [(p.pid, p.cmdline()) for p in left]
    assert 'study interrupted: ' in err and 'run the same command again to resume' in err
    assert 'Traceback' not in err
    first = lines(out)
    records = [json.loads(line) for line in first]  # every line readable
    done = [r['id'] for r in records if not r['error']]
    assert after <= len(first) < total
    result = study(out, *args)
    assert result.returncode == 0, result.stderr[-3000:]
    assert f'{len(done)} of {total} jobs reused' in result.stderr
    final = lines(out)
    assert final[:len(first)] == first  # append-only
    ids = [json.loads(line)['id'] for line in final]
    assert all(ids.count(i) == 1 for i in done)  # a stored job never ran again
    assert len(set(ids)) == total
    return records


def throw_rows(out):
    with open(Path(out) / 'throws.csv', newline='') as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope='module')
def paper_study(tmp_path_factory):
    """The --quick study of the paper's method, stopped by SIGTERM mid-run and resumed."""
    out = tmp_path_factory.mktemp('quick')
    log = out.parent / 'quick-stderr.log'
    # interrupted among the throws: every demonstration and two throws stored
    first = check_stopped_and_resumed(out, QUICK_PAPER, 10, log, QUICK_PAPER_JOBS)
    return out, first, throw_rows(out)


def test_sigterm_stops_a_quick_study_at_once_and_the_same_command_resumes_it(paper_study):
    out, first, rows = paper_study
    assert {r['kind'] for r in first} == {'demo', 'throw'}
    assert len(rows) == 32 and {r['method'] for r in rows} == {'paper'}
    assert (out / 'report.md').exists()


def test_sigterm_stops_a_quick_study_on_a_local_dask_cluster_and_it_resumes(tmp_path):
    args = ['--quick', '--subjects', '1', '--methods', 'paper', '--workers', '2',
            '--engine', 'dask']
    check_stopped_and_resumed(tmp_path / 'dask', args, 5, tmp_path / 'stderr.log', 4 + 16)


def test_a_reordered_or_extended_method_list_reuses_every_stored_job(paper_study):
    out, _, paper_rows = paper_study
    before = lines(out)
    both = study(out, '--quick', '--methods', 'paper,pair_frame', '--workers', '2')
    assert both.returncode == 0, both.stderr[-3000:]
    assert f'{QUICK_PAPER_JOBS} of 72 jobs reused' in both.stderr
    added = [json.loads(line) for line in lines(out)[len(before):]]
    assert len(added) == 32  # only the added method's throws ran
    assert {(r['kind'], r['method']) for r in added} == {('throw', 'pair_frame')}
    rows = throw_rows(out)
    assert [r for r in rows if r['method'] == 'paper'] == paper_rows  # the shared rows
    # a results file of the earlier format is named and never mixed in
    (out / 'results-0123456789ab.jsonl').write_text(before[0] + '\n')
    reversed_ = study(out, '--quick', '--methods', 'pair_frame,paper', '--workers', '2')
    assert reversed_.returncode == 0, reversed_.stderr[-3000:]
    assert '72 of 72 jobs reused' in reversed_.stderr
    assert 'results-0123456789ab.jsonl holds results of an earlier format' in reversed_.stderr
    assert len(lines(out)) == len(before) + 32  # nothing ran
    again = throw_rows(out)  # the same rows, in the new method order
    assert sorted(tuple(r.items()) for r in again) == sorted(tuple(r.items()) for r in rows)


def test_a_second_signal_exits_at_once_and_takes_the_run_s_processes(tmp_path):
    # a run that defers the first signal (as the job loops do) and holds a child process
    script = textwrap.dedent("""
        import subprocess, sys, time
        from suture_lfd.study.signals import stop_on_signals
        with stop_on_signals() as stop, stop.deferred():
            child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])
            print(child.pid, flush=True)
            time.sleep(600)
    """)
    proc = subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        child = psutil.Process(int(proc.stdout.readline()))
        proc.send_signal(signal.SIGTERM)
        time.sleep(1.0)
        assert proc.poll() is None  # the first one only asked the run to stop
        proc.send_signal(signal.SIGINT)
        status = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert status == 130
    assert 'stopped at once by a second SIGINT' in proc.stderr.read()
    child.wait(timeout=10)
    assert not alive(child)


def plan(out, *args):
    result = study(out, '--plan', *args)
    assert result.returncode == 0, result.stderr[-3000:]
    return {j['key']: j['id'] for j in json.loads((Path(out) / 'jobs.json').read_text())}


def test_a_job_s_id_is_what_decides_its_result_not_the_jobs_beside_it(tmp_path):
    both = plan(tmp_path / 'a', '--quick', '--methods', 'paper,pair_frame')
    reversed_ = plan(tmp_path / 'b', '--quick', '--methods', 'pair_frame,paper')
    paper = plan(tmp_path / 'c', '--quick', '--methods', 'paper')
    more = plan(tmp_path / 'd', '--quick', '--methods', 'paper', '--subjects', '4')
    held = plan(tmp_path / 'e', '--quick', '--methods', 'paper', '--held-out', '1')
    seed = plan(tmp_path / 'f', '--quick', '--methods', 'paper', '--seed', '1')
    assert len(set(both.values())) == len(both) == 72
    assert reversed_ == both
    assert paper == {k: v for k, v in both.items() if '/pair_frame/' not in k}
    assert {k: more[k] for k in paper if k in more} == {k: v for k, v in paper.items()
                                                         if k in more}
    assert {k for k in paper if k in more} >= {k for k in paper if '/S01/' in k}
    assert {k: v for k, v in held.items() if not k.startswith('held_out/')} == paper
    assert not set(seed.values()) & set(paper.values())
