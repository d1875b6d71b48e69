import numpy as np
import pytest
from suture_lfd.demos.demonstration import Demonstration
from suture_lfd.demos.synthetic_throw import needle_throw


def make_demo(n=40, **changes):
    T, P, Q = needle_throw(n, 2.0)
    values = {'t': T, 'psm1_pose': np.hstack((P - 0.01, Q)), 'psm2_pose': np.hstack((P, Q)),
              'psm1_jaw': np.full(n, 0.5), 'psm2_jaw': np.zeros(n),
              'needle_pose': np.hstack((P, Q)), 'psm1_holds': np.zeros(n, bool),
              'psm2_holds': np.ones(n, bool), 'entry': [0.0, 0.0, 0.0],
              'exit': [0.01, 0.0, 0.0], 'normal': [0.0, 0.0, 1.0], 'pair': 'synth2'}
    values.update(changes)
    return Demonstration(**values)


def test_a_demonstration_round_trips_through_a_file(tmp_path):
    demo = make_demo()
    path = tmp_path / 'demo.npz'
    demo.save(path)
    again = Demonstration.load(path)
    for name in demo.__dataclass_fields__:
        assert np.array_equal(getattr(again, name), getattr(demo, name)), name
    assert again.pair == 'synth2' and again.psm2_holds.dtype == bool


def test_a_window_keeps_the_samples_in_it():
    demo = make_demo()
    part = demo.window(5, 20)
    assert part.n == 16 and part.t[0] == demo.t[5] and part.t[-1] == demo.t[20]
    assert np.array_equal(part.needle_pose, demo.needle_pose[5:21])
    with pytest.raises(ValueError, match='window needs'):
        demo.window(20, 5)


@pytest.mark.parametrize('field, value, message', [
    ('t', np.r_[np.linspace(0.0, 1.0, 39), 0.5], r't must be strictly increasing'),
    ('psm2_pose', np.full((40, 7), np.nan), r'psm2_pose must be finite'),
    ('needle_pose', np.zeros((40, 7)), r'needle_pose orientation is not a unit quaternion'),
    ('psm1_jaw', np.zeros(39), r'psm1_jaw must have shape \(40\)'),
    ('psm1_holds', np.full(40, 2), r'psm1_holds must be booleans'),
    ('normal', [0.0, 0.0, 2.0], r'normal must be a unit vector'),
])
def test_invalid_records_are_rejected_naming_the_field(field, value, message):
    with pytest.raises(ValueError, match=message):
        make_demo(**{field: value})


def test_loading_checks_the_format(tmp_path):
    path = tmp_path / 'demo.npz'
    make_demo().save(path)
    with np.load(path) as data:
        arrays = dict(data)
    arrays['format_version'] = np.array(7)
    with open(path, 'wb') as handle:
        np.savez(handle, **arrays)
    with pytest.raises(ValueError, match=r'demo\.npz.*version 7'):
        Demonstration.load(path)
    junk = tmp_path / 'junk.npz'
    junk.write_bytes(b'junk')
    with pytest.raises(ValueError, match=r'junk\.npz'):
        Demonstration.load(junk)
