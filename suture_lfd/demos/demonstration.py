"""
One suturing demonstration in memory, as the bag reader fills it and the segmenter reads it.

All arrays share one time axis ``t`` (s). Poses are 7-vectors ``(x, y, z, qx, qy, qz, qw)`` in
the ``world`` frame (m, unit quaternion; signs may flip between samples). Jaw angles in rad.
The record validates itself on construction and saves to / loads from ``.npz`` with a format
tag and version.
"""

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from sim_bridge.common.archive import load_archive, save_archive
from sim_bridge.common.validation import check_array, check_quaternions, check_times

FORMAT = 'suture_lfd.demonstration'  # the files' format tag (kept when the module moved)
FORMAT_VERSION = 1

_POSES = ('psm1_pose', 'psm2_pose', 'needle_pose')
_SIGNALS = ('psm1_jaw', 'psm2_jaw')
_FLAGS = ('psm1_holds', 'psm2_holds')
_POINTS = ('entry', 'exit', 'normal')


@dataclass(frozen=True, eq=False)
class Demonstration:
    """
    One recorded demonstration of a single throw.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Strictly increasing sample times, s.
    psm1_pose, psm2_pose : ndarray, shape (n, 7)
        Tool-tip poses of PSM1 (left) and PSM2 (right) in ``world``.
    psm1_jaw, psm2_jaw : ndarray, shape (n,)
        Jaw angles, rad.
    needle_pose : ndarray, shape (n, 7)
        Needle pose in ``world`` (ground truth).
    psm1_holds, psm2_holds : ndarray of bool, shape (n,)
        Whether each arm holds the needle (the simulator's grasp state).
    entry, exit : ndarray, shape (3,)
        Entry and exit marker of the pair, m (``world``).
    normal : ndarray, shape (3,)
        Phantom surface normal at the pair (``world``, unit length).
    pair : str
        Name of the entry/exit pair (``'synth1'`` .. ``'scan4'``).

    """

    t: np.ndarray
    psm1_pose: np.ndarray
    psm2_pose: np.ndarray
    psm1_jaw: np.ndarray
    psm2_jaw: np.ndarray
    needle_pose: np.ndarray
    psm1_holds: np.ndarray
    psm2_holds: np.ndarray
    entry: np.ndarray
    exit: np.ndarray
    normal: np.ndarray
    pair: str = ''

    def __post_init__(self) -> None:
        for name in ('t',) + _POSES + _SIGNALS + _POINTS:
            object.__setattr__(self, name, check_array(getattr(self, name), name).copy())
        for name in _FLAGS:
            value = np.asarray(getattr(self, name))
            if value.dtype != bool:
                if not np.issubdtype(value.dtype, np.number) or not np.all(np.isin(value, (0, 1))):
                    raise ValueError(f'{name} must be booleans (or 0/1), got dtype {value.dtype}')
                value = value.astype(bool)
            object.__setattr__(self, name, value.copy())
        self.validate()

    def validate(self) -> 'Demonstration':
        """
        Check shapes, finiteness, time order, unit quaternions and the pair geometry.

        Returns
        -------
        Demonstration
            ``self``.

        Raises
        ------
        ValueError
            Naming the field and what was expected.

        """
        t = check_times(self.t, 't')
        n = t.size
        for name in _POSES:
            pose = check_array(getattr(self, name), name, shape=(n, 7))
            check_quaternions(pose[:, 3:], f'{name} orientation', normalise=False)
        for name in _SIGNALS:
            check_array(getattr(self, name), name, shape=(n,))
        for name in _FLAGS:
            flags = getattr(self, name)
            if flags.shape != (n,):
                raise ValueError(f'{name} must have shape ({n},), got {flags.shape}')
        for name in _POINTS:
            check_array(getattr(self, name), name, shape=(3,))
        length = float(np.linalg.norm(self.normal))
        if abs(length - 1.0) > 1e-3:
            raise ValueError(f'normal must be a unit vector, got norm {length:.6g}')
        if not isinstance(self.pair, str):
            raise ValueError(f'pair must be a string, got {type(self.pair).__name__}')
        return self

    @property
    def n(self) -> int:
        """int: Number of samples."""
        return self.t.size

    @property
    def duration(self) -> float:
        """float: ``t[-1] - t[0]``, s."""
        return float(self.t[-1] - self.t[0])

    def window(self, start_index: int, end_index: int) -> 'Demonstration':
        """
        Return the samples ``start_index .. end_index`` (inclusive) as a new demonstration.

        Parameters
        ----------
        start_index, end_index : int
            First and last sample, ``0 <= start_index < end_index < n``.

        Returns
        -------
        Demonstration
            The window (times unchanged).

        """
        if not (0 <= start_index < end_index < self.n):
            raise ValueError(f'window needs 0 <= start_index < end_index < {self.n}, got '
                             f'{start_index} and {end_index}')
        cut = slice(start_index, end_index + 1)
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in ('t',) + _POSES + _SIGNALS + _FLAGS:
            values[name] = values[name][cut]
        return Demonstration(**values)

    def save(self, path: str | Path) -> None:
        """
        Write the demonstration to an ``.npz`` file (format tag and version included).

        Parameters
        ----------
        path : str or Path
            Output file (written as given, no suffix added).

        """
        arrays = {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}
        save_archive(path, arrays, FORMAT, FORMAT_VERSION)

    @classmethod
    def load(cls, path: str | Path) -> 'Demonstration':
        """
        Read a demonstration written by :meth:`save`.

        Parameters
        ----------
        path : str or Path
            ``.npz`` file.

        Returns
        -------
        Demonstration
            The validated record.

        Raises
        ------
        ValueError
            If the file is not a demonstration file, has another format version or holds
            invalid data; the message names the file.

        """
        arrays = load_archive(path, FORMAT, FORMAT_VERSION, 'demonstration file')
        names = [f.name for f in fields(cls)]
        missing = [name for name in names if name not in arrays]
        if missing:
            raise ValueError(f'{path}: demonstration file lacks {missing}')
        values: dict[str, Any] = {name: arrays[name] for name in names}
        values['pair'] = str(values['pair'])
        try:
            return cls(**values)
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from exc
