"""
Where a user's phantom mesh gets its wound line, and the phantom frame that follows from it.

A mesh file (STL, OBJ, PLY; z up) has coordinates of its own. Its *top surface* is the part of
its height field within ``top_band`` of its highest point; a point of it is *flat enough* when
the surface's slope there is at most ``max_slope_deg``. The wound line is the longest straight
segment whose every point keeps ``clearance`` (the markers' half width plus their radius and a
margin) from any top-surface point that is not flat enough, or from the surface's edge
(:func:`find_wound_line`). A raised pad of a scanned suture pad thus gets the line along its
longest extent, never the base between the pads.

:func:`wound_frame` gives the phantom frame of a wound line: origin on the surface at the line's
centre, ``x`` along the line, ``z`` up (the phantom frame the generated pads use), as the
transform ``T_phantom_file`` that maps file coordinates (metres, after the mesh scale) into it.

Lengths are metres, angles radians unless a name says ``deg``.
"""

from dataclasses import dataclass
import math
from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

if TYPE_CHECKING:
    from sim_bridge.scene.heightfield import HeightField


@dataclass(frozen=True)
class WoundSearch:
    """
    Settings of the search for a wound line on a mesh's top surface.

    Attributes
    ----------
    top_band : float
        Height (m) below the highest surface point that still counts as the top surface.
    max_slope_deg : float
        Steepest slope (deg) of a flat-enough surface point.
    margin : float
        Extra room (m) kept around the markers, beyond their half width and radius.
    angles : int
        Number of line directions tried over 180 deg.
    spacing : float
        Grid spacing (m) of the search.

    """

    top_band: float = 0.003
    max_slope_deg: float = 20.0
    margin: float = 0.001
    angles: int = 36
    spacing: float = 0.001


@dataclass(frozen=True)
class WoundLineFound:
    """
    A straight wound line found on a surface (the surface's frame, metres).

    Attributes
    ----------
    start, end : ndarray, shape (2,)
        End points (x, y) of the line.
    length : float
        Its length (m).
    height : float
        Surface height (m) at its centre.
    angle_deg : float
        Direction of the line from the surface's x axis (deg, in [0, 180)).

    """

    start: np.ndarray
    end: np.ndarray
    length: float
    height: float
    angle_deg: float

    @property
    def centre(self) -> np.ndarray:
        """Centre (x, y) of the line (m)."""
        return 0.5 * (self.start + self.end)


def flat_top_mask(surface: 'HeightField', search: WoundSearch = WoundSearch()) -> np.ndarray:
    """
    Grid nodes of a height field on its flat-enough top surface.

    Parameters
    ----------
    surface : sim_bridge.scene.heightfield.HeightField
        The mesh's surface (its frame, z up).
    search : WoundSearch
        Top band and slope limit.

    Returns
    -------
    ndarray of bool, shape (ny, nx)

    """
    top = surface.top
    foot = surface.footprint
    highest = float(top[foot].max())
    gy, gx = np.gradient(top, surface.spacing)
    slope_ok = np.hypot(gx, gy) <= math.tan(math.radians(search.max_slope_deg))
    return foot & slope_ok & (top >= highest - search.top_band)


def _longest_run(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start index and length of the longest run of True in each row of a 2-D bool array."""
    n_rows, n = rows.shape
    padded = np.zeros((n_rows, n + 2), dtype=np.int8)
    padded[:, 1:-1] = rows
    d = np.diff(padded, axis=1)
    best_len = np.zeros(n_rows, dtype=int)
    best_start = np.zeros(n_rows, dtype=int)
    r_up, c_up = np.nonzero(d == 1)
    r_dn, c_dn = np.nonzero(d == -1)
    # starts and ends pair up in order within each row (np.nonzero runs row by row)
    lengths = c_dn - c_up
    for r, c, length in zip(r_up, c_up, lengths):
        if length > best_len[r]:
            best_len[r], best_start[r] = length, c
    return best_start, best_len


def find_wound_line(surface: 'HeightField', clearance: float,
                    search: WoundSearch = WoundSearch()) -> WoundLineFound | None:
    """
    Find the longest straight line on the flat-enough top surface with room either side.

    Parameters
    ----------
    surface : sim_bridge.scene.heightfield.HeightField
        The mesh's surface (its frame, z up).
    clearance : float
        Distance (m) every point of the line keeps from surface points that are not flat-enough
        top surface (the markers' half width, radius and a margin).
    search : WoundSearch
        Search settings.

    Returns
    -------
    WoundLineFound or None
        None when no point of the top surface has the clearance.

    """
    mask = flat_top_mask(surface, search)
    # room: distance of each node from the nearest node that is not usable
    room = ndimage.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1] * surface.spacing
    usable = room >= clearance
    if not usable.any():
        return None
    (x0, y0), (x1, y1) = surface.bounds
    centre = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
    half = 0.5 * math.hypot(x1 - x0, y1 - y0)
    step = search.spacing
    n = int(math.ceil(2.0 * half / step)) + 1
    t = np.linspace(-half, half, n)
    best: tuple[float, np.ndarray, np.ndarray, float] | None = None
    for k in range(search.angles):
        a = math.pi * k / search.angles
        d = np.array([math.cos(a), math.sin(a)])
        perp = np.array([-d[1], d[0]])
        # rows: lines at offsets t across the direction; columns: points t along it
        px = centre[0] + t[:, None] * perp[0] + t[None, :] * d[0]
        py = centre[1] + t[:, None] * perp[1] + t[None, :] * d[1]
        i = np.rint((px - surface.x0) / surface.spacing).astype(np.intp)
        j = np.rint((py - surface.y0) / surface.spacing).astype(np.intp)
        inside = (i >= 0) & (i < surface.nx) & (j >= 0) & (j < surface.ny)
        ok = np.zeros(px.shape, dtype=bool)
        ok[inside] = usable[j[inside], i[inside]]
        starts, lengths = _longest_run(ok)
        r = int(np.argmax(lengths))
        length = (lengths[r] - 1) * step
        if lengths[r] > 0 and (best is None or length > best[0] + 0.5 * step):
            p0 = centre + t[r] * perp + t[starts[r]] * d
            p1 = centre + t[r] * perp + t[starts[r] + lengths[r] - 1] * d
            best = (length, p0, p1, math.degrees(a))
    # best is None only if no line meets a usable node: unpacking then fails as before
    length, p0, p1, angle = cast(tuple[float, np.ndarray, np.ndarray, float], best)
    mid = 0.5 * (p0 + p1)
    return WoundLineFound(p0, p1, float(length), float(surface.height(mid)), angle)


def wound_frame(centre: ArrayLike, direction: ArrayLike, height: float) -> np.ndarray:
    """
    Transform ``T_phantom_file`` of a wound's phantom frame.

    Parameters
    ----------
    centre : array_like, shape (2,)
        Wound centre (x, y) in the file's frame (m).
    direction : array_like, shape (2,)
        Direction of the wound in the file's x-y plane (the phantom's ``x``).
    height : float
        Surface height (m, file frame) at the centre.

    Returns
    -------
    ndarray, shape (4, 4)
        Maps file coordinates into the phantom frame: the centre on the surface goes to the
        origin, the wound direction onto ``x``, ``z`` stays up.

    """
    d = np.asarray(direction, dtype=float)
    a = math.atan2(d[1], d[0])
    c, s = math.cos(-a), math.sin(-a)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    mid = np.array([*np.asarray(centre, dtype=float)[:2], height])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ mid
    return T


def apply_xy(T: ArrayLike, xy: ArrayLike) -> np.ndarray:
    """
    Map x-y points by the planar part of a transform about z.

    Parameters
    ----------
    T : array_like, shape (4, 4)
        Transform whose rotation is about z.
    xy : array_like, shape (n, 2)
        Points (m).

    Returns
    -------
    ndarray, shape (n, 2)

    """
    T = np.asarray(T, dtype=float)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return xy @ T[:2, :2].T + T[:2, 3]
