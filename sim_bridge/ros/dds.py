"""
The DDS settings every process of the project starts with: ``config/fastdds.xml``.

:func:`use_project_profile` points Fast DDS at the project's profile (why it exists: the file's
comment) unless the user has named a profile file of their own; it must run before rclpy creates
the process's first participant (``rclpy.init``), and the node entry point and the test harness
call it then. Child processes inherit it through the environment.
"""

import os

from sim_bridge.common.paths import config_path

PROFILE = 'fastdds.xml'
# Fast DDS 2.x reads the first, 3.x the second
PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def use_project_profile(env=None):
    """
    Name the project's Fast DDS profile in ``env`` unless a profile file is named already.

    Parameters
    ----------
    env : dict, optional
        Environment to change (default ``os.environ``, which Fast DDS reads).

    Returns
    -------
    str
        The profile file in use.

    """
    env = os.environ if env is None else env
    for name in PROFILE_VARIABLES:
        if env.get(name):
            return env[name]
    path = str(config_path(PROFILE))
    for name in PROFILE_VARIABLES:
        env[name] = path
    return path
