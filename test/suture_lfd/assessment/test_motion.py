"""Motion metrics on constructed trajectories whose answers are known."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from suture_lfd.assessment.motion import (
    MotionConfig,
    motion_metrics,
    path_length,
    spectral_arc_length,
)

RATE = 100.0


def _min_jerk(n, start, end):
    """A minimum-jerk movement of n samples from start to end (rest at both ends)."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    shape = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
    return start + (end - start) * shape


def _times(n):
    return np.arange(n) / RATE


def test_straight_line_at_constant_speed_has_its_length_and_no_jerk():
    rng = np.random.default_rng(3)
    for _ in range(5):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        speed = rng.uniform(0.005, 0.05)
        T = _times(301)
        P = rng.normal(scale=0.05, size=3) + np.outer(T * speed, direction)
        m = motion_metrics(T, P)
        assert m.path_length_m == pytest.approx(speed * 3.0, rel=1e-9)
        assert m.rms_jerk == pytest.approx(0.0, abs=1e-4)  # m/s^3; a shaky hand: ~1
        assert m.economy == pytest.approx(1.0)
        assert m.velocity_peaks == 1
        assert m.idle_s == 0.0
        assert m.movements == 1


def test_path_length_of_a_square_is_its_perimeter():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0]], float) * 0.01
    assert path_length(square) == pytest.approx(0.04)


def test_separated_movements_give_one_velocity_peak_each():
    a, b = np.zeros(3), np.array([0.02, 0.0, 0.0])
    for k in (1, 2, 3, 5):
        parts, here = [], a
        for j in range(k):
            there = b if j % 2 == 0 else a
            parts += [_min_jerk(80, here, there), np.repeat(there[None], 40, axis=0)]
            here = there
        P = np.vstack(parts)
        m = motion_metrics(_times(len(P)), P)
        assert m.velocity_peaks == k
        assert m.movements == k


def test_one_minimum_jerk_movement_is_smooth():
    P = _min_jerk(200, np.zeros(3), np.array([0.01, 0.02, 0.0]))
    m = motion_metrics(_times(len(P)), P)
    # dimensionless jerk of a minimum-jerk movement: integral (60 - 360 s + 360 s^2)^2 = 720
    assert m.log_dimensionless_jerk == pytest.approx(-math.log(720.0), abs=0.05)
    assert m.economy == pytest.approx(1.0, abs=1e-6)
    assert -1.8 < m.sparc < -1.3


def test_a_tremor_lowers_smoothness():
    T = _times(300)
    P = _min_jerk(300, np.zeros(3), np.array([0.03, 0.0, 0.0]))
    shaky = P + 5e-5 * np.sin(2 * np.pi * 8.0 * T)[:, None] * np.array([0.0, 1.0, 0.0])
    smooth, rough = motion_metrics(T, P), motion_metrics(T, shaky)
    assert rough.sparc < smooth.sparc
    assert rough.log_dimensionless_jerk < smooth.log_dimensionless_jerk
    assert rough.velocity_peaks > smooth.velocity_peaks
    assert rough.rms_jerk > smooth.rms_jerk


@pytest.mark.parametrize('pause', [0.5, 1.5, 2.25])
def test_an_idle_period_of_known_length_is_measured(pause):
    duration, amplitude = 1.0, 0.02
    a, b = np.zeros(3), np.array([amplitude, 0.0, 0.0])
    n = int(round(duration * RATE)) + 1
    rest = np.repeat(b[None], int(round(pause * RATE)) - 1, axis=0)
    P = np.vstack((_min_jerk(n, a, b), rest, _min_jerk(n, b, a)))
    config = MotionConfig()
    # a minimum-jerk movement moves at (A / D) 30 s^2 (1 - s)^2: under the idle speed for
    # its first and last s* D seconds, which join the pause
    s_star = brentq(lambda s: amplitude / duration * 30 * s * s * (1 - s) ** 2
                    - config.idle_speed, 1e-6, 0.5)
    m = motion_metrics(_times(len(P)), P, config)
    assert m.idle_s == pytest.approx(pause + 2 * s_star * duration, abs=0.04)
    assert m.movements == 2
    assert m.velocity_peaks == 2


def test_a_detour_lowers_economy():
    out = np.linspace([0, 0, 0], [0.01, 0.01, 0], 100)
    on = np.linspace([0.01, 0.01, 0], [0.02, 0, 0], 100)[1:]
    m = motion_metrics(_times(199), np.vstack((out, on)))
    assert m.economy == pytest.approx(1.0 / math.sqrt(2.0), rel=0.01)


def test_spectral_arc_length_of_a_speed_that_never_moves_is_nan():
    assert math.isnan(spectral_arc_length(np.zeros(50), 0.01))


def test_bad_thresholds_are_named():
    with pytest.raises(ValueError, match='idle_speed'):
        MotionConfig(idle_speed=0.0)
    with pytest.raises(ValueError, match='P must have shape'):
        motion_metrics(_times(10), np.zeros((9, 3)))
