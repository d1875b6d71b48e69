"""
The needle's 6-DoF pose from a stereo pair: its pixels, then a fit of the projected arc.

Method
------
1. **Pixels.** The needle is the scene's unsaturated, bright (metal) thing
   (:func:`suture_lfd.perception.images.metal_mask`). Each image becomes a cost field that is
   lowest on the centre line of the needle's pixels and grows with the distance from them:
   the (slightly blurred) distance in pixels to the centre line of the needle's pixels, whose
   ridge is where they lie farthest from other pixels (OpenCV distance transforms).
2. **Start.** With a prior (the tool pose and the grasp while the needle is held, the last
   estimate while it lies free) the fit starts there. Without one, the needle is detected: in
   each image the elongated blobs of needle pixels, their two ends and the bulge of their arc,
   triangulated and aligned with the arc's tail, middle and tip (both ways round).
3. **Fit.** ``n_points`` points of the arc (radius 10.18 mm, 120 deg; the scene's
   :class:`sim_bridge.common.needle.NeedleGeometry`) are projected into both images with the
   camera model and the pose is moved until they lie on the centre lines
   (:func:`scipy.optimize.least_squares`, a soft-L1 loss so that the hidden parts of the arc
   pull little). Arc points whose pixels fall on an instrument (``tools``: jaws, wrist,
   shaft, from the arm's kinematics) are left out in that image.
4. **Trust.** A point is *seen* when it lies on needle pixels in an image. The residual is the
   RMS distance (pixels) of the points seen in both images from the centre line, the visible
   share the fraction of arc points seen in both. An estimate is ``found`` only when enough of
   the arc is seen in both images (``min_visible``) and it fits them closely
   (``max_residual``); otherwise it says why.
5. **Which end is the tip.** The arc is symmetric: turned half a turn about its middle radius,
   tail and tip swap with the same image. Without a prior, the end nearer the thread's pixels is
   the tail; with one, the pose nearer the prior is kept.

Size: one tracker whose detection, fit and trust measures share the arc's model and its
projections; what the images say about a wire is in :mod:`suture_lfd.perception.wire_images`,
the pose helpers in :mod:`suture_lfd.perception.arc_poses`, the optional fit to the
triangulated centre line in :mod:`suture_lfd.perception.arc_stereo`, the search for a lost
needle in :mod:`suture_lfd.perception.reacquire`.

Frames: ``pose_camera`` is ``T_camera_needle`` (4, 4) in the camera (left optical) frame of
:mod:`suture_lfd.perception.stereo`; the needle frame is :mod:`sim_bridge.common.needle`'s (origin
at the arc centre, arc in the x-y plane, tail at 180 deg, tip at 60 deg). Lengths in metres,
image distances in pixels.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from sim_bridge.common.needle import NeedleGeometry
from suture_lfd.perception.arc_poses import flip_transform, kabsch, mirrored, rotvec_matrix
from suture_lfd.perception.arc_stereo import (
    arc_distances,
    centre_line_points,
    fit_arc_to_points,
)
from suture_lfd.perception.grasp import GraspFit, HeldView
from suture_lfd.perception.images import check_image
from suture_lfd.perception.reacquire import shifted_priors
from suture_lfd.perception.stereo import StereoModel
from suture_lfd.perception.wire_images import (
    WireImage,
    hidden_in_images,
    runs,
    sample,
    tool_capsules,
)

Fields = tuple[WireImage, WireImage]  # the left and right images' wire fields

_OUT_OF_VIEW = 30.0  # cost (pixels) of an arc point outside an image
_BEYOND = np.arange(0.5, 4.6, 1.0)  # pixels past a wire's end where the thread is looked for
# the arc fit's relative step of its forward differences, and where a variable is 0 the
# square root of the doubles' epsilon (least_squares's own 2-point scheme)
_DIFF_STEP, _EPS_STEP = 0.02, math.sqrt(np.finfo(float).eps)


@dataclass(frozen=True)
class TrackerConfig:
    """
    Settings of the needle tracker.

    Attributes
    ----------
    n_points : int
        Arc points projected in the fit.
    blur : float
        Gaussian blur (pixels) of the cost field.
    loss_scale : float
        Distance (pixels) beyond which an arc point pulls less (soft-L1 loss).
    seen_distance : float
        Largest distance (pixels) of a seen arc point from the needle's pixels.
    min_visible : float
        Smallest share of arc points seen in both images for an estimate.
    max_residual : float
        Largest residual (pixels) of an estimate.
    partial_below : float
        Visible share under which an estimate is flagged ``partial``.
    jaw_length, jaw_radius : float
        An instrument's jaws (m): a capsule from the tool-tip origin along tool ``z``.
    shaft_length, shaft_radius : float
        Its wrist and shaft (m): a capsule from the tool-tip origin back along ``-z``. Arc
        points whose pixels fall on either are hidden in that image.
    profile_half_length, profile_step : float
        Reach and sampling step (pixels) of the search for the wire's edges across the arc.
    refine_iterations : int
        Gauss-Newton iterations on the edges.
    huber : float
        Offset (pixels) beyond which an edge pulls less.
    max_support_tilt : float
        Largest angle (rad) between a free needle's plane and the surface it lies on.
    ambiguity, ambiguity_distance : float
        Another pose at least ``ambiguity_distance`` (m, mean over base, middle and tip) away
        whose cost is within ``ambiguity`` (pixels) makes a detection ambiguous.
    ends_margin : float
        Of poses that fit the images alike, one whose arc ends lie at least this much closer
        (m, mean of the two) to the wire's ends triangulated from the pair than every other's
        is taken, and the detection is not ambiguous (0: never).
    end_gate : float
        Largest offset (pixels) of a seen end of the wire from the arc's projected end.
    end_weight : float
        Weight of an end against one point across the arc.
    min_blob_area : int
        Smallest blob (pixels) that may be a needle when detecting without a prior.
    min_elongation : float
        Smallest length-to-width ratio of such a blob.
    centre_line : bool
        Move a detection onto the wire's centre line triangulated row by row before the edges
        refine it (:mod:`suture_lfd.perception.arc_stereo`). Off by default: it halves the
        90th-percentile error of a needle lying on the curved (scanned) pad, but doubles the
        median error on the flat one and leaves more detections ambiguous
        (``bench/bench_lying_needle.py``).
    min_stereo_points : int
        Fewest triangulated centre-line points for which a detection is fitted to them.
    stereo_weight : float
        Cost (pixels) of a detection per millimetre of the triangulated points' median
        distance from its arc, added to its image cost.

    """

    n_points: int = 40
    blur: float = 1.0
    loss_scale: float = 2.0
    seen_distance: float = 1.5
    min_visible: float = 0.3
    max_residual: float = 1.5
    partial_below: float = 0.85
    jaw_length: float = 0.0105
    jaw_radius: float = 0.0025
    shaft_length: float = 0.06
    shaft_radius: float = 0.0045
    profile_half_length: float = 12.0
    profile_step: float = 0.5
    refine_iterations: int = 30
    huber: float = 1.0
    max_support_tilt: float = math.radians(35.0)
    ambiguity: float = 0.15
    ambiguity_distance: float = 0.001
    ends_margin: float = 0.00025
    end_gate: float = 5.0
    end_weight: float = 4.0
    min_blob_area: int = 40
    min_elongation: float = 5.0
    centre_line: bool = False
    min_stereo_points: int = 20
    stereo_weight: float = 0.5

    def __post_init__(self) -> None:
        if self.n_points < 8:
            raise ValueError(f'tracker n_points must be >= 8, got {self.n_points}')
        for name in ('loss_scale', 'seen_distance', 'max_residual', 'jaw_length',
                     'jaw_radius', 'shaft_length', 'shaft_radius'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'tracker {name} must be > 0, got {getattr(self, name)}')
        if not 0.0 < self.min_visible <= 1.0:
            raise ValueError(f'tracker min_visible must be in (0, 1], got {self.min_visible}')


@dataclass(frozen=True, eq=False)
class NeedleEstimate:
    """
    What the stereo pair says about the needle.

    Attributes
    ----------
    found : bool
        A pose that can be trusted; False means "not found" (``reason`` says why) and
        ``pose_camera`` is then only the best fit, not an estimate.
    pose_camera : ndarray, shape (4, 4) or None
        ``T_camera_needle`` (m, camera = left optical frame); None when nothing was fitted.
    residual_px : float
        RMS distance (pixels) of the arc points seen in both images from the needle's centre
        line; ``inf`` when none is seen.
    visible_share : float
        Share of the arc seen in both images (0-1).
    visible_left, visible_right : float
        Share of the arc seen in each image.
    partial : bool
        Part of the arc is hidden (jaws, tissue, image border): ``visible_share`` under
        ``partial_below``.
    reason : str
        Why the estimate is not found (empty when found).
    rival_distance : float
        When ambiguous: how far (m, mean of base, middle and tip) the other pose that fits
        the images as well lies from ``pose_camera``; ``inf`` otherwise.

    """

    found: bool
    pose_camera: np.ndarray | None
    residual_px: float
    visible_share: float
    visible_left: float = 0.0
    visible_right: float = 0.0
    partial: bool = False
    reason: str = ''
    rival_distance: float = math.inf

    def points_camera(self, geometry: NeedleGeometry | None = None) -> np.ndarray | None:
        """Return the base (tail), middle and tip (3, 3) in the camera frame (m), or None."""
        if self.pose_camera is None:
            return None
        g = geometry or NeedleGeometry()
        p = g.point_at(np.array([0.0, 0.5, 1.0]))
        return p @ self.pose_camera[:3, :3].T + self.pose_camera[:3, 3]


class NeedleTracker:
    """
    Needle pose from a rectified stereo pair, with a residual and visibility.

    Parameters
    ----------
    geometry : sim_bridge.common.needle.NeedleGeometry, optional
        The needle (default: radius 10.18 mm, 120 deg arc, 1 mm wire).
    config : TrackerConfig, optional

    Examples
    --------
    >>> tracker = NeedleTracker()
    >>> estimate = tracker.estimate(left, right, stereo)            # lying free: detect
    >>> estimate = tracker.estimate(left, right, stereo, prior=T_camera_tool @ T_tool_needle,
    ...                             tools=[T_camera_tool])           # held: follow the jaw

    """

    def __init__(self, geometry: NeedleGeometry | None = None,
                 config: TrackerConfig | None = None) -> None:
        self.geometry = geometry or NeedleGeometry()
        self.config = config or TrackerConfig()
        self._model = self.geometry.arc_points(self.config.n_points)
        self._flip = flip_transform(self.geometry)
        self._tangents = self.geometry.tangent_at(np.linspace(0.0, 1.0, self.config.n_points))
        c = self.config
        self._steps = np.arange(-c.profile_half_length, c.profile_half_length + 1e-9,
                                c.profile_step)
        # the profiles' arc points: every one across the arc, then the tail and the tip along
        # it; the runs across closed on both sides, those along open outwards (both images)
        n = self.config.n_points
        self._index = np.concatenate([np.arange(n), [0, n - 1]])
        self._closed = np.tile(np.arange(n + 2) < n, 2)
        # units of the fit's variables: rotation as arc length at the radius, translation in
        # mm, so that one unit of either moves the arc about a millimetre
        self._scale = np.array([1.0 / (1000.0 * self.geometry.radius)] * 3 + [1e-3] * 3)

    # ------------------------------------------------------------------ fields
    # ------------------------------------------------------------------ fit
    def _project(self, T: np.ndarray,
                 stereo: StereoModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        points = self._model @ T[:3, :3].T + T[:3, 3]
        return points, *stereo.project(points)

    def _residuals(self, x: np.ndarray, T0: np.ndarray, stereo: StereoModel, fields: Fields,
                   keep: np.ndarray) -> np.ndarray:
        return self._batch_residuals(x[None, :], T0, stereo, fields, keep)[0]

    def _batch_residuals(self, xs: np.ndarray, T0: np.ndarray, stereo: StereoModel,
                         fields: Fields, keep: np.ndarray) -> np.ndarray:
        """Return the fit's residuals (m, 2k) at ``m`` poses, projected and sampled together."""
        model = self._model[keep]
        k = len(model)
        moved = []
        turn, R = None, np.eye(3)
        for x in xs:
            if turn is None or np.any(x[:3] != turn):  # poses that only shift share a turn
                turn = x[:3]
                R = rotvec_matrix(turn * self._scale[:3]) @ T0[:3, :3]
            moved.append(model @ R.T + (T0[:3, 3] + x[3:] * self._scale[3:]))
        points = np.concatenate(moved)
        behind = (points[:, 2] <= 1e-4).reshape(len(xs), k).any(axis=1)
        points[:, 2] = np.where(points[:, 2] <= 1e-4, 1.0, points[:, 2])
        uv_l, uv_r = stereo.project(points)
        r = np.concatenate([sample(fields[0].cost, uv_l).reshape(len(xs), k),
                            sample(fields[1].cost, uv_r).reshape(len(xs), k)], axis=1)
        r = np.where(np.isnan(r), _OUT_OF_VIEW, r)
        r[behind] = _OUT_OF_VIEW
        return r

    def _jacobian(self, x: np.ndarray, T0: np.ndarray, stereo: StereoModel, fields: Fields,
                  keep: np.ndarray) -> np.ndarray:
        """
        Forward differences of :meth:`_residuals`, the six steps evaluated in one pass.

        The steps are those of ``least_squares``'s own ``2-point`` scheme with ``diff_step``
        ``_DIFF_STEP`` (relative to each variable; the square root of the doubles' epsilon
        where the variable is 0), so the fit is the same; one pass saves the Python of six.
        """
        sign = np.where(x >= 0.0, 1.0, -1.0)
        h = _DIFF_STEP * sign * np.abs(x)
        h = np.where((x + h) - x == 0.0, _EPS_STEP * sign * np.maximum(1.0, np.abs(x)), h)
        xs = np.repeat(x[None, :], 7, axis=0)
        xs[np.arange(1, 7), np.arange(6)] += h
        r = self._batch_residuals(xs, T0, stereo, fields, keep)
        dx = np.array([(x[i] + h[i]) - x[i] for i in range(6)])
        return ((r[1:] - r[0]) / dx[:, None]).T

    def _fit(self, T0: np.ndarray, stereo: StereoModel, fields: Fields,
             hidden: np.ndarray) -> np.ndarray:
        keep = ~hidden.any(axis=0)
        if keep.sum() < 4:
            return T0
        result = least_squares(self._residuals, np.zeros(6), jac=self._jacobian,
                               args=(T0, stereo, fields, keep), loss='soft_l1',
                               f_scale=self.config.loss_scale, method='trf', x_scale=1.0,
                               max_nfev=60, xtol=1e-4, ftol=1e-6)
        x = result.x
        T = np.eye(4)
        T[:3, :3] = rotvec_matrix(x[:3] * self._scale[:3]) @ T0[:3, :3]
        T[:3, 3] = T0[:3, 3] + x[3:] * self._scale[3:]
        return T

    def _profiles(self, T: np.ndarray, stereo: StereoModel, fields: Fields,
                  hidden: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray,
                                                    np.ndarray]]:
        """
        Where the wire is seen around each projected arc point, in both images.

        For every arc point the mask is sampled along the normal of the projected arc; the run
        of needle pixels through the point (or the nearest one) gives two edges to a sub-pixel
        (the mask's 0.5 crossings), and their middle the centre's offset along the normal. At
        the tail and the tip the mask is also sampled along the arc, outwards: where the run
        ends is the end's offset (kept only within ``end_gate`` pixels: an end hidden in the
        tissue or under the thread would pull the arc along itself).

        Returns
        -------
        list of (index, direction, offset, valid) per image: the arc point (k,), the unit image
        direction (k, 2) and the offset (k,) pixels along it; rows 0..n-1 are the normals, the
        last two the tail and the tip.

        """
        c = self.config
        n = len(self._model)
        points = self._model @ T[:3, :3].T + T[:3, 3]
        tangents = self._tangents @ T[:3, :3].T
        ahead = points + 1e-4 * tangents
        width = self.geometry.wire_diameter * stereo.fx / points[:, 2]
        index = self._index
        steps = self._steps
        m = len(steps)
        # both images at once (each row's arithmetic is its own): pixels of the points and of
        # the points a little ahead, (2, n, 2)
        both = np.array(stereo.project(np.concatenate([points, ahead])))
        seen = both[:, :n]
        direction = both[:, n:] - seen
        direction /= np.maximum(np.sqrt(np.sum(direction * direction, axis=2, keepdims=True)),
                                1e-12)
        normal = np.stack([-direction[..., 1], direction[..., 0]], axis=2)
        dirs = np.concatenate([normal, -direction[:, :1], direction[:, -1:]], axis=1)
        origin = seen[:, index]
        samples = origin[:, :, None, :] + steps[None, None, :, None] * dirs[:, :, None, :]
        k = len(index) * m
        flat = samples.reshape(2, k, 2)
        profile = np.concatenate([sample(fields[0].soft, flat[0], 0.0),
                                  sample(fields[1].soft, flat[1], 0.0)]).reshape(
                                      2 * len(index), m)
        edges, valid = runs(profile, steps, c.profile_step, closed=self._closed)
        edges = edges.reshape(2, 2, len(index))
        valid = valid.reshape(2, len(index))
        wide = edges[1, :, :n] - edges[0, :, :n]
        normals_valid = (valid[:, :n] & ~hidden & (wide >= 0.5 * width)
                         & (wide <= 1.6 * width + 1.0))
        offset = np.where(normals_valid, 0.5 * (edges[0, :, :n] + edges[1, :, :n]), 0.0)
        end = edges[1, :, n:]
        ends_valid = valid[:, n:] & ~hidden[:, [0, n - 1]] & (np.abs(end) <= c.end_gate)
        # an end that runs into the thread (tied to the tail) is hidden, not seen
        beyond = (origin[:, n:, None, :] + (end[:, :, None, None] + _BEYOND[None, None, :, None])
                  * dirs[:, n:, None, :]).reshape(2, -1, 2)
        out = []
        for side, field in enumerate(fields):
            ok = ends_valid[side]
            if ok.any():
                thread = sample(field.thread_soft, beyond[side], 0.0).reshape(2, -1)
                ok = ok & ~(thread > 0.25).any(axis=1)
            out.append((index, dirs[side],
                        np.concatenate([offset[side], np.where(ok, end[side], 0.0)]),
                        np.concatenate([normals_valid[side], ok])))
        return out

    def _seen(self, left: np.ndarray, right: np.ndarray, stereo: StereoModel,
              tools: Sequence[ArrayLike]) -> tuple[Fields, list[Any]]:
        """Return a checked pair's wire fields and the capsules of the instruments in view."""
        c = self.config
        fields = (WireImage(check_image(left, stereo, 'left'), c.blur),
                  WireImage(check_image(right, stereo, 'right'), c.blur))
        capsules = [k for T in tools for k in tool_capsules(
            _pose(T, 'tool pose'), c.jaw_length, c.jaw_radius, c.shaft_length, c.shaft_radius)]
        return fields, capsules

    def edge_rows(self, T: np.ndarray, stereo: StereoModel, fields: Fields,
                  hidden: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Return the edge fit's linear system at pose ``T`` (``T_camera_needle``).

        Returns
        -------
        tuple of ndarray
            Rows ``(k, 6)`` -- the derivative of each seen edge offset (pixels) by a rotation
            (rad, camera axes) about ``T``'s origin, then by a translation (m) --, the offsets
            ``(k,)`` and their Huber weights ``(k,)``; ``k`` is 0 when no edge is seen.

        """
        c = self.config
        n = len(self._model)
        weight = np.ones(n + 2)
        weight[n:] = c.end_weight
        fx, fy, b = stereo.fx, stereo.fy, stereo.baseline
        (index, dirs_l, offset_l, valid_l), (_, dirs_r, offset_r, valid_r) = self._profiles(
            T, stereo, fields, hidden)
        # both images' seen edges at once, the left's rows first (each row's arithmetic is its
        # own)
        k_l = int(np.count_nonzero(valid_l))
        if not k_l + np.count_nonzero(valid_r):
            return np.zeros((0, 6)), np.zeros(0), np.zeros(0)
        seen = np.concatenate([index[valid_l], index[valid_r]])
        points = self._model[seen] @ T[:3, :3].T + T[:3, 3]
        lever = points - T[:3, 3]
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        zeros = np.zeros_like(z)
        shift = np.zeros_like(z)
        shift[k_l:] = fx * b
        du = np.column_stack([fx / z, zeros, (-fx * x + shift) / z ** 2])
        dv = np.column_stack([zeros, fy / z, -fy * y / z ** 2])
        d = np.concatenate([dirs_l[valid_l], dirs_r[valid_r]])
        g = d[:, :1] * du + d[:, 1:] * dv  # d(offset along the direction)/dX
        # dX/domega = -[lever]_x, dX/dtau = I; lever x g by its components (np.cross's
        # products and differences, without its axis handling on this hot path)
        lx, ly, lz = lever[:, 0], lever[:, 1], lever[:, 2]
        gx, gy, gz = g[:, 0], g[:, 1], g[:, 2]
        rows = np.column_stack([ly * gz - lz * gy, lz * gx - lx * gz, lx * gy - ly * gx, g])
        r = np.concatenate([offset_l[valid_l], offset_r[valid_r]])
        w = np.concatenate([weight[valid_l], weight[valid_r]])
        return rows, r, w * np.minimum(1.0, c.huber / np.maximum(np.abs(r), 1e-9))

    def _refine(self, T: np.ndarray, stereo: StereoModel, fields: Fields,
                hidden: np.ndarray) -> np.ndarray:
        """Gauss-Newton on the edges' offsets (Huber weights); returns the pose."""
        T = T.copy()
        for _ in range(self.config.refine_iterations):
            J, r, w = self.edge_rows(T, stereo, fields, hidden)
            if not len(r):
                break
            step = _gauss_newton_step(J, r, w)
            T[:3, :3] = rotvec_matrix(step[:3]) @ T[:3, :3]
            T[:3, 3] = T[:3, 3] + step[3:]
            if np.linalg.norm(step[3:]) < 2e-6 and np.linalg.norm(step[:3]) < 2e-4:
                break
        return T

    def fit_grasp(self, views: Sequence[HeldView], stereo: StereoModel,
                  T_tool_needle: ArrayLike, offsets: int = 0,
                  offset_sigma: float = 0.05,
                  offset_prior: ArrayLike | None = None) -> GraspFit:
        """
        Fit the grasp ``T_tool_needle`` to several stereo pairs of one grasp at once.

        Seen nearly face on, a needle's tilt across the line of sight hardly changes one pair's
        images (a lying needle on a sloping pad can be 10-15 degrees off and fit as well as
        the truth). The grasp is the same in every pair while the tool turns the needle
        between them, so the tilt one pair cannot see another shows: the edges of all pairs
        are fitted together (Gauss-Newton on the tool-frame grasp).

        With ``offsets``, the wrist's own joint offsets are fitted too: the pairs whose view
        has ``tool_at`` see the tool where its wrist joints are ``offsets`` (rad) more than
        believed. A grasp alone takes up a wrist offset at one wrist pose only; pairs of other
        wrist poses tell the two apart (the needle, a 10 mm lever, turns with the wrist).

        Parameters
        ----------
        views : sequence of HeldView
            The pairs, each with the holding tool's pose (camera frame); a pair taken before
            the grasp (the needle lying where the jaw then closed) gives the tool's pose at the
            grasp.
        stereo : suture_lfd.perception.stereo.StereoModel
        T_tool_needle : array_like, shape (4, 4)
            Starting grasp.
        offsets : int
            How many wrist offsets to fit with the grasp (0: the grasp alone).
        offset_sigma : float
            Prior spread (rad) of each offset about ``offset_prior``: an offset this far costs
            as much as every edge a quarter of a pixel further off (a pull that keeps offsets
            the poses hardly tell near the prior, and gives way to what they tell well).
        offset_prior : array_like, shape (offsets,), optional
            The offsets' prior centre (default 0).

        Returns
        -------
        GraspFit

        Raises
        ------
        ValueError
            When an image is not uint8 RGB of the camera's size, or a pose is not 4x4.

        """
        c = self.config
        G = _pose(T_tool_needle, 'grasp').copy()
        k = int(offsets)
        delta = np.zeros(k)
        centre = np.zeros(k) if offset_prior is None else np.asarray(offset_prior, dtype=float)
        prepared = []
        for v in views:
            fields, capsules = self._seen(v.left, v.right, stereo, v.tools)
            prepared.append((fields, _pose(v.T_camera_tool, 'tool pose'), capsules,
                             v.tool_at if k else None))

        def hidden(T: np.ndarray, capsules: list[Any]) -> np.ndarray:
            return hidden_in_images(self._model @ T[:3, :3].T + T[:3, 3], capsules, stereo)

        def tool(T_ct: np.ndarray, tool_at: Any) -> np.ndarray:
            return T_ct if tool_at is None else _pose(tool_at(delta), 'tool pose')

        for _ in range(c.refine_iterations):
            rows, rhs, weights = [], [], []
            for fields, T_ct, capsules, tool_at in prepared:
                T_ct = tool(T_ct, tool_at)
                T = T_ct @ G
                J, r, w = self.edge_rows(T, stereo, fields, hidden(T, capsules))
                R = T_ct[:3, :3]  # a tool-frame change of the grasp, seen in this camera
                columns = [J[:, :3] @ R, J[:, 3:] @ R]
                if k:
                    columns.append(_offset_columns(J, T_ct, G, tool_at, delta))
                rows.append(np.hstack(columns))
                rhs.append(r)
                weights.append(w)
            if k:  # the prior: each offset about its centre, spread offset_sigma
                n = sum(len(r) for r in rhs)
                rows.append(np.hstack([np.zeros((k, 6)), np.eye(k) / offset_sigma]))
                rhs.append((centre - delta) / offset_sigma)
                weights.append(np.full(k, 0.0625 * max(n, 1)))
            J, r = np.vstack(rows), np.concatenate(rhs)
            if len(r) <= k:
                break
            step = _gauss_newton_step(J, r, np.concatenate(weights))
            G[:3, :3] = rotvec_matrix(step[:3]) @ G[:3, :3]
            G[:3, 3] = G[:3, 3] + step[3:6]
            delta = delta + step[6:]
            if (np.linalg.norm(step[3:6]) < 2e-6 and np.linalg.norm(step[:3]) < 2e-4
                    and np.all(np.abs(step[6:]) < 2e-4)):
                break
        scores = []
        for fields, T_ct, capsules, tool_at in prepared:
            T = tool(T_ct, tool_at) @ G
            residual, share, _, _ = self._score(T, stereo, fields, hidden(T, capsules))
            scores.append((residual, share))
        return GraspFit(T_tool_needle=G, residual_px=tuple(k[0] for k in scores),
                        visible_share=tuple(k[1] for k in scores), offsets=delta)

    def _score(self, T: np.ndarray, stereo: StereoModel, fields: Fields,
               hidden: np.ndarray) -> tuple[float, float, float, float]:
        """Residual (px), visible shares (both, left, right) of a pose."""
        points = self._model @ T[:3, :3].T + T[:3, 3]
        if np.any(points[:, 2] <= 1e-4):
            return math.inf, 0.0, 0.0, 0.0
        (_, _, off_l, ok_l), (_, _, off_r, ok_r) = self._profiles(T, stereo, fields, hidden)
        n = len(self._model)
        off_l, ok_l, off_r, ok_r = off_l[:n], ok_l[:n], off_r[:n], ok_r[:n]
        both = ok_l & ok_r
        share_l, share_r = ok_l.sum() / n, ok_r.sum() / n
        if not both.any():
            return math.inf, 0.0, share_l, share_r
        off = np.concatenate([off_l[both], off_r[both]])
        return float(np.sqrt(np.mean(off ** 2))), both.sum() / n, share_l, share_r

    def _thread_near_tail(self, T: np.ndarray, stereo: StereoModel, fields: Fields) -> int:
        """Thread pixels near the tail minus near the tip, both images (a count)."""
        g = self.geometry
        ends = np.array([g.tail, g.tip]) @ T[:3, :3].T + T[:3, 3]
        if np.any(ends[:, 2] <= 1e-4):
            return 0
        radius = max(3, int(round(0.002 * stereo.fx / ends[:, 2].mean())))
        score = 0
        for field, uv in zip(fields, stereo.project(ends)):
            h, w = field.thread.shape
            counts = []
            for u, v in uv:
                u0, v0 = int(round(u)), int(round(v))
                if not (0 <= u0 < w and 0 <= v0 < h):
                    counts.append(0)
                    continue
                window = field.thread[max(0, v0 - radius):v0 + radius + 1,
                                      max(0, u0 - radius):u0 + radius + 1]
                counts.append(int(np.count_nonzero(window)))
            score += counts[0] - counts[1]
        return score

    # ------------------------------------------------------------------ detection
    def _blobs(self, field: WireImage, stereo: StereoModel) -> list[np.ndarray]:
        """End, end and bulge pixels (3, 2) of the elongated needle blobs, largest first."""
        c = self.config
        mask = (field.mask > 0).astype(np.uint8)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        order = np.argsort(-stats[1:, cv2.CC_STAT_AREA]) + 1
        blobs: list[np.ndarray] = []
        for label in order:
            if stats[label, cv2.CC_STAT_AREA] < c.min_blob_area or len(blobs) == 2:
                break  # the two largest elongated blobs (an instrument's metal is not one)
            x, y, w, h = stats[label, :4]
            sub = labels[y:y + h, x:x + w] == label
            vs, us = np.nonzero(sub)
            pts = np.column_stack([us + x, vs + y]).astype(float)
            a = pts[np.argmax(np.sum((pts - pts.mean(axis=0)) ** 2, axis=1))]
            b = pts[np.argmax(np.sum((pts - a) ** 2, axis=1))]
            length = float(np.linalg.norm(b - a))
            width = 2.0 * float(np.max(cv2.distanceTransform(sub.astype(np.uint8), cv2.DIST_L2,
                                                              3)))
            if length < c.min_elongation * max(width, 1.0):
                continue
            ab = (b - a) / max(length, 1e-9)
            normal = np.array([-ab[1], ab[0]])
            offset = (pts - a) @ normal
            bulge = pts[np.argmax(np.abs(offset))]
            blobs.append(np.array([a, b, bulge]))
        return blobs

    def _detections(self, stereo: StereoModel, fields: Fields) -> list[np.ndarray]:
        """Start poses from triangulated blob ends and bulges, each both ways round."""
        g = self.geometry
        model = g.point_at(np.array([0.0, 1.0, 0.5]))
        starts = []
        for bl in self._blobs(fields[0], stereo):
            for br in self._blobs(fields[1], stereo):
                for right in (br, br[[1, 0, 2]]):
                    if np.abs(bl[:2, 1] - right[:2, 1]).max() > 6.0:
                        continue
                    points = stereo.triangulate(bl, right)
                    if not np.all(np.isfinite(points)) or np.any(points[:, 2] <= 0.0):
                        continue
                    chord = np.linalg.norm(points[1] - points[0])
                    if not 0.5 * g.chord < chord < 1.5 * g.chord:
                        continue
                    starts.append(kabsch(model, points))
        return starts

    def _laid_starts(self, stereo: StereoModel, fields: Fields, normal: np.ndarray,
                     point: np.ndarray) -> list[np.ndarray]:
        """
        Start poses from the left image's blobs laid flat on the support's plane.

        The rays through a blob's ends and bulge meet the plane ``normal . X = normal . point``
        raised by the wire's radius (``normal`` towards the camera) where a needle lying on
        it would put its tail, tip and middle.
        """
        g = self.geometry
        model = g.point_at(np.array([0.0, 1.0, 0.5]))
        level = float(normal @ point) + 0.5 * g.wire_diameter
        starts = []
        for blob in self._blobs(fields[0], stereo):
            rays = np.column_stack([(blob[:, 0] - stereo.cx) / stereo.fx,
                                    (blob[:, 1] - stereo.cy) / stereo.fy, np.ones(len(blob))])
            along = rays @ normal
            if np.any(along * level <= 0.0):
                continue  # a ray that does not meet the plane in front of the camera
            points = rays * (level / along)[:, None]
            chord = float(np.linalg.norm(points[1] - points[0]))
            if not 0.5 * g.chord < chord < 1.5 * g.chord:
                continue
            starts.append(kabsch(model, points))
        return starts

    # ------------------------------------------------------------------ the estimate
    def estimate(self, left: np.ndarray, right: np.ndarray, stereo: StereoModel,
                 prior: ArrayLike | None = None, tools: Sequence[ArrayLike] = (),
                 support_normal: ArrayLike | None = None, search: int = 0,
                 support_point: ArrayLike | None = None,
                 expected: ArrayLike | None = None) -> NeedleEstimate:
        """
        Estimate the needle's pose in the camera frame from a rectified stereo pair.

        Parameters
        ----------
        left, right : ndarray, shape (height, width, 3), uint8
            RGB images of the left and right cameras (nothing else of the scene is used).
        stereo : suture_lfd.perception.stereo.StereoModel
            The pair's calibration (``camera_info``).
        prior : array_like, shape (4, 4), optional
            Where the needle is thought to be (``T_camera_needle``): the tool pose times the
            grasp while held, the last estimate while it lies free; None: detect it.
        tools : sequence of array_like, shape (4, 4)
            Tool-tip poses (camera frame) of the instruments near the needle: the arc where
            their jaws, wrist or shaft cover it in an image is not looked for there.
        support_normal : array_like, shape (3,), optional
            Normal (camera frame) of the surface a free needle lies on, e.g.
            :attr:`suture_lfd.perception.markers.MarkerDetections.normal`: of the poses that
            fit the images alike, one whose plane is within ``max_support_tilt`` of it is
            taken. Without it (and without a prior) such a tie is "not found".
        support_point : array_like, shape (3,), optional
            A point (camera frame) of that surface, e.g. the markers' centroid: with
            ``support_normal``, detection also starts from the needle's blobs laid flat on
            the surface's plane, and takes those fits when the images clearly prefer one (a
            start triangulated from the blobs' ends alone can be tens of degrees off, seen
            nearly face on, and settle in a fit 5-8 mm off at the tip).
        search : int
            With a prior: also start from the prior moved to where the images show the needle
            within this many pixels (:func:`suture_lfd.perception.reacquire.shifted_priors`),
            to re-acquire a needle lost by tracking; 0: from the prior only.
        expected : array_like, shape (4, 4), optional
            Without a prior, where a needle lying free is expected (``T_camera_needle``, e.g.
            a scene's layout, a millimetre or so and some degrees off): with
            ``support_normal`` and ``support_point``, detection starts only from the left
            image's blobs laid on the surface (either way round) whose arc is within
            :attr:`expected_reach` of it and whose plane faces as its does, not from every
            triangulated blob and its mirror; when none is, it detects as without it. The
            blobs are laid on the surface's plane and on the expected pose's own.

        Returns
        -------
        NeedleEstimate

        Raises
        ------
        ValueError
            When an image is not uint8 RGB of the camera's size, or a pose is not 4x4.

        """
        c = self.config
        fields, capsules = self._seen(left, right, stereo, tools)
        normal: np.ndarray | None = None
        if support_normal is not None:
            normal = np.asarray(support_normal, dtype=float).reshape(3)
            normal = normal / np.linalg.norm(normal)
        points = None
        laid = None
        if prior is None and expected is not None and normal is not None \
                and support_point is not None:
            laid = self._expected_starts(stereo, fields, normal, np.asarray(
                support_point, dtype=float).reshape(3), _pose(expected, 'expected pose'))
        if laid:
            starts = laid
        elif prior is not None:
            starts = [_pose(prior, 'prior')]
            if search > 0:
                starts += shifted_priors(starts[0], (fields[0].mask, fields[1].mask), stereo,
                                         self._model, self.geometry.wire_diameter, int(search))
        else:
            starts = self._detections(stereo, fields)
            if not starts:
                return NeedleEstimate(found=False, pose_camera=None, residual_px=math.inf,
                                      visible_share=0.0, reason='no needle-like blob in both '
                                                                'images')
            # each detection and its mirror: the images tell them apart by a fraction of a
            # pixel only
            none = np.zeros((2, len(self._model)), bool)
            starts = [self._refine(self._fit(T0, stereo, fields, none), stereo, fields, none)
                      for T0 in starts]
            starts += [mirrored(T) for T in starts]
            if c.centre_line:
                # seen nearly face on, a tilt across the line of sight hardly changes the
                # images (both fits above may be off by it): the wire's depth, triangulated
                # where it crosses the rows steeply, fixes the plane; the edges then refine it
                wire_px = self.geometry.wire_diameter * stereo.fx / max(
                    float(np.median([T[2, 3] for T in starts])), 1e-3)
                points = centre_line_points(fields[0].mask, fields[1].mask, stereo,
                                            int(2.0 * wire_px) + 1)
                if len(points) >= c.min_stereo_points:
                    starts = [self._refine(fit_arc_to_points(T, points, self.geometry),
                                           stereo, fields, none) for T in starts]
                else:
                    points = None
        candidates = self._candidates(starts, stereo, fields, capsules, points)
        if normal is not None:
            # a needle lying free lies on the tissue: its plane near the surface's
            if prior is None and support_point is not None and not laid:
                candidates += self._laid_candidates(stereo, fields, capsules, points,
                                                    candidates, normal, np.asarray(
                                                        support_point, dtype=float).reshape(3))
            on_surface = self._on_surface(candidates, normal)
            candidates = on_surface or candidates
        candidates.sort(key=lambda k: (not k[0], k[1]))
        _, cost, T, residual, share, share_l, share_r = candidates[0]
        reason = ''
        apart = math.inf
        if prior is None:
            rivals = [k for k in candidates[1:] if k[0] and k[1] <= cost + c.ambiguity
                      and self.arc_distance(k[2], T) > c.ambiguity_distance]
            if rivals and c.ends_margin > 0.0:
                best, rivals = self._by_ends(T, rivals, stereo, fields)
                if best is not T:
                    _, cost, T, residual, share, share_l, share_r = next(
                        k for k in candidates if k[2] is best)
            # the flip of the best fit fits the images as well: the thread says which end
            # is the tail
            flipped = T @ self._flip
            if self._thread_near_tail(flipped, stereo, fields) > self._thread_near_tail(
                    T, stereo, fields):
                T = flipped
            if rivals:
                apart = self.arc_distance(rivals[0][2], T)
                reason = (f'ambiguous: another pose {apart * 1e3:.1f} mm away fits the images '
                          f'as well (cost {rivals[0][1]:.2f} against {cost:.2f} px)')
        if share < c.min_visible:
            reason = (f'too little of the needle seen in both images ({share:.0%} < '
                      f'{c.min_visible:.0%})')
        elif residual > c.max_residual:
            reason = f'the arc does not fit the images (residual {residual:.2f} px)'
        return NeedleEstimate(found=not reason, pose_camera=T, residual_px=residual,
                              visible_share=float(share), visible_left=float(share_l),
                              visible_right=float(share_r),
                              partial=bool(share < c.partial_below), reason=reason,
                              rival_distance=apart if reason.startswith('ambiguous') else math.inf)

    #: m: a start laid on the surface is taken near an expected pose within this (mean of
    #: tail, middle and tip, either way round): a layout's millimetre and the yaw's degrees
    expected_reach = 0.004

    def _expected_starts(self, stereo: StereoModel, fields: Fields, normal: np.ndarray,
                         point: np.ndarray, expected: np.ndarray) -> list[np.ndarray]:
        """
        Return the blobs laid near ``expected`` on two planes, each the way round it faces.

        The planes: the surface's (``normal``, ``point``) and the expected needle's own (a
        layout's tilt of the surface under it, which on a curved pad the markers' plane misses
        by degrees; where the layout's tilt is wrong, the surface's start fits better).
        """
        own = expected[:3, 2] if expected[:3, 2] @ expected[:3, 3] < 0.0 else -expected[:3, 2]
        laid = self._laid_starts(stereo, fields, normal, point) + self._laid_starts(
            stereo, fields, own, expected[:3, 3] - 0.5 * self.geometry.wire_diameter * own)
        starts = []
        for T in laid:
            if self.arc_distance(T, expected) > self.expected_reach:
                continue
            # tail and tip the other way round turn the plane over: keep the one facing as
            # the expected pose does
            flipped = T @ self._flip
            starts.append(T if T[:3, 2] @ expected[:3, 2] >= flipped[:3, 2] @ expected[:3, 2]
                          else flipped)
        return starts

    def _candidates(self, starts: list[np.ndarray], stereo: StereoModel, fields: Fields,
                    capsules: list[Any], points: np.ndarray | None) -> list[tuple[Any, ...]]:
        """Refine each start; ``(trusted, cost, T, residual, share, share_l, share_r)`` each."""
        c = self.config
        candidates = []
        for T in starts:
            hidden = hidden_in_images(self._model @ T[:3, :3].T + T[:3, 3], capsules, stereo)
            T = self._refine(T, stereo, fields, hidden)
            hidden = hidden_in_images(self._model @ T[:3, :3].T + T[:3, 3], capsules, stereo)
            residual, share, share_l, share_r = self._score(T, stereo, fields, hidden)
            trusted = share >= c.min_visible and residual <= c.max_residual
            # the closest fit, a hidden tenth of the arc counting as 0.2 px
            cost = residual + 2.0 * (1.0 - share)
            if points is not None:
                # and off the triangulated wire: px per mm of the points' median distance
                cost += c.stereo_weight * 1e3 * float(np.median(arc_distances(
                    T, points, self.geometry)))
            candidates.append((trusted, cost, T, residual, share, share_l, share_r))
        return candidates

    def _laid_candidates(self, stereo: StereoModel, fields: Fields, capsules: list[Any],
                         points: np.ndarray | None, candidates: list[tuple[Any, ...]],
                         normal: np.ndarray, point: np.ndarray) -> list[tuple[Any, ...]]:
        """
        Return the fits started from the blobs laid on the surface's plane, if one is better.

        They count only when one of them, trusted and on the surface, costs less by
        ``ambiguity`` than every trusted fit on the surface from the triangulated starts
        (or there is none): otherwise the images do not prefer them, and as rivals a
        millimetre away they would only make a good detection ambiguous.
        """
        none = np.zeros((2, len(self._model)), bool)
        laid = [self._refine(T0, stereo, fields, none)
                for T0 in self._laid_starts(stereo, fields, normal, point)]
        found = self._candidates(laid + [mirrored(T) for T in laid], stereo, fields,
                                 capsules, points)

        def best(ks: list[tuple[Any, ...]]) -> float:
            return min((k[1] for k in self._on_surface(ks, normal) if k[0]), default=math.inf)

        return found if best(found) < best(candidates) - self.config.ambiguity else []

    def _on_surface(self, candidates: list[tuple[Any, ...]],
                    normal: np.ndarray) -> list[tuple[Any, ...]]:
        """Return the candidates whose plane is within ``max_support_tilt`` of the surface's."""
        cos = math.cos(self.config.max_support_tilt)
        return [k for k in candidates if abs(k[2][:3, 2] @ normal) >= cos]

    def _seen_ends(self, stereo: StereoModel, fields: Fields) -> np.ndarray | None:
        """Return the wire's two ends triangulated from each image's largest blob, (2, 3) m."""
        left, right = self._blobs(fields[0], stereo), self._blobs(fields[1], stereo)
        if not (left and right):
            return None
        a, b = left[0][:2], right[0][:2]
        if np.abs(a[:, 1] - b[:, 1]).max() > np.abs(a[:, 1] - b[::-1, 1]).max():
            b = b[::-1]  # the ends paired by their rows (rectified images)
        if np.abs(a[:, 1] - b[:, 1]).max() > 6.0:
            return None
        ends = stereo.triangulate(a, b)
        if not np.all(np.isfinite(ends)) or np.any(ends[:, 2] <= 0.0):
            return None
        return ends

    def _by_ends(self, T: np.ndarray, rivals: list[Any], stereo: StereoModel, fields: Fields
                 ) -> tuple[np.ndarray, list[Any]]:
        """
        Settle a tie of ``T`` and its ``rivals`` by the wire's triangulated ends.

        Poses that fit the images within a fraction of a pixel (a lying needle's tilt either
        way across the line of sight) put their arc's ends at different depths by a millimetre
        or more; the ends of the wire's pixels, triangulated, say which. Returns the pose whose
        ends lie closest, with no rivals when it is closer than every other by ``ends_margin``;
        otherwise ``T`` and ``rivals`` unchanged.
        """
        seen = self._seen_ends(stereo, fields)
        if seen is None:
            return T, rivals
        g = self.geometry
        poses = [T] + [k[2] for k in rivals]
        gaps = []
        for P in poses:
            ends = np.array([g.tail, g.tip]) @ P[:3, :3].T + P[:3, 3]
            gaps.append(min(float(np.linalg.norm(ends - seen, axis=1).mean()),
                            float(np.linalg.norm(ends - seen[::-1], axis=1).mean())))
        order = np.argsort(gaps)
        if gaps[order[1]] - gaps[order[0]] < self.config.ends_margin:
            return T, rivals
        return poses[int(order[0])], []

    def arc_distance(self, T_a: np.ndarray, T_b: np.ndarray) -> float:
        """Mean distance (m) of the arcs' base, middle and tip, tail and tip either way."""
        p = self.geometry.point_at(np.array([0.0, 0.5, 1.0]))
        a = p @ T_a[:3, :3].T + T_a[:3, 3]
        b = p @ T_b[:3, :3].T + T_b[:3, 3]
        same = np.linalg.norm(a - b, axis=1).mean()
        swapped = np.linalg.norm(a - b[::-1], axis=1).mean()
        return float(min(same, swapped))


def _gauss_newton_step(J: np.ndarray, r: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Return the weighted least-squares step of rows ``J`` to offsets ``r`` (damped a little)."""
    A = J.T @ (w[:, None] * J)
    A += 1e-6 * np.trace(A) * np.eye(len(A))
    return np.linalg.solve(A, J.T @ (w * r))


def _offset_columns(J: np.ndarray, T_ct: np.ndarray, G: np.ndarray, tool_at: Any,
                    delta: np.ndarray, eps: float = 1e-4) -> np.ndarray:
    """
    Columns of the edge rows ``J`` (needle pose, camera frame) for the wrist offsets ``delta``.

    A wrist offset turns and shifts the tool in its own frame, by the twist ``(w, u)`` per
    radian (a finite difference of ``tool_at``); a tool-frame point ``x`` moves by
    ``w x x + u``, the needle's pose (rotation about its origin, translation; camera frame) by
    ``R w`` and ``R u + (R w) x (R g)``, ``R`` the tool's rotation and ``g`` the grasp's origin.
    """
    out = np.zeros((len(J), len(delta)))
    if tool_at is None:
        return out
    R, g = T_ct[:3, :3], T_ct[:3, :3] @ G[:3, 3]
    inv = np.linalg.inv(T_ct)
    for i in range(len(delta)):
        moved = delta.copy()
        moved[i] += eps
        D = inv @ np.asarray(tool_at(moved), dtype=float)
        w = R @ Rotation.from_matrix(D[:3, :3]).as_rotvec() / eps
        v = R @ D[:3, 3] / eps + np.cross(w, g)
        out[:, i] = J[:, :3] @ w + J[:, 3:] @ v
    return out


def _pose(T: ArrayLike, what: str) -> np.ndarray:
    array = np.asarray(T, dtype=float)
    if array.shape != (4, 4) or not np.all(np.isfinite(array)):
        raise ValueError(f'{what} must be a finite 4x4 transform, got shape {array.shape}')
    return array
