"""
A simulated dVRK arm behind the CRTK command set: operating state, servo/move, jaw, events.

The arm is kinematic: ``step(dt)`` advances trajectories and moves the measured joints towards
the setpoint within the joint velocity/acceleration limits (the stand-in for the dVRK PID). The
owner (the simulation) calls ``step`` at a fixed period and reads the state properties; commands
may arrive at any time between steps and never raise: bad input becomes an ``error`` event and
the arm keeps holding its setpoint.

Operating-state rules follow the dVRK (cisst ``prmOperatingState``, sawIntuitiveResearchKit
``mtsIntuitiveResearchKitArm``):

- states ``DISABLED``, ``ENABLED``, ``PAUSED``, ``FAULT``; commands ``enable``, ``disable``,
  ``home``, ``unhome``, ``pause``, ``resume``; every ``state_command`` first re-emits the current
  state, a command that the current state does not accept becomes the warning
  ``"<ARM>: command <cmd> is not supported in state <STATE>"``;
- ``enable`` from DISABLED (or FAULT) emits (DISABLED, busy), powers for ``power_up_time``
  seconds of simulated time (the dVRK's POWERING state; another ``enable`` meanwhile changes
  nothing, ``disable`` stops it) and then emits (ENABLED, idle), the arm holding where it is;
- ``home`` (ENABLED only) emits busy, runs a trajectory at the joint trajectory limits from
  where the arm is (its rest pose ``initial_jp`` after start-up) to the homing goal (all joints
  0, insertion 0.12 m) and ends with (ENABLED, homed, idle); ``home`` while homed (or homing)
  is the desired state already reached (or under way): it only re-emits the state, is_homed
  stays true and the arm does not move;
- ``move_*`` (and ``jaw_move_jp``) emit busy at the start, ``goal_reached(True)`` and idle at the
  end, also for zero-length moves (at the next step); a move that arrives while another runs
  replaces it; ``servo_*`` supersede any running move of the same part and leave busy false;
- motion commands while not ready (not ENABLED, not homed, or no tool for Cartesian/jaw
  commands) are ignored with the throttled warning ``"<ARM>: <command>, arm not ready"``.

ECM Cartesian goals (``servo_cp``, ``move_cp``; PoseStamped in the ``measured_cp`` frame, IK on
``base_frame^-1 * goal``): a 4-DOF RCM arm cannot hold an arbitrary tip orientation while it
moves, so the ECM reaches the commanded position, with the camera looking along the line from
the RCM to it (what yaw, pitch and insertion give), and rolls about the shaft as close to the
commanded orientation as that line allows (:meth:`EcmKinematics.ik_position`); ``setpoint_cp``
then carries the commanded position and that orientation. The rest of the orientation is not a
fault and raises nothing. A position outside the workspace (beyond the joint limits) is a
``warning``: ``servo_cp`` goes to the joint-limited pose closest to it, ``move_cp`` moves there
and ends with ``goal_reached`` true; the RCM itself is rejected (``goal_reached`` false). The
PSM (6 joints) reaches position and orientation, and an unreachable pose is an ``error``.

Frames: ``measured_cp = base_frame @ local_measured_cp``, ``local_measured_cp`` being the tool tip
in the RCM frame ``<ARM>_base`` (DH chain and tooltip offset). Units are SI.

Size: one class, the arm's whole CRTK surface: its twenty-odd commands all check their input
against the same state (operating state, limits, frames, the running motion) that :meth:`Arm.step`
advances and the state properties read; cut apart, one object would live in several files.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import logging
import math
import struct
from typing import Any, TypeVar, cast

import numpy as np
from numpy.typing import ArrayLike
from sim_bridge.common.geometry import matrix_from_quaternion
from sim_bridge.common.validation import check_positive, check_quaternions
from sim_bridge.kinematics import EcmKinematics, PsmKinematics, UnreachableError, check_pose
from sim_bridge.realism.servo import ServoLag
from sim_bridge.trajectory import Floats, JointMotion

logger = logging.getLogger(__name__)

STATES = ('DISABLED', 'ENABLED', 'PAUSED', 'FAULT')
STATE_COMMANDS = ('enable', 'disable', 'home', 'unhome', 'pause', 'resume')
# cisst prmOperatingState::ValidCommand
VALID_COMMANDS = {
    'DISABLED': ('enable', 'disable', 'unhome'),
    'ENABLED': ('enable', 'disable', 'pause', 'unhome', 'home'),
    'PAUSED': ('disable', 'pause', 'resume', 'unhome'),
    'FAULT': ('enable', 'disable', 'unhome'),
}
# Joint values as a command gives them (returned as they are when already in joint order).
_Values = TypeVar('_Values')
JAW_NAMES = ('jaw',)  # the joint name of jaw/measured_js and jaw goals
EVENT_KINDS = ('operating_state', 'goal_reached', 'error', 'warning', 'status', 'ratio')


@dataclass(frozen=True)
class OperatingState:
    """
    CRTK operating state (crtk_msgs/OperatingState without the header).

    Attributes
    ----------
    state : str
        ``'DISABLED'``, ``'ENABLED'``, ``'PAUSED'`` or ``'FAULT'``.
    is_homed : bool
    is_busy : bool
        A ``move_*``, ``jaw_move_jp`` or homing trajectory is running.

    """

    state: str
    is_homed: bool
    is_busy: bool


@dataclass(frozen=True)
class ArmEvent:
    """
    Something the dVRK publishes as an event topic.

    Attributes
    ----------
    kind : str
        ``'operating_state'`` (value OperatingState), ``'goal_reached'`` (bool), ``'error'``,
        ``'warning'``, ``'status'`` (str) or ``'ratio'`` (float).
    value : object

    """

    kind: str
    value: object


@dataclass(frozen=True)
class ArmConfig:
    """
    Configuration of a simulated arm.

    Attributes
    ----------
    initial_jp : tuple of float, optional
        Joint positions (rad / m) at start-up; default: the homing goal.
    initial_jaw : float
        PSM jaw angle at start-up (rad).
    home_jp : tuple of float, optional
        Homing goal (rad / m); default: the kinematics' home (insertion 0.12 m, others 0).
    tracking : str
        ``'limited'``: the measured joints follow the setpoint within the velocity and
        acceleration limits; ``'exact'``: measured = setpoint.
    throttle_period : float
        Repeated "not ready" warnings, clipping warnings and errors of streaming (``servo_*``)
        commands are emitted at most once per this much simulated time (s).
    servo_stream_gap : float
        ``servo_*`` commands closer than this (s) form a stream: the measured joints glide from
        one setpoint to the next over the command interval; further apart, a command is a jump.
    tool_present : bool
        PSM instrument present at start-up (Cartesian and jaw commands need it).
    power_up_time : float
        Simulated time (s) from ``enable`` to ENABLED (DISABLED and busy meanwhile); 0: at once.
    servo : sim_bridge.realism.servo.ServoConfig or None
        The arm joints' servo dynamics (lag, overshoot); None: ideal limited tracking.

    """

    initial_jp: tuple[float, ...] | None = None
    initial_jaw: float = 0.0
    home_jp: tuple[float, ...] | None = None
    tracking: str = 'limited'
    throttle_period: float = 1.0
    servo_stream_gap: float = 0.1
    tool_present: bool = True
    power_up_time: float = 0.0
    servo: Any = None

    def __post_init__(self) -> None:
        if self.tracking not in ('limited', 'exact'):
            raise ValueError(f"tracking must be 'limited' or 'exact', got {self.tracking!r}")
        if not self.throttle_period >= 0.0:
            raise ValueError(f'throttle_period must be >= 0 s, got {self.throttle_period}')
        if not (np.isfinite(self.power_up_time) and self.power_up_time >= 0.0):
            raise ValueError(f'power_up_time must be >= 0 s, got {self.power_up_time}')
        check_positive(self.servo_stream_gap, 'servo_stream_gap (s)')


class Arm:
    """
    A simulated dVRK arm (PSM or ECM) with the CRTK command set and operating-state machine.

    Parameters
    ----------
    name : str
        Arm name (``'PSM1'``, ``'ECM'``), used in messages and the default frame id.
    kinematics : PsmKinematics or EcmKinematics
        The arm's chain; a PSM chain adds the jaw.
    config : ArmConfig
        Start-up position, homing goal and tracking options.

    Notes
    -----
    Command methods never raise; results arrive as events (:meth:`pop_events`). Time advances
    only in :meth:`step`.

    """

    def __init__(self, name: str, kinematics: PsmKinematics | EcmKinematics,
                 config: ArmConfig = ArmConfig()) -> None:
        self.name = str(name)
        self.kinematics = kinematics
        self.config = config
        k: Any = kinematics  # a PSM's or the ECM's: the jaw limits are read for a PSM only
        self._has_jaw = isinstance(k, PsmKinematics)
        home = k.home if config.home_jp is None else k.check_q(config.home_jp, name='home_jp')
        if not k.within_limits(home):
            raise ValueError(f'{self.name}: home_jp {home.tolist()} is outside the joint limits')
        self._home = home
        q0 = home if config.initial_jp is None else k.check_q(config.initial_jp,
                                                                name='initial_jp')
        if not k.within_limits(q0):
            raise ValueError(f'{self.name}: initial_jp {q0.tolist()} is outside the joint limits '
                             f'[{k.lower.tolist()}, {k.upper.tolist()}]')
        self._arm = JointMotion(q0, k.lower, k.upper, k.v_max, k.a_max)
        if config.servo is not None and config.tracking == 'limited':
            self._arm.servo_loop = ServoLag(config.servo)
        if self._has_jaw:
            jaw0 = float(config.initial_jaw)
            if not k.jaw_lower <= jaw0 <= k.jaw_upper:
                raise ValueError(f'{self.name}: initial_jaw {jaw0} is outside '
                                 f'[{k.jaw_lower}, {k.jaw_upper}]')
            self._jaw: JointMotion | None = JointMotion([jaw0], [k.jaw_lower], [k.jaw_upper],
                                                        [k.jaw_v_max], [k.jaw_a_max])
        else:
            self._jaw = None
        self._state = 'DISABLED'
        self._homed = False
        self._busy = False
        self._homing = False
        # while powering: the simulated time ENABLED is reached
        self._powered_at: float | None = None
        self._free = False
        self._tool_present = bool(config.tool_present)
        self._ratio = 1.0
        self._base_frame = _read_only(np.eye(4))
        self._base_is_identity = True
        self._exact = config.tracking == 'exact'
        self._pack_joints = struct.Struct(f'{k.n_joints}d').pack  # exact bytes of a joint tuple
        # (goal and reference bytes, joints) of the last servo_cp IK
        self._ik_memo: tuple[tuple[bytes, bytes], Floats] | None = None
        # 'measured' / 'setpoint' -> (joint tuple, read-only tool-tip pose)
        self._fk_memo: dict[str, tuple[Floats, np.ndarray]] = {}
        # 'spatial' / 'body' -> (joint tuple, read-only Jacobian)
        self._jacobian_memo: dict[str, tuple[Floats, np.ndarray]] = {}
        self._reference_frame = f'{self.name}_base'
        self._setpoint_jf = np.zeros(k.n_joints)
        self._time = 0.0
        self._events: list[ArmEvent] = []
        self._last_message: dict[tuple[str, str], float] = {}

    # -- events --------------------------------------------------------------------------------

    def pop_events(self) -> list[ArmEvent]:
        """
        Return and clear the events emitted since the last call, oldest first.

        Returns
        -------
        list of ArmEvent

        """
        events, self._events = self._events, []
        return events

    def _emit(self, kind: str, value: object) -> None:
        self._events.append(ArmEvent(kind, value))

    def _emit_state(self) -> None:
        self._emit('operating_state', self.operating_state)

    def _message(self, kind: str, text: str, throttle_key: tuple[str, str] | None = None) -> None:
        if throttle_key is not None:
            last = self._last_message.get(throttle_key)
            if last is not None and self._time - last < self.config.throttle_period:
                return
            self._last_message[throttle_key] = self._time
        (logger.error if kind == 'error' else logger.warning if kind == 'warning'
         else logger.info)(text)
        self._emit(kind, text)

    def _set_busy(self, busy: bool, force: bool = False) -> None:
        """Emit an operating_state event when busy changes (or always with ``force``)."""
        if busy != self._busy or force:
            self._busy = busy
            self._emit_state()

    def _motion_running(self) -> bool:
        jaw_moving = self._jaw is not None and self._jaw.trajectory is not None
        return self._homing or self._arm.trajectory is not None or jaw_moving

    # -- operating state -----------------------------------------------------------------------

    def state_command(self, command: str) -> None:
        """
        Apply a CRTK state command.

        Parameters
        ----------
        command : str
            ``'enable'``, ``'disable'``, ``'home'``, ``'unhome'``, ``'pause'`` or ``'resume'``.

        Notes
        -----
        Always emits the current operating state first; an unknown command emits an error, a
        command the current state does not accept emits a warning, both without state change.

        """
        self._emit_state()
        if command not in STATE_COMMANDS:
            self._message('error', f'{self.name}: unknown state command {command!r}; expected '
                          f'one of {", ".join(STATE_COMMANDS)}')
            return
        if command not in VALID_COMMANDS[self._state]:
            self._message('warning', f'{self.name}: command {command} is not supported in '
                          f'state {self._state}')
            return
        getattr(self, f'_command_{command}')()

    def _abort_motions(self) -> None:
        """Stop every running move (goal_reached False) and homing; hold the measured joints."""
        for part in (self._arm, self._jaw):
            if part is None:
                continue
            homing = part is self._arm and self._homing
            if part.trajectory is not None and not homing:
                self._emit('goal_reached', False)
            part.hold()
        self._homing = False

    def _command_enable(self) -> None:
        if self._state == 'ENABLED' or self._powered_at is not None:
            return  # enabled, or powering already: the state has been emitted again
        self._state, self._busy = 'DISABLED', True
        self._emit_state()  # powering
        self._arm.hold()
        if self._jaw is not None:
            self._jaw.hold()
        if self.config.power_up_time > 0.0:
            self._powered_at = self._time + self.config.power_up_time
        else:
            self._power_on()

    def _power_on(self) -> None:
        self._powered_at = None
        self._state = 'ENABLED'
        self._free = False
        self._busy = False
        self._emit_state()

    def _command_disable(self) -> None:
        if self._state == 'DISABLED' and self._powered_at is None:
            return
        self._powered_at = None
        self._abort_motions()
        self._state = 'DISABLED'
        self._busy = False
        self._emit_state()

    def _command_pause(self) -> None:
        if self._state == 'PAUSED':
            return
        self._abort_motions()
        self._state = 'PAUSED'
        self._busy = False
        self._emit_state()

    def _command_resume(self) -> None:
        self._state = 'ENABLED'
        self._emit_state()

    def _command_unhome(self) -> None:
        if not self._homed and not self._motion_running():
            return
        self._abort_motions()
        self._homed = False
        self._busy = self._powered_at is not None
        self._emit_state()

    def _command_home(self) -> None:
        if self._homed or self._homing:
            return  # homed (or homing) already, as the dVRK: the state has been emitted again
        self._abort_motions()
        self._homed = False
        self._free = False
        self._arm.move(self._home, self._time, self._ratio)
        self._homing = True
        self._set_busy(True, force=True)

    # -- readiness, validation -----------------------------------------------------------------

    def _ready(self, command: str, needs_tool: bool = False) -> bool:
        ready = self._state == 'ENABLED' and self._homed
        if ready and needs_tool and self._has_jaw and not self._tool_present:
            ready = False
        if not ready:
            self._message('warning', f'{self.name}: {command}, arm not ready',
                          throttle_key=(command, 'not ready'))
        return ready

    def _by_name(self, values: ArrayLike, names: Sequence[str] | None, command: str) -> ArrayLike:
        """Return a joint vector in the arm's joint order (:func:`order_by_name`)."""
        if not names:
            return values  # the common case: crtk clients send no names
        return order_by_name(values, names, self.kinematics.joint_names,
                             f'{self.name}: {command}')

    def _clip_arm(self, command: str, q: np.ndarray, stream: bool) -> np.ndarray:
        clipped = self.kinematics.clip(q)
        if np.any(clipped != q):
            names = [n for n, a, b in zip(self.kinematics.joint_names, q, clipped) if a != b]
            self._message('warning', f'{self.name}: {command} goal clipped to the joint limits '
                          f'({", ".join(names)})',
                          throttle_key=(command, 'clipped') if stream else None)
        return clipped

    def _clip_jaw(self, command: str, angle: float, stream: bool) -> float:
        clipped = cast(PsmKinematics, self.kinematics).clip_jaw(angle)  # a PSM's jaw
        if clipped != angle:
            k = cast(PsmKinematics, self.kinematics)
            self._message('warning', f'{self.name}: {command} angle {angle:.4f} rad clipped to '
                          f'[{k.jaw_lower:.4f}, {k.jaw_upper:.4f}]',
                          throttle_key=(command, 'clipped') if stream else None)
        return clipped

    def _pose_in_rcm(self, pose: ArrayLike, command: str, local: bool = False) -> np.ndarray:
        """
        Validate a Cartesian goal and express it in <ARM>_base.

        The goal is in the measured_cp frame, or in ``<ARM>_base`` already when ``local``.
        """
        if isinstance(pose, np.ndarray) and pose.dtype == np.float64 and pose.shape == (4, 4):
            T = check_pose(pose, name=f'{command} goal')  # the common case: a float matrix
            # in the RCM frame already when the base frame is the identity (solve would copy)
            return T if local or self._base_is_identity else np.linalg.solve(self._base_frame, T)
        arr = np.asarray(pose, dtype=float) if _is_numeric(pose) else None
        if arr is None:
            raise ValueError(f'{command} goal must be a 4x4 pose or (x, y, z, qx, qy, qz, qw)')
        if arr.shape == (7,):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f'{command} goal contains NaN or infinite values')
            q = check_quaternions(arr[3:], f'{command} orientation')
            T = np.eye(4)
            T[:3, :3] = matrix_from_quaternion(q)
            T[:3, 3] = arr[:3]
        else:
            T = check_pose(arr, name=f'{command} goal')
        return T if local else np.linalg.solve(self._base_frame, T)

    # -- arm commands --------------------------------------------------------------------------

    def _servo_arm(self, q: Sequence[float] | np.ndarray) -> None:
        if self._arm.trajectory is not None:
            self._emit('goal_reached', False)
        self._free = False
        self._arm.servo(q, self._time, self.config.servo_stream_gap)
        self._set_busy(self._motion_running())

    def servo_jp(self, q: ArrayLike, names: Sequence[str] | None = None) -> None:
        """
        Set the joint setpoint directly (no trajectory; leaves busy false).

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint positions (rad / m); clipped to the limits with a warning.
        names : sequence of str, optional
            Joint names of ``q``, in any order (:func:`order_by_name`); none, or numeric ones:
            ``q`` is in the arm's joint order.

        """
        if not self._ready('servo_jp'):
            return
        try:
            q = self.kinematics.check_q(self._by_name(q, names, 'servo_jp'),
                                        name='servo_jp position')
        except ValueError as exc:
            self._message('error', f'{self.name}: {exc}', throttle_key=('servo_jp', 'input'))
            return
        self._servo_arm(self._clip_arm('servo_jp', q, stream=True))

    def servo_jr(self, dq: ArrayLike, names: Sequence[str] | None = None) -> None:
        """
        Add a joint increment to the current setpoint.

        Parameters
        ----------
        dq : array_like, shape (n,)
            Joint increments (rad / m).
        names : sequence of str, optional
            Joint names of ``dq`` (as :meth:`servo_jp`).

        """
        if not self._ready('servo_jr'):
            return
        try:
            dq = self.kinematics.check_q(self._by_name(dq, names, 'servo_jr'),
                                         name='servo_jr increment')
        except ValueError as exc:
            self._message('error', f'{self.name}: {exc}', throttle_key=('servo_jr', 'input'))
            return
        self._servo_arm(self._clip_arm('servo_jr', self._arm.setpoint + dq, stream=True))

    def servo_cp(self, pose: ArrayLike, local: bool = False) -> None:
        """
        Set a Cartesian setpoint: closed-form IK near the current setpoint.

        Parameters
        ----------
        pose : array_like, shape (4, 4) or (7,)
            Tool-tip goal in the ``measured_cp`` frame (``base_frame`` applied), as a matrix or as
            ``(x, y, z, qx, qy, qz, qw)`` (metres, unit quaternion).
        local : bool
            The goal is in the RCM frame ``<ARM>_base`` (as ``local_measured_cp``) instead.

        """
        if not self._ready('servo_cp', needs_tool=True):
            return
        try:
            T = self._pose_in_rcm(pose, 'servo_cp', local)
            q_ref = self._arm.setpoint_values
            key = (T.tobytes(), self._pack_joints(*q_ref))
            if self._ik_memo is not None and self._ik_memo[0] == key:
                q = self._ik_memo[1]  # the same goal from the same setpoint: same answer
            elif not self._has_jaw:
                q = tuple(self._ecm_goal(T, np.array(q_ref), 'servo_cp', stream=True).tolist())
                self._ik_memo = (key, q)
            else:
                # the pose is checked and the setpoint finite: no second check in the IK
                q = self.kinematics.ik_unchecked(T, q_ref)
                self._ik_memo = (key, q)
        except _OutsideWorkspaceError:
            return
        except UnreachableError as exc:
            self._message('error', f'{self.name}: servo_cp goal unreachable: {exc}',
                          throttle_key=('servo_cp', 'unreachable'))
            return
        except ValueError as exc:
            self._message('error', f'{self.name}: {exc}', throttle_key=('servo_cp', 'input'))
            return
        self._servo_arm(q)

    def _ecm_goal(self, T: np.ndarray, q_ref: ArrayLike, command: str, stream: bool) -> np.ndarray:
        """
        ECM joints for a Cartesian goal in ``<ARM>_base``: its position, roll about the shaft.

        A position outside the workspace is a warning and gives the joint-limited pose closest
        to it; the RCM itself raises :class:`_OutsideWorkspaceError` after the warning.
        """
        throttle = (command, 'workspace') if stream else None
        p = T[:3, 3]
        where = f'({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m'
        try:
            q, inside = cast(EcmKinematics, self.kinematics).ik_position(T, q_ref=q_ref)
        except UnreachableError as exc:
            self._message('warning', f'{self.name}: {command} position {where} is outside the '
                          f'workspace: {exc}', throttle_key=throttle)
            raise _OutsideWorkspaceError from exc
        if not inside:
            clipped = self.kinematics.clip(q)
            names = [n for n, a, b in zip(self.kinematics.joint_names, q, clipped) if a != b]
            self._message('warning', f'{self.name}: {command} position {where} is outside the '
                          f'workspace; going to the closest pose within the joint limits '
                          f'({", ".join(names)} limited)', throttle_key=throttle)
            q = clipped
        return q

    def reject_goal(self, command: str, text: str) -> None:
        """
        Refuse a Cartesian goal its sender placed in a frame the arm's owner does not know.

        A ``warning`` (throttled per command); a ``move_cp`` also gets its busy pulse, closed by
        ``goal_reached`` false, so a client waiting for the move ends. The arm holds its goal.
        """
        self._message('warning', text, throttle_key=(command, 'frame'))
        if command.startswith('move'):
            self._set_busy(True, force=True)
            self._emit('goal_reached', False)
            self._set_busy(self._motion_running())

    def _reject_move(self, text: str) -> None:
        """Error, then a busy pulse closed by goal_reached(False), the arm holding its goal."""
        self._message('error', text)
        self._set_busy(True, force=True)
        self._emit('goal_reached', False)
        self._set_busy(self._motion_running())

    def _move_arm(self, goal: np.ndarray) -> None:
        self._arm.move(goal, self._time, self._ratio)
        self._free = False
        self._set_busy(True, force=True)

    def move_jp(self, q: ArrayLike, names: Sequence[str] | None = None) -> None:
        """
        Start a joint trajectory to ``q`` (busy until it arrives, then goal_reached True).

        Parameters
        ----------
        q : array_like, shape (n,)
            Goal joint positions (rad / m); clipped to the limits with a warning.
        names : sequence of str, optional
            Joint names of ``q`` (as :meth:`servo_jp`).

        """
        if not self._ready('move_jp'):
            return
        try:
            q = self.kinematics.check_q(self._by_name(q, names, 'move_jp'),
                                        name='move_jp position')
        except ValueError as exc:
            self._reject_move(f'{self.name}: {exc}')
            return
        self._move_arm(self._clip_arm('move_jp', q, stream=False))

    def move_jr(self, dq: ArrayLike, names: Sequence[str] | None = None) -> None:
        """
        Start a joint trajectory by an increment from the current setpoint.

        Parameters
        ----------
        dq : array_like, shape (n,)
            Joint increments (rad / m).
        names : sequence of str, optional
            Joint names of ``dq`` (as :meth:`servo_jp`).

        """
        if not self._ready('move_jr'):
            return
        try:
            dq = self.kinematics.check_q(self._by_name(dq, names, 'move_jr'),
                                         name='move_jr increment')
        except ValueError as exc:
            self._reject_move(f'{self.name}: {exc}')
            return
        goal = self._arm.target(self._time)[0] + dq
        self._move_arm(self._clip_arm('move_jr', goal, stream=False))

    def move_cp(self, pose: ArrayLike, local: bool = False) -> None:
        """
        Start a joint trajectory to the IK solution of a Cartesian goal (not a straight line).

        Parameters
        ----------
        pose : array_like, shape (4, 4) or (7,)
            Tool-tip goal in the ``measured_cp`` frame, matrix or ``(x, y, z, qx, qy, qz, qw)``.
        local : bool
            The goal is in the RCM frame ``<ARM>_base`` instead.

        Notes
        -----
        An unreachable goal emits an error and a busy pulse ending with goal_reached False.

        """
        if not self._ready('move_cp', needs_tool=True):
            return
        try:
            T = self._pose_in_rcm(pose, 'move_cp', local)
            q_ref = self._arm.target(self._time)[0]
            if self._has_jaw:
                q = self.kinematics.ik(T, q_ref=q_ref)
            else:
                q = self._ecm_goal(T, q_ref, 'move_cp', stream=False)
        except _OutsideWorkspaceError:
            self._set_busy(True, force=True)  # the warning is out: a pulse ending the move
            self._emit('goal_reached', False)
            self._set_busy(self._motion_running())
            return
        except UnreachableError as exc:
            self._reject_move(f'{self.name}: move_cp goal unreachable: {exc}')
            return
        except ValueError as exc:
            self._reject_move(f'{self.name}: {exc}')
            return
        self._move_arm(q)

    def servo_jf(self, effort: ArrayLike, names: Sequence[str] | None = None) -> None:
        """
        Record a joint effort setpoint (N, N m); the kinematic simulation does not act on it.

        Parameters
        ----------
        effort : array_like, shape (n,)
        names : sequence of str, optional
            Joint names of ``effort`` (as :meth:`servo_jp`).

        """
        try:
            self._setpoint_jf = self.kinematics.check_q(self._by_name(effort, names, 'servo_jf'),
                                                        name='servo_jf effort')
        except ValueError as exc:
            self._message('error', f'{self.name}: {exc}', throttle_key=('servo_jf', 'input'))

    def hold(self) -> None:
        """Stop every motion and hold the measured position (running moves: goal_reached False)."""
        if self._state != 'ENABLED':
            return
        self._abort_motions()
        self._free = False
        self._set_busy(False)

    def free(self) -> None:
        """Stop holding: the arm stays where it is and setpoints follow the measured joints."""
        if self._state != 'ENABLED':
            return
        self._abort_motions()
        self._free = True
        self._set_busy(False)

    # -- jaw -----------------------------------------------------------------------------------

    def _jaw_angle(self, command: str, angle: ArrayLike | None,
                   names: Sequence[str] | None = None) -> float | None:
        if not self._has_jaw:
            self._message('error', f'{self.name}: {command}: this arm has no jaw')
            return None
        if not self._ready(command, needs_tool=True):
            return None
        if isinstance(angle, float) and math.isfinite(angle):  # the common case, a number
            return self._clip_jaw(command, float(angle), stream=command == 'jaw_servo_jp')
        if names:
            try:
                angle = order_by_name(angle, names, JAW_NAMES, f'{self.name}: {command}')
            except ValueError as exc:
                self._report_input(command, str(exc))
                return None
        try:
            value = np.asarray(angle, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            value = np.array([np.nan, np.nan])
        if value.shape != (1,) or not math.isfinite(value[0]):
            self._report_input(command, f'{self.name}: {command} needs one finite angle (rad), '
                                        f'got {angle!r}')
            return None
        return self._clip_jaw(command, float(value[0]), stream=command == 'jaw_servo_jp')

    def _report_input(self, command: str, text: str) -> None:
        """Reject a jaw goal: a move ends at once (goal_reached False), a servo stream warns."""
        if command == 'jaw_move_jp':
            self._reject_move(text)
        else:
            self._message('error', text, throttle_key=(command, 'input'))

    def jaw_servo_jp(self, angle: ArrayLike | None, names: Sequence[str] | None = None) -> None:
        """
        Set the jaw setpoint directly (PSM only).

        Parameters
        ----------
        angle : float or array_like, shape (1,)
            Jaw opening angle (rad); clipped to the jaw range with a warning.
        names : sequence of str, optional
            ``('jaw',)``, none, or a numeric name; any other is rejected.

        """
        angle = self._jaw_angle('jaw_servo_jp', angle, names)
        if angle is None:
            return
        # a PSM's jaw (casts: typing only): _jaw_angle rejects an arm without one
        if cast(JointMotion, self._jaw).trajectory is not None:
            self._emit('goal_reached', False)
        cast(JointMotion, self._jaw).servo((angle,), self._time, self.config.servo_stream_gap)
        self._set_busy(self._motion_running())

    def jaw_move_jp(self, angle: ArrayLike | None, names: Sequence[str] | None = None) -> None:
        """
        Start a jaw trajectory (PSM only); shares the arm's busy flag, runs alongside arm moves.

        Parameters
        ----------
        angle : float or array_like, shape (1,)
            Goal jaw angle (rad); clipped to the jaw range with a warning.
        names : sequence of str, optional
            As :meth:`jaw_servo_jp`.

        """
        angle = self._jaw_angle('jaw_move_jp', angle, names)
        if angle is None:
            return
        cast(JointMotion, self._jaw).move((angle,), self._time, self._ratio)  # a PSM's
        self._set_busy(True, force=True)

    # -- settings ------------------------------------------------------------------------------

    def set_ratio(self, ratio: float) -> None:
        """
        Scale the trajectory velocity and acceleration limits (``trajectory_j/set_ratio``).

        Parameters
        ----------
        ratio : float
            In ]0, 1]; applies to trajectories started afterwards. Emits a ``ratio`` event.

        """
        try:
            r = float(ratio)
        except (TypeError, ValueError):
            r = float('nan')
        if not (np.isfinite(r) and 0.0 < r <= 1.0):
            self._message('error', f'{self.name}: trajectory ratio must be in ]0, 1], '
                          f'got {ratio!r}')
            return
        self._ratio = r
        self._emit('ratio', r)

    def set_base_frame(self, pose: ArrayLike, frame_id: str | None = None,
                       checked: bool = False) -> None:
        """
        Set the base frame: ``measured_cp = base_frame @ local_measured_cp``.

        Parameters
        ----------
        pose : array_like, shape (4, 4)
            ``T_ref_base``: the RCM frame ``<ARM>_base`` in the new reference frame (metres).
        frame_id : str, optional
            Name of the new reference frame (the ``measured_cp`` frame id); default keeps the
            current one.
        checked : bool
            ``pose`` is a rigid float matrix of the caller's own making, taken as it is (the
            simulation's camera frame, set again at every step the ECM moves); default: it is
            checked, and a bad one is an ``error`` event.

        """
        if checked:
            T = cast(np.ndarray, pose)  # checked by the caller: a float 4x4 pose
        else:
            try:
                T = check_pose(pose, name='set_base_frame pose')
            except ValueError as exc:
                self._message('error', f'{self.name}: {exc}')
                return
        self._base_frame = _read_only(T)
        self._base_is_identity = False if checked else bool(np.array_equal(T, np.eye(4)))
        if frame_id:
            self._reference_frame = str(frame_id)

    def emulate_tool_present(self, present: bool) -> None:
        """
        Pretend a PSM instrument is (or is not) mounted; Cartesian and jaw commands need one.

        Parameters
        ----------
        present : bool

        """
        self._tool_present = bool(present)
        self._message('status', f'{self.name}: tool {"present" if present else "removed"} '
                      '(emulated)')

    # -- time ----------------------------------------------------------------------------------

    def step(self, dt: float) -> None:
        """
        Advance the arm by ``dt`` seconds of simulated time.

        Parameters
        ----------
        dt : float
            Time step (s), > 0.

        """
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'step dt must be a positive number of seconds, got {dt}')
        self._time += dt
        now = self._time
        if self._powered_at is not None and now >= self._powered_at - 1e-9:
            self._power_on()
        arm, jaw = self._arm, self._jaw
        if self._state != 'ENABLED':
            arm.stop()
            if jaw is not None:
                jaw.stop()
            return
        exact = self._exact
        if self._free:
            arm.hold()
            arm_arrived = False
        else:
            arm_arrived = arm.advance(now, dt, exact)
        jaw_arrived = jaw is not None and jaw.advance(now, dt, exact)
        if arm_arrived:
            if self._homing:
                self._homing = False
                self._homed = True
                self._busy = self._motion_running()
                self._emit_state()
            else:
                self._emit('goal_reached', True)
        if jaw_arrived:
            self._emit('goal_reached', True)
        # _motion_running(), written out
        busy = self._homing or arm.trajectory is not None or (
            jaw is not None and jaw.trajectory is not None)
        if busy != self._busy:
            self._set_busy(busy)

    # -- state ---------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Simulated time (s) accumulated by :meth:`step`."""
        return self._time

    @property
    def has_jaw(self) -> bool:
        """Whether the arm has a jaw (PSM)."""
        return self._has_jaw

    @property
    def operating_state(self) -> OperatingState:
        """Current :class:`OperatingState`."""
        return OperatingState(self._state, self._homed, self._busy)

    @property
    def ratio(self) -> float:
        """Trajectory ratio in ]0, 1]."""
        return self._ratio

    @property
    def base_frame(self) -> np.ndarray:
        """``T_ref_base``, shape (4, 4): the RCM frame in the ``measured_cp`` reference frame."""
        return self._base_frame.copy()

    @property
    def base_frame_view(self) -> np.ndarray:
        """:attr:`base_frame` without the copy: read-only, the same array until it is set."""
        return self._base_frame

    @property
    def reference_frame(self) -> str:
        """Frame id of ``measured_cp`` / ``setpoint_cp`` (default ``'<ARM>_base'``)."""
        return self._reference_frame

    @property
    def tool_present(self) -> bool:
        """Whether a PSM instrument is (emulated as) mounted."""
        return self._tool_present

    @property
    def measured_jp(self) -> np.ndarray:
        """Measured joint positions, shape (n,) (rad / m)."""
        return np.array(self._arm.q_values)

    @property
    def measured_jv(self) -> np.ndarray:
        """Measured joint velocities, shape (n,) (rad/s, m/s)."""
        return np.array(self._arm.qd_values)

    @property
    def measured_jf(self) -> np.ndarray:
        """Measured joint efforts, shape (n,) (N, N m); zero in the kinematic simulation."""
        return np.zeros(self.kinematics.n_joints)

    @property
    def setpoint_jp(self) -> np.ndarray:
        """Joint setpoint, shape (n,) (rad / m): servo goal or current trajectory sample."""
        return np.array(self._arm.setpoint_values)

    @property
    def setpoint_jf(self) -> np.ndarray:
        """Joint effort setpoint, shape (n,) (N, N m): the last ``servo_jf``."""
        return self._setpoint_jf.copy()

    @property
    def local_measured_cp(self) -> np.ndarray:
        """Tool tip in the RCM frame ``<ARM>_base``, shape (4, 4) (metres)."""
        return self._fk('measured', self._arm.q_values).copy()

    @property
    def local_measured_cp_view(self) -> np.ndarray:
        """
        :attr:`local_measured_cp` without the copy: a read-only array.

        The same array object as long as the measured joints do not move, so that a caller can
        keep what it derived from it (the simulation's world pose of the tool) until then.
        """
        return self._fk('measured', self._arm.q_values)

    @property
    def local_setpoint_cp(self) -> np.ndarray:
        """Tool-tip setpoint in the RCM frame ``<ARM>_base``, shape (4, 4) (metres)."""
        return self._fk('setpoint', self._arm.setpoint_values).copy()

    def _fk(self, which: str, q: Floats) -> np.ndarray:
        """Forward kinematics of the joint tuple ``q``, computed again only when it moved."""
        memo = self._fk_memo.get(which)
        if memo is None or memo[0] is not q:  # a joint tuple is replaced when the joints move
            # the arm's own joints, finite since every command is checked: no check again
            memo = self._fk_memo[which] = (q, self.kinematics.fk_unchecked(q, read_only=True))
        return memo[1]

    @property
    def measured_cp(self) -> np.ndarray:
        """Tool tip in :attr:`reference_frame`: ``base_frame @ local_measured_cp``, (4, 4)."""
        return self._base_frame @ self._fk('measured', self._arm.q_values)

    @property
    def setpoint_cp(self) -> np.ndarray:
        """Tool-tip setpoint in :attr:`reference_frame`, shape (4, 4) (metres)."""
        return self._base_frame @ self._fk('setpoint', self._arm.setpoint_values)

    @property
    def jacobian_spatial(self) -> np.ndarray:
        """Spatial Jacobian at the measured joints, shape (6, n): ``[v; w]`` in ``<ARM>_base``."""
        return self._jacobian('spatial').copy()

    @property
    def jacobian_body(self) -> np.ndarray:
        """Body Jacobian at the measured joints, shape (6, n): ``[v; w]`` in the tip frame."""
        return self._jacobian('body').copy()

    def _jacobian(self, which: str) -> np.ndarray:
        """Jacobian at the measured joints (read-only), computed again only when they moved."""
        q = self._arm.q_values
        memo = self._jacobian_memo.get(which)
        if memo is None or memo[0] is not q:
            J = (self.kinematics.jacobian(np.array(q)) if which == 'spatial'
                 else self.kinematics.jacobian_body(np.array(q)))
            memo = self._jacobian_memo[which] = (q, _read_only(J))
        return memo[1]

    @property
    def measured_cv(self) -> np.ndarray:
        """
        Tool-tip twist, shape (6,): linear (m/s) and angular (rad/s) velocity.

        Expressed in the orientation of :attr:`reference_frame` (base frame applied), as the dVRK
        rotates the body twist by the ``measured_cp`` rotation.

        """
        twist = self._jacobian('spatial') @ np.array(self._arm.qd_values)
        R = self._base_frame[:3, :3]
        return np.concatenate([R @ twist[:3], R @ twist[3:]])

    @property
    def local_measured_cv(self) -> np.ndarray:
        """Body twist of the tool tip, shape (6,): ``[v; w]`` in the tool-tip frame."""
        return self._jacobian('body') @ np.array(self._arm.qd_values)

    def _require_jaw(self) -> JointMotion:
        if not self._has_jaw:
            raise AttributeError(f'{self.name} has no jaw')
        return cast(JointMotion, self._jaw)  # set for an arm with a jaw

    @property
    def jaw_measured_jp(self) -> float:
        """Measured jaw angle (rad), PSM only."""
        return self._require_jaw().q_values[0]

    @property
    def jaw_measured_jv(self) -> float:
        """Measured jaw velocity (rad/s), PSM only."""
        return self._require_jaw().qd_values[0]

    @property
    def jaw_setpoint_jp(self) -> float:
        """Jaw setpoint (rad), PSM only."""
        return self._require_jaw().setpoint_values[0]


def _read_only(array: np.ndarray) -> np.ndarray:
    """Return ``array`` marked read-only (it is shared, not copied)."""
    array.flags.writeable = False
    return array


def _positional(names: Sequence[object]) -> bool:
    """Whether joint names say nothing of the order: none, or all numeric (``'0'``, ``'1'``)."""
    return all(str(n).strip().isdigit() for n in names)


def order_by_name(values: _Values, names: Sequence[str] | None, joint_names: Sequence[str],
                  what: str = 'joint goal') -> _Values | np.ndarray:
    """
    Put a joint vector given with joint names into the arm's joint order.

    The dVRK simulators' contract: joint commands are mapped by name, in any order; with no
    names, or numeric names only, they are taken by position.

    Parameters
    ----------
    values : array_like, shape (k,)
        Positions (rad / m), increments or efforts, one per name.
    names : sequence of str or None
        Their joint names.
    joint_names : sequence of str
        The arm's joints, in its order (``measured_js`` names).
    what : str
        The command, for messages.

    Returns
    -------
    array_like
        ``values`` itself when taken by position, else a float array of shape
        ``(len(joint_names),)``.

    Raises
    ------
    ValueError
        If a name is not one of the arm's joints, a joint is named twice or not at all, or the
        numbers of names and values differ.

    """
    if not names or _positional(names):
        return values
    names = tuple(names)
    joint_names = tuple(joint_names)
    if names == joint_names:
        return values
    expected = ', '.join(joint_names)
    unknown = [n for n in names if n not in joint_names]
    if unknown:
        raise ValueError(f'{what}: unknown joint name{"s" if len(unknown) > 1 else ""} '
                         f'{", ".join(map(repr, unknown))}; the joints are {expected}')
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f'{what}: joint {", ".join(map(repr, twice))} named more than once')
    missing = [n for n in joint_names if n not in names]
    if missing:
        raise ValueError(f'{what}: no value for joint {", ".join(map(repr, missing))}; name '
                         f'every joint ({expected}) or none')
    try:
        arr = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f'{what}: joint values must be numbers, got {values!r}') from None
    if arr.size != len(names):
        raise ValueError(f'{what}: {len(names)} joint names for {arr.size} values')
    index = {n: i for i, n in enumerate(names)}
    return arr[[index[n] for n in joint_names]]


class _OutsideWorkspaceError(Exception):
    """An ECM Cartesian goal at the RCM: warned about, nothing to move to."""


def _is_numeric(value: object) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True
