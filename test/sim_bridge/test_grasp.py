"""Needle grasping: attach on closing around the wire, release on opening, handover."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sim_bridge.common.geometry import invert_transform
from sim_bridge.common.needle import NeedleGeometry
from sim_bridge.scene.grasp import GraspConfig, GraspManager

NEEDLE = NeedleGeometry()
CONFIG = GraspConfig()
OPEN, CLOSED = 1.047, -0.349  # what a dVRK client sends: open 60 deg, close -20 deg


def _random_pose(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    T[:3, 3] = rng.uniform(-0.05, 0.05, 3)
    return T


def _translate(T, offset_tool):
    out = T.copy()
    out[:3, 3] += T[:3, :3] @ np.asarray(offset_tool, dtype=float)
    return out


class Scene:
    """Two tools and a needle, all poses in the world."""

    def __init__(self, rng):
        self.needle = _random_pose(rng)
        self.tools = {'PSM1': _random_pose(rng), 'PSM2': _random_pose(rng)}
        self.jaws = {'PSM1': OPEN, 'PSM2': OPEN}
        self.grasp = GraspManager(CONFIG, NEEDLE, ('PSM1', 'PSM2'))
        self.update()

    def place_on_needle(self, arm, s=None, roll=0.0):
        self.tools[arm] = self.needle @ invert_transform(NEEDLE.grasp_transform(s, roll))

    def update(self):
        events = self.grasp.update(self.jaws, self.tools.__getitem__, self.needle)
        if self.grasp.leader is not None:
            self.needle = self.grasp.needle_pose(self.tools[self.grasp.leader])
        return events


def test_the_canonical_grasp_puts_the_wire_in_the_jaw_region():
    for s in np.linspace(0.0, 1.0, 7):
        T_world_tool = invert_transform(NEEDLE.grasp_transform(s))
        assert GraspManager(CONFIG, NEEDLE, ['PSM1']).wire_distance(T_world_tool,
                                                                    np.eye(4)) < 1e-4


def test_closing_on_the_needle_attaches_it_at_the_current_relative_pose():
    rng = np.random.default_rng(1)
    for _ in range(50):
        scene = Scene(rng)
        s, roll = rng.uniform(0.1, 0.9), rng.uniform(-np.pi, np.pi)
        scene.place_on_needle('PSM2', s, roll)
        # a grasp a little off the canonical one still holds the needle where it is
        scene.tools['PSM2'] = _translate(scene.tools['PSM2'], rng.uniform(-0.001, 0.001, 3))
        relative = invert_transform(scene.tools['PSM2']) @ scene.needle
        scene.jaws['PSM2'] = CLOSED
        events = scene.update()
        assert [(e.kind, e.arm) for e in events] == [('grasp', 'PSM2')]
        assert scene.grasp.holders == ('PSM2',)
        assert np.allclose(scene.grasp.relative_pose('PSM2'), relative)
        # the needle now follows the tool rigidly
        scene.tools['PSM2'] = _random_pose(rng)
        scene.update()
        assert np.allclose(invert_transform(scene.tools['PSM2']) @ scene.needle, relative)


def test_release_needs_the_jaw_opened_past_the_release_angle():
    rng = np.random.default_rng(2)
    scene = Scene(rng)
    scene.place_on_needle('PSM1')
    scene.jaws['PSM1'] = CLOSED
    assert scene.update()[0].kind == 'grasp'
    # opening into the hysteresis band (between close and release angles) keeps the needle
    for angle in (0.0, CONFIG.close_angle + 0.01, 0.5 * (CONFIG.close_angle
                                                          + CONFIG.release_angle),
                  CONFIG.release_angle - 1e-3, CONFIG.close_angle - 0.01):
        scene.jaws['PSM1'] = angle
        assert scene.update() == []
        assert scene.grasp.holders == ('PSM1',)
    scene.jaws['PSM1'] = CONFIG.release_angle
    events = scene.update()
    assert [(e.kind, e.arm, e.leader) for e in events] == [('release', 'PSM1', None)]
    assert scene.grasp.holders == ()
    # partly closing again (not past close_angle) grasps nothing
    scene.jaws['PSM1'] = CONFIG.close_angle + 0.01
    assert scene.update() == []
    assert scene.grasp.holders == ()


def test_closing_five_millimetres_from_the_needle_grasps_nothing():
    rng = np.random.default_rng(3)
    # away from the wire (which runs along tool x in a grasp): sideways, forwards, backwards
    directions = [(0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (0, 0.6, 0.8), (0, -0.6, 0.8)]
    for d in directions:
        scene = Scene(rng)
        scene.place_on_needle('PSM1', s=rng.uniform(0.2, 0.8))
        scene.tools['PSM1'] = _translate(scene.tools['PSM1'], 0.005 * np.array(d, float))
        scene.jaws['PSM1'] = CLOSED
        assert scene.update() == [], d
        assert scene.grasp.holders == ()


def test_a_closed_jaw_moved_onto_the_needle_grasps_nothing():
    rng = np.random.default_rng(4)
    scene = Scene(rng)
    scene.jaws['PSM2'] = CLOSED
    scene.update()
    scene.place_on_needle('PSM2')
    assert scene.update() == []
    assert scene.grasp.holders == ()
    # it must open and close again to grasp
    scene.jaws['PSM2'] = OPEN
    scene.update()
    scene.jaws['PSM2'] = CLOSED
    assert [e.kind for e in scene.update()] == ['grasp']


def test_handover_keeps_the_needle_pose_continuous():
    rng = np.random.default_rng(5)
    for _ in range(20):
        scene = Scene(rng)
        scene.place_on_needle('PSM2', s=0.3)
        scene.jaws['PSM2'] = CLOSED
        scene.update()
        # PSM2 carries the needle somewhere, PSM1 grasps it near the tip
        for _ in range(5):
            scene.tools['PSM2'] = _translate(scene.tools['PSM2'], rng.uniform(-0.002, 0.002, 3))
            scene.update()
        scene.place_on_needle('PSM1', s=0.8, roll=np.pi)
        scene.jaws['PSM1'] = CLOSED
        events = scene.update()
        assert [(e.kind, e.arm, e.leader) for e in events] == [('grasp', 'PSM1', 'PSM2')]
        assert scene.grasp.holders == ('PSM2', 'PSM1')
        # both hold; the first grasper leads, even if the second drifts a little
        scene.tools['PSM1'] = _translate(scene.tools['PSM1'], [0.0003, 0.0, 0.0])
        before = scene.needle.copy()
        scene.update()
        assert np.allclose(scene.needle, before)
        scene.jaws['PSM2'] = OPEN
        events = scene.update()
        assert [(e.kind, e.arm, e.leader) for e in events] == [('release', 'PSM2', 'PSM1')]
        assert np.allclose(scene.needle, before, atol=1e-12)
        # PSM1 now carries it from where it was
        scene.tools['PSM1'] = _translate(scene.tools['PSM1'], [0.0, 0.01, 0.0])
        scene.update()
        assert np.allclose(scene.needle[:3, :3], before[:3, :3])
        moved = scene.needle[:3, 3] - before[:3, 3]
        assert np.linalg.norm(moved) == pytest.approx(0.01)


def test_thresholds_must_leave_a_hysteresis_band():
    with pytest.raises(ValueError, match='release_angle'):
        GraspConfig(close_angle=0.2, release_angle=0.1)
