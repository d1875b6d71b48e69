"""
The needle's centre line triangulated row by row, and the arc fitted to those points in 3-D.

A needle lying nearly face on to the camera casts almost the same pair of images when it is
tilted a few degrees across the line of sight: a fit of the projected arc to the images finds
two poses 1-2 mm apart that fit alike, and often neither is right. The depth of the wire,
read directly where it crosses the image rows steeply, does not share that ambiguity:
:func:`centre_line_points` takes, on each row where both images cross the wire the same number
of times, each crossing's middle (a narrow run: the wire steep in the image), and triangulates
the left and right middles (rectified: the same row); :func:`fit_arc_to_points` then moves the
arc until those points lie on it (:func:`scipy.optimize.least_squares`, soft-L1 loss, distance to
the nearest of a dense set of arc points). Each point's depth is coarse (half a pixel of
disparity is about a millimetre at 80 mm), but some sixty of them fix the arc's plane.

Frames: the camera (left optical) frame, metres; ``T`` is ``T_camera_needle``.
"""

import numpy as np
from scipy.optimize import least_squares
from sim_bridge.common.needle import NeedleGeometry
from suture_lfd.perception.arc_poses import rotvec_matrix
from suture_lfd.perception.stereo import StereoModel


def _runs(row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last column of each run of nonzero values in a row."""
    padded = np.concatenate([[0], (row > 0).astype(np.int8), [0]])
    step = np.diff(padded)
    return np.nonzero(step == 1)[0], np.nonzero(step == -1)[0] - 1


def centre_line_points(mask_left: np.ndarray, mask_right: np.ndarray, stereo: StereoModel,
                       max_run: int) -> np.ndarray:
    """
    Triangulate the middles of the wire's steep crossings of the image rows.

    Parameters
    ----------
    mask_left, mask_right : ndarray, shape (h, w), uint8
        Needle pixels of the rectified pair.
    stereo : suture_lfd.perception.stereo.StereoModel
    max_run : int
        Longest run (pixels) along a row that counts as a steep crossing.

    Returns
    -------
    ndarray, shape (n, 3)
        Camera-frame points (m) on the wire's centre line.

    """
    rows = np.nonzero(mask_left.any(axis=1) & mask_right.any(axis=1))[0]
    left, right = [], []
    for v in rows:
        a, b = _runs(mask_left[v])
        c, d = _runs(mask_right[v])
        if len(a) != len(c):
            continue  # a crossing seen in one image only: no match
        steep = (b - a < max_run) & (d - c < max_run)
        for i in np.nonzero(steep)[0]:
            left.append((0.5 * (a[i] + b[i]), v))
            right.append((0.5 * (c[i] + d[i]), v))
    if not left:
        return np.zeros((0, 3))
    points = stereo.triangulate(np.array(left, float), np.array(right, float))
    return points[np.all(np.isfinite(points), axis=1) & (points[:, 2] > 0.0)]


def arc_distances(T: np.ndarray, points: np.ndarray, geometry: NeedleGeometry) -> np.ndarray:
    """
    Return each point's distance (m) from the needle's arc at pose ``T``.

    Parameters
    ----------
    T : ndarray, shape (4, 4)
        ``T_camera_needle``.
    points : ndarray, shape (n, 3)
        Camera-frame points (m).
    geometry : sim_bridge.common.needle.NeedleGeometry

    Returns
    -------
    ndarray, shape (n,)

    """
    return geometry.distance_to_arc((points - T[:3, 3]) @ T[:3, :3])


def fit_arc_to_points(T0: np.ndarray, points: np.ndarray, geometry: NeedleGeometry,
                      scale: float = 0.5e-3) -> np.ndarray:
    """
    Move the arc from ``T0`` until the points lie on it.

    Parameters
    ----------
    T0 : ndarray, shape (4, 4)
        Start ``T_camera_needle``.
    points : ndarray, shape (n, 3)
        Camera-frame points on the wire (:func:`centre_line_points`), m.
    geometry : sim_bridge.common.needle.NeedleGeometry
        The needle's arc.
    scale : float
        Distance (m) beyond which a point pulls less (soft-L1).

    Returns
    -------
    ndarray, shape (4, 4)
        The fitted pose (``T0`` when there are fewer than 6 points).

    """
    if len(points) < 6:
        return T0

    def pose(x: np.ndarray) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = rotvec_matrix(x[:3]) @ T0[:3, :3]
        T[:3, 3] = T0[:3, 3] + 1e-3 * x[3:]
        return T

    def residuals(x: np.ndarray) -> np.ndarray:
        return arc_distances(pose(x), points, geometry) / scale

    result = least_squares(residuals, np.zeros(6), loss='soft_l1', diff_step=1e-3,
                           max_nfev=300, x_scale=1.0)
    return pose(result.x)
