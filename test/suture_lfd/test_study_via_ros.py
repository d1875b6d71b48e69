"""
``suture-lfd study --via-ros``: the study's throws executed by real node processes over DDS on
loopback (a simulator and an executor node per throw, a private ROS domain per worker).

One subject, one pair of the synthetic phantom, the paper's method: one demonstration
(in-process) and its regeneration throw (through the nodes). The study process itself never
imports rclpy; the rows of its CSV must be what the executor node reported.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest
from suture_lfd.study import report
from suture_lfd.study.records import ThrowJob
from suture_lfd.study.ros import (
    DomainLease,
    RosSettings,
    RosThrowError,
    RosThrows,
    outcome_from_result,
)

TINY = ['--subjects', '1', '--phantoms', 'synthetic', '--pairs', '1', '--methods', 'paper']
TIMEOUT = 900   # s of wall time for the whole tiny study on a loaded 2-core machine
THROW_KEY = 'throw/paper/S01/synth1/synth1'


def study(out, *args):
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT)


def records(out):
    (path,) = Path(out).glob('results.jsonl')
    return [json.loads(line) for line in path.read_text().splitlines()]


def children(pids):
    """Return the pids of the live processes whose parent is in ``pids``."""
    found = set()
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / 'stat').read_text().rsplit(')', 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) in pids and fields[0] != 'Z':
                found.add(int(entry.name))
    return found


def cmdline(pid):
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().decode(errors='replace')
    except OSError:
        return ''


def alive(pid):
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state != 'Z'


@pytest.fixture(scope='module')
def via_ros(tmp_path_factory):
    out = tmp_path_factory.mktemp('study_via_ros')
    result = study(out, *TINY, '--workers', '1', '--via-ros')
    assert result.returncode == 0, result.stderr[-3000:]
    return out, result


def test_a_via_ros_study_reports_what_the_nodes_did(via_ros):
    out, result = via_ros
    assert 'report:' in result.stderr
    jobs = {r['key']: r for r in records(out)}
    assert set(jobs) == {'demo/S01/synth1', THROW_KEY}
    throw = jobs[THROW_KEY]
    assert not throw['error'], throw['error']
    # the executor node's own outcome of the throw, kept by the study
    node = json.loads((out / 'ros' / 'results' / 'paper_S01_synth1_synth1.json').read_text())
    assert node['key'] == THROW_KEY and node['pair'] == 'synth1' and node['state'] == 'done'
    assert node['method'] == 'paper' and node['learnt_on'] == 'synth1'
    assert node['servo_cp_sent'] > 100 and node['domain_id'] != int(os.environ['ROS_DOMAIN_ID'])
    (row,) = report.read_csv(out / 'throws.csv')
    assert float(row['score']) == node['score'] == throw['score']
    assert float(row['time_s']) == pytest.approx(node['time_s'], abs=1e-5)
    assert float(row['entry_error_mm']) == pytest.approx(node['entry_error_mm'], abs=1e-5)
    assert float(row['exit_error_mm']) == pytest.approx(node['exit_error_mm'], abs=1e-5)
    for task in ('i', 'ii', 'iii', 'iv', 'v'):
        assert (row[task] == 'true') == node['subtasks'][task]
    assert float(row['score']) == 1.0 or row['failure']
    # the needle the simulator node measured during ii and iv made the executed curves
    assert float(row['ii_exec_traj_mm']) >= 0.0 and float(row['iv_exec_traj_mm']) >= 0.0
    config = json.loads((out / 'config.json').read_text())
    assert config['via_ros']['nodes']['real_time_factor'] > 0
    assert not list((out / 'ros' / 'logs').glob('*.log'))   # logs of good throws are dropped


def test_the_in_process_plan_has_the_same_jobs_and_fields(via_ros, tmp_path):
    out, _ = via_ros
    plan = study(tmp_path / 'plan', *TINY, '--plan')
    assert plan.returncode == 0, plan.stderr
    jobs = json.loads((tmp_path / 'plan' / 'jobs.json').read_text())
    assert {j['key'] for j in jobs} == {r['key'] for r in records(out)}
    ros_plan = study(tmp_path / 'ros_plan', *TINY, '--plan', '--via-ros')
    assert ros_plan.returncode == 0, ros_plan.stderr
    ros_jobs = json.loads((tmp_path / 'ros_plan' / 'jobs.json').read_text())
    # the same jobs with the same fields; their ids differ: a job's id holds the via-ros
    # settings, so results through the nodes never stand in for in-process ones
    assert [{k: v for k, v in j.items() if k != 'id'} for j in ros_jobs] == \
        [{k: v for k, v in j.items() if k != 'id'} for j in jobs]
    assert not {j['id'] for j in ros_jobs} & {j['id'] for j in jobs}
    hashes = [json.loads((p / 'config.json').read_text())['hash']
              for p in (tmp_path / 'plan', tmp_path / 'ros_plan')]
    assert hashes[0] != hashes[1]   # results through the nodes never mix with in-process ones
    # the record of a throw has the fields an in-process throw record has
    in_process = tmp_path / 'in_process'
    result = study(in_process, *TINY, '--workers', '1')
    assert result.returncode == 0, result.stderr[-3000:]
    mine = {r['key']: r for r in records(in_process)}
    theirs = {r['key']: r for r in records(out)}
    assert set(mine[THROW_KEY]) == set(theirs[THROW_KEY])
    assert (in_process / 'throws.csv').read_text().splitlines()[0] == \
        (out / 'throws.csv').read_text().splitlines()[0]


def test_a_throw_the_nodes_do_not_finish_in_time_fails_with_the_reason(via_ros, tmp_path):
    out, _ = via_ros
    from suture_lfd.skill import ThrowSkill

    skill = ThrowSkill.load(out / 'ros' / 'skills' / 'paper_S01_synth1.npz')
    job = ThrowJob(key=THROW_KEY, subject='S01', group='experienced', method='paper',
                   train_phantom='synthetic', train_pair='synth1', test_phantom='synthetic',
                   test_pair='synth1', seed=3, demo_key='demo/S01/synth1')
    runner = RosThrows(RosSettings(domain_base=os.getpid(), wall_timeout=4.0), tmp_path, 60.0)
    try:
        with pytest.raises(RosThrowError, match='no outcome after 4 s of wall time') as info:
            runner.execute(job, skill)
    finally:
        runner.close()
    assert 'logs:' in str(info.value)
    assert (tmp_path / 'ros' / 'logs' / 'paper_S01_synth1_synth1.executor.log').exists()
    # both nodes stopped (multiprocessing's resource tracker, started by an earlier test of
    # this process that ran worker processes, lives as long as this process and is no node)
    assert not {p for p in children({os.getpid()})
                if 'multiprocessing.resource_tracker' not in cmdline(p)}


def test_a_throw_the_executor_stopped_is_an_error_and_planning_failures_score_zero():
    with pytest.raises(RosThrowError, match='stopped'):
        outcome_from_result({'state': 'stopped', 'reason': 'no /clock ...: the simulator '
                             'stopped', 'duration': 3.0, 'score': 0.0})
    with pytest.raises(RosThrowError, match='arms not enabled'):
        outcome_from_result({'state': 'failed', 'reason': 'arms not enabled and homed',
                             'duration': None, 'score': None})
    unreachable = outcome_from_result({'state': 'failed', 'reason': 'cannot plan',
                                       'planning_error': 'no grasp', 'duration': None})
    assert unreachable.score == 0.0 and unreachable.failure == 'unreachable: no grasp'


def test_workers_lease_different_domains(tmp_path):
    leases = [DomainLease(base=7, avoid=9) for _ in range(3)]
    try:
        ids = [lease.domain_id for lease in leases]
        assert len(set(ids)) == 3 and 9 not in ids and all(1 <= i <= 101 for i in ids)
    finally:
        for lease in leases:
            lease.release()
    again = DomainLease(base=7, avoid=9)   # given back: the first id is free again
    assert again.domain_id == ids[0]
    again.release()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGKILL], ids=['ctrl-c', 'sigkill'])
def test_ctrl_c_or_a_kill_stops_the_study_and_its_nodes(tmp_path, sig):
    # Ctrl-C: the study's process group; SIGKILL: the study's process alone (no clean-up of
    # its own), after which its workers and their nodes must not live on
    out = tmp_path / 'interrupted'
    cmd = [sys.executable, '-m', 'suture_lfd.cli', 'study', '--out', str(out), *TINY,
           '--workers', '2', '--via-ros']
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    nodes = set()
    try:
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline and not nodes:   # until a throw's nodes run
            assert proc.poll() is None, proc.communicate()[1][-3000:]
            workers = children({proc.pid})
            nodes = {p for p in children(workers) if 'simulator' in cmdline(p)}
            time.sleep(0.2)
        workers = children({proc.pid})
        nodes |= children(workers)
        assert nodes, 'no node process started'
        if sig == signal.SIGINT:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            os.kill(proc.pid, signal.SIGKILL)
            nodes |= {w for w in workers if 'resource_tracker' not in cmdline(w)}
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == (130 if sig == signal.SIGINT else -signal.SIGKILL), err[-3000:]
    deadline = time.monotonic() + 30.0
    while any(alive(p) for p in nodes) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [p for p in nodes if alive(p)]
