"""
Scene configuration (``config/scene.yaml``): needle, thread, phantoms, tissue, scoring, expert.

``load_scene_config`` reads the YAML file through :mod:`sim_bridge.configfile` into frozen
dataclasses. Errors name the file, the key and what was expected. Relative phantom mesh paths
are resolved against the directory of the YAML file.
"""

from dataclasses import dataclass, field, replace
from pathlib import Path

from sim_bridge.configfile import ConfigError, dataclass_from_mapping, load_yaml
from sim_bridge.control import ExpertConfig
from sim_bridge.paths import config_path
from sim_bridge.scene.needle import NeedleGeometry, ThreadGeometry
from sim_bridge.scene.phantom import PhantomConfig, build_phantom
from sim_bridge.scene.scoring import ScoringConfig
from sim_bridge.scene.tissue import TissueConfig


def _default_phantoms():
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

    def phantom_config(self, name=None):
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

    def build_phantom(self, name=None):
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

    def phantom_for_pair(self, pair):
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


def load_scene_config(path=None):
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
            mesh = Path(cfg.mesh)
            if not mesh.is_absolute():
                mesh = path.parent / mesh
            if not mesh.is_file():
                raise ConfigError(f"{source}: key 'phantoms.{name}.mesh': cannot read mesh "
                                  f'file {mesh} (expected an STL, OBJ or PLY file)')
            cfg = replace(cfg, mesh=str(mesh))
        phantoms[name] = cfg
    return replace(scene, phantoms=phantoms)
