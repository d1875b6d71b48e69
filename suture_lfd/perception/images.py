"""
What perception takes from the images: checks of a stereo pair, and the colours it looks for.

Images are ``(height, width, 3)`` uint8 RGB arrays, row 0 at the top. The classes of pixels are
the scene's colours as an endoscope shows them, independent of the light's brightness:

- **red** (entry/exit markers): red well above green and blue;
- **metal** (the needle, also the instrument jaws): grey or white, bright, unsaturated;
- **thread** (the suture, attached to the needle's tail): purple, red and blue well above green.
"""

from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from suture_lfd.perception.stereo import StereoModel


def check_image(image: ArrayLike, stereo: 'StereoModel', side: str) -> np.ndarray:
    """
    Return an image as a contiguous uint8 RGB array, or say what is wrong with it.

    Parameters
    ----------
    image : array_like, shape (height, width, 3), uint8
        Colour image.
    stereo : suture_lfd.perception.stereo.StereoModel
        The camera model the image must match.
    side : str
        ``'left'`` or ``'right'``, for the message.

    Returns
    -------
    ndarray, shape (height, width, 3), uint8

    Raises
    ------
    ValueError
        When the image is not uint8 RGB or its size does not match the camera model.

    """
    array = np.asarray(image)
    if array.dtype != np.uint8:
        raise ValueError(f'{side} image must be uint8 RGB, got dtype {array.dtype}')
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f'{side} image must have shape (height, width, 3) (RGB), '
                         f'got {array.shape}')
    if array.shape[:2] != (stereo.height, stereo.width):
        raise ValueError(f'{side} image is {array.shape[1]}x{array.shape[0]} but camera_info '
                         f'says {stereo.width}x{stereo.height}')
    return np.ascontiguousarray(array)


def _channels(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rgb = rgb.astype(np.int16)
    return rgb[:, :, 0], rgb[:, :, 1], rgb[:, :, 2]


def red_mask(rgb: np.ndarray, min_red: int = 60, max_ratio: float = 0.45) -> np.ndarray:
    """
    Marker pixels: red above ``min_red`` with green and blue under ``max_ratio`` of it.

    Parameters
    ----------
    rgb : ndarray, shape (h, w, 3), uint8
    min_red : int
        Darkest red (grey level) that counts.
    max_ratio : float
        Largest green/red and blue/red ratio.

    Returns
    -------
    ndarray, shape (h, w), uint8
        255 on marker pixels, 0 elsewhere.

    """
    r, g, b = _channels(rgb)
    limit = (max_ratio * r).astype(np.int16)
    return ((r >= min_red) & (g <= limit) & (b <= limit)).astype(np.uint8) * 255


def metal_mask(rgb: np.ndarray, min_value: int = 70,
               max_saturation: float = 0.16) -> np.ndarray:
    """
    Needle pixels: bright (``max >= min_value``) and unsaturated (``(max - min) / max``).

    Parameters
    ----------
    rgb : ndarray, shape (h, w, 3), uint8
    min_value : int
        Darkest grey level that counts.
    max_saturation : float
        Largest ``(max - min) / max``.

    Returns
    -------
    ndarray, shape (h, w), uint8
        255 on needle-coloured pixels, 0 elsewhere.

    """
    r, g, b = cv2.split(rgb)
    hi = cv2.max(cv2.max(r, g), b)
    spread = cv2.subtract(hi, cv2.min(cv2.min(r, g), b))
    # OpenCV's stubs know no scalar operands: the saturating uint8 arithmetic is what is meant
    bright = cv2.compare(hi, min_value, cv2.CMP_GE)  # type: ignore[call-overload]
    grey = cv2.compare(spread, cv2.multiply(hi, max_saturation),  # type: ignore[call-overload]
                       cv2.CMP_LE)
    return cv2.bitwise_and(bright, grey)


def thread_mask(rgb: np.ndarray, min_ratio: float = 1.4, min_blue: int = 50) -> np.ndarray:
    """
    Thread pixels: purple (red and blue both ``min_ratio`` times green, blue >= ``min_blue``).

    Parameters
    ----------
    rgb : ndarray, shape (h, w, 3), uint8

    Returns
    -------
    ndarray, shape (h, w), uint8
        255 on thread pixels, 0 elsewhere.

    """
    r, g, b = _channels(rgb)
    return ((b >= min_blue) & (r >= min_ratio * g) & (b >= min_ratio * g)).astype(np.uint8) * 255
