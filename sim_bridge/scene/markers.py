"""
Entry/exit marker pairs on a phantom's surface, and where a phantom's configuration puts them.

Positions in metres; a :class:`MarkerPair` is in whatever frame its points were given in (the
phantom frame when placed, ``world`` once the phantom is).
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from sim_bridge.scene.heightfield import HeightField
    from sim_bridge.scene.phantom_config import PhantomConfig
    from sim_bridge.scene.phantom_shapes import WoundLine


@dataclass(frozen=True, eq=False)
class MarkerPair:
    """
    An entry/exit marker pair on the phantom surface (world frame, metres).

    Attributes
    ----------
    name : str
        Pair name (``synth1``, ``scan3``).
    entry, exit : ndarray, shape (3,)
        Marker centres on the surface.
    normal : ndarray, shape (3,)
        Unit mean of the two surface normals (outward, away from the tissue).
    entry_normal, exit_normal : ndarray, shape (3,)
        Unit surface normals at the markers.
    index : int
        1-based position of the pair along the wound.

    """

    name: str
    entry: np.ndarray
    exit: np.ndarray
    normal: np.ndarray
    entry_normal: np.ndarray
    exit_normal: np.ndarray
    index: int = 0

    @property
    def midpoint(self) -> np.ndarray:
        """Midpoint of entry and exit (m), shape (3,)."""
        return 0.5 * (self.entry + self.exit)

    @property
    def chord(self) -> float:
        """Entry-to-exit distance (m)."""
        return float(np.linalg.norm(self.exit - self.entry))

    @property
    def frame(self) -> np.ndarray:
        """
        Pair frame ``T_world_pair`` (4, 4).

        Origin at the midpoint; ``x`` from entry towards exit (made perpendicular to ``z``);
        ``z`` the mean surface normal; ``y = z x x`` runs along the wound.
        """
        z = self.normal
        x = self.exit - self.entry
        x = x - np.dot(x, z) * z
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        T[:3, 3] = self.midpoint
        return T

    def transformed(self, T: ArrayLike) -> 'MarkerPair':
        """
        Return this pair with its points and normals mapped by the rigid transform ``T``.

        Parameters
        ----------
        T : array_like, shape (4, 4)
            Transform applied to positions (rotation only for normals).

        Returns
        -------
        MarkerPair

        """
        T = np.asarray(T, dtype=float)
        R, t = T[:3, :3], T[:3, 3]
        return MarkerPair(self.name, R @ self.entry + t, R @ self.exit + t, R @ self.normal,
                          R @ self.entry_normal, R @ self.exit_normal, self.index)


def marker_frame(point: np.ndarray, normal: np.ndarray, other: np.ndarray) -> np.ndarray:
    """
    Return the frame of one marker, ``T_world_marker`` (4, 4).

    Parameters
    ----------
    point : ndarray, shape (3,)
        Marker centre (origin of the frame).
    normal : ndarray, shape (3,)
        Surface normal at the marker (``z``; normalised here).
    other : ndarray, shape (3,)
        The pair's other marker: ``x`` points towards it, in the plane normal to ``z``.

    Returns
    -------
    ndarray, shape (4, 4)
        ``x`` towards the other marker, ``y = z x x``, ``z`` the normal.

    """
    z = normal / np.linalg.norm(normal)
    x = other - point
    x = x - (x @ z) * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = point
    return T


def place_markers(config: 'PhantomConfig', surface: 'HeightField',
                  wound: 'WoundLine | None') -> dict[str, MarkerPair]:
    """
    Return the marker pairs of a phantom, dropped onto its tissue surface (phantom frame).

    Parameters
    ----------
    config : sim_bridge.scene.phantom_config.PhantomConfig
        The phantom's markers, or its wound's ``n_pairs``, ``spacing``, ``offset``,
        ``half_width`` and ``entry_side``.
    surface : sim_bridge.scene.heightfield.HeightField
        Tissue surface (phantom frame).
    wound : sim_bridge.scene.phantom_shapes.WoundLine or None
        Wound line (phantom frame); None only when ``config`` gives the markers.

    Returns
    -------
    dict of str to MarkerPair
        Pairs by name, in order along the wound.

    Raises
    ------
    ValueError
        If a pair falls off the wound line or outside the pad's footprint.

    """
    prefix = config.marker_prefix
    pairs = {}
    if config.markers:
        items = [(name, np.array(m.entry, float), np.array(m.exit, float))
                 for name, m in config.markers.items()]
    else:
        w = config.wound
        assert wound is not None, 'a phantom without its markers has a wound line'
        items = []
        centre = 0.5 * wound.length + w.offset
        for k in range(w.n_pairs):
            s = centre + (k - 0.5 * (w.n_pairs - 1)) * w.spacing
            if not 0.0 <= s <= wound.length:
                raise ValueError(
                    f'phantom {prefix}: marker pair {k + 1} falls off the wound line '
                    f'(arc length {s:.4f} m of {wound.length:.4f} m); reduce spacing or '
                    f'n_pairs')
            c = wound.point(s)
            left = wound.left(s) * w.half_width * w.entry_side
            items.append((f'{prefix}{k + 1}', c + left, c - left))
    for index, (name, e_xy, x_xy) in enumerate(items, start=1):
        ex = np.vstack([e_xy, x_xy])
        inside = surface.contains(np.column_stack([ex, surface.height(ex) - 1e-6]))
        if not inside.all():
            raise ValueError(f'phantom {prefix}: marker pair {name} lies outside the pad '
                             f'footprint')
        pts = surface.surface_point(ex)
        normals = surface.normal(ex)
        mean = normals.sum(axis=0)
        pairs[name] = MarkerPair(name, pts[0], pts[1], mean / np.linalg.norm(mean),
                                 normals[0], normals[1], index)
    return pairs
