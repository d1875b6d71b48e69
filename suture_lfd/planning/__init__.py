"""
Task planning of a throw: what the arms should do, not how the simulation does it.

- :mod:`~suture_lfd.planning.throw_geometry`: the needle's circle through an entry/exit pair.
- :mod:`~suture_lfd.planning.suturing_frames`: suture frames of pairs and grasp transforms.
- :mod:`~suture_lfd.planning.waypoints`: minimum-jerk tool and needle motions.
- :mod:`~suture_lfd.planning.expert`: the scripted expert (grasp choice, tracks, throw plan).

The controller interface (observation, command) is :mod:`sim_bridge.control`.
"""
