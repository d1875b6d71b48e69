"""
The state machine of the dVRK's MTM -> PSM teleoperation, without ROS.

States (``dvrk_teleoperation.py``, names as the issue of this package gives them):

- ``SETTING_ARMS``: both arms must be ENABLED, homed and not busy; ``enable`` / ``home`` are
  sent when they are not (once, again after ``command_retry`` s if the arm did not start on it);
  enabling and homing take the arm's time (``is_busy``), which is waited on;
- ``ALIGNING``: with ``align_mtm`` the MTM is moved (``move_cp``) to the PSM's orientation
  seen through the camera, and following waits until they agree within
  ``orientation_tolerance``; the operator must be present (coag pedal) and active (the gripper
  opened or closed by ``start_gripper_threshold``, or the wrist rolled by
  ``start_roll_threshold``, in this state, before or after the pedal: either order), then the
  map is anchored;
- ``FOLLOWING``: every cycle the PSM gets ``servo_cp`` (the anchored map of the MTM pose) and
  ``jaw/servo_jp`` (the rate-limited gripper);
- ``CLUTCHED``: the clutch pedal is down: the PSM holds (``hold``), the MTM's orientation is
  locked (``lock_orientation``) when it is aligned, the hand recentres; releasing the clutch goes
  back through ``ALIGNING`` and anchors again, so the tool does not jump.

When the operator leaves (coag released), the PSM holds, the gesture is forgotten and the
machine goes back to ``ALIGNING``; when an arm stops being ready, back to ``SETTING_ARMS``.

:meth:`Teleoperation.step` takes one cycle's :class:`TeleopInputs` and returns the commands
(:class:`Command`) for the ROS layer to send, in order.
"""

from dataclasses import dataclass
import math
from typing import NamedTuple, Optional

import numpy as np
from sim_bridge.common.validation import check_positive
from suture_lfd.teleop.mapping import DEG, CartesianMap, GripperToJaw, JawRamp

SETTING_ARMS = 'SETTING_ARMS'
ALIGNING = 'ALIGNING'
FOLLOWING = 'FOLLOWING'
CLUTCHED = 'CLUTCHED'
DISABLED = 'DISABLED'


@dataclass(frozen=True)
class TeleopConfig:
    """
    Parameters of the teleoperation (names as in ``config/teleop.yaml``).

    Attributes
    ----------
    mtm, psm, ecm : str
        Namespaces of the arms (``ecm``: the camera; ``''`` = motion in the PSM's frame).
    clutch_topic, operator_present_topic : str
        sensor_msgs/Joy pedals (``buttons[0]`` 1 = pressed); ``operator_present_topic`` ``''``:
        the operator is always present.
    rate : float
        Cycles per second (the dVRK's teleop: 200, ``--interval 0.005``).
    idle_rate : float
        Cycles per second while nobody teleoperates: the operator is not present and the
        teleoperation neither follows nor is clutched (the node's cycles cost CPU for nothing).
    scale : float
        PSM translation per MTM translation.
    align_mtm : bool
        Move the MTM's wrist to the PSM's orientation before following (off for a device
        without a powered wrist).
    rotation_locked, translation_locked : bool
        Keep the PSM's orientation / position while following.
    ignore_jaw : bool
        Do not command the jaw.
    mtm_rotation : tuple of float
        Quaternion (x, y, z, w) of the MTM's frame in the camera frame, used when the MTM's
        ``measured_cp`` frame is not on ``/tf_static`` (a console's display frame).
    orientation_tolerance, start_gripper_threshold, start_roll_threshold : float
        rad (the dVRK: 5, 5 and 3 degrees); thresholds 0 make the operator active at once.
    gripper_zero, gripper_max, jaw_min, jaw_max, jaw_at_gripper_zero : float
        Gripper -> jaw map (rad), :class:`suture_lfd.teleop.mapping.GripperToJaw`.
    jaw_rate, jaw_rate_back_from_clutch, tolerance_back_from_clutch : float
        Jaw ramp (rad/s, rad).
    enable_arms : bool
        Enable and home the arms that are not.
    command_retry : float
        s before an ``enable``/``home`` that did not start the arm is sent again.
    align_period : float
        s between two alignment moves of the MTM.

    """

    mtm: str = 'MTMR'
    psm: str = 'PSM1'
    ecm: str = 'ECM'
    clutch_topic: str = '/footpedals/clutch'
    operator_present_topic: str = '/footpedals/coag'
    rate: float = 200.0
    idle_rate: float = 10.0
    scale: float = 0.2
    align_mtm: bool = True
    rotation_locked: bool = False
    translation_locked: bool = False
    ignore_jaw: bool = False
    mtm_rotation: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0)
    orientation_tolerance: float = 5.0 * DEG
    start_gripper_threshold: float = 5.0 * DEG
    start_roll_threshold: float = 3.0 * DEG
    # the gripper -> jaw map: GripperToJaw's defaults, stated there only
    gripper_zero: float = GripperToJaw.gripper_zero
    gripper_max: float = GripperToJaw.gripper_max
    jaw_min: float = GripperToJaw.jaw_min
    jaw_max: float = GripperToJaw.jaw_max
    jaw_at_gripper_zero: float = GripperToJaw.jaw_at_gripper_zero
    jaw_rate: float = GripperToJaw.jaw_rate
    jaw_rate_back_from_clutch: float = GripperToJaw.jaw_rate_back_from_clutch
    tolerance_back_from_clutch: float = GripperToJaw.tolerance_back_from_clutch
    enable_arms: bool = True
    command_retry: float = 10.0
    align_period: float = 10.0

    def __post_init__(self) -> None:
        for name in ('rate', 'idle_rate', 'scale', 'command_retry', 'align_period'):
            check_positive(getattr(self, name), f'parameter {name}')
        for name in ('orientation_tolerance', 'start_gripper_threshold', 'start_roll_threshold'):
            if getattr(self, name) < 0:
                raise ValueError(f'parameter {name} must be >= 0, got {getattr(self, name)}')
        if not self.mtm or not self.psm:
            raise ValueError('parameters mtm and psm must name the arms (e.g. MTMR, PSM1)')
        q = np.asarray(self.mtm_rotation, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1) > 1e-6:
            raise ValueError(f'parameter mtm_rotation must be a unit quaternion (x, y, z, w), '
                             f'got {list(self.mtm_rotation)}')
        self.gripper_to_jaw()   # checks the jaw parameters

    def gripper_to_jaw(self) -> GripperToJaw:
        """Return the :class:`GripperToJaw` of these parameters."""
        return GripperToJaw(
            gripper_zero=self.gripper_zero, gripper_max=self.gripper_max, jaw_min=self.jaw_min,
            jaw_max=self.jaw_max, jaw_at_gripper_zero=self.jaw_at_gripper_zero,
            jaw_rate=self.jaw_rate, jaw_rate_back_from_clutch=self.jaw_rate_back_from_clutch,
            tolerance_back_from_clutch=self.tolerance_back_from_clutch)


class ArmState(NamedTuple):
    """An arm's ``operating_state``."""

    state: str
    is_homed: bool
    is_busy: bool

    @property
    def ready(self) -> bool:
        """ENABLED, homed and not busy (the CRTK "ready")."""
        return self.state == 'ENABLED' and self.is_homed and not self.is_busy

    @property
    def operational(self) -> bool:
        """ENABLED and homed (a move of its own may be under way)."""
        return self.state == 'ENABLED' and self.is_homed


@dataclass
class TeleopInputs:
    """
    What one cycle reads (None: not received yet).

    Attributes
    ----------
    t : float
        Time (s, monotonic).
    mtm_cp : ndarray (4, 4) or None
        MTM ``measured_cp`` (frame M).
    gripper : float or None
        MTM ``gripper/measured_js`` position (rad).
    psm_cp : ndarray (4, 4) or None
        PSM ``setpoint_cp`` (frame P).
    psm_jaw : float or None
        PSM ``jaw/setpoint_js`` position (rad).
    mtm_state, psm_state : ArmState or None
    R_C_M, R_C_P : ndarray (3, 3) or None
        Rotations of the MTM's and PSM's frames into the camera frame.
    clutch, operator_present : bool

    """

    t: float
    mtm_cp: Optional[np.ndarray] = None
    gripper: Optional[float] = None
    psm_cp: Optional[np.ndarray] = None
    psm_jaw: Optional[float] = None
    mtm_state: Optional[ArmState] = None
    psm_state: Optional[ArmState] = None
    R_C_M: Optional[np.ndarray] = None
    R_C_P: Optional[np.ndarray] = None
    clutch: bool = False
    operator_present: bool = False


class Command(NamedTuple):
    """
    One command for the ROS layer.

    ``kind``: ``state_command`` (value: 'enable'/'home'), ``servo_cp`` (4x4), ``jaw_servo_jp``
    (rad), ``hold``, ``move_cp`` (4x4), ``lock_orientation`` (3x3), ``unlock_orientation``,
    ``use_gravity_compensation`` (bool), ``body_servo_cf`` (6 zeros); ``arm``: 'mtm' or 'psm'.
    """

    kind: str
    arm: str
    value: object = None


class Teleoperation:
    """
    One MTM -> PSM teleoperation.

    Parameters
    ----------
    config : TeleopConfig

    """

    def __init__(self, config: TeleopConfig) -> None:
        self.config = config
        self.map = CartesianMap(config.scale, config.rotation_locked,
                                config.translation_locked)
        self.jaw = JawRamp(config.gripper_to_jaw())
        self.state = SETTING_ARMS
        self.enabled = True
        self.operator_active = False
        self._back_from_clutch = False
        self._active_before_clutch = False
        self._sent: dict[tuple[str, str], float] = {}  # (arm, command) -> time sent
        self._last_align = -math.inf
        self._range: list[float] | None = None  # [gripper min, max, roll min, max] since aligning
        self._present = False
        self._t: float | None = None
        self.transitions: list[tuple[float, str]] = []  # (t, state) history, for logs and tests

    # --- helpers --------------------------------------------------------------------------

    def _enter(self, t: float, state: str) -> None:
        self.state = state
        self.transitions.append((t, state))

    def _ready_inputs(self, inp: TeleopInputs) -> bool:
        return (inp.mtm_cp is not None and inp.psm_cp is not None and inp.R_C_M is not None
                and inp.R_C_P is not None)

    def _arm_commands(self, inp: TeleopInputs, out: list[Command]) -> bool:
        """Send enable/home to arms that need it; return whether both are ready."""
        ready = True
        for arm, st in (('psm', inp.psm_state), ('mtm', inp.mtm_state)):
            if st is None:
                ready = False
                continue
            if st.ready:
                continue
            ready = False
            if not self.config.enable_arms or st.is_busy:
                continue
            command = 'enable' if st.state != 'ENABLED' else ('home' if not st.is_homed else '')
            if not command:
                continue
            key = (arm, command)
            if inp.t - self._sent.get(key, -math.inf) >= self.config.command_retry:
                self._sent[key] = inp.t
                out.append(Command('state_command', arm, command))
        return ready

    def _track_activity(self, inp: TeleopInputs) -> None:
        """Watch gripper and roll for the operator's "I am here" gesture."""
        cfg = self.config
        if self.operator_active:
            return
        if cfg.start_gripper_threshold == 0 or cfg.start_roll_threshold == 0:
            self.operator_active = True
            return
        R_goal = CartesianMap.aligned_mtm_rotation(inp.psm_cp[:3, :3], inp.R_C_M, inp.R_C_P)
        y_goal, y_mtm = R_goal[:, 1], inp.mtm_cp[:3, 1]
        roll = math.acos(max(-1.0, min(1.0, float(y_goal @ y_mtm))))
        g = inp.gripper if inp.gripper is not None else 0.0
        if self._range is None:
            self._range = [g, g, roll, roll]
        r = self._range
        r[0], r[1] = min(r[0], g), max(r[1], g)
        r[2], r[3] = min(r[2], roll), max(r[3], roll)
        grip, turn = r[1] - r[0], r[3] - r[2]
        if grip >= cfg.start_gripper_threshold or turn >= cfg.start_roll_threshold or \
                grip + turn > 0.8 * (cfg.start_gripper_threshold + cfg.start_roll_threshold):
            self.operator_active = True

    def _enter_aligning(self, t: float) -> None:
        self._enter(t, ALIGNING)
        self._last_align = -math.inf
        self._range = None
        if self._back_from_clutch:
            self.operator_active = self._active_before_clutch

    def _start_following(self, inp: TeleopInputs, out: list[Command]) -> None:
        cfg = self.config
        self.map.anchor(inp.mtm_cp, inp.psm_cp, inp.R_C_M, inp.R_C_P)
        if not cfg.ignore_jaw:
            jaw = inp.psm_jaw if inp.psm_jaw is not None else cfg.jaw_at_gripper_zero
            self.jaw.start(jaw, back_from_clutch=self._back_from_clutch)
        self._back_from_clutch = False
        out.append(Command('use_gravity_compensation', 'mtm', True))
        out.append(Command('body_servo_cf', 'mtm', (0.0,) * 6))
        if cfg.rotation_locked:
            out.append(Command('lock_orientation', 'mtm', inp.mtm_cp[:3, :3].copy()))
        else:
            out.append(Command('unlock_orientation', 'mtm'))
        self._enter(inp.t, FOLLOWING)

    def _clutch_in(self, inp: TeleopInputs, out: list[Command]) -> None:
        self._active_before_clutch = self.operator_active
        if self.config.align_mtm or self.config.rotation_locked:
            out.append(Command('lock_orientation', 'mtm', inp.mtm_cp[:3, :3].copy()))
        else:
            out.append(Command('unlock_orientation', 'mtm'))
        out.append(Command('hold', 'psm'))
        self._enter(inp.t, CLUTCHED)

    # --- the cycle ------------------------------------------------------------------------

    def set_enabled(self, enabled: bool, t: float) -> None:
        """Enable or disable the teleoperation (the dVRK teleop's ``state_command``)."""
        self.enabled = bool(enabled)
        if not self.enabled and self.state != DISABLED:
            self._enter(t, DISABLED)
        elif self.enabled and self.state == DISABLED:
            self._enter(t, SETTING_ARMS)

    def step(self, inp: TeleopInputs) -> list[Command]:
        """
        Run one cycle on ``inp`` (:class:`TeleopInputs`); return the commands, in order.

        Returns
        -------
        list of Command

        """
        cfg = self.config
        out: list[Command] = []
        dt = 0.0 if self._t is None else max(0.0, inp.t - self._t)
        self._t = inp.t
        present = inp.operator_present
        if self._present and not present:
            self.operator_active = False    # the operator left: wait for a new gesture
            self._range = None
        self._present = present
        if self.state == DISABLED:
            return out
        arms_ready = self._arm_commands(inp, out)
        operational = all(st is not None and st.operational
                          for st in (inp.mtm_state, inp.psm_state))
        if self.state != SETTING_ARMS and not (operational and self._ready_inputs(inp)):
            if self.state == FOLLOWING:
                out.append(Command('hold', 'psm'))
            self._enter(inp.t, SETTING_ARMS)
            return out
        if self.state == SETTING_ARMS:
            if arms_ready and self._ready_inputs(inp):
                self._enter_aligning(inp.t)
            else:
                return out
        if self.state == FOLLOWING:
            if not present:
                out.append(Command('hold', 'psm'))
                self._enter_aligning(inp.t)
                return out
            if inp.clutch:
                self._clutch_in(inp, out)
                return out
            out.append(Command('servo_cp', 'psm', self.map.goal(inp.mtm_cp)))
            if not cfg.ignore_jaw and inp.gripper is not None:
                out.append(Command('jaw_servo_jp', 'psm', self.jaw.step(inp.gripper, dt)))
            return out
        if self.state == CLUTCHED:
            if not present:
                self._back_from_clutch = False
                self._enter_aligning(inp.t)
            elif not inp.clutch:
                self._back_from_clutch = True
                self._enter_aligning(inp.t)
            return out
        # ALIGNING
        error = 0.0
        if cfg.align_mtm:
            error = CartesianMap.alignment_error(inp.mtm_cp[:3, :3], inp.psm_cp[:3, :3],
                                                 inp.R_C_M, inp.R_C_P)
        mtm_busy = inp.mtm_state is not None and inp.mtm_state.is_busy
        if cfg.align_mtm and not inp.clutch and error > cfg.orientation_tolerance \
                and inp.t - self._last_align >= cfg.align_period and not mtm_busy:
            self._last_align = inp.t
            T = np.array(inp.mtm_cp, dtype=float)
            T[:3, :3] = CartesianMap.aligned_mtm_rotation(inp.psm_cp[:3, :3], inp.R_C_M,
                                                          inp.R_C_P)
            out.append(Command('move_cp', 'mtm', T))
            self._range = None          # the move turns the wrist: not the operator's gesture
            return out
        if not mtm_busy:
            self._track_activity(inp)       # a pinch counts before the coag pedal as after
        if present and self.operator_active and error <= cfg.orientation_tolerance \
                and not mtm_busy:
            if inp.clutch:
                self._start_following(inp, [])
                self._clutch_in(inp, out)
            else:
                self._start_following(inp, out)
        return out
