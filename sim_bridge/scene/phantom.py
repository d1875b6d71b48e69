"""
Suture phantoms: pad meshes, the tissue surface used for needle tracking, and red markers.

Two generated phantoms follow the paper's experiment setup: ``synthetic`` (a flat suture pad with
a wound slit along its length, markers ``synth1..4``) and ``scanned`` (a curved, irregular pad
like an MRI scan of a moulded suture pad, markers ``scan1..4``). Kind ``mesh`` loads any STL,
OBJ or PLY file instead.

Phantom frame: ``x`` along the pad (the wound direction), ``y`` across it, ``z`` up; the origin
is on the top surface at the wound centre. ``T_world_phantom`` (config ``position``,
``quaternion`` (x, y, z, w)) places it in the world.

Tissue surface: the top surface as a :class:`~sim_bridge.scene.heightfield.HeightField` in the
phantom frame, with the wound slit closed (a needle passing under the wound stays inside the
tissue): generated pads use their slit-free analytic surface; a user mesh is ray cast once at load
time and gaps narrower than ``wound_closing`` are closed. ``Phantom.mesh`` (phantom frame) keeps
the slit, for display and instrument collision.

Markers: four entry/exit pairs, either given in the config (x-y in the phantom frame, dropped
onto the surface) or spaced along the wound line at ``spacing`` with entry and exit
``half_width`` either side of it. Entry is on the wound's left (``+y`` for a wound along ``+x``)
when ``entry_side`` is +1, on its right when -1.

A user mesh with ``frame: wound`` is moved into the phantom frame of its wound: its wound line
or markers are given in the file's coordinates (metres, after ``mesh_scale``), and the mesh is
turned and shifted so that the wound's centre on the surface is the origin and the wound runs
along ``x``. Without a wound line or markers, the longest straight line of the mesh's
flat-enough top surface with room for the markers is the wound
(:mod:`sim_bridge.scene.mesh_placement`); the log says where it lies in the file.

The configuration is in :mod:`sim_bridge.scene.phantom_config`, the marker pairs in
:mod:`sim_bridge.scene.markers`; both are importable from here too.
"""

from collections.abc import Mapping
from dataclasses import replace
import logging
import math
from pathlib import Path
from typing import cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import invert_transform
from sim_bridge.scene.heightfield import HeightField, grid_mesh, rasterize_mesh
from sim_bridge.scene.markers import MarkerPair, place_markers
from sim_bridge.scene.mesh_placement import apply_xy, find_wound_line, wound_frame
from sim_bridge.scene.phantom_config import (
    FRAMES,
    KINDS,
    MarkerConfig,
    PhantomConfig,
    WoundConfig,
)
from sim_bridge.scene.phantom_shapes import (
    WoundLine,
    breakpoints,
    scanned_height,
    synthetic_height,
)
import trimesh

__all__ = ['FRAMES', 'KINDS', 'MarkerConfig', 'MarkerPair', 'Phantom', 'PhantomConfig',
           'WoundConfig', 'build_phantom']

_LOG = logging.getLogger(__name__)


class Phantom:
    """
    A suture phantom: mesh, tissue surface and markers, placed in the world.

    Build it with :func:`build_phantom`.

    Attributes
    ----------
    name : str
        Config name (``synthetic``, ``scanned``).
    config : PhantomConfig
        Its configuration.
    T_world_phantom : ndarray, shape (4, 4)
        Pose of the phantom frame in the world.
    mesh : trimesh.Trimesh
        Watertight pad mesh in the phantom frame (with the wound slit).
    surface : HeightField
        Tissue surface (top, slit closed) and bottom, phantom frame.
    wound : WoundLine or None
        Wound curve in the phantom's x-y plane.
    markers_phantom : dict of MarkerPair
        Marker pairs in the phantom frame.
    markers : dict of MarkerPair
        Marker pairs in the world frame, in order ``<prefix>1 ..``.
    placement : str
        Where the markers of a user mesh lie (a sentence for the log; empty otherwise).
    T_phantom_file : ndarray, shape (4, 4)
        Maps a user mesh file's coordinates (metres, after ``mesh_scale``) into the phantom
        frame (identity for generated pads).

    """

    def __init__(self, name: str, config: PhantomConfig, mesh: trimesh.Trimesh,
                 surface: HeightField, wound: WoundLine | None,
                 markers_phantom: Mapping[str, MarkerPair]) -> None:
        self.name = name
        self.config = config
        self.T_world_phantom = config.T_world_phantom
        self.T_phantom_world = invert_transform(self.T_world_phantom)
        self.mesh = mesh
        self.surface = surface
        self.wound = wound
        self.markers_phantom = dict(markers_phantom)
        self.markers = {k: m.transformed(self.T_world_phantom)
                        for k, m in self.markers_phantom.items()}
        self._R = self.T_phantom_world[:3, :3].copy()
        self._t = self.T_phantom_world[:3, 3].copy()
        self.placement = ''
        self.T_phantom_file = np.eye(4)

    @property
    def kind(self) -> str:
        """Phantom kind (``synthetic``, ``scanned``, ``mesh``)."""
        return self.config.kind

    @property
    def marker_radius(self) -> float:
        """Marker disc radius (m)."""
        return self.config.marker_radius

    @property
    def marker_rgba(self) -> tuple[float, float, float, float]:
        """Marker colour (r, g, b, a)."""
        return self.config.marker_rgba

    @property
    def rgba(self) -> tuple[float, float, float, float]:
        """Pad colour (r, g, b, a)."""
        return self.config.rgba

    def to_phantom(self, points_world: ArrayLike) -> np.ndarray:
        """
        Map world points into the phantom frame.

        Parameters
        ----------
        points_world : array_like, shape (n, 3) or (3,)
            Points (m), world frame.

        Returns
        -------
        ndarray, same shape
            Points (m), phantom frame.

        """
        return np.asarray(points_world, dtype=float) @ self._R.T + self._t

    def mesh_world(self) -> trimesh.Trimesh:
        """Return a copy of the pad mesh in the world frame (trimesh.Trimesh)."""
        m = self.mesh.copy()
        m.apply_transform(self.T_world_phantom)
        return m

    def height(self, xy: ArrayLike) -> float | np.ndarray:
        """
        Tissue-surface height at phantom-frame x-y positions (slit closed).

        Parameters
        ----------
        xy : array_like, shape (2,) or (n, 2)
            Positions (m), phantom frame.

        Returns
        -------
        float or ndarray, shape (n,)
            Heights (m), phantom frame.

        """
        return self.surface.height(xy)

    def normal(self, xy: ArrayLike) -> np.ndarray:
        """
        Upward unit surface normal at phantom-frame x-y positions (phantom frame).

        Parameters
        ----------
        xy : array_like, shape (2,) or (n, 2)
            Positions (m), phantom frame.

        Returns
        -------
        ndarray, shape (3,) or (n, 3)

        """
        return self.surface.normal(xy)

    def is_inside(self, points_world: ArrayLike) -> np.ndarray:
        """
        Whether world points lie inside the tissue (within the footprint, below the surface).

        Parameters
        ----------
        points_world : array_like, shape (n, 3)
            Points (m), world frame.

        Returns
        -------
        ndarray of bool, shape (n,)

        """
        return self.surface.depth(self.to_phantom(points_world))[1]

    def penetration(self, points_world: ArrayLike) -> np.ndarray:
        """
        Depth of world points below the tissue surface, zero outside the tissue.

        Use it for instrument-phantom contact of tool-tip and jaw points.

        Parameters
        ----------
        points_world : array_like, shape (n, 3)
            Points (m), world frame.

        Returns
        -------
        ndarray, shape (n,)
            Depth (m) >= 0.

        """
        d, inside = self.surface.depth(self.to_phantom(points_world))
        return np.where(inside, d, 0.0)

    def nearest_marker(self, point_world: ArrayLike) -> tuple[str | None, float]:
        """
        Nearest marker to a world point.

        Parameters
        ----------
        point_world : array_like, shape (3,)
            Point (m), world frame.

        Returns
        -------
        name : str
            ``'<pair>.entry'`` or ``'<pair>.exit'``, or ``''`` without markers.
        distance : float
            Distance (m).

        """
        p = np.asarray(point_world, dtype=float)
        best, dist = '', float('inf')
        for pair in self.markers.values():
            for which, q in (('entry', pair.entry), ('exit', pair.exit)):
                d = float(np.linalg.norm(p - q))
                if d < dist:
                    best, dist = f'{pair.name}.{which}', d
        return best, dist


# ---------------------------------------------------------------------- construction


def _generated(config: PhantomConfig) -> tuple[trimesh.Trimesh, HeightField, WoundLine]:
    length, width, thickness = config.size
    wound = WoundLine(config.wound.line)
    centre = wound.point(0.5 * wound.length)
    if config.kind == 'synthetic':
        def height(xy: np.ndarray) -> np.ndarray:
            return synthetic_height(xy, config.size)
    else:
        def height(xy: np.ndarray) -> np.ndarray:
            return scanned_height(xy, config.size, config.shape, config.seed, centre)
    # Tissue surface: the slit-free analytic surface on a fine grid.
    res = config.resolution
    nx = int(np.ceil(length / res)) + 1
    ny = int(np.ceil(width / res)) + 1
    xs = np.linspace(-0.5 * length, 0.5 * length, nx)
    ys = np.linspace(-0.5 * width, 0.5 * width, ny)
    X, Y = np.meshgrid(xs, ys)
    top = height(np.stack([X, Y], axis=-1))
    bottom = np.full_like(top, -thickness)
    surface = HeightField(xs[0], ys[0], xs[1] - xs[0], top, bottom)
    if np.any(top <= -thickness):
        raise ValueError(f'phantom {config.marker_prefix}: the surface dips below the pad '
                         f'bottom; increase size[2] (thickness)')
    # Mesh: a grid with the slit carved in; straight wounds get exact slit walls.
    w = config.wound
    extra_x, extra_y = [], []
    step = config.mesh_resolution
    if wound.straight and w.slit_width > 0.0:
        (ax, ay), (bx, by) = wound.points[0], wound.points[-1]
        hw, eps = 0.5 * w.slit_width, min(5e-5, 0.25 * w.slit_width)
        if abs(ay - by) < 1e-9:
            extra_y = [ay - hw - eps, ay - hw, ay + hw, ay + hw + eps]
            extra_x = [min(ax, bx) - eps, min(ax, bx), max(ax, bx), max(ax, bx) + eps]
        elif abs(ax - bx) < 1e-9:
            extra_x = [ax - hw - eps, ax - hw, ax + hw, ax + hw + eps]
            extra_y = [min(ay, by) - eps, min(ay, by), max(ay, by), max(ay, by) + eps]
        else:
            step = min(step, 0.5 * w.slit_width)
    elif w.slit_width > 0.0:
        step = min(step, max(0.5 * w.slit_width, 0.0005))
    mx = breakpoints(-0.5 * length, 0.5 * length, step, extra_x)
    my = breakpoints(-0.5 * width, 0.5 * width, step, extra_y)
    MX, MY = np.meshgrid(mx, my)
    grid_xy = np.stack([MX, MY], axis=-1)
    mtop = height(grid_xy)
    if w.slit_width > 0.0 and w.slit_depth > 0.0:
        slit = wound.slit_mask(grid_xy.reshape(-1, 2), 0.5 * w.slit_width + 1e-9)
        mtop = mtop - w.slit_depth * slit.reshape(mtop.shape)
    mesh = grid_mesh(mx, my, mtop, -thickness)
    return mesh, surface, wound


def _load_user_mesh(config: PhantomConfig, base_dir: str | Path | None
                    ) -> tuple[trimesh.Trimesh, HeightField, WoundLine | None, PhantomConfig,
                               np.ndarray | None, str]:
    path = Path(cast(str, config.mesh))  # a mesh phantom has its file (PhantomConfig checks)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    try:
        loaded = trimesh.load(str(path), force='mesh')
    except Exception as exc:  # trimesh raises many types for bad files
        raise ValueError(f'cannot read phantom mesh {path}: {exc}') from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f'cannot read phantom mesh {path}: no triangles found')
    mesh = loaded.copy()
    if config.mesh_scale != 1.0:
        mesh.apply_scale(config.mesh_scale)
    if not mesh.is_watertight:
        _LOG.warning('phantom mesh %s is not watertight; its top surface is still used', path)
    config, T, note = _place_wound(config, mesh, path)
    if T is not None:
        mesh.apply_transform(T)
    raw = rasterize_mesh(mesh, config.resolution)
    surface = raw.closed(config.wound_closing)
    wound = WoundLine(config.wound.line) if config.wound.line else None
    return mesh, surface, wound, config, T, note


def _place_wound(config: PhantomConfig, mesh: trimesh.Trimesh, path: Path
                 ) -> tuple[PhantomConfig, np.ndarray | None, str]:
    """
    Wound line or markers of a user mesh, and its phantom frame.

    Returns the configuration with wound line and markers in the phantom frame, the transform
    ``T_phantom_file`` (None: the file's frame is the phantom frame) and a sentence saying
    where the markers lie.
    """
    T: np.ndarray | None  # None: the file's frame is the phantom frame
    markers: dict[str, MarkerConfig] | None
    w = config.wound
    if config.frame == 'file' and (config.markers or w.line):
        return config, None, ''
    coarse = rasterize_mesh(mesh, max(config.resolution, config.wound_search.spacing))
    coarse = coarse.closed(config.wound_closing)
    mm = 1e3
    if config.markers and not w.line:
        entries = np.array([m.entry for m in config.markers.values()], dtype=float)
        exits = np.array([m.exit for m in config.markers.values()], dtype=float)
        across = (entries - exits).mean(axis=0) * w.entry_side
        centre = 0.5 * (entries + exits).mean(axis=0)
        T = wound_frame(centre, (across[1], -across[0]), cast(float, coarse.height(centre)))
        markers = {name: MarkerConfig(tuple(apply_xy(T, m.entry)[0]),
                                      tuple(apply_xy(T, m.exit)[0]))
                   for name, m in config.markers.items()}
        note = (f'{len(markers)} marker pairs as given, centred at ({centre[0] * mm:.1f}, '
                f'{centre[1] * mm:.1f}) mm of {path.name}')
        return replace(config, markers=markers), T, note
    if w.line:
        line = WoundLine(w.line)
        centre = line.point(0.5 * line.length)
        T = wound_frame(centre, np.subtract(w.line[-1], w.line[0]),
                        cast(float, coarse.height(centre)))
        points = tuple(tuple(p) for p in apply_xy(T, w.line))
        markers = config.markers
        if markers:  # given with the line: placed in the line's frame
            markers = {name: MarkerConfig(tuple(apply_xy(T, m.entry)[0]),
                                          tuple(apply_xy(T, m.exit)[0]))
                       for name, m in markers.items()}
        n = len(markers) if markers else w.n_pairs
        how = 'as given' if markers else 'along the given wound line'
        note = (f'{n} marker pairs {how}, wound centred at ({centre[0] * mm:.1f}, '
                f'{centre[1] * mm:.1f}) mm of {path.name}')
        return replace(config, wound=replace(w, line=points), markers=markers), T, note
    search = config.wound_search
    clearance = w.half_width + config.marker_radius + search.margin
    found = find_wound_line(coarse, clearance, search)
    if found is None:
        raise ValueError(
            f'phantom mesh {path}: no point of its top surface (within '
            f'{search.top_band * mm:g} mm of its highest point, slope <= '
            f'{search.max_slope_deg:g} deg) has {clearance * mm:.1f} mm of room around it for '
            f'the markers; give the wound line (wound.line) or the marker pairs (markers) in '
            f"the file's coordinates, or a smaller wound.half_width")
    n_pairs = min(w.n_pairs, int(math.floor(found.length / w.spacing + 1e-9)) + 1)
    if n_pairs < w.n_pairs:
        _LOG.warning('phantom mesh %s: its longest flat-enough line is %.1f mm long: room '
                     'for %d of %d marker pairs %.1f mm apart (wound.spacing)', path,
                     found.length * mm, n_pairs, w.n_pairs, w.spacing * mm)
    direction = found.end - found.start
    T = wound_frame(found.centre, direction, found.height)
    if config.frame == 'file':
        T = None
        points = (tuple(found.start), tuple(found.end))
    else:
        half = 0.5 * found.length
        points = ((-half, 0.0), (half, 0.0))
    note = (f'{n_pairs} marker pairs {w.spacing * mm:g} mm apart on the top surface of '
            f'{path.name}, along its longest flat-enough line from ({found.start[0] * mm:.1f}, '
            f'{found.start[1] * mm:.1f}) to ({found.end[0] * mm:.1f}, {found.end[1] * mm:.1f}) '
            f'mm ({found.length * mm:.1f} mm long, surface at z = {found.height * mm:.1f} mm; '
            f'file coordinates)')
    return replace(config, wound=replace(w, line=points, n_pairs=n_pairs)), T, note


def build_phantom(config: PhantomConfig, name: str = 'phantom',
                  base_dir: str | Path | None = None) -> Phantom:
    """
    Build a phantom from its configuration.

    Parameters
    ----------
    config : PhantomConfig
        Configuration (kind, size, pose, wound, markers).
    name : str
        Name of the phantom in the scene.
    base_dir : str or Path, optional
        Directory against which a relative ``config.mesh`` path is resolved.

    Returns
    -------
    Phantom

    Raises
    ------
    ValueError
        If the mesh file cannot be read, or a marker falls outside the pad.

    """
    T_phantom_file, placement = None, ''
    if config.kind == 'mesh':
        mesh, surface, wound, config, T_phantom_file, placement = _load_user_mesh(config,
                                                                                  base_dir)
    else:
        mesh, surface, wound = _generated(config)
    markers = place_markers(config, surface, wound)
    if placement:
        _LOG.info('phantom %s: %s', name, placement)
    phantom = Phantom(name, config, mesh, surface, wound, markers)
    phantom.placement = placement
    phantom.T_phantom_file = np.eye(4) if T_phantom_file is None else T_phantom_file
    return phantom
