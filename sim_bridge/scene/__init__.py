"""
The scene on the table: world and bodies, needle and thread, phantoms, tissue, grasps, camera.

- :mod:`~sim_bridge.scene.world`: the PyBullet world (table, arms' bases, light, gravity).
- :mod:`~sim_bridge.common.needle`: needle and thread geometry.
- :mod:`~sim_bridge.scene.thread`: the thread's chain dynamics.
- :mod:`~sim_bridge.scene.phantom`, :mod:`~sim_bridge.scene.phantom_config`,
  :mod:`~sim_bridge.scene.phantom_shapes`, :mod:`~sim_bridge.scene.markers`,
  :mod:`~sim_bridge.scene.heightfield`: the synthetic and scanned phantoms with their marker pairs.
- :mod:`~sim_bridge.scene.tissue`: the needle's passage through the tissue.
- :mod:`~sim_bridge.scene.grasp`: jaw grasps of the needle.
- :mod:`~sim_bridge.scene.camera`: the ECM's stereo camera.
- :mod:`~sim_bridge.scene.scoring`: scoring a throw.
- :mod:`~sim_bridge.scene.scene_config`: ``config/scene.yaml``.

No module here imports rclpy; frames and units are those of :mod:`sim_bridge`.
"""
