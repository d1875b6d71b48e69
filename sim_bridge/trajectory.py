"""
Joint-space motion: synchronised trapezoidal trajectories and limited setpoint tracking.

:class:`JointTrajectory` is what a dVRK ``move_jp`` runs (the dVRK uses Reflexxes): every joint
follows a velocity trapezoid (or triangle) inside its velocity and acceleration limits, scaled by
the ``trajectory_j/set_ratio`` ratio, and the slower joints set one common duration so that all
joints start and arrive together. A trajectory may start while the joints are moving (a move that
replaces a running one), in which case the profile first ramps from the current velocity.

:func:`track_step` moves a measured position one time step towards a setpoint within the same
limits: the kinematic stand-in for the dVRK's joint PID when a ``servo_*`` command jumps the
setpoint.

Units: joint positions in rad or m, velocities per second, accelerations per second squared;
arrays have shape (n,) for n joints.

Size: the trapezoid planner and the limited tracking step share one profile arithmetic on the
per-step path of every arm, which is kept in one file for speed.
"""

from collections.abc import Sequence
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

# Joint values as a tuple of Python floats (the state of :class:`JointMotion`).
Floats = tuple[float, ...]


def _rest_to_rest_time(distance: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Minimum time to travel ``distance`` >= 0 from rest to rest (triangle or trapezoid)."""
    return np.where(distance <= v * v / a, 2.0 * np.sqrt(np.maximum(distance, 0.0) / a),
                    distance / v + v / a)


def minimum_duration(distance: ArrayLike, v0: ArrayLike, v_max: ArrayLike,
                     a_max: ArrayLike) -> np.ndarray:
    """
    Minimum time to travel a displacement from velocity ``v0`` to rest, per joint.

    Parameters
    ----------
    distance : array_like, shape (n,)
        Signed displacement (rad or m).
    v0 : array_like, shape (n,)
        Initial velocity (rad/s or m/s); may exceed ``v_max``.
    v_max, a_max : array_like, shape (n,)
        Velocity and acceleration limits, > 0.

    Returns
    -------
    ndarray, shape (n,)
        Durations (s).

    """
    distance = np.asarray(distance, dtype=float)
    flip = distance < 0.0
    D = np.where(flip, -distance, distance)
    w = np.where(flip, -np.asarray(v0, dtype=float), v0)
    v = np.asarray(v_max, dtype=float)
    a = np.asarray(a_max, dtype=float)
    stop = w * np.abs(w) / (2.0 * a)  # signed displacement needed to stop
    # moving towards the goal too fast to stop in time: stop, then come back
    t_over = w / a + _rest_to_rest_time(stop - D, v, a)
    # moving away from the goal: stop, then go
    t_away = -w / a + _rest_to_rest_time(D - stop, v, a)
    # moving towards the goal (or at rest) above the limit: slow down to v_max, cruise, stop
    t_fast = w / a + (D - stop) / v
    # at or below the limit: accelerate to the peak (triangle) or to v_max (trapezoid)
    peak = np.sqrt(np.maximum(a * D + 0.5 * w * w, 0.0))
    t_tri = (2.0 * peak - w) / a
    t_trap = (v - w) / a + v / a + (D - (2.0 * v * v - w * w) / (2.0 * a)) / v
    t_near = np.where(peak <= v, t_tri, t_trap)
    return np.where(w < 0.0, t_away,
                    np.where(stop > D, t_over, np.where(w > v, t_fast, t_near)))


def _profile_distance(vc: np.ndarray, T: float, v0: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Displacement of the ramp(v0 -> vc), cruise(vc), ramp(vc -> 0) profile of duration T."""
    return vc * T + (v0 - vc) * np.abs(vc - v0) / (2.0 * a) - vc * np.abs(vc) / (2.0 * a)


class JointTrajectory:
    """
    Time-synchronised trapezoidal joint trajectory from ``start`` to ``goal``.

    Each joint ramps from its start velocity to a cruise velocity, cruises and ramps down to rest,
    never above ``ratio * v_max`` (unless it starts faster, then it only slows down) nor above
    ``ratio * a_max``. The duration is that of the slowest joint; the others cruise slower so that
    all arrive together.

    Parameters
    ----------
    start, goal : array_like, shape (n,)
        Joint positions (rad / m).
    v_max, a_max : array_like, shape (n,)
        Velocity (rad/s, m/s) and acceleration (rad/s^2, m/s^2) limits, > 0.
    ratio : float
        Scaling in ]0, 1] applied to both ``v_max`` and ``a_max`` (dVRK
        ``trajectory_j/set_ratio``).
    start_velocity : array_like, shape (n,), optional
        Joint velocities at ``t = 0`` (default: at rest).

    Attributes
    ----------
    start, goal : ndarray, shape (n,)
    duration : float
        Time (s) at which every joint is at ``goal`` and at rest.

    """

    def __init__(self, start: ArrayLike, goal: ArrayLike, v_max: ArrayLike, a_max: ArrayLike,
                 ratio: float = 1.0, start_velocity: ArrayLike | None = None) -> None:
        self.start = np.array(start, dtype=float)
        self.goal = np.array(goal, dtype=float)
        n = self.start.shape
        if self.goal.shape != n or self.start.ndim != 1:
            raise ValueError(f'start and goal must both have shape (n,), got {n} and '
                             f'{self.goal.shape}')
        if not (np.all(np.isfinite(self.start)) and np.all(np.isfinite(self.goal))):
            raise ValueError('start and goal must be finite')
        if not (np.isfinite(ratio) and 0.0 < ratio <= 1.0):
            raise ValueError(f'ratio must be in ]0, 1], got {ratio}')
        self.v_limit = ratio * np.broadcast_to(np.asarray(v_max, dtype=float), n)
        self.a_limit = ratio * np.broadcast_to(np.asarray(a_max, dtype=float), n)
        if not (np.all(self.v_limit > 0.0) and np.all(self.a_limit > 0.0)):
            raise ValueError('v_max and a_max must be positive')
        v0 = np.zeros(n) if start_velocity is None else np.array(start_velocity, dtype=float)
        if v0.shape != n or not np.all(np.isfinite(v0)):
            raise ValueError(f'start_velocity must be finite with shape {n}')
        self._v0 = v0
        distance = self.goal - self.start
        durations = minimum_duration(distance, v0, self.v_limit, self.a_limit)
        self.duration = float(np.max(durations)) if durations.size else 0.0
        self._vc = self._cruise_velocities(distance, self.duration)
        a = self.a_limit
        self._t1 = np.abs(self._vc - v0) / a
        self._s1 = np.sign(self._vc - v0)
        self._b2 = np.maximum(self._t1, self.duration - np.abs(self._vc) / a)
        self._s3 = -np.sign(self._vc)
        # per joint, in plain floats, for sample_values()
        self._joint_terms = tuple(zip(*(x.tolist() for x in (
            self.start, v0, self._vc, self.a_limit, self._t1, self._b2, self._s1, self._s3))))
        self._goal_values = tuple(self.goal.tolist())

    def _cruise_velocities(self, distance: np.ndarray, T: float) -> np.ndarray:
        """Bisect the cruise velocity per joint so that the profile of duration T covers it."""
        v0, a, v = self._v0, self.a_limit, self.v_limit
        aT = a * T
        lo = np.maximum(-v, 0.5 * (v0 - aT))
        hi = np.minimum(v, 0.5 * (v0 + aT))
        lo = np.minimum(lo, hi)
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            below = _profile_distance(mid, T, v0, a) < distance
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        return 0.5 * (lo + hi)

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """
        Position and velocity at time ``t``.

        Parameters
        ----------
        t : float
            Time since the start (s); clamped to ``[0, duration]``.

        Returns
        -------
        q : ndarray, shape (n,)
            Joint positions (rad / m); exactly ``goal`` once ``t >= duration``.
        qd : ndarray, shape (n,)
            Joint velocities (rad/s, m/s).

        """
        if t >= self.duration:
            return self.goal.copy(), np.zeros_like(self.goal)
        t = max(float(t), 0.0)
        a, v0, vc = self.a_limit, self._v0, self._vc
        tau1 = np.minimum(t, self._t1)
        tau2 = np.clip(t - self._t1, 0.0, self._b2 - self._t1)
        tau3 = np.maximum(t - self._b2, 0.0)
        q = (self.start + v0 * tau1 + 0.5 * self._s1 * a * tau1 * tau1 + vc * tau2
             + vc * tau3 + 0.5 * self._s3 * a * tau3 * tau3)
        qd = np.where(t <= self._t1, v0 + self._s1 * a * t,
                      np.where(t <= self._b2, vc, vc + self._s3 * a * tau3))
        return q, qd

    def sample_values(self, t: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """
        :meth:`sample` in plain floats: the same operations joint by joint, the same values.

        Parameters
        ----------
        t : float
            Time since the start (s); clamped to ``[0, duration]``.

        Returns
        -------
        q, qd : tuple of float, length n
            Joint positions (rad / m) and velocities (rad/s, m/s).

        """
        if t >= self.duration:
            return self._goal_values, (0.0,) * len(self._goal_values)
        t = max(float(t), 0.0)
        q, qd = [], []
        for start, v0, vc, a, t1, b2, s1, s3 in self._joint_terms:
            # min(x, y) is "y if y < x else x" and max(x, y) "y if y > x else x", written out
            tau1 = t1 if t1 < t else t
            x = t - t1
            x = 0.0 if 0.0 > x else x
            tau2 = b2 - t1 if b2 - t1 < x else x
            x = t - b2
            tau3 = 0.0 if 0.0 > x else x
            q.append(start + v0 * tau1 + 0.5 * s1 * a * tau1 * tau1 + vc * tau2
                     + vc * tau3 + 0.5 * s3 * a * tau3 * tau3)
            qd.append(v0 + s1 * a * t if t <= t1 else vc if t <= b2 else vc + s3 * a * tau3)
        return tuple(q), tuple(qd)

    def done(self, t: float) -> bool:
        """
        Whether the trajectory has arrived at time ``t``.

        Parameters
        ----------
        t : float
            Time since the start (s).

        Returns
        -------
        bool

        """
        return t >= self.duration


def track_step(q: ArrayLike, qd: ArrayLike, target: ArrayLike, v_max: ArrayLike,
               a_max: ArrayLike, dt: float, target_velocity: ArrayLike | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """
    Move a measured position one time step towards a setpoint within velocity/acceleration limits.

    The commanded velocity is the setpoint velocity ``v_s`` (feed-forward) plus a correction that
    can still stop at the setpoint, ``sign(e) * min(sqrt(2 a |e|), |e| / dt)`` with
    ``e = target - q - v_s dt`` the error seen from the moving setpoint; it is clipped to
    ``v_max`` and reached with at most ``a_max * dt`` change of velocity. ``target`` is the
    setpoint at the end of the step.

    Parameters
    ----------
    q, qd : array_like, shape (n,)
        Current position (rad / m) and velocity (rad/s, m/s).
    target : array_like, shape (n,)
        Setpoint position (rad / m).
    v_max, a_max : array_like, shape (n,)
        Limits (per second, per second squared), > 0.
    dt : float
        Time step (s), > 0.
    target_velocity : array_like, shape (n,), optional
        Setpoint velocity (rad/s, m/s) used as feed-forward; default zero.

    Returns
    -------
    q : ndarray, shape (n,)
        New position.
    qd : ndarray, shape (n,)
        New velocity.

    """
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    target = np.asarray(target, dtype=float)
    tv = 0.0 if target_velocity is None else np.asarray(target_velocity, dtype=float)
    # error to close, seen from a frame moving with the setpoint during this step
    e = target - q - tv * dt
    a = np.asarray(a_max, dtype=float)
    v = np.asarray(v_max, dtype=float)
    mag = np.abs(e)
    correction = np.sign(e) * np.minimum(np.sqrt(2.0 * a * mag), mag / dt)
    v_des = np.clip(tv + correction, -v, v)
    qd_new = qd + np.clip(v_des - qd, -a * dt, a * dt)
    q_new = q + qd_new * dt
    arrived = (np.abs(target - q_new) < 1e-12) & (np.abs(qd_new) <= a * dt)
    return np.where(arrived, target, q_new), qd_new




def _values(x: Sequence[float] | np.ndarray) -> tuple[float, ...]:
    """Return joint values (array, list or tuple) as a tuple of Python floats."""
    if isinstance(x, np.ndarray):
        return tuple(x.astype(float, copy=False).reshape(-1).tolist())
    return tuple(map(float, x))


class JointMotion:
    """
    A joint group (the arm joints or the jaw) following its setpoint within limits.

    Holds the measured state, the setpoint and what drives the setpoint: a
    :class:`JointTrajectory` (``move_*``), a stream of servo setpoints (``servo_*``: the measured
    joints glide from one setpoint to the next over the command interval), or nothing (hold).

    The state is kept as tuples of Python floats (``q_values``, ``qd_values``,
    ``setpoint_values``): a few joints stepped every physics step cost less that way than
    through NumPy, with the same operations as the array functions :func:`track_step` and
    :meth:`JointTrajectory.sample` (bit for bit). A tuple is replaced, never changed, when the
    joints move, so a caller may keep one and compare it by identity. ``q``, ``qd`` and
    ``setpoint`` give NumPy copies.

    Parameters
    ----------
    q0 : array_like, shape (n,)
        Initial position (rad / m); also the initial setpoint.
    lower, upper : array_like, shape (n,)
        Position limits (rad / m).
    v_max, a_max : array_like, shape (n,)
        Velocity and acceleration limits (per s, per s^2).

    Attributes
    ----------
    trajectory : JointTrajectory or None
        The running move.

    """

    def __init__(self, q0: ArrayLike, lower: ArrayLike, upper: ArrayLike, v_max: ArrayLike,
                 a_max: ArrayLike) -> None:
        self._q = _values(np.array(q0, dtype=float))
        n = len(self._q)
        self._zeros = (0.0,) * n
        self._qd = self._zeros
        self._sp = self._q
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.v_max = np.asarray(v_max, dtype=float)
        self.a_max = np.asarray(a_max, dtype=float)
        self._limits = tuple(zip(self.v_max.tolist(), self.a_max.tolist(), self.lower.tolist(),
                                 self.upper.tolist(), (-self.v_max).tolist()))
        self._bounds = tuple(zip(self.lower.tolist(), self.upper.tolist()))
        self.trajectory: JointTrajectory | None = None
        self.servo_loop: Any = None  # a sim_bridge.realism.servo.ServoLag, or None: ideal tracking
        self._t0 = 0.0
        # (start, goal, start time, interval) of a servo glide
        self._ramp: tuple[Floats, Floats, float, float] | None = None
        self._last_servo_time: float | None = None

    # -- state -----------------------------------------------------------------------------------

    @property
    def q(self) -> np.ndarray:
        """Measured position (rad / m), shape (n,) (a copy)."""
        return np.array(self._q)

    @q.setter
    def q(self, value: Sequence[float] | np.ndarray) -> None:
        self._q = _values(value)

    @property
    def qd(self) -> np.ndarray:
        """Measured velocity (rad/s, m/s), shape (n,) (a copy)."""
        return np.array(self._qd)

    @qd.setter
    def qd(self, value: Sequence[float] | np.ndarray) -> None:
        self._qd = _values(value)

    @property
    def setpoint(self) -> np.ndarray:
        """Servo goal, or the trajectory sample at the last :meth:`advance`, shape (n,)."""
        return np.array(self._sp)

    @setpoint.setter
    def setpoint(self, value: Sequence[float] | np.ndarray) -> None:
        self._sp = _values(value)

    @property
    def q_values(self) -> tuple[float, ...]:
        """Measured position as a tuple of floats (replaced, not changed, when it moves)."""
        return self._q

    @property
    def qd_values(self) -> tuple[float, ...]:
        """Measured velocity as a tuple of floats."""
        return self._qd

    @property
    def setpoint_values(self) -> tuple[float, ...]:
        """Setpoint as a tuple of floats (replaced, not changed, when it moves)."""
        return self._sp

    # -- tracking --------------------------------------------------------------------------------

    def _track(self, target: Sequence[float], velocity: Sequence[float] | None, dt: float,
               glide: tuple[float, float] | None = None) -> tuple[Floats, Floats]:
        """
        :func:`track_step`, then the position limits (a joint held at a limit stops), per joint.

        The same operations as the array version, joint by joint in plain floats: a few joints
        are cheaper that way than through a dozen NumPy calls. ``target`` and ``velocity``
        (None: zero) are sequences of floats; returns tuples (q, qd). With ``glide = (m,
        interval)`` they are the start and goal of a servo glide instead, and each joint tracks
        ``start + (goal - start) * m`` at ``(goal - start) / interval`` (what :meth:`target`
        gives), formed in the same loop.
        """
        loop = self.servo_loop
        if loop is not None:  # sim_bridge.realism.servo: the ideal motion is the loop's reference
            measured = (self._q, self._qd)
            if loop.reference is not None:
                self._q, self._qd = loop.reference
            self.servo_loop = None
            try:
                loop.reference = self._track(target, velocity, dt, glide)
            finally:
                self.servo_loop = loop
                self._q, self._qd = measured
            return loop.follow(measured, loop.reference, dt, self._bounds)
        # min(x, y) is "y if y < x else x" and max(x, y) "y if y > x else x", written out
        q_out, qd_out = [], []
        tv = self._zeros if velocity is None else velocity
        m, interval = glide if glide is not None else (0.0, 0.0)
        sqrt = math.sqrt
        for q, qd, g, w, (v, a, lo, hi, minus_v) in zip(self._q, self._qd, target, tv,
                                                          self._limits):
            if glide is not None:
                g, w = g + (w - g) * m, (w - g) / interval  # from (start, goal)
            e = g - q - w * dt
            mag = abs(e)
            root, ramp = sqrt(2.0 * a * mag), mag / dt
            step = ramp if ramp < root else root
            x = w + (step if e > 0.0 else -step if e < 0.0 else 0.0 * step)
            x = minus_v if minus_v > x else x
            v_des = v if v < x else x
            dv = a * dt
            x = v_des - qd
            x = -dv if -dv > x else x
            qd_new = qd + (dv if dv < x else x)
            q_new = q + qd_new * dt
            if abs(g - q_new) < 1e-12 and abs(qd_new) <= dv:
                q_new = g
            x = lo if lo > q_new else q_new
            clipped = hi if hi < x else x
            q_out.append(clipped)
            qd_out.append(qd_new if clipped == q_new else 0.0)
        return tuple(q_out), tuple(qd_out)

    def _target(self, now: float) -> tuple[Floats, Floats | None]:
        """:meth:`target` as tuples of floats (the velocity None when standing still)."""
        if self.trajectory is not None:
            return self.trajectory.sample_values(now - self._t0)
        if self._ramp is not None:
            start, goal, t0, interval = self._ramp
            s = (now - t0) / interval
            if s <= 1.0 + 1e-9:
                m = min(s, 1.0)
                return (tuple([a + (b - a) * m for a, b in zip(start, goal)]),
                        tuple([(b - a) / interval for a, b in zip(start, goal)]))
        return self._sp, None

    def target(self, now: float) -> tuple[np.ndarray, np.ndarray | None]:
        """
        Setpoint to track at time ``now`` (s) and its velocity (None when standing still).

        Returns
        -------
        q : ndarray, shape (n,)
        qd : ndarray, shape (n,) or None

        """
        q, qd = self._target(now)
        return np.array(q), None if qd is None else np.array(qd)

    def setpoint_velocity(self, now: float) -> np.ndarray:
        """Velocity (per s) of the tracked setpoint at time ``now``, shape (n,)."""
        velocity = self._target(now)[1]
        return np.zeros(len(self._q)) if velocity is None else np.array(velocity)

    def servo(self, goal: Sequence[float] | np.ndarray, now: float, stream_gap: float) -> None:
        """
        Jump the setpoint to ``goal`` (stopping any trajectory).

        Parameters
        ----------
        goal : array_like, shape (n,)
            New setpoint (rad / m), already inside the limits.
        now : float
            Current time (s).
        stream_gap : float
            Commands closer than this (s) to the previous one glide from it over the interval.

        """
        goal = _values(goal)
        last = self._last_servo_time
        if last is not None and 0.0 < now - last <= stream_gap:
            start = self._target(now)[0]
            # gliding to where the setpoint already is would be a ramp that does not move
            self._ramp = None if start == goal else (start, goal, now, now - last)
        elif last is not None and now == last and self._ramp is not None:
            start, _, t0, interval = self._ramp
            self._ramp = (start, goal, t0, interval)
        else:
            self._ramp = None
        self._last_servo_time = now
        self.trajectory = None
        self._sp = goal

    def move(self, goal: ArrayLike, now: float, ratio: float) -> JointTrajectory:
        """
        Start a trajectory to ``goal`` from the current setpoint and its velocity.

        Parameters
        ----------
        goal : array_like, shape (n,)
            Goal (rad / m), already inside the limits.
        now : float
            Current time (s).
        ratio : float
            Trajectory ratio in ]0, 1].

        Returns
        -------
        JointTrajectory

        """
        velocity: Sequence[float] | np.ndarray | None
        start, velocity = self._target(now)
        velocity = self._zeros if velocity is None else velocity
        velocity = np.clip(velocity, -self.v_max, self.v_max)
        self.trajectory = JointTrajectory(start, goal, self.v_max, self.a_max, ratio=ratio,
                                          start_velocity=velocity)
        self._t0 = now
        self._ramp = None
        self._sp = tuple(self.trajectory.start.tolist())
        return self.trajectory

    def hold(self) -> None:
        """Stop where the measured joints are: no trajectory, setpoint = measured, at rest."""
        self.trajectory = None
        self._ramp = None
        self._sp = self._q
        self._qd = self._zeros

    def stop(self) -> None:
        """Zero the measured velocity, keeping everything else (an arm without power)."""
        self._qd = self._zeros

    @property
    def idle(self) -> bool:
        """Whether nothing moves: no trajectory, no glide, at rest on the setpoint."""
        return (self.trajectory is None and self._ramp is None and self._q == self._sp
                and not any(self._qd))

    def advance(self, now: float, dt: float, exact: bool = False) -> bool:
        """
        Move the measured joints over one step ending at ``now`` and update the setpoint.

        Parameters
        ----------
        now : float
            Time at the end of the step (s).
        dt : float
            Step length (s).
        exact : bool
            Measured = setpoint instead of limited tracking.

        Returns
        -------
        bool
            True when a trajectory arrived during this step.

        """
        ramp = self._ramp
        if self.trajectory is None and ramp is None:
            if self._q == self._sp and not any(self._qd):
                return False  # at rest on its setpoint: nothing moves (the common idle case)
            target, velocity = self._sp, None
        elif ramp is not None and not exact and self.trajectory is None:
            start, goal, t0, interval = ramp  # a servo glide: its setpoint formed while tracking
            s = (now - t0) / interval
            if s <= 1.0 + 1e-9:
                self._q, self._qd = self._track(start, goal, dt, (min(s, 1.0), interval))
            else:
                self._q, self._qd = self._track(self._sp, None, dt)
            if now > t0 + interval * (1.0 + 1e-9):
                self._ramp = None
            return False
        else:
            target, velocity = self._target(now)
        if exact:
            # np.clip with array bounds, written out (a bound wins a tie: signs of zeros)
            out = []
            for v, (lo, hi) in zip(target, self._bounds):
                x = v if v > lo else lo
                out.append(x if x < hi else hi)
            clipped = tuple(out)
            qd = self._zeros if velocity is None else velocity
            self._qd = tuple([w if c == v else 0.0 for c, v, w in zip(clipped, target, qd)])
            self._q = clipped
        else:
            self._q, self._qd = self._track(target, velocity, dt)
        ramp = self._ramp
        if ramp is not None and now > ramp[2] + ramp[3] * (1.0 + 1e-9):
            self._ramp = None
        if self.trajectory is None:
            return False
        self._sp = target
        if self.trajectory.done(now - self._t0):
            self.trajectory = None
            return True
        return False
