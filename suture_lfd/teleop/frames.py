"""
A small tree of named frames, for the rotations between the MTM's, the PSM's and the camera's.

Edges come from ``/tf_static`` (``world -> <ARM>_base`` in simulation) and from the arms'
``measured_cp`` (``frame_id -> <ARM>``, as the dVRK's tf broadcaster names them: the ECM's
moving frame ``ECM`` is the camera). :meth:`FrameTree.transform` walks both frames up to a
common root. Poses are 4x4 matrices; ``T_a_b`` maps ``b`` coordinates into ``a``.
"""

import numpy as np
from numpy.typing import ArrayLike


class FrameTree:
    """Parent links ``child -> (parent, T_parent_child)``."""

    def __init__(self) -> None:
        self._parent: dict[str, tuple[str, np.ndarray]] = {}

    def set(self, parent: str, child: str, T_parent_child: ArrayLike) -> None:
        """Add or replace the edge ``parent -> child``."""
        if parent == child:
            return
        self._parent[child] = (parent, np.asarray(T_parent_child, dtype=float))

    def knows(self, frame: str) -> bool:
        """Whether ``frame`` is in the tree (as a child or a parent)."""
        return frame in self._parent or any(p == frame for p, _ in self._parent.values())

    def _to_root(self, frame: str) -> tuple[str, np.ndarray]:
        """Return ``(root, T_root_frame)`` following parents (at most 32 links)."""
        T = np.eye(4)
        for _ in range(32):
            link = self._parent.get(frame)
            if link is None:
                return frame, T
            frame, T_parent = link[0], link[1]
            T = T_parent @ T
        raise ValueError(f'frame tree: a loop through {frame!r}')

    def transform(self, target: str, source: str) -> np.ndarray | None:
        """Return ``T_target_source`` (4x4), or None if the frames are not connected."""
        if target == source:
            return np.eye(4)
        root_t, T_rt = self._to_root(target)
        root_s, T_rs = self._to_root(source)
        if root_t != root_s:
            return None
        return np.linalg.solve(T_rt, T_rs)

    def rotation(self, target: str, source: str) -> np.ndarray | None:
        """Return ``R_target_source`` (3x3), or None if the frames are not connected."""
        T = self.transform(target, source)
        return None if T is None else T[:3, :3]
