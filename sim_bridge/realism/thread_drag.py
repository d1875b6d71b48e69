"""
Thread drag: after the exit, the thread in the tissue pulls back on the needle's tail.

Between the tip's exit and the extraction (the tail pulled through), the suture trailing from
the tail runs through the needle's track; it pulls on the tail backwards along the wire with a
constant drag (Coulomb friction of the suture in its track). Frames: ``world``; N, m.
"""

import numpy as np
from sim_bridge.realism.needle_tissue import Contact


def thread_pull(T_world_needle: np.ndarray, tail: np.ndarray, tail_tangent: np.ndarray,
                drag: float) -> Contact:
    """
    Return the thread's pull on the tail.

    Parameters
    ----------
    T_world_needle : ndarray, shape (4, 4)
        Needle pose (``world``).
    tail : ndarray, shape (3,)
        Tail point in the needle frame (m).
    tail_tangent : ndarray, shape (3,)
        Unit tangent of the wire at the tail (tail to tip), needle frame.
    drag : float
        Pull (N).

    Returns
    -------
    Contact
        At the tail, along minus the tangent, without stiffness.

    """
    R = T_world_needle[:3, :3]
    return Contact(R @ tail + T_world_needle[:3, 3], -drag * (R @ tail_tangent), 0.0)
