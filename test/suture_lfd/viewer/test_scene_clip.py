"""
Line markers cut at the endoscope's near plane: what is in front stays, what is behind goes;
the transform tree's version moves only when a transform changes (a scene at rest is not drawn
again).
"""

import numpy as np
from suture_lfd.viewer.scene import TransformTree, clip_segments, rotation_with_z


def test_segments_are_cut_at_the_plane_and_dropped_behind_it():
    rng = np.random.default_rng(5)
    point, normal = np.array([0.0, -0.05, 0.07]), np.array([0.0, 0.6, -0.8])
    segments = rng.normal(scale=0.1, size=(200, 2, 3))
    clipped = clip_segments(segments, (point, normal))
    d = (segments - point) @ normal
    assert len(clipped) == int((d > 0).any(axis=1).sum())
    assert ((clipped - point) @ normal >= -1e-12).all()          # nothing behind the plane
    front = (d > 0).all(axis=1)
    np.testing.assert_array_equal(clipped[front[(d > 0).any(axis=1)]], segments[front])
    for seg, cut in zip(segments[(d > 0).any(axis=1)], clipped):  # cut along the segment
        direction = seg[1] - seg[0]
        for p in cut:
            residual = np.cross(p - seg[0], direction)
            assert np.linalg.norm(residual) < 1e-9 * max(1.0, np.linalg.norm(direction))
    assert clip_segments(segments, None) is not None and len(clip_segments(segments, None)) == 200


def test_a_rotation_with_a_given_z_axis_is_a_rotation():
    rng = np.random.default_rng(6)
    for _ in range(50):
        z = rng.normal(size=3)
        z /= np.linalg.norm(z)
        R = rotation_with_z(z)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R[:, 2], z, atol=1e-12)
        assert np.linalg.det(R) > 0


def test_the_transform_tree_moves_its_version_only_when_a_transform_changes():
    tree = TransformTree()
    T = np.eye(4)
    T[:3, 3] = (0.01, 0.02, 0.03)
    tree.set('world', 'PSM1_base', T)
    version = tree.version
    tree.set('world', 'PSM1_base', T.copy())         # a scene at rest: the same transform
    assert tree.version == version
    T[0, 3] += 1e-9
    tree.set('world', 'PSM1_base', T.copy())
    assert tree.version == version + 1
    tree.set('ECM', 'PSM1_base', T.copy())           # the same pose from another parent
    assert tree.version == version + 2
