"""
Demonstrations: the recorded data of a throw and the ways to make it.

- :mod:`~suture_lfd.demos.demonstration`: the :class:`Demonstration` record.
- :mod:`~suture_lfd.demos.cohort`: simulated subjects and their skill profiles.
- :mod:`~suture_lfd.demos.demonstrator`: a simulated subject performing a throw.
- :mod:`~suture_lfd.demos.scripted_demo`: an open-loop demonstration from the scripted expert.
- :mod:`~suture_lfd.demos.synthetic_throw`: a synthetic needle throw (no simulation).
- :mod:`~suture_lfd.demos.demo_bag`: demonstrations to and from bag files.
- :mod:`~suture_lfd.demos.resampling`: resampling poses and quaternions in time.
- :mod:`~suture_lfd.demos.segment_file`: the segment file the executor learns from.
"""
