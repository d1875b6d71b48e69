"""
The endoscope's stereo pair side by side on the page, as the dVRK's stereo viewer shows it.

A page panel (:meth:`suture_lfd.viewer.page.ViewerPage.add_panel`): the ``Stereo pair`` button
turns the page's 3-D view into the ECM's left and right images side by side (the left image on
the left half, each at its own aspect, black bars filling the rest of the view), the format a
side-by-side 3-D display takes; the scene is hidden meanwhile. Pressed again, the scene is back.

The images come from :meth:`StereoPanel.set_image` (any thread, RGB ``(h, w, 3)`` uint8, as the
simulator publishes them on ``ECM/left|right/image_raw`` when its ``camera_rate`` is set);
:meth:`StereoPanel.render` sends the pair when it changed, only while it is shown. Sending and
turning the pair off exclude each other: a pair sent just after the scene came back would stay
on the page in its place, with nothing left to take it off.
"""

import threading
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

SIDES = ('left', 'right')
SHOW_LABEL = 'Stereo pair: show'
HIDE_LABEL = 'Stereo pair: back to the scene'
JPEG_QUALITY = 90


def side_by_side(left: ArrayLike, right: ArrayLike, aspect: float | None = None) -> np.ndarray:
    """
    Return the left and right images side by side, padded with black to ``aspect``.

    Parameters
    ----------
    left, right : array_like, shape (h, w, 3), uint8
        The pair, of the same size.
    aspect : float, optional
        Width over height of the view that shows the result (the page's 3-D view, which
        stretches its background to fill it); None: no padding.

    Returns
    -------
    numpy.ndarray, shape (H, W, 3), uint8
        ``[left | right]`` centred in black bars (above and below, or at the sides).

    """
    left, right = np.asarray(left, np.uint8), np.asarray(right, np.uint8)
    if left.shape != right.shape or left.ndim != 3 or left.shape[2] != 3:
        raise ValueError(f'a stereo pair is two RGB images (h, w, 3) of one size, got '
                         f'{left.shape} and {right.shape}')
    pair = np.concatenate((left, right), axis=1)
    if aspect is None or not aspect > 0:
        return pair
    h, w = pair.shape[:2]
    height, width = max(h, round(w / aspect)), max(w, round(h * aspect))
    framed = np.zeros((height, width, 3), np.uint8)
    top, side = (height - h) // 2, (width - w) // 2
    framed[top:top + h, side:side + w] = pair
    return framed


class StereoPanel:
    """
    The ``Stereo pair`` button and the side-by-side view it turns on.

    Attributes
    ----------
    shown : bool
        Whether the page shows the pair (in place of the scene).

    """

    def __init__(self) -> None:
        self.shown = False
        self._lock = threading.Lock()
        # held while the page is changed: render's send and show's switch, one at a time
        self._page_lock = threading.Lock()
        self._images: dict[str, np.ndarray | None] = dict.fromkeys(SIDES)
        self._version = 0       # of the images set
        self._sent = -1         # version of the pair on the page (-1: none)
        self._page: Any = None
        self.button: Any = None

    def attach(self, page: Any) -> None:
        """Build the button on ``page``."""
        self._page = page
        self.button = page.server.gui.add_button(
            SHOW_LABEL, color='gray', hint="the endoscope's left and right images side by side, "
                                           'for a 3-D display')
        self.button.on_click(lambda _event: self.show(not self.shown))

    def show(self, shown: bool) -> None:
        """Show the pair in place of the scene (True) or the scene again (False)."""
        with self._page_lock:
            with self._lock:
                self.shown = bool(shown)
                self._sent = -1
            if self._page is None:
                return
            scene = self._page.server.scene
            scene.set_global_visibility(not shown)
            if not shown:
                scene.set_background_image(None)
            self.button.label = HIDE_LABEL if shown else SHOW_LABEL

    def set_image(self, side: str, rgb: ArrayLike) -> None:
        """Take the latest image of one side (``left`` or ``right``): RGB ``(h, w, 3)`` uint8."""
        if side not in SIDES:
            raise ValueError(f'side must be one of {SIDES}, got {side!r}')
        with self._lock:
            self._images[side] = np.asarray(rgb, np.uint8)
            self._version += 1

    def render(self) -> bool:
        """Send the pair to the page if it is shown and changed; return whether it was sent."""
        with self._page_lock:
            with self._lock:
                left, right = self._images['left'], self._images['right']
                if (not self.shown or self._page is None or left is None or right is None
                        or left.shape != right.shape or self._sent == self._version):
                    return False
                self._sent = self._version
            cameras = self._page.client_cameras()
            aspect = cameras[0]['width'] / cameras[0]['height'] \
                if cameras and cameras[0]['height'] > 0 else None
            self._page.server.scene.set_background_image(
                side_by_side(left, right, aspect), format='jpeg', jpeg_quality=JPEG_QUALITY)
            return True
