import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.scene.scene_config import load_scene_config
from sim_bridge.scene.tissue import TissueTracker
from suture_lfd.planning.throw_geometry import ThrowArc


@pytest.fixture(scope='module')
def scene():
    return load_scene_config()


@pytest.fixture(scope='module')
def phantoms(scene):
    return {name: scene.build_phantom(name) for name in ('synthetic', 'scanned')}


def drive(tracker, poses, dt=0.001):
    events = []
    for k, T in enumerate(poses):
        events += tracker.update(k * dt, T)
    return events


def rotation_through(arc, shift=None, n=1500):
    shift = np.zeros(3) if shift is None else shift
    alphas = np.linspace(arc.alpha_entry + 0.3, arc.alpha_through - 0.3, n)
    for a in alphas:
        T = arc.T_world_needle(a)
        T[:3, 3] += shift
        yield T


def all_pairs(phantoms):
    return [(p, name) for p in phantoms.values() for name in p.markers]


def test_a_rotation_about_the_arc_centre_hits_both_markers_without_trauma(scene, phantoms):
    for phantom, name in all_pairs(phantoms):
        tracker = TissueTracker(phantom, scene.needle, scene.tissue)
        tracker.set_target_pair(name)
        arc = ThrowArc(phantom.markers[name], scene.needle)
        events = drive(tracker, rotation_through(arc))
        assert [e.kind for e in events] == ['entry', 'exit', 'extracted'], name
        entry, exit_, extracted = events
        assert entry.distance_to_marker < 5e-5 and exit_.distance_to_marker < 5e-5
        assert entry.marker_name == f'{name}.entry' and exit_.marker_name == f'{name}.exit'
        assert extracted.t > exit_.t > entry.t
        assert tracker.trauma_max < 1e-6
        state = tracker.state()
        assert state.extracted and not state.in_tissue and state.inside_fraction == 0.0
        assert state.entry_error < 5e-5 and state.exit_error < 5e-5


def test_the_same_motion_shifted_5_mm_along_the_wound_misses_by_5_mm(scene, phantoms):
    phantom = phantoms['synthetic']
    tracker = TissueTracker(phantom, scene.needle, scene.tissue)
    tracker.set_target_pair('synth2')
    pair = phantom.markers['synth2']
    arc = ThrowArc(pair, scene.needle)
    along = pair.frame[:3, 1]
    events = drive(tracker, rotation_through(arc, shift=0.005 * along))
    assert [e.kind for e in events] == ['entry', 'exit', 'extracted']
    assert events[0].distance_to_marker == pytest.approx(0.005, abs=1e-4)
    assert events[1].distance_to_marker == pytest.approx(0.005, abs=1e-4)
    assert tracker.trauma_max < 1e-6


def test_without_a_target_the_error_is_to_the_nearest_marker_of_the_kind(scene, phantoms):
    phantom = phantoms['scanned']
    tracker = TissueTracker(phantom, scene.needle, scene.tissue)
    arc = ThrowArc(phantom.markers['scan3'], scene.needle)
    events = drive(tracker, rotation_through(arc))
    assert events[0].distance_to_marker < 5e-5 and events[0].marker_name == 'scan3.entry'
    with pytest.raises(ValueError, match='unknown marker pair'):
        tracker.set_target_pair('scan9')


def test_sideways_translation_while_inside_is_trauma(scene, phantoms):
    phantom = phantoms['synthetic']
    tracker = TissueTracker(phantom, scene.needle, scene.tissue)
    tracker.set_target_pair('synth1')
    arc = ThrowArc(phantom.markers['synth1'], scene.needle)
    mid = 0.5 * (arc.alpha_entry + arc.alpha_exit)
    alphas = np.linspace(arc.alpha_entry + 0.2, mid, 300)
    poses = [arc.T_world_needle(a) for a in alphas]
    events = drive(tracker, poses)
    assert [e.kind for e in events] == ['entry']
    T = poses[-1].copy()
    sideways = arc.plane_normal
    more = []
    for k in range(1, 101):
        Tk = T.copy()
        Tk[:3, 3] += 0.0015 * k / 100 * sideways
        more += tracker.update(1.0 + k * 0.001, Tk)
    assert tracker.trauma_max == pytest.approx(0.0015, abs=1e-4)
    assert tracker.trauma_mean > 0.0
    trauma = [e for e in more if e.kind == 'trauma']
    assert len(trauma) == 1 and trauma[0].deviation > scene.tissue.trauma_event_threshold


def test_backing_the_needle_out_is_a_withdrawal_not_an_exit(scene, phantoms):
    phantom = phantoms['synthetic']
    tracker = TissueTracker(phantom, scene.needle, scene.tissue)
    arc = ThrowArc(phantom.markers['synth3'], scene.needle)
    mid = 0.5 * (arc.alpha_entry + arc.alpha_exit)
    alphas = np.concatenate([np.linspace(arc.alpha_entry + 0.2, mid, 200),
                             np.linspace(mid, arc.alpha_entry + 0.2, 200)])
    events = drive(tracker, [arc.T_world_needle(a) for a in alphas])
    assert [e.kind for e in events] == ['entry', 'withdrawn']
    assert not tracker.in_tissue and not tracker.extracted


def test_inside_fraction_counts_needle_points_under_the_surface(scene, phantoms):
    phantom = phantoms['synthetic']
    tracker = TissueTracker(phantom, scene.needle, scene.tissue)
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.01, 0.02]
    tracker.update(0.0, T)
    assert tracker.inside_fraction == 0.0 and not tracker.tip_inside
    T[:3, 3] = [0.0, 0.0, -0.005]
    tracker.update(0.001, T)
    assert tracker.inside_fraction == 1.0
    arc = ThrowArc(phantom.markers['synth4'], scene.needle)
    tracker.reset()
    tracker.update(0.0, arc.T_world_needle(arc.alpha_exit))
    expected = arc.inside_angle / scene.needle.arc
    assert tracker.inside_fraction == pytest.approx(expected, abs=1.5 / 24)


def test_random_rigid_motions_keep_events_consistent(scene, phantoms):
    """Every exit follows an entry; errors are distances to real markers."""
    phantom = phantoms['scanned']
    rng = np.random.default_rng(3)
    for _ in range(20):
        tracker = TissueTracker(phantom, scene.needle, scene.tissue)
        pos = np.array([0.0, 0.0, 0.01])
        rotvec = rng.normal(size=3)
        events = []
        for k in range(200):
            pos = pos + rng.normal(scale=0.0008, size=3) + [0, 0, -0.0001]
            rotvec = rotvec + rng.normal(scale=0.05, size=3)
            T = np.eye(4)
            T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
            T[:3, 3] = pos
            events += tracker.update(k * 0.01, T)
        depth = 0
        for e in events:
            if e.kind == 'entry':
                depth += 1
            elif e.kind in ('exit', 'withdrawn'):
                depth -= 1
            assert depth in (0, 1)
            if e.kind in ('entry', 'exit', 'withdrawn'):
                q = phantom.to_phantom(e.point)
                on_top = abs(q[2] - phantom.height(q[:2])) < 1e-4
                on_bottom = abs(q[2] - phantom.surface.bottom_height(q[:2])) < 1e-4
                on_side = abs(abs(q[0]) - 0.03) < 1e-3 or abs(abs(q[1]) - 0.0225) < 1e-3
                assert on_top or on_bottom or on_side
                assert math.isfinite(e.distance_to_marker)


def _held(poses, hold):
    """Every pose of ``poses`` repeated ``hold`` times (a needle that stops now and then)."""
    return [T for T in poses for _ in range(hold)]


def _same_values_other_bytes(T):
    """The pose with its unused bottom row changed: a tracker cannot take it for the last one."""
    T = T.copy()
    T[3, 0] = 1e-300
    return T


def test_a_needle_held_still_counts_as_if_every_update_were_computed(scene, phantoms):
    phantom = phantoms['synthetic']
    arc = ThrowArc(phantom.markers['synth1'], scene.needle)
    mid = 0.5 * (arc.alpha_entry + arc.alpha_exit)
    poses = [arc.T_world_needle(a) for a in np.linspace(arc.alpha_entry + 0.3, mid, 60)]
    sideways = arc.plane_normal
    for k in range(1, 41):  # then it strays sideways inside the tissue (trauma)
        T = poses[-1].copy()
        T[:3, 3] += 0.0015 * k / 40 * sideways
        poses.append(T)
    poses += [arc.T_world_needle(a) for a in np.linspace(mid, arc.alpha_through - 0.3, 120)]
    held = _held(poses, 4)
    recomputed = [T if k % 4 == 0 else _same_values_other_bytes(T) for k, T in enumerate(held)]
    a = TissueTracker(phantom, scene.needle, scene.tissue)
    b = TissueTracker(phantom, scene.needle, scene.tissue)
    for tracker in (a, b):
        tracker.set_target_pair('synth1')
    events_a, events_b = drive(a, held), drive(b, recomputed)
    assert [e.kind for e in events_a] == [e.kind for e in events_b]
    assert {'entry', 'trauma', 'exit', 'extracted'} <= {e.kind for e in events_a}
    assert [(e.t, e.deviation, e.distance_to_marker) for e in events_a] == \
        [(e.t, e.deviation, e.distance_to_marker) for e in events_b]
    sa, sb = a.state(), b.state()
    assert a.trauma_mean > 0.0
    for name in ('t', 'tip_inside', 'inside_fraction', 'in_tissue', 'trauma_current',
                 'trauma_max', 'trauma_mean', 'entry_error', 'exit_error', 'extracted',
                 'n_entries', 'n_exits'):
        assert getattr(sa, name) == getattr(sb, name), name


def _recording(test, results):
    def recorded(T):
        results.append(test(T))
        return results[-1]
    return recorded


def test_a_needle_wholly_above_the_tissue_is_followed_as_if_every_update_were_computed(
        scene, phantoms):
    for phantom, name in all_pairs(phantoms):
        arc = ThrowArc(phantom.markers[name], scene.needle)
        normal = phantom.markers[name].entry_normal
        start = arc.T_world_needle(arc.alpha_entry + 0.3)
        poses = []
        for k in range(200):  # lowered onto the tissue from 2 cm above, then the throw
            T = start.copy()
            T[:3, 3] += (0.02 * (1.0 - k / 199)) * normal
            poses.append(T)
        poses += list(rotation_through(arc, n=600))
        for k in range(1, 200):  # and lifted away
            T = poses[-1].copy()
            T[2, 3] += 0.0001 * k
            poses.append(T)
        fast = TissueTracker(phantom, scene.needle, scene.tissue)
        full = TissueTracker(phantom, scene.needle, scene.tissue)
        full._clear_of_tissue = lambda T: False
        clear = []
        fast._clear_of_tissue = _recording(fast._clear_of_tissue, clear)
        for tracker in (fast, full):
            tracker.set_target_pair(name)
        events_fast, events_full = drive(fast, poses), drive(full, poses)
        assert sum(clear) > 150, name  # most of the approach and the lift took the short way
        assert [e.kind for e in events_fast][:3] == ['entry', 'exit', 'extracted'], name
        assert [(e.kind, e.t, e.point.tolist(), e.distance_to_marker) for e in events_fast] == \
            [(e.kind, e.t, e.point.tolist(), e.distance_to_marker) for e in events_full]
        a, b = fast.state(), full.state()
        for field_name in ('t', 'tip_inside', 'inside_fraction', 'in_tissue', 'trauma_max',
                           'trauma_mean', 'entry_error', 'exit_error', 'extracted'):
            assert getattr(a, field_name) == getattr(b, field_name), (name, field_name)
