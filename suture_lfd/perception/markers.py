"""
Entry/exit markers from a stereo pair: red dots found, matched, triangulated and paired.

Each image's red pixels form blobs (:func:`suture_lfd.perception.images.red_mask`, OpenCV's
connected components); a blob's centroid is the projection of its dot's centre. The blobs of the
two images are matched along the rows of the rectified pair (same ``v``, a positive disparity
close to the others'), triangulated in the camera frame (:mod:`suture_lfd.perception.stereo`) and
lowered by the dots' height above the surface along the normal of the plane through them.

Pairs come from the layout alone, never from the scene's configuration: the dots lie in two rows
along the wound (the rows' direction is the principal axis of the dots), one dot of each row per
pair; pairs are numbered along the wound in the direction of the camera's ``+x`` (left to right
in the image), and the entry row is the one farther from the camera (``entry_row='far'``), as the
surgeon sees a wound across the view with its entry side away from them.
"""

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment
from suture_lfd.perception.images import check_image, red_mask
from suture_lfd.perception.stereo import StereoModel


@dataclass(frozen=True)
class MarkerConfig:
    """
    Settings of the marker detector.

    Attributes
    ----------
    min_area : int
        Smallest blob (pixels) taken for a dot.
    max_row_offset : float
        Largest row difference (pixels) of a dot's two images.
    max_disparity_offset : float
        Largest difference (pixels) of a dot's disparity from the median of all dots.
    dot_height : float
        Height (m) of a dot's visible face above the surface it marks (the scene's marker
        discs: 0.2 mm); the surface point is reported.
    entry_row : {'far', 'near'}
        Which row holds the entry markers: the one farther from the camera or the nearer one.

    """

    min_area: int = 12
    max_row_offset: float = 2.0
    max_disparity_offset: float = 12.0
    dot_height: float = 0.0002
    entry_row: str = 'far'

    def __post_init__(self) -> None:
        if self.entry_row not in ('far', 'near'):
            raise ValueError(f"marker entry_row must be 'far' or 'near', got {self.entry_row!r}")
        if self.min_area < 1 or self.max_row_offset <= 0 or self.max_disparity_offset <= 0:
            raise ValueError('marker min_area, max_row_offset and max_disparity_offset must be '
                             'positive')


@dataclass(frozen=True, eq=False)
class MarkerDetections:
    """
    The markers a stereo pair shows.

    Attributes
    ----------
    points : ndarray, shape (n, 3)
        Dots matched in both images (m, camera frame: the left optical frame), on the surface.
    pixels_left, pixels_right : ndarray, shape (n, 2)
        Their blob centroids (pixels).
    entries, exits : ndarray, shape (m, 3)
        Paired markers (m, camera frame), pair ``i`` (0-based, along the camera's ``+x``) in
        row ``i``; a marker that was not seen (covered, out of view) is a NaN row.
    normal : ndarray, shape (3,)
        Unit normal of the plane through the dots, towards the camera.
    unmatched : int
        Blobs of either image left without a partner in the other.

    """

    points: np.ndarray
    pixels_left: np.ndarray
    pixels_right: np.ndarray
    entries: np.ndarray
    exits: np.ndarray
    normal: np.ndarray
    unmatched: int = 0

    @property
    def n_pairs(self) -> int:
        """Number of entry/exit pairs found."""
        return len(self.entries)


def pair_normal(entries: np.ndarray, exits: np.ndarray, i: int,
                normal: np.ndarray) -> np.ndarray:
    """
    Return the surface normal at pair ``i``: of the plane through its dots and its neighbours'.

    On a curved pad the plane of all the dots can be 4-5 degrees off a pair's own surface, the
    plane of the pair's and its neighbours' dots 1-2 degrees.

    Parameters
    ----------
    entries, exits : ndarray, shape (n, 3)
        The pairs' dots (:class:`MarkerDetections`; NaN rows not seen), in order along the wound.
    i : int
        The pair (0-based).
    normal : ndarray, shape (3,)
        The plane of all the dots' normal (towards the camera): the answer's side, and the
        answer when fewer than four dots around the pair are seen.

    Returns
    -------
    ndarray, shape (3,)
        Unit normal, on ``normal``'s side.

    """
    lo, hi = max(0, i - 1), min(len(entries), i + 2)
    points = np.vstack([entries[lo:hi], exits[lo:hi]])
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 4:
        return np.asarray(normal, dtype=float)
    _, _, vt = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)
    return vt[2] if vt[2] @ normal >= 0.0 else -vt[2]


def _blobs(mask: np.ndarray, min_area: int) -> np.ndarray:
    n, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = stats[1:, cv2.CC_STAT_AREA] >= min_area
    return centroids[1:][keep]


def _match(left: np.ndarray, right: np.ndarray,
           config: MarkerConfig) -> tuple[np.ndarray, np.ndarray]:
    """Return the indices of matching blobs: rows within ``max_row_offset``, disparities alike."""
    if not len(left) or not len(right):
        return np.zeros(0, int), np.zeros(0, int)
    dv = np.abs(left[:, None, 1] - right[None, :, 1])
    d = left[:, None, 0] - right[None, :, 0]
    ok = (dv <= config.max_row_offset) & (d > 0.0)
    if not ok.any():
        return np.zeros(0, int), np.zeros(0, int)
    # each left blob's nearest candidate (smallest positive disparity) is its dot when the
    # dots are farther apart than the disparity; their median is the scene's disparity
    nearest = np.where(ok, d, np.inf).min(axis=1)
    d_ref = np.median(nearest[np.isfinite(nearest)])
    cost = dv + 0.2 * np.abs(d - d_ref)
    bad = ~ok | (np.abs(d - d_ref) > config.max_disparity_offset)
    cost[bad] = 1e6
    i, j = linear_sum_assignment(cost)
    good = cost[i, j] < 1e6
    return i[good], j[good]


def _pairs(points: np.ndarray, normal: np.ndarray,
           entry_row: str) -> tuple[np.ndarray, np.ndarray]:
    """
    Split dots into two rows along their principal axis and pair them along the wound.

    The row with more dots sets the pairs (one per dot, in order along the wound); each dot of
    the other row joins the nearest of them along the wound, within half their spacing. A pair
    whose partner was not seen has NaN for it.
    """
    empty = np.zeros((0, 3))
    if len(points) < 2:
        return empty, empty
    centre = points.mean(axis=0)
    q = points - centre
    # the wound's direction: the principal axis within the dots' plane, oriented along +x
    q_plane = q - np.outer(q @ normal, normal)
    _, _, vt = np.linalg.svd(q_plane, full_matrices=False)
    along = vt[0] if vt[0][0] >= 0.0 else -vt[0]
    across = np.cross(normal, along)
    side = q @ across
    rows = [np.flatnonzero(side >= 0.0), np.flatnonzero(side < 0.0)]
    if not len(rows[0]) or not len(rows[1]):
        return empty, empty
    # the row whose dots lie farther from the camera (larger mean z)
    far = 0 if points[rows[0], 2].mean() > points[rows[1], 2].mean() else 1
    entry_idx, exit_idx = (rows[far], rows[1 - far]) if entry_row == 'far' else (
        rows[1 - far], rows[far])
    s_entry = q[entry_idx] @ along
    s_exit = q[exit_idx] @ along
    entry_idx, s_entry = entry_idx[np.argsort(s_entry)], np.sort(s_entry)
    exit_idx, s_exit = exit_idx[np.argsort(s_exit)], np.sort(s_exit)
    lead_is_entry = len(entry_idx) >= len(exit_idx)
    lead_s, other_s = (s_entry, s_exit) if lead_is_entry else (s_exit, s_entry)
    lead_idx, other_idx = (entry_idx, exit_idx) if lead_is_entry else (exit_idx, entry_idx)
    spacing = np.median(np.diff(lead_s)) if len(lead_s) > 1 else np.inf
    partner = np.full(len(lead_idx), -1)
    cost = np.abs(lead_s[:, None] - other_s[None, :])
    i, j = linear_sum_assignment(cost)
    keep = cost[i, j] <= 0.5 * spacing
    partner[i[keep]] = other_idx[j[keep]]
    nan = np.full(3, np.nan)
    lead = points[lead_idx]
    other = np.array([points[k] if k >= 0 else nan for k in partner]).reshape(-1, 3)
    return (lead, other) if lead_is_entry else (other, lead)


def detect_markers(left: np.ndarray, right: np.ndarray, stereo: StereoModel,
                   config: MarkerConfig | None = None) -> MarkerDetections:
    """
    Find the red entry/exit markers in a stereo pair and pair them along the wound.

    Parameters
    ----------
    left, right : ndarray, shape (height, width, 3), uint8
        Rectified RGB images of the left and right cameras.
    stereo : suture_lfd.perception.stereo.StereoModel
        Their calibration (``camera_info``).
    config : MarkerConfig, optional

    Returns
    -------
    MarkerDetections
        Points in the camera frame (m); pairs ordered along the camera's ``+x``.

    Raises
    ------
    ValueError
        When an image is not uint8 RGB of the camera's size.

    """
    config = config or MarkerConfig()
    left = check_image(left, stereo, 'left')
    right = check_image(right, stereo, 'right')
    blobs_l = _blobs(red_mask(left), config.min_area)
    blobs_r = _blobs(red_mask(right), config.min_area)
    i, j = _match(blobs_l, blobs_r, config)
    unmatched = len(blobs_l) + len(blobs_r) - 2 * len(i)
    uv_l, uv_r = blobs_l[i], blobs_r[j]
    points = stereo.triangulate(uv_l, uv_r)
    normal = np.array([0.0, 0.0, -1.0])
    if len(points) >= 3:
        centre = points.mean(axis=0)
        _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
        normal = vt[2] if vt[2] @ centre < 0.0 else -vt[2]
    points = points - config.dot_height * normal
    entries, exits = _pairs(points, normal, config.entry_row)
    return MarkerDetections(points=points, pixels_left=uv_l, pixels_right=uv_r, entries=entries,
                            exits=exits, normal=normal, unmatched=int(unmatched))
