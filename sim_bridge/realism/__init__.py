"""
How far a physical dVRK is from a perfect simulation: one small module per imperfection.

Each effect sits between the truth (physics, task) and what the robot and its camera show, and
has a *level*: 0 is off and keeps the simulation bit-identical to an ideal one; a named preset
(``dvrk`` for the arms and the endoscope, ``tissue`` for the needle in tissue) sets magnitudes
cited from the literature in the preset's config file (``config/realism_*.yaml``).

The arm, the physics and the camera compose these modules through one narrow interface each,
so that a controller meets them only through what an observer shows it.
"""
