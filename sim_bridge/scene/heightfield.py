"""
Height fields: a solid's top (and bottom) surface sampled on a regular x-y grid.

A :class:`HeightField` describes a solid that, inside its footprint, spans
``bottom(x, y) <= z <= top(x, y)`` in its own frame (here the phantom frame, z up). Queries use
bilinear interpolation and are vectorised over points. :func:`rasterize_mesh` builds one from a
triangle mesh by casting vertical rays through every grid node (implemented as a z-buffer over
the mesh triangles, so it is exact and needs no ray-tracing library). :func:`grid_mesh` turns a
top-surface grid back into a closed, watertight triangle mesh.

All lengths are metres; arrays of points have shape ``(n, 3)`` (or ``(n, 2)`` for x-y).

Size: the grid, its queries and the two conversions from and to a mesh share one grid layout.
"""

from collections.abc import Callable
import math
from typing import cast

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage
from sim_bridge.common.validation import check_positive
import trimesh


class HeightField:
    """
    Top and bottom surfaces of a solid on a regular grid, in the solid's own frame.

    Parameters
    ----------
    x0, y0 : float
        Coordinates (m) of grid node ``[0, 0]``.
    spacing : float
        Grid spacing (m), the same along x and y.
    top : array_like, shape (ny, nx)
        Top-surface height (m) at node ``[j, i] = (x0 + i * spacing, y0 + j * spacing)``.
    bottom : array_like, shape (ny, nx)
        Bottom-surface height (m).
    footprint : array_like of bool, shape (ny, nx), optional
        Nodes where the solid exists (default: all). Values outside the footprint are replaced by
        those of the nearest footprint node so that interpolation stays finite.

    """

    def __init__(self, x0: float, y0: float, spacing: float, top: ArrayLike, bottom: ArrayLike,
                 footprint: ArrayLike | None = None) -> None:
        top = np.array(top, dtype=float)
        bottom = np.array(bottom, dtype=float)
        if top.ndim != 2 or top.shape[0] < 2 or top.shape[1] < 2:
            raise ValueError(f'height field top must be a 2-D grid of at least 2x2, got '
                             f'shape {top.shape}')
        if bottom.shape != top.shape:
            raise ValueError(f'height field bottom shape {bottom.shape} differs from top '
                             f'shape {top.shape}')
        check_positive(spacing, 'height field spacing (m)')
        if footprint is None:
            footprint = np.ones(top.shape, dtype=bool)
        footprint = np.array(footprint, dtype=bool)
        if footprint.shape != top.shape:
            raise ValueError('height field footprint must have the shape of top')
        if not footprint.any():
            raise ValueError('height field footprint is empty')
        if not footprint.all():
            _, (jj, ii) = ndimage.distance_transform_edt(~footprint, return_indices=True)
            top = cast(np.ndarray, top[jj, ii])
            bottom = cast(np.ndarray, bottom[jj, ii])
        self.x0 = float(x0)
        self.y0 = float(y0)
        self.spacing = float(spacing)
        self.ny, self.nx = top.shape
        self.top = top
        self.bottom = bottom
        self.footprint = footprint
        self._top_flat = top.ravel()
        self._bottom_flat = bottom.ravel()
        gy, gx = np.gradient(top, self.spacing)
        self._gx_flat = gx.ravel()
        self._gy_flat = gy.ravel()
        self._inv = 1.0 / self.spacing
        # Containment grid: one ring of nodes around the grid, and every node outside the
        # footprint, get a top far below and a bottom far above any point, so that a single
        # bilinear lookup (its weights held in [0, 1] off the grid) decides inside/outside
        # without bounds or footprint tests.
        far = 1.0e3
        top_in = np.where(footprint, top, -far)
        bottom_in = np.where(footprint, bottom, far)
        self._pnx = self.nx + 2
        self._porigin = np.array([[self.x0 - self.spacing], [self.y0 - self.spacing]])
        self._pimax = np.array([[self.nx], [self.ny]], dtype=np.intp)
        self._ptb = np.column_stack([np.pad(top_in, 1, constant_values=-far).ravel(),
                                     np.pad(bottom_in, 1, constant_values=far).ravel()])
        # Per cell of that grid (by its lower-left node), one column: the (top, bottom) values
        # of the corners [0, 0] and [1, 0] and the differences [0, 1] - [0, 0] and
        # [1, 1] - [1, 0], so that one lookup gives what the bilinear blend needs (the same sums
        # as from the nodes), as rows that NumPy walks contiguously.
        tb = self._ptb
        pnx = self._pnx
        n = len(tb) - pnx - 1
        self._pquad = np.ascontiguousarray(np.column_stack([
            tb[:n], tb[1:n + 1] - tb[:n], tb[pnx:pnx + n],
            tb[pnx + 1:pnx + 1 + n] - tb[pnx:pnx + n]]).T)
        self._x1 = self.x0 + (self.nx - 1) * self.spacing
        self._y1 = self.y0 + (self.ny - 1) * self.spacing

    # ------------------------------------------------------------------ grid helpers
    @property
    def xs(self) -> np.ndarray:
        """Grid node x coordinates (m), shape (nx,)."""
        return self.x0 + self.spacing * np.arange(self.nx)

    @property
    def ys(self) -> np.ndarray:
        """Grid node y coordinates (m), shape (ny,)."""
        return self.y0 + self.spacing * np.arange(self.ny)

    @property
    def bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``((xmin, ymin), (xmax, ymax))`` (m) of the grid."""
        return (self.x0, self.y0), (self._x1, self._y1)

    def _cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        fx = (x - self.x0) * self._inv
        fy = (y - self.y0) * self._inv
        ix = np.clip(fx.astype(np.intp), 0, self.nx - 2)
        iy = np.clip(fy.astype(np.intp), 0, self.ny - 2)
        tx = np.clip(fx - ix, 0.0, 1.0)
        ty = np.clip(fy - iy, 0.0, 1.0)
        return iy * self.nx + ix, tx, ty

    def _lerp(self, flat: np.ndarray, idx: np.ndarray, tx: np.ndarray, ty: np.ndarray
              ) -> np.ndarray:
        nx = self.nx
        v00 = flat[idx]
        v01 = flat[idx + 1]
        v10 = flat[idx + nx]
        v11 = flat[idx + nx + 1]
        a = v00 + (v01 - v00) * tx
        b = v10 + (v11 - v10) * tx
        return a + (b - a) * ty

    # ------------------------------------------------------------------ queries
    def height(self, xy: ArrayLike) -> float | np.ndarray:
        """
        Top-surface height at x-y positions (bilinear).

        Parameters
        ----------
        xy : array_like, shape (2,) or (n, 2) (extra trailing columns are ignored)
            Positions (m) in the height field's frame.

        Returns
        -------
        float or ndarray, shape (n,)
            Heights ``z`` (m); positions outside the grid take the edge value.

        """
        xy = np.asarray(xy, dtype=float)
        idx, tx, ty = self._cells(xy[..., 0], xy[..., 1])
        z = self._lerp(self._top_flat, idx, tx, ty)
        return float(z) if np.ndim(z) == 0 else z

    def bottom_height(self, xy: ArrayLike) -> float | np.ndarray:
        """
        Bottom-surface height at x-y positions (bilinear), like :meth:`height`.

        Parameters
        ----------
        xy : array_like, shape (2,) or (n, 2)
            Positions (m).

        Returns
        -------
        float or ndarray, shape (n,)
            Heights (m).

        """
        xy = np.asarray(xy, dtype=float)
        idx, tx, ty = self._cells(xy[..., 0], xy[..., 1])
        z = self._lerp(self._bottom_flat, idx, tx, ty)
        return float(z) if np.ndim(z) == 0 else z

    def gradient(self, xy: ArrayLike) -> np.ndarray:
        """
        Top-surface slope ``(dz/dx, dz/dy)`` at x-y positions.

        Parameters
        ----------
        xy : array_like, shape (2,) or (n, 2)
            Positions (m).

        Returns
        -------
        ndarray, shape (2,) or (n, 2)
            Slopes (dimensionless).

        """
        xy = np.asarray(xy, dtype=float)
        idx, tx, ty = self._cells(xy[..., 0], xy[..., 1])
        return np.stack([self._lerp(self._gx_flat, idx, tx, ty),
                         self._lerp(self._gy_flat, idx, tx, ty)], axis=-1)

    def normal(self, xy: ArrayLike) -> np.ndarray:
        """
        Upward unit normal of the top surface at x-y positions.

        Parameters
        ----------
        xy : array_like, shape (2,) or (n, 2)
            Positions (m).

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Unit normals (height field frame), ``z`` component > 0.

        """
        g = self.gradient(xy)
        n = np.concatenate([-g, np.ones(g.shape[:-1] + (1,))], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def surface_point(self, xy: ArrayLike) -> np.ndarray:
        """
        Point(s) of the top surface above x-y positions.

        Parameters
        ----------
        xy : array_like, shape (2,) or (n, 2)
            Positions (m).

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            ``(x, y, height(x, y))`` (m).

        """
        xy = np.asarray(xy, dtype=float)[..., :2]
        z = np.asarray(self.height(xy))
        return np.concatenate([xy, z[..., None]], axis=-1)

    def depth(self, points: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """
        Depth of points below the top surface, and whether they lie inside the solid.

        Parameters
        ----------
        points : array_like, shape (n, 3)
            Points (m) in the height field frame.

        Returns
        -------
        depth : ndarray, shape (n,)
            ``top(x, y) - z`` (m); positive below the top surface. Only meaningful where
            ``inside`` or near the surface; more than a grid cell outside the footprint (on
            any side, corners included) it is about -1000 m.
        inside : ndarray of bool, shape (n,)
            Within the footprint and between the bottom and top surfaces.

        """
        p = np.asarray(points, dtype=float)
        if p.ndim != 2:
            d, inside = self.depth(p.reshape(-1, 3))
            return d.reshape(p.shape[:-1]), inside.reshape(p.shape[:-1])
        pt = p.T
        f = (pt[:2] - self._porigin) * self._inv
        i = f.astype(np.intp)
        np.maximum(i, 0, out=i)
        np.minimum(i, self._pimax, out=i)
        w = f - i
        # beyond the ring the blend would extrapolate, and off two sides at once (a corner) its
        # cross term turns the far-below top into one far above: hold the ring's values there
        np.clip(w, 0.0, 1.0, out=w)
        idx = i[1] * self._pnx
        idx += i[0]
        q = self._pquad.take(idx, axis=1)
        tx = w[0]
        a = q[0:2] + q[2:4] * tx
        zb = a + (q[4:6] + q[6:8] * tx - a) * w[1]
        z = pt[2]
        d = zb[0] - z
        inside = (d >= 0.0) & (z >= zb[1])
        return d, inside

    def top_bound(self, radius: float) -> Callable[[float, float], float]:
        """
        Return a bound of the top surface :meth:`depth` sees within ``radius`` of a point.

        Parameters
        ----------
        radius : float
            Horizontal distance (m) the bound must cover.

        Returns
        -------
        callable
            ``bound(x, y) -> float``: no point within ``radius`` (in x-y) of ``(x, y)`` lies
            below the top surface unless its z is at most this value (m), up to rounding.
            Within the grid and its ring, :meth:`depth` blends the four grid values around a
            point, so the bound is the largest grid value within ``radius`` plus two cells of
            the nearest grid node; ``inf`` where the disc reaches beyond the ring (there
            :meth:`depth` extrapolates).

        """
        reach = int(np.ceil(radius * self._inv)) + 3
        grid = self._ptb[:, 0].reshape(self.ny + 2, self._pnx)
        flat = ndimage.maximum_filter(grid, size=2 * reach + 1, mode='nearest').ravel().tolist()
        x0, y0 = float(self._porigin[0, 0]), float(self._porigin[1, 0])
        inv, pnx, last_i, last_j = self._inv, self._pnx, self.nx + 1, self.ny + 1
        keep = radius + 0.5 * self.spacing  # from the ring's outer edge
        x_lo, x_hi = x0 + keep, x0 + last_i * self.spacing - keep
        y_lo, y_hi = y0 + keep, y0 + last_j * self.spacing - keep

        def bound(x: float, y: float) -> float:
            if not (x_lo <= x <= x_hi and y_lo <= y <= y_hi):
                return math.inf
            i = min(max(round((x - x0) * inv), 0), last_i)
            j = min(max(round((y - y0) * inv), 0), last_j)
            return flat[j * pnx + i]

        return bound

    def contains(self, points: ArrayLike) -> np.ndarray:
        """
        Whether points lie inside the solid (footprint, and bottom <= z <= top).

        Parameters
        ----------
        points : array_like, shape (n, 3)
            Points (m) in the height field frame.

        Returns
        -------
        ndarray of bool, shape (n,)

        """
        return self.depth(points)[1]

    def closed(self, width: float) -> 'HeightField':
        """
        Return a copy whose top surface has gaps narrower than ``width`` filled.

        A grey-scale morphological closing (dilation then erosion with a square window) removes
        slits and crevices narrower than the window while leaving smooth surfaces unchanged to
        within ``(curvature * width**2) / 8``.

        Parameters
        ----------
        width : float
            Window width (m); 0 returns ``self``.

        Returns
        -------
        HeightField

        """
        if width <= 0.0:
            return self
        k = int(np.ceil(width / self.spacing)) | 1
        top = ndimage.grey_closing(self.top, size=(k, k), mode='nearest')
        return HeightField(self.x0, self.y0, self.spacing, top, self.bottom, self.footprint)


def rasterize_mesh(mesh: trimesh.Trimesh, spacing: float, margin: float = 0.0,
                   chunk: int = 2_000_000) -> HeightField:
    """
    Height field of a mesh's top and bottom surfaces by vertical ray casting.

    Every grid node ``(x, y)`` casts a vertical ray; the highest hit is the top surface, the
    lowest the bottom. Nodes whose ray misses the mesh are outside the footprint.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Mesh in the frame of the height field (z up), metres.
    spacing : float
        Grid spacing (m).
    margin : float
        Extra border (m) added around the mesh's x-y bounds.
    chunk : int
        Maximum number of (triangle, node) pairs processed at once (memory bound).

    Returns
    -------
    HeightField

    """
    check_positive(spacing, 'rasterize_mesh spacing (m)')
    tris = np.asarray(mesh.triangles, dtype=float)
    if len(tris) == 0:
        raise ValueError('rasterize_mesh: the mesh has no triangles')
    (xmin, ymin, _), (xmax, ymax, _) = mesh.bounds
    x0, y0 = xmin - margin, ymin - margin
    nx = max(2, int(np.floor((xmax + margin - x0) / spacing)) + 1)
    ny = max(2, int(np.floor((ymax + margin - y0) / spacing)) + 1)
    top: np.ndarray = np.full(ny * nx, -np.inf)
    bottom: np.ndarray = np.full(ny * nx, np.inf)

    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    keep = np.abs(det) > 1e-18
    a, b, c, det = a[keep], b[keep], c[keep], det[keep]
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    i0 = np.clip(np.ceil((lo[:, 0] - x0) / spacing - 1e-9), 0, nx - 1).astype(np.intp)
    i1 = np.clip(np.floor((hi[:, 0] - x0) / spacing + 1e-9), -1, nx - 1).astype(np.intp)
    j0 = np.clip(np.ceil((lo[:, 1] - y0) / spacing - 1e-9), 0, ny - 1).astype(np.intp)
    j1 = np.clip(np.floor((hi[:, 1] - y0) / spacing + 1e-9), -1, ny - 1).astype(np.intp)
    w = np.maximum(i1 - i0 + 1, 0)
    h = np.maximum(j1 - j0 + 1, 0)
    counts = w * h
    order = np.arange(len(counts))
    start = 0
    while start < len(counts):
        total = np.cumsum(counts[start:])
        stop = start + max(1, int(np.searchsorted(total, chunk, side='right')))
        sel = order[start:stop]
        n = counts[sel]
        tri = np.repeat(sel, n)
        first = np.repeat(np.cumsum(n) - n, n)
        local = np.arange(len(tri)) - first
        ii = i0[tri] + local % w[tri]
        jj = j0[tri] + local // w[tri]
        px = x0 + ii * spacing
        py = y0 + jj * spacing
        ta, tb, tc, td = a[tri], b[tri], c[tri], det[tri]
        l1 = ((px - ta[:, 0]) * (tc[:, 1] - ta[:, 1]) - (tc[:, 0] - ta[:, 0]) *
              (py - ta[:, 1])) / td
        l2 = ((tb[:, 0] - ta[:, 0]) * (py - ta[:, 1]) - (px - ta[:, 0]) *
              (tb[:, 1] - ta[:, 1])) / td
        l0 = 1.0 - l1 - l2
        eps = -1e-9
        hit = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        z = l0 * ta[:, 2] + l1 * tb[:, 2] + l2 * tc[:, 2]
        flat = (jj * nx + ii)[hit]
        np.maximum.at(top, flat, z[hit])
        np.minimum.at(bottom, flat, z[hit])
        start = stop
    footprint = np.isfinite(top)
    if not footprint.any():
        raise ValueError('rasterize_mesh: no vertical ray hits the mesh (is it flat or empty?)')
    top = np.where(footprint, top, 0.0).reshape(ny, nx)
    bottom = np.where(footprint, bottom, 0.0).reshape(ny, nx)
    return HeightField(x0, y0, spacing, top, bottom, footprint.reshape(ny, nx))


def grid_mesh(xs: ArrayLike, ys: ArrayLike, top: ArrayLike, bottom_z: float) -> trimesh.Trimesh:
    """
    Build a closed, watertight mesh of a block whose top surface is a height grid.

    The mesh has the grid as its top, vertical side walls down to ``bottom_z`` and a flat
    bottom (a fan around the bottom centre). Faces point outwards.

    Parameters
    ----------
    xs : array_like, shape (nx,)
        Increasing grid x coordinates (m); need not be uniform.
    ys : array_like, shape (ny,)
        Increasing grid y coordinates (m).
    top : array_like, shape (ny, nx)
        Heights (m) of the top surface at the grid nodes.
    bottom_z : float
        Height (m) of the flat bottom; below every top value.

    Returns
    -------
    trimesh.Trimesh

    """
    xs = np.asarray(xs, dtype=float)
    ys = np.asarray(ys, dtype=float)
    top = np.asarray(top, dtype=float)
    ny, nx = top.shape
    if (len(xs), len(ys)) != (nx, ny):
        raise ValueError(f'grid_mesh: top shape {top.shape} does not match xs, ys '
                         f'({len(ys)}, {len(xs)})')
    if not np.all(top > bottom_z):
        raise ValueError('grid_mesh: bottom_z must lie below the whole top surface')
    X, Y = np.meshgrid(xs, ys)
    verts_top = np.column_stack([X.ravel(), Y.ravel(), top.ravel()])
    idx = np.arange(ny * nx).reshape(ny, nx)
    v00 = idx[:-1, :-1].ravel()
    v01 = idx[:-1, 1:].ravel()
    v10 = idx[1:, :-1].ravel()
    v11 = idx[1:, 1:].ravel()
    faces = [np.column_stack([v00, v01, v11]), np.column_stack([v00, v11, v10])]
    # Boundary loop counter-clockwise seen from above: bottom row, right column, top row, left.
    loop = np.concatenate([idx[0, :], idx[1:, -1], idx[-1, -2::-1], idx[-2:0:-1, 0]])
    nb = len(loop)
    base = ny * nx
    verts_bottom = verts_top[loop].copy()
    verts_bottom[:, 2] = bottom_z
    centre = np.array([[0.5 * (xs[0] + xs[-1]), 0.5 * (ys[0] + ys[-1]), bottom_z]])
    k = np.arange(nb)
    kn = (k + 1) % nb
    # Side walls: outward normals for a counter-clockwise loop.
    faces.append(np.column_stack([loop[k], base + k, base + kn]))
    faces.append(np.column_stack([loop[k], base + kn, loop[kn]]))
    # Bottom fan, facing down.
    c = base + nb
    faces.append(np.column_stack([np.full(nb, c), base + kn, base + k]))
    vertices = np.vstack([verts_top, verts_bottom, centre])
    return trimesh.Trimesh(vertices=vertices, faces=np.vstack(faces), process=False)
