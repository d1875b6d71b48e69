"""Segment files: resampled needle trajectories, grasps, timing; save/load and its errors."""

import numpy as np
import pytest
from sim_bridge.common.geometry import transform_from_pose
from suture_lfd.dmp import load_dmp_params
from suture_lfd.segmentation import segment_demonstration
from suture_lfd.segmentation.segments import FORMAT, SegmentFile, make_segment_file


@pytest.fixture(scope='module')
def segments(experienced_run):
    demo = experienced_run.demo
    seg = segment_demonstration(demo)
    return demo, seg, make_segment_file(demo, seg, source='test', subject='S01')


def test_the_needle_trajectories_of_ii_and_iv_are_resampled_to_table_one(segments):
    demo, seg, sf = segments
    for task in ('ii', 'iv'):
        t, poses = sf.needle(task)
        assert len(t) == load_dmp_params(task=task).n_pts
        start, end = seg[task].start_time, seg[task].end_time
        assert demo.t[seg[task].start_index] == pytest.approx(t[0])
        assert abs(t[0] - start) <= 0.01 and abs(t[-1] - end) <= 0.01
        # the resampled path passes through the recorded needle positions
        k = seg[task].start_index + 3
        j = np.argmin(np.abs(t - demo.t[k]))
        assert np.linalg.norm(poses[j, :3] - demo.needle_pose[k, :3]) < 2e-4
        q = poses[:, 3:]
        assert np.all(np.sum(q[1:] * q[:-1], axis=1) > 0.0)   # sign-continuous
    assert np.allclose(sf.subtask_times, seg.boundaries())
    assert sf.pair == demo.pair and np.allclose(sf.entry, demo.entry)


def test_the_grasps_carry_the_tool_onto_the_needle(segments):
    demo, seg, sf = segments
    for task, tools in (('ii', demo.psm2_pose), ('iv', demo.psm1_pose)):
        k = seg[task].end_index
        needle = transform_from_pose(tools[k]) @ sf.grasp(task)
        assert np.linalg.norm(needle[:3, 3] - demo.needle_pose[k, :3]) < 1e-4


def test_save_and_load_give_the_same_segments(segments, tmp_path):
    sf = segments[2]
    path = tmp_path / 'seg.npz'
    sf.save(path)
    back = SegmentFile.load(path)
    for name in ('ii_t', 'ii_needle', 'iv_needle', 'ii_grasp', 'subtask_times', 'normal'):
        assert np.array_equal(getattr(back, name), getattr(sf, name))
    assert (back.pair, back.subject, back.source) == ('synth1', 'S01', 'test')


def _rewrite(src, dst, **changes):
    with np.load(src) as data:
        arrays = {k: data[k] for k in data.files}
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    with open(dst, 'wb') as handle:
        np.savez(handle, **arrays)


@pytest.mark.parametrize(('changes', 'words'), [
    ({'format_version': np.array(7)}, ['format_version', '7']),
    ({'format': np.array('suture_lfd.demonstration')}, ['format', FORMAT]),
    ({'iv_grasp': None}, ["'iv_grasp'"]),
    ({'ii_needle': np.zeros((3, 7))}, ['ii_needle']),
])
def test_a_wrong_segment_file_names_the_file_and_the_key(segments, tmp_path, changes, words):
    good = tmp_path / 'good.npz'
    segments[2].save(good)
    bad = tmp_path / 'bad.npz'
    _rewrite(good, bad, **changes)
    with pytest.raises(ValueError) as err:
        SegmentFile.load(bad)
    assert str(bad) in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_a_file_that_is_not_an_archive_is_refused(tmp_path):
    path = tmp_path / 'text.npz'
    path.write_text('hello')
    with pytest.raises(ValueError, match=str(path)):
        SegmentFile.load(path)
