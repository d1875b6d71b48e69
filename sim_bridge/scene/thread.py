"""
Suture thread dynamics: an inextensible, damped chain of nodes hanging from the needle tail.

The thread is ``n`` straight segments (capsules of radius ``radius`` between ``n + 1`` nodes),
node 0 pinned to the needle tail. Each step is Dynamic Follow-The-Leader (Mueller, Kim and
Chentanez, "Fast Simulation of Inextensible Hair and Fur", VRIPHYS 2012):

1. predict ``p_i = x_i + exp(-damping dt) v_i dt + g dt^2`` and pin ``p_0`` to the needle tail;
2. walk from the tail: put node ``i`` at distance ``L_i`` from node ``i - 1`` along
   ``p_i - p_{i-1}`` (every segment keeps its length exactly), and no lower than ``radius`` above
   the support surface (the phantom and the table) below it;
3. velocities ``v_i = (p_i - x_i) / dt - s * d_{i+1} / dt``, where ``d_i`` is node ``i``'s
   projection correction and ``s`` (``ftl_damping``) cancels most of the artificial damping the
   one-pass projection introduces; nodes resting on the support lose ``friction`` of their
   tangential velocity.

The projection is geometric, so the chain stays inextensible and stable at steps of 10 ms and
more; a first-order global solve of the length constraints (or PyBullet point-to-point
constraints) becomes unstable above ~2 ms when a straight thread falls and whips. In PyBullet
3.2.7 a 40-capsule chain joined by point-to-point constraints also stretched by nearly a segment
per joint at 10 solver iterations and cost ~70 us per 2 ms step, a spherical-joint multibody
0.3-0.8 ms; this chain costs ~30 us per step. PyBullet still draws the thread as capsules.

Steps queued with :meth:`ThreadChain.follow` run only when the thread is next read (its nodes,
velocities or speed): a thread that nothing draws or reads, as in a batch run, costs nothing,
and one that is read gets the very same steps in the same order, so its nodes are the same as
if every step had run at once.

Frames and units: node positions are in ``world`` metres, shape ``(n + 1, 3)``.
"""

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.validation import check_positive

# Queued steps beyond this many run one by one, oldest first, as new ones come (a thread that
# nobody reads for long holds bounded memory and never runs a long backlog at once).
_MAX_QUEUED = 4096
# A support surface: height (m, ``world`` z) under each of n (x, y) points, shape (n,).
Support = Callable[[np.ndarray], ArrayLike]


@dataclass(frozen=True)
class ThreadDynamicsConfig:
    """
    Thread material and solver settings.

    Attributes
    ----------
    damping : float
        Velocity damping rate (1/s): velocities decay as ``exp(-damping * dt)`` per step.
    ftl_damping : float
        Follow-the-leader velocity correction ``s`` in [0, 1] (Mueller et al. use 0.9).
    friction : float
        Fraction of a resting node's tangential velocity removed per step, in [0, 1].
    gravity : float
        Gravitational acceleration along world -z (m/s^2).

    """

    damping: float = 4.0
    ftl_damping: float = 0.9
    friction: float = 0.5
    gravity: float = 9.81

    def __post_init__(self) -> None:
        if not self.damping >= 0.0:
            raise ValueError(f'thread damping must be >= 0 1/s, got {self.damping}')
        if not 0.0 <= self.ftl_damping <= 1.0:
            raise ValueError(f'thread ftl_damping must be in [0, 1], got {self.ftl_damping}')
        if not 0.0 <= self.friction <= 1.0:
            raise ValueError(f'thread friction must be in [0, 1], got {self.friction}')


class ThreadChain:
    """
    An inextensible, damped chain of nodes pinned at node 0.

    Parameters
    ----------
    nodes : array_like, shape (n + 1, 3)
        Initial node positions in ``world`` (m); segment lengths at rest are taken from them.
    radius : float
        Thread radius (m); nodes rest ``radius`` above the support surface.
    config : ThreadDynamicsConfig, optional
        Material and solver settings.

    """

    def __init__(self, nodes: ArrayLike, radius: float,
                 config: ThreadDynamicsConfig | None = None) -> None:
        nodes = np.array(nodes, dtype=float)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or nodes.shape[0] < 2:
            raise ValueError(f'thread nodes must have shape (n + 1, 3), got {nodes.shape}')
        if not np.all(np.isfinite(nodes)):
            raise ValueError('thread nodes contain NaN or inf')
        lengths = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
        if np.any(lengths <= 0.0):
            raise ValueError('thread nodes must be distinct (a segment has zero length)')
        check_positive(radius, 'thread radius (m)')
        self.config = config or ThreadDynamicsConfig()
        self.radius = float(radius)
        self.rest_lengths = lengths
        self._lengths = lengths.tolist()
        self._x = nodes
        self._v = np.zeros_like(nodes)
        self._speed = 0.0
        self._queued: deque[tuple[float, ArrayLike, Support | None]] = deque()

    @property
    def nodes(self) -> np.ndarray:
        """Node positions, shape (n + 1, 3), ``world`` (m); a copy."""
        self.catch_up()
        return self._x.copy()

    @property
    def velocities(self) -> np.ndarray:
        """Node velocities, shape (n + 1, 3), ``world`` (m/s); a copy."""
        self.catch_up()
        return self._v.copy()

    @property
    def segment_count(self) -> int:
        """Number of segments ``n``."""
        return len(self.rest_lengths)

    def reset(self, nodes: ArrayLike) -> None:
        """
        Place the chain at ``nodes`` (``world``, m, shape (n + 1, 3)) at rest.

        Parameters
        ----------
        nodes : array_like, shape (n + 1, 3)
            New node positions; the segment count must not change.

        """
        nodes = np.array(nodes, dtype=float)
        if nodes.shape != self._x.shape:
            raise ValueError(f'thread nodes must have shape {self._x.shape}, got {nodes.shape}')
        self._x = nodes
        self._v = np.zeros_like(nodes)
        self._speed = 0.0
        self._queued = deque()

    def follow(self, dt: float, anchor: ArrayLike, support: Support | None = None) -> None:
        """
        Queue a :meth:`step`; queued steps run, in order, when the thread is next read.

        Parameters
        ----------
        dt : float
            Time step (s), positive.
        anchor : array_like, shape (3,)
            Needle tail position in ``world`` (m); kept as given, so pass an array that is
            not changed afterwards.
        support : callable, optional
            As for :meth:`step`; it must give the same heights when the step runs later (a
            fixed surface).

        """
        self._queued.append((dt, anchor, support))
        if len(self._queued) > _MAX_QUEUED:
            self._advance(*self._queued.popleft())

    def catch_up(self) -> None:
        """Run the steps queued by :meth:`follow`, oldest first."""
        queued = self._queued
        while queued:
            self._advance(*queued.popleft())

    def step(self, dt: float, anchor: ArrayLike, support: Support | None = None) -> None:
        """
        Advance the chain by ``dt`` seconds with node 0 at ``anchor`` (after any queued steps).

        Parameters
        ----------
        dt : float
            Time step (s), positive.
        anchor : array_like, shape (3,)
            Needle tail position in ``world`` (m); node 0 is placed there.
        support : callable, optional
            ``support(xy) -> z``: surface height (m) below points ``xy`` (shape (m, 2), world
            metres), vectorised; nodes are kept ``radius`` above it. None means no support.

        """
        self.catch_up()
        self._advance(dt, anchor, support)

    def _advance(self, dt: float, anchor: ArrayLike, support: Support | None) -> None:
        cfg = self.config
        x = self._x
        p = x + self._v * (dt * math.exp(-cfg.damping * dt))
        p[:, 2] -= cfg.gravity * dt * dt
        p[0] = anchor
        if support is None:
            floors = [-math.inf] * len(p)
        else:
            floors = (np.asarray(support(p[:, :2]), dtype=float) + self.radius).tolist()
        pts = p.tolist()
        corr = [(0.0, 0.0, 0.0)] * len(pts)
        resting = [False] * len(pts)
        ax, ay, az = pts[0]
        for i in range(1, len(pts)):
            qx, qy, qz = pts[i]
            ex, ey, ez = qx - ax, qy - ay, qz - az
            length = math.sqrt(ex * ex + ey * ey + ez * ez)
            if length < 1e-12:
                ex, ey, ez, length = 0.0, 0.0, -1.0, 1.0
            seg = self._lengths[i - 1]
            f = seg / length
            nx, ny, nz = ax + ex * f, ay + ey * f, az + ez * f
            if nz < floors[i]:
                # Lie on the support: keep the length, turn the segment up to the floor.
                nz = floors[i]
                rise = nz - az
                horizontal = math.hypot(ex, ey)
                if abs(rise) < seg and horizontal > 1e-12:
                    g = math.sqrt(seg * seg - rise * rise) / horizontal
                    nx, ny = ax + ex * g, ay + ey * g
                resting[i] = True
            corr[i] = (nx - qx, ny - qy, nz - qz)
            pts[i] = (nx, ny, nz)
            ax, ay, az = nx, ny, nz
        new = np.array(pts)
        d = np.array(corr)
        v = (new - x) / dt
        self._speed = float(np.sqrt(np.max(np.einsum('ij,ij->i', v, v))))
        v[:-1] -= (cfg.ftl_damping / dt) * d[1:]
        if support is not None and any(resting):
            rest = np.array(resting)
            v[rest, :2] *= 1.0 - cfg.friction
            v[rest, 2] = np.maximum(v[rest, 2], 0.0)
        v[0] = 0.0
        self._x = new
        self._v = v

    def max_speed(self) -> float:
        """
        Largest node displacement over the last step divided by its length (m/s).

        The follow-the-leader velocity state carries a correction term; this is the speed at
        which the nodes actually moved.

        Returns
        -------
        float
            Maximum node speed (m/s).

        """
        self.catch_up()
        return self._speed
