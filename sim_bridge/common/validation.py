"""
Input checks shared by the LfD core, each raising a ValueError that names the argument.

Public functions validate once at the boundary and hand clean float arrays to the numerical
code; the messages say which argument is wrong and what was expected.
"""

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
"""A float64 array: what every check returns, and what the numerical modules return."""

UNIT_NORM_TOLERANCE = 1e-3


def check_array(value: ArrayLike, name: str, *, shape: Sequence[int | None] | None = None,
                min_rows: int | None = None, finite: bool = True) -> FloatArray:
    """
    Return ``value`` as a float64 array after checking its shape and values.

    Parameters
    ----------
    value : array_like
        The input.
    name : str
        Argument name used in error messages.
    shape : tuple of (int or None), optional
        Expected shape; ``None`` entries match any size. ``(None, 3)`` is an ``(n, 3)`` array.
    min_rows : int, optional
        Minimum size of the first axis.
    finite : bool
        Reject NaN and infinite entries.

    Returns
    -------
    ndarray
        Float64 copy-free view where possible.

    Raises
    ------
    ValueError
        If the value is not numeric, has the wrong shape, too few rows or non-finite entries.

    """
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{name} must be a numeric array ({exc})') from exc
    if shape is not None:
        if array.ndim != len(shape) or any(
                want is not None and got != want for got, want in zip(array.shape, shape)):
            wanted = '(' + ', '.join('n' if s is None else str(s) for s in shape) + ')'
            raise ValueError(f'{name} must have shape {wanted}, got {array.shape}')
    if min_rows is not None and (array.ndim == 0 or array.shape[0] < min_rows):
        got = 0 if array.ndim == 0 else array.shape[0]
        raise ValueError(f'{name} needs at least {min_rows} points, got {got}')
    if finite and not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array.reshape(-1)))[0])
        raise ValueError(
            f'{name} must be finite (no NaN or inf); entry {bad} of the flattened array is '
            f'{array.reshape(-1)[bad]}')
    return array


def check_times(T: ArrayLike, name: str = 'T', *, min_points: int = 2) -> FloatArray:
    """
    Return a strictly increasing time vector in seconds.

    Parameters
    ----------
    T : array_like, shape (n,)
        Sample times, s.
    name : str
        Argument name used in error messages.
    min_points : int
        Minimum number of samples.

    Returns
    -------
    ndarray, shape (n,)
        The times as float64.

    Raises
    ------
    ValueError
        If ``T`` is not a finite 1-D vector of at least ``min_points`` strictly increasing times.

    """
    T = check_array(T, name, shape=(None,), min_rows=min_points)
    steps = np.diff(T)
    if np.any(steps <= 0.0):
        k = int(np.flatnonzero(steps <= 0.0)[0])
        raise ValueError(
            f'{name} must be strictly increasing; sample {k + 1} ({T[k + 1]!r} s) does not come '
            f'after sample {k} ({T[k]!r} s)')
    return T


def check_quaternions(Q: ArrayLike, name: str = 'Q', *, tolerance: float = UNIT_NORM_TOLERANCE,
                      normalise: bool = True) -> FloatArray:
    """
    Return unit quaternions (x, y, z, w), checking that each has norm close to one.

    Parameters
    ----------
    Q : array_like, shape (..., 4)
        Quaternions, scalar last.
    name : str
        Argument name used in error messages.
    tolerance : float
        Accepted deviation of the norm from 1.
    normalise : bool
        Divide by the norm before returning.

    Returns
    -------
    ndarray, shape (..., 4)
        The quaternions (normalised if asked).

    Raises
    ------
    ValueError
        If the last axis is not 4 long, an entry is not finite or a norm is off by more than
        ``tolerance`` (a zero quaternion included).

    """
    Q = check_array(Q, name)
    if Q.ndim == 0 or Q.shape[-1] != 4:
        raise ValueError(f'{name} must hold quaternions (x, y, z, w) on its last axis, '
                         f'got shape {Q.shape}')
    norms = np.linalg.norm(Q, axis=-1)
    bad = np.abs(norms - 1.0) > tolerance
    if np.any(bad):
        k = int(np.flatnonzero(bad.reshape(-1))[0])
        raise ValueError(
            f'{name} is not a unit quaternion (norm {norms.reshape(-1)[k]:.6g} at entry {k}); '
            'expected (x, y, z, w) with norm 1')
    if normalise:
        return Q / norms[..., None]
    return Q


def check_positive(value: Any, name: str) -> float:
    """
    Return ``value`` as a float after checking that it is finite and strictly positive.

    Parameters
    ----------
    value : float
        The input.
    name : str
        Argument name used in error messages.

    Returns
    -------
    float
        The value.

    Raises
    ------
    ValueError
        If the value is not a finite positive number.

    """
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{name} must be a positive number, got {value!r}') from exc
    if not np.isfinite(number) or number <= 0.0:
        raise ValueError(f'{name} must be a finite positive number, got {value!r}')
    return number
