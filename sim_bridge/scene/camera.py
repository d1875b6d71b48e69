"""
The ECM's stereo endoscope: pinhole intrinsics, camera_info matrices and CPU rendering.

Camera frames (optical convention, as ROS ``sensor_msgs/CameraInfo`` and OpenCV use them)
-----------------------------------------------------------------------------------------
- ``z`` forward along the viewing direction, ``x`` right in the image, ``y`` down in the image.
- The ECM tool-tip frame (ECM ``measured_cp`` with the endoscope's tooltip offset) has ``z`` along
  the endoscope axis, looking away from the arm; it is taken as the optical frame of the stereo
  rig's centre. The left camera sits ``baseline / 2`` along ``-x`` of it, the right camera
  ``baseline / 2`` along ``+x``; both have the tip's orientation (a rectified pair, ``R = I``).
- A point ``p`` (left-camera frame) projects to pixel ``(u, v) = (fx x / z + cx, fy y / z + cy)``
  with ``(0, 0)`` at the centre of the top-left pixel; in homogeneous form ``P_left [p; 1]`` with
  ``P_left = [K | 0]``. The right camera's ``P_right = [K | (-fx * baseline, 0, 0)^T]`` takes
  left-camera coordinates, as camera_info defines it for a rectified stereo pair.
- Distortion model ``plumb_bob``: the renderer is an ideal pinhole; a lens
  (:mod:`sim_bridge.realism.lens`, off by default) makes the raw images of it, whose
  ``camera_info`` carries its coefficients, and their rectification (``image_rect``, zero ``D``).
- A window ``(u0, v0, width, height)`` of the image is rendered alone as the same camera with its
  principal point at ``(cx - u0, cy - v0)``, as a camera's region of interest.

Rendering uses PyBullet's CPU renderer (``ER_TINY_RENDERER``) through an injected client; depth is
metric: the ``z`` coordinate (m) of the surface point seen in each pixel, in the camera frame, and
is computed only when asked for (``depth``).

Image realism (all off by default, seeded): the light's direction jittered per frame
(``light_jitter``), a specular needle (``specular``, the renderer's specular coefficient for
bodies made shiny with :meth:`StereoCamera.make_shiny`), a Gaussian blur (``blur_sigma``, the
optics' point spread) and Gaussian sensor noise (``noise_std``, grey levels), drawn from
``numpy.random.default_rng(seed)`` frame after frame.

Size: the camera's intrinsics, its calibration messages and its renders (whole, a window, through
the lens) share one projection; the lens's own maps are in :mod:`sim_bridge.realism.lens`.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.bullet import pybullet
from sim_bridge.realism.lens import Lens, LensConfig

# Optical frame (x right, y down, z forward) -> OpenGL camera frame (x right, y up, z backward).
_OPTICAL_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class CameraConfig:
    """
    Stereo endoscope intrinsics and rendering settings.

    Attributes
    ----------
    width, height : int
        Image size (pixels).
    vertical_fov : float
        Vertical field of view (rad); used when ``fy`` is 0.
    fx, fy : float
        Focal lengths (pixels); 0 derives them from ``vertical_fov`` (square pixels).
    cx, cy : float
        Principal point (pixels, (0, 0) = centre of the top-left pixel); negative values put it
        at the image centre ``((width - 1) / 2, (height - 1) / 2)``.
    baseline : float
        Distance (m) between the left and right optical centres.
    near, far : float
        Clipping distances (m) of the renderer; depth outside them is not seen.
    light_direction : tuple of float
        Direction (world frame) towards the light for shading.
    depth : bool
        Compute metric depth images (a physical endoscope gives none; off saves the
        conversion).
    noise_std : float
        Standard deviation of Gaussian sensor noise (grey levels of 255); 0 = none.
    blur_sigma : float
        Standard deviation (pixels) of a Gaussian blur; 0 = none.
    light_jitter : float
        Standard deviation (rad) of a per-frame random tilt of the light direction; 0 = none.
    specular : float
        Specular coefficient of the light on shiny bodies (:meth:`StereoCamera.make_shiny`).
    seed : int
        Seed of the realism's random numbers.

    """

    width: int = 640
    height: int = 480
    vertical_fov: float = 0.9
    fx: float = 0.0
    fy: float = 0.0
    cx: float = -1.0
    cy: float = -1.0
    baseline: float = 0.005
    near: float = 0.01
    far: float = 1.0
    light_direction: tuple[float, float, float] = (0.2, -0.3, 1.0)
    depth: bool = True
    noise_std: float = 0.0
    blur_sigma: float = 0.0
    light_jitter: float = 0.0
    specular: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.width < 2 or self.height < 2:
            raise ValueError(
                f'camera width and height must be >= 2 pixels, got {self.width}x{self.height}')
        if not (0.0 < self.vertical_fov < math.pi) and self.fy <= 0.0:
            raise ValueError(
                f'camera vertical_fov must be in (0, pi) rad, got {self.vertical_fov}')
        if self.fx < 0.0 or self.fy < 0.0:
            raise ValueError(f'camera fx, fy must be >= 0 pixels, got {self.fx}, {self.fy}')
        if not self.baseline >= 0.0:
            raise ValueError(f'camera baseline must be >= 0 m, got {self.baseline}')
        if not 0.0 < self.near < self.far:
            raise ValueError(
                f'camera near/far must satisfy 0 < near < far, got {self.near}, {self.far}')
        for name in ('noise_std', 'blur_sigma', 'light_jitter', 'specular'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'camera {name} must be >= 0 (0: off), got {value}')


@dataclass(frozen=True)
class CameraInfo:
    """
    What a ``sensor_msgs/CameraInfo`` carries, as arrays.

    Attributes
    ----------
    width, height : int
        Image size (pixels).
    distortion_model : str
        ``'plumb_bob'``.
    D : ndarray, shape (5,)
        Distortion coefficients (zeros).
    K : ndarray, shape (3, 3)
        Intrinsic matrix.
    R : ndarray, shape (3, 3)
        Rectification rotation (identity).
    P : ndarray, shape (3, 4)
        Projection matrix; ``P[0, 3] = -fx * baseline`` for the right camera.

    """

    width: int
    height: int
    distortion_model: str
    D: np.ndarray
    K: np.ndarray
    R: np.ndarray
    P: np.ndarray


@dataclass(frozen=True)
class StereoFrame:
    """
    One rendered stereo pair.

    Attributes
    ----------
    left_rgb, right_rgb : ndarray, shape (height, width, 3), uint8
        Colour images, row 0 at the top.
    left_depth, right_depth : ndarray, shape (height, width), float32, or None
        Metric depth (m): camera-frame ``z`` of the surface in each pixel; ``inf`` where
        nothing is closer than ``far``; None when the camera computes no depth.
    T_world_left, T_world_right : ndarray, shape (4, 4)
        Optical frames of the two cameras in ``world``.
    left_raw, right_raw : ndarray, shape (height, width, 3), uint8, or None
        The raw images through the lens (:mod:`sim_bridge.realism.lens`), of which
        ``left_rgb`` and ``right_rgb`` are the rectification (``image_rect``); None for an
        ideal lens (the colour images are then the raw ones too).

    """

    left_rgb: np.ndarray
    left_depth: np.ndarray | None
    right_rgb: np.ndarray
    right_depth: np.ndarray | None
    T_world_left: np.ndarray
    T_world_right: np.ndarray
    left_raw: np.ndarray | None = None
    right_raw: np.ndarray | None = None


class StereoCamera:
    """
    A rectified stereo pair rendered on the CPU at the ECM tool-tip pose.

    Parameters
    ----------
    config : CameraConfig
        Intrinsics and rendering settings.
    client : pybullet_utils.bullet_client.BulletClient, optional
        PyBullet client to render with; needed only by :meth:`render` and :meth:`render_view`.
    lens : LensConfig, optional
        The endoscope's distortion (default: an ideal pinhole).

    """

    def __init__(self, config: CameraConfig | None = None, client: Any = None,
                 lens: LensConfig | None = None) -> None:
        self.config = config or CameraConfig()
        self._client = client
        c = self.config
        fy = c.fy if c.fy > 0.0 else 0.5 * c.height / math.tan(0.5 * c.vertical_fov)
        fx = c.fx if c.fx > 0.0 else fy
        cx = c.cx if c.cx >= 0.0 else 0.5 * (c.width - 1)
        cy = c.cy if c.cy >= 0.0 else 0.5 * (c.height - 1)
        self.K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        self._projection = self._gl_projection(fx, fy, cx, cy)
        self.T_tip_left = np.eye(4)
        self.T_tip_left[0, 3] = -0.5 * c.baseline
        self.T_tip_right = np.eye(4)
        self.T_tip_right[0, 3] = 0.5 * c.baseline
        self._rng = np.random.default_rng(c.seed)
        self._light = np.asarray(c.light_direction, dtype=float)
        self._realistic = bool(c.noise_std or c.blur_sigma or c.light_jitter)
        self.lens = Lens(self.K, (lens or LensConfig()).D, (c.width, c.height))
        # The calibration camera_info reports (a calibration's result): the true one unless
        # report_calibration says otherwise; the render always uses the true K and baseline.
        self.K_reported = self.K
        self.baseline_reported = c.baseline

    def report_calibration(self, fx_scale: float, fy_scale: float, dcx: float, dcy: float,
                           baseline_scale: float) -> None:
        """
        Let ``camera_info`` report a calibration that is off the true intrinsics by this much.

        Parameters
        ----------
        fx_scale, fy_scale : float
            Reported over true focal length.
        dcx, dcy : float
            Reported minus true principal point (px).
        baseline_scale : float
            Reported over true stereo baseline.

        """
        K = self.K.copy()
        K[0, 0] *= fx_scale
        K[1, 1] *= fy_scale
        K[0, 2] += dcx
        K[1, 2] += dcy
        self.K_reported = K
        self.baseline_reported = self.config.baseline * baseline_scale

    def make_shiny(self, body: int, link: int = -1) -> None:
        """
        Give a body a white specular colour, lit with ``specular`` (no effect when it is 0).

        Parameters
        ----------
        body : int
            PyBullet body id (the needle).
        link : int
            Link index (-1: the base).

        """
        if self.config.specular > 0.0 and self._client is not None:
            self._client.changeVisualShape(body, link, specularColor=[1.0, 1.0, 1.0])

    # ------------------------------------------------------------------ intrinsics
    @property
    def P_left(self) -> np.ndarray:  # noqa: N802 (camera_info names)
        """Left projection matrix ``[K | 0]``, shape (3, 4)."""
        return np.hstack([self.K, np.zeros((3, 1))])

    @property
    def P_right(self) -> np.ndarray:  # noqa: N802 (camera_info names)
        """Right projection matrix ``[K | (-fx * baseline, 0, 0)]``, shape (3, 4)."""
        P = self.P_left
        P[0, 3] = -self.K[0, 0] * self.config.baseline
        return P

    def camera_info(self, side: str, raw: bool = False) -> CameraInfo:
        """
        Calibration of one camera, as camera_info carries it.

        Parameters
        ----------
        side : {'left', 'right'}
            Which camera.
        raw : bool
            The calibration of the raw images (``D`` the lens's coefficients) rather than of
            the rectified ones (``D`` zero).

        Returns
        -------
        CameraInfo
            Intrinsics, rectification and projection matrices: the calibration's
            (:meth:`report_calibration`), which the render need not share.

        """
        if side not in ('left', 'right'):
            raise ValueError(f"camera side must be 'left' or 'right', got {side!r}")
        K = self.K_reported
        P = np.hstack([K, np.zeros((3, 1))])
        if side == 'right':
            P[0, 3] = -K[0, 0] * self.baseline_reported
        D = self.lens.D.copy() if raw else np.zeros(5)
        return CameraInfo(width=self.config.width, height=self.config.height,
                          distortion_model='plumb_bob', D=D, K=K.copy(),
                          R=np.eye(3), P=P)

    def camera_poses(self, T_world_tip: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """
        Optical frames of the left and right cameras.

        Parameters
        ----------
        T_world_tip : array_like, shape (4, 4)
            ECM tool-tip pose in ``world``.

        Returns
        -------
        tuple of ndarray, shape (4, 4)
            ``(T_world_left, T_world_right)``.

        """
        T = np.asarray(T_world_tip, dtype=float)
        return T @ self.T_tip_left, T @ self.T_tip_right

    def project(self, points_world: ArrayLike, T_world_camera: ArrayLike) -> np.ndarray:
        """
        Project world points into a camera's image with ``K``.

        Parameters
        ----------
        points_world : array_like, shape (n, 3)
            Points (m) in ``world``.
        T_world_camera : array_like, shape (4, 4)
            Optical frame of the camera in ``world``.

        Returns
        -------
        ndarray, shape (n, 2)
            Pixel coordinates ``(u, v)``; ``(0, 0)`` is the centre of the top-left pixel.

        """
        T = np.asarray(T_world_camera, dtype=float)
        p = np.atleast_2d(np.asarray(points_world, dtype=float))
        cam = (p - T[:3, 3]) @ T[:3, :3]
        uvw = cam @ self.K.T
        return uvw[:, :2] / uvw[:, 2:3]

    # ------------------------------------------------------------------ rendering
    def _gl_projection(self, fx: float, fy: float, cx: float, cy: float,
                       size: tuple[int, int] | None = None) -> list[float]:
        """
        OpenGL projection (column-major list of 16) for pinhole ``K`` and near/far planes.

        ``size`` is the image's ``(width, height)`` (default: the configured one); a window of
        the image is the same camera with its principal point moved by the window's corner.
        """
        c = self.config
        w, h = size if size is not None else (c.width, c.height)
        n, f = c.near, c.far
        P = np.zeros((4, 4))
        P[0, 0] = 2.0 * fx / w
        # TinyRenderer samples pixel column i at window x = i and writes row r from window
        # y = h - 1 - r, so pixel (u, v) = window (u, h - 1 - v).
        P[0, 2] = 1.0 - 2.0 * cx / w
        P[1, 1] = 2.0 * fy / h
        P[1, 2] = 2.0 * (cy + 1.0) / h - 1.0
        P[2, 2] = -(f + n) / (f - n)
        P[2, 3] = -2.0 * f * n / (f - n)
        P[3, 2] = -1.0
        return P.T.reshape(-1).tolist()

    def _light_direction(self) -> list[float]:
        """Return the light's direction for the next frame (jittered when ``light_jitter`` > 0)."""
        if not self.config.light_jitter:
            return self._light.tolist()
        tilt = self._rng.normal(0.0, self.config.light_jitter, 3)
        return (self._light + np.linalg.norm(self._light) * tilt).tolist()

    def _degrade(self, rgb: np.ndarray) -> np.ndarray:
        """Blur and noise of the optics and the sensor (seeded), on a uint8 RGB image."""
        c = self.config
        if c.blur_sigma > 0.0:
            rgb = cv2.GaussianBlur(rgb, (0, 0), c.blur_sigma)
        if c.noise_std > 0.0:
            noisy = rgb + self._rng.normal(0.0, c.noise_std, rgb.shape)
            rgb = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        return rgb

    def render_view(self, T_world_camera: ArrayLike,
                    light_direction: Sequence[float] | None = None,
                    window: tuple[int, int, int, int] | None = None
                    ) -> tuple[np.ndarray, np.ndarray | None]:
        """
        Render one camera's colour and metric depth images, or a window of them.

        Parameters
        ----------
        T_world_camera : array_like, shape (4, 4)
            Optical frame of the camera in ``world``.
        light_direction : sequence of float, optional
            Direction (world) towards the light; default: the configured one (jittered).
        window : tuple of int, optional
            ``(u0, v0, width, height)``: render only these pixels of the full image (rows
            ``v0 .. v0 + height``, columns ``u0 .. u0 + width``), as a camera's region of interest
            does: the same camera with its principal point at ``(cx - u0, cy - v0)``. Default:
            the whole image.

        Returns
        -------
        rgb : ndarray, shape (height, width, 3), uint8
            Colour image, row 0 at the top (blurred and noisy when so configured).
        depth : ndarray, shape (height, width), float32, or None
            Camera-frame ``z`` (m) of the surface seen in each pixel; ``inf`` beyond ``far``;
            None when ``depth`` is off.

        """
        if self._client is None:
            raise ValueError('StereoCamera was built without a PyBullet client; pass client=')
        c = self.config
        if light_direction is None:
            light_direction = self._light_direction()
        T_gl = np.asarray(T_world_camera, dtype=float) @ _OPTICAL_TO_GL
        view = np.linalg.inv(T_gl)
        light = {'lightSpecularCoeff': c.specular} if c.specular > 0.0 else {}
        width, height, projection = c.width, c.height, self._projection
        if window is not None:
            u0, v0, width, height = self.check_window(window)
            K = self.K
            projection = self._gl_projection(K[0, 0], K[1, 1], K[0, 2] - u0, K[1, 2] - v0,
                                             (width, height))
        _, _, rgba, depth_buffer, _ = self._client.getCameraImage(
            width, height, viewMatrix=view.T.reshape(-1).tolist(),
            projectionMatrix=projection, lightDirection=list(light_direction),
            shadow=0, renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK, **light)
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        rgb = rgba[:, :, :3].copy()
        if self._realistic:
            rgb = self._degrade(rgb)
        if not c.depth:
            return rgb, None
        d = np.asarray(depth_buffer, dtype=np.float64).reshape(height, width)
        depth = c.far * c.near / (c.far - (c.far - c.near) * d)
        depth[d >= 1.0] = np.inf
        return rgb, depth.astype(np.float32)

    def check_window(self, window: Sequence[int]) -> tuple[int, int, int, int]:
        """
        Return a region of interest ``(u0, v0, width, height)`` checked against the image.

        Raises
        ------
        ValueError
            If it is not four integers inside the image with a size of at least 2 x 2.

        """
        if len(window) != 4:
            raise ValueError(f'camera window must be (u0, v0, width, height), got {window!r}')
        u0, v0, w, h = (int(x) for x in window)
        c = self.config
        if w < 2 or h < 2 or u0 < 0 or v0 < 0 or u0 + w > c.width or v0 + h > c.height:
            raise ValueError(f'camera window {(u0, v0, w, h)} is not inside the '
                             f'{c.width}x{c.height} image (at least 2x2 pixels)')
        return u0, v0, w, h

    def render(self, T_world_tip: ArrayLike,
               window: tuple[int, int, int, int] | None = None) -> StereoFrame:
        """
        Render the stereo pair at the ECM tool-tip pose, or one window of both images.

        Parameters
        ----------
        T_world_tip : array_like, shape (4, 4)
            ECM tool-tip pose in ``world``.
        window : tuple of int, optional
            ``(u0, v0, width, height)``: only these pixels of both images (the same window in
            each, :meth:`render_view`; its camera is :meth:`window_info`'s). Through a lens the
            window is the rectified image's (``image_rect``), made by the lens and the
            rectification from the region of the ideal image they read
            (:meth:`sim_bridge.realism.lens.Lens.rectify_window`); no raw images then, and the
            depth is the ideal image's.

        Returns
        -------
        StereoFrame
            Left and right colour and depth images (the window's size with ``window``) and the
            two camera poses.

        """
        T_left, T_right = self.camera_poses(T_world_tip)
        light = self._light_direction()  # one light for both eyes
        if window is not None and not self.lens.is_ideal:
            return self._lens_window(T_left, T_right, light, self.check_window(window))
        left_rgb, left_depth = self.render_view(T_left, light, window)
        right_rgb, right_depth = self.render_view(T_right, light, window)
        if self.lens.is_ideal:
            return StereoFrame(left_rgb=left_rgb, left_depth=left_depth, right_rgb=right_rgb,
                               right_depth=right_depth, T_world_left=T_left,
                               T_world_right=T_right)
        # through the lens, then rectified as the ROS image pipeline does (image_rect)
        left_raw, right_raw = self.lens.distort(left_rgb), self.lens.distort(right_rgb)
        return StereoFrame(left_rgb=self.lens.rectify(left_raw), left_depth=left_depth,
                           right_rgb=self.lens.rectify(right_raw), right_depth=right_depth,
                           T_world_left=T_left, T_world_right=T_right, left_raw=left_raw,
                           right_raw=right_raw)

    def _lens_window(self, T_left: np.ndarray, T_right: np.ndarray, light: list[float],
                     window: tuple[int, int, int, int]) -> StereoFrame:
        """Render a window of both rectified images through the lens, from what it reads."""
        source = self.lens.window_source(window)
        du, dv = window[0] - source[0], window[1] - source[1]
        rgbs, depths = [], []
        for T in (T_left, T_right):
            rgb, depth = self.render_view(T, light, source)
            rgbs.append(self.lens.rectify_window(rgb, window))
            depths.append(None if depth is None
                          else depth[dv:dv + window[3], du:du + window[2]])
        return StereoFrame(left_rgb=rgbs[0], left_depth=depths[0], right_rgb=rgbs[1],
                           right_depth=depths[1], T_world_left=T_left, T_world_right=T_right)

    def window_info(self, side: str, window: Sequence[int]) -> CameraInfo:
        """
        Calibration of a window ``(u0, v0, width, height)`` of one rectified image.

        The same camera with its principal point moved by the window's corner, as a camera's
        region of interest reports it.

        Raises
        ------
        ValueError
            If the side or the window is not valid (:meth:`check_window`).

        """
        u0, v0, w, h = self.check_window(window)
        info = self.camera_info(side)
        K, P = info.K.copy(), info.P.copy()
        K[0, 2] -= u0
        K[1, 2] -= v0
        P[0, 2] -= u0
        P[1, 2] -= v0
        return CameraInfo(width=w, height=h, distortion_model='plumb_bob', D=np.zeros(5), K=K,
                          R=np.eye(3), P=P)
