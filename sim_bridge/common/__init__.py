"""
The foundation both packages stand on.

Geometry, validation, configuration files, paths, errors, CDR, child processes, the needle's
geometry and the project's vocabulary.

Nothing here imports the simulator (the rest of :mod:`sim_bridge`), the learning-from-
demonstration package (:mod:`suture_lfd`) or ROS; ``test/test_architecture.py`` keeps it so.

- :mod:`~sim_bridge.common.geometry`: rigid transforms and quaternions ``(x, y, z, w)``.
- :mod:`~sim_bridge.common.validation`: array and argument checks with errors that say what to fix.
- :mod:`~sim_bridge.common.configfile`: YAML files read into dataclasses.
- :mod:`~sim_bridge.common.paths`: where the installed configuration lives.
- :mod:`~sim_bridge.common.errors`: the configuration error shared by both packages.
- :mod:`~sim_bridge.common.cdr`: ROS 2 message bytes without rclpy.
- :mod:`~sim_bridge.common.processes`: child processes that die with their parent.
- :mod:`~sim_bridge.common.needle`: the suture needle's and thread's geometry.
- :mod:`~sim_bridge.common.vocabulary`: arm names, subtasks, learnt tasks, tolerances.
"""
