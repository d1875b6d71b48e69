"""
Watching the grasp during the DMP subtasks: the needle can turn in the jaw on tissue.

On tissue the needle driver holds the needle only as well as its grip allows: the tissue's push
can turn the needle in the jaw during the insertion (PSM2, subtask ii) or the extraction (PSM1,
subtask iv), and the tool then carries a needle that is no longer where the rollout wants it.

- **Ground truth** (the grasp observed every step, ``T_tool_needle = inv(T_world_tool) @
  T_world_needle``): :class:`SlipWatch` compares the observed grasp with the one followed. Once
  they differ by more than the thresholds and the observed grasp has stayed the same for
  :data:`SETTLE` observations (the slip is over), the observed grasp is followed from then on,
  so the *needle*, not the tool, keeps to the rollout -- at most ``corrections`` times per DMP
  subtask: pushing the needle straight back onto a rollout the grip cannot hold makes the tissue
  turn it again and again until the grasp breaks.
- **Physical mode** (the grasp measured only when the robot looks): :func:`slip_checkpoints`
  spreads looks at the holding arm's grasp over each DMP subtask.

Frames: ``world``; grasps ``T_tool_needle`` 4x4; radians, metres, seconds.
"""

import math

import numpy as np
from sim_bridge.common.vocabulary import TASKS

#: Observations of the same new grasp after which a slip in the jaw counts as over.
SETTLE = 5
#: Looks at the grasp per DMP subtask in physical mode when the tissue realism is on.
TISSUE_LOOKS = 2


def holding_arm(label: str) -> str:
    """Return the arm that carries the needle through DMP subtask ``label`` (``'ii'``/``'iv'``)."""
    return 'PSM2' if label == 'ii' else 'PSM1'


def observed_grasp(T_world_tool: np.ndarray, T_world_needle: np.ndarray) -> np.ndarray:
    """
    Return the grasp ``T_tool_needle`` a tool pose and a needle pose show.

    Parameters
    ----------
    T_world_tool, T_world_needle : ndarray, shape (4, 4)
        Poses in ``world``.

    Returns
    -------
    ndarray, shape (4, 4)

    """
    T, N = np.asarray(T_world_tool), np.asarray(T_world_needle)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T @ N[:3, :3]
    out[:3, 3] = T[:3, :3].T @ (N[:3, 3] - T[:3, 3])
    return out


def grasps_differ(a: np.ndarray, b: np.ndarray, turn: float, shift: float) -> bool:
    """
    Whether grasps ``a`` and ``b`` differ by more than ``turn`` (rad) or ``shift`` (m).

    Parameters
    ----------
    a, b : ndarray, shape (4, 4)
        Grasps ``T_tool_needle``.
    turn : float
        Largest rotation angle (rad) between them still counted the same.
    shift : float
        Largest distance (m) between their origins still counted the same.

    Returns
    -------
    bool

    """
    c = 0.5 * (float(np.sum(a[:3, :3] * b[:3, :3])) - 1.0)
    return (math.acos(max(-1.0, min(1.0, c))) > turn
            or float(np.linalg.norm(a[:3, 3] - b[:3, 3])) > shift)


def slip_checkpoints(labels: list[tuple[float, str]], looks: int) -> list[tuple[float, str]]:
    """
    Plan times (s) and arms of ``looks`` evenly spread looks at the grasp per DMP subtask.

    Parameters
    ----------
    labels : list of (float, str)
        The plan's subtask labels: start time (s) and name, in order.
    looks : int
        Looks per DMP subtask.

    Returns
    -------
    list of (float, str)

    """
    out = []
    for (t0, name), (t1, _) in zip(labels[:-1], labels[1:]):
        if name in TASKS:
            arm = holding_arm(name)
            out += [(t0 + (t1 - t0) * (k + 1) / (looks + 1), arm) for k in range(looks)]
    return out


class SlipWatch:
    """
    Notice from the observed grasp that the needle turned in the jaw, once the slip is over.

    Parameters
    ----------
    turn, shift : float
        A grasp differing from the one followed by more than this turn (rad) or shift (m)
        means the needle slipped.
    corrections : int
        Most grasps taken again per DMP subtask.

    Attributes
    ----------
    noticed : int
        Grasps taken again since :meth:`reset`.

    """

    def __init__(self, turn: float, shift: float, corrections: int) -> None:
        self.turn = float(turn)
        self.shift = float(shift)
        self.corrections = int(corrections)
        self.reset()

    def reset(self) -> None:
        """Start a new throw: nothing noticed."""
        self.noticed = 0
        self._fixes: dict[str, int] = {}
        self._seen: tuple[np.ndarray, int] | None = None

    def notice(self, label: str, known: np.ndarray | None, T_world_tool: np.ndarray,
               T_world_needle: np.ndarray) -> np.ndarray | None:
        """
        Return the grasp to follow from now on, or None to keep ``known``.

        Parameters
        ----------
        label : str
            The plan's subtask now (only ``'ii'`` and ``'iv'`` are watched).
        known : ndarray, shape (4, 4) or None
            The grasp followed.
        T_world_tool, T_world_needle : ndarray, shape (4, 4)
            The holding tool and the needle as observed.

        Returns
        -------
        ndarray, shape (4, 4) or None

        """
        if label not in TASKS or known is None:
            return None
        if self._fixes.get(label, 0) >= self.corrections:
            return None
        seen = observed_grasp(T_world_tool, T_world_needle)
        if not grasps_differ(seen, known, self.turn, self.shift):
            self._seen = None
            return None
        last, count = self._seen if self._seen is not None else (None, 0)
        same = last is not None and not grasps_differ(seen, last, self.turn, self.shift)
        count = count + 1 if same else 1
        self._seen = (seen, count)
        if count < SETTLE:
            return None
        self._fixes[label] = self._fixes.get(label, 0) + 1
        self._seen = None
        self.noticed += 1
        return seen
