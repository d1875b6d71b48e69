"""
What an image says about a thin wire: its pixels, their edges across a line, and what covers it.

The needle's pixels come from :func:`suture_lfd.perception.images.metal_mask`, closed across
gaps of up to 3 pixels: a wire that touches the tissue is drawn with the tissue's pixels along
its middle where it sinks in by a few hundredths of a millimetre (the needle at rest after the
study's 10 ms physics steps), and would be seen as two thin lines instead of one wire.
:func:`runs` finds, on profiles sampled across the projected arc, the run of wire pixels
through the middle and its two edges to a sub-pixel (0.5 crossings of the bilinear samples);
:func:`hidden_in_images` says which arc points an instrument covers in each image (its jaws,
wrist and shaft as capsules, :func:`tool_capsules`). Pixels: ``(u, v)``, ``(0, 0)`` the centre
of the top-left pixel.
"""

from collections.abc import Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import ArrayLike
from suture_lfd.perception.images import metal_mask, thread_mask

if TYPE_CHECKING:
    from suture_lfd.perception.stereo import StereoModel

Capsule = tuple[np.ndarray, np.ndarray, float]  # start (3,), end (3,) m, radius m

#: The closing of the needle's pixels: fills a gap of up to 3 pixels inside the wire (the
#: renderer's cracks, the tissue drawn along the middle of a wire resting on it: 2-3 px wide at
#: 80 mm, the wire itself 7-8 px), too small to join two wires a wire's width apart.
_CLOSE = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
_RIDGE = np.ones((3, 3), np.uint8)


class WireImage:
    """One image's needle pixels, and (on demand) the fields the detection needs."""

    def __init__(self, rgb: np.ndarray, blur: float) -> None:
        self.rgb = rgb
        self._blur = blur
        # a closing fills the cracks along the thin wire and the tissue seen along its middle
        self.mask = cv2.morphologyEx(metal_mask(rgb), cv2.MORPH_CLOSE, _CLOSE)
        self.soft = (self.mask > 0).astype(np.float32)
        self._cost: np.ndarray | None = None
        self._d_out: np.ndarray | None = None
        self._thread: np.ndarray | None = None
        self._thread_soft: np.ndarray | None = None

    @property
    def d_out(self) -> np.ndarray:
        """Distance (pixels) to the nearest needle pixel (0 on them)."""
        if self._d_out is None:
            self._d_out = cv2.distanceTransform(cv2.bitwise_not(self.mask), cv2.DIST_L2, 5)
        return self._d_out

    @property
    def cost(self) -> np.ndarray:
        """Distance (pixels, blurred) to the centre line of the needle pixels."""
        if self._cost is None:
            d_in = cv2.distanceTransform(self.mask, cv2.DIST_L2, 5)
            # centre line: needle pixels farthest from the background among their neighbours
            ridge = (self.mask > 0) & (d_in >= cv2.dilate(d_in, _RIDGE))
            centre = cv2.distanceTransform(np.where(ridge, 0, 255).astype(np.uint8),
                                           cv2.DIST_L2, 5)
            self._cost = (cv2.GaussianBlur(centre, (0, 0), self._blur) if self._blur > 0.0
                          else centre)
        return self._cost

    @property
    def thread_soft(self) -> np.ndarray:
        """Thread pixels as 0.0 / 1.0 (float32)."""
        if self._thread_soft is None:
            self._thread_soft = (self.thread > 0).astype(np.float32)
        return self._thread_soft

    @property
    def thread(self) -> np.ndarray:
        """Thread pixels (uint8, 255)."""
        if self._thread is None:
            self._thread = thread_mask(self.rgb)
        return self._thread


def sample(image: np.ndarray, uv: np.ndarray, outside: float = np.nan) -> np.ndarray:
    """Bilinear samples of a float image at pixels ``uv`` (n, 2); ``outside`` (NaN) outside."""
    h, w = image.shape
    u, v = uv[:, 0], uv[:, 1]
    inside = (u >= 0.0) & (v >= 0.0) & (u <= w - 1.001) & (v <= h - 1.001)
    u = np.where(inside, u, 0.0)
    v = np.where(inside, v, 0.0)
    u0 = u.astype(np.intp)
    v0 = v.astype(np.intp)
    a, b = u - u0, v - v0
    a1, b1 = 1 - a, 1 - b
    # the four neighbours gathered by flat index (the same values as image[v, u], cheaper)
    flat = image.reshape(-1)
    k = v0 * w + u0
    f = (flat.take(k) * a1 * b1 + flat.take(k + 1) * a * b1
         + flat.take(k + w) * a1 * b + flat.take(k + w + 1) * a * b)
    return np.where(inside, f, outside)


def runs(profile: np.ndarray, steps: np.ndarray, step: float,
         closed: bool | np.ndarray = True) -> tuple[np.ndarray, np.ndarray]:
    """
    Edges (sub-pixel) of the run of needle samples through or nearest each profile's middle.

    Parameters
    ----------
    profile : ndarray, shape (n, m)
        Mask values (0-1) sampled across the arc at offsets ``steps`` (m,).
    steps : ndarray, shape (m,)
    step : float
        Spacing of ``steps``.
    closed : bool or ndarray, shape (n,)
        Whether a run must end inside the profile on both sides (per profile, or for all).

    Returns
    -------
    edges : ndarray, shape (2, n)
        Offsets of the run's two 0.5 crossings.
    valid : ndarray, shape (n,)
        A run that ends inside the profile on both sides (``closed``), or on the far side.

    """
    n, m = profile.shape
    inside = profile >= 0.5
    idx = np.arange(m)
    middle = m // 2
    dist = np.where(inside, np.abs(idx - middle), m + 1)
    j = np.argmin(dist, axis=1)
    any_inside = dist[np.arange(n), j] <= m
    outside = ~inside
    lo_out = np.where(outside & (idx[None, :] < j[:, None]), idx[None, :], -1).max(axis=1)
    hi_out = np.where(outside & (idx[None, :] > j[:, None]), idx[None, :], m).min(axis=1)
    valid = any_inside & (hi_out <= m - 1)
    if np.ndim(closed) or closed:
        valid &= (lo_out >= 0) | ~np.asarray(closed, dtype=bool)
    # np.minimum and np.maximum rather than np.clip: the same values, less overhead on this
    # hot path
    lo_out = np.minimum(np.maximum(lo_out, 0), m - 2)
    hi_out = np.minimum(np.maximum(hi_out, 1), m - 1)
    rows = np.arange(n)
    p0, p1 = profile[rows, lo_out], profile[rows, lo_out + 1]
    q0, q1 = profile[rows, hi_out - 1], profile[rows, hi_out]
    with np.errstate(divide='ignore', invalid='ignore'):
        a = steps[lo_out] + np.minimum(np.maximum((0.5 - p0) / (p1 - p0), 0.0), 1.0) * step
        b = steps[hi_out - 1] + np.minimum(np.maximum((q0 - 0.5) / (q0 - q1), 0.0), 1.0) * step
    return np.array([a, b]), valid


def tool_capsules(T_camera_tool: ArrayLike, jaw_length: float, jaw_radius: float,
                  shaft_length: float, shaft_radius: float) -> list[Capsule]:
    """
    Return an instrument's jaws and its wrist and shaft as capsules (camera frame).

    Parameters
    ----------
    T_camera_tool : array_like, shape (4, 4)
        Tool-tip pose (``measured_cp`` carried into the camera frame).
    jaw_length, jaw_radius, shaft_length, shaft_radius : float
        Sizes (m) of the jaws and of the wrist and shaft capsules.

    Returns
    -------
    list of tuple
        ``(start (3,), end (3,), radius)`` (m): the jaws from the hinge along tool ``z``, the
        wrist and shaft back along ``-z``.

    """
    T = np.asarray(T_camera_tool, dtype=float)
    hinge, z = T[:3, 3], T[:3, 2]
    return [(hinge, hinge + jaw_length * z, jaw_radius),
            (hinge, hinge - shaft_length * z, shaft_radius)]


def hidden_in_images(points: np.ndarray, capsules: Sequence[Capsule],
                     stereo: 'StereoModel') -> np.ndarray:
    """
    Return the arc points (n, 3) whose pixel falls on an instrument's, per image (2, n) bool.

    An arc point is taken as hidden where its pixel lies within a capsule's projected outline
    and the capsule is nearer the camera there.
    """
    hidden = np.zeros((2, len(points)), bool)
    if not capsules:
        return hidden
    uv = stereo.project(points)
    for a, b, radius in capsules:
        if a[2] <= 1e-3 or b[2] <= 1e-3:
            continue
        ends = stereo.project(np.array([a, b]))
        for side in (0, 1):
            p0, p1 = ends[side]
            d = p1 - p0
            t = np.clip((uv[side] - p0) @ d / max(d @ d, 1e-12), 0.0, 1.0)
            # the depth along the axis, interpolated in the image: close enough for this
            depth = a[2] + t * (b[2] - a[2])
            near = (np.linalg.norm(uv[side] - (p0 + t[:, None] * d), axis=1)
                    < radius * stereo.fx / depth)
            hidden[side] |= near & (depth - radius < points[:, 2])
    return hidden
