"""
Where a lost needle went: a wide image search around its last pose, for a tracker to refine.

A tracker refines a prior only within a few pixels of it (the edge profiles' reach); a needle
that moved farther between two processed pairs -- an arm lifting it a few millimetres while the
loop was busy -- is lost, and a held needle cannot be detected afresh (the jaw's metal joins its
pixels into one blob that is not a wire). :func:`shifted_priors` looks for it where it was: in
each image the arc of the last pose is drawn as a line the wire's width and slid over the thin
needle pixels (the metal mask without the thick parts, which are jaws and wrists) within
``reach`` pixels (:func:`cv2.matchTemplate`, the overlap as score); the arc's middle, moved by the
best shift in both images, is triangulated and the pose translated there. Rotations are left to
the tracker's refinement.

Frames: ``T`` (4, 4) is ``T_camera_needle`` in the camera (left optical) frame, metres; image
shifts in pixels.
"""

import cv2
import numpy as np
from suture_lfd.perception.stereo import StereoModel


def thin_mask(mask: np.ndarray, wire_px: float) -> np.ndarray:
    """
    Return the needle pixels of a mask without its thick parts (jaws, wrists).

    Parameters
    ----------
    mask : ndarray, shape (h, w), uint8
        Metal pixels (255).
    wire_px : float
        The wire's width (pixels) at the needle's depth.

    Returns
    -------
    ndarray, shape (h, w), float32
        1.0 on metal pixels farther than a wire's width from any part thicker than two wires,
        0.0 elsewhere.

    """
    size = 2 * int(np.ceil(wire_px)) + 3
    thick = cv2.morphologyEx(mask, cv2.MORPH_OPEN,
                             cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    near_thick = cv2.dilate(thick, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    return ((mask > 0) & (near_thick == 0)).astype(np.float32)


def image_shift(thin: np.ndarray, uv: np.ndarray, width: int, reach: int) -> np.ndarray | None:
    """
    Return the shift (du, dv) pixels that lays the polyline ``uv`` best on the thin pixels.

    Parameters
    ----------
    thin : ndarray, shape (h, w), float32
        Thin needle pixels (:func:`thin_mask`).
    uv : ndarray, shape (n, 2)
        The arc's projection (pixels).
    width : int
        Line width (pixels) of the drawn arc.
    reach : int
        Largest shift (pixels) along either axis.

    Returns
    -------
    ndarray, shape (2,) or None
        The shift; None when the window holds no thin pixel or leaves the image.

    """
    h, w = thin.shape
    pad = width + 1
    lo = np.floor(uv.min(axis=0)).astype(int) - pad
    hi = np.ceil(uv.max(axis=0)).astype(int) + pad
    template = np.zeros((hi[1] - lo[1] + 1, hi[0] - lo[0] + 1), np.float32)
    cv2.polylines(template, [np.round(uv - lo).astype(np.int32)], False, 1.0, thickness=width)
    x0, y0 = lo[0] - reach, lo[1] - reach
    x1, y1 = hi[0] + reach + 1, hi[1] + reach + 1
    # the part of the search window inside the image, zero-padded back to its full size
    window = np.zeros((y1 - y0, x1 - x0), np.float32)
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx0 >= cx1 or cy0 >= cy1:
        return None
    window[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0] = thin[cy0:cy1, cx0:cx1]
    if not window.any():
        return None
    score = cv2.matchTemplate(window, template, cv2.TM_CCORR)
    _, best, _, (i, j) = cv2.minMaxLoc(score)
    if best <= 0.0:
        return None
    return np.array([i - reach, j - reach], dtype=float)


def shifted_priors(T: np.ndarray, masks: tuple[np.ndarray, np.ndarray], stereo: StereoModel,
                   model: np.ndarray, wire_diameter: float, reach: int) -> list[np.ndarray]:
    """
    Return the last pose translated to where the images show the needle now (0 or 1 pose).

    Parameters
    ----------
    T : ndarray, shape (4, 4)
        The needle's last pose (camera frame).
    masks : tuple of ndarray, shape (h, w), uint8
        Metal pixels of the left and right images.
    stereo : suture_lfd.perception.stereo.StereoModel
    model : ndarray, shape (n, 3)
        Arc points (needle frame, m).
    wire_diameter : float
        The wire's diameter (m).
    reach : int
        Largest image shift (pixels) looked at.

    Returns
    -------
    list of ndarray, shape (4, 4)
        The translated pose, or nothing when an image shows no thin needle pixels near the
        last pose or the shifts do not triangulate.

    """
    points = model @ T[:3, :3].T + T[:3, 3]
    if np.any(points[:, 2] <= 1e-4):
        return []
    wire_px = wire_diameter * stereo.fx / float(points[:, 2].mean())
    width = max(1, int(round(wire_px)))
    middle = points.mean(axis=0)
    shifts, centres = [], []
    for mask, uv, centre in zip(masks, stereo.project(points),
                                stereo.project(middle[None])):
        shift = image_shift(thin_mask(mask, wire_px), uv, width, reach)
        if shift is None:
            return []
        shifts.append(shift)
        centres.append(centre[0] + shift)
    # rectified: one row for both; the shifts' rows differ by the rotation the search ignores
    row = 0.5 * (centres[0][1] + centres[1][1])
    moved = stereo.triangulate([[centres[0][0], row]], [[centres[1][0], row]])[0]
    if not np.all(np.isfinite(moved)) or moved[2] <= 0.0:
        return []
    out = T.copy()
    out[:3, 3] = T[:3, 3] + (moved - middle)
    return [out]
