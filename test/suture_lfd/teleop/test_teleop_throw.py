"""
A person's throw through the virtual MTMs: a scripted operator with trembling hands clutches
to recentre, drives both arms through the handover, is recorded; the bag segments into the five
subtasks, and the skill learnt from it scores 1.0 on another pair of the same phantom.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys

from harness import wait_for
import pytest
from sim_bridge.common.processes import popen
from suture_lfd.demos.segment_file import SUBTASK_NAMES, SegmentFile

REPO = Path(__file__).resolve().parents[3]
SCRIPTS = REPO / 'scripts'
OPERATOR = Path(__file__).with_name('scripted_operator.py')


def run_script(name, *args, timeout):
    proc = popen([str(SCRIPTS / name), *map(str, args)], stdout=subprocess.PIPE,
                 stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
        pytest.fail(f'{name} did not finish in {timeout} s:\n{err[-3000:]}')
    return proc.returncode, out, err


def record_throw(launch, out, seed):
    """Run the graph and the scripted operator for one throw; stop the graph; return its log."""
    procs = [
        launch('simulator', '--ros-args', '-p', 'real_time_factor:=1.0'),
        launch('recorder', '--ros-args', '-p', f'output_dir:={out}', '-p', 'use_sim_time:=true'),
        launch('mtms', '--ros-args', '-p', 'device:=browser', '-p', 'pedals:=emulate'),
        launch('teleop', '--ros-args', '-r', '__node:=MTMR_PSM1'),
        launch('teleop', '--ros-args', '-r', '__node:=MTML_PSM2', '-p', 'mtm:=MTML',
               '-p', 'psm:=PSM2')]
    # the operator waits for a tool only when it lags by more than the teleop's latency makes
    # it (3 mm): a person's hand moves on, and a stop-and-go insertion would not segment
    operator = launch(sys.executable, str(OPERATOR), '--ros-args', '-p', 'subject:=S01',
                      '-p', 'pair:=synth1', '-p', f'seed:={seed}', '-p', 'timeout:=240.0',
                      '-p', 'lag_tolerance:=0.003')
    finished = wait_for(lambda: not operator.running(), timeout=600, period=0.5)
    operator.stop()
    for proc in reversed(procs):      # the scripts below start a simulator of their own
        proc.stop()
    assert finished, operator.log()[-4000:]
    return operator.log_path.read_text()


def learn_and_execute(tmp_path, log, seed):
    """Segment the recorded throw, learn it, execute it on synth3; return what went wrong."""
    lines = [x for x in log.splitlines() if x.startswith('{"')]   # the operator's result line
    assert lines, log[-4000:]
    result = json.loads(lines[-1])
    if result['score'] != 1.0:
        detail = result.get('score_detail') or {}
        # the operator's last report (stage, teleops, waits, lags): what it was waiting on
        reports = [x for x in log.splitlines() if '] [demonstrator]: stage ' in x]
        last = reports[-1].split(']: ', 1)[1] if reports else 'no report'
        return (f'seed {seed}: demonstration {result.get("reason")} {detail.get("failures")} '
                f'(last report: {last})')
    clutches = [x for x in log.splitlines() if 'operator clutched' in x]
    assert int(clutches[-1].split('clutched ')[1].split()[0]) >= 2    # it recentred its hands
    out = tmp_path / f'segments{seed}.npz'
    code, _, stderr = run_script('segment_bag.sh', Path(result['bag']), out, '--subject', 'S01',
                                 timeout=300)
    assert code == 0, stderr[-3000:]
    segments = SegmentFile.load(out)
    times = [segments.times(name) for name in SUBTASK_NAMES]
    assert all(start < end for start, end in times)
    assert all(a[0] < b[0] for a, b in zip(times, times[1:]))
    code, stdout, stderr = run_script('learn_and_execute.sh', out, 'synth3', timeout=600)
    results = [json.loads(line) for line in stdout.splitlines() if line.startswith('{')]
    if code == 0 and results and results[-1]['score'] == 1.0 \
            and all(results[-1]['subtasks'].values()):
        return ''
    return f'seed {seed}: on synth3 {results[-1] if results else stderr[-2000:]}'


def test_a_human_style_throw_through_the_virtual_mtms_is_learnt_and_scores_on_synth3(
        launch, tmp_path):
    # A live throw runs on the wall clock: now and then the insertion backs the tip out of its
    # puncture ("withdrawn"), as in the pipeline's own live test, and a demonstration's
    # insertion does not carry to the new pair; like a study subject, the operator gets
    # further throws with other seeds.
    failures = []
    for seed in (0, 1, 2, 3):
        log = record_throw(launch, tmp_path / f'demos{seed}', seed)
        failure = learn_and_execute(tmp_path, log, seed)
        if not failure:
            return
        failures.append(failure)
    pytest.fail('; '.join(failures))
