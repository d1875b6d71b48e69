"""
Forces of the tissue on the needle: puncture push, friction along the wire, off-arc resistance.

The model is quasi-static, after Okamura et al. (2004) for straight needles and Jackson &
Cavusoglu (2012) for circular ones:

- before the tip punctures, the surface pushes back on the tip along its outward normal with
  ``pad_stiffness`` times the surface's deflection (capped by the puncture force);
- at every puncture the needle occupies, the tissue pulls the needle's wire back towards the
  puncture point with ``lateral_stiffness`` times their distance (zero while the needle moves
  along its own arc), and rubs along the wire against its motion with
  ``friction_per_length`` times the length of wire inside, shared among the punctures.

Each force is a :class:`Contact`: a point on the needle and a force on the needle there
(``world``, m and N) plus the stiffness that resists moving that point, which the grip uses to
find how far the needle turns until the torque it holds balances the tissue's.
"""

from dataclasses import dataclass
import math

import numpy as np

# Needle speed (m per step) along the wire below which friction fades linearly (stiction).
_FRICTION_SLIP = 1e-6


@dataclass(frozen=True, eq=False)
class Contact:
    """
    A force of the tissue on the needle.

    Attributes
    ----------
    point : ndarray, shape (3,)
        Point of the needle it acts on (``world``, m).
    force : ndarray, shape (3,)
        Force on the needle (``world``, N).
    stiffness : float
        Stiffness (N/m) against moving ``point`` (0 for friction and drag).

    """

    point: np.ndarray
    force: np.ndarray
    stiffness: float


def nearest_on_arc(T_world_needle: np.ndarray, radius: float, p: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """
    Nearest point of the needle's circle to ``p`` and the wire's tangent there (tail to tip).

    Parameters
    ----------
    T_world_needle : ndarray, shape (4, 4)
        Needle pose (``world``).
    radius : float
        Needle radius (m).
    p : ndarray, shape (3,)
        Point (``world``, m).

    Returns
    -------
    point, tangent : ndarray, shape (3,)
        In ``world``.

    """
    R, t = T_world_needle[:3, :3], T_world_needle[:3, 3]
    q = R.T @ (p - t)
    phi = float(np.arctan2(q[1], q[0]))
    c, s = np.cos(phi), np.sin(phi)
    return R @ np.array([radius * c, radius * s, 0.0]) + t, R @ np.array([s, -c, 0.0])


def puncture_push(tip: np.ndarray, normal: np.ndarray, deflection: float,
                  stiffness: float) -> Contact:
    """
    Return the surface's push on the tip before puncture.

    Parameters
    ----------
    tip : ndarray, shape (3,)
        Needle tip (``world``, m).
    normal : ndarray, shape (3,)
        Outward unit normal of the surface.
    deflection : float
        How far (m) the surface is pressed in under the tip.
    stiffness : float
        Surface stiffness (N/m).

    Returns
    -------
    Contact

    """
    return Contact(tip, stiffness * deflection * normal, stiffness)


def puncture_contacts(T_world_needle: np.ndarray, T_prev: np.ndarray, radius: float,
                      punctures: np.ndarray, lateral_stiffness: float, friction: float
                      ) -> list[Contact]:
    """
    Off-arc resistance and friction at the punctures the needle occupies.

    Parameters
    ----------
    T_world_needle, T_prev : ndarray, shape (4, 4)
        Needle pose now and one step before (``world``).
    radius : float
        Needle radius (m).
    punctures : ndarray, shape (n, 3)
        Occupied puncture points (``world``, m).
    lateral_stiffness : float
        N/m per puncture.
    friction : float
        Total friction (N) along the wire, shared among the punctures.

    Returns
    -------
    list of Contact

    """
    out = []
    share = friction / max(1, len(punctures))
    R = T_world_needle[:3, :3]
    t = T_world_needle[:3, 3]
    # the same needle point one step before: R_prev R^T (c - t) + t_prev
    R_rel = (T_prev[:3, :3] @ R.T).tolist()
    t_prev = T_prev[:3, 3].tolist()
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    t0, t1, t2 = t.tolist()
    for p in punctures.tolist():  # plain floats: one or two punctures, every physics step
        d0, d1, d2 = p[0] - t0, p[1] - t1, p[2] - t2
        q0 = r00 * d0 + r10 * d1 + r20 * d2  # R^T d
        q1 = r01 * d0 + r11 * d1 + r21 * d2
        phi = math.atan2(q1, q0)
        cs, sn = math.cos(phi), math.sin(phi)
        c = (r00 * radius * cs + r01 * radius * sn + t0,
             r10 * radius * cs + r11 * radius * sn + t1,
             r20 * radius * cs + r21 * radius * sn + t2)
        tangent = (r00 * sn - r01 * cs, r10 * sn - r11 * cs, r20 * sn - r21 * cs)
        force = [lateral_stiffness * (p[i] - c[i]) for i in range(3)]
        if share > 0.0:
            e = (c[0] - t0, c[1] - t1, c[2] - t2)
            before = [sum(R_rel[i][j] * e[j] for j in range(3)) + t_prev[i] for i in range(3)]
            along = sum(tangent[i] * (c[i] - before[i]) for i in range(3))
            rub = share * max(-1.0, min(1.0, along / _FRICTION_SLIP))
            force = [force[i] - rub * tangent[i] for i in range(3)]
        out.append(Contact(np.array(c), np.array(force), lateral_stiffness))
    return out
