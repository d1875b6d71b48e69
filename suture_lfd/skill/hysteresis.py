"""
Cable backlash as the robot's own joint reports reveal it: a play operator run on ``measured_js``.

A cable-driven joint takes up its slack before it moves when its motor reverses, so where the
joint truly is depends on the direction it last moved in: ``q_true = q_motor + p`` with the play
``p`` in ``[-b/2, b/2]`` (``b`` the dead band), pushed to ``-b/2`` while the motor turns up and
to ``+b/2`` while it turns down, unchanged inside the band (a play operator; Hwang et al., RA-L
2020, model the dVRK's cable hysteresis this way before learning the rest). A physical dVRK's
encoders sit on the motors, so the play never shows in ``measured_js``; but it is a function of
the reported joints' history alone, so a controller that knows each joint's dead band can
follow it from the reports it receives, and a registration that sees the tool at poses reached
from different directions can fit the band (:mod:`suture_lfd.skill.arm_registration`).

- :class:`PlayTracker` follows the play of one arm's joints from each new report.
- :class:`TargetPlay` is the backlash inverse: the play a command must allow for, from the
  direction the load-side joint targets move in (not the lagging, overshooting reports).
- :func:`run_lengths` and :func:`plays_at` evaluate the play at a registration's poses for a
  candidate band quickly: a motion's reports are reduced once to their monotone runs (a play
  operator's output depends only on those), the band then costs a few hundred float operations;
  :class:`PlaysMemo` keeps each joint's plays per band for a fit's finite differences.

Joints in the arm's ``measured_js`` order, rad (rotary) and m (prismatic). Core module: numpy only.
"""

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ['PSM_STILL', 'PlayTracker', 'PlaysMemo', 'TargetPlay', 'plays_at', 'run_lengths']

#: A PSM's smallest joint motion (rad, rad, m, rad, rad, rad) that tells a direction: five
#: counts of a dVRK encoder (1e-4 rad, 2 um), ten times the encoders' noise, so that a joint
#: at rest, its reading jittering by a count, keeps its play instead of flipping it
PSM_STILL = (5e-4, 5e-4, 1e-5, 5e-4, 5e-4, 5e-4)


class PlayTracker:
    """
    The estimated play of one arm's joints, advanced by each report of its joints.

    The play starts at 0 (unknown: the middle of the band); any motion of a joint longer than
    its band sets it exactly, as it sets the true one.

    Parameters
    ----------
    band : array_like, shape (n,)
        Full dead band per joint (rad / m, >= 0; 0: a joint without backlash).

    """

    def __init__(self, band: ArrayLike) -> None:
        self.half = [0.5 * float(b) for b in np.asarray(band, dtype=float).ravel()]
        self.play = [0.0] * len(self.half)
        self._last: list[float] | None = None

    @property
    def active(self) -> bool:
        """Whether any joint has a dead band."""
        return any(h > 0.0 for h in self.half)

    def update(self, q: ArrayLike) -> list[float]:
        """
        Advance the play to the reported joints ``q`` and return it (rad / m, per joint).

        Parameters
        ----------
        q : array_like, shape (n,) or longer
            Reported joints; the first ``n`` are used.

        """
        values = _floats(q)[:len(self.half)]
        last = self._last
        if last is not None:
            play = self.play
            for j, h in enumerate(self.half):
                if h > 0.0:
                    p = play[j] - (values[j] - last[j])
                    play[j] = h if p > h else (-h if p < -h else p)
        self._last = values
        return list(self.play)

    def heading(self, q: ArrayLike, q_to: ArrayLike,
                still: float | Sequence[float] = 1e-5) -> list[float]:
        """
        Return the play the joints will have once moved from ``q`` towards ``q_to``.

        A backlash inverse: a joint about to move up will have taken up its slack at
        ``-b/2``, one about to move down at ``+b/2``; a joint that moves less than ``still``
        keeps its play. Commanding the
        motors with this play instead of the present one crosses a reversal's dead band at
        once, instead of one command late at every step.

        Parameters
        ----------
        q, q_to : array_like, shape (n,) or longer
            Reported joints now and the joints commanded next (rad / m).
        still : float or sequence of float
            Smallest motion (rad / m) that counts as a direction, one for every joint or one
            per joint (:data:`PSM_STILL`).

        """
        a = _floats(q)
        b = _floats(q_to)
        out = list(self.play)
        limits = [float(still)] * len(self.half) if isinstance(still, (int, float)) else still
        for j, h in enumerate(self.half):
            d = b[j] - a[j]
            if h > 0.0 and abs(d) > limits[j]:
                out[j] = -h if d > 0.0 else h
        return out


class TargetPlay:
    """
    The backlash inverse of one arm: the play each joint will have where it is commanded to.

    To put a cable-driven joint truly at ``x`` its motor goes to ``x - p``, where ``p`` is
    ``-b/2`` while the joint's target rises and ``+b/2`` while it falls: the direction is that
    of the *targets* (the true joints the commands ask for), which move as smoothly as the plan,
    once a joint has one (a joint without takes it from its target against the reports, as
    :meth:`PlayTracker.heading` does). Judged against the reported joints throughout, a motor
    that overshoots its command after crossing a band by more than a few counts (the servo's
    lag, then its small overshoot) reads as a reversal, the next command crosses the band
    back, and the joint cycles by its whole band (up to 1 mm at the tool, period a few tenths
    of a second; measured at the ``dvrk`` preset). A target must come back ``still`` from its
    furthest point for a reversal.

    Parameters
    ----------
    band : array_like, shape (n,)
        Full dead band per joint (rad / m, >= 0).
    still : sequence of float
        Per joint, how far (rad / m) a target must turn back to count as a reversal.

    """

    def __init__(self, band: ArrayLike, still: Sequence[float] = PSM_STILL) -> None:
        self.half = [0.5 * float(b) for b in np.asarray(band, dtype=float).ravel()]
        self.still = [float(v) for v in still]
        #: the commands' play (None: not started); the time of the last target
        self.play: list[float] | None = None
        self.t: float | None = None
        self._peak: list[float] = []
        self._rising: list[int] = []

    def start(self, play: Sequence[float], target: Sequence[float]) -> None:
        """Start from the joints' present ``play`` at the load-side ``target`` (no direction)."""
        self.play = [float(p) for p in play]
        self._peak = [float(x) for x in target[:len(self.half)]]
        self._rising = [0] * len(self.half)

    def update(self, target: Sequence[float], reported: 'Sequence[float] | np.ndarray',
               present: Sequence[float]) -> list[float]:
        """
        Return the play for the next load-side joint ``target`` (rad / m), the direction kept.

        A joint with no direction yet takes it as :meth:`PlayTracker.heading` does, from the
        target against where the reports put the joint (``reported`` plus ``present``), and
        keeps the present play while within ``still`` of it; once it has a direction, only the
        targets turn it.

        Parameters
        ----------
        target : sequence of float
            Where the joints should truly go (reported joints plus play, offsets aside).
        reported : sequence of float
            The reported joints now.
        present : sequence of float
            The play the reports show now (:class:`PlayTracker`).

        """
        assert self.play is not None  # start() first
        play, peak, rising = self.play, self._peak, self._rising
        for j, h in enumerate(self.half):
            if h <= 0.0:
                continue
            x, r, s = float(target[j]), rising[j], self.still[j]
            if r == 0:
                d = x - float(reported[j]) - float(present[j])
                if abs(d) > s:
                    rising[j], peak[j], play[j] = (1, x, -h) if d > 0.0 else (-1, x, h)
                else:
                    play[j] = float(present[j])
            elif (r > 0 and x >= peak[j]) or (r < 0 and x <= peak[j]):
                peak[j] = x  # further the same way
            elif r > 0 and x < peak[j] - s:
                rising[j], peak[j], play[j] = -1, x, h
            elif r < 0 and x > peak[j] + s:
                rising[j], peak[j], play[j] = 1, x, -h
        return list(play)


def _floats(q: ArrayLike) -> list[float]:
    """Return joints as a flat list of plain floats (a list or tuple of floats as it is)."""
    if type(q) is np.ndarray and q.dtype == np.float64:
        return q.ravel().tolist()
    if isinstance(q, (list, tuple)) and all(type(v) is float for v in q):
        return list(q)
    return np.asarray(q, dtype=float).ravel().tolist()


def run_lengths(paths: Sequence[ArrayLike], joints: int) -> list[list[list[float]]]:
    """
    Reduce a motion's joint reports to the signed lengths of each joint's monotone runs.

    Parameters
    ----------
    paths : sequence of array_like, each shape (m_k, >= joints)
        The reported joints from one pose to the next, in order; ``paths[k]`` ends at pose
        ``k`` (its first row may repeat the previous path's last).
    joints : int
        How many leading joints to keep.

    Returns
    -------
    list
        ``runs[k][j]``: the signed lengths (rad / m) of joint ``j``'s monotone runs from pose
        ``k - 1`` (or the first report) to pose ``k``.

    """
    out: list[list[list[float]]] = []
    last: np.ndarray | None = None
    for path in paths:
        P = np.asarray(path, dtype=float)
        P = np.zeros((0, joints)) if P.size == 0 else P.reshape(len(P), -1)[:, :joints]
        if last is not None:
            P = np.vstack([last[None, :], P])
        last = P[-1].copy() if len(P) else last
        runs_k: list[list[float]] = []
        for j in range(joints):
            d = np.diff(P[:, j]) if len(P) > 1 else np.zeros(0)
            d = d[d != 0.0]
            runs: list[float] = []
            if len(d):
                # split where the sign changes, sum each run
                cut = np.flatnonzero(np.sign(d[1:]) != np.sign(d[:-1])) + 1
                runs = [float(s.sum()) for s in np.split(d, cut)]
            runs_k.append(runs)
        out.append(runs_k)
    return out


def plays_at(runs: list[list[list[float]]], band: ArrayLike) -> np.ndarray:
    """
    Return each joint's play at each pose for a candidate dead band (:func:`run_lengths`).

    Parameters
    ----------
    runs : list
        ``run_lengths(paths, joints)``.
    band : array_like, shape (joints,)
        Full dead band per joint (rad / m).

    Returns
    -------
    ndarray, shape (poses, joints)
        ``q_true - q_reported`` from the backlash at each pose (the play starts at 0).

    """
    return PlaysMemo(runs)(band)


def _joint_plays(runs: list[list[list[float]]], j: int, h: float) -> list[float]:
    """Return joint ``j``'s play at each pose for the half band ``h`` (:func:`plays_at`)."""
    p = 0.0
    out = []
    for per_joint in runs:
        for r in per_joint[j]:
            p -= r
            p = h if p > h else (-h if p < -h else p)
        out.append(p)
    return out


class PlaysMemo:
    """
    :func:`plays_at` of one motion for many candidate bands, each joint's plays kept per band.

    A fit's finite differences change one joint's band at a time (or none): the other joints'
    plays are taken from the memo, the same floats as computed afresh.

    Parameters
    ----------
    runs : list
        ``run_lengths(paths, joints)``.
    size : int
        Plays kept per joint before the memo starts again.

    """

    def __init__(self, runs: list[list[list[float]]], size: int = 256) -> None:
        self.runs = runs
        self._size = size
        self._memo: dict[tuple[int, float], list[float]] = {}

    def __call__(self, band: ArrayLike) -> np.ndarray:
        """Return :func:`plays_at` ``(runs, band)``."""
        half = [0.5 * abs(float(b)) for b in np.asarray(band, dtype=float).ravel()]
        memo = self._memo
        columns = []
        for j, h in enumerate(half):
            column = memo.get((j, h))
            if column is None:
                if len(memo) >= self._size * len(half):
                    memo.clear()
                column = memo[(j, h)] = _joint_plays(self.runs, j, h)
            columns.append(column)
        out = np.zeros((len(self.runs), len(half)))
        for j, column in enumerate(columns):
            out[:, j] = column
        return out
