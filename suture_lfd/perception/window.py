"""
A region of interest around what perception expects to see: a window, not a frame.

Tracking a needle whose pose is roughly known, or an instrument where its kinematics put it,
needs the few hundred pixels around it, not the whole 640x480 pair: rendering (or reading out,
on a camera with a region of interest) and processing a window costs a fraction of the frame.
:func:`points_window` gives the window ``(u0, v0, width, height)`` around points expected in
the camera, the same in both images of the rectified pair (it spans the points' disparity), so
that :func:`window_stereo` is a rectified pair again: the same camera with its principal point
moved by the window's corner, as a camera's region of interest reports it in ``camera_info``.
Without a prior (a search), the whole frame.

Pixels ``(u, v)``: ``(0, 0)`` the centre of the top-left pixel; the camera frame is the left
optical frame of :mod:`suture_lfd.perception.stereo` (metres).
"""

from dataclasses import replace
import math

import numpy as np
from numpy.typing import ArrayLike
from suture_lfd.perception.stereo import StereoModel

Window = tuple[int, int, int, int]

#: A window larger than this share of the frame is not worth it: the whole frame is taken.
MAX_SHARE = 0.6


def points_window(stereo: StereoModel, points: ArrayLike, margin: float,
                  max_share: float = MAX_SHARE) -> Window | None:
    """
    Return the window around camera-frame points in both images, or None for the whole frame.

    Parameters
    ----------
    stereo : StereoModel
        The full frame's camera.
    points : array_like, shape (n, 3)
        Points (m, camera frame) expected in view.
    margin : float
        Distance (m) the points may be off from where they are expected, at their median
        depth: the window is widened by it (and by 4 pixels of blur and the wire's edges).
    max_share : float
        Largest share of the frame a window may cover.

    Returns
    -------
    tuple of int or None
        ``(u0, v0, width, height)`` inside the image; None when a point is not in front of the
        camera, none is inside the image or the window would cover more than ``max_share``.

    """
    p = np.atleast_2d(np.asarray(points, dtype=float))
    if not len(p) or not np.all(np.isfinite(p)) or p[:, 2].min() <= 1e-6:
        return None
    uv_l, uv_r = stereo.project(p)
    uv = np.vstack([uv_l, uv_r])
    pad = stereo.fx * margin / float(np.median(p[:, 2])) + 4.0
    u_lo = max(0, math.floor(uv[:, 0].min() - pad))
    v_lo = max(0, math.floor(uv[:, 1].min() - pad))
    u_hi = min(stereo.width, math.ceil(uv[:, 0].max() + pad) + 1)
    v_hi = min(stereo.height, math.ceil(uv[:, 1].max() + pad) + 1)
    w, h = u_hi - u_lo, v_hi - v_lo
    if w < 2 or h < 2 or w * h > max_share * stereo.width * stereo.height:
        return None
    return int(u_lo), int(v_lo), int(w), int(h)


def window_stereo(stereo: StereoModel, window: Window) -> StereoModel:
    """
    Return the camera of a window of both images: the principal point moved by its corner.

    Parameters
    ----------
    stereo : StereoModel
        The full frame's camera.
    window : tuple of int
        ``(u0, v0, width, height)``, the same in both images.

    Returns
    -------
    StereoModel
        Its ``K`` and ``P`` with ``cx - u0``, ``cy - v0``; the window's size.

    """
    u0, v0, w, h = (int(x) for x in window)
    K, P_left, P_right = stereo.K.copy(), stereo.P_left.copy(), stereo.P_right.copy()
    for M in (K, P_left, P_right):
        M[0, 2] -= u0
        M[1, 2] -= v0
    return replace(stereo, width=w, height=h, K=K, P_left=P_left, P_right=P_right)


def crop(image: np.ndarray, window: Window) -> np.ndarray:
    """Return the window ``(u0, v0, width, height)`` of a full image (a contiguous copy)."""
    u0, v0, w, h = window
    return np.ascontiguousarray(image[v0:v0 + h, u0:u0 + w])


def in_frame(image: np.ndarray, window: Window, stereo: StereoModel) -> np.ndarray:
    """
    Return a window's image placed in a black frame of the full image's size.

    What lies outside the window is unseen: black is neither needle, thread nor marker.
    """
    u0, v0, w, h = window
    out = np.zeros((stereo.height, stereo.width, *image.shape[2:]), dtype=image.dtype)
    out[v0:v0 + h, u0:u0 + w] = image
    return out
