"""
Hyper-parameters, phase, online stepping and file format shared by the DMP classes.

:class:`DmpParams` holds the seed paper's Table I and the guards of lfd_anchors section 2;
:class:`Primitive` is the base of :class:`~suture_lfd.dmp.position.PositionDmp`,
:class:`~suture_lfd.dmp.quaternion.QuaternionDmp` and :class:`~suture_lfd.dmp.PoseDmp`: the
canonical phase, phase stopping, time grids, and ``save``/``load`` of ``.npz`` files with a
format tag and version.
"""

from dataclasses import asdict, dataclass
import json
import math
import os
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.archive import load_archive, save_archive
from sim_bridge.common.configfile import dataclass_from_mapping
from sim_bridge.common.validation import FloatArray, check_positive, check_times
from suture_lfd.dmp.equations import (
    basis_activations,
    canonical_phase,
    least_squares_weights,
    lwr_weights,
    uniform_activations,
    uniform_phase,
)

FORMAT = 'suture_lfd.dmp'
FORMAT_VERSION = 1
MIN_FIT_POINTS = 5
ORIENTATION_FORMS = ('ude', 'log')
REGRESSIONS = ('lwr', 'least_squares')

PathLike = str | os.PathLike[str]
"""A file name: a string or a path."""


@dataclass(frozen=True)
class DmpParams:
    """
    Hyper-parameters of a needle-trajectory DMP (the seed paper's Table I and our guards).

    Attributes
    ----------
    alpha_x : float
        Canonical-system gain (Table I: 1).
    alpha_y, beta_y : float
        Position transformation-system gains (Table I: 25, 6.25).
    alpha_z, beta_z : float
        Orientation transformation-system gains (Table I: 25, 6.25).
    n_bfs : int
        Position basis functions (Table I: 100 for task ii, 50 for task iv).
    n_bfs_o : int
        Orientation basis functions (Table I: 40 for task ii, 20 for task iv).
    n_pts : int
        Points of a regenerated trajectory (Table I: 500 for task ii, 100 for task iv).
    scale_guard : float
        A dimension with ``|g - y0| < scale_guard * max(range, floor)`` is learnt unscaled.
    scale_guard_floor_m : float
        Floor of the range for positions, m.
    scale_guard_floor_rad : float
        Floor of the range for orientation components, rad.
    goal_filter : float
        Goal-switching filter gain ``alpha_g`` in ``g' = alpha_g (G - g)`` (normalised time).
    phase_stop_position : float
        Phase-stopping gain for the squared position error, 1/m^2 (1e6: 1 mm halves the
        speed of the phase, 0.1 mm slows it by 1 %).
    phase_stop_orientation : float
        Phase-stopping gain for the squared orientation error, 1/rad^2.
    orientation_form : {'ude', 'log'}
        ``'ude'`` (the paper): ``omega' = alpha_z (beta_z 2 log(g * conj(q)) - omega) + f_o``.
        ``'log'``: the same attractor written linearly in ``u = 2 log(q * conj(g))``,
        ``u'' = -alpha_z beta_z u - alpha_z u' + f_o``; identical for a rotation about a fixed
        axis, and stable when the rotation exceeds 180 degrees about a drifting axis, where
        the Ude form amplifies errors across the axis (see :class:`QuaternionDmp`).
    regression : {'lwr', 'least_squares'}
        How the weights are fitted: ``'lwr'`` (the paper) fits each basis function alone
        (:func:`~suture_lfd.dmp.equations.lwr_weights`); ``'least_squares'`` fits all of them
        together (:func:`~suture_lfd.dmp.equations.least_squares_weights`), which keeps
        movements shorter than a basis function's width.
    ridge : float
        Relative regularisation of ``'least_squares'``.

    """

    alpha_x: float = 1.0
    alpha_y: float = 25.0
    beta_y: float = 6.25
    alpha_z: float = 25.0
    beta_z: float = 6.25
    n_bfs: int = 100
    n_bfs_o: int = 40
    n_pts: int = 500
    scale_guard: float = 1e-3
    scale_guard_floor_m: float = 1e-3
    scale_guard_floor_rad: float = 0.01
    goal_filter: float = 12.5
    phase_stop_position: float = 1.0e6
    phase_stop_orientation: float = 100.0
    orientation_form: str = 'ude'
    regression: str = 'lwr'
    ridge: float = 1e-8

    def __post_init__(self) -> None:
        if self.orientation_form not in ORIENTATION_FORMS:
            raise ValueError(f'DmpParams.orientation_form must be one of {ORIENTATION_FORMS}, '
                             f'got {self.orientation_form!r}')
        if self.regression not in REGRESSIONS:
            raise ValueError(f'DmpParams.regression must be one of {REGRESSIONS}, '
                             f'got {self.regression!r}')
        for name in ('alpha_x', 'alpha_y', 'beta_y', 'alpha_z', 'beta_z', 'goal_filter'):
            check_positive(getattr(self, name), f'DmpParams.{name}')
        for name in ('scale_guard', 'scale_guard_floor_m', 'scale_guard_floor_rad',
                     'phase_stop_position', 'phase_stop_orientation', 'ridge'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f'DmpParams.{name} must be a finite number >= 0, got {value!r}')
        for name, least in (('n_bfs', 2), ('n_bfs_o', 2), ('n_pts', 2)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f'DmpParams.{name} must be an integer >= {least}, got {value!r}')



def _uniform_grid(T: ArrayLike, name: str) -> tuple[FloatArray, float]:
    """Return (T, duration) after checking that ``T`` is evenly spaced."""
    T = check_times(T, name)
    steps = np.diff(T)
    if np.ptp(steps) > 1e-6 * steps.mean():
        raise ValueError(f'{name} must be evenly spaced (steps from {steps.min():.6g} s to '
                         f'{steps.max():.6g} s); resample it first')
    return T, float(T[-1] - T[0])


P = TypeVar('P', bound='Primitive')


class Primitive:
    """Phase, timing, online stepping and file input/output shared by the primitives."""

    KIND = ''

    def __init__(self, params: DmpParams | None = None) -> None:
        if params is None:
            params = DmpParams()
        if not isinstance(params, DmpParams):
            raise ValueError(f'params must be a DmpParams, got {type(params).__name__}')
        self.params = params
        self.duration_: float | None = None
        self._running = False
        self._x = 1.0
        self._s = 0.0
        self._tau = 1.0

    # --- learning --------------------------------------------------------------------------
    def _fit_time(self, T: ArrayLike, n_values: int,
                  name: str) -> tuple[float | FloatArray, FloatArray, float]:
        T = check_times(T, 'T', min_points=MIN_FIT_POINTS)
        if n_values != T.size:
            raise ValueError(f'{name} must have one row per time in T ({T.size}), got {n_values}')
        duration = float(T[-1] - T[0])
        s = (T - T[0]) / duration
        steps = np.diff(s)
        if np.ptp(steps) <= 1e-9 * steps.mean():
            # evenly spaced (a resampled demonstration): cached phase, spacing for the
            # derivatives
            return 1.0 / (s.size - 1), uniform_phase(s.size, self.params.alpha_x), duration
        return s, canonical_phase(s, self.params.alpha_x), duration

    def _weights(self, psi: FloatArray, x: FloatArray, targets: FloatArray,
                 scale: ArrayLike) -> FloatArray:
        """Fit the weights with the regression of the parameters."""
        if self.params.regression == 'least_squares':
            return least_squares_weights(psi, x, targets, scale, self.params.ridge)
        return lwr_weights(psi, x, targets, scale)

    def _activations(self, s: float | FloatArray, x: FloatArray, centres: FloatArray,
                     widths: FloatArray) -> FloatArray:
        """Basis activations at the phases ``x`` (cached for an evenly spaced ``s``)."""
        if isinstance(s, float):
            return uniform_activations(x.size, centres.size, self.params.alpha_x)
        return basis_activations(x, centres, widths)

    @property
    def is_fitted(self) -> bool:
        """bool: Whether weights have been learnt or loaded."""
        return self.duration_ is not None

    def _check_fitted(self) -> float:
        """Return the demonstrated duration, s, or raise if nothing was learnt."""
        if self.duration_ is None:
            raise ValueError(f'this {type(self).__name__} has no weights; call fit() or load()')
        return self.duration_

    def _time_grid(self, n_pts: int | None, T: ArrayLike | None) -> tuple[FloatArray, float]:
        """Return (times in s, tau) for a rollout."""
        duration = self._check_fitted()
        if T is not None:
            if n_pts is not None:
                raise ValueError('give either n_pts or T, not both')
            T, tau = _uniform_grid(T, 'T')
            return T, tau
        n_pts = self.params.n_pts if n_pts is None else n_pts
        if isinstance(n_pts, bool) or not isinstance(n_pts, (int, np.integer)) or n_pts < 2:
            raise ValueError(f'n_pts must be an integer >= 2, got {n_pts!r}')
        return np.linspace(0.0, duration, int(n_pts)), duration

    # --- online execution --------------------------------------------------------------------
    def reset(self: P, start: ArrayLike | None = None, goal: ArrayLike | None = None,
              duration: float | None = None) -> P:
        """
        Start an online execution from ``start`` towards ``goal``.

        Parameters
        ----------
        start, goal : array_like, optional
            Start and goal state (the demonstrated ones by default); same layout as
            :meth:`rollout`.
        duration : float, optional
            Execution time ``tau``, s (the demonstrated duration by default).

        Returns
        -------
        self

        """
        demonstrated = self._check_fitted()
        tau = demonstrated if duration is None else check_positive(duration, 'duration')
        self._begin(start, goal)
        self._tau = tau
        self._x = 1.0
        self._s = 0.0
        self._running = True
        return self

    def step(self, dt: float, measured: ArrayLike | None = None) -> FloatArray:
        """
        Advance the online execution by ``dt`` seconds and return the new commanded state.

        Phase stopping (Ijspeert et al. 2013, section 3.1, with the orientation term of Ude
        et al. 2014): with a measured state the time constant is stretched,
        ``tau_eff = tau (1 + k_p |p_meas - p|^2 + k_o d(q_meas, q)^2)`` (``d`` the rotation
        angle), for both the canonical and the transformation system, so a robot that is held
        back pauses the movement and resumes where it stopped when released; small tracking
        errors barely slow it.

        Parameters
        ----------
        dt : float
            Time step, s.
        measured : array_like, optional
            Measured state in the layout of the output (position (n_dims,) m, quaternion
            (4,), or pose (7,)); ``None`` disables phase stopping for this step.

        Returns
        -------
        ndarray
            Commanded position (n_dims,), quaternion (4,) or pose (7,) after the step.

        """
        if not self._running:
            raise ValueError(f'call reset() on this {type(self).__name__} before step()')
        dt = check_positive(dt, 'dt')
        slow = 1.0 + (0.0 if measured is None else self._phase_error(measured))
        h = dt / (self._tau * slow)
        x1 = self._x * math.exp(-self.params.alpha_x * h)
        self._advance(h, self._x, x1)
        self._x = x1
        self._s += h
        return self._output()

    # --- what each primitive defines ---------------------------------------------------------
    def _begin(self, start: ArrayLike | None, goal: ArrayLike | None) -> None:
        """Set the online state at ``start`` heading for ``goal`` (the demonstrated by default)."""
        raise NotImplementedError

    def _phase_error(self, measured: ArrayLike) -> float:
        """Return the weighted squared tracking error that stretches the time constant."""
        raise NotImplementedError

    def _advance(self, h: float, x0: float, x1: float) -> None:
        """Integrate the online state over a step ``h`` with the phase going from x0 to x1."""
        raise NotImplementedError

    def _output(self) -> FloatArray:
        """Return the commanded state of the online execution."""
        raise NotImplementedError

    def _arrays(self) -> dict[str, Any]:
        """Return the arrays :meth:`save` writes."""
        raise NotImplementedError

    @classmethod
    def _from_arrays(cls: type[P], params: DmpParams, arrays: dict[str, Any],
                     path: PathLike) -> P:
        """Return a primitive of this class from the arrays :meth:`save` wrote."""
        raise NotImplementedError

    @property
    def phase(self) -> float:
        """float: Canonical phase ``x`` of the online execution (1 at the start)."""
        return self._x

    @property
    def elapsed(self) -> float:
        """float: Phase time of the online execution, s (wall time minus pauses)."""
        return self._s * self._tau

    # --- files -------------------------------------------------------------------------------
    def save(self, path: PathLike) -> None:
        """
        Write the learnt primitive and its hyper-parameters to an ``.npz`` file.

        Parameters
        ----------
        path : str or Path
            Output file (written as given, no suffix added).

        """
        self._check_fitted()
        arrays = {'kind': np.array(self.KIND), 'params': np.array(json.dumps(asdict(self.params)))}
        arrays.update(self._arrays())
        save_archive(path, arrays, FORMAT, FORMAT_VERSION)

    @classmethod
    def load(cls: type[P], path: PathLike) -> P:
        """
        Read a primitive written by :meth:`save`.

        Parameters
        ----------
        path : str or Path
            ``.npz`` file.

        Returns
        -------
        instance of the class
            The learnt primitive.

        Raises
        ------
        ValueError
            If the file is not a DMP file, has another format version, or holds another kind
            of primitive; the message names the file.

        """
        kind, params, arrays = read_dmp_file(path)
        if kind != cls.KIND:
            raise ValueError(f'{path}: holds a {kind!r} DMP, expected {cls.KIND!r} '
                             f'(use suture_lfd.dmp.load_dmp to read any kind)')
        return cls._from_arrays(params, arrays, path)


class PrimitivePart(Primitive):
    """
    A position or quaternion primitive: learnt weights, demonstrated start and goal.

    The attributes below are set by ``fit`` or ``load``.

    Attributes
    ----------
    weights_ : ndarray, shape (n_bfs, n)
        Forcing-term weights.
    start_, goal_ : ndarray
        Demonstrated start and goal.
    degenerate_ : ndarray of bool
        Dimensions learnt unscaled (the scaling guard).

    """

    PREFIX = ''  # key prefix of the part's arrays in a DMP file

    def __init__(self, params: DmpParams | None = None) -> None:
        super().__init__(params)
        self.weights_: FloatArray | None = None
        self.start_: FloatArray | None = None
        self.goal_: FloatArray | None = None
        self.degenerate_: FloatArray | None = None

    def _arrays(self, prefix: str | None = None) -> dict[str, Any]:
        prefix = self.PREFIX if prefix is None else prefix
        return {prefix + 'weights': self.weights_, prefix + 'start': self.start_,
                prefix + 'goal': self.goal_, prefix + 'duration': np.array(self.duration_),
                prefix + 'degenerate': self.degenerate_}

    def _read_arrays(self, arrays: dict[str, Any], path: PathLike, prefix: str) -> None:
        """Set the learnt attributes from what :meth:`_arrays` stored under ``prefix``."""
        self.weights_ = stored_array(arrays, prefix + 'weights', path).astype(float)
        self.start_ = stored_array(arrays, prefix + 'start', path).astype(float)
        self.goal_ = stored_array(arrays, prefix + 'goal', path).astype(float)
        self.degenerate_ = stored_array(arrays, prefix + 'degenerate', path).astype(bool)
        self.duration_ = float(stored_array(arrays, prefix + 'duration', path))


def read_dmp_file(path: PathLike) -> tuple[str, DmpParams, dict[str, Any]]:
    """
    Return ``(kind, params, arrays)`` of a DMP file, raising ValueError naming ``path``.

    Parameters
    ----------
    path : str or Path
        ``.npz`` file written by ``save``.

    Returns
    -------
    kind : str
        ``'position'``, ``'quaternion'`` or ``'pose'``.
    params : DmpParams
        Stored hyper-parameters.
    arrays : dict of str to ndarray
        All stored arrays.

    """
    arrays = load_archive(path, FORMAT, FORMAT_VERSION, 'DMP file')
    try:
        mapping = json.loads(str(arrays['params']))
        kind = str(arrays['kind'])
    except (KeyError, json.JSONDecodeError) as exc:
        raise ValueError(f'{path}: DMP file without readable hyper-parameters ({exc})') from exc
    params = dataclass_from_mapping(DmpParams, mapping, source=str(path), prefix='params')
    return kind, params, arrays


def stored_array(arrays: dict[str, Any], key: str, path: PathLike) -> FloatArray:
    """Return ``arrays[key]``, or raise a ValueError naming ``path`` and the missing key."""
    if key not in arrays:
        raise ValueError(f'{path}: DMP file lacks the array {key!r}')
    return np.array(arrays[key])
