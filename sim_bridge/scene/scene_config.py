"""
Scene configuration (``config/scene.yaml``): needle, thread, phantoms, tissue, scoring, expert.

``load_scene_config`` reads the YAML file through :mod:`sim_bridge.common.configfile` into frozen
dataclasses. Errors name the file, the key and what was expected. Relative phantom mesh paths
are resolved against the directory of the YAML file.

A *phantom file* (:func:`load_phantom_file`) describes one user phantom with the keys of a
``phantoms.<name>`` entry of ``scene.yaml``; unlike there, ``kind`` defaults to ``mesh``,
``frame`` to ``wound`` (wound line and markers in the mesh file's coordinates; without them the
wound is found on the mesh's top surface) and ``marker_prefix`` to ``mesh``::

    mesh: my_pad.obj              # STL, OBJ or PLY, z up; relative to this file
    mesh_scale: 0.001             # the file is in millimetres
    position: [0.0, 0.0, 0.0]     # phantom frame (the wound's centre) in the world
    quaternion: [0.0, 0.0, 0.0, 1.0]
    wound:                        # optional
      line: [[0.040, 0.077], [0.110, 0.077]]   # file coordinates (m, after mesh_scale)
      n_pairs: 4
      spacing: 0.012
      half_width: 0.004
"""

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import cast

from sim_bridge.common.configfile import ConfigError, dataclass_from_mapping, load_yaml
from sim_bridge.common.needle import NeedleGeometry, ThreadGeometry
from sim_bridge.common.paths import config_path
from sim_bridge.control import ExpertConfig
from sim_bridge.scene.phantom import Phantom, PhantomConfig, build_phantom
from sim_bridge.scene.scoring import ScoringConfig
from sim_bridge.scene.tissue import TissueConfig

PHANTOM_FILE_DEFAULTS = {'kind': 'mesh', 'frame': 'wound', 'marker_prefix': 'mesh'}
MESH_SUFFIXES = ('.stl', '.obj', '.ply')


def _default_phantoms() -> dict[str, PhantomConfig]:
    return {'synthetic': PhantomConfig()}


@dataclass(frozen=True)
class SceneConfig:
    """
    The suturing scene.

    Attributes
    ----------
    needle : NeedleGeometry
        Needle geometry and canonical grasp.
    thread : ThreadGeometry
        Thread capsule chain.
    phantoms : dict of PhantomConfig
        Phantoms by name (``synthetic``, ``scanned``).
    active_phantom : str
        Name of the phantom placed in the world.
    tissue : TissueConfig
        Needle-tissue tracker settings.
    scoring : ScoringConfig
        Throw scoring tolerances.
    expert : ExpertConfig
        Motion parameters of the scripted expert.

    """

    needle: NeedleGeometry = field(default_factory=NeedleGeometry)
    thread: ThreadGeometry = field(default_factory=ThreadGeometry)
    phantoms: dict[str, PhantomConfig] = field(default_factory=_default_phantoms)
    active_phantom: str = 'synthetic'
    tissue: TissueConfig = field(default_factory=TissueConfig)
    scoring: ScoringConfig = field(default_factory=ScoringConfig)
    expert: ExpertConfig = field(default_factory=ExpertConfig)

    def phantom_config(self, name: str | None = None) -> PhantomConfig:
        """
        Return the configuration of a phantom.

        Parameters
        ----------
        name : str, optional
            Phantom name (default: ``active_phantom``).

        Returns
        -------
        PhantomConfig

        """
        name = self.active_phantom if name is None else name
        if name not in self.phantoms:
            raise ValueError(f'unknown phantom {name!r}; the scene has {sorted(self.phantoms)}')
        return self.phantoms[name]

    def build_phantom(self, name: str | None = None) -> Phantom:
        """
        Build a phantom of the scene.

        Parameters
        ----------
        name : str, optional
            Phantom name (default: ``active_phantom``).

        Returns
        -------
        sim_bridge.scene.phantom.Phantom

        """
        name = self.active_phantom if name is None else name
        return build_phantom(self.phantom_config(name), name=name)

    def phantom_for_pair(self, pair: str) -> str:
        """
        Return the phantom whose marker prefix names the pair (``'scan2'`` -> ``'scanned'``).

        Parameters
        ----------
        pair : str
            Marker pair name.

        Returns
        -------
        str

        """
        for name, cfg in self.phantoms.items():
            if cfg.markers and pair in cfg.markers:
                return name
            suffix = pair[len(cfg.marker_prefix):]
            if pair.startswith(cfg.marker_prefix) and suffix.isdigit():
                return name
        raise ValueError(f'no phantom of the scene has marker pair {pair!r}')


def load_scene_config(path: str | Path | None = None) -> 'SceneConfig':
    """
    Read the scene configuration.

    Parameters
    ----------
    path : str or Path, optional
        YAML file (default: the installed ``config/scene.yaml``).

    Returns
    -------
    SceneConfig

    Raises
    ------
    ConfigError
        Unreadable file, unknown key, missing value, wrong type, invalid value or a phantom
        mesh file that cannot be read; the message names the file and the key.

    """
    path = Path(config_path('scene.yaml') if path is None else path)
    source = str(path)
    data = load_yaml(path)
    try:
        scene = dataclass_from_mapping(SceneConfig, data, source=source)
    except ConfigError:
        raise
    except ValueError as exc:
        raise ConfigError(f'{source}: invalid value: {exc}') from exc
    if scene.active_phantom not in scene.phantoms:
        raise ConfigError(f"{source}: key 'active_phantom' must name one of the phantoms "
                          f'{sorted(scene.phantoms)}, got {scene.active_phantom!r}')
    phantoms = {}
    for name, cfg in scene.phantoms.items():
        if cfg.mesh:
            cfg = _resolve_mesh(cfg, path.parent, source, f'phantoms.{name}.mesh')
        phantoms[name] = cfg
    return replace(scene, phantoms=phantoms)


def _resolve_mesh(cfg: PhantomConfig, base: str | Path, source: object,
                  key: str) -> PhantomConfig:
    mesh = Path(cast(str, cfg.mesh))  # both callers check that cfg.mesh is set
    if not mesh.is_absolute():
        mesh = Path(base) / mesh
    if not mesh.is_file():
        raise ConfigError(f"{source}: key '{key}': cannot read mesh file {mesh} (expected an "
                          f'STL, OBJ or PLY file)')
    return replace(cfg, mesh=str(mesh))


def load_phantom_file(path: str | Path,
                      template: PhantomConfig | None = None) -> PhantomConfig:
    """
    Read a phantom file: one user phantom (mesh, scale, pose, wound line or markers).

    Parameters
    ----------
    path : str or Path
        YAML file with the keys of a ``phantoms.<name>`` entry of ``scene.yaml``.
    template : PhantomConfig, optional
        Values of the keys the file leaves out (marker size and colour, grid resolution, wound
        spacing); the file's defaults (``kind`` mesh, ``frame`` wound, ``marker_prefix`` mesh,
        no wound line) override it.

    Returns
    -------
    PhantomConfig

    Raises
    ------
    ConfigError
        Unreadable file, unknown key, wrong type or invalid value, or a mesh file that cannot
        be read; the message names the file and the key.

    """
    path = Path(path)
    source = str(path)
    data = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f'{source}: expected a mapping of phantom keys (mesh, mesh_scale, '
                          f'position, quaternion, wound, markers)')
    base = {}
    if template is not None:
        base = {f.name: getattr(template, f.name) for f in fields(template)
                if f.name not in ('markers', 'mesh', 'shape', 'wound', 'wound_search')}
        base['wound'] = {f.name: getattr(template.wound, f.name)
                         for f in fields(template.wound)}
    merged = {**base, **PHANTOM_FILE_DEFAULTS, **data}
    wound = {**base.get('wound', {}), 'line': [], **(data.get('wound') or {})}
    merged['wound'] = wound
    try:
        cfg = dataclass_from_mapping(PhantomConfig, merged, source=source)
    except ConfigError:
        raise
    except ValueError as exc:
        raise ConfigError(f'{source}: invalid value: {exc}') from exc
    if not cfg.mesh:
        raise ConfigError(f"{source}: key 'mesh' is missing (expected an STL, OBJ or PLY file)")
    return _resolve_mesh(cfg, path.parent, source, 'mesh')


def phantom_from_argument(scene: 'SceneConfig', phantom: str | Path | PhantomConfig
                          ) -> tuple[str, PhantomConfig]:
    """
    Return the phantom configuration a ``phantom`` argument names.

    Parameters
    ----------
    scene : SceneConfig
        The scene (its phantoms are the templates).
    phantom : str or Path or PhantomConfig
        A phantom of the scene (``'synthetic'``, ``'scanned'``), a mesh file (STL, OBJ, PLY in
        metres, z up; markers on its top surface), a phantom file (``.yaml``) or a
        configuration.

    Returns
    -------
    name : str
        Phantom name (the scene's name, or the file's stem).
    config : PhantomConfig

    Raises
    ------
    ValueError
        Neither a phantom of the scene nor a readable mesh or phantom file.

    """
    if isinstance(phantom, PhantomConfig):
        return 'phantom', phantom
    if str(phantom) in scene.phantoms:
        return str(phantom), scene.phantoms[str(phantom)]
    path = Path(phantom)
    template = scene.phantoms.get('synthetic', next(iter(scene.phantoms.values())))
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES + ('.yaml', '.yml'):
        raise ValueError(f'phantom must be one of {sorted(scene.phantoms)}, an STL, OBJ or PLY '
                         f'mesh file or a phantom file (.yaml), got {str(phantom)!r}')
    if not path.is_file():
        raise ValueError(f'phantom file {path} does not exist')
    if suffix in ('.yaml', '.yml'):
        return path.stem, load_phantom_file(path, template)
    wound = replace(template.wound, line=())
    return path.stem, replace(template, kind='mesh', mesh=str(path), marker_prefix='mesh',
                              frame='wound', wound=wound)
