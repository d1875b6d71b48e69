"""Demonstration bags: written as the recorder would, read back by rosbags, mcap and the reader."""

import json
import shutil

from mcap.reader import make_reader
import numpy as np
import pytest
from suture_lfd import bags
from suture_lfd.demos.demo_bag import (
    DEMO_TOPICS,
    REQUIRED_TOPICS,
    demonstration_from_bag,
    write_demonstration_bag,
)
from suture_lfd.segmentation import segment_demonstration


@pytest.fixture(scope='module')
def bag(experienced_run, tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'demo'
    counts = write_demonstration_bag(path, experienced_run.demo)
    return path, counts


def _mcap_counts(path):
    counts = {}
    with open(next(path.glob('*.mcap')), 'rb') as handle:
        for _, channel, _ in make_reader(handle).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_the_bag_holds_the_simulator_topics_and_mcap_counts_every_message(bag, experienced_run):
    path, counts = bag
    n = experienced_run.demo.n
    assert set(DEMO_TOPICS) <= set(counts)
    assert {'/sim/markers/synth1/entry', '/sim/markers/synth1/exit'} <= set(counts)
    for topic in ('/PSM1/measured_cp', '/PSM2/measured_cp', '/sim/needle/measured_cp',
                  '/PSM1/jaw/measured_js'):
        assert counts[topic] == n
    assert _mcap_counts(path) == counts
    with bags.open_bag(path) as reader:
        assert {t: s.count for t, s in reader.topics.items()} == counts
        frames = {reader.deserialize(m).header.frame_id
                  for m in reader.messages(['/PSM1/measured_cp'])}
        kinds = [json.loads(reader.deserialize(m).string)['kind']
                 for m in reader.messages(['/sim/events'])]
    assert frames == {'PSM1_base'}
    assert kinds == ['target_pair', 'grasp', 'grasp', 'release', 'grasp', 'release']


@pytest.mark.parametrize('measured_frame', ['base', 'world'])
def test_a_demonstration_survives_the_round_trip(experienced_run, tmp_path, bag,
                                                 measured_frame):
    demo = experienced_run.demo
    if measured_frame == 'base':
        path = bag[0]
    else:
        path = tmp_path / 'world'
        write_demonstration_bag(path, demo, measured_frame='world')
    back = demonstration_from_bag(path)
    assert back.pair == 'synth1' and back.n == demo.n
    assert np.allclose(back.t, demo.t, atol=1e-9)
    for name in ('psm1_pose', 'psm2_pose', 'needle_pose'):
        a, b = getattr(demo, name), getattr(back, name)
        assert np.abs(a[:, :3] - b[:, :3]).max() < 1e-9
        assert np.all(np.abs(np.sum(a[:, 3:] * b[:, 3:], axis=1)) > 1 - 1e-9)
    assert np.allclose(back.psm1_jaw, demo.psm1_jaw) and np.allclose(back.psm2_jaw, demo.psm2_jaw)
    assert np.array_equal(back.psm1_holds, demo.psm1_holds)
    assert np.array_equal(back.psm2_holds, demo.psm2_holds)
    assert np.allclose(back.entry, demo.entry) and np.allclose(back.normal, demo.normal)
    a = segment_demonstration(demo).boundaries()
    b = segment_demonstration(back).boundaries()
    assert np.allclose(a, b, atol=1e-6)


def _copy_without(src, dst, skip):
    with bags.open_bag(src) as reader, bags.BagWriter(dst) as writer:
        for message in reader.messages():
            if message.topic == skip:
                continue
            if not writer.has_topic(message.topic):
                writer.add_topic(message.topic, message.msgtype)
            writer.write(message.topic, message.t_ns, message.rawdata)


@pytest.mark.parametrize('topic', [REQUIRED_TOPICS[0], '/sim/needle/measured_cp',
                                   '/sim/markers/synth1/exit'])
def test_a_bag_without_a_needed_topic_names_the_bag_and_the_topic(bag, tmp_path, topic):
    broken = tmp_path / 'broken'
    _copy_without(bag[0], broken, topic)
    with pytest.raises(bags.BagError) as err:
        demonstration_from_bag(broken)
    assert str(broken) in str(err.value) and topic in str(err.value)


def test_an_unknown_pair_and_a_truncated_bag_are_clear_errors(bag, tmp_path):
    with pytest.raises(bags.BagError, match='synth3'):
        demonstration_from_bag(bag[0], pair='synth3')
    cut = tmp_path / 'cut'
    shutil.copytree(bag[0], cut)
    mcap = next(cut.glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    with pytest.raises(bags.BagError) as err:
        demonstration_from_bag(cut)
    assert str(cut) in str(err.value)
