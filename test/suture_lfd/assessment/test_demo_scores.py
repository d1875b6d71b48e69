"""Scores of a demonstration: geometric measures on constructed needle motions, and a real bag."""

import math

import numpy as np
import pytest
from sim_bridge.common.geometry import pose_from_transform
from sim_bridge.common.needle import NeedleGeometry
from suture_lfd.assessment.demo_scores import (
    arc_deviation,
    plane_tilt_deg,
    read_score_table,
    surface_crossings,
    tip_positions,
)

NEEDLE = NeedleGeometry()


def _rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _poses(R_list, centres):
    out = []
    for R, c in zip(R_list, centres):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, c
        out.append(pose_from_transform(T))
    return np.array(out)


# the needle plane is world x-z: needle x -> world x, needle y -> world -z, needle z -> y
_PLANE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _throw(n=200, centre_height=0.004, turn_deg=175.0):
    """Needle turned tip first about its centre (above a surface z = 0), tip down and up."""
    angles = np.linspace(0.0, math.radians(turn_deg), n)
    R = [_PLANE @ _rot_z(math.radians(120) - a) for a in angles]
    centres = np.tile([0.0, 0.0, centre_height], (n, 1))
    return np.linspace(0.0, 2.0, n), _poses(R, centres)


def test_a_needle_turned_about_its_centre_crosses_the_surface_on_its_circle():
    t, poses = _throw()
    tips = tip_positions(poses, NEEDLE)
    normal = np.array([0.0, 0.0, 1.0])
    half_chord = math.sqrt(NEEDLE.radius ** 2 - 0.004 ** 2)
    entry = np.array([-half_chord, 0.0, 0.0])
    exit_ = np.array([half_chord, 0.0, 0.0])
    ins = surface_crossings(t, tips, entry, normal, inward=True)
    outs = surface_crossings(t, tips, exit_, normal, inward=False)
    assert len(ins) == 1 and len(outs) == 1
    assert ins[0].error_m == pytest.approx(0.0, abs=2e-5)
    assert outs[0].error_m == pytest.approx(0.0, abs=2e-5)
    # shifted markers: the error is the shift
    moved = surface_crossings(t, tips, entry + [0.0015, 0.0, 0.0], normal, inward=True)
    assert moved[0].error_m == pytest.approx(0.0015, abs=2e-5)
    # turning about its own centre, the needle stays on the path it cut
    dev_max, dev_mean = arc_deviation(t, poses, ins + outs, NEEDLE, t[-1])
    assert dev_max == pytest.approx(0.0, abs=1e-6)


def test_a_needle_dragged_sideways_strays_from_its_arc_by_the_drag():
    t, poses = _throw()
    tips = tip_positions(poses, NEEDLE)
    half_chord = math.sqrt(NEEDLE.radius ** 2 - 0.004 ** 2)
    ins = surface_crossings(t, tips, np.array([-half_chord, 0.0, 0.0]),
                            np.array([0.0, 0.0, 1.0]), inward=True)
    dragged = poses.copy()
    after = t > ins[0].t
    dragged[after, 1] += 0.0007   # 0.7 mm along the needle plane's normal
    dev_max, _ = arc_deviation(t, dragged, ins, NEEDLE, t[-1])
    assert dev_max == pytest.approx(0.0007, rel=1e-6)


@pytest.mark.parametrize('tilt_deg', [0.0, 3.0, 12.5])
def test_the_tilt_of_the_needle_plane_is_the_turn_about_the_surface_normal(tilt_deg):
    _, poses = _throw(n=20)
    a = math.radians(tilt_deg)
    R = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0],
                  [0.0, 0.0, 1.0]])
    from sim_bridge.common.geometry import transform_from_pose
    T = transform_from_pose(poses)
    turned = pose_from_transform(np.einsum('ij,njk->nik', np.block(
        [[R, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]), T))
    tilt = plane_tilt_deg(turned, [-0.004, 0, 0], [0.004, 0, 0], np.array([0.0, 0.0, 1.0]))
    assert tilt == pytest.approx(np.full(20, tilt_deg), abs=1e-6)


def test_suture_lfd_assess_scores_a_real_demonstration_bag(experienced_run, tmp_path, capsys):
    from suture_lfd.cli import main
    from suture_lfd.demos.demo_bag import write_demonstration_bag

    demo = experienced_run.demo
    bag = tmp_path / 'demo_bag'
    write_demonstration_bag(bag, demo)
    out = tmp_path / 'scores.csv'
    assert main(['assess', str(bag), '--out', str(out)]) == 0
    row = read_score_table(out)
    assert row['pair'] == 'synth1'
    assert row['task_time_s'] == pytest.approx(demo.t[-1] - demo.t[0], abs=0.02)
    assert sum(row[f't_{k}_s'] for k in ('i', 'ii', 'iii', 'iv', 'v')) < row['task_time_s']
    assert row['psm1_grasps'] == 1 and row['psm2_grasps'] == 2 and row['regrasps'] == 0
    assert row['entries'] == 1
    # a successful experienced throw: the tip enters and leaves near its markers
    assert row['entry_error_mm'] < 3.0 and row['exit_error_mm'] < 3.0
    assert 0.0 <= row['arc_deviation_max_mm'] < 1.0
    assert 0.0 < row['psm2_economy'] <= 1.0
    assert row['psm2_path_length_m'] > 0.05
    assert 'scores:' in capsys.readouterr().out


def test_suture_lfd_assess_names_a_missing_bag(tmp_path, capsys):
    from suture_lfd.cli import main

    assert main(['assess', str(tmp_path / 'nothing')]) == 1
    assert 'suture-lfd assess: error' in capsys.readouterr().err
