"""
The rectified stereo camera as perception sees it: ``camera_info``'s K and P, nothing else.

Frames and units
----------------
The **camera frame** of every result of :mod:`suture_lfd.perception` is the left camera's optical
frame (``x`` right, ``y`` down, ``z`` forward; metres), in which ``P_left = [K | 0]``. The right
camera sits ``baseline`` along ``+x``: ``P_right = [K | (-fx * baseline, 0, 0)^T]``, as
``camera_info`` gives a rectified pair, so a point seen at row ``v`` in one image is seen at the
same row in the other, ``d = u_left - u_right = fx * baseline / z`` pixels apart.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True, eq=False)
class StereoModel:
    """
    A calibrated, rectified stereo pair.

    Attributes
    ----------
    width, height : int
        Image size (pixels) of both cameras.
    K : ndarray, shape (3, 3)
        Intrinsics of the rectified images (both cameras).
    P_left, P_right : ndarray, shape (3, 4)
        Projection matrices of ``camera_info`` (left-camera coordinates in).

    """

    width: int
    height: int
    K: np.ndarray
    P_left: np.ndarray
    P_right: np.ndarray

    @property
    def fx(self) -> float:
        """Focal length along ``u`` (pixels)."""
        return float(self.P_left[0, 0])

    @property
    def fy(self) -> float:
        """Focal length along ``v`` (pixels)."""
        return float(self.P_left[1, 1])

    @property
    def cx(self) -> float:
        """Principal point ``u`` (pixels)."""
        return float(self.P_left[0, 2])

    @property
    def cy(self) -> float:
        """Principal point ``v`` (pixels)."""
        return float(self.P_left[1, 2])

    @property
    def baseline(self) -> float:
        """Distance (m) between the optical centres: ``-P_right[0, 3] / fx``."""
        return float(-self.P_right[0, 3] / self.P_right[0, 0])

    def project(self, points: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """
        Pixels of camera-frame points in both images.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Points (m) in the camera (left optical) frame, ``z > 0``.

        Returns
        -------
        uv_left, uv_right : ndarray, shape (n, 2)
            Pixel coordinates ``(u, v)``; ``(0, 0)`` is the centre of the top-left pixel.

        """
        p = np.asarray(points, dtype=float)
        z = p[:, 2]
        u = self.fx * p[:, 0] / z + self.cx
        v = self.fy * p[:, 1] / z + self.cy
        uv_left = np.column_stack([u, v])
        uv_right = np.column_stack([u - self.fx * self.baseline / z, v])
        return uv_left, uv_right

    def triangulate(self, uv_left: ArrayLike, uv_right: ArrayLike) -> np.ndarray:
        """
        Camera-frame points seen at matching pixels of the two images.

        For a rectified pair the rays meet where ``z = fx * baseline / (u_left - u_right)``;
        the two rows are averaged.

        Parameters
        ----------
        uv_left, uv_right : array_like, shape (n, 2)
            Matching pixel coordinates; ``u_left > u_right``.

        Returns
        -------
        ndarray, shape (n, 3)
            Points (m) in the camera frame; ``nan`` rows where the disparity is not positive.

        """
        a = np.atleast_2d(np.asarray(uv_left, dtype=float))
        b = np.atleast_2d(np.asarray(uv_right, dtype=float))
        d = a[:, 0] - b[:, 0]
        with np.errstate(divide='ignore', invalid='ignore'):
            z = np.where(d > 0.0, self.fx * self.baseline / d, np.nan)
        v = 0.5 * (a[:, 1] + b[:, 1])
        x = (a[:, 0] - self.cx) * z / self.fx
        y = (v - self.cy) * z / self.fy
        return np.column_stack([x, y, z])


def _matrix(info: Any, name: str, shape: tuple[int, int], side: str) -> np.ndarray:
    value = info[name] if isinstance(info, dict) else getattr(info, name, None)
    if value is None:
        raise ValueError(f'{side} camera_info has no {name}')
    array = np.asarray(value, dtype=float)
    if array.size != shape[0] * shape[1] or not np.all(np.isfinite(array)):
        raise ValueError(f'{side} camera_info {name} must be {shape[0]}x{shape[1]} finite '
                         f'numbers, got {array.size} values')
    return array.reshape(shape)


def _size(info: Any, name: str, side: str) -> int:
    value = info[name] if isinstance(info, dict) else getattr(info, name, None)
    if value is None or int(value) < 2:
        raise ValueError(f'{side} camera_info {name} must be >= 2 pixels, got {value}')
    return int(value)


def stereo_from_camera_info(left: Any, right: Any) -> StereoModel:
    """
    Return the rectified stereo model of a pair's two ``camera_info``.

    Parameters
    ----------
    left, right : object or dict
        Anything with ``width``, ``height``, ``K`` (9 or 3x3) and ``P`` (12 or 3x4): a
        :class:`sim_bridge.scene.camera.CameraInfo`, a dict, or the arrays of a
        ``sensor_msgs/CameraInfo``.

    Returns
    -------
    StereoModel

    Raises
    ------
    ValueError
        When the pair is not rectified (different sizes or projections, a left ``P`` with a
        translation) or the baseline is not positive; the message says which.

    """
    width, height = _size(left, 'width', 'left'), _size(left, 'height', 'left')
    if (_size(right, 'width', 'right'), _size(right, 'height', 'right')) != (width, height):
        raise ValueError(f'left and right camera_info sizes differ: {width}x{height} and '
                         f'{_size(right, "width", "right")}x{_size(right, "height", "right")}')
    K = _matrix(left, 'K', (3, 3), 'left')
    P_left = _matrix(left, 'P', (3, 4), 'left')
    P_right = _matrix(right, 'P', (3, 4), 'right')
    if P_left[0, 0] <= 0.0 or P_left[1, 1] <= 0.0:
        raise ValueError(f'left camera_info P has no positive focal lengths: '
                         f'fx {P_left[0, 0]}, fy {P_left[1, 1]}')
    if np.abs(P_left[:, 3]).max() > 1e-9:
        raise ValueError(f'left camera_info P must be [K | 0] (a rectified left camera), got '
                         f'translation {P_left[:, 3].tolist()}')
    if not np.allclose(P_left[:, :3], P_right[:, :3], rtol=1e-9, atol=1e-9):
        raise ValueError('left and right camera_info P differ in their first three columns: '
                         'the images are not rectified')
    if P_right[0, 3] >= 0.0 or abs(P_right[1, 3]) > 1e-9 or abs(P_right[2, 3]) > 1e-9:
        raise ValueError(f'right camera_info P must carry -fx * baseline (< 0) in P[0, 3] only, '
                         f'got {P_right[:, 3].tolist()}')
    return StereoModel(width=width, height=height, K=K, P_left=P_left, P_right=P_right)
