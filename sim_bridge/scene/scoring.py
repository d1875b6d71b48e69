"""
Throw scoring: the paper's generality levels and per-subtask success for one suture throw.

:class:`ThrowScorer` consumes, in time order, grasp events (``on_grasp``, ``on_release``,
``on_drop``), needle-tissue events from :class:`sim_bridge.scene.tissue.TissueTracker`
(``on_tissue_event``) and instrument-phantom collisions (``on_collision``), and produces a
:class:`ThrowScore` with :meth:`ThrowScorer.result`.

Rules
-----
Let *entry* be the first ``entry`` event and *exit* the first ``exit`` event after it;
``tol = marker_tolerance``; holders are the arms holding the needle at an event's time.

Subtasks (the paper's five, Sec. III-C):

- **i** pick with PSM2 and reach the entry: PSM2 held the needle at *entry*, and *entry* is
  within ``tol`` of the entry marker.
- **ii** insert to the exit: *exit* happened while PSM2 held the needle, no ``withdrawn`` event
  came between *entry* and *exit*, and *exit* is within ``tol`` of the exit marker.
- **iii** regrasp with PSM1: after *exit*, PSM1 grasped the needle and then PSM2 released it while
  PSM1 still held it.
- **iv** extract: an ``extracted`` event while PSM1 (and not PSM2) held the needle.
- **v** hand over: after the extraction PSM2 grasped the needle and then PSM1 released it, leaving
  PSM2 the only holder, with no drop after the extraction.

Failure reasons (all that apply, in this order): ``no entry``, ``not held by PSM2 at entry``,
``entry missed`` (error > ``tol``), ``withdrawn``, ``no exit``, ``exit missed`` (error > ``tol``),
``not regrasped``, ``not extracted``, ``no handover`` (only if ``require_handover``),
``dropped`` (any drop before the handover completed), ``trauma`` (largest puncture-to-arc
distance > ``trauma_tolerance``), ``collisions`` (more than ``max_collisions`` when that is >= 0).

Score (the generality levels of the paper, Sec. IV-C):

- **1.0** no failure: the throw is complete.
- **0.8** the only failure is ``exit missed``: everything else succeeded but the needle came out
  away from the exit marker.
- **0.4** the failures are ``entry missed`` (and possibly ``exit missed``) only, with the entry
  error within ``reasonable_entry``: the needle missed the entry marker but still followed a
  reasonable trajectory (through the tissue on its arc, regrasped, extracted, handed over).
- **0.0** any other failure.

``time_s`` is the time from ``t_start`` to the completed handover (subtask v), or to ``t_end``
when the throw is not complete. Errors are reported in millimetres (NaN when the crossing did
not happen).
"""

from dataclasses import dataclass
import math
from typing import TYPE_CHECKING

from sim_bridge.common.validation import check_positive

if TYPE_CHECKING:
    from sim_bridge.scene.tissue import TissueEvent


@dataclass(frozen=True)
class ScoringConfig:
    """
    Tolerances of the throw score.

    Attributes
    ----------
    marker_tolerance : float
        Largest distance (m) between a tip crossing and its marker that still hits the marker.
    reasonable_entry : float
        Largest entry error (m) of a throw that misses the entry marker but still follows a
        reasonable trajectory (score 0.4).
    trauma_tolerance : float
        Largest puncture-to-arc distance (m) of an acceptable throw.
    max_collisions : int
        Instrument-phantom collisions allowed (-1: any number).
    require_handover : bool
        Whether subtask v is needed for a complete throw.

    """

    marker_tolerance: float = 0.0025
    reasonable_entry: float = 0.008
    trauma_tolerance: float = 0.002
    max_collisions: int = -1
    require_handover: bool = True

    def __post_init__(self) -> None:
        check_positive(self.marker_tolerance, 'scoring marker_tolerance (m)')
        if not self.reasonable_entry >= self.marker_tolerance:
            raise ValueError('scoring reasonable_entry must be >= marker_tolerance')
        check_positive(self.trauma_tolerance, 'scoring trauma_tolerance (m)')


@dataclass(frozen=True)
class ThrowScore:
    """
    Outcome of one throw.

    Attributes
    ----------
    score : float
        Generality level: 1.0, 0.8, 0.4 or 0.0.
    subtasks : dict of str to bool
        Success of subtasks ``'i'`` .. ``'v'``.
    entry_error_mm, exit_error_mm : float
        Distances (mm) of the first entry and exit crossings to their markers (NaN if none).
    trauma_mm : float
        Largest puncture-to-arc distance (mm).
    time_s : float
        Time (s) to the completed throw, or to the end of scoring.
    dropped : bool
        The needle was dropped before the handover completed.
    collisions : int
        Instrument-phantom collisions.
    failure : str
        ``''`` for a complete throw, else the failure reasons joined by ``'; '``.
    failures : tuple of str
        The failure reasons.

    """

    score: float
    subtasks: dict
    entry_error_mm: float
    exit_error_mm: float
    trauma_mm: float
    time_s: float
    dropped: bool
    collisions: int
    failure: str
    failures: tuple = ()

    @property
    def complete(self) -> bool:
        """Whether the throw is complete (score 1.0)."""
        return self.score == 1.0


class ThrowScorer:
    """
    Score one suture throw from its event stream (see the module docstring for the rules).

    Parameters
    ----------
    config : ScoringConfig, optional
        Tolerances.
    t_start : float
        Time (s) the throw starts.

    """

    def __init__(self, config: ScoringConfig | None = None, t_start: float = 0.0) -> None:
        self.config = ScoringConfig() if config is None else config
        self.t_start = float(t_start)
        self._holders: set[str] = set()
        self._entry: TissueEvent | None = None
        self._entry_holders: frozenset[str] = frozenset()
        self._exit: TissueEvent | None = None
        self._exit_holders: frozenset[str] = frozenset()
        self._withdrawn_before_exit = False
        self._psm1_after_exit = False
        self._regrasped = False
        self._extracted = False
        self._extract_holders: frozenset[str] = frozenset()
        self._psm2_after_extract = False
        self._handover_t: float | None = None
        self._dropped = False
        self._dropped_after_extract = False
        self._collisions = 0
        self._trauma = 0.0

    # ------------------------------------------------------------------ inputs
    def on_grasp(self, t: float, arm: str) -> None:
        """
        Record that ``arm`` (``'PSM1'``, ``'PSM2'``) grasped the needle at time ``t`` (s).

        Parameters
        ----------
        t : float
            Time (s).
        arm : str
            Arm name.

        """
        self._holders.add(arm)
        if arm == 'PSM1' and self._exit is not None and not self._extracted:
            self._psm1_after_exit = True
        if arm == 'PSM2' and self._extracted:
            self._psm2_after_extract = True

    def on_release(self, t: float, arm: str) -> None:
        """
        Record that ``arm`` opened its jaw on the needle at time ``t`` (s).

        Parameters
        ----------
        t : float
            Time (s).
        arm : str
            Arm name.

        """
        self._holders.discard(arm)
        if (arm == 'PSM2' and self._psm1_after_exit and 'PSM1' in self._holders
                and not self._extracted):
            self._regrasped = True
        if (arm == 'PSM1' and self._psm2_after_extract and self._holders == {'PSM2'}
                and not self._dropped_after_extract and self._handover_t is None):
            self._handover_t = float(t)

    def on_drop(self, t: float) -> None:
        """
        Record that the needle fell free of every arm at time ``t`` (s).

        Parameters
        ----------
        t : float
            Time (s).

        """
        self._holders.clear()
        if self._handover_t is None:
            self._dropped = True
            if self._extracted:
                self._dropped_after_extract = True

    def on_collision(self, t: float, arm: str) -> None:
        """
        Record an instrument-phantom collision of ``arm`` at time ``t`` (s).

        Parameters
        ----------
        t : float
            Time (s).
        arm : str
            Arm name.

        """
        self._collisions += 1

    def update_trauma(self, trauma_max: float) -> None:
        """
        Raise the recorded largest puncture-to-arc distance (m) to at least ``trauma_max``.

        Parameters
        ----------
        trauma_max : float
            A tracker's ``trauma_max`` (m).

        """
        self._trauma = max(self._trauma, float(trauma_max))

    def on_tissue_event(self, ev: 'TissueEvent') -> None:
        """
        Record a needle-tissue event.

        Parameters
        ----------
        ev : sim_bridge.scene.tissue.TissueEvent
            Event (``entry``, ``exit``, ``withdrawn``, ``extracted``, ``trauma``).

        """
        holders = frozenset(self._holders)
        if ev.kind == 'entry':
            if self._entry is None:
                self._entry = ev
                self._entry_holders = holders
        elif ev.kind == 'exit':
            if self._entry is not None and self._exit is None:
                self._exit = ev
                self._exit_holders = holders
        elif ev.kind == 'withdrawn':
            if self._entry is not None and self._exit is None:
                self._withdrawn_before_exit = True
        elif ev.kind == 'extracted':
            if self._exit is not None and not self._extracted:
                self._extracted = True
                self._extract_holders = holders
            self.update_trauma(ev.deviation)
        elif ev.kind == 'trauma':
            self.update_trauma(ev.deviation)
        else:
            raise ValueError(f'unknown tissue event kind {ev.kind!r}')

    # ------------------------------------------------------------------ result
    def result(self, t_end: float) -> ThrowScore:
        """
        Score the throw as it stands at time ``t_end`` (s).

        Parameters
        ----------
        t_end : float
            Time (s) scoring ends.

        Returns
        -------
        ThrowScore

        """
        cfg = self.config
        tol = cfg.marker_tolerance
        e_err = self._entry.distance_to_marker if self._entry is not None else math.nan
        x_err = self._exit.distance_to_marker if self._exit is not None else math.nan
        entry_hit = self._entry is not None and e_err <= tol
        exit_hit = self._exit is not None and x_err <= tol
        psm2_entry = 'PSM2' in self._entry_holders
        sub = {
            'i': self._entry is not None and psm2_entry and entry_hit,
            'ii': (self._exit is not None and 'PSM2' in self._exit_holders
                   and not self._withdrawn_before_exit and exit_hit),
            'iii': self._regrasped,
            'iv': self._extracted and 'PSM1' in self._extract_holders
            and 'PSM2' not in self._extract_holders,
            'v': self._handover_t is not None,
        }
        fails = []
        if self._entry is None:
            fails.append('no entry')
        else:
            if not psm2_entry:
                fails.append('not held by PSM2 at entry')
            if not entry_hit:
                fails.append('entry missed')
        if self._withdrawn_before_exit:
            fails.append('withdrawn')
        if self._exit is None:
            fails.append('no exit')
        elif not exit_hit:
            fails.append('exit missed')
        if not sub['iii']:
            fails.append('not regrasped')
        if not sub['iv']:
            fails.append('not extracted')
        if cfg.require_handover and not sub['v']:
            fails.append('no handover')
        if self._dropped:
            fails.append('dropped')
        if self._trauma > cfg.trauma_tolerance:
            fails.append('trauma')
        if 0 <= cfg.max_collisions < self._collisions:
            fails.append('collisions')
        kinds = set(fails)
        if not kinds:
            score = 1.0
        elif kinds == {'exit missed'}:
            score = 0.8
        elif ('entry missed' in kinds and kinds <= {'entry missed', 'exit missed'}
              and e_err <= cfg.reasonable_entry):
            score = 0.4
        else:
            score = 0.0
        done = self._handover_t if (not fails and self._handover_t is not None) else None
        end = done if done is not None else float(t_end)
        return ThrowScore(
            score=score, subtasks=sub, entry_error_mm=1e3 * e_err, exit_error_mm=1e3 * x_err,
            trauma_mm=1e3 * self._trauma, time_s=end - self.t_start, dropped=self._dropped,
            collisions=self._collisions, failure='; '.join(fails), failures=tuple(fails))
