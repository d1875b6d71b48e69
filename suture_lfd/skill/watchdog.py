"""
The throw's watchdog: tells arms that stopped answering from a machine too busy to answer.

A controller streaming goals to remote arms must stop when they stop answering, but a loaded
machine that holds up the simulator (or the controller) for a while must not count as a dead
arm. :class:`ArmWatchdog` judges by the simulator's own clock (``/clock``) where there is one:

- an arm is silent when the clock advanced by more than ``stale_timeout`` simulation seconds
  since its last ``measured_cp`` was handled (ten times that while the throw settles): the
  simulation runs but the arm does not answer. A busy machine stops both the clock and the
  arms, so it never counts;
- the simulator is dead when neither the clock nor any ``measured_cp`` has come for
  ``clock_timeout`` seconds of wall time (not counting ticks the controller itself came late
  to). When the simulator's process can be watched (same machine), an exited process is dead
  as soon as the topics have been quiet for ``stale_timeout`` s of wall time, and a running one
  is waited for (starved of CPU, not dead) up to ``starved_timeout`` s of silence.

Without any clock message the silence is estimated from the wall time since the last
``measured_cp`` and the rate the simulation clock advanced over the last second of arrivals.

The watchdog is plain logic: its caller hands it the arrivals and the times (``now``: a
monotonic wall clock, s; stamps: simulation seconds), so it runs the same in a node and in a
unit test. Units: seconds.
"""

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
import math
from typing import Protocol


class WatchedProcess(Protocol):
    """The simulator's process, as seen from the same machine."""

    pid: int

    def alive(self) -> bool:
        """Return whether the process still exists."""


@dataclass(frozen=True)
class Verdict:
    """
    What the watchdog says at one check.

    Attributes
    ----------
    halt : bool
        Stop commanding (the arms or the simulator stopped answering).
    reason : str
        Why, in words for the log and the status (or the warning when not halting).
    details : dict
        ``silence_s`` (simulation s), ``wall_silence_s`` (wall s, when known),
        ``last_measured_t`` (stamp of the oldest newest ``measured_cp``).

    """

    halt: bool
    reason: str
    details: dict = field(default_factory=dict)


class ArmWatchdog:
    """
    Silence of the arms and of the simulator, judged by the simulator's clock.

    Parameters
    ----------
    arms : sequence of str
        The arms that must answer (the first gives the simulation rate).
    rate : float
        Checks per wall second (a check later than five periods counts as the caller's delay).
    stale_timeout, clock_timeout, starved_timeout : float
        See the module's docstring (s).

    """

    def __init__(self, arms: Sequence[str], rate: float, stale_timeout: float,
                 clock_timeout: float, starved_timeout: float) -> None:
        for name, value in (('rate', rate), ('stale_timeout', stale_timeout),
                            ('clock_timeout', clock_timeout),
                            ('starved_timeout', starved_timeout)):
            if not value > 0:
                raise ValueError(f'watchdog {name} must be > 0, got {value}')
        self.arms = tuple(arms)
        self.period = 1.0 / rate
        self.stale_timeout = stale_timeout
        self.clock_timeout = clock_timeout
        self.starved_timeout = starved_timeout
        self._arrival: dict[str, float] = {}  # arm -> wall time of the last measured_cp
        self._sim_rate = 1.0     # simulation s per wall s, from measured_cp stamps
        self._window: deque[tuple[float, float]] = deque()
        self._clock_t: float | None = None  # newest clock (simulation s)
        self._clock_wall: float | None = None  # wall time the clock last advanced
        self._clock_handled = -math.inf
        # arm -> clock (s) when its last measured_cp was handled
        self._heard: dict[str, float] = {}
        self._last_check: float | None = None
        self._starved_said = False

    # --- inputs -------------------------------------------------------------------------------

    def measured(self, arm: str, stamp: float, now: float) -> None:
        """Take an arm's ``measured_cp`` stamped ``stamp``, handled at wall time ``now``."""
        if arm == self.arms[0]:
            # simulation seconds per wall second over the last second of arrivals (bursts of
            # queued messages would make a per-message estimate wild)
            window = self._window
            window.append((now, stamp))
            while now - window[0][0] > 1.0:
                window.popleft()
            wall, advance = now - window[0][0], stamp - window[0][1]
            if wall > 0.2 and advance > 0.0:
                self._sim_rate = min(max(advance / wall, 0.05), 100.0)
        self._arrival[arm] = now
        self._heard[arm] = stamp if self._clock_t is None else max(stamp, self._clock_t)

    def clock(self, t: float, now: float) -> None:
        """Take a clock message (simulation s ``t``), handled at wall time ``now``."""
        if self._clock_t is not None and t > self._clock_t \
                and now - self._clock_handled > 5.0 * self.period:
            # the first clock after a while without one: the caller (or the simulator) was held
            # up, and the measured_cp that came meanwhile are still queued behind it; the jump
            # is no sign of silent arms
            for a in self._heard:
                self._heard[a] += t - self._clock_t
        self._clock_handled = now
        if self._clock_t is None or t > self._clock_t:
            self._clock_t = t
            self._clock_wall = now

    # --- judgement ----------------------------------------------------------------------------

    def silence(self, now: float) -> tuple[float, float | None]:
        """
        Return ``(simulation s, wall s or None)`` of silence at wall time ``now``.

        The first is the simulation time the clock advanced since the oldest last
        ``measured_cp`` was handled (without a clock: estimated from the wall time and the
        simulation rate); the second the wall time since anything came (clock or
        ``measured_cp``; None without a clock). A check that comes late (the caller was busy)
        restarts the wall counts: what arrived meanwhile is still queued.
        """
        late = self._last_check is None or now - self._last_check > 5.0 * self.period
        self._last_check = now
        if late:
            for a in self.arms:
                self._arrival[a] = max(self._arrival.get(a, now), now - self.period)
            if self._clock_wall is not None:
                self._clock_wall = max(self._clock_wall, now - self.period)
        if self._clock_t is None:
            return max((now - self._arrival.get(a, -math.inf)) * self._sim_rate
                       for a in self.arms), None
        assert self._clock_wall is not None  # set with the clock
        silence = max(self._clock_t - self._heard.get(a, -math.inf) for a in self.arms)
        heard = max([self._clock_wall] + [self._arrival.get(a, -math.inf) for a in self.arms])
        return max(silence, 0.0), now - heard

    def check(self, now: float, last_measured_t: float, settling: bool = False,
              process: WatchedProcess | None = None) -> Verdict | None:
        """
        Judge the silence at wall time ``now``.

        Parameters
        ----------
        now : float
            Wall time (monotonic s).
        last_measured_t : float
            Stamp (s) of the oldest of the arms' newest ``measured_cp``, for the message.
        settling : bool
            The commands are done: a silent arm counts only after ten times ``stale_timeout``.
        process : WatchedProcess, optional
            The simulator's process when it runs on this machine.

        Returns
        -------
        Verdict or None
            None while all is well; a verdict that halts, or one that only warns (once per
            starved spell) that a running simulator is being waited for.

        """
        silence, quiet = self.silence(now)
        if silence > self.stale_timeout * (10.0 if settling else 1.0):
            return Verdict(True, f'no measured_cp for {silence * 1e3:.0f} ms of simulation '
                                 f'time (last at t = {last_measured_t:.3f} s): the arms stopped '
                                 'answering',
                           {'silence_s': silence, 'last_measured_t': last_measured_t})
        if quiet is None:
            return None
        alive = None
        if quiet > self.stale_timeout and process is not None:
            alive = process.alive()
        elif quiet <= self.stale_timeout:
            self._starved_said = False
        details = {'silence_s': silence, 'wall_silence_s': quiet,
                   'last_measured_t': last_measured_t}
        if quiet > self.clock_timeout and alive and quiet <= self.starved_timeout:
            assert process is not None  # alive is set only with a process
            if self._starved_said:
                return None
            self._starved_said = True  # its process runs: starved of CPU, not dead
            return Verdict(False, f'no /clock and no measured_cp for {quiet:.2f} s, but the '
                                  f'simulator process {process.pid} runs: waiting for it '
                                  f'(starved_timeout {self.starved_timeout:g} s)', details)
        if alive is False:
            assert process is not None
            return Verdict(True, f'the simulator process {process.pid} exited: no /clock and '
                                 f'no measured_cp for {quiet:.2f} s of wall time (last '
                                 f'measured_cp at t = {last_measured_t:.3f} s)', details)
        if quiet > self.clock_timeout:
            return Verdict(True, f'no /clock and no measured_cp for {quiet:.2f} s of wall time '
                                 f'(last measured_cp at t = {last_measured_t:.3f} s, '
                                 f'{silence * 1e3:.0f} ms of simulation time before the clock '
                                 'stopped): the simulator stopped', details)
        return None
