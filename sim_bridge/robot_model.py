"""
URDF robot models of the simulated arms, made from the kinematics chains the simulator runs.

One URDF per arm, as the dVRK's own models (jhu-dvrk/dvrk_model) are split: a PSM with its
instrument (the Large Needle Driver by default) and the ECM with its endoscope. Every joint
origin is the fixed part of the arm's modified-DH link transform
(``SerialChain.joint_placements``: ``RotX(alpha) TransX(a) RotZ(theta0) TransZ(d0)``, offsets
included), and every joint turns about (revolute) or slides along (prismatic) its link's ``z``,
so the URDF's link frame ``<ARM>_<joint>_link`` is the DH frame of that joint, the frame the
simulator's PyBullet link has. The models are built from the chain objects themselves, so they
cannot disagree with the simulator's forward kinematics.

Names, as the dVRK's models and topics use them:

- the root link is the RCM frame ``<ARM>_base`` (the frame of ``local/measured_cp``, which the
  simulator places in ``world`` on ``/tf_static``); ``parent`` attaches it to another frame
  (e.g. ``world``) by a fixed joint ``<ARM>_base_fixed``;
- moving joints are named exactly as in ``measured_js`` (``yaw``, ``pitch``, ``insertion``,
  ``roll``, ``wrist_pitch``, ``wrist_yaw``; the ECM's four) and ``jaw`` as in ``jaw/measured_js``,
  so ``joint_state_publisher`` and ``robot_state_publisher`` take the arm's topics as they are;
- ``<ARM>_tool_tip_link`` hangs on a fixed joint ``tool_tip`` carrying the tooltip offset: its
  frame is the ``measured_cp`` frame (unlike dvrk_model's drawn tip 10.2 mm along the jaws);
- a PSM's jaw as dvrk_model has it: joint ``jaw`` (link ``<ARM>_jaw_link``, no geometry) and
  the two halves ``jaw_1`` / ``jaw_2`` (links ``<ARM>_jaw_1_link`` / ``<ARM>_jaw_2_link``)
  mimicking it x(+0.5) / x(-0.5), all children of ``<ARM>_wrist_yaw_link`` turning about its
  ``z``, the wrist-yaw axis (the tool tip's ``-x``): ``jaw_1`` / ``jaw_2`` turn as the
  simulator's ``jaw_b`` / ``jaw_a`` links (:func:`simulator_link_frames`).

Visual geometry is the simulator's own (``InstrumentShape``: the instrument shaft, the wrist
clevis, the jaws, the endoscope), capsules written as a cylinder with a sphere at each end.
Units are SI (metres, radians); URDF ``rpy`` is ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from collections.abc import Sequence
import math
from xml.etree import ElementTree as ET

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.kinematics import PsmKinematics, SerialChain, ecm_kinematics, psm_kinematics
from sim_bridge.scene.world import ECM_LINKS, PSM_LINKS, InstrumentShape
from sim_bridge.simulation import ARMS, PSMS, SimulationConfig, load_simulation_config

# Smaller magnitudes are written as 0: a cos(pi/2) of 6e-17 is rounding, not geometry.
_ZERO = 1e-12
# URDF wants an effort limit on every moving joint; the simulated arms model no joint forces.
_EFFORT = 0.0

# The simulator's PyBullet link names (``World.link_index``) that are not DH joint names.
_SIM_TO_URDF = {'tip': 'tool_tip', 'jaw_a': 'jaw_2', 'jaw_b': 'jaw_1'}


def is_psm(chain: SerialChain) -> bool:
    """
    Whether a chain is a PSM's (it has a jaw).

    Parameters
    ----------
    chain : SerialChain

    Returns
    -------
    bool

    """
    return isinstance(chain, PsmKinematics)


def base_frame(arm: str) -> str:
    """
    Name of an arm's RCM frame and the root link of its URDF: ``'<ARM>_base'``.

    Parameters
    ----------
    arm : str
        ``'PSM1'``, ``'PSM2'`` or ``'ECM'``.

    Returns
    -------
    str

    """
    return f'{arm}_base'


def link_name(arm: str, link: str) -> str:
    """
    URDF link name of a link of an arm: ``'<ARM>_<link>_link'``.

    Parameters
    ----------
    arm : str
        Arm name.
    link : str
        A joint name (``'yaw'``, ...; the link moved by that joint), ``'tool_tip'``, ``'jaw'``,
        ``'jaw_1'`` or ``'jaw_2'``.

    Returns
    -------
    str

    """
    return f'{arm}_{link}_link'


def simulator_link_frames(arm: str, chain: SerialChain) -> dict[str, tuple[str, np.ndarray]]:
    """
    Map every PyBullet link the simulator builds for an arm to its URDF link.

    Parameters
    ----------
    arm : str
        Arm name.
    chain : SerialChain
        Its kinematics.

    Returns
    -------
    dict of str to (str, ndarray of shape (4, 4))
        ``World.link_index`` names (``'yaw'`` ... ``'tip'``, ``'jaw_a'``, ``'jaw_b'``) to the URDF
        link and the pose of the simulator's link frame in it: the identity, except for the jaw
        halves (hinged on the wrist-yaw link in the URDF, on the tool tip in the simulator), where
        it is the tooltip offset's rotation.

    """
    names = PSM_LINKS if is_psm(chain) else ECM_LINKS
    rotation = np.array(chain.tooltip_offset, dtype=float)
    rotation[:3, 3] = 0.0
    return {n: (link_name(arm, _SIM_TO_URDF.get(n, n)),
                rotation if n in ('jaw_a', 'jaw_b') else np.eye(4)) for n in names}


def rpy_from_matrix(R: ArrayLike) -> tuple[float, float, float]:
    """
    URDF roll, pitch, yaw of a rotation matrix, ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    The yaw is taken first from the first column and removed, then pitch and roll come from
    entries of order one, so the angles rebuild ``R`` to rounding also at and near
    ``pitch = +-pi/2`` (where yaw and roll share one axis and yaw is chosen 0).

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Rotation matrix.

    Returns
    -------
    roll, pitch, yaw : float
        Angles (rad).

    """
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(R, dtype=float).tolist()
    yaw = math.atan2(r10, r00) if abs(r10) + abs(r00) > _ZERO else 0.0
    c, s = math.cos(yaw), math.sin(yaw)
    # Rz(-yaw) R = Ry(pitch) Rx(roll)
    a00 = c * r00 + s * r10
    a11 = -s * r01 + c * r11
    a12 = -s * r02 + c * r12
    pitch = math.atan2(-r20, a00)
    roll = math.atan2(-a12, a11)
    return roll, pitch, yaw


def _number(v: float) -> str:
    """Write ``v`` as the shortest text that reads back as it (whole numbers without a point)."""
    v = float(v)
    if abs(v) < _ZERO:
        return '0'
    return str(int(v)) if v.is_integer() and abs(v) < 1e15 else repr(v)


def _numbers(values: ArrayLike) -> str:
    return ' '.join(_number(v) for v in np.ravel(values))


def _origin(parent: ET.Element, T: ArrayLike) -> None:
    """Add ``<origin xyz rpy>`` of the pose ``T`` (4x4) to ``parent``."""
    T = np.asarray(T, dtype=float)
    ET.SubElement(parent, 'origin', xyz=_numbers(T[:3, 3]),
                  rpy=_numbers(rpy_from_matrix(T[:3, :3])))


def _pose(xyz: ArrayLike, rpy: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 pose of a translation and URDF angles."""
    roll, pitch, yaw = rpy
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    T = np.eye(4)
    T[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                 [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                 [-sp, cp * sr, cp * cr]]
    T[:3, 3] = xyz
    return T


class _UrdfWriter:
    """Links, joints and materials of one robot element."""

    def __init__(self, name: str, materials: dict[str, Sequence[float]]):
        self.robot = ET.Element('robot', name=name)
        for material, rgba in materials.items():
            ET.SubElement(ET.SubElement(self.robot, 'material', name=material), 'color',
                          rgba=_numbers(rgba))

    def link(self, name: str) -> ET.Element:
        return ET.SubElement(self.robot, 'link', name=name)

    def joint(self, name: str, kind: str, parent: str, child: str, T: ArrayLike,
              axis: ArrayLike | None = None,
              limits: tuple[float, float, float] | None = None,
              mimic: tuple[str, float] | None = None) -> ET.Element:
        joint = ET.SubElement(self.robot, 'joint', name=name, type=kind)
        _origin(joint, T)
        ET.SubElement(joint, 'parent', link=parent)
        ET.SubElement(joint, 'child', link=child)
        if axis is not None:
            ET.SubElement(joint, 'axis', xyz=_numbers(axis))
        if limits is not None:
            lower, upper, velocity = limits
            ET.SubElement(joint, 'limit', lower=_number(lower), upper=_number(upper),
                          effort=_number(_EFFORT), velocity=_number(velocity))
        if mimic is not None:
            ET.SubElement(joint, 'mimic', joint=mimic[0], multiplier=_number(mimic[1]),
                          offset='0')
        return joint

    @staticmethod
    def visual(link: ET.Element, material: str, T: ArrayLike, shape: str, **size: str) -> None:
        visual = ET.SubElement(link, 'visual')
        _origin(visual, T)
        ET.SubElement(ET.SubElement(visual, 'geometry'), shape, attrib=dict(size))
        ET.SubElement(visual, 'material', name=material)

    def capsule(self, link: ET.Element, material: str, centre: Sequence[float], along: str,
                radius: float, length: float) -> None:
        """Add a capsule along the link's ``x`` or ``z`` axis: a cylinder and two spheres."""
        rpy = (0.0, math.pi / 2, 0.0) if along == 'x' else (0.0, 0.0, 0.0)
        self.visual(link, material, _pose(centre, rpy), 'cylinder', radius=_number(radius),
                    length=_number(length))
        axis = np.array([1.0, 0.0, 0.0] if along == 'x' else [0.0, 0.0, 1.0])
        for end in (-0.5, 0.5):
            self.visual(link, material, _pose(np.asarray(centre) + end * length * axis),
                        'sphere', radius=_number(radius))

    def text(self) -> str:
        ET.indent(self.robot, space='  ')
        return '<?xml version="1.0"?>\n' + ET.tostring(self.robot, encoding='unicode') + '\n'


def arm_urdf(arm: str, chain: SerialChain, shape: InstrumentShape | None = None,
             parent: str | None = None, T_parent_base: ArrayLike | None = None) -> str:
    """
    URDF of one arm from its kinematics chain, with the simulator's visual shapes.

    Parameters
    ----------
    arm : str
        Arm name (``'PSM1'``, ``'PSM2'``, ``'ECM'``): the robot's name and the prefix of its links.
    chain : SerialChain
        The arm's kinematics (``PsmKinematics`` gets the jaw joints), as the simulator runs it.
    shape : InstrumentShape, optional
        Instrument sizes and colours (default: ``InstrumentShape()``; the simulator passes its
        ``world.instrument``).
    parent : str, optional
        Frame to attach the root ``<ARM>_base`` to (e.g. ``'world'``); default: the RCM frame
        ``<ARM>_base`` is the root.
    T_parent_base : array_like, shape (4, 4), optional
        Pose of ``<ARM>_base`` in ``parent`` (metres); default identity.

    Returns
    -------
    str
        The URDF document (UTF-8 text).

    """
    if not arm or not arm.replace('_', '').isalnum():
        raise ValueError(f'arm name must be letters, digits and underscores, got {arm!r}')
    if T_parent_base is not None and parent is None:
        raise ValueError('T_parent_base needs parent, the frame it is given in')
    shape = shape or InstrumentShape()
    materials = ({'shaft': shape.shaft_rgba, 'wrist': shape.wrist_rgba, 'jaw': shape.jaw_rgba}
                 if is_psm(chain) else {'endoscope': shape.endoscope_rgba})
    w = _UrdfWriter(arm, {f'{arm}_{m}': rgba for m, rgba in materials.items()})
    root = base_frame(arm)
    if parent is not None:
        w.link(parent)
        w.link(root)
        w.joint(f'{root}_fixed', 'fixed', parent, root,
                np.eye(4) if T_parent_base is None else T_parent_base)
    else:
        w.link(root)
    previous = root
    links = {}
    for joint, placement in zip(chain.joints, chain.joint_placements()):
        name = link_name(arm, joint.name)
        links[joint.name] = w.link(name)
        kind = 'revolute' if joint.is_revolute else 'prismatic'
        w.joint(joint.name, kind, previous, name, placement, axis=(0.0, 0.0, 1.0),
                limits=(joint.lower, joint.upper, joint.v_max))
        previous = name
    tip = link_name(arm, 'tool_tip')
    w.link(tip)
    w.joint('tool_tip', 'fixed', previous, tip, chain.tooltip_offset)
    names = list(chain.joint_names)
    roll = links[names[3]]
    if isinstance(chain, PsmKinematics):
        r = shape.wrist_radius
        w.capsule(roll, f'{arm}_shaft', (0.0, 0.0, -0.5 * shape.shaft_length - r), 'z',
                  shape.shaft_radius, shape.shaft_length)
        a6 = chain.joints[5].a
        w.capsule(links[names[4]], f'{arm}_wrist', (0.5 * a6, 0.0, 0.0), 'x', r, abs(a6))
        _jaws(w, arm, chain, shape)
    else:
        w.capsule(roll, f'{arm}_endoscope',
                  (0.0, 0.0, -0.5 * shape.endoscope_length - shape.endoscope_radius
                   - shape.endoscope_gap), 'z', shape.endoscope_radius, shape.endoscope_length)
    return w.text()


def _jaws(w: _UrdfWriter, arm: str, chain: PsmKinematics, shape: InstrumentShape) -> None:
    """Add the jaw joint and its two mimicking halves on the wrist-yaw link, about its ``z``."""
    lower, upper = chain.jaw_lower, chain.jaw_upper
    velocity = chain.jaw_v_max
    wrist = link_name(arm, chain.joint_names[-1])
    offset = np.array(chain.tooltip_offset, dtype=float)
    # the hinge: the tool tip's point, turning about the tool tip's -x (the wrist-yaw z axis
    # for the dVRK's tooltip offset), as the simulator's jaws do
    hinge = np.eye(4)
    hinge[:3, 3] = offset[:3, 3]
    axis = -offset[:3, 0]
    w.link(link_name(arm, 'jaw'))
    w.joint('jaw', 'revolute', wrist, link_name(arm, 'jaw'), hinge, axis=axis,
            limits=(lower, upper, velocity))
    size = _numbers((shape.jaw_width, shape.jaw_thickness, shape.jaw_length))
    rotation = offset.copy()
    rotation[:3, 3] = 0.0
    # jaw_1 turns by -jaw/2 about the tool tip's x, as the simulator's jaw_b (box on tool +y)
    for half, multiplier, side in (('jaw_1', 0.5, 1.0), ('jaw_2', -0.5, -1.0)):
        link = w.link(link_name(arm, half))
        ends = sorted((multiplier * lower, multiplier * upper))
        w.joint(half, 'revolute', wrist, link_name(arm, half), hinge, axis=axis,
                limits=(ends[0], ends[1], 0.5 * velocity), mimic=('jaw', multiplier))
        centre = (0.0, side * 0.5 * shape.jaw_thickness, 0.5 * shape.jaw_length)
        w.visual(link, f'{arm}_jaw', rotation @ _pose(centre), 'box', size=size)


def simulation_urdfs(config: SimulationConfig | None = None,
                     parent: str | None = None) -> dict[str, str]:
    """
    URDF of every arm of the simulator as a configuration builds it.

    Parameters
    ----------
    config : SimulationConfig, optional
        Default: ``config/world.yaml`` and ``config/scene.yaml``
        (:func:`sim_bridge.simulation.load_simulation_config`).
    parent : str, optional
        ``'world'`` attaches each arm's ``<ARM>_base`` to ``world`` where the configuration
        places it; default: each URDF's root is ``<ARM>_base``.

    Returns
    -------
    dict of str to str
        ``{'PSM1': urdf, 'PSM2': urdf, 'ECM': urdf}``.

    """
    if parent not in (None, 'world'):
        raise ValueError(f"parent must be 'world' or None, got {parent!r}")
    cfg = config or load_simulation_config()
    psm = psm_kinematics(cfg.psm_tool) if cfg.psm_tool else psm_kinematics()
    ecm = ecm_kinematics()
    placements = cfg.world.arms
    return {arm: arm_urdf(arm, psm if arm in PSMS else ecm, cfg.world.instrument, parent=parent,
                          T_parent_base=None if parent is None else placements[arm].T)
            for arm in ARMS}
