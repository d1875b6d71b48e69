"""
The demonstration pipeline over real processes: script-driven recording, bag read-back by two
readers, the segmenter, and (with the executor node) learning on one pair and executing on another.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile

from mcap.reader import make_reader
import pytest
from suture_lfd import bags
from suture_lfd.demos.demo_bag import demonstration_from_bag
from suture_lfd.demos.segment_file import SUBTASK_NAMES, SegmentFile
import yaml

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = REPO / 'scripts'
RECORD_TIMEOUT = 900.0   # s of wall time: the whole throw on a loaded 2-core machine


def run_script(name, *args, timeout, cwd=None):
    """Run a script in its own process group; kill the group if it overruns."""
    logs = Path(tempfile.mkdtemp(prefix='script-logs-'))
    proc = subprocess.Popen([str(SCRIPTS / name), *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd,
                            env={**os.environ, 'SUTURE_LFD_LOGS': str(logs)},
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
        pytest.fail(f'{name} did not finish in {timeout} s:\n{err[-3000:]}')
    if proc.returncode == 0:  # a script that succeeds cleans its logs up
        assert not logs.exists(), list(logs.rglob('*'))
    return proc.returncode, out, err


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    # A live throw runs on the wall clock: now and then (about one full test run in three on
    # this machine) the subject's insertion backs the tip out of its puncture ("withdrawn").
    # Like a study subject, who gets up to three attempts, the subject gets a second throw with
    # another seed; a failed one is kept in the message if both fail.
    failures = []
    for seed in ('0', '1'):
        out = tmp_path_factory.mktemp('demos')
        code, stdout, stderr = run_script('record_demo.sh', '--subject', 'S01', '--pair',
                                          'synth1', '--seed', seed, '--out', out,
                                          timeout=RECORD_TIMEOUT)
        if code == 0:
            break
        failures.append(stderr[-4000:])
    assert code == 0, '\n'.join(failures)
    bag = Path(stdout.strip().splitlines()[-1])
    line = [x for x in stderr.splitlines() if 'throw on ' in x][-1]
    return bag, json.loads(line[line.index('{'):])


def _mcap_counts(bag):
    counts = {}
    for file in sorted(bag.glob('*.mcap')):
        with open(file, 'rb') as handle:
            for _, channel, _ in make_reader(handle).iter_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_a_scripted_demonstration_is_recorded_to_one_bag(recorded):
    bag, result = recorded
    assert bag.is_dir() and bag.parent.is_dir()
    assert [p for p in bag.parent.iterdir() if p.is_dir()] == [bag]   # one bag, one throw
    assert result['completed'] and result['score'] == 1.0 and result['bag'] == str(bag)


def test_the_bag_opens_with_rosbags_and_mcap_and_holds_every_message_received(recorded):
    bag, result = recorded
    with bags.open_bag(bag) as reader:
        counts = {t: s.count for t, s in reader.topics.items()}
        events = [json.loads(reader.deserialize(m).string)
                  for m in reader.messages(['/sim/events'])]
    assert _mcap_counts(bag) == counts
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    recorder_counts = json.loads(info['custom_data']['suture_lfd.counts'])
    for topic, c in recorder_counts.items():
        assert c['written'] == c['received'] + c['carried'] == counts.get(topic, 0), topic
    # every command the subject published reached the bag
    for topic, published in result['published'].items():
        assert counts[topic] == published, topic
    for topic in ('/PSM1/measured_cp', '/PSM2/measured_cp', '/sim/needle/measured_cp',
                  '/sim/markers/synth1/entry', '/sim/PSM2/base_frame', '/footpedals/coag'):
        assert counts.get(topic, 0) > 0, topic
    kinds = [e['kind'] for e in events]
    assert kinds.count('grasp') == 3 and 'extracted' in kinds
    assert [e['score']['score'] for e in events if e['kind'] == 'score'][-1] == 1.0


def test_the_segmenter_finds_the_five_subtasks(recorded, tmp_path):
    bag, _ = recorded
    out = tmp_path / 'segments.npz'
    code, stdout, stderr = run_script('segment_bag.sh', bag, out, '--subject', 'S01',
                                      timeout=300)
    assert code == 0, stderr[-3000:]
    assert Path(stdout.strip().splitlines()[-1]) == out
    segments = SegmentFile.load(out)
    times = [segments.times(name) for name in SUBTASK_NAMES]
    assert all(start < end for start, end in times)
    assert all(a[0] < b[0] for a, b in zip(times, times[1:]))
    assert segments.pair == 'synth1' and segments.subject == 'S01'
    demo = demonstration_from_bag(bag)
    assert demo.t[0] <= times[0][0] and times[-1][1] <= demo.t[-1] + 1e-6


def test_the_segmenter_names_a_bag_it_cannot_read(tmp_path, launch):
    missing = tmp_path / 'no_such_bag'
    proc = launch('segmenter', '--ros-args', '-p', f'bag:={missing}')
    assert proc.popen.wait(120) == 1
    assert str(missing) in proc.log()


def test_the_demonstrator_refuses_an_unknown_subject(launch):
    proc = launch('demonstrator', '--ros-args', '-p', 'subject:=S99')
    assert proc.popen.wait(120) == 2
    assert 'S99' in proc.log()


def test_the_executor_trained_on_synth1_executes_on_synth3(recorded, tmp_path):
    if not (REPO / 'suture_lfd' / 'nodes' / 'executor.py').is_file():
        pytest.skip('the executor node is not part of this checkout yet')
    assert (Path(sys.executable).parent / 'executor').is_file()
    bag, _ = recorded
    out = tmp_path / 'segments.npz'
    code, _, stderr = run_script('segment_bag.sh', bag, out, timeout=300)
    assert code == 0, stderr[-3000:]
    code, stdout, stderr = run_script('learn_and_execute.sh', out, 'synth3',
                                      timeout=RECORD_TIMEOUT)
    assert code == 0, stderr[-4000:]
    results = [json.loads(line) for line in stdout.splitlines() if line.startswith('{')]
    assert len(results) == 1, stdout  # one result line
    final = results[0]
    assert final['score'] == 1.0 and all(final['subtasks'].values())   # exit code 0 says so
