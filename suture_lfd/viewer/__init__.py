"""
The browser viewer: a viser page of the simulated scene, its replay and offline pictures.

No rclpy here: :mod:`suture_lfd.nodes.viewer` feeds the page from ROS topics, ``suture-lfd view``
from a bag or a study. Modules: :mod:`~suture_lfd.viewer.scene` (the 3-D scene, posed from a
transform tree), :mod:`~suture_lfd.viewer.page` (the server, the events panel, plug-in panels),
:mod:`~suture_lfd.viewer.controls` (the virtual MTMs' browser input), :mod:`~suture_lfd.viewer.
replay` (recordings of bags and study throws, the time slider) and
:mod:`~suture_lfd.viewer.filmstrip` (PNG frames from the ECM's point of view).
"""
