"""
Motion metrics of one instrument (or the needle): path, economy, smoothness and idle time.

The objective measures of the suturing-skill literature the seed paper cites for its future work
(Moorthy et al. 2004: time, path length and number of movements of each hand; Vedula et al.
2016: time, path length, number of movements and idle time of each instrument; Frischknecht et
al. 2013: entry/exit accuracy, see :mod:`suture_lfd.assessment.demo_scores`), with the
smoothness measures of the motor-control literature:

- path length ``L = sum |p[k+1] - p[k]|``;
- economy of motion ``E`` (in (0, 1]): the movements' straight-line distances from where each
  starts to where it ends, over the path travelled in them; 1 for straight movements;
- jerk: the root mean square of ``|d^3 p / dt^3|`` (m/s^3, 0 for a line at constant speed)
  and the dimensionless jerk ``(D^5 / L^2) integral |jerk|^2 dt`` of Hogan and Sternad 2009
  (``D`` the duration, ``L`` the path length): scale free, 720 for one minimum-jerk movement
  (``integral_0^1 (60 - 360 s + 360 s^2)^2 ds``) and larger for less smooth ones; reported as
  its log, ``LDLJ = -ln`` of it (Balasubramanian et al. 2015): -6.58 for one minimum-jerk
  movement, more negative for less smooth ones;
- number of velocity peaks: maxima of the speed that rise at least ``peak_prominence`` of the
  largest speed above the trough before them and fall as far after them (one per smooth
  movement; the speed is zero before the first and after the last sample);
- spectral arc length (SPARC, Balasubramanian et al. 2012 and 2015): minus the arc length of
  the normalised Fourier magnitude spectrum of the speed, over frequencies up to the last one
  above ``sparc_threshold`` below ``sparc_cutoff_hz``; -1.6 or so for one smooth movement,
  more negative for less smooth ones;
- idle time: total time of the rests (speed below ``idle_speed`` for at least ``min_idle_s``).

Derivatives come from positions low-passed at ``cutoff_hz`` (zero-phase Butterworth) on an
evenly spaced time grid; rests (idle time, the movements between them) from positions
low-passed at ``idle_cutoff_hz``, so that a hand at rest with a tremor still rests. Units: m, s.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import butter, sosfiltfilt
from sim_bridge.common.validation import check_array, check_times


@dataclass(frozen=True)
class MotionConfig:
    """
    Thresholds of the motion metrics.

    Attributes
    ----------
    cutoff_hz : float
        Low-pass cut-off (Hz) of the positions before differentiating (above the 8-9 Hz
        physiological tremor, so tremor counts against smoothness).
    idle_cutoff_hz : float
        Low-pass cut-off (Hz) of the positions for finding rests (below the tremor: a 50 um
        tremor at 8 Hz moves the tip at 2.5 mm/s).
    idle_speed : float
        Speed (m/s) under which an instrument rests.
    min_idle_s : float
        Shortest rest (s) counted as idle time.
    peak_prominence : float
        Prominence of a velocity peak as a fraction of the largest speed.
    sparc_cutoff_hz : float
        Highest frequency (Hz) of the spectral arc length.
    sparc_threshold : float
        Normalised magnitude under which the spectrum is cut (SPARC's adaptive cut-off).
    sparc_padding : int
        Zero padding of the speed before its Fourier transform (power of two above
        ``n * 2**sparc_padding``).

    """

    cutoff_hz: float = 15.0
    idle_cutoff_hz: float = 3.0
    idle_speed: float = 0.002
    min_idle_s: float = 0.1
    peak_prominence: float = 0.1
    sparc_cutoff_hz: float = 10.0
    sparc_threshold: float = 0.05
    sparc_padding: int = 4

    def __post_init__(self) -> None:
        for name in ('cutoff_hz', 'idle_cutoff_hz', 'idle_speed', 'peak_prominence',
                     'sparc_cutoff_hz', 'sparc_threshold'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ValueError(f'MotionConfig.{name} must be a number > 0, got {value!r}')
        if not (isinstance(self.min_idle_s, (int, float)) and self.min_idle_s >= 0.0):
            raise ValueError(f'MotionConfig.min_idle_s must be >= 0 s, got {self.min_idle_s!r}')


@dataclass(frozen=True)
class MotionMetrics:
    """
    Motion metrics of one trajectory (see the module docstring for the definitions).

    Attributes
    ----------
    duration_s : float
        Time span, s.
    path_length_m : float
        Travelled distance, m.
    economy : float
        Sum of the movements' chords over the path travelled in them (1 = straight
        movements; NaN without movement).
    rms_jerk : float
        Root mean square jerk, m/s^3.
    log_dimensionless_jerk : float
        ``-ln(D^5 / L^2 * integral |jerk|^2 dt)`` (NaN without movement or jerk).
    velocity_peaks : int
        Number of velocity peaks.
    sparc : float
        Spectral arc length of the speed (NaN without movement).
    idle_s : float
        Idle time, s.
    movements : int
        Number of movements (intervals between rests).

    """

    duration_s: float
    path_length_m: float
    economy: float
    rms_jerk: float
    log_dimensionless_jerk: float
    velocity_peaks: int
    sparc: float
    idle_s: float
    movements: int


def _grid(T: ArrayLike, P: ArrayLike) -> tuple[np.ndarray, np.ndarray, float]:
    T = check_times(T, 'T', min_points=4)
    P = check_array(P, 'P')
    if P.ndim == 1:
        P = P[:, None]
    if P.ndim != 2 or P.shape[0] != T.size:
        raise ValueError(f'P must have shape ({T.size}, n_dims), got {P.shape}')
    steps = np.diff(T)
    if np.ptp(steps) > 1e-6 * steps.mean():
        n = int(round((T[-1] - T[0]) / steps.mean())) + 1
        grid = np.linspace(T[0], T[-1], n)
        P = np.column_stack([np.interp(grid, T, P[:, k]) for k in range(P.shape[1])])
        T = grid
    return T, P, float(T[1] - T[0])


def smoothed(T: np.ndarray, P: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """
    Return positions low-passed at ``cutoff_hz`` (zero-phase 2nd-order Butterworth).

    The ends are padded with the trajectory's point reflection over three time constants,
    so a motion at constant velocity passes unchanged.

    A cut-off at or above the Nyquist frequency returns the positions unchanged.

    Parameters
    ----------
    T : ndarray, shape (n,)
        Evenly spaced times, s.
    P : ndarray, shape (n, n_dims)
        Positions, m.
    cutoff_hz : float
        Cut-off frequency, Hz.

    Returns
    -------
    ndarray, shape (n, n_dims)

    """
    dt = float(T[1] - T[0])
    nyquist = 0.5 / dt
    if cutoff_hz >= nyquist or P.shape[0] < 16:
        return P
    # odd padding over three time constants: a motion at constant velocity passes unchanged
    # and the filter's start-up transient dies out in the padding
    pad = min(P.shape[0] - 1, int(math.ceil(3.0 / (cutoff_hz * dt))))
    sos = butter(2, cutoff_hz / nyquist, output='sos')
    return sosfiltfilt(sos, P, axis=0, padtype='odd', padlen=pad)


def speed_profile(T: ArrayLike, P: ArrayLike, config: 'MotionConfig | None' = None,
                  cutoff_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the evenly spaced times and the speed of a trajectory.

    Parameters
    ----------
    T : array_like, shape (n,)
        Increasing times, s (resampled to an even grid when uneven).
    P : array_like, shape (n, n_dims)
        Positions, m.
    config : MotionConfig, optional
    cutoff_hz : float, optional
        Low-pass cut-off, Hz (default ``config.cutoff_hz``).

    Returns
    -------
    T : ndarray, shape (m,)
        Times, s.
    speed : ndarray, shape (m,)
        Speed, m/s (central differences of the low-passed positions).

    """
    config = MotionConfig() if config is None else config
    cutoff_hz = config.cutoff_hz if cutoff_hz is None else cutoff_hz
    T, P, dt = _grid(T, P)
    V = np.gradient(smoothed(T, P, cutoff_hz), dt, axis=0)
    return T, np.linalg.norm(V, axis=1)


def path_length(P: ArrayLike) -> float:
    """Return the length (m) of the polyline through the positions ``P`` (n, n_dims)."""
    P = check_array(P, 'P')
    if P.ndim == 1:
        P = P[:, None]
    return float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum()) if len(P) > 1 else 0.0


def rests(T: np.ndarray, speed: np.ndarray, idle_speed: float,
          min_idle_s: float) -> list[tuple[int, int]]:
    """
    Return the rests of a speed profile: ``(start, end)`` sample index pairs (end exclusive).

    A rest is a run of samples with ``speed < idle_speed`` lasting at least ``min_idle_s``
    (from the first to one sample past the last of the run).
    """
    slow = speed < idle_speed
    edges = np.flatnonzero(np.diff(np.concatenate(([0], slow.astype(np.int8), [0]))))
    dt = float(T[1] - T[0]) if T.size > 1 else 0.0
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])
            if (b - a) * dt >= min_idle_s - 1e-9]


def spectral_arc_length(speed: ArrayLike, dt: float, cutoff_hz: float = 10.0,
                        threshold: float = 0.05, padding: int = 4) -> float:
    """
    Return the spectral arc length (SPARC) of a speed profile.

    Balasubramanian, Melendez-Calderon, Roby-Brami, Burdet, "On the analysis of movement
    smoothness", J. NeuroEng. Rehabil. 2015: with ``V(f)`` the Fourier magnitude of the
    zero-padded speed normalised by ``V(0)``, and ``f_c`` the highest frequency under
    ``cutoff_hz`` where ``V >= threshold``,
    ``SPARC = -integral_0^f_c sqrt((1 / f_c)^2 + (dV/df)^2) df``.

    Parameters
    ----------
    speed : array_like, shape (n,)
        Speed samples, evenly spaced.
    dt : float
        Sample period, s.
    cutoff_hz, threshold : float
        Upper frequency bound (Hz) and amplitude threshold.
    padding : int
        The transform has ``2**(ceil(log2 n) + padding)`` points.

    Returns
    -------
    float
        SPARC (negative; NaN for a speed that is zero throughout).

    """
    v = np.asarray(speed, dtype=float)
    if v.size < 2 or not np.any(v > 0.0):
        return float('nan')
    n_fft = int(2 ** (math.ceil(math.log2(v.size)) + padding))
    f = np.fft.rfftfreq(n_fft, dt)
    V = np.abs(np.fft.rfft(v, n_fft))
    V = V / V[0]
    band = f <= cutoff_hz
    f, V = f[band], V[band]
    above = np.flatnonzero(V >= threshold)
    last = int(above[-1]) if above.size else 0
    f, V = f[:last + 1], V[:last + 1]
    if f.size < 2:
        return 0.0
    df = np.diff(f) / (f[-1] - f[0])
    return -float(np.sum(np.hypot(df, np.diff(V))))


def velocity_peaks(speed: Sequence[float] | np.ndarray, delta: float) -> int:
    """
    Return the number of speed peaks that rise and fall by at least ``delta``.

    A peak counts when the speed has risen ``delta`` above the lowest value since the last
    counted peak and then falls ``delta`` below its highest value; the speed is taken as zero
    before the first and after the last sample.

    Parameters
    ----------
    speed : sequence of float or ndarray, shape (n,)
        Speed samples, m/s.
    delta : float
        Least rise and fall, m/s (> 0).

    Returns
    -------
    int

    """
    count, up, low, high = 0, True, 0.0, 0.0
    for v in [float(x) for x in speed] + [0.0]:
        if up:
            if v > high:
                high = v
            elif high - v >= delta and high - low >= delta:
                count, up, low = count + 1, False, v
        elif v < low:
            low = v
        elif v - low >= delta:
            up, high = True, v
    return count


def motion_metrics(T: ArrayLike, P: ArrayLike, config: 'MotionConfig | None' = None
                   ) -> 'MotionMetrics':
    """
    Return the motion metrics of a trajectory.

    Parameters
    ----------
    T : array_like, shape (n,)
        Increasing times, s (resampled to an even grid when uneven), ``n >= 4``.
    P : array_like, shape (n, n_dims)
        Positions, m (any frame: every metric is frame-invariant).
    config : MotionConfig, optional
        Thresholds (defaults of :class:`MotionConfig`).

    Returns
    -------
    MotionMetrics

    """
    config = MotionConfig() if config is None else config
    T, P, dt = _grid(T, P)
    S = smoothed(T, P, config.cutoff_hz)
    V = np.gradient(S, dt, axis=0)
    speed = np.linalg.norm(V, axis=1)
    J = np.gradient(np.gradient(V, dt, axis=0), dt, axis=0)
    jerk2 = np.sum(J * J, axis=1)
    duration = float(T[-1] - T[0])
    length = path_length(P)
    slow = np.linalg.norm(np.gradient(smoothed(T, P, config.idle_cutoff_hz), dt, axis=0),
                          axis=1)
    idle = rests(T, slow, config.idle_speed, config.min_idle_s)
    idle_s = sum(b - a for a, b in idle) * dt
    # movements: the intervals between rests (the chord of each over the path travelled)
    bounds, k = [], 0
    for a, b in idle:
        if a > k:
            bounds.append((k, a))
        k = b
    if k < T.size - 1:
        bounds.append((k, T.size - 1))
    bounds = [(a, min(b, T.size - 1)) for a, b in bounds if b > a]
    chords = sum(float(np.linalg.norm(P[b] - P[a])) for a, b in bounds)
    travelled = sum(path_length(P[a:b + 1]) for a, b in bounds)
    moving = length > 1e-12
    peak = float(speed.max()) if speed.size else 0.0
    peaks = velocity_peaks(speed, config.peak_prominence * peak) if peak > 0.0 else 0
    integral = float(np.sum(0.5 * (jerk2[1:] + jerk2[:-1])) * dt)
    return MotionMetrics(
        duration_s=duration,
        path_length_m=length,
        economy=min(1.0, chords / travelled) if travelled > 1e-12 else float('nan'),
        rms_jerk=math.sqrt(integral / duration) if duration > 0.0 else 0.0,
        log_dimensionless_jerk=(-math.log(duration ** 5 / length ** 2 * integral)
                                if moving and integral > 0.0 else float('nan')),
        velocity_peaks=peaks,
        sparc=spectral_arc_length(speed, dt, config.sparc_cutoff_hz, config.sparc_threshold,
                                  config.sparc_padding) if moving else float('nan'),
        idle_s=float(idle_s),
        movements=len(bounds))
