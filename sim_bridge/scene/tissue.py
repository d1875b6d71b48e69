"""
Needle-tissue tracking: surface crossings of the needle tip, marker errors and tissue trauma.

:class:`TissueTracker` is called once per simulation step with the needle pose. It samples the
needle's centre line at ``n_arc_points`` points (tail to tip), maps them into the phantom frame
and asks the phantom's tissue surface which are inside. It reports:

- ``entry``: the tip crossed the tissue surface from outside to inside. The crossing point is
  interpolated on the segment between the previous and the current tip position (where the
  depth below the surface changes sign) and put on the surface. Each entry opens a puncture.
- ``exit``: the tip crossed from inside to outside (it emerged). Opens a puncture too.
- ``withdrawn``: the tip left the tissue through a puncture it had entered by (backed out)
  rather than through new tissue.
- ``extracted``: after an exit, no sampled point of the needle is inside the tissue any more and
  the needle left through its punctures (the tail passed them): the throw is pulled through.
- ``trauma``: the needle strays from its own arc while inside: the distance from an occupied
  puncture point to the needle's circle rose above ``trauma_event_threshold`` (emitted once per
  rise; re-armed when it falls under half the threshold).

Trauma (tissue tearing): while the needle occupies a puncture (the puncture's projection onto
the needle circle lies on the arc, between tail and tip), the distance from the puncture point
to the needle's circle is how far the needle has moved off the path it cut. A needle rotated
exactly about its arc centre keeps it at zero. ``trauma_max`` and ``trauma_mean`` (the mean,
over updates with at least one occupied puncture, of the largest current distance) summarise
the throw.

Marker errors: ``distance_to_marker`` of an entry event is its distance to the target pair's
entry marker (exit, withdrawn, extracted: to the exit marker); without a target pair, to the
nearest marker of that kind. ``marker_name`` names the nearest marker of any pair
(``'synth2.entry'``).

Everything is in the world frame unless named otherwise; lengths in metres, time in seconds.

Size: one tracker whose per-step state (crossings, depths, trauma) every report reads; it runs on
the per-step path that is being made faster, and stays one file until that settles.
"""

from dataclasses import dataclass, field
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.validation import check_positive

if TYPE_CHECKING:
    from sim_bridge.common.needle import NeedleGeometry
    from sim_bridge.scene.phantom import Phantom

# Margin (m) of the test that the needle is wholly above the tissue: far above rounding.
_CLEARANCE = 1e-7


@dataclass(frozen=True)
class TissueConfig:
    """
    Tissue tracker settings.

    Attributes
    ----------
    n_arc_points : int
        Points sampled along the needle (tail to tip) each update.
    trauma_event_threshold : float
        Puncture-to-arc distance (m) that raises a ``trauma`` event.
    occupancy_margin : float
        Arc-parameter margin: a puncture is released once its projection lies more than this
        beyond the tail (pulled through) or the tip (backed out).
    withdraw_radius : float
        An outward tip crossing closer than this (m) to an occupied entry puncture is a
        withdrawal, not an exit.
    crossing_samples : int
        Samples along the last tip step used to locate a surface crossing.

    """

    n_arc_points: int = 24
    trauma_event_threshold: float = 0.001
    occupancy_margin: float = 0.02
    withdraw_radius: float = 0.0015
    crossing_samples: int = 32

    def __post_init__(self) -> None:
        if self.n_arc_points < 2:
            raise ValueError(f'tissue n_arc_points must be >= 2, got {self.n_arc_points}')
        check_positive(self.trauma_event_threshold, 'tissue trauma_event_threshold (m)')
        if self.occupancy_margin < 0.0:
            raise ValueError('tissue occupancy_margin must be >= 0')
        if self.withdraw_radius < 0.0:
            raise ValueError('tissue withdraw_radius must be >= 0 m')
        if self.crossing_samples < 2:
            raise ValueError('tissue crossing_samples must be >= 2')


@dataclass(frozen=True, eq=False)
class TissueEvent:
    """
    A needle-tissue event.

    Attributes
    ----------
    t : float
        Simulation time (s).
    kind : str
        ``'entry'``, ``'exit'``, ``'withdrawn'``, ``'extracted'`` or ``'trauma'``.
    point : ndarray, shape (3,)
        Crossing point on the surface (entry, exit, withdrawn), the exit puncture
        (extracted) or the puncture that strays (trauma); world frame, m.
    distance_to_marker : float
        Distance (m) from ``point`` to the target pair's marker of the event's kind (entry for
        ``entry``, exit otherwise); NaN for ``trauma``.
    marker_name : str
        Nearest marker of any pair (``'<pair>.entry'`` or ``'<pair>.exit'``).
    deviation : float
        Puncture-to-arc distance (m) for ``trauma``; the throw's largest so far for
        ``extracted``; 0 otherwise.

    """

    t: float
    kind: str
    point: np.ndarray
    distance_to_marker: float
    marker_name: str
    deviation: float = 0.0


@dataclass
class Puncture:
    """
    A hole the needle tip made in the surface (phantom frame).

    Attributes
    ----------
    kind : str
        ``'entry'`` or ``'exit'``.
    point : ndarray, shape (3,)
        Position (m), phantom frame.
    t : float
        Time (s) it was made.
    occupied : bool
        The needle still passes through it.
    released_by : str
        ``''`` while occupied, ``'tail'`` (pulled through) or ``'tip'`` (backed out).
    deviation_max : float
        Largest puncture-to-arc distance (m) seen.

    """

    kind: str
    point: np.ndarray
    t: float
    occupied: bool = True
    released_by: str = ''
    deviation_max: float = 0.0


@dataclass(frozen=True, eq=False)
class TissueState:
    """
    Snapshot of the needle-tissue state (world frame, metres).

    Attributes
    ----------
    t : float
        Time (s) of the last update.
    tip_inside : bool
        The tip is inside the tissue.
    inside_fraction : float
        Fraction of the sampled needle points inside the tissue.
    in_tissue : bool
        Some sampled point is inside, or a puncture is still occupied.
    trauma_current, trauma_max, trauma_mean : float
        Puncture-to-arc distances (m): now, largest, mean over occupied updates.
    entry_point, exit_point : ndarray, shape (3,) or None
        First entry and first exit crossing points.
    entry_error, exit_error : float
        Their distances (m) to the target markers (NaN if none yet).
    extracted : bool
        The needle has been pulled through.
    n_entries, n_exits : int
        Number of entry and exit crossings.

    """

    t: float
    tip_inside: bool
    inside_fraction: float
    in_tissue: bool
    trauma_current: float
    trauma_max: float
    trauma_mean: float
    entry_point: np.ndarray | None
    exit_point: np.ndarray | None
    entry_error: float
    exit_error: float
    extracted: bool
    n_entries: int
    n_exits: int
    punctures: tuple = field(default=())


class TissueTracker:
    """
    Track the needle against a phantom's tissue surface, one simulation step at a time.

    Parameters
    ----------
    phantom : sim_bridge.scene.phantom.Phantom
        Phantom (tissue surface, markers, pose).
    needle_geometry : sim_bridge.common.needle.NeedleGeometry
        Needle geometry.
    config : TissueConfig, optional
        Settings.

    """

    def __init__(self, phantom: 'Phantom', needle_geometry: 'NeedleGeometry',
                 config: TissueConfig | None = None) -> None:
        self.phantom = phantom
        self.needle = needle_geometry
        self.config = TissueConfig() if config is None else config
        self._surface = phantom.surface
        self._R_pw = phantom.T_phantom_world[:3, :3].copy()
        self._t_pw = phantom.T_phantom_world[:3, 3].copy()
        self._R_wp = phantom.T_world_phantom[:3, :3].copy()
        self._t_wp = phantom.T_world_phantom[:3, 3].copy()
        self._arc = needle_geometry.arc_points(self.config.n_arc_points)
        self._radius = needle_geometry.radius
        self._s_mid = math.pi - 0.5 * needle_geometry.arc
        self._inv_arc = 1.0 / needle_geometry.arc
        self._lam = np.linspace(0.0, 1.0, self.config.crossing_samples + 1)
        # What tells cheaply that the whole needle is above the tissue (see _clear_of_tissue).
        self._top_near = self._surface.top_bound(self._radius)
        self._R_pw_rows = self._R_pw.tolist()
        self._t_pw_list = self._t_pw.tolist()
        self._arc_span = (math.pi - needle_geometry.arc, math.pi)
        self._markers = {}
        for pair in phantom.markers_phantom.values():
            self._markers[f'{pair.name}.entry'] = pair.entry
            self._markers[f'{pair.name}.exit'] = pair.exit
        self._marker_names = list(self._markers)
        self._marker_pts = (np.array(list(self._markers.values())) if self._markers
                            else np.zeros((0, 3)))
        self._target: str | None = None
        self.reset()

    # ------------------------------------------------------------------ control
    def reset(self) -> None:
        """Forget all punctures and statistics (a new throw on fresh tissue)."""
        self._prev_tip: np.ndarray | bytes | None = None  # bytes: the pose of a repeat
        self._prev_in = False
        self.punctures: list[Puncture] = []
        self._occupied = np.zeros((0, 3))
        self._occ_index: list[int] = []
        self._t = 0.0
        self._inside_fraction = 0.0
        self._any_inside = False
        self._had_exit = False
        self._extracted = False
        self._trauma_now = 0.0
        self._trauma_max = 0.0
        self._trauma_sum = 0.0
        self._trauma_n = 0
        self._trauma_armed = True
        self._entry: np.ndarray | None = None
        self._exit: np.ndarray | None = None
        self._entry_error = math.nan
        self._exit_error = math.nan
        self._n_entries = 0
        self._n_exits = 0
        # (pose bytes, largest occupied deviation or None) of the last update when it changed
        # nothing but the statistics: the same pose again repeats that update (see update).
        self._repeat: tuple[bytes, float | None] | None = None

    def set_target_pair(self, name: str | None) -> None:
        """
        Choose the marker pair the throw aims at (``None`` for none).

        Parameters
        ----------
        name : str or None
            Pair name (``'synth1'``); must be one of the phantom's markers.

        """
        if name is not None and name not in self.phantom.markers_phantom:
            raise ValueError(f'unknown marker pair {name!r}; the phantom has '
                             f'{sorted(self.phantom.markers_phantom)}')
        self._target = name
        self._repeat = None

    @property
    def target_pair(self) -> str | None:
        """Name of the target marker pair, or None."""
        return self._target

    # ------------------------------------------------------------------ helpers
    def _to_world(self, p: np.ndarray) -> np.ndarray:
        return self._R_wp @ p + self._t_wp

    def _marker_info(self, p: np.ndarray, kind: str) -> tuple[float, str]:
        """Return (distance to the target marker of ``kind``, nearest marker name)."""
        if not len(self._marker_pts):
            return math.nan, ''
        d = np.linalg.norm(self._marker_pts - p, axis=1)
        nearest = self._marker_names[int(np.argmin(d))]
        if self._target is not None:
            q = self._markers[f'{self._target}.{kind}']
            return float(np.linalg.norm(q - p)), nearest
        same = [i for i, n in enumerate(self._marker_names) if n.endswith('.' + kind)]
        return float(d[same].min()), nearest

    def _crossing(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Point where the segment a -> b (phantom frame) crosses the tissue boundary."""
        seg = a + np.outer(self._lam, b - a)
        depth, inside = self._surface.depth(seg)
        change = np.nonzero(inside[1:] != inside[:-1])[0]
        k = int(change[0]) if len(change) else len(self._lam) - 2
        d0, d1 = depth[k], depth[k + 1]
        if d0 * d1 < 0.0:
            f = d0 / (d0 - d1)
            p = seg[k] + f * (seg[k + 1] - seg[k])
            p[2] = self._surface.height(p[:2])
            return p
        return 0.5 * (seg[k] + seg[k + 1])

    def _tip_at(self, prev: np.ndarray | bytes) -> np.ndarray:
        """Return the tip (phantom frame) of the last update, worked out again from its pose."""
        if not isinstance(prev, bytes):
            return prev
        T = np.frombuffer(prev).reshape(4, 4)
        R = self._R_pw @ T[:3, :3]
        tr = self._R_pw @ T[:3, 3] + self._t_pw
        return (self._arc @ R.T + tr)[-1]  # as update computes it

    def _clear_of_tissue(self, T: np.ndarray) -> bool:
        """
        Whether every sampled needle point of the pose ``T`` is above the tissue's top surface.

        A conservative test in plain floats: the lowest point of the needle's arc (phantom
        frame) against :meth:`HeightField.top_bound` around the arc centre, with a margin far
        larger than any rounding, so that True means :meth:`update` would find no point
        inside.
        """
        m = T.tolist()
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = self._R_pw_rows
        tx, ty, tz = self._t_pw_list
        x, y, z = m[0][3], m[1][3], m[2][3]
        cx = a0 * x + a1 * y + a2 * z + tx
        cy = b0 * x + b1 * y + b2 * z + ty
        cz = c0 * x + c1 * y + c2 * z + tz
        # z of the arc point at polar angle phi: cz + radius * (A cos(phi) + B sin(phi))
        A = c0 * m[0][0] + c1 * m[1][0] + c2 * m[2][0]
        B = c0 * m[0][1] + c1 * m[1][1] + c2 * m[2][1]
        start, end = self._arc_span
        lowest = min(A * math.cos(start) + B * math.sin(start), -A)  # the tip and the tail
        rho = math.hypot(A, B)
        if (math.atan2(B, A) + math.pi - start) % (2.0 * math.pi) <= end - start:
            lowest = -rho  # the circle's lowest point lies on the arc
        return cz + self._radius * lowest - _CLEARANCE > self._top_near(cx, cy)

    def _rebuild_occupied(self) -> None:
        self._occ_index = [i for i, p in enumerate(self.punctures) if p.occupied]
        self._occupied = (np.array([self.punctures[i].point for i in self._occ_index])
                          if self._occ_index else np.zeros((0, 3)))

    # ------------------------------------------------------------------ step
    def update(self, t: float, T_world_needle: ArrayLike) -> list[TissueEvent]:
        """
        Advance the tracker to time ``t`` with the needle at ``T_world_needle``.

        Parameters
        ----------
        t : float
            Simulation time (s).
        T_world_needle : array_like, shape (4, 4)
            Needle pose in the world frame.

        Returns
        -------
        list of TissueEvent
            Events of this step, in order (usually empty).

        """
        T = np.asarray(T_world_needle, dtype=float)
        key = T.tobytes()
        repeat = self._repeat
        if repeat is not None and repeat[0] == key:
            # The needle has not moved since an update that raised no event and released no
            # puncture: this one finds the same points, crossings and deviations, so it only
            # adds the occupied deviation to the trauma statistics again.
            self._t = float(t)
            now = repeat[1]
            if now is not None:
                self._trauma_now = now
                self._trauma_sum += now
                self._trauma_n += 1
            return []
        if (not self._occ_index and not self._prev_in and not self._any_inside
                and T.shape == (4, 4) and T.flags.c_contiguous and self._clear_of_tissue(T)):
            # Outside before and wholly above the tissue now: no crossing, nothing inside, no
            # puncture to follow, and the extraction test sees what the last update saw. The
            # tip is worked out from the pose only if the next update needs it (a crossing).
            self._t = float(t)
            self._inside_fraction = 0.0
            self._prev_tip = key
            self._repeat = (key, None)
            return []
        R = self._R_pw @ T[:3, :3]
        tr = self._R_pw @ T[:3, 3] + self._t_pw
        pts = self._arc @ R.T + tr
        depth, inside = self._surface.depth(pts)
        tip = pts[-1]
        tip_in = bool(inside[-1])
        self._t = float(t)
        events = []
        now = None
        released_any = False

        if self._prev_tip is not None and tip_in != self._prev_in:
            p = self._crossing(self._tip_at(self._prev_tip), tip)
            if tip_in:
                events.append(self._on_entry(t, p))
            else:
                events.append(self._on_exit(t, p))

        # Occupancy and trauma of the punctures the needle passes through.
        if self._occ_index:
            q = (self._occupied - tr) @ R
            phi = np.arctan2(q[:, 1], q[:, 0])
            dphi = np.mod(phi - self._s_mid + math.pi, 2.0 * math.pi) - math.pi
            s = 0.5 - dphi * self._inv_arc
            dev = np.hypot(np.hypot(q[:, 0], q[:, 1]) - self._radius, q[:, 2])
            m = self.config.occupancy_margin
            released = (s < -m) | (s > 1.0 + m)
            occ = ~released
            now = float(dev[occ].max()) if occ.any() else 0.0
            for j, i in enumerate(self._occ_index):
                punct = self.punctures[i]
                if occ[j]:
                    if dev[j] > punct.deviation_max:
                        punct.deviation_max = float(dev[j])
                else:
                    punct.occupied = False
                    punct.released_by = 'tail' if s[j] < 0.0 else 'tip'
            if occ.any():
                self._trauma_now = now
                self._trauma_sum += now
                self._trauma_n += 1
                if now > self._trauma_max:
                    self._trauma_max = now
                thr = self.config.trauma_event_threshold
                if self._trauma_armed and now > thr:
                    j = int(np.argmax(np.where(occ, dev, -1.0)))
                    point = self._to_world(self._occupied[j])
                    _, name = self._marker_info(self._occupied[j], 'entry')
                    events.append(TissueEvent(t, 'trauma', point, math.nan, name, now))
                    self._trauma_armed = False
                elif now < 0.5 * thr:
                    self._trauma_armed = True
            else:
                self._trauma_now = 0.0
            if released.any():
                released_any = True
                self._rebuild_occupied()

        n_inside = int(np.count_nonzero(inside))
        any_inside = n_inside > 0
        self._inside_fraction = float(n_inside) / len(inside)
        self._any_inside = any_inside
        if (self._had_exit and not self._extracted and not any_inside and not self._occ_index
                and not tip_in):
            last_exit = next(p for p in reversed(self.punctures) if p.kind == 'exit')
            if last_exit.released_by == 'tail':
                self._extracted = True
                dist, name = self._marker_info(last_exit.point, 'exit')
                events.append(TissueEvent(t, 'extracted', self._to_world(last_exit.point),
                                          dist, name, self._trauma_max))
        self._prev_tip = tip
        self._prev_in = tip_in
        self._repeat = None if events or released_any else (key, now)
        return events

    def _on_entry(self, t: float, p: np.ndarray) -> TissueEvent:
        self.punctures.append(Puncture('entry', p, float(t)))
        self._rebuild_occupied()
        self._n_entries += 1
        dist, name = self._marker_info(p, 'entry')
        if self._entry is None:
            self._entry = p
            self._entry_error = dist
        return TissueEvent(t, 'entry', self._to_world(p), dist, name)

    def _on_exit(self, t: float, p: np.ndarray) -> TissueEvent:
        wr = self.config.withdraw_radius
        for i in self._occ_index:
            punct = self.punctures[i]
            if punct.kind == 'entry' and np.linalg.norm(punct.point - p) < wr:
                punct.occupied = False
                punct.released_by = 'tip'
                self._rebuild_occupied()
                dist, name = self._marker_info(p, 'exit')
                return TissueEvent(t, 'withdrawn', self._to_world(p), dist, name)
        self.punctures.append(Puncture('exit', p, float(t)))
        self._rebuild_occupied()
        self._n_exits += 1
        self._had_exit = True
        dist, name = self._marker_info(p, 'exit')
        if self._exit is None:
            self._exit = p
            self._exit_error = dist
        return TissueEvent(t, 'exit', self._to_world(p), dist, name)

    # ------------------------------------------------------------------ state
    @property
    def inside_fraction(self) -> float:
        """Fraction of sampled needle points inside the tissue at the last update."""
        return self._inside_fraction

    @property
    def tip_inside(self) -> bool:
        """Whether the tip was inside the tissue at the last update."""
        return self._prev_in

    def wire_depth(self, T_world_needle: ArrayLike) -> float:
        """
        Return how deep (m) the needle's centre line dips below the tissue's top surface.

        The deepest of the arc points the tracker follows, as :meth:`update` sees them;
        negative when the whole needle is above the surface (by that much).
        """
        T = np.asarray(T_world_needle, dtype=float)
        pts = self._arc @ (self._R_pw @ T[:3, :3]).T + (self._R_pw @ T[:3, 3] + self._t_pw)
        depth, _ = self._surface.depth(pts)
        return float(depth.max())

    @property
    def in_tissue(self) -> bool:
        """Whether the needle is in the tissue (a point inside or a puncture occupied)."""
        return self._any_inside or bool(self._occ_index)

    @property
    def had_exit(self) -> bool:
        """Whether the tip has come out of the tissue (an exit) since the last reset."""
        return self._had_exit

    @property
    def extracted(self) -> bool:
        """Whether the needle has been pulled through after an exit."""
        return self._extracted

    @property
    def trauma_max(self) -> float:
        """Largest puncture-to-arc distance (m) so far."""
        return self._trauma_max

    @property
    def trauma_mean(self) -> float:
        """Mean over occupied updates of the largest puncture-to-arc distance (m)."""
        return self._trauma_sum / self._trauma_n if self._trauma_n else 0.0

    def state(self) -> TissueState:
        """
        Snapshot of the tracker (world frame).

        Returns
        -------
        TissueState

        """
        ep = None if self._entry is None else self._to_world(self._entry)
        xp = None if self._exit is None else self._to_world(self._exit)
        return TissueState(
            t=self._t, tip_inside=self._prev_in, inside_fraction=self._inside_fraction,
            in_tissue=self.in_tissue, trauma_current=self._trauma_now,
            trauma_max=self._trauma_max, trauma_mean=self.trauma_mean, entry_point=ep,
            exit_point=xp, entry_error=self._entry_error, exit_error=self._exit_error,
            extracted=self._extracted, n_entries=self._n_entries, n_exits=self._n_exits,
            punctures=tuple((p.kind, self._to_world(p.point), p.occupied)
                            for p in self.punctures))
