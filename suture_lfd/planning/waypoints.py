"""
Timed motion segments with minimum-jerk time scaling, for tool poses, needle paths and jaws.

A segment runs from ``t0`` to ``t1`` (s). Its phase ``u = (t - t0) / (t1 - t0)`` is mapped
through the minimum-jerk profile ``sigma = 10 u^3 - 15 u^4 + 6 u^5`` (zero velocity and
acceleration at both ends). Positions interpolate linearly in ``sigma``, orientations along the
geodesic (constant axis), needle rotations about the arc centre in angle.

- :class:`ToolMove`: a tool-tip pose from ``A`` to ``B`` (world frame) and a jaw angle.
- :class:`NeedleMove`: the tool carries the needle along a needle path; the tool pose is
  ``T_world_needle(sigma) @ inv(T_tool_needle)`` for the grasp ``T_tool_needle``.
- Needle paths: :class:`RigidPath` (straight line and geodesic between two needle poses) and
  :class:`ArcPath` (rotation about the needle's arc centre, through
  :class:`suture_lfd.planning.throw_geometry.ThrowArc`).

Poses are 4x4 homogeneous matrices (world frame, metres); angles in radians.
"""

import math
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import invert_transform

if TYPE_CHECKING:
    from suture_lfd.planning.throw_geometry import ThrowArc


def minimum_jerk(u: float) -> float:
    """
    Minimum-jerk profile ``10 u^3 - 15 u^4 + 6 u^5`` on [0, 1] (clamped outside).

    Parameters
    ----------
    u : float
        Normalised time.

    Returns
    -------
    float
        Normalised position in [0, 1].

    """
    u = min(1.0, max(0.0, u))
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


def rotation_log(R: ArrayLike) -> np.ndarray:
    """
    Rotation vector (axis times angle, rad) of a rotation matrix.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Rotation matrix.

    Returns
    -------
    ndarray, shape (3,)

    """
    R = np.asarray(R, dtype=float)
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    c = max(-1.0, min(1.0, 0.5 * (r00 + r11 + r22 - 1.0)))  # the trace summed as numpy does
    angle = math.acos(c)
    w = np.array([r21 - r12, r02 - r20, r10 - r01])
    if angle < 1e-9:
        return 0.5 * w
    if math.pi - angle < 1e-6:
        # Near 180 deg: the axis is the dominant column of R + I.
        M = R + np.eye(3)
        k = int(np.argmax(np.linalg.norm(M, axis=0)))
        axis = M[:, k] / np.linalg.norm(M[:, k])
        return angle * axis
    return angle / (2.0 * math.sin(angle)) * w


def rotation_exp(w: ArrayLike) -> np.ndarray:
    """
    Rotation matrix of a rotation vector (Rodrigues).

    Parameters
    ----------
    w : array_like, shape (3,)
        Axis times angle (rad).

    Returns
    -------
    ndarray, shape (3, 3)

    """
    w = np.asarray(w, dtype=float)
    angle = math.sqrt(w.dot(w))  # numpy.linalg.norm of a vector, without its checks
    if angle < 1e-12:
        return np.eye(3)
    k0, k1, k2 = (w / angle).tolist()
    K = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


class NeedlePath(Protocol):
    """
    A path of poses over ``sigma`` in [0, 1].

    :class:`RigidPath`, :class:`ArcPath` or a sampled one (a DMP rollout).
    """

    @property
    def A(self) -> np.ndarray:  # noqa: N802 (pose names follow the project's T_a_b style)
        """Start pose (4, 4)."""

    @property
    def B(self) -> np.ndarray:  # noqa: N802
        """End pose (4, 4)."""

    @property
    def angle(self) -> float:
        """Rotation angle (rad)."""

    @property
    def distance(self) -> float:
        """Distance (m) travelled."""

    def __call__(self, sigma: float) -> np.ndarray:
        """Return the pose (4, 4) at path parameter ``sigma``."""


class PoseInterpolator:
    """
    Straight-line position and constant-axis rotation between two poses.

    Parameters
    ----------
    A, B : array_like, shape (4, 4)
        Start and end poses.

    """

    def __init__(self, A: ArrayLike, B: ArrayLike) -> None:
        self.A = np.array(A, dtype=float)
        self.B = np.array(B, dtype=float)
        self._dp = self.B[:3, 3] - self.A[:3, 3]
        self._w = rotation_log(self.A[:3, :3].T @ self.B[:3, :3])
        self._still: np.ndarray | None = None
        if not self._dp.any() and float(np.linalg.norm(self._w)) < 1e-12:
            # A pose held still: every sigma below 1 gives the pose at sigma 0 (the rotation
            # vector sigma * w is below rotation_exp's 1e-12 for every sigma <= 1, and
            # sigma * 0 adds nothing), so it is computed once.
            self._still = self._at(0.0)

    @property
    def distance(self) -> float:
        """Translation length (m)."""
        return float(np.linalg.norm(self._dp))

    @property
    def angle(self) -> float:
        """Rotation angle (rad)."""
        return float(np.linalg.norm(self._w))

    def __call__(self, sigma: float) -> np.ndarray:
        """
        Pose at path parameter ``sigma`` in [0, 1].

        Parameters
        ----------
        sigma : float
            Path parameter.

        Returns
        -------
        ndarray, shape (4, 4)

        """
        if sigma >= 1.0:
            return self.B.copy()
        if self._still is not None:
            return self._still.copy()
        return self._at(sigma)

    def _at(self, sigma: float) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.A[:3, :3] @ rotation_exp(sigma * self._w)
        T[:3, 3] = self.A[:3, 3] + sigma * self._dp
        return T

    def many(self, sigmas: ArrayLike) -> np.ndarray:
        """
        Poses at many path parameters in [0, 1) at once.

        Parameters
        ----------
        sigmas : array_like, shape (n,)
            Path parameters below 1.

        Returns
        -------
        ndarray, shape (n, 4, 4)
            The poses ``self(sigma)`` (to rounding).

        """
        sigmas = np.asarray(sigmas, dtype=float)
        T = np.zeros((sigmas.size, 4, 4))
        T[:, 3, 3] = 1.0
        angle = float(np.linalg.norm(self._w))
        if angle < 1e-12:
            T[:, :3, :3] = self.A[:3, :3]
        else:
            k = self._w / angle
            K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
            a = sigmas * angle
            R = (np.eye(3) + np.sin(a)[:, None, None] * K
                 + (1.0 - np.cos(a))[:, None, None] * (K @ K))
            T[:, :3, :3] = self.A[:3, :3] @ R
        T[:, :3, 3] = self.A[:3, 3] + sigmas[:, None] * self._dp
        return T


class RigidPath(PoseInterpolator):
    """Needle path: straight line and geodesic rotation between two needle poses."""


class ArcPath:
    """
    Needle path: rotation about the needle's arc centre from ``alpha_a`` to ``alpha_b``.

    Parameters
    ----------
    arc : suture_lfd.planning.throw_geometry.ThrowArc
        The throw circle.
    alpha_a, alpha_b : float
        Start and end angle (rad); decreasing drives the needle forwards.

    """

    def __init__(self, arc: 'ThrowArc', alpha_a: float, alpha_b: float) -> None:
        self.arc = arc
        self.alpha_a = float(alpha_a)
        self.alpha_b = float(alpha_b)

    @property
    def A(self) -> np.ndarray:  # noqa: N802 (pose names follow the project's T_a_b style)
        """Start needle pose (4, 4)."""
        return self.arc.T_world_needle(self.alpha_a)

    @property
    def B(self) -> np.ndarray:  # noqa: N802
        """End needle pose (4, 4)."""
        return self.arc.T_world_needle(self.alpha_b)

    @property
    def angle(self) -> float:
        """Rotation angle (rad)."""
        return abs(self.alpha_b - self.alpha_a)

    @property
    def distance(self) -> float:
        """Largest distance (m) travelled by a needle point."""
        return self.arc.needle.radius * self.angle

    def alpha(self, sigma: float) -> float:
        """Angle (rad) at path parameter ``sigma``."""
        return self.alpha_a + sigma * (self.alpha_b - self.alpha_a)

    def __call__(self, sigma: float) -> np.ndarray:
        """
        Needle pose at path parameter ``sigma`` in [0, 1].

        Parameters
        ----------
        sigma : float
            Path parameter.

        Returns
        -------
        ndarray, shape (4, 4)

        """
        return self.arc.T_world_needle(self.alpha(min(1.0, sigma)))


class ToolMove:
    """
    Tool-tip pose and jaw angle moving from one value to another with minimum jerk.

    Parameters
    ----------
    t0, t1 : float
        Start and end time (s).
    A, B : array_like, shape (4, 4)
        Tool-tip poses ``T_world_tool`` at ``t0`` and ``t1``.
    jaw0, jaw1 : float
        Jaw angles (rad) at ``t0`` and ``t1``.

    """

    carries_needle = False

    def __init__(self, t0: float, t1: float, A: ArrayLike, B: ArrayLike, jaw0: float,
                 jaw1: float) -> None:
        self.t0 = float(t0)
        self.t1 = float(t1)
        self.path: NeedlePath = PoseInterpolator(A, B)
        self.jaw0 = float(jaw0)
        self.jaw1 = float(jaw1)

    def sigma(self, t: float) -> float:
        """Minimum-jerk path parameter at time ``t`` (s)."""
        if self.t1 <= self.t0:
            return 1.0
        return minimum_jerk((t - self.t0) / (self.t1 - self.t0))

    def tool(self, t: float, T_tool_needle: np.ndarray | None = None) -> np.ndarray:
        """
        Tool-tip pose ``T_world_tool`` (4, 4) at time ``t`` (s).

        Parameters
        ----------
        t : float
            Time (s).
        T_tool_needle : array_like, shape (4, 4), optional
            Unused (the tool does not carry the needle).

        Returns
        -------
        ndarray, shape (4, 4)

        """
        return self.path(self.sigma(t))

    def jaw(self, t: float) -> float:
        """Jaw angle (rad) at time ``t`` (s)."""
        return self.jaw0 + self.sigma(t) * (self.jaw1 - self.jaw0)

    def needle(self, t: float) -> np.ndarray | None:
        """Needle pose carried by this segment (None: it carries none)."""
        return None


class NeedleMove(ToolMove):
    """
    The tool carries the needle along a needle path.

    Parameters
    ----------
    t0, t1 : float
        Start and end time (s).
    path : NeedlePath
        Needle pose as a function of the path parameter.
    T_tool_needle : array_like, shape (4, 4)
        Planned grasp (tool-tip frame <- needle frame).
    jaw0, jaw1 : float
        Jaw angles (rad) at ``t0`` and ``t1`` (``jaw1`` defaults to ``jaw0``).

    """

    carries_needle = True

    def __init__(self, t0: float, t1: float, path: NeedlePath,
                 T_tool_needle: ArrayLike, jaw0: float, jaw1: float | None = None) -> None:
        self.t0 = float(t0)
        self.t1 = float(t1)
        self.path = path
        self.grasp = np.array(T_tool_needle, dtype=float)
        self._inv = invert_transform(self.grasp)
        self._measured: np.ndarray | None = None
        self._measured_inv: np.ndarray | None = None
        self.jaw0 = float(jaw0)
        self.jaw1 = self.jaw0 if jaw1 is None else float(jaw1)

    def needle(self, t: float) -> np.ndarray:
        """Planned needle pose ``T_world_needle`` (4, 4) at time ``t`` (s)."""
        return self.path(self.sigma(t))

    def tool(self, t: float, T_tool_needle: np.ndarray | None = None) -> np.ndarray:
        """
        Tool-tip pose carrying the needle at time ``t`` (s).

        Parameters
        ----------
        t : float
            Time (s).
        T_tool_needle : array_like, shape (4, 4), optional
            Measured grasp to use instead of the planned one; its inverse is kept for the next
            call with the same array, so the caller must not change that array in place.

        Returns
        -------
        ndarray, shape (4, 4)
            ``T_world_needle(t) @ inv(T_tool_needle)``.

        """
        if T_tool_needle is None:
            inv = self._inv
        elif T_tool_needle is self._measured:
            # the same measured grasp as the last call (not changed), so its inverse is set
            inv = cast(np.ndarray, self._measured_inv)
        else:
            inv = invert_transform(T_tool_needle)
            self._measured, self._measured_inv = T_tool_needle, inv
        return self.needle(t) @ inv
