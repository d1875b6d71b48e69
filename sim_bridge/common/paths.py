"""
Where the package's installed data lives (configuration files, meshes).

Looks in the install prefix first (``<prefix>/share/suture_lfd``, as colcon and ``pip install``
lay it out), then in every ``AMENT_PREFIX_PATH`` entry, then in the source checkout.
"""

import os
from pathlib import Path
import sys

PACKAGE = 'suture_lfd'


def share_dir():
    """
    Return the package's share directory (holding ``config/``).

    Returns
    -------
    Path
        Directory that contains ``config/``.

    """
    candidates = [Path(sys.prefix) / 'share' / PACKAGE]
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / 'share' / PACKAGE)
    # Installed next to the Python package (colcon: <prefix>/lib/pythonX/site-packages/..).
    here = Path(__file__).resolve().parent.parent  # the sim_bridge package
    for parent in here.parents[:5]:
        candidates.append(parent / 'share' / PACKAGE)
    candidates.append(here.parent)  # source checkout (editable install)
    for candidate in candidates:
        if (candidate / 'config').is_dir():
            return candidate
    raise FileNotFoundError(
        f'cannot find the {PACKAGE} config directory; looked in '
        + ', '.join(str(c) for c in candidates))


def config_path(name):
    """
    Return the path of an installed configuration file.

    Parameters
    ----------
    name : str
        File name inside ``config/`` (``'simulator.yaml'``).

    Returns
    -------
    Path
        Absolute path.

    """
    return share_dir() / 'config' / name
