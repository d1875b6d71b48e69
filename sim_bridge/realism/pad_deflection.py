"""
A pad that gives: the surface near the tip is pressed in before the puncture and relaxes after.

The dimple is a Gaussian of depth ``depth`` and radius ``spread`` centred where the tip first
touched the surface, pressed in along the surface's inward normal and dragged along the surface
with the tip (``drag``: the tip's motion along the surface since it touched, up to ``limit`` --
the entry point moves before the tip punctures). Before the puncture its depth follows the
tip's indentation of the undeformed surface up to ``limit`` (the puncture force over the pad's
stiffness); the tip punctures when its indentation passes ``limit``. After the puncture depth
and drag relax exponentially with time constant ``relax_time``. Frames: ``world``, metres,
seconds.
"""

import math

import numpy as np
from numpy.typing import ArrayLike


class PadDeflection:
    """
    The dimple of the surface under the needle tip.

    Parameters
    ----------
    limit : float
        Deepest deflection (m) before the tip punctures.
    spread : float
        Gaussian radius (m) of the dimple.
    relax_time : float
        Relaxation time constant (s) after the puncture.
    normal : array_like, shape (3,)
        Outward unit normal of the surface (``world``).

    Attributes
    ----------
    depth : float
        Current deflection (m) at the centre.
    centre : ndarray, shape (3,) or None
        Surface point (``world``) at the centre of the dimple.
    punctured : bool
        The tip has punctured since :meth:`reset`.

    """

    def __init__(self, limit: float, spread: float, relax_time: float,
                 normal: ArrayLike) -> None:
        self.limit = float(limit)
        self.spread = float(spread)
        self.relax_time = float(relax_time)
        self.normal = np.asarray(normal, dtype=float)
        self.reset()

    def reset(self) -> None:
        """Start an untouched pad: no dimple, no puncture yet."""
        self.depth = 0.0
        self.centre: np.ndarray | None = None
        self.drag = np.zeros(3)
        self.punctured = False

    def press(self, tip: np.ndarray, indentation: float) -> float:
        """
        Press the pad with the tip ``indentation`` (m) below the undeformed surface.

        Parameters
        ----------
        tip : ndarray, shape (3,)
            Needle tip (``world``).
        indentation : float
            Depth of the tip below the undeformed surface (m; <= 0 above it).

        Returns
        -------
        float
            The deflection (m) now: ``min(indentation, limit)``, 0 above the surface. When the
            indentation passes ``limit`` the pad is punctured from then on.

        """
        if indentation <= 0.0:
            self.depth = 0.0
            self.drag = np.zeros(3)
            return 0.0
        on_surface = tip + indentation * self.normal
        if self.depth == 0.0 or self.centre is None:
            self.centre = on_surface  # where the tip touched
        along = on_surface - self.centre
        along = along - (along @ self.normal) * self.normal
        length = float(np.linalg.norm(along))
        self.drag = along if length <= self.limit else along * (self.limit / length)
        self.depth = min(indentation, self.limit)
        if indentation > self.limit:
            self.punctured = True
        return self.depth

    def relax(self, dt: float) -> None:
        """
        Let the dimple relax for ``dt`` seconds (after the puncture).

        Parameters
        ----------
        dt : float
            Time step (s).

        """
        if self.depth > 0.0:
            decay = math.exp(-dt / self.relax_time)
            self.depth *= decay
            self.drag = self.drag * decay
            if self.depth < 1e-7:
                self.depth = 0.0
                self.drag = np.zeros(3)

    def displacement(self, points: ArrayLike, normal_cap: float = math.inf) -> np.ndarray:
        """
        How far the surface at ``points`` is moved by the dimple (``world``, m).

        Parameters
        ----------
        points : array_like, shape (n, 3)
            Surface points (``world``).
        normal_cap : float
            Largest part (m) along the normal (drawing on a pad mesh that is not deformed: a
            marker pressed deeper than its thickness would vanish under it).

        Returns
        -------
        ndarray, shape (n, 3)
            Displacements: the drag along the surface and the press along the inward normal.

        """
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        if self.depth == 0.0 or self.centre is None:
            return np.zeros_like(pts)
        d = pts - self.centre
        d = d - np.outer(d @ self.normal, self.normal)
        w = np.exp(-0.5 * np.einsum('ij,ij->i', d, d) / self.spread ** 2)
        return np.outer(w, self.drag) - np.outer(np.minimum(self.depth * w, normal_cap),
                                                  self.normal)
