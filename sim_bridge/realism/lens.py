"""
The endoscope's lens: radial and tangential distortion (``plumb_bob``) and its rectification.

A physical endoscope's raw images are distorted; its calibration (``camera_info`` ``D``, the
``plumb_bob`` model of OpenCV and ROS: ``k1, k2, p1, p2, k3``) lets the ROS image pipeline
publish ``image_rect``, the undistorted image of an ideal pinhole camera with the same ``K``.
The renderer draws that ideal image; :class:`Lens` turns it into the raw one and back, with
OpenCV remap tables built once per image size.

For a normalised image point ``(x, y)`` (``x = X / Z``, ``y = Y / Z``) and ``r^2 = x^2 + y^2``,
the distorted point is ``x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)`` and
``y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y`` (Brown-Conrady); pixels are
``K`` times the normalised points. Level 0 has all coefficients zero: the raw image is the ideal
one, untouched.

Pixels ``(u, v)``: ``(0, 0)`` is the centre of the top-left pixel, as in
:mod:`sim_bridge.scene.camera`.
"""

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True)
class LensConfig:
    """
    The lens's distortion at level 1 (a preset) and the level that scales it.

    Attributes
    ----------
    level : float
        Scale of the coefficients (0: an ideal pinhole, bit-identical images).
    k1, k2, k3 : float
        Radial coefficients.
    p1, p2 : float
        Tangential coefficients.

    """

    level: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    @property
    def D(self) -> np.ndarray:  # noqa: N802 (camera_info's name)
        """The coefficients ``(k1, k2, p1, p2, k3)`` at the level, shape (5,)."""
        return self.level * np.array([self.k1, self.k2, self.p1, self.p2, self.k3])


class Lens:
    """
    Distortion of one camera's images and its rectification.

    Parameters
    ----------
    K : array_like, shape (3, 3)
        Intrinsic matrix of the rectified (ideal) image.
    D : array_like, shape (5,)
        ``plumb_bob`` coefficients ``(k1, k2, p1, p2, k3)``.
    size : tuple of int
        ``(width, height)`` of the images.

    """

    def __init__(self, K: ArrayLike, D: ArrayLike, size: tuple[int, int]) -> None:
        self.K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        self.D = np.asarray(D, dtype=np.float64).reshape(5)
        self.size = (int(size[0]), int(size[1]))
        self.is_ideal = not self.D.any()
        self._maps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        # each map's integer source columns and rows as contiguous planes (built once): the
        # extent a window reads is their minimum and maximum over it
        self._planes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._region_memo: dict[tuple[int, int, int, int],
                                tuple[tuple[int, int, int, int], tuple[int, int, int, int]]] = {}

    def distort_points(self, uv: ArrayLike) -> np.ndarray:
        """
        Return where ideal (rectified) pixels lie in the raw image.

        Parameters
        ----------
        uv : array_like, shape (n, 2)
            Pixels of the ideal pinhole image.

        Returns
        -------
        ndarray, shape (n, 2)
            The same points in the raw, distorted image.

        """
        uv = np.atleast_2d(np.asarray(uv, dtype=np.float64))
        if self.is_ideal:
            return uv.copy()
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        x, y = (uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy
        k1, k2, p1, p2, k3 = self.D
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.column_stack([fx * xd + cx, fy * yd + cy])

    def undistort_points(self, uv_raw: ArrayLike) -> np.ndarray:
        """
        Return where raw pixels lie in the ideal (rectified) image (OpenCV's iterative inverse).

        Parameters
        ----------
        uv_raw : array_like, shape (n, 2)
            Pixels of the raw image.

        Returns
        -------
        ndarray, shape (n, 2)

        """
        uv_raw = np.atleast_2d(np.asarray(uv_raw, dtype=np.float64))
        if self.is_ideal:
            return uv_raw.copy()
        out = cv2.undistortPointsIter(uv_raw.reshape(-1, 1, 2), self.K, self.D, None, self.K,
                                      (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9))
        return out.reshape(-1, 2)

    def _map(self, source: str) -> tuple[np.ndarray, np.ndarray]:
        """
        Return the point map that resamples an image from the ``source`` one (built once).

        ``'ideal'``: for each raw pixel, where it lies in the ideal image (from
        :meth:`undistort_points`); ``'raw'``: for each rectified pixel, where it lies in the raw
        image (OpenCV's ``initUndistortRectifyMap``, the ROS image pipeline's own).
        """
        maps = self._maps.get(source)
        if maps is None:
            if source == 'ideal':
                w, h = self.size
                u, v = np.meshgrid(np.arange(w, dtype=np.float64),
                                   np.arange(h, dtype=np.float64))
                ideal = self.undistort_points(np.column_stack([u.ravel(), v.ravel()]))
                maps = cv2.convertMaps(ideal[:, 0].reshape(h, w).astype(np.float32),
                                       ideal[:, 1].reshape(h, w).astype(np.float32),
                                       cv2.CV_16SC2)
            else:
                maps = cv2.initUndistortRectifyMap(self.K, self.D, np.eye(3), self.K, self.size,
                                                   cv2.CV_16SC2)
            self._maps[source] = maps
        return maps

    def _remap(self, image: np.ndarray, source: str) -> np.ndarray:
        """Return ``image`` resampled from the ``source`` image (``'ideal'`` or ``'raw'``)."""
        if self.is_ideal:
            return image
        m1, m2 = self._map(source)
        return cv2.remap(image, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def distort(self, image: np.ndarray) -> np.ndarray:
        """
        Return the raw image the lens makes of an ideal one (the renderer's).

        Parameters
        ----------
        image : ndarray, shape (height, width, ...)
            Ideal pinhole image.

        Returns
        -------
        ndarray
            Raw image, same shape and type (the input itself at level 0).

        """
        return self._remap(image, 'ideal')

    def rectify(self, raw: np.ndarray) -> np.ndarray:
        """
        Return ``image_rect``: the raw image undistorted, as the ROS image pipeline makes it.

        Parameters
        ----------
        raw : ndarray, shape (height, width, ...)
            Raw image.

        Returns
        -------
        ndarray
            Rectified image, same shape and type (the input itself at level 0).

        """
        return self._remap(raw, 'raw')

    def _regions(self, window: tuple[int, int, int, int]
                 ) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]]:
        """
        Return the raw and the ideal regions a window of ``image_rect`` is made from.

        Each is ``(u0, v0, width, height)`` inside the image: the pixels the rectification's
        remap reads (bilinear: one more on each side) for the window, then those the lens's
        remap reads for them.
        """
        window = (int(window[0]), int(window[1]), int(window[2]), int(window[3]))
        hit = self._region_memo.get(window)
        if hit is None:
            raw = self._reach('raw', *window)
            hit = (raw, self._reach('ideal', *raw))
            if len(self._region_memo) >= 4096:
                self._region_memo.clear()
            self._region_memo[window] = hit
        return hit

    def _reach(self, source: str, u0: int, v0: int, uw: int, vh: int
               ) -> tuple[int, int, int, int]:
        """Return the region (inside the image) the map ``source`` reads for a region of it."""
        planes = self._planes.get(source)
        if planes is None:
            m1 = self._map(source)[0]
            planes = self._planes[source] = (np.ascontiguousarray(m1[:, :, 0]),
                                             np.ascontiguousarray(m1[:, :, 1]))
        w, h = self.size
        cols = planes[0][v0:v0 + vh, u0:u0 + uw]
        rows = planes[1][v0:v0 + vh, u0:u0 + uw]
        lo_u, lo_v = max(int(cols.min()), 0), max(int(rows.min()), 0)
        hi_u = max(min(int(cols.max()) + 1, w - 1), lo_u + 1)
        hi_v = max(min(int(rows.max()) + 1, h - 1), lo_v + 1)
        return lo_u, lo_v, hi_u - lo_u + 1, hi_v - lo_v + 1

    def window_source(self, window: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
        """
        Return the region of the ideal image a window of ``image_rect`` is made from.

        Parameters
        ----------
        window : tuple of int
            ``(u0, v0, width, height)`` of the rectified image.

        Returns
        -------
        tuple of int
            ``(u0, v0, width, height)`` of the ideal image (the window itself for an ideal lens).

        """
        return tuple(window) if self.is_ideal else self._regions(window)[1]  # type: ignore

    def rectify_window(self, ideal: np.ndarray, window: tuple[int, int, int, int]
                       ) -> np.ndarray:
        """
        Return a window of ``image_rect`` from the ideal image's :meth:`window_source` region.

        The same two remaps as :meth:`distort` then :meth:`rectify` on the whole image, done on
        the pixels they read for the window only: the window of the whole image's
        ``image_rect``, pixel for pixel.

        Parameters
        ----------
        ideal : ndarray, shape (height, width, ...)
            The ideal image of ``window_source(window)``.
        window : tuple of int
            ``(u0, v0, width, height)`` of the rectified image.

        Returns
        -------
        ndarray, shape (window height, window width, ...)

        """
        u0, v0, w, h = window
        if self.is_ideal:
            return ideal
        (ru, rv, rw, rh), (iu, iv, _, _) = self._regions(window)
        m1, m2 = self._map('ideal')
        raw = cv2.remap(ideal, m1[rv:rv + rh, ru:ru + rw] - np.array([iu, iv], np.int16),
                        m2[rv:rv + rh, ru:ru + rw], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT)
        m1, m2 = self._map('raw')
        return cv2.remap(raw, m1[v0:v0 + h, u0:u0 + w] - np.array([ru, rv], np.int16),
                         m2[v0:v0 + h, u0:u0 + w], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT)
