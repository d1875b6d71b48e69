"""
The needle driver's grip: the needle is held up to a torque and a force, and turns past them.

Frames: the tool-tip frame of the holding PSM (``x`` the jaw hinge axis, along which the wire
lies in a canonical grasp; ``z`` the jaw's long axis). The grip holds the needle against a
torque about the jaw's long axis ``z`` through the grasp point up to ``torque`` and against a
force along the wire ``x`` up to ``force`` (Coulomb friction of the jaw faces). Beyond them the
needle turns about ``z`` (or slides along ``x``) until the tissue's wrench falls back to the
grip's limit -- quasi-static: the turn is the excess torque over the tissue's rotational
stiffness -- and it stays where it slipped to (the grasp itself is changed). A regrasp starts a
new :class:`Grip` episode (:meth:`Grip.reset`).
"""

from dataclasses import dataclass
import math

import numpy as np


@dataclass(frozen=True)
class Wrench:
    """
    The tissue's wrench on the needle at the grasp point, in the tool frame.

    Attributes
    ----------
    torque_z : float
        Torque (N m) about the jaw's long axis through the grasp point.
    force_x : float
        Force (N) along the wire (tool ``x``).
    stiffness_z : float
        Rotational stiffness (N m / rad) of the tissue against a turn about that axis.
    stiffness_x : float
        Stiffness (N/m) against a slide along tool ``x``.

    """

    torque_z: float
    force_x: float
    stiffness_z: float
    stiffness_x: float


@dataclass(frozen=True)
class Slip:
    """
    How the needle moved in the jaw in one step.

    Attributes
    ----------
    angle : float
        Turn (rad) about the jaw's long axis (tool ``z``) through the grasp point.
    slide : float
        Slide (m) along tool ``x``.

    """

    angle: float = 0.0
    slide: float = 0.0

    @property
    def moved(self) -> bool:
        """Whether the needle moved in the jaw."""
        return self.angle != 0.0 or self.slide != 0.0


class Grip:
    """
    A grip's limits and the slip since the needle was grasped.

    Parameters
    ----------
    torque : float
        Torque (N m) held about the jaw's long axis.
    force : float
        Force (N) held along the wire.
    max_step : float
        Largest turn (rad) per step; a slide is capped at a hundredth of it in m.

    Attributes
    ----------
    angle, slide : float
        Total turn (rad) and slide (m) since :meth:`reset`.

    """

    def __init__(self, torque: float, force: float, max_step: float) -> None:
        self.torque = float(torque)
        self.force = float(force)
        self.max_step = float(max_step)
        self.reset()

    def reset(self) -> None:
        """Forget the slip (a new grasp)."""
        self.angle = 0.0
        self.slide = 0.0

    def hold(self, wrench: Wrench) -> Slip:
        """
        Hold the needle against ``wrench``; return how far it slipped this step.

        Parameters
        ----------
        wrench : Wrench
            The tissue's wrench at the grasp point.

        Returns
        -------
        Slip
            Zero while the grip holds.

        """
        angle = slide = 0.0
        excess = abs(wrench.torque_z) - self.torque
        if excess > 0.0 and wrench.stiffness_z > 0.0:
            angle = math.copysign(min(excess / wrench.stiffness_z, self.max_step),
                                  wrench.torque_z)
        excess = abs(wrench.force_x) - self.force
        if excess > 0.0 and wrench.stiffness_x > 0.0:
            slide = math.copysign(min(excess / wrench.stiffness_x, 0.01 * self.max_step),
                                  wrench.force_x)
        self.angle += angle
        self.slide += slide
        return Slip(angle, slide)


def wrench_at(contacts: list, T_world_tool: np.ndarray, grasp_point: np.ndarray) -> Wrench:
    """
    Sum contacts into the wrench at the grasp point, in the tool frame.

    Parameters
    ----------
    contacts : list of sim_bridge.realism.needle_tissue.Contact
        Forces on the needle (``world``).
    T_world_tool : ndarray, shape (4, 4)
        The holding tool's pose.
    grasp_point : ndarray, shape (3,)
        Grasp point in the tool frame (m).

    Returns
    -------
    Wrench

    """
    R = T_world_tool[:3, :3]
    j0, j1, j2 = (R @ grasp_point + T_world_tool[:3, 3]).tolist()
    (x0, _, z0), (x1, _, z1), (x2, _, z2) = R[:, [0, 1, 2]].tolist()
    torque = force = k_rot = k_x = 0.0
    for c in contacts:  # plain floats: a few contacts, every physics step
        p0, p1, p2 = c.point.tolist()
        f0, f1, f2 = c.force.tolist()
        l0, l1, l2 = p0 - j0, p1 - j1, p2 - j2
        torque += (l1 * f2 - l2 * f1) * z0 + (l2 * f0 - l0 * f2) * z1 + (l0 * f1 - l1 * f0) * z2
        force += f0 * x0 + f1 * x1 + f2 * x2
        lz = l0 * z0 + l1 * z1 + l2 * z2
        k_rot += c.stiffness * (l0 * l0 + l1 * l1 + l2 * l2 - lz * lz)
        k_x += c.stiffness
    return Wrench(torque, force, k_rot, k_x)


def slipped_grasp(T_tool_needle: np.ndarray, grasp_point: np.ndarray, slip: Slip) -> np.ndarray:
    """
    Return the grasp ``T_tool_needle`` after ``slip`` (turned about tool ``z`` at the grasp).

    Parameters
    ----------
    T_tool_needle : ndarray, shape (4, 4)
        Grasp before.
    grasp_point : ndarray, shape (3,)
        Grasp point (tool frame, m).
    slip : Slip
        The step's slip.

    Returns
    -------
    ndarray, shape (4, 4)

    """
    c, s = math.cos(slip.angle), math.sin(slip.angle)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = T_tool_needle.copy()
    out[:3, :3] = Rz @ T_tool_needle[:3, :3]
    out[:3, 3] = Rz @ (T_tool_needle[:3, 3] - grasp_point) + grasp_point
    out[0, 3] += slip.slide
    return out
