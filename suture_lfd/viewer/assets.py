"""
What the viewer draws that no topic carries: the phantom mesh and the needle's arc.

Both come from the package configuration (``config/scene.yaml``), as the simulator builds them,
so a viewer started with the simulator's ``phantom`` parameter draws the same pad.
"""

from dataclasses import replace
import math
from pathlib import Path
from typing import TYPE_CHECKING

from sim_bridge.scene.phantom import build_phantom
from sim_bridge.simulation import load_simulation_config

if TYPE_CHECKING:
    import numpy as np
    from sim_bridge.scene.phantom import Phantom
    from sim_bridge.simulation_config import SimulationConfig


def load_phantom(phantom: str = 'synthetic', config: 'SimulationConfig | None' = None
                 ) -> 'Phantom':
    """
    Build the phantom the simulator builds for its ``phantom`` parameter.

    Parameters
    ----------
    phantom : str
        A phantom of ``config/scene.yaml`` (``synthetic``, ``scanned``) or an STL/OBJ/PLY file.
    config : sim_bridge.simulation.SimulationConfig, optional
        Default: the package's configuration.

    Returns
    -------
    sim_bridge.phantom.Phantom
        Its ``mesh`` is in the ``phantom`` frame, ``T_world_phantom`` places it.

    """
    scene = (config or load_simulation_config()).scene
    if str(phantom) in scene.phantoms:
        return scene.build_phantom(str(phantom))
    path = Path(phantom)
    if path.suffix.lower() not in ('.stl', '.obj', '.ply') or not path.is_file():
        raise ValueError(f'phantom must be one of {sorted(scene.phantoms)} or an existing STL, '
                         f'OBJ or PLY mesh file, got {phantom!r}')
    template = scene.phantoms.get('synthetic', next(iter(scene.phantoms.values())))
    return build_phantom(replace(template, kind='mesh', mesh=str(path), marker_prefix='mesh'),
                         name=path.stem)


def phantom_of_pair(pair: str) -> str:
    """Return the phantom a marker pair belongs to, from its name (``scan2``: ``scanned``)."""
    return 'scanned' if str(pair).startswith('scan') else 'synthetic'


def needle_arc(config: 'SimulationConfig | None' = None, n: int = 32
               ) -> 'tuple[np.ndarray, float]':
    """
    Return the needle's wire centre line in the ``needle`` frame and its diameter.

    Returns
    -------
    points : ndarray, shape (n, 3)
        Arc from tail to tip (m).
    diameter : float
        Wire diameter (m).

    """
    needle = (config or load_simulation_config()).scene.needle
    return needle.arc_points(n), needle.wire_diameter


def endoscope_fov(config: 'SimulationConfig | None' = None) -> float:
    """
    Return the vertical field of view (rad) of the ECM's cameras, from the camera model.

    ``fy`` (pixels) when the configuration gives it, otherwise ``vertical_fov``.
    """
    camera = (config or load_simulation_config()).camera
    if camera.fy > 0:
        return 2.0 * math.atan(0.5 * camera.height / camera.fy)
    return float(camera.vertical_fov)
