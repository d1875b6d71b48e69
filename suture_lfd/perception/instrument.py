"""
A PSM instrument in one image: its shaft's axis and its distal end, near where it is expected.

What a camera-to-arm registration measures of a tool held straight (wrist joints at zero, jaw
closed): the instrument is then a dark shaft (a cylinder, whose silhouette's centre line is its
projected axis) ending in a bright wrist and jaws along the same axis. In one image,

1. the shaft is the largest dark, unsaturated region inside a corridor around where the arm's
   kinematics put it; a line fitted (:func:`cv2.fitLine`, Huber) to the midpoints of its
   chords across the expected axis (those at full width, not cut by the image's border) is
   its axis;
2. the distal end is the far end of the run of instrument pixels (dark or metal) along that
   axis, within a narrow band around it: the jaw tips.

The caller compares these with the projection of its own model of the instrument
(:mod:`suture_lfd.skill.arm_registration`). Pixels: ``(u, v)``, ``(0, 0)`` the centre of the
top-left pixel.
"""

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike
from suture_lfd.perception.images import metal_mask

# Shaft pixels: dark (brightest channel below this) and grey (spread at most this share of it,
# plus a grey level of noise).
_DARK_MAX = 70
_DARK_SPREAD = 0.25
# Half-width (pixels) of the band around the axis in which the distal end is looked for, and
# the largest gap (pixels) along the axis inside the instrument's run of pixels.
_BAND = 7.0
_GAP = 4.0
# Chords across the shaft: half-length and spacing (pixels).
_CHORD = 250.0
_CHORD_STEP = 4.0


@dataclass(frozen=True, eq=False)
class InstrumentView:
    """
    A straight instrument in one image.

    Attributes
    ----------
    point : ndarray, shape (2,)
        A point of the shaft's projected axis (pixels).
    direction : ndarray, shape (2,)
        Unit direction of the axis, towards the distal end.
    end : ndarray, shape (2,)
        The distal end (the jaw tips) on the axis (pixels).
    shaft_pixels : int
        Pixels of the shaft region the axis was fitted to.

    """

    point: np.ndarray
    direction: np.ndarray
    end: np.ndarray
    shaft_pixels: int

    def distance(self, uv: ArrayLike) -> np.ndarray:
        """Signed distances (pixels) of points ``uv`` (n, 2) from the axis."""
        d = np.asarray(uv, dtype=float) - self.point
        return d[:, 0] * self.direction[1] - d[:, 1] * self.direction[0]

    def along(self, uv: ArrayLike) -> np.ndarray:
        """Positions (pixels) of points ``uv`` (n, 2) along the axis, from the distal end."""
        return (np.asarray(uv, dtype=float) - self.end) @ self.direction


def dark_mask(rgb: np.ndarray) -> np.ndarray:
    """
    Shaft-coloured pixels: dark and grey.

    Parameters
    ----------
    rgb : ndarray, shape (h, w, 3), uint8

    Returns
    -------
    ndarray, shape (h, w), uint8
        255 on dark grey pixels.

    """
    r, g, b = cv2.split(rgb)
    hi = cv2.max(cv2.max(r, g), b)
    spread = cv2.subtract(hi, cv2.min(cv2.min(r, g), b))
    dark = cv2.compare(hi, _DARK_MAX, cv2.CMP_LT)  # type: ignore[call-overload]
    limit = cv2.add(cv2.multiply(hi, _DARK_SPREAD), 2)  # type: ignore[call-overload]
    grey = cv2.compare(spread, limit, cv2.CMP_LE)
    return cv2.bitwise_and(dark, grey)


def _chord_midpoints(region: np.ndarray, end_uv: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """
    Midpoints of the shaft region's chords across the expected axis, every few pixels along it.

    A chord that reaches the image's border is cut by it, and one narrower than most crosses
    the shaft's rounded end: both are left out. The midpoints of parallel chords of a straight
    band lie on its centre line whatever the chords' slant.
    """
    h, w = region.shape
    normal = np.array([axis[1], -axis[0]])
    s = np.arange(-_CHORD, _CHORD + 0.5, 1.0)
    out: list[np.ndarray] = []
    widths: Any = []  # a list, then its array
    for t in np.arange(0.0, 2.0 * (w + h), _CHORD_STEP):
        line = end_uv - t * axis + s[:, None] * normal
        u = np.rint(line[:, 0]).astype(int)
        v = np.rint(line[:, 1]).astype(int)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        if not inside.any():
            if t > 0.0 and out:
                break
            continue
        on = np.zeros(len(s), bool)
        on[inside] = region[v[inside], u[inside]]
        idx = np.nonzero(on)[0]
        if idx.size < 3 or idx[0] == 0 or idx[-1] == len(s) - 1:
            continue
        first, last = idx[0], idx[-1]
        if not (inside[first - 1] and inside[last + 1]) or last - first + 1 != idx.size:
            continue  # cut by the border, or not one run
        out.append(end_uv - t * axis + 0.5 * (s[first] + s[last]) * normal)
        widths.append(s[last] - s[first])
    if not out:
        return np.zeros((0, 2))
    widths = np.asarray(widths)
    keep = widths >= 0.9 * np.median(widths)
    return np.asarray(out)[keep]


def find_instrument(rgb: np.ndarray, shaft_uv: ArrayLike, end_uv: ArrayLike,
                    corridor: float = 150.0, min_pixels: int = 300) -> 'InstrumentView | None':
    """
    Find a straight instrument near its expected projection in one image.

    Parameters
    ----------
    rgb : ndarray, shape (h, w, 3), uint8
        The image.
    shaft_uv : array_like, shape (2, 2)
        Two expected points of the shaft's axis (pixels), the first nearer the distal end.
    end_uv : array_like, shape (2,)
        Expected distal end (pixels).
    corridor : float
        Half-width (pixels) of the corridor around the expected axis searched for the shaft.
    min_pixels : int
        Fewest shaft pixels for a measurement.

    Returns
    -------
    InstrumentView or None
        None when no shaft or no distal end is seen.

    """
    h, w = rgb.shape[:2]
    shaft_uv = np.asarray(shaft_uv, dtype=float)
    end_uv = np.asarray(end_uv, dtype=float)
    axis = end_uv - shaft_uv[1]
    norm = float(np.linalg.norm(axis))
    if not np.isfinite(norm) or norm < 1e-6:
        return None
    axis /= norm
    # the corridor: the expected axis from the distal end back to the image's border
    far = end_uv - 2.0 * (w + h) * axis
    lane = np.zeros((h, w), np.uint8)
    cv2.line(lane, tuple(int(round(x)) for x in end_uv), tuple(int(round(x)) for x in far),
             255, thickness=int(2 * corridor))
    dark = dark_mask(rgb)
    n, labels = cv2.connectedComponents(dark, connectivity=8)
    if n < 2:
        return None
    # the dark region most of whose pixels lie in the corridor, whole (chords cut by the
    # corridor's edge would move their midpoints)
    inside = np.bincount(labels[lane > 0], minlength=n)
    inside[0] = 0
    k = int(np.argmax(inside))
    count = int(inside[k])
    if count < min_pixels:
        return None
    region = labels == k
    vs, us = np.nonzero(region)
    pts = np.column_stack([us, vs]).astype(np.float32)
    mids = _chord_midpoints(region, end_uv, axis)
    if len(mids) < 5:
        return None
    vx, vy, x0, y0 = cv2.fitLine(mids.astype(np.float32), cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
    direction = np.array([vx, vy], dtype=float)
    if direction @ axis < 0.0:
        direction = -direction
    point = np.array([x0, y0], dtype=float)
    # the instrument's pixels in a band around the axis, walked from the shaft to the tip
    instrument = cv2.bitwise_or(dark_mask(rgb), metal_mask(rgb))
    vs, us = np.nonzero(instrument)
    uv = np.column_stack([us, vs]).astype(float)
    d = uv - point
    across = d[:, 0] * direction[1] - d[:, 1] * direction[0]
    along = d @ direction
    shaft_along = (pts - point) @ direction
    start = float(np.percentile(shaft_along, 95.0))
    keep = (np.abs(across) <= _BAND) & (along >= start - 2.0 * _BAND)
    s = np.sort(along[keep])
    if s.size == 0:
        return None
    s = s[s >= start]
    if s.size == 0:
        return None
    gaps = np.nonzero(np.diff(s) > _GAP)[0]
    last = float(s[gaps[0]] if gaps.size else s[-1])
    return InstrumentView(point=point, direction=direction, end=point + last * direction,
                          shaft_pixels=count)
