"""
The pose DMP (position and unit quaternion together), the hyper-parameters' file and DMP files.

:func:`load_dmp_params` reads the paper's Table I from ``config/dmp.yaml``; :class:`PoseDmp`
learns and executes a needle pose trajectory with a :class:`~suture_lfd.dmp.position.PositionDmp`
and a :class:`~suture_lfd.dmp.quaternion.QuaternionDmp`; :func:`load_dmp` reads any saved
primitive back.

Units: positions m, angles rad, time s. Quaternions (x, y, z, w). Poses are 7-vectors
``(x, y, z, qx, qy, qz, qw)`` in the frame the demonstration was given in.
"""

from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.configfile import dataclass_from_mapping, load_yaml, section
from sim_bridge.common.paths import config_path
from sim_bridge.common.validation import FloatArray, check_array
from sim_bridge.common.vocabulary import TASKS
from suture_lfd.dmp.base import (
    DmpParams,
    PathLike,
    Primitive,
    read_dmp_file,
)
from suture_lfd.dmp.position import PositionDmp
from suture_lfd.dmp.quaternion import QuaternionDmp

__all__ = ['PoseDmp', 'load_dmp', 'load_dmp_params']


def load_dmp_params(path: PathLike | None = None, task: str = 'ii') -> DmpParams:
    """
    Read the hyper-parameters of one learned subtask from ``config/dmp.yaml``.

    Parameters
    ----------
    path : str or Path, optional
        YAML file; the installed ``dmp.yaml`` by default.
    task : {'ii', 'iv'}
        Subtask (ii insertion with PSM2, iv extraction with PSM1); the section ``task_<task>``.

    Returns
    -------
    DmpParams
        The parameters.

    Raises
    ------
    ValueError
        If the task is unknown or the file does not match :class:`DmpParams` (a
        ``ConfigError`` naming the file and key).

    """
    if task not in TASKS:
        raise ValueError(f"task must be 'ii' or 'iv', got {task!r}")
    path = config_path('dmp.yaml') if path is None else path
    data = load_yaml(path)
    key = f'task_{task}'
    return dataclass_from_mapping(DmpParams, section(data, key, source=str(path)),
                                  source=str(path), prefix=key)


def load_dmp(path: PathLike) -> Primitive:
    """
    Read any primitive written by ``save``.

    Parameters
    ----------
    path : str or Path
        ``.npz`` file.

    Returns
    -------
    PositionDmp, QuaternionDmp or PoseDmp
        The learnt primitive, of the kind stored in the file.

    """
    kind, params, arrays = read_dmp_file(path)
    classes = {c.KIND: c for c in (PositionDmp, QuaternionDmp, PoseDmp)}
    if kind not in classes:
        raise ValueError(f'{path}: unknown DMP kind {kind!r}; expected one of {sorted(classes)}')
    return classes[kind]._from_arrays(params, arrays, path)


class PoseDmp(Primitive):
    """
    Position and orientation primitives learnt on one pose trajectory, sharing one phase.

    Attributes
    ----------
    position : PositionDmp
        The 3-D position part.
    orientation : QuaternionDmp
        The quaternion part.

    """

    KIND = 'pose'

    def __init__(self, params: DmpParams | None = None) -> None:
        super().__init__(params)
        self.position = PositionDmp(self.params)
        self.orientation = QuaternionDmp(self.params)

    def fit(self, T: ArrayLike, P: ArrayLike, Q: ArrayLike) -> 'PoseDmp':
        """
        Learn both parts from one pose demonstration.

        Parameters
        ----------
        T : array_like, shape (n,)
            Strictly increasing sample times, s.
        P : array_like, shape (n, 3)
            Positions, m.
        Q : array_like, shape (n, 4)
            Unit quaternions (x, y, z, w).

        Returns
        -------
        self

        """
        P = check_array(P, 'P', shape=(None, 3))
        self.position.fit(T, P)
        self.orientation.fit(T, Q)
        self.duration_ = self.position.duration_
        return self

    @property
    def start_(self) -> FloatArray:
        """ndarray, shape (7,): Demonstrated start pose."""
        self._check_fitted()
        return np.concatenate((self.position.start_, self.orientation.start_))

    @property
    def goal_(self) -> FloatArray:
        """ndarray, shape (7,): Demonstrated goal pose."""
        self._check_fitted()
        return np.concatenate((self.position.goal_, self.orientation.goal_))

    @staticmethod
    def _split(pose: ArrayLike | None,
               name: str) -> tuple[FloatArray, FloatArray] | tuple[None, None]:
        if pose is None:
            return None, None
        pose = check_array(pose, name, shape=(7,))
        return pose[:3], pose[3:]

    def rollout(self, start: ArrayLike | None = None, goal: ArrayLike | None = None,
                n_pts: int | None = None,
                T: ArrayLike | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
        """
        Generate the pose trajectory from ``start`` to ``goal``.

        Parameters
        ----------
        start, goal : array_like, shape (7,), optional
            Poses ``(x, y, z, qx, qy, qz, qw)``; the demonstrated ones by default.
        n_pts : int, optional
            Number of points over the demonstrated duration (``params.n_pts`` by default).
        T : array_like, shape (n,), optional
            Evenly spaced output times, s.

        Returns
        -------
        T : ndarray, shape (n,)
            Times, s.
        P : ndarray, shape (n, 3)
            Positions, m.
        Q : ndarray, shape (n, 4)
            Unit quaternions (x, y, z, w).

        """
        given = T is not None
        T, _ = self._time_grid(n_pts, T)
        p0, q0 = self._split(start, 'start')
        p1, q1 = self._split(goal, 'goal')
        # both parts share the demonstrated duration: hand them the grid checked here
        grid = {'T': T} if given else {'n_pts': T.size}
        _, P = self.position.rollout(p0, p1, **grid)
        _, Q = self.orientation.rollout(q0, q1, **grid)
        return T, P, Q

    def reset(self, start: ArrayLike | None = None, goal: ArrayLike | None = None,
              duration: float | None = None) -> 'PoseDmp':
        """
        Start an online execution from ``start`` towards ``goal`` (poses, 7-vectors).

        Parameters
        ----------
        start, goal : array_like, shape (7,), optional
            Poses ``(x, y, z, qx, qy, qz, qw)``; the demonstrated ones by default.
        duration : float, optional
            Execution time ``tau``, s (the demonstrated duration by default).

        Returns
        -------
        self

        """
        super().reset(start, goal, duration)
        self.position._tau = self.orientation._tau = self._tau
        return self

    def _begin(self, start: ArrayLike | None, goal: ArrayLike | None) -> None:
        p0, q0 = self._split(start, 'start')
        p1, q1 = self._split(goal, 'goal')
        self.position._begin(p0, p1)
        self.orientation._begin(q0, q1)
        for part in (self.position, self.orientation):
            part._running = True

    def set_goal(self, goal: ArrayLike, immediate: bool = False) -> None:
        """
        Switch the goal pose of the online execution (both parts filtered).

        Parameters
        ----------
        goal : array_like, shape (7,)
            New goal ``(x, y, z, qx, qy, qz, qw)``.
        immediate : bool
            Skip the goal filters.

        """
        if not self._running:
            raise ValueError('call reset() before set_goal()')
        p, q = self._split(goal, 'goal')
        self.position.set_goal(p, immediate)
        self.orientation.set_goal(q, immediate)

    def _phase_error(self, measured: ArrayLike) -> float:
        p, q = self._split(measured, 'measured')
        return self.position._phase_error(p) + self.orientation._phase_error(q)

    def _advance(self, h: float, x0: float, x1: float) -> None:
        self.position._advance(h, x0, x1)
        self.orientation._advance(h, x0, x1)

    def _output(self) -> FloatArray:
        return np.concatenate((self.position._output(), self.orientation._output()))

    def _arrays(self) -> dict[str, Any]:
        arrays = self.position._arrays()
        arrays.update(self.orientation._arrays())
        return arrays

    @classmethod
    def _from_arrays(cls, params: DmpParams, arrays: dict[str, Any], path: PathLike) -> 'PoseDmp':
        dmp = cls(params)
        dmp.position = PositionDmp._from_arrays(params, arrays, path)
        dmp.orientation = QuaternionDmp._from_arrays(params, arrays, path)
        dmp.duration_ = dmp.position.duration_
        return dmp
