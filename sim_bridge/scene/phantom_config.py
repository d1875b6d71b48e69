"""
Configuration of a suture phantom: its kind, size and pose, wound line and marker pairs.

The keys are those of the ``phantom`` sections of ``config/scene.yaml`` and of a phantom file;
:func:`sim_bridge.scene.phantom.build_phantom` makes a phantom of one.
"""

from dataclasses import dataclass, field

import numpy as np
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.common.validation import check_positive, check_quaternions
from sim_bridge.scene.mesh_placement import WoundSearch
from sim_bridge.scene.phantom_shapes import ScannedShape

KINDS = ('synthetic', 'scanned', 'mesh')
FRAMES = ('file', 'wound')


@dataclass(frozen=True)
class WoundConfig:
    """
    Wound line and the markers placed along it (phantom frame, metres).

    Attributes
    ----------
    line : tuple of (x, y)
        Control points of the wound curve in the phantom's x-y plane (in the file's x-y plane
        for a mesh with ``frame: wound``); empty for a user mesh: found on its top surface.
    slit_width : float
        Width of the slit cut into the generated mesh (0: no slit).
    slit_depth : float
        Depth of the slit below the surface.
    n_pairs : int
        Number of entry/exit pairs placed along the wound.
    spacing : float
        Arc-length distance between neighbouring pairs.
    half_width : float
        Distance of entry and exit from the wound line (in x-y).
    entry_side : int
        +1: entry on the wound's left (``z x tangent``), -1: on its right.
    offset : float
        Arc-length shift of the pair pattern from the wound's middle.

    """

    line: tuple[tuple[float, float], ...] = ((-0.025, 0.0), (0.025, 0.0))
    slit_width: float = 0.0008
    slit_depth: float = 0.004
    n_pairs: int = 4
    spacing: float = 0.012
    half_width: float = 0.004
    entry_side: int = 1
    offset: float = 0.0

    def __post_init__(self) -> None:
        if len(self.line) == 1:
            raise ValueError('wound line needs at least two (x, y) points (or none on a user '
                             'mesh: found on its top surface)')
        if self.entry_side not in (-1, 1):
            raise ValueError(f'wound entry_side must be +1 or -1, got {self.entry_side}')
        if self.n_pairs < 0:
            raise ValueError(f'wound n_pairs must be >= 0, got {self.n_pairs}')
        check_positive(self.half_width, 'wound half_width (m)')
        if self.slit_width < 0.0 or self.slit_depth < 0.0:
            raise ValueError('wound slit_width and slit_depth must be >= 0 m')


@dataclass(frozen=True)
class MarkerConfig:
    """
    One entry/exit pair given explicitly (x-y in the phantom frame, metres).

    Attributes
    ----------
    entry : (x, y)
        Entry marker; its height is taken from the surface.
    exit : (x, y)
        Exit marker.

    """

    entry: tuple[float, float]
    exit: tuple[float, float]


@dataclass(frozen=True)
class PhantomConfig:
    """
    One phantom of the scene.

    Attributes
    ----------
    kind : str
        ``'synthetic'``, ``'scanned'`` or ``'mesh'``.
    marker_prefix : str
        Marker pair names are ``<prefix>1 .. <prefix>n`` (``synth``, ``scan``).
    size : (length, width, thickness)
        Pad size (m) of generated phantoms.
    seed : int
        Seed of the scanned pad's bumps.
    position : (x, y, z)
        Phantom frame origin in the world (m).
    quaternion : (x, y, z, w)
        Phantom frame orientation in the world.
    mesh : str or None
        Mesh file (STL, OBJ, PLY) for kind ``mesh``; relative paths are resolved against the
        config file's directory.
    mesh_scale : float
        Factor applied to the mesh file's coordinates (0.001 for a file in millimetres).
    resolution : float
        Grid spacing (m) of the tissue height field.
    mesh_resolution : float
        Grid spacing (m) of generated meshes.
    wound_closing : float
        Gaps narrower than this (m) are closed in a user mesh's tissue surface.
    frame : str
        User mesh only: ``'file'`` (the file's coordinates are the phantom frame) or
        ``'wound'`` (the phantom frame of the wound: origin on the surface at the wound's
        centre, ``x`` along it; wound line and markers given in file coordinates).
    wound_search : WoundSearch
        How a user mesh without wound line or markers gets one (top band, slope limit).
    wound : WoundConfig
        Wound line, slit and marker placement.
    markers : dict of MarkerConfig or None
        Explicit marker pairs by name; replaces placement along the wound.
    shape : ScannedShape
        Surface shape of the scanned pad.
    rgba : (r, g, b, a)
        Pad colour.
    marker_radius : float
        Radius (m) of the red marker discs.
    marker_rgba : (r, g, b, a)
        Marker colour.

    """

    kind: str = 'synthetic'
    marker_prefix: str = 'synth'
    size: tuple[float, float, float] = (0.060, 0.040, 0.010)
    seed: int = 0
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    mesh: str | None = None
    mesh_scale: float = 1.0
    resolution: float = 0.00025
    mesh_resolution: float = 0.002
    wound_closing: float = 0.002
    frame: str = 'file'
    wound_search: WoundSearch = field(default_factory=WoundSearch)
    wound: WoundConfig = field(default_factory=WoundConfig)
    markers: dict[str, MarkerConfig] | None = None
    shape: ScannedShape = field(default_factory=ScannedShape)
    rgba: tuple[float, float, float, float] = (0.93, 0.72, 0.68, 1.0)
    marker_radius: float = 0.0015
    marker_rgba: tuple[float, float, float, float] = (0.9, 0.05, 0.05, 1.0)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f'phantom kind must be one of {KINDS}, got {self.kind!r}')
        if self.kind == 'mesh' and not self.mesh:
            raise ValueError("phantom kind 'mesh' needs a mesh file (key 'mesh')")
        if self.kind != 'mesh' and len(self.wound.line) < 2:
            raise ValueError(f'phantom kind {self.kind!r} needs a wound line of at least two '
                             f'(x, y) points (key wound.line)')
        if self.frame not in FRAMES:
            raise ValueError(f'phantom frame must be one of {FRAMES}, got {self.frame!r}')
        if min(self.size) <= 0.0:
            raise ValueError(f'phantom size must be positive (m), got {self.size}')
        if not 0.0 < self.resolution <= 0.001:
            raise ValueError(f'phantom resolution must be in (0, 0.001] m, got '
                             f'{self.resolution}')
        check_positive(self.mesh_resolution, 'phantom mesh_resolution (m)')
        check_positive(self.mesh_scale, 'phantom mesh_scale')
        check_quaternions(self.quaternion, 'phantom quaternion')

    @property
    def T_world_phantom(self) -> np.ndarray:  # noqa: N802 (the project names poses T_a_b)
        """Phantom pose in the world, shape (4, 4)."""
        T = np.eye(4)
        q = check_quaternions(self.quaternion, 'phantom quaternion')
        T[:3, :3] = matrix_from_quaternion(q)
        T[:3, 3] = self.position
        return T
