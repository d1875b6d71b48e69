"""
The suturing task of a simulated scene: what the evaluation knows and the robot does not.

The scene is split the way dm_control splits an environment: the physics (arms, needle, grasp,
tissue, thread; :class:`sim_bridge.simulation.Simulation`), the task (this module: the target
marker pair, the markers' and the needle's ground truth, the throw's scoring) and the loop
(:meth:`sim_bridge.simulation.Simulation.run`, which asks an observer,
:mod:`sim_bridge.observers`, what a controller sees). Ground truth belongs to the task: the
scorer, the study's report and the viewer read it; a controller only sees what its observer
gives it.

Frames: ``world`` (z up, phantom at the origin); poses 4x4 ``T_world_*``; SI units.
"""

from collections.abc import Callable, Iterable

import numpy as np
from sim_bridge.scene.markers import marker_frame
from sim_bridge.scene.phantom import MarkerPair, Phantom
from sim_bridge.scene.scoring import ScoringConfig, ThrowScore, ThrowScorer


class SuturingTask:
    """
    The target pair, the markers' and needle's ground truth, and the scoring of a throw.

    Parameters
    ----------
    phantom : sim_bridge.scene.phantom.Phantom
        The phantom with its marker pairs.
    scoring : sim_bridge.scene.scoring.ScoringConfig
        Scoring rules (``scoring`` of ``config/scene.yaml``).
    emit : callable
        ``emit(kind, **data)``: records a scene event (``score`` here).
    needle_pose : callable
        ``needle_pose() -> ndarray (4, 4)``: the needle's true pose in ``world`` (read-only;
        the physics owns it).

    """

    def __init__(self, phantom: Phantom, scoring: ScoringConfig, emit: Callable[..., None],
                 needle_pose: Callable[[], np.ndarray]) -> None:
        self.phantom = phantom
        self._scoring = scoring
        self._emit = emit
        self._needle_pose = needle_pose
        self._pair: MarkerPair | None = None
        self.scorer: ThrowScorer | None = None
        self._last_score: tuple | None = None

    # ------------------------------------------------------------------ target and scoring
    def start(self, name: str, t: float, holders: Iterable[str]) -> None:
        """
        Aim the throw at a marker pair and start its scoring afresh at time ``t``.

        Parameters
        ----------
        name : str
            Pair name (``'synth1'``).
        t : float
            Simulation time (s) the throw starts.
        holders : tuple of str
            Arms holding the needle now (their grasps count from ``t``).

        """
        if name not in self.phantom.markers:
            raise ValueError(f'unknown marker pair {name!r}; the phantom has '
                             f'{sorted(self.phantom.markers)}')
        self._pair = self.phantom.markers[name]
        self.scorer = ThrowScorer(self._scoring, t_start=t)
        for arm in holders:
            self.scorer.on_grasp(t, arm)
        self._last_score = None

    def report_score(self, t: float) -> None:
        """Emit a ``score`` event if the score or a subtask's outcome changed at time ``t``."""
        result = self.scorer.result(t)
        key = (result.score, tuple(sorted(result.subtasks.items())))
        if key != self._last_score:
            self._last_score = key
            self._emit('score', score=result)

    def score(self, t: float) -> ThrowScore:
        """
        Score of the current throw at time ``t``.

        Returns
        -------
        sim_bridge.scene.scoring.ThrowScore

        """
        return self.scorer.result(t)

    # ------------------------------------------------------------------ ground truth
    @property
    def pair(self) -> MarkerPair | None:
        """The target :class:`~sim_bridge.scene.phantom.MarkerPair` (``world``)."""
        return self._pair

    def needle_pose(self) -> np.ndarray:
        """Needle frame in ``world``, shape (4, 4) (a copy)."""
        return np.array(self._needle_pose())

    def phantom_pose(self) -> np.ndarray:
        """Phantom frame in ``world``, shape (4, 4) (a copy)."""
        return self.phantom.T_world_phantom.copy()

    def marker_poses(self) -> dict[str, np.ndarray]:
        """
        Frames of the red markers in ``world``.

        Returns
        -------
        dict of str to ndarray, shape (4, 4)
            ``'<pair>.entry'`` and ``'<pair>.exit'``: origin at the marker centre on the
            surface, ``z`` the surface normal, ``x`` towards the pair's other marker.

        """
        out = {}
        for pair in self.phantom.markers.values():
            for which, point, normal, other in (
                    ('entry', pair.entry, pair.entry_normal, pair.exit),
                    ('exit', pair.exit, pair.exit_normal, pair.entry)):
                out[f'{pair.name}.{which}'] = marker_frame(point, normal, other)
        return out
