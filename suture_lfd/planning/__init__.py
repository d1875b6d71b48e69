"""
Task planning of a throw: what the arms should do, not how the simulation does it.

- :mod:`~suture_lfd.planning.throw_geometry`: the needle's circle through an entry/exit pair.
- :mod:`~suture_lfd.planning.suturing_frames`: suture frames of pairs and grasp transforms.
- :mod:`~suture_lfd.planning.waypoints`: minimum-jerk tool and needle motions.
- :mod:`~suture_lfd.planning.grasps`: :class:`~suture_lfd.planning.grasps.GraspPlanner`, the
  choice of reachable grasps.
- :mod:`~suture_lfd.planning.tracks`: :class:`~suture_lfd.planning.tracks.Track`, one arm's
  timeline under construction.
- :mod:`~suture_lfd.planning.plan`: :class:`~suture_lfd.planning.plan.Plan` and the
  :class:`~suture_lfd.planning.plan.PlanFollower` that runs it in closed loop.
- :mod:`~suture_lfd.planning.throw`: :func:`~suture_lfd.planning.throw.plan_throw`, the one
  throw planner, around the needle paths of subtasks ii and iv it is given.
- :mod:`~suture_lfd.planning.expert`: the scripted expert (its needle paths turn about the
  throw circle); the DMP executor (:mod:`suture_lfd.skill.executor`) passes DMP rollouts.
- :mod:`~suture_lfd.planning.episode`: one throw in-process (start, control loop, settle).

The controller interface (observation, command) is :mod:`sim_bridge.control`.
"""
