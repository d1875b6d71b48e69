"""
Poses of the needle's arc: small rotations, the arc's two symmetries, and a rigid fit.

Frames: 4x4 transforms ``T_camera_needle``; the needle frame is
:mod:`sim_bridge.common.needle`'s (arc centre at the origin, arc in the x-y plane).
"""

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry


def rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad), Rodrigues' formula in scalars."""
    theta = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(theta) * K + (1.0 - math.cos(theta)) * (K @ K)


def flip_transform(geometry: 'NeedleGeometry') -> np.ndarray:
    """``T`` (4, 4) turning the arc half a turn about its middle radius (tail <-> tip)."""
    phi = geometry.angle_at(0.5)
    axis = np.array([math.cos(phi), math.sin(phi), 0.0])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(math.pi * axis).as_matrix()
    return T


def mirrored(T: np.ndarray) -> np.ndarray:
    """
    Return the pose whose arc projects almost alike: the plane reflected about the line of sight.

    A circle and its reflection in the plane through the line of sight to its centre and its
    own normal cast the same outline under weak perspective; the arc is kept where it is
    (its middle point stays on its ray).
    """
    centre = T[:3, 3]
    ray = centre / np.linalg.norm(centre)
    normal = T[:3, 2]
    mirrored = 2.0 * (normal @ ray) * ray - normal  # normal turned half a turn about the ray
    R = Rotation.align_vectors([mirrored], [normal])[0].as_matrix()
    M = np.eye(4)
    M[:3, :3] = R @ T[:3, :3]
    M[:3, 3] = centre
    return M


def kabsch(model: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Rigid ``T`` (4, 4) taking model points (n, 3) onto data points (n, 3)."""
    mc, dc = model.mean(axis=0), data.mean(axis=0)
    H = (model - mc).T @ (data - dc)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = dc - R @ mc
    return T
